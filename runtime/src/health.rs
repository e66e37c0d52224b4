//! Divergence detection: an [`Observer`] that watches the innovation tests of the updates and
//! the pose covariance, and says when the filter has diverged. The run goes on to the end
//! (its outputs are kept); the `slam` command then exits with a code of its own.
//!
//! A filter has diverged when
//! - the innovation test of [`FAILED_UPDATES`] consecutive updates fails: the update's NIS
//!   (summed over its paired observations) is above the 99.9% quantile of the chi-square with
//!   their degrees of freedom (a consistent filter fails one update in a thousand); or
//! - its pose estimate or covariance is not finite, has a negative variance, or a position
//!   standard deviation above [`MAX_POSITION_SIGMA_M`] (a blown-up covariance).

use serde::Serialize;
use slam_core::{Estimator, Pose2, UpdateReport};
use slam_sensors::TimedEvent;

use crate::error::Result;
use crate::session::Observer;

/// Consecutive updates whose innovation test fails that make a divergence.
pub const FAILED_UPDATES: usize = 50;

/// A position standard deviation above this (m) is a blown-up covariance.
pub const MAX_POSITION_SIGMA_M: f64 = 1e5;

/// The probability of the innovation test's upper bound.
const TEST_PROBABILITY: f64 = 0.999;

/// Where and why a filter diverged.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Divergence {
    /// The time of the data when the divergence was found, s (or sequence number).
    pub time: f64,
    /// What was seen.
    pub reason: String,
}

/// An [`Observer`] that finds the first divergence of a run (see the module documentation).
#[derive(Clone, Debug, Default)]
pub struct DivergenceMonitor {
    /// Consecutive failed innovation tests so far, with their NIS per degree of freedom.
    failed: usize,
    failed_nis_per_dof: f64,
    /// The first divergence found.
    divergence: Option<Divergence>,
    /// [`upper_quantile`] by degrees of freedom, computed once each (NaN: not yet).
    bounds: Vec<f64>,
}

impl DivergenceMonitor {
    /// The first divergence found, if any.
    pub fn divergence(&self) -> Option<&Divergence> {
        self.divergence.as_ref()
    }

    fn found(&mut self, time: f64, reason: String) {
        if self.divergence.is_none() {
            self.divergence = Some(Divergence { time, reason });
        }
    }

    /// [`upper_quantile`] of `dof`, remembered (a quantile costs an iterative search).
    fn bound(&mut self, dof: usize) -> f64 {
        if dof >= 1024 {
            return upper_quantile(dof);
        }
        if self.bounds.len() <= dof {
            self.bounds.resize(dof + 1, f64::NAN);
        }
        if self.bounds[dof].is_nan() {
            self.bounds[dof] = upper_quantile(dof);
        }
        self.bounds[dof]
    }

    /// Counts one update's innovation test.
    fn test(&mut self, time: f64, report: &UpdateReport) {
        let (nis, dof) = report
            .nis
            .iter()
            .fold((0.0, 0usize), |(s, d), (v, k)| (s + v, d + k));
        if dof == 0 {
            return;
        }
        if nis <= self.bound(dof) {
            self.failed = 0;
            self.failed_nis_per_dof = 0.0;
            return;
        }
        self.failed += 1;
        self.failed_nis_per_dof += nis / dof as f64;
        if self.failed == FAILED_UPDATES {
            let mean = self.failed_nis_per_dof / FAILED_UPDATES as f64;
            self.found(
                time,
                format!(
                    "the innovation test failed at {FAILED_UPDATES} consecutive updates \
                     (NIS per degree of freedom {mean:.3e} on average, above the 99.9% bound)"
                ),
            );
        }
    }
}

/// The 99.9% quantile of a chi-square with `dof` degrees of freedom (Wilson-Hilferty above
/// 100, exact below).
fn upper_quantile(dof: usize) -> f64 {
    if dof <= 100
        && let Ok(q) = slam_core::chi2_quantile(TEST_PROBABILITY, dof)
    {
        return q;
    }
    let nu = dof as f64;
    let a = 2.0 / (9.0 * nu);
    nu * (1.0 - a + 3.090_232_306_167_813 * a.sqrt()).powi(3)
}

