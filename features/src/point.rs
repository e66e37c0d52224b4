//! The point: one 3-D point (paper section IV-E), e.g. a ceiling lamp or a landmark.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use slam_core::{
    Coincidence, CoordBlock, Coordinates, Error, Feature, Growth, Ink, Mark, Result, Shape, Sketch,
    Subspace, downcast_feature, stack_rows,
};

/// x and y of the point.
pub const HORIZONTAL: Subspace = Subspace {
    name: "horizontal",
    rows: 2,
    description: "x and y of the point: revealed by a planar range-bearing sensor, or with \
                  the height by triangulating bearings from two or more views",
};

/// z of the point.
pub const HEIGHT: Subspace = Subspace {
    name: "height",
    rows: 1,
    description: "z of the point: revealed by triangulating camera bearings (a ceiling lamp)",
};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum PointSubspace {
    Horizontal,
    Height,
}

impl PointSubspace {
    fn spec(self) -> Subspace {
        match self {
            PointSubspace::Horizontal => HORIZONTAL,
            PointSubspace::Height => HEIGHT,
        }
    }

    /// Rows of B; B is the identity at full dimension (Table II), so B~ = B^T.
    fn rows(self) -> DMatrix<f64> {
        match self {
            PointSubspace::Horizontal => {
                DMatrix::from_row_slice(2, 3, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
            }
            PointSubspace::Height => DMatrix::from_row_slice(1, 3, &[0.0, 0.0, 1.0]),
        }
    }
}

/// A point feature, `x_f = {x^3D}` (Table I).
///
/// Its M-space at full dimension is the identity (Table II). This crate splits it into
/// `"horizontal"` (x, y) and `"height"` (z) so that a planar sensor, which cannot observe z,
/// carries a 2-D point without an unobservable row: the M-space idea applied to the point.
/// A lamp triangulated by a camera gains both at once (dimension 3, as in the paper).
///
/// ```
/// use slam_features::Point;
/// use slam_core::{Feature, nalgebra::Vector3};
/// let lamp = Point::full(Vector3::new(2.0, 1.0, 2.5)).unwrap();
/// assert_eq!(lamp.mspace_dim(), 3);
/// let landmark = Point::planar(Vector3::new(2.0, 1.0, 0.0)).unwrap();
/// assert_eq!(landmark.mspace_dim(), 2);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PointRepr", into = "PointRepr")]
pub struct Point {
    coordinates: Coordinates,
    active: Vec<PointSubspace>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PointRepr {
    position: Vector3<f64>,
    active: Vec<PointSubspace>,
}

impl From<Point> for PointRepr {
    fn from(point: Point) -> Self {
        PointRepr {
            position: point.position(),
            active: point.active,
        }
    }
}

impl TryFrom<PointRepr> for Point {
    type Error = Error;
    fn try_from(repr: PointRepr) -> Result<Self> {
        let mut point = Point::new(repr.position)?;
        for s in repr.active {
            point.activate(s.spec().name)?;
        }
        Ok(point)
    }
}

impl Point {
    /// A tentative point (M-space dimension 0).
    pub fn new(position: Vector3<f64>) -> Result<Self> {
        Ok(Point {
            coordinates: Coordinates::new([CoordBlock::Point3(position)])?,
            active: Vec::new(),
        })
    }

    /// A point with its full M-space (dimension 3, Table I).
    pub fn full(position: Vector3<f64>) -> Result<Self> {
        let mut point = Point::new(position)?;
        point.active = vec![PointSubspace::Horizontal, PointSubspace::Height];
        Ok(point)
    }

    /// A point observed by a planar sensor: x and y in its M-space, z held fixed.
    pub fn planar(position: Vector3<f64>) -> Result<Self> {
        let mut point = Point::new(position)?;
        point.active = vec![PointSubspace::Horizontal];
        Ok(point)
    }

    /// Whether the subspace named `name` ([`HORIZONTAL`], [`HEIGHT`]) is in the M-space,
    /// without listing the subspaces.
    ///
    /// ```
    /// use slam_features::point::{Point, HEIGHT, HORIZONTAL};
    /// let landmark = Point::planar(slam_core::nalgebra::Vector3::new(2.0, 1.0, 0.0)).unwrap();
    /// assert!(landmark.is_active(HORIZONTAL.name) && !landmark.is_active(HEIGHT.name));
    /// ```
    pub fn is_active(&self, name: &str) -> bool {
        self.active.iter().any(|s| s.spec().name == name)
    }

    /// `B~` on the stack: its first [`Feature::mspace_dim`] columns are
    /// [`Feature::dual`]'s, the rest zero (a range-bearing filter's hot path takes them
    /// without an allocation).
    ///
    /// ```
    /// use slam_core::Feature;
    /// use slam_features::point::Point;
    /// let landmark = Point::planar(slam_core::nalgebra::Vector3::new(2.0, 1.0, 0.0)).unwrap();
    /// let (dual, dim) = landmark.dual_columns();
    /// assert_eq!(dual.columns(0, dim), landmark.dual().unwrap());
    /// ```
    pub fn dual_columns(&self) -> (Matrix3<f64>, usize) {
        let mut dual = Matrix3::zeros();
        let mut column = 0;
        for subspace in &self.active {
            match subspace {
                PointSubspace::Horizontal => {
                    dual[(0, column)] = 1.0;
                    dual[(1, column + 1)] = 1.0;
                    column += 2;
                }
                PointSubspace::Height => {
                    dual[(2, column)] = 1.0;
                    column += 1;
                }
            }
        }
        (dual, column)
    }

