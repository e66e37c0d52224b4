//! A doorway: a feature type defined outside `slam-features`, with its own measurement
//! model. It implements the slam-core traits and passes the conformance suite, and it runs
//! through [`slam_core::FeatureMap`] and [`slam_core::linearize`] with no change anywhere else.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Matrix2, Vector2};
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, Growth, Innovation, MeasurementModel, Pose3, Result,
    Subspace, ensure_finite, stack_rows,
};

/// Position of the doorway's centre.
pub const CENTRE: Subspace = Subspace {
    name: "centre",
    rows: 2,
    description: "position of the doorway's centre: revealed by seeing the opening",
};

/// Width and orientation of the doorway (the difference of the jambs).
pub const SHAPE: Subspace = Subspace {
    name: "shape",
    rows: 2,
    description: "width and orientation (right jamb minus left jamb): revealed by seeing both \
                  jambs at once",
};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum DoorSubspace {
    Centre,
    Shape,
}

impl DoorSubspace {
    fn spec(self) -> Subspace {
        match self {
            DoorSubspace::Centre => CENTRE,
            DoorSubspace::Shape => SHAPE,
        }
    }

    /// Rows of B: centre = (l + r) / 2, shape = r - l.
    fn rows(self) -> DMatrix<f64> {
        let (a, b) = match self {
            DoorSubspace::Centre => (0.5, 0.5),
            DoorSubspace::Shape => (-1.0, 1.0),
        };
        DMatrix::from_row_slice(2, 4, &[a, 0.0, b, 0.0, 0.0, a, 0.0, b])
    }

    /// Columns of B~ as rows: the centre moves both jambs; the shape moves them apart.
    fn dual_rows(self) -> DMatrix<f64> {
        let (a, b) = match self {
            DoorSubspace::Centre => (1.0, 1.0),
            DoorSubspace::Shape => (-0.5, 0.5),
        };
        DMatrix::from_row_slice(2, 4, &[a, 0.0, b, 0.0, 0.0, a, 0.0, b])
    }
}

/// A doorway between two jambs, each a vertical edge (a 2-D point): `x_f = {left, right}`.
///
/// M-space: 0, 2 (`"centre"`), 4 (`"centre"` + `"shape"`).
///
/// ```
/// use slam_examples::Door;
/// use slam_core::{Feature, nalgebra::Vector2};
/// let door = Door::new(Vector2::new(2.0, 0.45), Vector2::new(2.0, -0.45)).unwrap();
/// slam_core::testing::assert_feature_conforms(&door);
/// assert!((door.width() - 0.9).abs() < 1e-12);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "DoorRepr", into = "DoorRepr")]
pub struct Door {
    coordinates: Coordinates,
    active: Vec<DoorSubspace>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct DoorRepr {
    left: Vector2<f64>,
    right: Vector2<f64>,
    active: Vec<DoorSubspace>,
}

impl From<Door> for DoorRepr {
    fn from(door: Door) -> Self {
        DoorRepr {
            left: door.jamb(0),
            right: door.jamb(1),
            active: door.active,
        }
    }
}

impl TryFrom<DoorRepr> for Door {
    type Error = Error;
    fn try_from(repr: DoorRepr) -> Result<Self> {
        let mut door = Door::new(repr.left, repr.right)?;
        for s in repr.active {
            door.activate(s.spec().name)?;
        }
        Ok(door)
    }
}

impl Door {
    /// Narrowest doorway accepted, in metres.
    pub const MIN_WIDTH: f64 = 0.2;

    /// A tentative doorway between two jambs.
    pub fn new(left: Vector2<f64>, right: Vector2<f64>) -> Result<Self> {
        let coordinates =
            Coordinates::new(vec![CoordBlock::Point2(left), CoordBlock::Point2(right)])?;
        if (right - left).norm() < Self::MIN_WIDTH {
            return Err(Error::Degenerate(format!(
                "doorway narrower than {} m",
                Self::MIN_WIDTH
            )));
        }
        Ok(Door {
            coordinates,
            active: Vec::new(),
        })
    }

    /// Jamb 0 (left) or 1 (right).
    pub fn jamb(&self, index: usize) -> Vector2<f64> {
        match self.coordinates.blocks()[index] {
            CoordBlock::Point2(p) => p,
            _ => Vector2::from_element(f64::NAN),
        }
    }

    /// Distance between the jambs.
    pub fn width(&self) -> f64 {
        (self.jamb(1) - self.jamb(0)).norm()
    }

    /// Whether the shape (both jambs) is in the M-space.
    pub fn has_shape(&self) -> bool {
        self.active.contains(&DoorSubspace::Shape)
    }

    fn allowed_growth(&self) -> Option<DoorSubspace> {
        match self.active.as_slice() {
            [] => Some(DoorSubspace::Centre),
            [DoorSubspace::Centre] => Some(DoorSubspace::Shape),
            _ => None,
        }
    }
}

#[typetag::serde(name = "door")]
impl Feature for Door {
    fn kind(&self) -> &'static str {
        "door"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        let [CoordBlock::Point2(left), CoordBlock::Point2(right)] = coordinates.blocks() else {
            return Err(Error::InvalidArgument(
                "a door's coordinates are two 2-D jambs".into(),
            ));
        };
        *self = Door {
            active: std::mem::take(&mut self.active),
            ..Door::new(*left, *right)?
        };
        Ok(())
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        self.active.iter().map(|s| s.spec()).collect()
    }

