//! The naive wall representation the M-space paper argues against (its Fig. 1): both
//! endpoints in the state from the first confirmation (`B = I`, dimension 4), with a large
//! variance along the wall where no real end has been seen. It is defined here, outside
//! `slam-features`, and runs through the EKF by configuration
//! (`[frontend] wall_representation = "endpoints"`), so that the two representations can be
//! compared on the same runs.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Vector2};
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, Growth, Ink, Innovation, Mark, MeasurementModel,
    Pose3, Result, Shape, Sketch, Subspace,
};
use slam_features::Wall;
use slam_sensors::models::WallObservation;

/// Both endpoints, in x and y.
pub const ENDPOINTS: Subspace = Subspace {
    name: "endpoints",
    rows: 4,
    description: "both endpoints in x and y (B = I): the naive representation, with a large \
                  variance along the wall where no real end was seen",
};

/// A wall as two plain endpoints: `x_f = {start, end}`, free side on the left of
/// `start -> end` as for [`Wall`]. M-space dimension 0, then 4 with `B = B~ = I`.
///
/// ```
/// use slam_core::{Feature, nalgebra::Vector2};
/// use slam_examples::EndpointWall;
/// let wall = EndpointWall::new(Vector2::new(0.0, 0.0), Vector2::new(3.0, 0.0), 1.0).unwrap();
/// slam_core::testing::assert_feature_conforms(&wall);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "EndpointWallRepr", into = "EndpointWallRepr")]
pub struct EndpointWall {
    coordinates: Coordinates,
    active: bool,
    /// Prior standard deviation of an endpoint along the wall, m.
    sigma_along: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct EndpointWallRepr {
    start: Vector2<f64>,
    end: Vector2<f64>,
    active: bool,
    sigma_along: f64,
}

impl From<EndpointWall> for EndpointWallRepr {
    fn from(wall: EndpointWall) -> Self {
        EndpointWallRepr {
            start: wall.point(0),
            end: wall.point(1),
            active: wall.active,
            sigma_along: wall.sigma_along,
        }
    }
}

impl TryFrom<EndpointWallRepr> for EndpointWall {
    type Error = Error;
    fn try_from(repr: EndpointWallRepr) -> Result<Self> {
        let mut wall = EndpointWall::new(repr.start, repr.end, repr.sigma_along)?;
        wall.active = repr.active;
        Ok(wall)
    }
}

impl EndpointWall {
    /// A tentative wall from `start` to `end` (at least [`Wall::MIN_LENGTH`] long) whose
    /// endpoints, once in the state, start with deviation `sigma_along` (m).
    pub fn new(start: Vector2<f64>, end: Vector2<f64>, sigma_along: f64) -> Result<Self> {
        Wall::new(start, end)?;
        if !(sigma_along.is_finite() && sigma_along > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "endpoint deviation along the wall must be positive, got {sigma_along}"
            )));
        }
        Ok(EndpointWall {
            coordinates: Coordinates::new(vec![
                CoordBlock::Point2(start),
                CoordBlock::Point2(end),
            ])?,
            active: false,
            sigma_along,
        })
    }

    fn point(&self, k: usize) -> Vector2<f64> {
        match self.coordinates.blocks()[k] {
            CoordBlock::Point2(p) => p,
            // The constructor and set_coordinates only admit two Point2 blocks.
            _ => Vector2::new(f64::NAN, f64::NAN),
        }
    }

    /// The start point.
    pub fn start(&self) -> Vector2<f64> {
        self.point(0)
    }

    /// The end point.
    pub fn end(&self) -> Vector2<f64> {
        self.point(1)
    }

    /// The same segment as an M-space [`Wall`] with the given subspaces (to reuse its
    /// measurement model's geometry).
    fn as_wall(&self, subspaces: &[&str]) -> Result<Wall> {
        Wall::new(self.start(), self.end())?.with_subspaces(subspaces)
    }
}

