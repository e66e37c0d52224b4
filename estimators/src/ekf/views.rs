//! Views of a feature that grew by triangulation, turned into measurements of its new rows
//! and of the current pose.

use slam_core::nalgebra::DMatrix;
use slam_core::{Error, FeatureId, Result, RobotPose, RowOwner, Skips, linearize};

use super::{Ekf, Pairing};

impl<P: RobotPose> Ekf<P> {
    /// The earlier views of a feature that grew by triangulation, as measurements of its new
    /// rows `old_dim..` and of the **current** pose: a view taken at `x_v` is treated as taken
    /// from the current pose moved by the estimated relative motion, with that motion's
    /// uncertainty (the growth of the pose covariance since the view) added to its noise.
    /// The views thus correlate the new rows with the pose, as the EKF needs, instead of
    /// entering as an independent prior (which makes the filter overconfident).
    pub(super) fn view_pairings(&mut self, id: FeatureId, old_dim: usize) -> Result<Vec<Pairing>> {
        let Some(track) = self.tracks.get(&id) else {
            return Ok(Vec::new());
        };
        let Some((_, others)) = track.views.split_last() else {
            return Ok(Vec::new());
        };
        let feature = self.map.get(id)?;
        let rows = self
            .rows
            .get(&RowOwner::Feature(id))
            .and_then(|r| r.get(old_dim..))
            .map(<[usize]>::to_vec)
            .ok_or_else(|| Error::Invariant(format!("feature {} grew without rows", id.0)))?;
        let added = rows.len();
        let c_now = slam_core::Estimator::pose_covariance(self);
        let mut pairings = Vec::new();
        let mut skips = Skips::default();
        for view in others {
            let Some(view_covariance) = &view.pose_covariance else {
                return Err(Error::Invariant(
                    "an EKF view without its pose covariance".into(),
                ));
            };
            let Ok(lin) = linearize(
                view.measurement.as_ref(),
                feature,
                &view.world_from_robot,
                &view.robot_from_sensor,
            ) else {
                skips.count("growth: a view does not linearize against the grown feature");
                continue;
            };
            let relative = psd_part(&(&c_now - view_covariance));
            let cov_eta =
                &lin.cov_eta + &lin.d_eta_d_robot * relative * lin.d_eta_d_robot.transpose();
            let m = lin.eta.len();
            let mut h = DMatrix::zeros(m, P::DIM + added);
            h.view_mut((0, 0), (m, P::DIM))
                .copy_from(&lin.d_eta_d_robot);
            h.view_mut((0, P::DIM), (m, added))
                .copy_from(&lin.d_eta_d_own.columns(old_dim, added));
            let mut indices: Vec<usize> = (0..P::DIM).collect();
            indices.extend_from_slice(&rows);
            pairings.push(Pairing {
                feature: id,
                indices,
                h,
                eta: lin.eta,
                cov_eta,
                nis: None,
            });
        }
        self.skips.merge(&skips);
        Ok(pairings)
    }
}

/// The positive semi-definite part of a symmetric matrix (negative eigenvalues set to 0).
fn psd_part(m: &DMatrix<f64>) -> DMatrix<f64> {
    let symmetric = 0.5 * (m + m.transpose());
    let eigen = symmetric.symmetric_eigen();
    let clipped = eigen.eigenvalues.map(|v| v.max(0.0));
    &eigen.eigenvectors * DMatrix::from_diagonal(&clipped) * eigen.eigenvectors.transpose()
}
