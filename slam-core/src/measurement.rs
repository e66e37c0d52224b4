//! Measurement models (paper section V-A): the innovation `eta(x_o, v)` with `J_eta_v` and
//! `J_eta_o`, and the generic chain that turns them into the Jacobian with respect to the
//! estimator's state, `J_eta,state = J_eta_o (J_or | J_of B~)` (eqs. 21 and 30).

use std::fmt::Debug;

use nalgebra::allocator::Allocator;
use nalgebra::{
    DMatrix, DVector, DefaultAllocator, Dim, Matrix, OMatrix, RawStorage, RawStorageMut,
};

use crate::coords::Coordinates;
use crate::error::{Error, Result};
use crate::feature::{Feature, downcast_feature};
use crate::pose::{Pose3, RobotPose, SensorPose};
use crate::transform::MapToSensor;

/// The innovation of one measurement of one feature and its Jacobians (eq. 16).
///
/// `eta` has expected value zero when the feature and pose are right.
#[derive(Clone, Debug, PartialEq)]
pub struct Innovation {
    /// `eta(x_o, v)`, length `m`.
    pub eta: DVector<f64>,
    /// `J_eta_o = d eta / d x_o`, `m x dim(x_f)`.
    pub d_eta_d_xo: DMatrix<f64>,
    /// `J_eta_v = d eta / d v`, `m x dim(v)`.
    pub d_eta_d_v: DMatrix<f64>,
    /// `C_v`, the covariance of the measurement `v`, `dim(v) x dim(v)`.
    pub cov_v: DMatrix<f64>,
}

impl Innovation {
    /// Number of innovation rows `m`.
    pub fn dim(&self) -> usize {
        self.eta.len()
    }

    /// `C_eta = J_eta_v C_v J_eta_v^T`, the innovation's own covariance (the `C_eta` of eq. 29).
    pub fn covariance(&self) -> DMatrix<f64> {
        &self.d_eta_d_v * &self.cov_v * self.d_eta_d_v.transpose()
    }

    /// Checks shapes against `dim(x_f)` and that every value is finite.
    pub fn validate(&self, dim_f: usize) -> Result<()> {
        let m = self.eta.len();
        let checks = [
            ("J_eta_o rows", m, self.d_eta_d_xo.nrows()),
            ("J_eta_o columns (dim x_f)", dim_f, self.d_eta_d_xo.ncols()),
            ("J_eta_v rows", m, self.d_eta_d_v.nrows()),
            (
                "C_v rows (dim v)",
                self.d_eta_d_v.ncols(),
                self.cov_v.nrows(),
            ),
            (
                "C_v columns (dim v)",
                self.d_eta_d_v.ncols(),
                self.cov_v.ncols(),
            ),
        ];
        for (what, expected, got) in checks {
            if expected != got {
                return Err(Error::DimensionMismatch {
                    what: what.into(),
                    expected,
                    got,
                });
            }
        }
        let all = [
            self.eta.as_slice(),
            self.d_eta_d_xo.as_slice(),
            self.d_eta_d_v.as_slice(),
            self.cov_v.as_slice(),
        ];
        if all_finite(&all) {
            Ok(())
        } else {
            Err(Error::NonFinite("innovation".into()))
        }
    }
}

/// Whether every value of every slice is finite (a plain loop: a chain of iterators over
/// matrices cost hundreds of instructions per innovation).
///
/// ```
/// assert!(slam_core::all_finite(&[&[1.0, 2.0], &[]]));
/// assert!(!slam_core::all_finite(&[&[1.0], &[f64::NAN]]));
/// ```
pub fn all_finite(slices: &[&[f64]]) -> bool {
    slices
        .iter()
        .all(|values| values.iter().all(|v| v.is_finite()))
}

