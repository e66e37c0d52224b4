//! The horizontal line: a ceiling line seen by an upward camera, two 3-D endpoints at one
//! height (paper section IV-G, Table II).

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Vector2, Vector3};
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, Growth, Ink, Mark, Result, Shape, Sketch, Subspace,
    stack_rows,
};

use crate::geometry::Segment2;

/// Direction in the horizontal plane.
pub const DIRECTION: Subspace = Subspace {
    name: "direction",
    rows: 1,
    description: "direction of the line in the horizontal plane (rotation about the centre \
                  scaled by 1/L): revealed by a single image of the line",
};

/// Horizontal normal offset and height.
pub const POSITION: Subspace = Subspace {
    name: "position",
    rows: 2,
    description: "horizontal normal offset of the centre and height: revealed by \
                  triangulating the line from two or more views",
};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum HLineSubspace {
    Direction,
    Position,
}

impl HLineSubspace {
    fn spec(self) -> Subspace {
        match self {
            HLineSubspace::Direction => DIRECTION,
            HLineSubspace::Position => POSITION,
        }
    }
}

/// A horizontal line, `x_f = {x_start^3D, x_end^3D}` with equal heights (Table I).
///
/// The horizontal constraint is kept by the M-space: no row of B~ changes the two heights
/// differently (section IV-C). `gamma` is the angle of the horizontal left normal of
/// start -> end, as for a wall. The tangential positions of the endpoints are never in the
/// M-space ("the position tangential to the line is not measured").
///
/// ```
/// use slam_features::HLine;
/// use slam_core::{Feature, nalgebra::Vector3};
/// let line = HLine::new(Vector3::new(0.0, 0.0, 2.5), Vector3::new(3.0, 0.0, 2.5)).unwrap();
/// let line = line.with_subspaces(&["direction", "position"]).unwrap();
/// assert_eq!(line.mspace_dim(), 3);
/// assert!(HLine::new(Vector3::new(0.0, 0.0, 2.5), Vector3::new(3.0, 0.0, 2.0)).is_err());
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "HLineRepr", into = "HLineRepr")]
pub struct HLine {
    coordinates: Coordinates,
    active: Vec<HLineSubspace>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct HLineRepr {
    start: Vector3<f64>,
    end: Vector3<f64>,
    active: Vec<HLineSubspace>,
}

impl From<HLine> for HLineRepr {
    fn from(line: HLine) -> Self {
        HLineRepr {
            start: line.start(),
            end: line.end(),
            active: line.active,
        }
    }
}

impl TryFrom<HLineRepr> for HLine {
    type Error = Error;
    fn try_from(repr: HLineRepr) -> Result<Self> {
        let mut line = HLine::new(repr.start, repr.end)?;
        for s in repr.active {
            line.activate(s.spec().name)?;
        }
        Ok(line)
    }
}

impl HLine {
    /// Shortest horizontal length accepted, in metres.
    pub const MIN_LENGTH: f64 = 1e-3;
    /// Largest height difference of the endpoints accepted, in metres (rounding only).
    pub const HEIGHT_TOLERANCE: f64 = 1e-9;

    /// A tentative horizontal line (dimension 0).
    pub fn new(start: Vector3<f64>, end: Vector3<f64>) -> Result<Self> {
        Ok(HLine {
            coordinates: Self::checked(start, end)?,
            active: Vec::new(),
        })
    }

    fn checked(start: Vector3<f64>, end: Vector3<f64>) -> Result<Coordinates> {
        let coordinates = Coordinates::new([CoordBlock::Point3(start), CoordBlock::Point3(end)])?;
        if (start.z - end.z).abs() > Self::HEIGHT_TOLERANCE * start.z.abs().max(1.0) {
            return Err(Error::InvalidArgument(format!(
                "horizontal line endpoints at different heights {} and {}",
                start.z, end.z
            )));
        }
        Segment2::new(start.xy(), end.xy(), Self::MIN_LENGTH)?;
        Ok(coordinates)
    }

    /// The line with its M-space grown by the named subspaces, in order.
    pub fn with_subspaces(mut self, names: &[&str]) -> Result<Self> {
        for name in names {
            self.activate(name)?;
        }
        Ok(self)
    }

    /// The start point.
    pub fn start(&self) -> Vector3<f64> {
        self.point(0)
    }

    /// The end point.
    pub fn end(&self) -> Vector3<f64> {
        self.point(1)
    }

    fn point(&self, index: usize) -> Vector3<f64> {
        match self.coordinates.blocks()[index] {
            CoordBlock::Point3(p) => p,
            _ => Vector3::from_element(f64::NAN),
        }
    }

    /// Height of the line.
    pub fn height(&self) -> f64 {
        self.start().z
    }

    /// Horizontal left normal `(cos gamma, sin gamma)`.
    pub fn normal(&self) -> Vector2<f64> {
        Segment2::unchecked(self.start().xy(), self.end().xy()).normal
    }

    fn rows(&self, subspace: HLineSubspace) -> Result<DMatrix<f64>> {
        let segment = Segment2::new(self.start().xy(), self.end().xy(), Self::MIN_LENGTH)?;
        let (n, l, s2) = (segment.normal, segment.length, std::f64::consts::SQRT_2);
        Ok(match subspace {
            HLineSubspace::Direction => DMatrix::from_row_slice(
                1,
                6,
                &[
                    n.x / (l * s2),
                    n.y / (l * s2),
                    0.0,
                    -n.x / (l * s2),
                    -n.y / (l * s2),
                    0.0,
                ],
            ),
            HLineSubspace::Position => DMatrix::from_row_slice(
                2,
                6,
                &[
                    n.x / s2,
                    n.y / s2,
                    0.0,
                    n.x / s2,
                    n.y / s2,
                    0.0,
                    0.0,
                    0.0,
                    1.0 / s2,
                    0.0,
                    0.0,
                    1.0 / s2,
                ],
            ),
        })
    }

