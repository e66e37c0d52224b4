//! Trajectory errors as the common tools compute them (`evo_ape tum GT EST -a`, `evo_rpe tum
//! GT EST`, TUM RGB-D `associate.py` / `evaluate_ate.py`):
//!
//! - **Association** ([`associate`]): estimate and ground-truth poses are matched by
//!   timestamp, nearest first, within `max_dt` seconds; each pose of either trajectory is used
//!   at most once (the greedy smallest-|dt|-first matching of TUM's `associate.py`).
//! - **Alignment** ([`alignment`], [`umeyama`]): `se3` (the default) is the least-squares rigid
//!   transform `p -> R p + t` taking the associated estimate positions onto the ground-truth
//!   positions (Umeyama 1991, the SVD form of Horn's closed-form solution, with the reflection
//!   fix `det R = +1`; no scale), as `evo_ape -a`; `sim3` adds a scale `p -> s R p + t`
//!   (Umeyama with scale, `evo_ape -as`); `none` compares the estimate as it is.
//! - **ATE** ([`ate`]): the statistics of `|g_i - (s R e_i + t)|` over the associated pairs,
//!   where `g_i` and `e_i` are the ground-truth and estimate positions (evo's APE of the
//!   translation part).
//! - **RPE** ([`rpe`]): for index pairs `(i, j)` of associated poses,
//!   `E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)` with `Q` ground truth and `P` the (aligned) estimate;
//!   the translational error is `|t(E)|` and the rotational error the rotation angle of `E`.
//!   With a frame delta `d` the pairs are `(0, d), (d, 2d), ...` (evo's default consecutive
//!   pairs) or, with `all_pairs`, every `(i, i + d)`; with a time delta the partner `j` of `i`
//!   is the first pose with `t_j >= t_i + delta`.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Matrix3, Vector3};
use slam_sensors::data::StampedPose;

use crate::error::{Result, RuntimeError};

/// How the estimate is aligned onto ground truth before the errors are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AlignMode {
    /// No alignment: the estimate is compared as it is.
    None,
    /// Least-squares rigid transform (rotation + translation; Umeyama 1991 without scale).
    Se3,
    /// Least-squares similarity transform (rotation + translation + scale; Umeyama 1991).
    Sim3,
}

impl AlignMode {
    /// The name used on the command line and in the output.
    pub fn name(self) -> &'static str {
        match self {
            AlignMode::None => "none",
            AlignMode::Se3 => "se3",
            AlignMode::Sim3 => "sim3",
        }
    }

    /// What the alignment is, in one line.
    pub fn description(self) -> &'static str {
        match self {
            AlignMode::None => "none: the estimate is compared as it is",
            AlignMode::Se3 => {
                "se3: least-squares rigid transform of the estimate onto ground truth \
                 (Umeyama 1991 / Horn; rotation + translation, no scale), as evo_ape -a"
            }
            AlignMode::Sim3 => {
                "sim3: least-squares similarity transform of the estimate onto ground truth \
                 (Umeyama 1991; rotation + translation + scale), as evo_ape -as"
            }
        }
    }
}

/// The RPE step between the two poses of a compared pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RpeDelta {
    /// A number of associated poses (at least 1).
    Frames(usize),
    /// A time, s (positive): the partner of pose `i` is the first pose `j` with
    /// `t_j >= t_i + delta`.
    Seconds(f64),
}

/// A similarity transform `p -> scale * rotation * p + translation` (scale 1 for a rigid one).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    /// Rotation (proper: determinant +1).
    pub rotation: Matrix3<f64>,
    /// Translation, m.
    pub translation: Vector3<f64>,
    /// Scale (1 unless estimated).
    pub scale: f64,
}

impl Alignment {
    /// The identity transform.
    pub fn identity() -> Self {
        Alignment {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// The transformed point `scale * rotation * p + translation`.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * p) + self.translation
    }
}

/// Statistics of a list of non-negative errors (as evo reports them; `std` is the population
/// standard deviation, `median` the mean of the two middle values for an even count).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Number of errors.
    pub count: usize,
}

impl ErrorStats {
    /// Whether every statistic is a finite number.
    pub fn is_finite(&self) -> bool {
        [
            self.rmse,
            self.mean,
            self.median,
            self.std,
            self.min,
            self.max,
        ]
        .iter()
        .all(|v| v.is_finite())
    }

    /// The statistics of `errors`; an empty list is an error.
    pub fn from_errors(errors: &[f64]) -> Result<Self> {
        if errors.is_empty() {
            return Err(RuntimeError::Eval(
                "no errors to summarize (no compared pose pairs)".into(),
            ));
        }
        let n = errors.len() as f64;
        let mean = errors.iter().sum::<f64>() / n;
        let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        let std = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let middle = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[middle]
        } else {
            0.5 * (sorted[middle - 1] + sorted[middle])
        };
        Ok(ErrorStats {
            rmse,
            mean,
            median,
            std,
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            count: errors.len(),
        })
    }
}

/// The absolute trajectory error: the alignment used and the statistics of the translation
/// errors `|g_i - alignment(e_i)|`, m.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ate {
    /// The transform applied to the estimate.
    pub alignment: Alignment,
    /// Translation errors after alignment, m.
    pub errors: ErrorStats,
}

