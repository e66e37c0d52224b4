//! Small 2-D geometry shared by the line-like features.

use slam_core::nalgebra::Vector2;
use slam_core::{Error, Result, ensure_finite};

/// A segment's length, unit tangent (start to end) and left unit normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Segment2 {
    pub length: f64,
    pub tangent: Vector2<f64>,
    pub normal: Vector2<f64>,
}

impl Segment2 {
    /// The segment from `start` to `end`; an error if not finite or shorter than `min_length`.
    pub fn new(start: Vector2<f64>, end: Vector2<f64>, min_length: f64) -> Result<Self> {
        ensure_finite(start.as_slice(), "segment start")?;
        ensure_finite(end.as_slice(), "segment end")?;
        let segment = Self::unchecked(start, end);
        if segment.length.is_nan() || segment.length < min_length {
            return Err(Error::Degenerate(format!(
                "segment of length {:.3e} m is shorter than {min_length:e} m",
                segment.length
            )));
        }
        Ok(segment)
    }

    /// The segment without checks (callers hold already validated endpoints).
    pub fn unchecked(start: Vector2<f64>, end: Vector2<f64>) -> Self {
        let d = end - start;
        let length = d.norm();
        let tangent = d / length;
        Segment2 {
            length,
            tangent,
            normal: Vector2::new(-tangent.y, tangent.x),
        }
    }
}
