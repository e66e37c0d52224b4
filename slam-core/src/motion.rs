//! Dead-reckoning motion models (paper eqs. 25-27).

use std::fmt::Debug;

use nalgebra::{DMatrix, DVector};

use crate::error::{Error, Result};
use crate::pose::RobotPose;

/// The predicted pose and the Jacobians an EKF needs (eqs. 25-27).
#[derive(Clone, Debug, PartialEq)]
pub struct MotionPrediction<P> {
    /// `x_r(t) = f(x_r(t-1), x_d(t, t-1))` (eq. 25).
    pub pose: P,
    /// `J_rr = df / dx_r` (`P::DIM x P::DIM`).
    pub d_pose_d_pose: DMatrix<f64>,
    /// `J_rd = df / dx_d` (`P::DIM x dim(x_d)`).
    pub d_pose_d_control: DMatrix<f64>,
    /// `C_d`, the covariance of the dead-reckoning increment `x_d`.
    pub cov_control: DMatrix<f64>,
}

impl<P> MotionPrediction<P> {
    /// `C_rr(t) = J_rr C_rr(t-1) J_rr^T + J_rd C_d J_rd^T` (eq. 26).
    ///
    /// ```
    /// use slam_core::{MotionPrediction, Pose2, nalgebra::DMatrix};
    /// let prediction = MotionPrediction {
    ///     pose: Pose2::identity(),
    ///     d_pose_d_pose: DMatrix::identity(3, 3),
    ///     d_pose_d_control: DMatrix::identity(3, 3),
    ///     cov_control: DMatrix::identity(3, 3) * 0.01,
    /// };
    /// let c = prediction.propagate_covariance(&DMatrix::identity(3, 3)).unwrap();
    /// assert!((c[(0, 0)] - 1.01).abs() < 1e-12);
    /// ```
    pub fn propagate_covariance(&self, cov_pose: &DMatrix<f64>) -> Result<DMatrix<f64>> {
        let n = self.d_pose_d_pose.nrows();
        if cov_pose.shape() != (n, n) {
            return Err(Error::DimensionMismatch {
                what: "pose covariance".into(),
                expected: n,
                got: cov_pose.nrows(),
            });
        }
        Ok(
            &self.d_pose_d_pose * cov_pose * self.d_pose_d_pose.transpose()
                + &self.d_pose_d_control * &self.cov_control * self.d_pose_d_control.transpose(),
        )
    }
}

/// One dead-reckoning increment `x_d(t, t-1)` and the motion function `f` it drives.
///
/// The covariance of the robot-to-feature block follows `C_rp(t) = J_rr C_rp(t-1)` (eq. 27).
/// Sampling filters draw `x_d` from `N(control(), C_d)` and call
/// [`apply_control`](MotionModel::apply_control).
pub trait MotionModel<P: RobotPose>: Debug + Send + Sync {
    /// The increment `x_d` as a vector.
    fn control(&self) -> DVector<f64>;

    /// `f(x_r, x_d)` for an arbitrary increment `control` (same layout as [`Self::control`]).
    fn apply_control(&self, pose: &P, control: &DVector<f64>) -> Result<P>;

    /// `f(x_r, x_d)` with `J_rr`, `J_rd` and `C_d` at the model's own increment (eqs. 25-27).
    fn predict(&self, pose: &P) -> Result<MotionPrediction<P>>;
}