/// A measurement `v` of one feature type together with the model that explains it.
///
/// Only `eta`, its Jacobians and the feature's `B` depend on the feature type (paper
/// section V-A); everything else is generic ([`linearize`]). Implement this typed trait; the
/// estimator stores measurements as `Arc<dyn DynMeasurementModel>` through the blanket
/// implementation, which checks the feature type. Run
/// [`crate::testing::assert_measurement_conforms`] on every implementation.
pub trait MeasurementModel: Clone + Debug + Send + Sync + 'static {
    /// The feature type this measurement observes.
    type Feature: Feature;

    /// `eta(x_o, v)` with `J_eta_o`, `J_eta_v` and `C_v` for the feature's coordinates `x_o` in
    /// the sensor frame. Only the directions in the feature's current M-space may be used
    /// (e.g. a wall's endpoint rows only once the endpoint is in its M-space).
    fn innovation(&self, feature: &Self::Feature, x_o: &Coordinates) -> Result<Innovation>;

    /// The measured values `v` as a vector.
    fn measurement(&self) -> DVector<f64>;

    /// The same measurement with values `v` (used to check `J_eta_v` by central differences).
    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self>
    where
        Self: Sized;

    /// A new, tentative feature (M-space dimension 0) in the map frame from this measurement
    /// alone, when one measurement suffices to place it; `None` otherwise.
    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Self::Feature>> {
        let _ = world_from_sensor;
        Ok(None)
    }

    /// Names of inactive subspaces of `feature` that this measurement observes directly
    /// (e.g. a real wall endpoint reveals `"start"`), for the estimator's lifecycle rules.
    /// `x_o` is the feature in the sensor frame, as for [`innovation`](Self::innovation).
    fn revealed_subspaces(&self, feature: &Self::Feature, x_o: &Coordinates) -> Vec<&'static str> {
        let _ = (feature, x_o);
        Vec::new()
    }

    /// Whether this measurement can be of `feature` at all, beyond what the innovation says
    /// (e.g. a wall segment must overlap the wall's extent, or lie close to it). Data
    /// association never pairs a measurement with a feature for which this is false. `x_o` is
    /// the feature in the sensor frame. Default: true.
    fn plausible(&self, feature: &Self::Feature, x_o: &Coordinates) -> bool {
        let _ = (feature, x_o);
        true
    }

    /// New map-frame coordinates for `feature` that agree with this measurement in
    /// directions **outside** the feature's M-space, or `None` to leave it as it is: a wall's
    /// extent grows to cover the measured segment where its endpoint is not estimated
    /// (section IV: such directions are not part of the estimate). An estimator applies it
    /// through [`crate::FeatureMap::set_coordinates_outside_mspace`], which checks that
    /// `B (x_new - x_old)` vanishes and gives the map of the M-space rows onto the new
    /// coordinates (see [`Extension`]).
    fn extend(
        &self,
        feature: &Self::Feature,
        world_from_sensor: &Pose3,
    ) -> Result<Option<Extension>> {
        let _ = (feature, world_from_sensor);
        Ok(None)
    }

    /// Whether [`triangulate`](Self::triangulate) can ever place a feature: an estimator
    /// keeps views of growing features only for measurements that triangulate. Default: false.
    fn triangulates(&self) -> bool {
        false
    }

    /// A feature placed by several measurements of it taken from different sensor poses
    /// (`world_from_sensor`, measurement), for features that one measurement cannot place
    /// (bearing-only lamps, ceiling lines), with the subspaces the views reveal together.
    /// `Ok(None)` while the views do not triangulate it well (too little parallax).
    fn triangulate(views: &[(Pose3, &Self)]) -> Result<Option<Triangulation<Self::Feature>>>
    where
        Self: Sized,
    {
        let _ = views;
        Ok(None)
    }

    /// [`linearize_own_at`] written out for this model, for speed: FastSLAM's landmark
    /// filters call it for every particle, observation and candidate. It writes into `out`,
    /// reusing its storage as [`MeasurementModel::linearize_at`] does. `None` (the default)
    /// takes the generic chain. An override must write the chain's numbers bit for bit
    /// whatever `out` held ([`chain_product`] and [`chain_covariance`] are the chain's own
    /// products, for any matrix sizes); [`crate::testing::assert_measurement_conforms`]
    /// checks it.
    fn linearize_own(
        &self,
        feature: &Self::Feature,
        to_sensor: &MapToSensor,
        out: &mut OwnLinearization,
    ) -> Option<Result<()>> {
        let _ = (feature, to_sensor, out);
        None
    }

    /// [`linearize_at`] written out for this model, for speed (FastSLAM 2.0's proposal and
    /// the EKF call it for every pairing), into `out`, reusing its matrices' storage where
    /// their shapes allow ([`reshape_zeroed`], [`chain_product_into`]): a filter that keeps
    /// one `out` linearizes without allocating. `None` (the default) takes the generic chain
    /// ([`chain_linearize_at`]); an override must write the chain's numbers bit for bit
    /// whatever `out` held before, which [`crate::testing::assert_measurement_conforms`]
    /// checks. On an error `out` holds no meaningful numbers.
    fn linearize_at(
        &self,
        feature: &Self::Feature,
        frame: &SensorFrame,
        out: &mut LinearizedMeasurement,
    ) -> Option<Result<()>> {
        let _ = (feature, frame, out);
        None
    }
}

/// A change of a feature's coordinates outside its M-space ([`MeasurementModel::extend`]).
///
/// Moving coordinates along unobserved directions changes what the M-space rows mean: a
/// wall's rows are its rotation and the normal offset **of its centre**, and extending the
/// wall moves the centre, so the offset at the new centre is less certain than at the old
/// one when the rotation is uncertain. `d_new_d_old` says how a small change of the old
/// coordinates carries over to the new ones (a wall end moved a fixed distance along the
/// wall turns with the wall); the estimator maps its rows by
/// `T = B(x_new) d_new_d_old B~(x_old)` (see [`crate::FeatureMap::set_coordinates_outside_mspace`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Extension {
    /// The new coordinates.
    pub coordinates: Coordinates,
    /// `d x_new / d x_old` (`dim(x_f)` square).
    pub d_new_d_old: DMatrix<f64>,
}

/// A feature placed by triangulation, with the subspaces its views reveal.
#[derive(Clone, Debug, PartialEq)]
pub struct Triangulation<F> {
    /// The feature, at M-space dimension 0, in the map frame.
    pub feature: F,
    /// The subspaces the views observe together, in activation order.
    pub reveals: Vec<&'static str>,
}

/// The object-safe form of [`MeasurementModel`], implemented for every model.
pub trait DynMeasurementModel: Debug + Send + Sync {
    /// Rust type name of the feature type the model observes (for messages).
    fn feature_type_name(&self) -> &'static str;

    /// Whether `feature` is of the type this model observes.
    fn accepts(&self, feature: &dyn Feature) -> bool;