/// The relative pose error.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RpeStats {
    /// Translational errors `|t(E)|`, m.
    pub translation_m: ErrorStats,
    /// Rotational errors, the rotation angle of `E`, degrees.
    pub rotation_deg: ErrorStats,
}

/// Matches estimate poses to ground-truth poses by timestamp: `(ground-truth index, estimate
/// index)` pairs with `|t_gt - t_est| <= max_dt`, each pose of either list used at most once,
/// chosen greedily smallest time difference first, as TUM's `associate.py` (an estimate
/// pose halfway between two ground-truth poses takes the earlier one). Sorted by estimate time. Empty when nothing matches
/// (including empty inputs or a negative or NaN `max_dt`). O(n log n).
pub fn associate(gt: &[StampedPose], est: &[StampedPose], max_dt: f64) -> Vec<(usize, usize)> {
    // All stamps in one sorted list. The closest unmatched (ground truth, estimate) pair is
    // always adjacent in the list of unmatched stamps, so a heap of adjacent pairs suffices.
    let mut items: Vec<(f64, bool, usize)> = gt
        .iter()
        .enumerate()
        .map(|(i, p)| (p.time, false, i))
        .chain(est.iter().enumerate().map(|(i, p)| (p.time, true, i)))
        .collect();
    items.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let n = items.len();
    let mut previous: Vec<Option<usize>> = (0..n).map(|k| k.checked_sub(1)).collect();
    let mut next: Vec<Option<usize>> = (0..n).map(|k| (k + 1 < n).then_some(k + 1)).collect();
    let mut unmatched = vec![true; n];
    // (|dt| as bits, ground-truth index, estimate index, list positions): for non-negative
    // floats the bit patterns order as the values.
    type Candidate = Reverse<(u64, usize, usize, usize, usize)>;
    let candidate = |a: usize, b: usize| -> Option<Candidate> {
        let (ta, a_is_est, ia) = items[a];
        let (tb, b_is_est, ib) = items[b];
        let dt = (tb - ta).abs();
        let within = dt <= max_dt; // false for NaN
        if a_is_est == b_is_est || !within {
            return None;
        }
        let (g, e) = if a_is_est { (ib, ia) } else { (ia, ib) };
        Some(Reverse((dt.to_bits(), g, e, a, b)))
    };
    let mut heap: BinaryHeap<Candidate> = (1..n).filter_map(|k| candidate(k - 1, k)).collect();
    let mut pairs = Vec::new();
    while let Some(Reverse((_, g, e, a, b))) = heap.pop() {
        // Positions are only ever removed, so a pair both of whose ends are unmatched is
        // still adjacent.
        if !(unmatched[a] && unmatched[b]) {
            continue;
        }
        unmatched[a] = false;
        unmatched[b] = false;
        pairs.push((g, e));
        let (left, right) = (previous[a], next[b]);
        if let Some(l) = left {
            next[l] = right;
        }
        if let Some(r) = right {
            previous[r] = left;
        }
        if let (Some(l), Some(r)) = (left, right)
            && let Some(c) = candidate(l, r)
        {
            heap.push(c);
        }
    }
    pairs.sort_by(|x, y| est[x.1].time.total_cmp(&est[y.1].time).then(x.1.cmp(&y.1)));
    pairs
}

/// Singular values below this fraction of the largest make the cross-covariance rank
/// deficient (collinear or coincident points).
const RANK_TOLERANCE: f64 = 1e-12;