    /// The position.
    pub fn position(&self) -> Vector3<f64> {
        match self.coordinates.blocks()[0] {
            CoordBlock::Point3(p) => p,
            _ => Vector3::from_element(f64::NAN),
        }
    }
}

#[typetag::serde(name = "point")]
impl Feature for Point {
    /// A 3-D point once placed in every direction, else a point of the floor plane.
    fn shape(&self) -> Option<Shape> {
        let position = self.position();
        Some(if self.mspace_dim() >= 3 {
            Shape::Point { position }
        } else {
            Shape::PlanarPoint {
                position: position.xy(),
            }
        })
    }

    /// Another point is this point when they coincide: in 3-D when both are placed in
    /// height, else in the floor plane.
    fn coincidence(&self, other: &dyn Feature) -> Result<Option<Coincidence>> {
        let Some(other) = downcast_feature::<Point>(other) else {
            return Ok(None);
        };
        let dims = if self.mspace_dim() >= 3 && other.mspace_dim() >= 3 {
            3
        } else {
            2
        };
        let difference = self.position() - other.position();
        let identity = DMatrix::identity(dims, 3);
        Ok(Some(Coincidence {
            residual: DVector::from_column_slice(&difference.as_slice()[..dims]),
            d_self: identity.clone(),
            d_other: -identity,
        }))
    }

    fn sketch(&self) -> Sketch {
        let ink = if self.mspace_dim() >= 3 {
            Ink::Ceiling
        } else {
            Ink::Point
        };
        let at = self.position().xy();
        Sketch::new("points and lamps", ink)
            .with(Mark::Marker {
                at,
                ink,
                size: 7,
                filled: true,
            })
            .with(Mark::Ellipse { offset: 0, at, ink })
    }

    fn kind(&self) -> &'static str {
        "point"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        if !matches!(coordinates.blocks(), [CoordBlock::Point3(_)]) {
            return Err(Error::InvalidArgument(
                "a point's coordinates are one 3-D point".into(),
            ));
        }
        self.coordinates = coordinates;
        Ok(())
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        self.active.iter().map(|s| s.spec()).collect()
    }

    /// The rows of the active subspaces, without collecting them (run for every point at
    /// every update).
    fn mspace_dim(&self) -> usize {
        self.active.iter().map(|s| s.spec().rows).sum()
    }

    fn growth_options(&self) -> Vec<Subspace> {
        [PointSubspace::Horizontal, PointSubspace::Height]
            .into_iter()
            .filter(|s| !self.active.contains(s))
            .map(PointSubspace::spec)
            .collect()
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        let wanted = [PointSubspace::Horizontal, PointSubspace::Height]
            .into_iter()
            .find(|s| s.spec().name == subspace && !self.active.contains(s))
            .ok_or_else(|| Error::Growth {
                feature: "point",
                subspace: subspace.to_string(),
                reason: format!("not available now (active {:?})", self.active),
            })?;
        let before = self.mspace_dim();
        self.active.push(wanted);
        Ok(Growth {
            subspace: wanted.spec(),
            rows: before..before + wanted.spec().rows,
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        stack_rows(3, &self.active, |s| Ok(s.rows()))
    }

    /// `B^T`, written directly: B is made of unit rows (one column of B~ per active
    /// coordinate), and this runs for every observation of a point.
    fn dual(&self) -> Result<DMatrix<f64>> {
        let (dual, dim) = self.dual_columns();
        Ok(DMatrix::from_fn(3, dim, |i, j| dual[(i, j)]))
    }

    /// `x_f += B~ dx_p` without forming B~: its rows are unit rows (the hot path of a
    /// landmark EKF, run for every point at every update).
    fn apply_perturbation(&mut self, dx_p: &slam_core::nalgebra::DVector<f64>) -> Result<()> {
        slam_core::check_perturbation(self.kind(), self.mspace_dim(), dx_p)?;
        let mut position = self.position();
        let mut row = 0;
        for subspace in &self.active {
            match subspace {
                PointSubspace::Horizontal => {
                    position.x += dx_p[row];
                    position.y += dx_p[row + 1];
                    row += 2;
                }
                PointSubspace::Height => {
                    position.z += dx_p[row];
                    row += 1;
                }
            }
        }
        slam_core::ensure_finite(position.as_slice(), "point after perturbation")?;
        self.coordinates.set_block(0, CoordBlock::Point3(position))
    }
}

#[cfg(test)]
mod dual_tests {
    use super::*;

    /// The directly written B~ is B^T for every order of activation.
    #[test]
    fn dual_is_the_transposed_projection() {
        let position = Vector3::new(1.0, -2.0, 0.5);
        let mut cases = vec![
            Point::new(position).unwrap(),
            Point::planar(position).unwrap(),
        ];
        let mut full = Point::planar(position).unwrap();
        full.activate(HEIGHT.name).unwrap();
        cases.push(full);
        let mut height_first = Point::new(position).unwrap();
        height_first.activate(HEIGHT.name).unwrap();
        height_first.activate(HORIZONTAL.name).unwrap();
        cases.push(height_first);
        for point in cases {
            assert_eq!(
                point.dual().unwrap(),
                point.projection().unwrap().transpose()
            );
            assert_eq!(
                point.mspace_dim(),
                point
                    .active_subspaces()
                    .iter()
                    .map(|s| s.rows)
                    .sum::<usize>()
            );
        }
    }
}