    /// [`MeasurementModel::innovation`], after checking the feature type and the result's shapes.
    fn innovation_dyn(&self, feature: &dyn Feature, x_o: &Coordinates) -> Result<Innovation>;

    /// [`MeasurementModel::measurement`].
    fn measurement_dyn(&self) -> DVector<f64>;

    /// [`MeasurementModel::initial_feature`], boxed.
    fn initial_feature_dyn(&self, world_from_sensor: &Pose3) -> Result<Option<Box<dyn Feature>>>;

    /// [`MeasurementModel::revealed_subspaces`], after checking the feature type.
    fn revealed_subspaces_dyn(
        &self,
        feature: &dyn Feature,
        x_o: &Coordinates,
    ) -> Result<Vec<&'static str>>;

    /// [`MeasurementModel::triangulate`] of this measurement (taken at `world_from_sensor`)
    /// together with `others`, which must be measurements of the same type.
    fn triangulate_dyn(
        &self,
        world_from_sensor: &Pose3,
        others: &[(Pose3, &dyn DynMeasurementModel)],
    ) -> Result<Option<Triangulation<Box<dyn Feature>>>>;

    /// [`MeasurementModel::plausible`], false for a feature of another type.
    fn plausible_dyn(&self, feature: &dyn Feature, x_o: &Coordinates) -> bool;

    /// [`MeasurementModel::extend`], after checking the feature type.
    fn extend_dyn(
        &self,
        feature: &dyn Feature,
        world_from_sensor: &Pose3,
    ) -> Result<Option<Extension>>;

    /// A boxed copy (an estimator keeps the views of a feature it triangulates).
    fn clone_box(&self) -> Box<dyn DynMeasurementModel>;

    /// [`MeasurementModel::triangulates`].
    fn triangulates_dyn(&self) -> bool;

    /// The measurement as `Any`, to recover its concrete type.
    fn as_any(&self) -> &dyn std::any::Any;

    /// [`MeasurementModel::linearize_own`]; `None` also when the feature is of another type
    /// (the generic chain then reports it).
    fn linearize_own_dyn(
        &self,
        feature: &dyn Feature,
        to_sensor: &MapToSensor,
        out: &mut OwnLinearization,
    ) -> Option<Result<()>> {
        let _ = (feature, to_sensor, out);
        None
    }

    /// [`MeasurementModel::linearize_at`]; `None` also when the feature is of another type.
    fn linearize_at_dyn(
        &self,
        feature: &dyn Feature,
        frame: &SensorFrame,
        out: &mut LinearizedMeasurement,
    ) -> Option<Result<()>> {
        let _ = (feature, frame, out);
        None
    }
}

impl<M: MeasurementModel> DynMeasurementModel for M {
    fn feature_type_name(&self) -> &'static str {
        std::any::type_name::<M::Feature>()
    }

    fn accepts(&self, feature: &dyn Feature) -> bool {
        downcast_feature::<M::Feature>(feature).is_some()
    }

    fn innovation_dyn(&self, feature: &dyn Feature, x_o: &Coordinates) -> Result<Innovation> {
        let typed = typed_feature::<M>(feature)?;
        let innovation = self.innovation(typed, x_o)?;
        innovation.validate(feature.coordinates().dim())?;
        Ok(innovation)
    }

    fn measurement_dyn(&self) -> DVector<f64> {
        self.measurement()
    }

    fn initial_feature_dyn(&self, world_from_sensor: &Pose3) -> Result<Option<Box<dyn Feature>>> {
        Ok(self
            .initial_feature(world_from_sensor)?
            .map(|f| Box::new(f) as Box<dyn Feature>))
    }

    fn revealed_subspaces_dyn(
        &self,
        feature: &dyn Feature,
        x_o: &Coordinates,
    ) -> Result<Vec<&'static str>> {
        Ok(self.revealed_subspaces(typed_feature::<M>(feature)?, x_o))
    }

    fn triangulate_dyn(
        &self,
        world_from_sensor: &Pose3,
        others: &[(Pose3, &dyn DynMeasurementModel)],
    ) -> Result<Option<Triangulation<Box<dyn Feature>>>> {
        let mut views = vec![(*world_from_sensor, self)];
        for (pose, other) in others {
            let typed = other.as_any().downcast_ref::<M>().ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "cannot triangulate a {} with a measurement of another type",
                    std::any::type_name::<M>()
                ))
            })?;
            views.push((*pose, typed));
        }
        Ok(M::triangulate(&views)?.map(|t| Triangulation {
            feature: Box::new(t.feature) as Box<dyn Feature>,
            reveals: t.reveals,
        }))
    }

    fn plausible_dyn(&self, feature: &dyn Feature, x_o: &Coordinates) -> bool {
        downcast_feature::<M::Feature>(feature).is_some_and(|typed| self.plausible(typed, x_o))
    }

    fn extend_dyn(
        &self,
        feature: &dyn Feature,
        world_from_sensor: &Pose3,
    ) -> Result<Option<Extension>> {
        self.extend(typed_feature::<M>(feature)?, world_from_sensor)
    }

    fn clone_box(&self) -> Box<dyn DynMeasurementModel> {
        Box::new(self.clone())
    }

    fn triangulates_dyn(&self) -> bool {
        self.triangulates()
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn linearize_own_dyn(
        &self,
        feature: &dyn Feature,
        to_sensor: &MapToSensor,
        out: &mut OwnLinearization,
    ) -> Option<Result<()>> {
        self.linearize_own(downcast_feature::<M::Feature>(feature)?, to_sensor, out)
    }

    fn linearize_at_dyn(
        &self,
        feature: &dyn Feature,
        frame: &SensorFrame,
        out: &mut LinearizedMeasurement,
    ) -> Option<Result<()>> {
        MeasurementModel::linearize_at(self, downcast_feature::<M::Feature>(feature)?, frame, out)
    }
}