/// The least-squares transform taking the points `from` onto the points `to` (Umeyama 1991):
/// minimizes `sum |to_i - (s R from_i + t)|^2` over rotations `R` (with the reflection fix,
/// so `det R = +1`), translations `t`, and, when `with_scale`, scales `s` (else `s = 1`).
/// Needs at least 3 pairs not all on one line (planar points are fine); otherwise, or for
/// lists of different lengths, an error.
pub fn umeyama(from: &[Vector3<f64>], to: &[Vector3<f64>], with_scale: bool) -> Result<Alignment> {
    if from.len() != to.len() {
        return Err(RuntimeError::Eval(format!(
            "alignment needs as many points on both sides, got {} and {}",
            from.len(),
            to.len()
        )));
    }
    let n = from.len();
    if n < 3 {
        return Err(RuntimeError::Eval(format!(
            "alignment needs at least 3 point pairs, got {n}"
        )));
    }
    let count = n as f64;
    let mean_from = from.iter().sum::<Vector3<f64>>() / count;
    let mean_to = to.iter().sum::<Vector3<f64>>() / count;
    let mut covariance = Matrix3::zeros();
    let mut variance_from = 0.0;
    for (a, b) in from.iter().zip(to) {
        let (da, db) = (a - mean_from, b - mean_to);
        covariance += db * da.transpose();
        variance_from += da.norm_squared();
    }
    covariance /= count;
    variance_from /= count;
    if !(covariance.iter().all(|v| v.is_finite()) && variance_from.is_finite()) {
        let largest = from.iter().chain(to).map(|p| p.amax()).fold(0.0, f64::max);
        return Err(RuntimeError::Eval(format!(
            "the sums of squares of the coordinates overflow (coordinates up to {largest:e} m): \
             no alignment can be computed; check the values and units of the trajectories"
        )));
    }
    // The general (Golub-Kahan) SVD of a dynamic matrix, singular values descending.
    // nalgebra's special path for `Matrix3` goes through the eigenvectors of
    // `covariance^T covariance`, which squares the condition number: for a nearly straight
    // trajectory (d[1] / d[0] = 1e-6) its rotation is off by 1e-4, this one by 1e-10.
    let svd = DMatrix::from_iterator(3, 3, covariance.iter().copied())
        .try_svd(true, true, f64::EPSILON, 0)
        .ok_or_else(|| RuntimeError::Eval("alignment failed: the SVD did not converge".into()))?;
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(RuntimeError::Eval(
            "alignment failed: the SVD gave no singular vectors".into(),
        ));
    };
    let d = Vector3::from_iterator(svd.singular_values.iter().copied());
    let u: Matrix3<f64> = u.fixed_view::<3, 3>(0, 0).into_owned();
    let v_t: Matrix3<f64> = v_t.fixed_view::<3, 3>(0, 0).into_owned();
    if !(d[0] > 0.0 && d[1] > RANK_TOLERANCE * d[0]) {
        return Err(RuntimeError::Eval(
            "alignment is not determined: the points are all on one line (or coincide), \
             so the rotation about that line is ambiguous"
                .into(),
        ));
    }
    // Reflection fix: the best proper rotation. With d[2] = 0 (planar points) the sign of the
    // third singular vectors is arbitrary, and this makes the product well defined.
    let mut signs = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        signs[2] = -1.0;
    }
    let rotation = u * Matrix3::from_diagonal(&signs) * v_t;
    let scale = if with_scale {
        d.dot(&signs) / variance_from
    } else {
        1.0
    };
    Ok(Alignment {
        rotation,
        translation: mean_to - scale * (rotation * mean_from),
        scale,
    })
}

/// The associated poses, checking the indices.
fn matched<'a>(
    gt: &'a [StampedPose],
    est: &'a [StampedPose],
    pairs: &[(usize, usize)],
) -> Result<Vec<(&'a StampedPose, &'a StampedPose)>> {
    if pairs.is_empty() {
        return Err(RuntimeError::Eval("no associated pose pairs".into()));
    }
    pairs
        .iter()
        .map(|&(g, e)| match (gt.get(g), est.get(e)) {
            (Some(a), Some(b)) => Ok((a, b)),
            _ => Err(RuntimeError::Eval(format!(
                "pose pair ({g}, {e}) out of range ({} ground-truth, {} estimate poses)",
                gt.len(),
                est.len()
            ))),
        })
        .collect()
}

/// The transform of `mode` taking the associated estimate positions onto the ground-truth
/// positions ([`umeyama`]; the identity for [`AlignMode::None`]).
pub fn alignment(
    gt: &[StampedPose],
    est: &[StampedPose],
    pairs: &[(usize, usize)],
    mode: AlignMode,
) -> Result<Alignment> {
    let poses = matched(gt, est, pairs)?;
    let with_scale = match mode {
        AlignMode::None => return Ok(Alignment::identity()),
        AlignMode::Se3 => false,
        AlignMode::Sim3 => true,
    };
    let from: Vec<_> = poses.iter().map(|(_, e)| e.pose.translation).collect();
    let to: Vec<_> = poses.iter().map(|(g, _)| g.pose.translation).collect();
    umeyama(&from, &to, with_scale).map_err(|error| {
        RuntimeError::Eval(format!(
            "{} alignment of the estimate onto ground truth over {} associated poses: {error}",
            mode.name(),
            pairs.len()
        ))
    })
}

/// The absolute trajectory error over the associated `pairs` (from [`associate`]): the
/// estimate is aligned onto ground truth by [`alignment`] with `mode`, then the statistics of
/// the position errors `|g_i - (s R e_i + t)|`, m, are taken (evo's APE, translation part).
pub fn ate(
    gt: &[StampedPose],
    est: &[StampedPose],
    pairs: &[(usize, usize)],
    mode: AlignMode,
) -> Result<Ate> {
    let alignment = alignment(gt, est, pairs, mode)?;
    let errors: Vec<f64> = matched(gt, est, pairs)?
        .iter()
        .map(|(g, e)| (g.pose.translation - alignment.apply(&e.pose.translation)).norm())
        .collect();
    Ok(Ate {
        alignment,
        errors: ErrorStats::from_errors(&errors)?,
    })
}

/// The index pairs `(i, j)` into a time-sorted sequence compared by the RPE.
fn rpe_index_pairs(times: &[f64], delta: RpeDelta, all_pairs: bool) -> Vec<(usize, usize)> {
    let n = times.len();
    match delta {
        RpeDelta::Frames(d) => {
            let d = d.max(1);
            if all_pairs {
                (0..n.saturating_sub(d)).map(|i| (i, i + d)).collect()
            } else {
                (0..n).step_by(d).zip((d..n).step_by(d)).collect()
            }
        }
        RpeDelta::Seconds(dt) => {
            let partner = |i: usize| {
                let target = times[i] + dt;
                let j = i + 1 + times[i + 1..].partition_point(|&t| t < target);
                (j < n).then_some(j)
            };
            let mut pairs = Vec::new();
            if all_pairs {
                pairs.extend((0..n).filter_map(|i| partner(i).map(|j| (i, j))));
            } else {
                let mut i = 0;
                while i < n {
                    let Some(j) = partner(i) else { break };
                    pairs.push((i, j));
                    i = j;
                }
            }
            pairs
        }
    }
}