#[typetag::serde(name = "endpoint-wall")]
impl Feature for EndpointWall {
    fn shape(&self) -> Option<Shape> {
        Some(Shape::Wall {
            start: self.start(),
            end: self.end(),
        })
    }

    /// The segment with the 95 % ellipses of both ends (both are in the state).
    fn sketch(&self) -> Sketch {
        let ellipse = |offset, at| Mark::Ellipse {
            offset,
            at,
            ink: Ink::Corner,
        };
        Sketch::new("endpoint walls", Ink::Wall)
            .with(Mark::Segment {
                from: self.start(),
                to: self.end(),
                ink: Ink::Wall,
                width: 4,
            })
            .with(ellipse(0, self.start()))
            .with(ellipse(2, self.end()))
    }

    fn kind(&self) -> &'static str {
        "endpoint-wall"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        let [CoordBlock::Point2(a), CoordBlock::Point2(b)] = coordinates.blocks() else {
            return Err(Error::InvalidArgument(
                "an endpoint wall is two 2-D points".into(),
            ));
        };
        Wall::new(*a, *b)?;
        self.coordinates = coordinates;
        Ok(())
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        if self.active {
            vec![ENDPOINTS]
        } else {
            Vec::new()
        }
    }

    fn growth_options(&self) -> Vec<Subspace> {
        if self.active {
            Vec::new()
        } else {
            vec![ENDPOINTS]
        }
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        if self.active || subspace != ENDPOINTS.name {
            return Err(Error::Growth {
                feature: "endpoint-wall",
                subspace: subspace.into(),
                reason: "only `endpoints`, once".into(),
            });
        }
        self.active = true;
        Ok(Growth {
            subspace: ENDPOINTS,
            rows: 0..4,
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        Ok(DMatrix::identity(self.mspace_dim(), 4))
    }

    fn dual(&self) -> Result<DMatrix<f64>> {
        Ok(DMatrix::identity(4, self.mspace_dim()))
    }

    /// `sigma_along^2 I`: the "large uncertainty along the wall" of the naive representation;
    /// the observation that confirms the wall then fixes the normal directions.
    fn growth_prior(&self, growth: &Growth) -> Option<DMatrix<f64>> {
        let n = growth.rows.len();
        Some(DMatrix::identity(n, n) * self.sigma_along.powi(2))
    }
}

/// A laser wall segment as a measurement of an [`EndpointWall`]: the line rows of
/// [`WallObservation`], a tangential row for each real end, and for an end that is not real
/// but reaches beyond the wall's endpoint, a tangential row with deviation `sigma_along`
/// (the endpoint is pulled outwards, loosely).
#[derive(Clone, Debug, PartialEq)]
pub struct EndpointWallObservation {
    /// The underlying segment observation.
    pub segment: WallObservation,
    /// Deviation of an end that is not real, along the wall, m.
    pub sigma_along: f64,
}

/// `wall_representation = "endpoints"` in the `features` front-end: every extracted segment
/// as an [`EndpointWallObservation`], the endpoints' deviation along the wall
/// `sigma_along_wall` (m) where no real end was seen. Registered by name through `typetag`,
/// the way any crate adds a wall representation; the `slam` command links this crate.
///
/// ```toml
/// [frontend.wall_representation]
/// type = "endpoints"
/// sigma_along_wall = 1.0
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EndpointWalls {
    /// Standard deviation along the wall of an endpoint not seen as a real end, m.
    pub sigma_along_wall: f64,
}

impl Default for EndpointWalls {
    fn default() -> Self {
        EndpointWalls {
            sigma_along_wall: 1.0,
        }
    }
}

#[typetag::serde(name = "endpoints")]
impl slam_runtime::frontend::WallModel for EndpointWalls {
    fn validate(&self) -> Result<()> {
        if self.sigma_along_wall.is_finite() && self.sigma_along_wall > 0.0 {
            Ok(())
        } else {
            Err(Error::InvalidArgument(format!(
                "sigma_along_wall must be positive, got {}",
                self.sigma_along_wall
            )))
        }
    }

    fn observation(
        &self,
        segment: &slam_sensors::extract::ExtractedSegment,
        sigma_range: f64,
    ) -> Result<Box<dyn slam_core::DynMeasurementModel>> {
        let observation = segment.to_observation(sigma_range)?;
        Ok(Box::new(EndpointWallObservation::new(
            observation,
            self.sigma_along_wall,
        )?))
    }
}

impl EndpointWallObservation {
    /// The naive observation of a segment.
    pub fn new(segment: WallObservation, sigma_along: f64) -> Result<Self> {
        if !(sigma_along.is_finite() && sigma_along > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "sigma_along must be positive, got {sigma_along}"
            )));
        }
        Ok(EndpointWallObservation {
            segment,
            sigma_along,
        })
    }

    /// Which measured endpoints are tangential measurements: `(wall end, measured index,
    /// deviation)`; the wall end is 0 (start) or 1 (end).
    fn tangential_rows(&self, x_o: &Coordinates) -> Vec<(usize, usize, f64)> {
        let [CoordBlock::Point2(s), CoordBlock::Point2(e)] = x_o.blocks() else {
            return Vec::new();
        };
        let t = (e - s).normalize();
        let q = self.segment.endpoints;
        let (to_start, to_end) = if t.dot(&q[0]) <= t.dot(&q[1]) {
            (0, 1)
        } else {
            (1, 0)
        };
        let mut rows = Vec::new();
        if self.segment.real[to_start] {
            rows.push((0, to_start, self.segment.sigma_endpoints[to_start]));
        } else if t.dot(&(q[to_start] - s)) < 0.0 {
            rows.push((0, to_start, self.sigma_along));
        }
        if self.segment.real[to_end] {
            rows.push((1, to_end, self.segment.sigma_endpoints[to_end]));
        } else if t.dot(&(q[to_end] - e)) > 0.0 {
            rows.push((1, to_end, self.sigma_along));
        }
        rows
    }
}

