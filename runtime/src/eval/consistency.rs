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
    /// The two-sided 95% interval of `mean_per_dof` for a consistent estimator (values
    /// chi-square distributed with their degrees of freedom, taken as independent): a mean
    /// outside it says the estimator is over- (above) or under-confident (below).
    pub band_95: [f64; 2],
}

impl ChiSquareSummary {
    /// `"1.180 (95% band 0.933-1.070)"`, or `"n/a"` for no values.
    pub fn describe(&self) -> String {
        if self.count == 0 {
            return "n/a".into();
        }
        format!(
            "{} (95% band {}-{})",
            short(self.mean_per_dof),
            short(self.band_95[0]),
            short(self.band_95[1])
        )
    }
}

/// A number in 3 decimals, or in scientific notation when large.
fn short(value: f64) -> String {
    if value.abs() >= 1e4 {
        format!("{value:.2e}")
    } else {
        format!("{value:.3}")
    }
}

/// The two-sided 95% interval of the mean of `v_i / d_i` over values `v_i` chi-square
/// distributed with `d_i` degrees of freedom: a chi-square with `nu = n^2 / sum(1 / d_i)`
/// degrees of freedom divided by `nu` (the same mean and variance), through the
/// Wilson-Hilferty approximation for large `nu`.
pub fn mean_band_95(count: usize, inverse_dof_sum: f64) -> [f64; 2] {
    if count == 0 || inverse_dof_sum.is_nan() || inverse_dof_sum <= 0.0 {
        return [0.0, 0.0];
    }
    let nu = (count as f64).powi(2) / inverse_dof_sum;
    let quantile = |p: f64, z: f64| -> f64 {
        let whole = nu.round();
        if nu <= 1000.0
            && (nu - whole).abs() < 1e-9
            && let Ok(q) = chi2_quantile(p, whole as usize)
        {
            return q / nu;
        }
        let a = 2.0 / (9.0 * nu);
        (1.0 - a + z * a.sqrt()).max(0.0).powi(3)
    };
    [
        quantile(0.025, -1.959_963_984_540_054),
        quantile(0.975, 1.959_963_984_540_054),
    ]
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
    inverse_dof_sum: f64,
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
        self.inverse_dof_sum += 1.0 / dof as f64;
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
            band_95: mean_band_95(self.count, self.inverse_dof_sum),
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
/// true pose. A pose whose covariance is singular (the start, known exactly; a collapsed
/// particle cloud) has none: [`singular_steps`] counts them.
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

/// The robot-pose NEES against reference poses that may lie in another frame: another
/// system's estimate of the same path, such as a corrected log's poses. Both paths are first
/// expressed from their first common time (`⊖start ⊕ pose`), the estimate's covariance
/// rotated with it and its start taken as known, as a filter's is; then [`pose_nees`]. The
/// reference's own error counts as the estimate's, so a consistent filter scores somewhat
/// above 1 per degree of freedom. Empty when no estimate has a reference pose.
///
/// ```
/// use std::collections::BTreeMap;
/// use slam_core::Pose2;
/// use slam_core::nalgebra::Matrix3;
/// use slam_runtime::eval::{Record, anchored_pose_nees};
///
/// let record = |time: f64, pose: Pose2| Record { time, pose, covariance: Matrix3::identity() * 0.01 };
/// let estimates = [record(0.0, Pose2::new(0.0, 0.0, 0.0)), record(1.0, Pose2::new(1.0, 0.1, 0.0))];
/// // The reference's frame is turned by 90 degrees and moved: its path runs along y.
/// let reference: BTreeMap<u64, Pose2> = [(0.0, Pose2::new(5.0, 5.0, 1.5707963267948966)),
///     (1.0, Pose2::new(5.0, 6.0, 1.5707963267948966))]
///     .into_iter().map(|(t, p)| (f64::to_bits(t), p)).collect();
/// let nees = anchored_pose_nees(&estimates, &reference);
/// // The start (here not singular) agrees exactly; then 0.1 m off across the path.
/// assert!(nees[0].1.abs() < 1e-12 && (nees[1].1 - 1.0).abs() < 1e-9);
/// ```
pub fn anchored_pose_nees(
    estimates: &[Record],
    reference: &BTreeMap<u64, Pose2>,
) -> Vec<(f64, f64)> {
    let Some((estimate_start, reference_start)) = estimates
        .iter()
        .find_map(|r| reference.get(&r.time.to_bits()).map(|p| (r.pose, *p)))
    else {
        return Vec::new();
    };
    // d(⊖start ⊕ pose)/d(pose) with the start fixed: the start's rotation, transposed.
    let mut start_from_world = Matrix3::identity();
    start_from_world
        .fixed_view_mut::<2, 2>(0, 0)
        .copy_from(&estimate_start.rotation().transpose());
    let anchored: Vec<Record> = estimates
        .iter()
        .map(|r| Record {
            time: r.time,
            pose: estimate_start.between(&r.pose),
            covariance: start_from_world * r.covariance * start_from_world.transpose(),
        })
        .collect();
    let anchored_reference = reference
        .iter()
        .map(|(&time, pose)| (time, reference_start.between(pose)))
        .collect();
    pose_nees(&anchored, &anchored_reference)
}

/// How many estimates with a true pose have no NEES because their covariance is singular
/// (not positive definite, or a standard deviation below 1e-9).
pub fn singular_steps(estimates: &[Record], truth: &BTreeMap<u64, Pose2>) -> usize {
    let with_truth = estimates
        .iter()
        .filter(|r| truth.contains_key(&r.time.to_bits()))
        .count();
    with_truth - pose_nees(estimates, truth).len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reference path in another frame (turned and moved) gives, at every time, the NEES
    /// against the same path in the estimate's frame; with no common time there is none.
    #[test]
    fn the_anchored_nees_does_not_depend_on_the_reference_frame() {
        let truth: Vec<(f64, Pose2)> = (0..20)
            .map(|k| {
                let t = k as f64 * 0.5;
                (t, Pose2::new(t.cos() + 0.3 * t, t.sin(), 0.7 + 0.2 * t))
            })
            .collect();
        let covariance = Matrix3::new(0.04, 0.01, 0.0, 0.01, 0.09, 0.002, 0.0, 0.002, 0.01);
        let estimates: Vec<Record> = truth
            .iter()
            .enumerate()
            .map(|(k, &(time, pose))| {
                let off = if k == 0 { 0.0 } else { 0.1 * (k as f64).sin() };
                Record {
                    time,
                    pose: Pose2::new(pose.x + off, pose.y - 0.5 * off, pose.theta + 0.3 * off),
                    covariance,
                }
            })
            .collect();
        let by_time = |poses: &[(f64, Pose2)]| -> BTreeMap<u64, Pose2> {
            poses.iter().map(|(t, p)| (t.to_bits(), *p)).collect()
        };
        let direct = pose_nees(&estimates, &by_time(&truth));
        let elsewhere = Pose2::new(-12.0, 7.5, 2.4);
        let moved: Vec<(f64, Pose2)> = truth
            .iter()
            .map(|&(t, p)| (t, elsewhere.compose(&p)))
            .collect();
        let anchored = anchored_pose_nees(&estimates, &by_time(&moved));
        assert_eq!(anchored.len(), direct.len());
        for ((t0, a), (t1, b)) in anchored.iter().zip(&direct) {
            assert_eq!(t0, t1);
            assert!((a - b).abs() < 1e-9 * (1.0 + b), "{a} against {b} at {t0}");
        }
        assert!(
            direct.iter().any(|&(_, n)| n > 0.1),
            "the test needs errors"
        );
        // Without a common time there is nothing to compare.
        let later: BTreeMap<u64, Pose2> = [(100.0_f64.to_bits(), elsewhere)].into();
        assert!(anchored_pose_nees(&estimates, &later).is_empty());
    }

    #[test]
    fn the_band_of_the_mean_narrows_with_the_count() {
        // One value of 3 dof: the band of chi2(3) / 3.
        let [lo, hi] = mean_band_95(1, 1.0 / 3.0);
        assert!((lo - 0.2157952826238981 / 3.0).abs() < 1e-9, "{lo}");
        assert!((hi - 9.348403604496145 / 3.0).abs() < 1e-9, "{hi}");
        // Many values: about 1 +- 1.96 sqrt(2 / nu).
        let [lo, hi] = mean_band_95(10_000, 10_000.0 / 3.0);
        let half = 1.96 * (2.0_f64 / 30_000.0).sqrt();
        assert!((lo - (1.0 - half)).abs() < 1e-3 && (hi - (1.0 + half)).abs() < 1e-3);
        assert_eq!(mean_band_95(0, 0.0), [0.0, 0.0]);
        let summary = chi_square_summary(&[(3.0, 3), (6.0, 3)]).unwrap();
        assert!(
            summary.describe().starts_with("1.500 (95% band 0."),
            "{}",
            summary.describe()
        );
    }
}