/// The rotation angle of a rotation matrix, radians in `[0, pi]` (accurate near 0 and pi).
fn rotation_angle(r: &Matrix3<f64>) -> f64 {
    let twice_sin = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    )
    .norm();
    let twice_cos = r.trace() - 1.0;
    twice_sin.atan2(twice_cos)
}

/// The relative pose error over the associated `pairs` (from [`associate`], sorted by time).
/// The estimate poses `P` are first transformed by `alignment` (`R -> R_a R`,
/// `t -> s R_a t + t_a`; only the scale changes the result). For each compared pair `(i, j)`
/// of associated poses (see [`RpeDelta`]; `all_pairs` false gives evo's default consecutive,
/// non-overlapping pairs), `E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)` with `Q` ground truth; the
/// statistics are those of `|t(E)|`, m, and of the rotation angle of `E`, degrees. Pair
/// selection uses the estimate times. No compared pair is an error.
pub fn rpe(
    gt: &[StampedPose],
    est: &[StampedPose],
    pairs: &[(usize, usize)],
    alignment: &Alignment,
    delta: RpeDelta,
    all_pairs: bool,
) -> Result<RpeStats> {
    match delta {
        RpeDelta::Frames(0) => {
            return Err(RuntimeError::Eval(
                "RPE delta must be at least 1 frame".into(),
            ));
        }
        RpeDelta::Seconds(dt) if !(dt.is_finite() && dt > 0.0) => {
            return Err(RuntimeError::Eval(format!(
                "RPE delta must be a positive time, got {dt} s"
            )));
        }
        _ => {}
    }
    let poses = matched(gt, est, pairs)?;
    let times: Vec<f64> = poses.iter().map(|(_, e)| e.time).collect();
    let index_pairs = rpe_index_pairs(&times, delta, all_pairs);
    if index_pairs.is_empty() {
        let span = times.last().copied().unwrap_or(0.0) - times.first().copied().unwrap_or(0.0);
        let asked = match delta {
            RpeDelta::Frames(d) => format!("{d} frames"),
            RpeDelta::Seconds(dt) => format!("{dt} s"),
        };
        return Err(RuntimeError::Eval(format!(
            "RPE: no two of the {} associated poses (spanning {span} s) are {asked} apart; \
             use a smaller --delta",
            poses.len()
        )));
    }
    let ground_truth: Vec<(Matrix3<f64>, Vector3<f64>)> = poses
        .iter()
        .map(|(g, _)| (g.pose.rotation(), g.pose.translation))
        .collect();
    let estimate: Vec<(Matrix3<f64>, Vector3<f64>)> = poses
        .iter()
        .map(|(_, e)| {
            (
                alignment.rotation * e.pose.rotation(),
                alignment.apply(&e.pose.translation),
            )
        })
        .collect();
    // a^-1 b for poses (R, t).
    let between = |a: &(Matrix3<f64>, Vector3<f64>), b: &(Matrix3<f64>, Vector3<f64>)| {
        (a.0.transpose() * b.0, a.0.transpose() * (b.1 - a.1))
    };
    let mut translation = Vec::with_capacity(index_pairs.len());
    let mut rotation = Vec::with_capacity(index_pairs.len());
    for &(i, j) in &index_pairs {
        let q = between(&ground_truth[i], &ground_truth[j]);
        let p = between(&estimate[i], &estimate[j]);
        let (r_e, t_e) = between(&q, &p);
        translation.push(t_e.norm());
        rotation.push(rotation_angle(&r_e).to_degrees());
    }
    Ok(RpeStats {
        translation_m: ErrorStats::from_errors(&translation)?,
        rotation_deg: ErrorStats::from_errors(&rotation)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::Pose3;
    use slam_core::nalgebra::{Rotation3, Unit};

    fn stamped(time: f64, pose: Pose3) -> StampedPose {
        StampedPose { time, pose }
    }

    fn at(time: f64) -> StampedPose {
        stamped(time, Pose3::identity())
    }

    /// A non-planar trajectory: a helix with a varying attitude, 0.1 s apart.
    fn helix(n: usize) -> Vec<StampedPose> {
        (0..n)
            .map(|k| {
                let s = k as f64 * 0.1;
                let position = Vector3::new(3.0 * s.cos(), 2.0 * s.sin(), 0.3 * s);
                stamped(s, Pose3::new(position, s, 0.1 * s.sin(), 0.05 * s.cos()))
            })
            .collect()
    }

    /// A planar (z = 0) trajectory: a lopsided figure eight.
    fn planar(n: usize) -> Vec<StampedPose> {
        (0..n)
            .map(|k| {
                let s = k as f64 * 0.1;
                let position = Vector3::new(4.0 * s.sin() + 0.5 * s, 2.0 * (2.0 * s).sin(), 0.0);
                stamped(s, Pose3::new(position, 0.7 * s, 0.0, 0.0))
            })
            .collect()
    }

    /// `p -> scale * rotation * p + translation` applied to every pose.
    fn transformed(
        poses: &[StampedPose],
        scale: f64,
        rotation: &Matrix3<f64>,
        translation: &Vector3<f64>,
    ) -> Vec<StampedPose> {
        poses
            .iter()
            .map(|p| {
                let t = scale * (rotation * p.pose.translation) + translation;
                stamped(
                    p.time,
                    Pose3::from_rotation(t, &(rotation * p.pose.rotation())),
                )
            })
            .collect()
    }

    fn one_to_one(n: usize) -> Vec<(usize, usize)> {
        (0..n).map(|k| (k, k)).collect()
    }

    fn known_rotation() -> Matrix3<f64> {
        Rotation3::from_euler_angles(0.2, -0.3, 1.1).into_inner()
    }

    /// Deterministic standard normal samples (SplitMix64 and Box-Muller).
    struct Normal(u64);

    impl Normal {
        fn uniform(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }

        fn sample(&mut self) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    #[test]
    fn se3_alignment_recovers_a_known_rigid_transform() {
        let gt = helix(60);
        let (r0, t0) = (known_rotation(), Vector3::new(5.0, -2.0, 1.0));
        let est = transformed(&gt, 1.0, &r0, &t0);
        let pairs = one_to_one(gt.len());
        let result = ate(&gt, &est, &pairs, AlignMode::Se3).unwrap();
        assert!(result.errors.rmse < 1e-9, "{:?}", result.errors);
        assert_eq!(result.errors.count, 60);
        // The alignment takes the estimate back: the inverse of (r0, t0).
        let a = result.alignment;
        assert!((a.rotation - r0.transpose()).amax() < 1e-12);
        assert!((a.translation + r0.transpose() * t0).amax() < 1e-12);
        assert_eq!(a.scale, 1.0);
        assert!((a.rotation.determinant() - 1.0).abs() < 1e-12);
        let unaligned = ate(&gt, &est, &pairs, AlignMode::None).unwrap();
        assert_eq!(unaligned.alignment, Alignment::identity());
        assert!(unaligned.errors.rmse > 1.0);
    }

    #[test]
    fn sim3_alignment_recovers_a_known_scale() {
        let gt = helix(40);
        let (r0, t0) = (known_rotation(), Vector3::new(-1.0, 0.5, 3.0));
        let est = transformed(&gt, 2.5, &r0, &t0);
        let pairs = one_to_one(gt.len());
        let sim3 = ate(&gt, &est, &pairs, AlignMode::Sim3).unwrap();
        assert!(sim3.errors.rmse < 1e-9, "{:?}", sim3.errors);
        assert!((sim3.alignment.scale - 0.4).abs() < 1e-12);
        assert!((sim3.alignment.rotation - r0.transpose()).amax() < 1e-12);
        assert!((sim3.alignment.translation + 0.4 * r0.transpose() * t0).amax() < 1e-12);
        let se3 = ate(&gt, &est, &pairs, AlignMode::Se3).unwrap();
        assert!(se3.errors.rmse > 0.5);
    }

    #[test]
    fn ate_of_noise_is_the_rmse_after_the_best_alignment() {
        let gt = helix(200);
        let (r0, t0) = (known_rotation(), Vector3::new(5.0, -2.0, 1.0));
        let mut noise = Normal(7);
        let mut est = transformed(&gt, 1.0, &r0, &t0);
        let mut noise_sq = 0.0;
        for p in &mut est {
            let n = Vector3::new(noise.sample(), noise.sample(), noise.sample()) * 0.05;
            noise_sq += n.norm_squared();
            p.pose.translation += n;
        }
        let noise_rms = (noise_sq / est.len() as f64).sqrt();
        let pairs = one_to_one(gt.len());
        let result = ate(&gt, &est, &pairs, AlignMode::Se3).unwrap();
        let a = result.alignment;
        let sse = |a: &Alignment| -> f64 {
            gt.iter()
                .zip(&est)
                .map(|(g, e)| (g.pose.translation - a.apply(&e.pose.translation)).norm_squared())
                .sum()
        };
        let direct = (sse(&a) / gt.len() as f64).sqrt();
        assert!((result.errors.rmse - direct).abs() < 1e-12);
        // The true transform is one candidate, so the best one does at least as well, and
        // with 200 poses not much better.
        assert!(result.errors.rmse <= noise_rms && result.errors.rmse > 0.9 * noise_rms);
        // Small changes of the alignment only make it worse.
        for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
            for step in [-1e-3, 1e-3] {
                let turned = Alignment {
                    rotation: Rotation3::from_axis_angle(&axis, step).into_inner() * a.rotation,
                    ..a
                };
                let shifted = Alignment {
                    translation: a.translation + axis.into_inner() * step,
                    ..a
                };
                assert!(sse(&turned) > sse(&a) && sse(&shifted) > sse(&a));
            }
        }
        let s = result.errors;
        assert!(s.min <= s.median && s.median <= s.max && s.min <= s.mean && s.mean <= s.max);
        assert!((s.rmse.powi(2) - (s.mean.powi(2) + s.std.powi(2))).abs() < 1e-12);
    }

    #[test]
    fn offsets_that_alignment_cannot_remove() {
        // A circle of radius 2 against one of radius 2.1 (planar, z = 0): no rigid motion
        // brings them closer than 0.1 m everywhere; a scale does.
        let circle = |r: f64| -> Vec<StampedPose> {
            (0..36)
                .map(|k| {
                    let a = k as f64 * std::f64::consts::TAU / 36.0;
                    stamped(
                        k as f64,
                        Pose3::new(Vector3::new(r * a.cos(), r * a.sin(), 0.0), a, 0.0, 0.0),
                    )
                })
                .collect()
        };
        let (gt, est) = (circle(2.0), circle(2.1));
        let pairs = one_to_one(36);
        let se3 = ate(&gt, &est, &pairs, AlignMode::Se3).unwrap();
        assert!((se3.alignment.rotation - Matrix3::identity()).amax() < 1e-12);
        assert!(se3.alignment.translation.amax() < 1e-12);
        let s = se3.errors;
        for value in [s.rmse, s.mean, s.median, s.min, s.max] {
            assert!((value - 0.1).abs() < 1e-12, "{s:?}");
        }
        assert!(s.std < 1e-12);
        let sim3 = ate(&gt, &est, &pairs, AlignMode::Sim3).unwrap();
        assert!(sim3.errors.rmse < 1e-12);
        assert!((sim3.alignment.scale - 2.0 / 2.1).abs() < 1e-12);
        // Without alignment a constant offset stays.
        let shifted = transformed(&gt, 1.0, &Matrix3::identity(), &Vector3::new(0.0, 0.1, 0.0));
        let none = ate(&gt, &shifted, &pairs, AlignMode::None).unwrap();
        assert!((none.errors.rmse - 0.1).abs() < 1e-12 && none.errors.std < 1e-12);
        assert!(
            ate(&gt, &shifted, &pairs, AlignMode::Se3)
                .unwrap()
                .errors
                .rmse
                < 1e-12
        );
    }

    #[test]
    fn planar_trajectories_give_a_proper_rotation() {
        let gt = planar(80);
        let yaw = Rotation3::from_euler_angles(0.0, 0.0, 0.7).into_inner();
        let t0 = Vector3::new(1.0, -3.0, 0.0);
        let est = transformed(&gt, 1.0, &yaw, &t0);
        let pairs = one_to_one(gt.len());
        let result = ate(&gt, &est, &pairs, AlignMode::Se3).unwrap();
        assert!(result.errors.rmse < 1e-9);
        // Not diag(1, 1, -1) times it: the reflection fix picks the proper rotation even
        // though the third singular value is zero.
        assert!((result.alignment.rotation - yaw.transpose()).amax() < 1e-12);
        // Identical planar trajectories: the identity, not a mirror through the plane.
        let same = ate(&gt, &gt, &pairs, AlignMode::Se3).unwrap();
        assert!((same.alignment.rotation - Matrix3::identity()).amax() < 1e-12);
        // A planar mirror image is undone by a half turn about an axis in the plane.
        let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0));
        let mirror = transformed(&gt, 1.0, &flip, &Vector3::zeros());
        let mirrored = ate(&gt, &mirror, &pairs, AlignMode::Se3).unwrap();
        assert!(mirrored.errors.rmse < 1e-9);
        let half_turn = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
        assert!((mirrored.alignment.rotation - half_turn).amax() < 1e-12);
        // A non-planar mirror image is not: still a proper rotation, and a large error.
        let helix = helix(60);
        let mirror = transformed(&helix, 1.0, &flip, &Vector3::zeros());
        let mirrored = ate(&helix, &mirror, &one_to_one(60), AlignMode::Se3).unwrap();
        assert!((mirrored.alignment.rotation.determinant() - 1.0).abs() < 1e-12);
        assert!(mirrored.errors.rmse > 0.5, "{:?}", mirrored.errors);
    }

    #[test]
    fn nearly_straight_trajectories_keep_an_accurate_rotation() {
        // 100 m along x with 4 cm wiggles: the second singular value is ~1e-6 of the first.
        let gt: Vec<_> = (0..500)
            .map(|k| {
                let x = k as f64 * 0.2;
                let position = Vector3::new(x, 0.04 * (0.5 * x).sin(), 0.03 * (0.3 * x).cos());
                stamped(k as f64, Pose3::new(position, 0.0, 0.0, 0.0))
            })
            .collect();
        let (r0, t0) = (known_rotation(), Vector3::new(5.0, -2.0, 1.0));
        let est = transformed(&gt, 1.0, &r0, &t0);
        let result = ate(&gt, &est, &one_to_one(500), AlignMode::Se3).unwrap();
        assert!((result.alignment.rotation - r0.transpose()).amax() < 1e-8);
        assert!(result.errors.rmse < 1e-8, "{:?}", result.errors);
    }

    #[test]
    fn degenerate_alignments_are_errors() {
        let gt = helix(10);
        let two = one_to_one(2);
        let error = ate(&gt, &gt, &two, AlignMode::Se3).unwrap_err().to_string();
        assert!(
            error.contains("at least 3") && error.contains("se3 alignment"),
            "{error}"
        );
        assert!(ate(&gt, &gt, &two, AlignMode::None).is_ok());
        let line: Vec<_> = (0..10)
            .map(|k| {
                stamped(
                    k as f64,
                    Pose3::new(Vector3::new(1.0, 2.0, 3.0) * k as f64, 0.0, 0.0, 0.0),
                )
            })
            .collect();
        let error = ate(&line, &line, &one_to_one(10), AlignMode::Sim3)
            .unwrap_err()
            .to_string();
        assert!(error.contains("one line"), "{error}");
        let points = [Vector3::zeros(); 4];
        assert!(umeyama(&points, &points, false).is_err());
        assert!(umeyama(&points[..3], &points, false).is_err());
        assert!(ate(&gt, &gt, &[], AlignMode::None).is_err());
        assert!(ate(&gt, &gt, &[(0, 10)], AlignMode::None).is_err());
        assert!(ErrorStats::from_errors(&[]).is_err());
    }

    #[test]
    fn association_takes_the_nearest_within_max_dt_once() {
        let gt: Vec<_> = [0.0, 0.1, 0.2, 0.3, 0.4].into_iter().map(at).collect();
        let est: Vec<_> = [0.004, 0.098, 0.103, 0.215, 0.35, 0.5]
            .into_iter()
            .map(at)
            .collect();
        // 0.103 also wants ground truth 0.1, which 0.098 has, closer; 0.215 is too far.
        assert_eq!(associate(&gt, &est, 0.01), vec![(0, 0), (1, 1)]);
        assert_eq!(associate(&gt, &est, 0.02), vec![(0, 0), (1, 1), (2, 3)]);
        // A wider window: 0.35 is as far from 0.3 as from 0.4 (up to rounding) and takes 0.3;
        // 0.103 stays unmatched (0.2 is 0.097 away) and 0.5 is 0.1 from 0.4.
        assert_eq!(
            associate(&gt, &est, 0.06),
            vec![(0, 0), (1, 1), (2, 3), (3, 4)]
        );
        assert_eq!(associate(&gt, &est, 0.1)[3..], [(3, 4), (4, 5)]);
        // Unsorted estimates: the same matches, in time order.
        let reversed: Vec<_> = est.iter().rev().copied().collect();
        assert_eq!(associate(&gt, &reversed, 0.01), vec![(0, 5), (1, 4)]);
        assert!(associate(&gt, &[], 0.01).is_empty());
        assert!(associate(&[], &est, 0.01).is_empty());
        assert!(associate(&gt, &est, -1.0).is_empty());
        assert!(associate(&gt, &est, f64::NAN).is_empty());
    }

    #[test]
    fn association_equals_the_brute_force_greedy_matching() {
        let mut noise = Normal(3);
        for round in 0..20 {
            let gt: Vec<_> = (0..40).map(|_| at(noise.uniform() * 4.0)).collect();
            let est: Vec<_> = (0..30).map(|_| at(noise.uniform() * 4.0)).collect();
            let max_dt = 0.05 * (round % 5) as f64;
            let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
            for (g, a) in gt.iter().enumerate() {
                for (e, b) in est.iter().enumerate() {
                    let dt = (a.time - b.time).abs();
                    if dt <= max_dt {
                        candidates.push((dt, g, e));
                    }
                }
            }
            candidates.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
            let (mut gt_used, mut est_used) = (vec![false; gt.len()], vec![false; est.len()]);
            let mut expected = Vec::new();
            for (_, g, e) in candidates {
                if !gt_used[g] && !est_used[e] {
                    gt_used[g] = true;
                    est_used[e] = true;
                    expected.push((g, e));
                }
            }
            expected.sort_by(|x, y| est[x.1].time.total_cmp(&est[y.1].time).then(x.1.cmp(&y.1)));
            assert_eq!(associate(&gt, &est, max_dt), expected, "round {round}");
        }
    }

    /// Ground truth: 1 m steps along x, 0.5 s apart. Estimate: each step 1.1 m along the
    /// body x axis and a 0.01 rad turn, so every one-step error is 0.1 m and 0.01 rad.
    fn drifting(n: usize) -> (Vec<StampedPose>, Vec<StampedPose>) {
        let gt = (0..n)
            .map(|k| {
                stamped(
                    0.5 * k as f64,
                    Pose3::new(Vector3::new(k as f64, 0.0, 0.0), 0.0, 0.0, 0.0),
                )
            })
            .collect();
        let step = Rotation3::from_euler_angles(0.0, 0.0, 0.01).into_inner();
        let (mut rotation, mut position) = (Matrix3::identity(), Vector3::zeros());
        let mut est = Vec::new();
        for k in 0..n {
            est.push(stamped(
                0.5 * k as f64,
                Pose3::from_rotation(position, &rotation),
            ));
            position += rotation * Vector3::new(1.1, 0.0, 0.0);
            rotation *= step;
        }
        (gt, est)
    }

    #[test]
    fn rpe_of_a_constant_drift_per_step() {
        let (gt, est) = drifting(11);
        let pairs = one_to_one(11);
        let identity = Alignment::identity();
        let one = rpe(&gt, &est, &pairs, &identity, RpeDelta::Frames(1), false).unwrap();
        assert_eq!(one.translation_m.count, 10);
        for value in [
            one.translation_m.rmse,
            one.translation_m.median,
            one.translation_m.max,
        ] {
            assert!((value - 0.1).abs() < 1e-12, "{one:?}");
        }
        let degrees = 0.01f64.to_degrees();
        for value in [
            one.rotation_deg.rmse,
            one.rotation_deg.mean,
            one.rotation_deg.max,
        ] {
            assert!((value - degrees).abs() < 1e-10, "{one:?}");
        }
        // A rigid alignment changes nothing.
        // (The ground truth is a straight line, so se3 alignment itself is undetermined.)
        let se3 = Alignment {
            rotation: known_rotation(),
            translation: Vector3::new(3.0, -1.0, 2.0),
            scale: 1.0,
        };
        let aligned = rpe(&gt, &est, &pairs, &se3, RpeDelta::Frames(1), false).unwrap();
        assert!((aligned.translation_m.rmse - 0.1).abs() < 1e-12);
        assert!((aligned.rotation_deg.rmse - degrees).abs() < 1e-10);
        // Two steps: (0, 2), (2, 4), ..., (8, 10).
        let two_steps = Vector3::new(1.1, 0.0, 0.0)
            + Rotation3::from_euler_angles(0.0, 0.0, 0.01) * Vector3::new(1.1, 0.0, 0.0);
        let two_error: f64 = (two_steps - Vector3::new(2.0, 0.0, 0.0)).norm();
        let two = rpe(&gt, &est, &pairs, &identity, RpeDelta::Frames(2), false).unwrap();
        assert_eq!(two.translation_m.count, 5);
        assert!((two.translation_m.rmse - two_error).abs() < 1e-12);
        assert!((two.rotation_deg.max - 0.02f64.to_degrees()).abs() < 1e-10);
        let all = rpe(&gt, &est, &pairs, &identity, RpeDelta::Frames(2), true).unwrap();
        assert_eq!(all.translation_m.count, 9);
        assert!((all.translation_m.max - two_error).abs() < 1e-12);
        // One second is two poses.
        for seconds in [1.0, 0.9] {
            let timed = rpe(
                &gt,
                &est,
                &pairs,
                &identity,
                RpeDelta::Seconds(seconds),
                false,
            )
            .unwrap();
            assert_eq!(timed, two);
        }
        assert_eq!(
            rpe_index_pairs(&[0.0, 0.5, 1.0, 1.5, 2.0], RpeDelta::Seconds(0.9), true),
            vec![(0, 2), (1, 3), (2, 4)]
        );
        // A scale multiplies the estimated steps: 2.2 m against 1 m.
        let scaled = Alignment {
            scale: 2.0,
            ..identity
        };
        let big = rpe(&gt, &est, &pairs, &scaled, RpeDelta::Frames(1), false).unwrap();
        assert!((big.translation_m.rmse - 1.2).abs() < 1e-12);
        // Nothing to compare.
        let error = rpe(
            &gt,
            &est,
            &pairs,
            &identity,
            RpeDelta::Seconds(100.0),
            false,
        )
        .unwrap_err();
        assert!(error.to_string().contains("smaller --delta"), "{error}");
        assert!(rpe(&gt, &est, &pairs, &identity, RpeDelta::Frames(11), false).is_err());
        assert!(rpe(&gt, &est, &pairs, &identity, RpeDelta::Frames(0), false).is_err());
        assert!(
            rpe(
                &gt,
                &est,
                &pairs,
                &identity,
                RpeDelta::Seconds(f64::NAN),
                false
            )
            .is_err()
        );
    }

    #[test]
    fn rotation_angle_is_accurate_near_zero_and_pi() {
        for angle in [1e-9, 1e-4, 1.0, 3.0, std::f64::consts::PI - 1e-7] {
            let r = Rotation3::from_axis_angle(
                &Unit::new_normalize(Vector3::new(1.0, 2.0, -0.5)),
                angle,
            );
            let got = rotation_angle(r.matrix());
            assert!(
                (got - angle).abs() <= 1e-6 * angle.min(1e-6),
                "{angle} {got}"
            );
        }
        assert_eq!(rotation_angle(&Matrix3::identity()), 0.0);
    }

    #[test]
    fn error_stats_match_hand_computed_values() {
        let s = ErrorStats::from_errors(&[4.0, 1.0, 3.0, 2.0]).unwrap();
        assert_eq!(
            (s.mean, s.median, s.min, s.max, s.count),
            (2.5, 2.5, 1.0, 4.0, 4)
        );
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15 && (s.std - 1.25f64.sqrt()).abs() < 1e-15);
        assert_eq!(
            ErrorStats::from_errors(&[3.0, 1.0, 2.0]).unwrap().median,
            2.0
        );
    }
}
