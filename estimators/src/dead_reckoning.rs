//! Dead reckoning: the pose from the motion model alone, no map. The baseline every SLAM
//! estimator is compared with ("odometry alone"), and the cheapest estimator to run when a
//! post-processing stage places the scans by poses the data give.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::DMatrix;
use slam_core::{
    Error, Estimator, FeatureMap, MotionModel, Observation, Result, RobotPose, RowOwner,
    UpdateReport,
};

/// Settings of [`DeadReckoning`] (it has none).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeadReckoningParams {}

/// The pose integrated from the motion increments with its covariance (eqs. 25-26); every
/// observation is rejected.
///
/// ```
/// use slam_core::{Estimator, Pose2, nalgebra::DMatrix};
/// use slam_estimators::DeadReckoning;
/// let odometry = DeadReckoning::new(Pose2::identity(), DMatrix::zeros(3, 3)).unwrap();
/// assert!(odometry.map().is_empty());
/// ```
#[derive(Debug)]
pub struct DeadReckoning<P: RobotPose> {
    pose: P,
    covariance: DMatrix<f64>,
    map: FeatureMap,
}

impl<P: RobotPose> DeadReckoning<P> {
    /// Starts at `pose` with covariance `pose_covariance` (`P::DIM` square).
    pub fn new(pose: P, pose_covariance: DMatrix<f64>) -> Result<Self> {
        if pose_covariance.shape() != (P::DIM, P::DIM) {
            return Err(Error::DimensionMismatch {
                what: "initial pose covariance".into(),
                expected: P::DIM,
                got: pose_covariance.nrows(),
            });
        }
        slam_core::ensure_finite(pose_covariance.as_slice(), "initial pose covariance")?;
        Ok(DeadReckoning {
            pose,
            covariance: pose_covariance,
            map: FeatureMap::new(),
        })
    }
}

impl<P: RobotPose> Estimator<P> for DeadReckoning<P> {
    fn name(&self) -> &'static str {
        "dead-reckoning"
    }

    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        let prediction = motion.predict(&self.pose)?;
        let covariance = prediction.propagate_covariance(&self.covariance)?;
        slam_core::ensure_finite(covariance.as_slice(), "dead-reckoning covariance")?;
        self.pose = prediction.pose;
        self.covariance = covariance;
        Ok(())
    }

    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        Ok(UpdateReport {
            rejected: observations.len(),
            ..UpdateReport::default()
        })
    }

    fn pose(&self) -> P {
        self.pose
    }

    fn pose_covariance(&self) -> DMatrix<f64> {
        self.covariance.clone()
    }

    fn map(&self) -> &FeatureMap {
        &self.map
    }

    fn row_covariance(&self, _: RowOwner) -> Option<DMatrix<f64>> {
        None
    }
}
