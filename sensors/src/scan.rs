//! A planar laser scan.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::Vector2;

use crate::error::{Result, SensorError};

/// The most beams a simulated laser may have (a resource limit; real 2-D lasers have a few
/// thousand at most).
pub const MAX_BEAMS: usize = 100_000;

/// One sweep of a planar laser: ranges at equally spaced bearings in the sensor frame
/// (counter-clockwise from `angle_min`, 0 straight ahead).
///
/// A reading is **valid** when it is finite, above `min_range` and below `max_range`; invalid
/// readings (NaN, infinite, negative, zero, max-range "no return") are kept in `ranges` so that
/// indices match the beams, and skipped by [`LaserScan::points`].
///
/// ```
/// use slam_sensors::LaserScan;
/// let scan = LaserScan::new(-1.0, 1.0, vec![2.0, f64::NAN, 80.0], 0.05, 80.0).unwrap();
/// assert_eq!(scan.points().len(), 1);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserScan {
    /// Bearing of the first beam, rad.
    pub angle_min: f64,
    /// Angle between consecutive beams, rad (positive).
    pub angle_increment: f64,
    /// Measured ranges, m, one per beam.
    pub ranges: Vec<f64>,
    /// Readings at or below this are invalid, m.
    pub min_range: f64,
    /// Readings at or above this are "no return", m.
    pub max_range: f64,
}

/// A valid reading as a point in the sensor frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanPoint {
    /// Beam index.
    pub index: usize,
    /// Range, m.
    pub range: f64,
    /// Bearing, rad.
    pub bearing: f64,
    /// `(range cos bearing, range sin bearing)`.
    pub position: Vector2<f64>,
}

impl LaserScan {
    /// A scan whose beams span `angle_min ..= angle_max` evenly.
    pub fn new(
        angle_min: f64,
        angle_max: f64,
        ranges: Vec<f64>,
        min_range: f64,
        max_range: f64,
    ) -> Result<Self> {
        if ranges.is_empty() {
            return Err(SensorError::InvalidArgument(
                "a scan needs at least one beam".into(),
            ));
        }
        let increment = if ranges.len() > 1 {
            (angle_max - angle_min) / (ranges.len() - 1) as f64
        } else {
            0.0
        };
        LaserScan::with_increment(angle_min, increment, ranges, min_range, max_range)
    }

    /// A scan from its first bearing and the spacing of the beams.
    pub fn with_increment(
        angle_min: f64,
        angle_increment: f64,
        ranges: Vec<f64>,
        min_range: f64,
        max_range: f64,
    ) -> Result<Self> {
        let finite = [angle_min, angle_increment, min_range, max_range]
            .iter()
            .all(|v| v.is_finite());
        if !finite || angle_increment < 0.0 || min_range < 0.0 || max_range <= min_range {
            return Err(SensorError::InvalidArgument(format!(
                "scan geometry: angle_min {angle_min}, increment {angle_increment}, \
                 range limits {min_range}..{max_range}"
            )));
        }
        Ok(LaserScan {
            angle_min,
            angle_increment,
            ranges,
            min_range,
            max_range,
        })
    }

    /// Bearing of beam `index`.
    pub fn bearing(&self, index: usize) -> f64 {
        self.angle_min + self.angle_increment * index as f64
    }

    /// Whether a range value is a usable return.
    pub fn is_valid(&self, range: f64) -> bool {
        range.is_finite() && range > self.min_range && range < self.max_range
    }

    /// The valid readings as points, in beam order.
    pub fn points(&self) -> Vec<ScanPoint> {
        self.ranges
            .iter()
            .enumerate()
            .filter(|(_, r)| self.is_valid(**r))
            .map(|(index, &range)| {
                let bearing = self.bearing(index);
                ScanPoint {
                    index,
                    range,
                    bearing,
                    position: Vector2::new(range * bearing.cos(), range * bearing.sin()),
                }
            })
            .collect()
    }
}