impl MeasurementModel for EndpointWallObservation {
    type Feature = EndpointWall;

    fn innovation(&self, wall: &EndpointWall, x_o: &Coordinates) -> Result<Innovation> {
        let line_wall = wall.as_wall(&["line"])?;
        let line_only = WallObservation {
            real: [false, false],
            ..self.segment.clone()
        };
        let line = line_only.innovation(&line_wall, x_o)?;
        if !wall.active {
            return Ok(line);
        }
        let rows = self.tangential_rows(x_o);
        let mut marked = self.segment.clone();
        marked.real = [false, false];
        for &(_, measured, _) in &rows {
            marked.real[measured] = true;
        }
        let full_wall = wall.as_wall(&["line", "start", "end"])?;
        let mut innovation = marked.innovation(&full_wall, x_o)?;
        for &(_, measured, sigma) in &rows {
            for k in [2 + 2 * measured, 3 + 2 * measured] {
                innovation.cov_v[(k, k)] = sigma * sigma;
            }
        }
        Ok(innovation)
    }

    fn measurement(&self) -> DVector<f64> {
        self.segment.measurement()
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        Ok(EndpointWallObservation {
            segment: self.segment.with_measurement(v)?,
            sigma_along: self.sigma_along,
        })
    }

    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<EndpointWall>> {
        let Some(wall) = self.segment.initial_feature(world_from_sensor)? else {
            return Ok(None);
        };
        EndpointWall::new(wall.start(), wall.end(), self.sigma_along).map(Some)
    }

    fn revealed_subspaces(&self, wall: &EndpointWall, _x_o: &Coordinates) -> Vec<&'static str> {
        wall.growth_options().iter().map(|s| s.name).collect()
    }

    /// As for an M-space wall whose ends are not estimated: the segment overlaps the wall or
    /// lies close to an end.
    fn plausible(&self, wall: &EndpointWall, x_o: &Coordinates) -> bool {
        wall.as_wall(&["line"])
            .is_ok_and(|line_wall| self.segment.plausible(&line_wall, x_o))
    }
}