fn typed_feature<M: MeasurementModel>(feature: &dyn Feature) -> Result<&M::Feature> {
    downcast_feature::<M::Feature>(feature).ok_or(Error::FeatureTypeMismatch {
        expected: std::any::type_name::<M::Feature>(),
        got: feature.kind(),
    })
}

/// A measurement linearized around the current estimate: eq. 16 with the chain of eq. 21,
/// giving every block of `J_eta,state` (eq. 30). The default holds empty matrices (a buffer
/// for [`linearize_at_into`]).
#[derive(Clone, Debug, PartialEq)]
pub struct LinearizedMeasurement {
    /// `eta` at the current estimate.
    pub eta: DVector<f64>,
    /// `C_eta = J_eta_v C_v J_eta_v^T`.
    pub cov_eta: DMatrix<f64>,
    /// `J_eta_o J_os J_sr`: with respect to the robot pose parameters (`m x P::DIM`).
    pub d_eta_d_robot: DMatrix<f64>,
    /// `J_eta_o J_os`: with respect to the sensor pose `(x, y, z, yaw, pitch, roll)` in the
    /// world; [`LinearizedMeasurement::d_eta_d_sensor_offset`] gives the sensor offset's
    /// columns from it (no estimator needs them at every step).
    pub d_eta_d_sensor: DMatrix<f64>,
    /// `J_eta_o J_of B~`: with respect to the feature's own M-space perturbation.
    pub d_eta_d_own: DMatrix<f64>,
    /// `J_eta_o J_of E_k` for each shared block `k` (block index, `m x dim(block)`): the shared
    /// block's rows are the identity on its coordinates (section VI).
    pub d_eta_d_shared: Vec<(usize, DMatrix<f64>)>,
    /// `J_eta_f = J_eta_o J_of`: with respect to all feature coordinates (what the measurement
    /// would observe of directions not yet in the M-space).
    pub d_eta_d_xf: DMatrix<f64>,
}

impl LinearizedMeasurement {
    /// Writes what a model's own linearization (on stack matrices) has besides its own
    /// columns, for a feature without shared blocks, reusing this buffer's storage: `eta`,
    /// `C_eta` (from [`chain_covariance`]), the sensor columns `J_eta_o J_os`, the robot
    /// columns `J_eta_o J_os J_sr` (the chain's product with `frame`'s `J_sr`) and
    /// `J_eta_f`. The caller writes `d_eta_d_own` (its `B~`).
    ///
    /// ```
    /// use slam_core::{LinearizedMeasurement, Pose2, Pose3, SensorFrame};
    /// use slam_core::nalgebra::{Matrix1x6, Matrix1x3, Matrix1};
    /// let frame = SensorFrame::new(&Pose2::new(1.0, 0.0, 0.3), &Pose3::identity()).unwrap();
    /// let mut out = LinearizedMeasurement::default();
    /// let d_eta_d_sensor = Matrix1x6::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    /// out.write_unshared(&[0.1], &Matrix1::new(0.01), &d_eta_d_sensor, &frame, &Matrix1x3::new(-1.0, 0.0, 0.0));
    /// assert_eq!(out.d_eta_d_robot.ncols(), 3);
    /// assert!(out.d_eta_d_shared.is_empty());
    /// ```
    pub fn write_unshared<RC, CC, SC, RS, CS, SS, RX, CX, SX>(
        &mut self,
        eta: &[f64],
        cov_eta: &Matrix<f64, RC, CC, SC>,
        d_eta_d_sensor: &Matrix<f64, RS, CS, SS>,
        frame: &SensorFrame,
        d_eta_d_xf: &Matrix<f64, RX, CX, SX>,
    ) where
        RC: Dim,
        CC: Dim,
        SC: RawStorage<f64, RC, CC>,
        RS: Dim,
        CS: Dim,
        SS: RawStorage<f64, RS, CS>,
        RX: Dim,
        CX: Dim,
        SX: RawStorage<f64, RX, CX>,
    {
        assign_vector(&mut self.eta, eta);
        assign_matrix(&mut self.cov_eta, cov_eta);
        chain_product_into(
            d_eta_d_sensor,
            &frame.pose.d_sensor_d_robot,
            &mut self.d_eta_d_robot,
        );
        assign_matrix(&mut self.d_eta_d_sensor, d_eta_d_sensor);
        self.d_eta_d_shared.clear();
        assign_matrix(&mut self.d_eta_d_xf, d_eta_d_xf);
    }
}

