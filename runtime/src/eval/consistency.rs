//! Statistical consistency: NEES of the robot pose against true poses and NIS of the paired
//! observations, summarized against their chi-square distributions.

use std::collections::BTreeMap;

use serde::Serialize;
use slam_core::nalgebra::{Matrix3, Vector3};
use slam_core::{Pose2, RobotPose, chi2_quantile};

use crate::error::Result;

/// Summary of a chi-square statistic over a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ChiSquareSummary {
    /// Number of values.
    pub count: usize,
    /// Mean of the values divided by their degrees of freedom (1 when consistent).
    pub mean_per_dof: f64,
    /// Fraction of values inside their two-sided 95% chi-square interval.
    pub within_95: f64,
}

/// A [`ChiSquareSummary`] built one value at a time (a run keeps no list of its NIS values).
///
/// ```
/// use slam_runtime::eval::ChiSquareAccumulator;
/// let mut nis = ChiSquareAccumulator::default();
/// nis.add(2.0, 2)?;
/// nis.add(1.0, 1)?;
/// let summary = nis.summary();
/// assert_eq!((summary.count, summary.mean_per_dof), (2, 1.0));
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChiSquareAccumulator {
    count: usize,
    sum_per_dof: f64,
    inside: usize,
    bands: BTreeMap<usize, (f64, f64)>,
}

impl ChiSquareAccumulator {
    /// Adds a value with `dof` degrees of freedom (a value with none counts, and adds nothing).
    pub fn add(&mut self, value: f64, dof: usize) -> Result<()> {
        self.count += 1;
        if dof == 0 {
            return Ok(());
        }
        let band = match self.bands.get(&dof) {
            Some(b) => *b,
            None => {
                let b = (chi2_quantile(0.025, dof)?, chi2_quantile(0.975, dof)?);
                self.bands.insert(dof, b);
                b
            }
        };
        self.inside += usize::from(value >= band.0 && value <= band.1);
        self.sum_per_dof += value / dof as f64;
        Ok(())
    }

    /// The summary of the values so far (all zero for none).
    pub fn summary(&self) -> ChiSquareSummary {
        if self.count == 0 {
            return ChiSquareSummary::default();
        }
        ChiSquareSummary {
            count: self.count,
            mean_per_dof: self.sum_per_dof / self.count as f64,
            within_95: self.inside as f64 / self.count as f64,
        }
    }
}

/// Summarizes `(value, dof)` pairs.
pub fn chi_square_summary(values: &[(f64, usize)]) -> Result<ChiSquareSummary> {
    let mut accumulator = ChiSquareAccumulator::default();
    for &(value, dof) in values {
        accumulator.add(value, dof)?;
    }
    Ok(accumulator.summary())
}

/// The estimate at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    /// Time, s (or sequence number).
    pub time: f64,
    /// Estimated pose.
    pub pose: Pose2,
    /// Its covariance `(x, y, heading)`.
    pub covariance: Matrix3<f64>,
}

/// The robot-pose NEES `e^T C^-1 e` (3 degrees of freedom) at every estimate that has a true
/// pose at the same time, `e = truth ⊟ estimate`; `truth` maps the bits of a time to the
/// true pose. A pose known exactly (the start, covariance zero) has none.
pub fn pose_nees(estimates: &[Record], truth: &BTreeMap<u64, Pose2>) -> Vec<(f64, f64)> {
    estimates
        .iter()
        .filter_map(|r| {
            let truth = truth.get(&r.time.to_bits())?;
            let e = truth.ominus(&r.pose);
            let e = Vector3::new(e[0], e[1], e[2]);
            let cholesky = r.covariance.cholesky()?;
            if cholesky.l().diagonal().min() < 1e-9 {
                return None;
            }
            Some((r.time, (e.transpose() * cholesky.inverse() * e)[(0, 0)]))
        })
        .collect()
}