    /// Columns of B~ for one subspace, written as rows (the dual of Table II's HLine B).
    fn dual_rows(&self, subspace: HLineSubspace) -> Result<DMatrix<f64>> {
        let segment = Segment2::new(self.start().xy(), self.end().xy(), Self::MIN_LENGTH)?;
        let (n, l, s2) = (segment.normal, segment.length, std::f64::consts::SQRT_2);
        Ok(match subspace {
            HLineSubspace::Direction => DMatrix::from_row_slice(
                1,
                6,
                &[
                    l * n.x / s2,
                    l * n.y / s2,
                    0.0,
                    -l * n.x / s2,
                    -l * n.y / s2,
                    0.0,
                ],
            ),
            HLineSubspace::Position => DMatrix::from_row_slice(
                2,
                6,
                &[
                    n.x / s2,
                    n.y / s2,
                    0.0,
                    n.x / s2,
                    n.y / s2,
                    0.0,
                    0.0,
                    0.0,
                    1.0 / s2,
                    0.0,
                    0.0,
                    1.0 / s2,
                ],
            ),
        })
    }

    fn allowed_growth(&self) -> Option<HLineSubspace> {
        match self.active.as_slice() {
            [] => Some(HLineSubspace::Direction),
            [HLineSubspace::Direction] => Some(HLineSubspace::Position),
            _ => None,
        }
    }
}

#[typetag::serde(name = "hline")]
impl Feature for HLine {
    /// Scored once placed in every direction (dimension 3).
    fn shape(&self) -> Option<Shape> {
        (self.mspace_dim() >= 3).then(|| Shape::Line {
            start: self.start(),
            end: self.end(),
        })
    }

    fn sketch(&self) -> Sketch {
        let (ink, width, label) = if self.mspace_dim() >= 3 {
            (Ink::Ceiling, 3, "ceiling lines (dim 3)")
        } else {
            (Ink::CeilingDirection, 1, "ceiling lines, direction only")
        };
        Sketch::new(label, ink).with(Mark::Segment {
            from: self.start().xy(),
            to: self.end().xy(),
            ink,
            width,
        })
    }

    fn kind(&self) -> &'static str {
        "hline"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        let [CoordBlock::Point3(start), CoordBlock::Point3(end)] = coordinates.blocks() else {
            return Err(Error::InvalidArgument(
                "a horizontal line's coordinates are two 3-D points".into(),
            ));
        };
        let checked = Self::checked(*start, *end)?;
        let old = self.end().xy() - self.start().xy();
        if (end.xy() - start.xy()).dot(&old) <= 0.0 {
            return Err(Error::Degenerate(
                "horizontal line update reverses its direction".into(),
            ));
        }
        self.coordinates = checked;
        Ok(())
    }

    /// The endpoints in this line's order: swapped when they run against it.
    fn conform(&self, coordinates: Coordinates) -> Coordinates {
        match coordinates.blocks() {
            [CoordBlock::Point3(start), CoordBlock::Point3(end)]
                if (end.xy() - start.xy()).dot(&(self.end().xy() - self.start().xy())) < 0.0 =>
            {
                Coordinates::new([CoordBlock::Point3(*end), CoordBlock::Point3(*start)])
                    .unwrap_or(coordinates)
            }
            _ => coordinates,
        }
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        self.active.iter().map(|s| s.spec()).collect()
    }

    /// The rows of the active subspaces, without collecting them.
    fn mspace_dim(&self) -> usize {
        self.active.iter().map(|s| s.spec().rows).sum()
    }

    fn growth_options(&self) -> Vec<Subspace> {
        self.allowed_growth()
            .map(HLineSubspace::spec)
            .into_iter()
            .collect()
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        let wanted = self
            .allowed_growth()
            .filter(|s| s.spec().name == subspace)
            .ok_or_else(|| Error::Growth {
                feature: "hline",
                subspace: subspace.to_string(),
                reason: format!(
                    "not available now (active {:?}); direction comes first",
                    self.active
                ),
            })?;
        let before = self.mspace_dim();
        self.active.push(wanted);
        Ok(Growth {
            subspace: wanted.spec(),
            rows: before..before + wanted.spec().rows,
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        stack_rows(6, &self.active, |&s| self.rows(s))
    }

    fn dual(&self) -> Result<DMatrix<f64>> {
        Ok(stack_rows(6, &self.active, |&s| self.dual_rows(s))?.transpose())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::nalgebra::DVector;

    /// The directions never in the M-space stay put: tangential positions of both endpoints
    /// and the height difference (the horizontal constraint, section IV-C).
    #[test]
    fn perturbations_keep_tangential_positions_and_equal_heights() {
        let start = Vector3::new(1.0, 2.0, 2.2);
        let end = Vector3::new(4.0, -1.0, 2.2);
        let mut line = HLine::new(start, end)
            .unwrap()
            .with_subspaces(&["direction", "position"])
            .unwrap();
        let tangent = (end - start).xy().normalize();
        line.apply_perturbation(&DVector::from_vec(vec![1e-3, 0.05, -0.1]))
            .unwrap();
        assert!(((line.start() - start).xy().dot(&tangent)).abs() < 1e-12);
        assert!(((line.end() - end).xy().dot(&tangent)).abs() < 1e-12);
        assert_eq!(line.start().z, line.end().z);
        assert!((line.height() - (2.2 - 0.1 / std::f64::consts::SQRT_2)).abs() < 1e-12);
    }
}