impl Default for LinearizedMeasurement {
    fn default() -> Self {
        LinearizedMeasurement {
            eta: DVector::zeros(0),
            cov_eta: DMatrix::zeros(0, 0),
            d_eta_d_robot: DMatrix::zeros(0, 0),
            d_eta_d_sensor: DMatrix::zeros(0, 0),
            d_eta_d_own: DMatrix::zeros(0, 0),
            d_eta_d_shared: Vec::new(),
            d_eta_d_xf: DMatrix::zeros(0, 0),
        }
    }
}

/// A sensor's frame at one robot pose: where the sensor is in the world (eq. 17) with `J_sr`
/// and `J_ss` (eq. 20), and the map-to-sensor transform (eqs. 7-9). It is the same for every
/// observation that sensor makes at that pose: an estimator makes it once per step and mount
/// and linearizes each observation with [`linearize_at`].
///
/// ```
/// use slam_core::{Pose2, Pose3, RobotPose, SensorFrame};
/// let robot = Pose2::new(1.0, 2.0, 0.5);
/// let frame = SensorFrame::new(&robot, &Pose3::identity()).unwrap();
/// assert_eq!(*frame.world_from_sensor(), robot.world_from_sensor(&Pose3::identity()));
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct SensorFrame {
    /// The sensor pose and its Jacobians.
    pub pose: SensorPose,
    /// The transform of map coordinates into the sensor frame.
    pub to_sensor: MapToSensor,
}

impl SensorFrame {
    /// The frame of a sensor at `robot_from_sensor` on a robot at `world_from_robot`; fails
    /// where [`RobotPose::sensor_pose`] or [`MapToSensor::new`] fails (gimbal lock, a pose
    /// that is not finite).
    pub fn new<P: RobotPose>(world_from_robot: &P, robot_from_sensor: &Pose3) -> Result<Self> {
        let pose = world_from_robot.sensor_pose(robot_from_sensor)?;
        let to_sensor = MapToSensor::new(&pose.world_from_sensor)?;
        Ok(SensorFrame { pose, to_sensor })
    }

    /// `world_from_sensor` (eq. 17).
    pub fn world_from_sensor(&self) -> &Pose3 {
        &self.pose.world_from_sensor
    }
}

/// Linearizes `measurement` of `feature` seen by a sensor at `robot_from_sensor` on a robot at
/// `world_from_robot`: eqs. 16-21 and 30, written once for every feature and estimator.
/// The same as [`linearize_at`] with the [`SensorFrame`] made for this one call.
///
/// ```
/// use slam_core::{linearize, Pose2, Pose3};
/// # fn demo(measurement: &dyn slam_core::DynMeasurementModel, feature: &dyn slam_core::Feature) -> slam_core::Result<()> {
/// let lin = linearize(measurement, feature, &Pose2::new(1.0, 0.0, 0.3), &Pose3::identity())?;
/// // The EKF's J_eta,state places d_eta_d_robot, d_eta_d_own and d_eta_d_shared in its columns.
/// assert_eq!(lin.d_eta_d_robot.ncols(), 3);
/// # Ok(()) }
/// ```
pub fn linearize<P: RobotPose>(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    world_from_robot: &P,
    robot_from_sensor: &Pose3,
) -> Result<LinearizedMeasurement> {
    let frame = SensorFrame::new(world_from_robot, robot_from_sensor)?;
    linearize_at(measurement, feature, &frame)
}

/// [`linearize`] in a sensor frame made beforehand: the frame (pose composition, its
/// Jacobians, the rotations of eqs. 7 and 34) is computed once for all observations of a
/// step, not once per observation. The model's own [`MeasurementModel::linearize_at`] when it
/// writes one, else [`chain_linearize_at`].
pub fn linearize_at(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    frame: &SensorFrame,
) -> Result<LinearizedMeasurement> {
    let mut out = LinearizedMeasurement::default();
    linearize_at_into(measurement, feature, frame, &mut out)?;
    Ok(out)
}

/// [`linearize_at`] into `out`, reusing its matrices' storage when the model writes its own
/// linearization ([`MeasurementModel::linearize_at`]); the generic chain replaces `out`.
/// The numbers are [`linearize_at`]'s whatever `out` held; on an error `out` holds no
/// meaningful numbers.
///
/// ```
/// use slam_core::{linearize_at, linearize_at_into, LinearizedMeasurement, Pose2, Pose3, SensorFrame};
/// # fn demo(measurement: &dyn slam_core::DynMeasurementModel, feature: &dyn slam_core::Feature) -> slam_core::Result<()> {
/// let frame = SensorFrame::new(&Pose2::new(1.0, 0.0, 0.3), &Pose3::identity())?;
/// let mut kept = LinearizedMeasurement::default();
/// for _ in 0..2 {
///     linearize_at_into(measurement, feature, &frame, &mut kept)?;
/// }
/// assert_eq!(kept, linearize_at(measurement, feature, &frame)?);
/// # Ok(()) }
/// ```
pub fn linearize_at_into(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    frame: &SensorFrame,
    out: &mut LinearizedMeasurement,
) -> Result<()> {
    let written = measurement.linearize_at_dyn(feature, frame, out);
    own_or_chain(written, out, || {
        chain_linearize_at(measurement, feature, frame)
    })
}

/// The model's own linearization when it wrote one into `out`, else `chain`'s in its place.
fn own_or_chain<T>(
    written: Option<Result<()>>,
    out: &mut T,
    chain: impl FnOnce() -> Result<T>,
) -> Result<()> {
    match written {
        Some(done) => done,
        None => {
            *out = chain()?;
            Ok(())
        }
    }
}

