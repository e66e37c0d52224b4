//! The estimator trait: what every SLAM algorithm (EKF, FastSLAM, post-processing) offers, so
//! that the `slam` command can swap one for another by configuration (paper section V: "the
//! M-space feature representation is orthogonal to the choice of SLAM algorithm").

use std::collections::BTreeMap;
use std::sync::Arc;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::map::{FeatureMap, RowOwner};
use crate::measurement::DynMeasurementModel;
use crate::motion::MotionModel;
use crate::pose::{Pose3, RobotPose};

/// One measurement taken by one sensor. The measurement is shared, not copied, when the
/// observation is cloned (a front-end passing on given observations, an estimator keeping a
/// view): cloning allocates nothing.
#[derive(Clone, Debug)]
pub struct Observation {
    /// Where the sensor sits on the robot, `x_r,s` (eq. 17).
    pub robot_from_sensor: Pose3,
    /// The measured values with their model.
    pub measurement: Arc<dyn DynMeasurementModel>,
    /// The true landmark identity when the data provide it (known data association).
    pub landmark_id: Option<u64>,
}

/// What an estimator or front-end left out, counted by reason (a failed linearization, a
/// singular innovation covariance, a change a feature refused): never a silent skip.
///
/// ```
/// use slam_core::Skips;
/// let mut skips = Skips::default();
/// skips.count("singular innovation covariance");
/// skips.count("singular innovation covariance");
/// assert_eq!(skips.get("singular innovation covariance"), 2);
/// assert_eq!(skips.total(), 2);
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Skips(BTreeMap<String, usize>);

impl Skips {
    /// Counts one skip for `reason`.
    pub fn count(&mut self, reason: &str) {
        self.add(reason, 1);
    }

    /// Counts `n` skips for `reason`.
    pub fn add(&mut self, reason: &str, n: usize) {
        if n == 0 {
            return;
        }
        match self.0.get_mut(reason) {
            Some(total) => *total += n,
            None => {
                self.0.insert(reason.to_string(), n);
            }
        }
    }

    /// Adds every count of `other`.
    pub fn merge(&mut self, other: &Skips) {
        for (reason, n) in &other.0 {
            self.add(reason, *n);
        }
    }

    /// The count for `reason`.
    pub fn get(&self, reason: &str) -> usize {
        self.0.get(reason).copied().unwrap_or(0)
    }

    /// All skips.
    pub fn total(&self) -> usize {
        self.0.values().sum()
    }

    /// True when nothing was skipped.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// `(reason, count)` in the order of the reasons.
    pub fn iter(&self) -> impl Iterator<Item = (&str, usize)> {
        self.0.iter().map(|(r, n)| (r.as_str(), *n))
    }
}

/// What one update step did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateReport {
    /// Observations matched to existing features and used in the update.
    pub associated: usize,
    /// Observations that started new (tentative) features.
    pub new_features: usize,
    /// Observations rejected (gated out, or failed to linearize).
    pub rejected: usize,
    /// Normalized innovation squared of each associated observation, with its degrees of
    /// freedom, for consistency checks (NIS).
    pub nis: Vec<(f64, usize)>,
    /// What the step left out besides the rejected observations, by reason.
    pub skipped: Skips,
}

/// A SLAM estimator over robot poses of type `P`, written against the slam-core traits only.
pub trait Estimator<P: RobotPose> {
    /// Short name used in configuration and outputs, e.g. `"ekf"`.
    fn name(&self) -> &'static str;

    /// Moves the robot by one dead-reckoning increment (eqs. 25-27 for an EKF).
    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()>;

    /// Incorporates the observations taken at the current pose (eqs. 28-32 for an EKF).
    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport>;

    /// The current robot pose estimate.
    fn pose(&self) -> P;

    /// Covariance of the robot pose (`P::DIM x P::DIM`).
    fn pose_covariance(&self) -> DMatrix<f64>;

    /// The current map (for a particle filter: the map of the most likely particle).
    fn map(&self) -> &FeatureMap;

    /// Covariance of one row group of the map's M-space perturbations, if the estimator has it.
    fn row_covariance(&self, owner: RowOwner) -> Option<DMatrix<f64>>;

    /// Cross-covariance of two row groups (`rows of a x rows of b`), if the estimator keeps
    /// it (a Gaussian over the whole map does; the default, and a particle filter whose
    /// features are independent given the path, gives `None`).
    fn cross_covariance(&self, a: RowOwner, b: RowOwner) -> Option<DMatrix<f64>> {
        let _ = (a, b);
        None
    }

    /// Ends one time step (the caller records the estimate once per step): a particle filter
    /// appends each particle's pose to that particle's path. Default: nothing.
    fn end_step(&mut self) {}

    /// The path the map belongs to, one pose per [`end_step`](Estimator::end_step), oldest
    /// first: for a particle filter, the path of the particle whose map [`map`](Estimator::map)
    /// returns (a sample, not the weighted mean of [`pose`](Estimator::pose)). `None` (the
    /// default) when the poses of [`pose`](Estimator::pose) are that path (an EKF).
    fn map_path(&self) -> Option<Vec<P>> {
        None
    }

    /// Where [`pose_covariance`](Estimator::pose_covariance) comes from, as the consistency
    /// statistics (NEES) name it: `"gaussian"` (the default: a Gaussian estimate's covariance)
    /// or `"particle cloud"` (the weighted covariance of a particle filter's poses).
    fn covariance_source(&self) -> &'static str {
        "gaussian"
    }

    /// The landmark id the data gave a feature (known data association), if any.
    fn landmark_id(&self, id: crate::FeatureId) -> Option<u64> {
        let _ = id;
        None
    }
}