/// Why a pose estimate and its covariance say the filter blew up, if they do.
fn blown_up(estimator: &dyn Estimator<Pose2>) -> Option<String> {
    let pose = estimator.pose();
    if !(pose.x.is_finite() && pose.y.is_finite() && pose.theta.is_finite()) {
        return Some("the pose estimate is not finite".into());
    }
    let c = estimator.pose_covariance();
    if c.iter().any(|v| !v.is_finite()) {
        return Some("the pose covariance is not finite".into());
    }
    let diagonal: Vec<f64> = c.diagonal().iter().copied().collect();
    if diagonal.iter().any(|v| *v < -1e-9) {
        return Some("the pose covariance has a negative variance".into());
    }
    let sigma = diagonal
        .iter()
        .take(2)
        .map(|v| v.max(0.0))
        .sum::<f64>()
        .sqrt();
    (sigma > MAX_POSITION_SIGMA_M).then(|| {
        format!(
            "the pose covariance blew up (position standard deviation {sigma:.3e} m, above \
             {MAX_POSITION_SIGMA_M:e} m)"
        )
    })
}

impl Observer for DivergenceMonitor {
    fn event(
        &mut self,
        event: &TimedEvent,
        update: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        if let Some(report) = update {
            self.test(event.time, report);
        }
        Ok(())
    }

    fn step_end(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        if self.divergence.is_none()
            && let Some(reason) = blown_up(estimator)
        {
            self.found(time, reason);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(nis: &[(f64, usize)]) -> UpdateReport {
        UpdateReport {
            nis: nis.to_vec(),
            ..UpdateReport::default()
        }
    }

    #[test]
    fn long_stretches_of_failed_innovation_tests_are_a_divergence() {
        let mut monitor = DivergenceMonitor::default();
        // Failures interrupted by a pass, and updates without pairings, are no divergence.
        for k in 0..200 {
            let nis = if k % 40 == 39 { 1.0 } else { 1e4 };
            monitor.test(k as f64, &report(&[(nis, 2)]));
            monitor.test(k as f64, &report(&[]));
        }
        assert!(monitor.divergence().is_none());
        for k in 0..FAILED_UPDATES {
            monitor.test(1000.0 + k as f64, &report(&[(30.0, 2), (20.0, 2)]));
        }
        let divergence = monitor.divergence().unwrap();
        assert_eq!(divergence.time, 1000.0 + (FAILED_UPDATES - 1) as f64);
        assert!(
            divergence.reason.contains("innovation test"),
            "{divergence:?}"
        );
    }

    #[test]
    fn a_blown_up_or_broken_pose_covariance_is_a_divergence() {
        use slam_core::nalgebra::{DMatrix, DVector};
        use slam_estimators::DeadReckoning;
        let at = |variances: [f64; 3]| {
            let covariance = DMatrix::from_diagonal(&DVector::from_row_slice(&variances));
            let estimator = DeadReckoning::new(Pose2::identity(), covariance).unwrap();
            let mut monitor = DivergenceMonitor::default();
            monitor.step_end(7.0, &estimator).unwrap();
            monitor.divergence().cloned()
        };
        // A large but finite uncertainty (1 km) is no divergence.
        assert!(at([1e6, 1e6, 1.0]).is_none());
        // A position standard deviation of 1000 km is.
        let divergence = at([1e12, 1e12, 1.0]).unwrap();
        assert_eq!(divergence.time, 7.0);
        assert!(divergence.reason.contains("blew up"), "{divergence:?}");
        let divergence = at([-1.0, 1.0, 1.0]).unwrap();
        assert!(
            divergence.reason.contains("negative variance"),
            "{divergence:?}"
        );
    }

    #[test]
    fn the_upper_quantile_is_continuous_across_the_approximation() {
        let exact = slam_core::chi2_quantile(TEST_PROBABILITY, 100).unwrap();
        let nu = 101.0_f64;
        let a = 2.0 / (9.0 * nu);
        let approximated = nu * (1.0 - a + 3.090_232_306_167_813 * a.sqrt()).powi(3);
        assert!(
            (approximated - exact).abs() < 3.0,
            "{approximated} vs {exact}"
        );
        assert!((upper_quantile(2) - 13.815510557964274).abs() < 1e-6);
    }
}