/// The generic chain of eqs. 16-21 and 30, the same for every feature type: the map-to-sensor
/// transform with its Jacobians, the model's innovation, and their products. What
/// [`linearize_at`] computes for a model that does not write its own.
pub fn chain_linearize_at(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    frame: &SensorFrame,
) -> Result<LinearizedMeasurement> {
    let seen = frame
        .to_sensor
        .transform_with_jacobians(feature.coordinates())?;
    let innovation = measurement.innovation_dyn(feature, &seen.x_o)?;
    let d_eta_d_sensor = small_product(&innovation.d_eta_d_xo, &seen.d_xo_d_sensor);
    let d_eta_d_xf = small_product(&innovation.d_eta_d_xo, &seen.d_xo_d_xm);
    let d_eta_d_own = own_columns(feature, &d_eta_d_xf)?;
    let coordinates = feature.coordinates();
    let d_eta_d_shared = (0..coordinates.num_blocks())
        .filter(|&k| feature.is_shared(k))
        .map(|k| {
            let offset = coordinates.offset(k);
            let width = coordinates.blocks()[k].dim();
            (k, d_eta_d_xf.columns(offset, width).into_owned())
        })
        .collect();
    Ok(LinearizedMeasurement {
        cov_eta: measurement_covariance(&innovation),
        d_eta_d_robot: small_product(&d_eta_d_sensor, &frame.pose.d_sensor_d_robot),
        d_eta_d_sensor,
        d_eta_d_own,
        d_eta_d_shared,
        d_eta_d_xf,
        eta: innovation.eta,
    })
}

/// `J_eta_o J_of B~` from `J_eta_f = J_eta_o J_of`: the columns of the feature's own
/// M-space perturbation.
fn own_columns(feature: &dyn Feature, d_eta_d_xf: &DMatrix<f64>) -> Result<DMatrix<f64>> {
    let dual = feature.dual()?;
    if dual.nrows() != d_eta_d_xf.ncols() {
        return Err(Error::DimensionMismatch {
            what: "B~ rows (dim x_f)".into(),
            expected: d_eta_d_xf.ncols(),
            got: dual.nrows(),
        });
    }
    Ok(small_product(d_eta_d_xf, &dual))
}

/// `C_eta = J_eta_v C_v J_eta_v^T`.
fn measurement_covariance(innovation: &Innovation) -> DMatrix<f64> {
    chain_covariance(&innovation.d_eta_d_v, &innovation.cov_v)
}

/// `J C J^T` as the generic chain computes `C_eta = J_eta_v C_v J_eta_v^T`, for matrices of
/// any storage (a model's [`MeasurementModel::linearize_own`] on stack matrices gets the same
/// bits).
///
/// ```
/// use slam_core::{chain_covariance, nalgebra::{Matrix2, Matrix2x3, Matrix3}};
/// let j = Matrix2x3::new(1.0, 0.0, 2.0, 0.0, 1.0, 0.0);
/// let c = Matrix3::from_diagonal_element(0.5);
/// assert_eq!(chain_covariance(&j, &c), Matrix2::new(2.5, 0.0, 0.0, 0.5));
/// ```
pub fn chain_covariance<R, V, SJ, SC>(
    d_eta_d_v: &Matrix<f64, R, V, SJ>,
    cov_v: &Matrix<f64, V, V, SC>,
) -> OMatrix<f64, R, R>
where
    R: Dim,
    V: Dim,
    SJ: RawStorage<f64, R, V>,
    SC: RawStorage<f64, V, V>,
    DefaultAllocator: Allocator<R, V> + Allocator<R, R>,
{
    let d_eta_d_v_cov = chain_product(d_eta_d_v, cov_v);
    let rows = d_eta_d_v.shape_generic().0;
    OMatrix::<f64, R, R>::from_fn_generic(rows, rows, |i, j| {
        (0..d_eta_d_v_cov.ncols())
            .map(|k| d_eta_d_v_cov[(i, k)] * d_eta_d_v[(j, k)])
            .sum()
    })
}

/// What a filter over one feature alone needs of a linearization (FastSLAM's landmark
/// filters, where the robot pose is given): the fields of [`LinearizedMeasurement`] of the
/// same name, equal to them bit for bit, without the robot and sensor columns. The default
/// holds empty matrices (a buffer for [`linearize_own_at_into`]).
#[derive(Clone, Debug, PartialEq)]
pub struct OwnLinearization {
    /// `eta` at the current estimate.
    pub eta: DVector<f64>,
    /// `C_eta = J_eta_v C_v J_eta_v^T`.
    pub cov_eta: DMatrix<f64>,
    /// `J_eta_o J_of B~`: with respect to the feature's own M-space perturbation.
    pub d_eta_d_own: DMatrix<f64>,
}

impl Default for OwnLinearization {
    fn default() -> Self {
        OwnLinearization {
            eta: DVector::zeros(0),
            cov_eta: DMatrix::zeros(0, 0),
            d_eta_d_own: DMatrix::zeros(0, 0),
        }
    }
}

