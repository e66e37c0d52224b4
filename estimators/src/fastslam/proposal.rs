//! FastSLAM 2.0's improved proposal (Montemerlo et al. 2003): the pose drawn from the motion
//! prior conditioned on the step's observations of confirmed features.

use rand_distr::{Distribution, StandardNormal};
use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{Observation, Result, RobotPose, linearize};

use super::step::{Decision, ParticleStep};
use crate::particles::{log_normal, matrix_sqrt};

/// One observation in the proposal: its index, `H_r`, `eta` and `Q = H_f P_f H_f^T + C_eta`.
struct ProposalRow {
    index: usize,
    h_r: DMatrix<f64>,
    eta: DVector<f64>,
    q: DMatrix<f64>,
}

/// The proposal's Gaussian `N(mean, root root^T)` on the pose change.
struct Draw {
    mean: DVector<f64>,
    root: DMatrix<f64>,
}

impl<P: RobotPose> ParticleStep<'_, '_, P> {
    /// Draws the pose from the motion prior conditioned on the observations of confirmed
    /// features paired in `decisions`, and counts their joint likelihood under the predicted
    /// pose. Without such observations the pose is drawn from the prior alone.
    pub(super) fn propose(
        &mut self,
        observations: &[Observation],
        decisions: &[Decision],
    ) -> Result<()> {
        let Some(prior) = self.particle.map.pending.take() else {
            return Ok(());
        };
        let rows = self.proposal_rows(observations, decisions);
        let draw = if rows.is_empty() {
            Draw {
                mean: DVector::zeros(P::DIM),
                root: matrix_sqrt(&prior),
            }
        } else {
            match self.conditioned(&prior, &rows) {
                Some(draw) => draw,
                None => {
                    self.report
                        .skipped
                        .count("proposal: singular information, pose not drawn");
                    return Ok(());
                }
            }
        };
        let z = DVector::from_fn(P::DIM, |_, _| StandardNormal.sample(&mut self.rng));
        let delta = draw.mean + draw.root * z;
        match self.particle.pose.oplus(delta.as_slice()) {
            Ok(drawn) => self.particle.pose = drawn,
            Err(_) => self.report.skipped.count("proposal: drawn pose invalid"),
        }
        Ok(())
    }

    /// `(observation, H_r, eta, Q)` of each pairing with a confirmed feature.
    fn proposal_rows(
        &mut self,
        observations: &[Observation],
        decisions: &[Decision],
    ) -> Vec<ProposalRow> {
        let pose = self.particle.pose;
        let mut rows = Vec::new();
        for (index, decision) in decisions.iter().enumerate() {
            let Decision::Pair(slot) = decision else {
                continue;
            };
            let Some(landmark) = self.particle.map.landmarks.get(*slot) else {
                continue;
            };
            let n = landmark.feature.mspace_dim();
            if n == 0 || landmark.cov.shape() != (n, n) {
                continue;
            }
            let observation = &observations[index];
            let Ok(lin) = linearize(
                observation.measurement.as_ref(),
                landmark.feature.as_ref(),
                &pose,
                &observation.robot_from_sensor,
            ) else {
                self.report.skipped.count("proposal: linearization failed");
                continue;
            };
            let q = &lin.d_eta_d_own * &landmark.cov * lin.d_eta_d_own.transpose() + &lin.cov_eta;
            rows.push(ProposalRow {
                index,
                h_r: lin.d_eta_d_robot,
                eta: lin.eta,
                q,
            });
        }
        rows
    }

    /// The prior conditioned on the rows in information form (the prior's information
    /// regularized for a still robot), and the rows' joint likelihood under the prior, which
    /// is counted in the weight. `None` when an information matrix is singular.
    fn conditioned(&mut self, prior: &DMatrix<f64>, rows: &[ProposalRow]) -> Option<Draw> {
        let d = P::DIM;
        let regularized = prior + DMatrix::identity(d, d) * 1e-12;
        let mut information = regularized.try_inverse()?;
        let mut gradient = DVector::zeros(d);
        let m: usize = rows.iter().map(|r| r.eta.len()).sum();
        let mut h = DMatrix::zeros(m, d);
        let mut eta = DVector::zeros(m);
        let mut q_all = DMatrix::zeros(m, m);
        let mut at = 0;
        for row in rows {
            let q_inv = row.q.clone().try_inverse()?;
            information += row.h_r.transpose() * &q_inv * &row.h_r;
            gradient += row.h_r.transpose() * &q_inv * &row.eta;
            let k = row.eta.len();
            h.view_mut((at, 0), (k, d)).copy_from(&row.h_r);
            eta.rows_mut(at, k).copy_from(&row.eta);
            q_all.view_mut((at, at), (k, k)).copy_from(&row.q);
            at += k;
        }
        let sigma = information.try_inverse()?;
        let s = &h * prior * h.transpose() + q_all;
        if let Some((log_likelihood, _)) = log_normal(&eta, &s) {
            self.log_likelihood += log_likelihood;
            for row in rows {
                self.weighted[row.index] = true;
            }
        }
        Some(Draw {
            mean: -(&sigma * gradient),
            root: matrix_sqrt(&sigma),
        })
    }
}
