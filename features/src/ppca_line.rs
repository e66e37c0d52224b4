//! A line cluster of IPSLAM (Brunskill & Roy 2005): a 1-D probabilistic PCA model of laser
//! points, `N(mu, W W^T + sigma^2 I)`, shown as the segment a uniform spread of the same
//! principal variance would cover. Its M-space is a wall's `line` subspace (rotation about the
//! centre and normal offset, Table II), so outputs and post-processing treat it like a wall
//! whose ends are not estimated.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Vector2};
use slam_core::{Coordinates, Error, Feature, Growth, Ink, Mark, Result, Shape, Sketch, Subspace};

use crate::Wall;

/// A PPCA line: the segment `mu -/+ sqrt(3 lambda) u` with the cluster's non-principal
/// variance `sigma^2` and its number of points.
///
/// ```
/// use slam_core::{Feature, nalgebra::Vector2};
/// use slam_features::PpcaLine;
/// let line = PpcaLine::from_cluster(Vector2::new(1.0, 2.0), Vector2::new(1.0, 0.0), 3.0, 1e-4, 120).unwrap();
/// assert_eq!(line.kind(), "ppca-line");
/// assert_eq!(line.mspace_dim(), 2);
/// assert!((line.end() - Vector2::new(4.0, 2.0)).norm() < 1e-12);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PpcaLineRepr", into = "PpcaLineRepr")]
pub struct PpcaLine {
    line: Wall,
    sigma2: f64,
    points: usize,
}

/// The serialized form, validated on the way in.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PpcaLineRepr {
    start: Vector2<f64>,
    end: Vector2<f64>,
    sigma2: f64,
    points: usize,
}

impl From<PpcaLine> for PpcaLineRepr {
    fn from(line: PpcaLine) -> Self {
        PpcaLineRepr {
            start: line.start(),
            end: line.end(),
            sigma2: line.sigma2,
            points: line.points,
        }
    }
}

impl TryFrom<PpcaLineRepr> for PpcaLine {
    type Error = Error;
    fn try_from(repr: PpcaLineRepr) -> Result<Self> {
        PpcaLine::new(repr.start, repr.end, repr.sigma2, repr.points)
    }
}

impl PpcaLine {
    /// A line from `start` to `end` with non-principal variance `sigma2` (m^2) summarizing
    /// `points` laser points.
    pub fn new(start: Vector2<f64>, end: Vector2<f64>, sigma2: f64, points: usize) -> Result<Self> {
        if !(sigma2.is_finite() && sigma2 >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "a PPCA line's sigma^2 must be finite and non-negative, got {sigma2}"
            )));
        }
        Ok(PpcaLine {
            line: Wall::new(start, end)?.with_subspaces(&["line"])?,
            sigma2,
            points,
        })
    }

    /// The line of a PPCA cluster with centre `mean`, principal direction `direction`,
    /// principal variance `principal_variance` and non-principal variance `sigma2`:
    /// the segment `mean -/+ sqrt(3 principal_variance) direction`.
    pub fn from_cluster(
        mean: Vector2<f64>,
        direction: Vector2<f64>,
        principal_variance: f64,
        sigma2: f64,
        points: usize,
    ) -> Result<Self> {
        let norm = direction.norm();
        if !(norm.is_finite() && norm > 0.0 && principal_variance.is_finite()) {
            return Err(Error::InvalidArgument(
                "a PPCA cluster needs a direction and a finite principal variance".into(),
            ));
        }
        let half = (3.0 * principal_variance.max(0.0)).sqrt();
        let u = direction / norm;
        Self::new(mean - u * half, mean + u * half, sigma2, points)
    }

    /// First end.
    pub fn start(&self) -> Vector2<f64> {
        self.line.start()
    }

    /// Second end.
    pub fn end(&self) -> Vector2<f64> {
        self.line.end()
    }

    /// The non-principal variance `sigma^2`, m^2.
    pub fn sigma2(&self) -> f64 {
        self.sigma2
    }

    /// Laser points the cluster summarizes.
    pub fn points(&self) -> usize {
        self.points
    }
}

#[typetag::serde(name = "ppca-line")]
impl Feature for PpcaLine {
    fn shape(&self) -> Option<Shape> {
        Some(Shape::Wall {
            start: self.start(),
            end: self.end(),
        })
    }

    fn sketch(&self) -> Sketch {
        Sketch::new("PPCA lines (IPSLAM clusters)", Ink::Wall).with(Mark::Segment {
            from: self.start(),
            to: self.end(),
            ink: Ink::Wall,
            width: 3,
        })
    }

    fn kind(&self) -> &'static str {
        "ppca-line"
    }

    fn coordinates(&self) -> &Coordinates {
        self.line.coordinates()
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        self.line.set_coordinates(coordinates)
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        self.line.active_subspaces()
    }

    /// A PPCA line's ends are not estimated: it never grows.
    fn growth_options(&self) -> Vec<Subspace> {
        Vec::new()
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        Err(Error::Growth {
            feature: "ppca-line",
            subspace: subspace.to_string(),
            reason: "a PPCA line has only its line subspace".into(),
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        self.line.projection()
    }

    fn dual(&self) -> Result<DMatrix<f64>> {
        self.line.dual()
    }
}