/// [`linearize_at`] reduced to [`OwnLinearization`]: the innovation, its covariance and the
/// feature's own columns (eqs. 16, 19 and 21 without `J_os`), with the sensor's
/// map-to-sensor transform made beforehand. The model's own
/// [`MeasurementModel::linearize_own`] when it writes one, else [`chain_linearize_own_at`].
///
/// ```
/// use slam_core::{linearize_at, linearize_own_at, Pose2, Pose3, SensorFrame};
/// # fn demo(measurement: &dyn slam_core::DynMeasurementModel, feature: &dyn slam_core::Feature) -> slam_core::Result<()> {
/// let frame = SensorFrame::new(&Pose2::new(1.0, 0.0, 0.3), &Pose3::identity())?;
/// let own = linearize_own_at(measurement, feature, &frame.to_sensor)?;
/// assert_eq!(own.d_eta_d_own, linearize_at(measurement, feature, &frame)?.d_eta_d_own);
/// # Ok(()) }
/// ```
pub fn linearize_own_at(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    to_sensor: &MapToSensor,
) -> Result<OwnLinearization> {
    let mut out = OwnLinearization::default();
    linearize_own_at_into(measurement, feature, to_sensor, &mut out)?;
    Ok(out)
}

/// [`linearize_own_at`] into `out`, reusing its storage when the model writes its own
/// ([`MeasurementModel::linearize_own`]); the generic chain replaces `out`. The numbers are
/// [`linearize_own_at`]'s whatever `out` held; on an error `out` holds no meaningful numbers.
///
/// ```
/// use slam_core::{linearize_own_at, linearize_own_at_into, OwnLinearization, Pose2, Pose3, SensorFrame};
/// # fn demo(measurement: &dyn slam_core::DynMeasurementModel, feature: &dyn slam_core::Feature) -> slam_core::Result<()> {
/// let frame = SensorFrame::new(&Pose2::new(1.0, 0.0, 0.3), &Pose3::identity())?;
/// let mut kept = OwnLinearization::default();
/// linearize_own_at_into(measurement, feature, &frame.to_sensor, &mut kept)?;
/// assert_eq!(kept, linearize_own_at(measurement, feature, &frame.to_sensor)?);
/// # Ok(()) }
/// ```
pub fn linearize_own_at_into(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    to_sensor: &MapToSensor,
    out: &mut OwnLinearization,
) -> Result<()> {
    let written = measurement.linearize_own_dyn(feature, to_sensor, out);
    own_or_chain(written, out, || {
        chain_linearize_own_at(measurement, feature, to_sensor)
    })
}

/// The generic chain of [`linearize_own_at`] (see [`chain_linearize_at`]).
pub fn chain_linearize_own_at(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    to_sensor: &MapToSensor,
) -> Result<OwnLinearization> {
    let (x_o, d_xo_d_xm) = to_sensor.transform_with_feature_jacobian(feature.coordinates())?;
    let innovation = measurement.innovation_dyn(feature, &x_o)?;
    let d_eta_d_xf = small_product(&innovation.d_eta_d_xo, &d_xo_d_xm);
    Ok(OwnLinearization {
        d_eta_d_own: own_columns(feature, &d_eta_d_xf)?,
        cov_eta: measurement_covariance(&innovation),
        eta: innovation.eta,
    })
}

impl LinearizedMeasurement {
    /// `J_eta_o J_os J_ss`: with respect to the sensor offset `(x, y, z, yaw, pitch, roll)`
    /// on the robot, for the frame the measurement was linearized in.
    pub fn d_eta_d_sensor_offset(&self, frame: &SensorFrame) -> DMatrix<f64> {
        small_product(
            &self.d_eta_d_sensor,
            &DMatrix::from_column_slice(6, 6, frame.pose.d_sensor_d_offset.as_slice()),
        )
    }
}

/// `a b` for the small matrices of one measurement, by plain loops (a general matrix
/// product's set-up costs more than the product at these sizes).
/// The shapes are the caller's to check (a panic on a mismatch, as for `a * b`).
fn small_product(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    chain_product(a, b)
}

/// `a b` as the generic measurement chain computes it (each column summed in order of `k`,
/// zero entries of `b` skipped), for matrices of any storage: a model's
/// [`MeasurementModel::linearize_own`] on stack matrices gets the chain's bits with it.
///
/// # Panics
/// When `a`'s columns are not `b`'s rows, as `a * b` does.
///
/// ```
/// use slam_core::{chain_product, nalgebra::Matrix2};
/// let a = Matrix2::new(1.0, 2.0, 3.0, 4.0);
/// assert_eq!(chain_product(&a, &Matrix2::identity()), a);
/// ```
pub fn chain_product<R, K1, K2, C, SA, SB>(
    a: &Matrix<f64, R, K1, SA>,
    b: &Matrix<f64, K2, C, SB>,
) -> OMatrix<f64, R, C>
where
    R: Dim,
    K1: Dim,
    K2: Dim,
    C: Dim,
    SA: RawStorage<f64, R, K1>,
    SB: RawStorage<f64, K2, C>,
    DefaultAllocator: Allocator<R, C>,
{
    assert_eq!(a.ncols(), b.nrows(), "chain_product: shapes do not chain");
    let mut out = OMatrix::<f64, R, C>::zeros_generic(a.shape_generic().0, b.shape_generic().1);
    add_chain_product(a, b, &mut out);
    out
}