    fn growth_options(&self) -> Vec<Subspace> {
        self.allowed_growth()
            .map(DoorSubspace::spec)
            .into_iter()
            .collect()
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        let wanted = self
            .allowed_growth()
            .filter(|s| s.spec().name == subspace)
            .ok_or_else(|| Error::Growth {
                feature: "door",
                subspace: subspace.to_string(),
                reason: "the centre comes first, then the shape".into(),
            })?;
        let before = self.mspace_dim();
        self.active.push(wanted);
        Ok(Growth {
            subspace: wanted.spec(),
            rows: before..before + 2,
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        stack_rows(4, &self.active, |s| Ok(s.rows()))
    }

    fn dual(&self) -> Result<DMatrix<f64>> {
        Ok(stack_rows(4, &self.active, |s| Ok(s.dual_rows()))?.transpose())
    }
}

/// Both jambs of a doorway seen by a 2-D laser: range and bearing of each, in the sensor frame.
///
/// The innovation is Cartesian (no angle wrapping): predicted minus measured jamb positions
/// once the door has its shape; before that, only the centre (the mean of the jambs).
#[derive(Clone, Debug, PartialEq)]
pub struct DoorObservation {
    /// `[range_left, bearing_left, range_right, bearing_right]`, metres and radians.
    pub v: [f64; 4],
    /// Standard deviation of each range, metres.
    pub sigma_range: f64,
    /// Standard deviation of each bearing, radians.
    pub sigma_bearing: f64,
}

impl DoorObservation {
    /// An observation; values and deviations must be finite and ranges positive.
    pub fn new(v: [f64; 4], sigma_range: f64, sigma_bearing: f64) -> Result<Self> {
        ensure_finite(&v, "door observation")?;
        if v[0] <= 0.0
            || v[2] <= 0.0
            || sigma_range.is_nan()
            || sigma_range <= 0.0
            || sigma_bearing.is_nan()
            || sigma_bearing <= 0.0
        {
            return Err(Error::InvalidArgument(
                "door observation needs positive ranges and deviations".into(),
            ));
        }
        Ok(DoorObservation {
            v,
            sigma_range,
            sigma_bearing,
        })
    }

    /// Measured jamb `i` in sensor Cartesian coordinates and its Jacobian w.r.t. (range, bearing).
    fn jamb(&self, i: usize) -> (Vector2<f64>, Matrix2<f64>) {
        let (r, b) = (self.v[2 * i], self.v[2 * i + 1]);
        let (s, c) = b.sin_cos();
        (
            Vector2::new(r * c, r * s),
            Matrix2::new(c, -r * s, s, r * c),
        )
    }
}

impl MeasurementModel for DoorObservation {
    type Feature = Door;

    fn innovation(&self, door: &Door, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point2(left), CoordBlock::Point2(right)] = x_o.blocks() else {
            return Err(Error::InvalidArgument(
                "a door's coordinates are two 2-D jambs".into(),
            ));
        };
        let (measured_left, d_left) = self.jamb(0);
        let (measured_right, d_right) = self.jamb(1);
        let mut d_eta_d_v = DMatrix::zeros(4, 4);
        d_eta_d_v.view_mut((0, 0), (2, 2)).copy_from(&(-d_left));
        d_eta_d_v.view_mut((2, 2), (2, 2)).copy_from(&(-d_right));
        let cov_v = DMatrix::from_diagonal(&DVector::from_vec(vec![
            self.sigma_range.powi(2),
            self.sigma_bearing.powi(2),
            self.sigma_range.powi(2),
            self.sigma_bearing.powi(2),
        ]));
        let full = Innovation {
            eta: DVector::from_vec(vec![
                left.x - measured_left.x,
                left.y - measured_left.y,
                right.x - measured_right.x,
                right.y - measured_right.y,
            ]),
            d_eta_d_xo: DMatrix::identity(4, 4),
            d_eta_d_v,
            cov_v,
        };
        if door.has_shape() {
            return Ok(full);
        }
        // Centre only: the mean of the jamb rows.
        let mean = DMatrix::from_row_slice(2, 4, &[0.5, 0.0, 0.5, 0.0, 0.0, 0.5, 0.0, 0.5]);
        Ok(Innovation {
            eta: &mean * full.eta,
            d_eta_d_xo: mean.clone(),
            d_eta_d_v: mean * full.d_eta_d_v,
            cov_v: full.cov_v,
        })
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_column_slice(&self.v)
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        let values: [f64; 4] = v
            .as_slice()
            .try_into()
            .map_err(|_| Error::DimensionMismatch {
                what: "door observation".into(),
                expected: 4,
                got: v.len(),
            })?;
        DoorObservation::new(values, self.sigma_range, self.sigma_bearing)
    }

    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Door>> {
        // Inverse of eq. 34: a scan-plane point (u, v) lies on the vertical line at
        // M (u, v) + t, M the top-left 2x2 block of the sensor's rotation.
        let plane = world_from_sensor
            .rotation()
            .fixed_view::<2, 2>(0, 0)
            .into_owned();
        let t = world_from_sensor.translation.xy();
        let left = plane * self.jamb(0).0 + t;
        let right = plane * self.jamb(1).0 + t;
        Door::new(left, right).map(Some)
    }

    fn revealed_subspaces(&self, door: &Door, _x_o: &Coordinates) -> Vec<&'static str> {
        door.allowed_growth()
            .map(|s| s.spec().name)
            .into_iter()
            .collect()
    }
}