/// [`chain_product`] written into `out` (reshaped, its storage reused when large enough):
/// the same bits, without an allocation on a filter's hot path.
///
/// # Panics
/// When `a`'s columns are not `b`'s rows, as `a * b` does.
///
/// ```
/// use slam_core::{chain_product, chain_product_into, nalgebra::{DMatrix, Matrix2}};
/// let a = Matrix2::new(1.0, 2.0, 3.0, 4.0);
/// let mut out = DMatrix::from_element(5, 1, f64::NAN);
/// chain_product_into(&a, &Matrix2::identity(), &mut out);
/// assert_eq!(out, DMatrix::from_column_slice(2, 2, chain_product(&a, &Matrix2::identity()).as_slice()));
/// ```
pub fn chain_product_into<R, K1, K2, C, SA, SB>(
    a: &Matrix<f64, R, K1, SA>,
    b: &Matrix<f64, K2, C, SB>,
    out: &mut DMatrix<f64>,
) where
    R: Dim,
    K1: Dim,
    K2: Dim,
    C: Dim,
    SA: RawStorage<f64, R, K1>,
    SB: RawStorage<f64, K2, C>,
{
    assert_eq!(a.ncols(), b.nrows(), "chain_product: shapes do not chain");
    reshape_zeroed(out, a.nrows(), b.ncols());
    add_chain_product(a, b, out);
}

/// `out += a b`, each column summed in order of `k`, zero entries of `b` skipped.
fn add_chain_product<R, K1, K2, C, R2, C2, SA, SB, SO>(
    a: &Matrix<f64, R, K1, SA>,
    b: &Matrix<f64, K2, C, SB>,
    out: &mut Matrix<f64, R2, C2, SO>,
) where
    R: Dim,
    K1: Dim,
    K2: Dim,
    C: Dim,
    R2: Dim,
    C2: Dim,
    SA: RawStorage<f64, R, K1>,
    SB: RawStorage<f64, K2, C>,
    SO: RawStorageMut<f64, R2, C2>,
{
    for j in 0..b.ncols() {
        for k in 0..a.ncols() {
            let weight = b[(k, j)];
            if weight != 0.0 {
                for i in 0..a.nrows() {
                    out[(i, j)] += a[(i, k)] * weight;
                }
            }
        }
    }
}

/// Makes `matrix` an `nrows x ncols` matrix of zeros, reusing its storage (no allocation
/// when it held at least as many entries): what a buffer kept across steps needs.
///
/// ```
/// use slam_core::{reshape_zeroed, nalgebra::DMatrix};
/// let mut buffer = DMatrix::from_element(3, 4, 1.0);
/// reshape_zeroed(&mut buffer, 2, 5);
/// assert_eq!(buffer, DMatrix::zeros(2, 5));
/// ```
pub fn reshape_zeroed(matrix: &mut DMatrix<f64>, nrows: usize, ncols: usize) {
    if matrix.shape() == (nrows, ncols) {
        matrix.fill(0.0);
        return;
    }
    let mut data: Vec<f64> = std::mem::replace(matrix, DMatrix::zeros(0, 0)).data.into();
    data.clear();
    data.resize(nrows * ncols, 0.0);
    *matrix = DMatrix::from_vec(nrows, ncols, data);
}

/// Writes `source` into `matrix` (reshaped by [`reshape_zeroed`], its storage reused).
///
/// ```
/// use slam_core::{assign_matrix, nalgebra::{DMatrix, Matrix2x3}};
/// let mut buffer = DMatrix::zeros(0, 0);
/// assign_matrix(&mut buffer, &Matrix2x3::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0));
/// assert_eq!(buffer[(1, 2)], 6.0);
/// ```
pub fn assign_matrix<R: Dim, C: Dim, S: RawStorage<f64, R, C>>(
    matrix: &mut DMatrix<f64>,
    source: &Matrix<f64, R, C, S>,
) {
    reshape_zeroed(matrix, source.nrows(), source.ncols());
    for j in 0..source.ncols() {
        for i in 0..source.nrows() {
            matrix[(i, j)] = source[(i, j)];
        }
    }
}

/// Writes `values` into `vector`, reusing its storage.
///
/// ```
/// use slam_core::{assign_vector, nalgebra::DVector};
/// let mut buffer = DVector::zeros(5);
/// assign_vector(&mut buffer, &[1.0, 2.0]);
/// assert_eq!(buffer, DVector::from_column_slice(&[1.0, 2.0]));
/// ```
pub fn assign_vector(vector: &mut DVector<f64>, values: &[f64]) {
    if vector.len() == values.len() {
        vector.as_mut_slice().copy_from_slice(values);
        return;
    }
    let mut data: Vec<f64> = std::mem::replace(vector, DVector::zeros(0)).data.into();
    data.clear();
    data.extend_from_slice(values);
    *vector = DVector::from_vec(data);
}

/// The innovation alone (no Jacobians through the chain): for gating and checks.
pub fn innovation_at<P: RobotPose>(
    measurement: &dyn DynMeasurementModel,
    feature: &dyn Feature,
    world_from_robot: &P,
    robot_from_sensor: &Pose3,
) -> Result<Innovation> {
    let world_from_sensor = world_from_robot.world_from_sensor(robot_from_sensor);
    let x_o = MapToSensor::new(&world_from_sensor)?.transform(feature.coordinates())?;
    measurement.innovation_dyn(feature, &x_o)
}
