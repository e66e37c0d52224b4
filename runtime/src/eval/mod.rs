//! Evaluation anyone can call: trajectory errors (ATE, RPE, [`trajectory`]), consistency
//! (NEES, NIS, [`ChiSquareSummary`]) and map error ([`map_error_against_truth`],
//! [`map_error_against_landmarks`]) and map quality without truth ([`map_quality`],
//! [`close_landmarks`], [`revisit_consistency`]), ceiling lines found in images against the true ones
//! ([`image_lines`]), as functions of plain data (the metrics of a whole run,
//! `metrics.json`, are [`crate::RunMetrics`]).

mod close;
mod consistency;
pub mod image_lines;
mod map;
mod map_quality;
mod revisits;
pub mod trajectory;

use std::collections::BTreeMap;

use serde::Serialize;
use slam_core::Pose2;
use slam_core::nalgebra::{Vector2, Vector3};
use slam_sensors::TruthKind;
use slam_sensors::data::StampedPose;

use crate::error::Result;

pub use close::{CloseLandmarks, close_landmarks};
pub use consistency::{
    ChiSquareAccumulator, ChiSquareSummary, Record, anchored_pose_nees, chi_square_summary,
    mean_band_95, pose_nees, singular_steps,
};
pub use map::{
    MapError, anchor_covariance, confirmed, coordinate_covariance, feature_counts,
    map_error_against_landmarks, map_error_against_truth, shared_dims,
};
pub(crate) use map_quality::SegmentGrid;
pub use map_quality::{
    DEFAULT_SAMPLE_SIZE, DOUBLED_ANGLE_DEG, DOUBLED_DISTANCE_M, MapQuality, ScanSample,
    confirmed_wall_segments, map_quality, wall_segments,
};
pub use revisits::{
    REVISIT_GAP_M, REVISIT_LINE_RATIO, REVISIT_MAX_MEASURED, REVISIT_MIN_NEIGHBOURS,
    REVISIT_RADIUS_M, RevisitConsistency, revisit_consistency,
};
pub use trajectory::{AlignMode, Alignment, ErrorStats, associate, ate, umeyama};

/// The value at fraction `q` (0 to 1) of `sorted` (ascending), by the nearest rank
/// (`round((n - 1) q)`); `None` when it is empty.
pub(crate) fn nearest_rank(sorted: &[f64], q: f64) -> Option<f64> {
    let last = sorted.len().checked_sub(1)?;
    sorted.get(((last as f64) * q).round() as usize).copied()
}

/// The trajectory errors of a run against its ground truth (or reference) poses.
#[derive(Clone, Debug, Serialize)]
pub struct TrajectoryErrors {
    /// ATE after the least-squares rigid alignment (Umeyama, no scale; `evo_ape -a`), m.
    pub ate_rmse_m: f64,
    /// ATE without alignment, m.
    pub ate_rmse_unaligned_m: f64,
    /// Full statistics of the aligned ATE.
    pub ate: ErrorStats,
    /// Whether the poses compared against are independent truth or another system's output.
    pub against: &'static str,
    /// The alignment of the estimate onto the references.
    #[serde(skip)]
    pub alignment: Alignment,
    /// Reference fixes left out as jumps of the receiver ([`gps_jumps`]); 0 against poses.
    pub reference_rejected: usize,
}

/// The fastest a ground vehicle's GPS antenna is taken to move, m/s (72 km/h): a fix reached
/// and left faster than this is the receiver's jump ([`gps_jumps`]).
pub const GPS_MAX_SPEED_MPS: f64 = 20.0;

/// Which GPS fixes are jumps of the receiver, not motion of the vehicle: a fix reached from
/// its predecessor and left for its successor both faster than [`GPS_MAX_SPEED_MPS`], while
/// the predecessor and the successor are within that speed of each other (the fix is off on
/// its own and the path comes back). Decided from the fixes alone, never from an estimate.
/// Victoria Park's receiver "was failing": one of its 4466 fixes lies 141 m from both
/// neighbours, reached at 64 m/s and left at 28 m/s.
///
/// ```
/// use slam_runtime::eval::gps_jumps;
/// use slam_core::nalgebra::Vector2;
/// let fixes: Vec<(f64, Vector2<f64>)> = [(0.0, 0.0), (1.0, 1.0), (2.0, 140.0), (3.0, 3.0), (4.0, 4.0)]
///     .iter()
///     .map(|&(t, x)| (t, Vector2::new(x, 0.0)))
///     .collect();
/// assert_eq!(gps_jumps(&fixes), vec![false, false, true, false, false]);
/// ```
pub fn gps_jumps(fixes: &[(f64, Vector2<f64>)]) -> Vec<bool> {
    let speed = |a: &(f64, Vector2<f64>), b: &(f64, Vector2<f64>)| {
        let dt = (b.0 - a.0).abs();
        let distance = (b.1 - a.1).norm();
        if dt > 0.0 {
            distance / dt
        } else if distance > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    };
    (0..fixes.len())
        .map(|i| {
            if i == 0 || i + 1 >= fixes.len() {
                return false;
            }
            let (before, fix, after) = (&fixes[i - 1], &fixes[i], &fixes[i + 1]);
            speed(before, fix) > GPS_MAX_SPEED_MPS
                && speed(fix, after) > GPS_MAX_SPEED_MPS
                && speed(before, after) <= GPS_MAX_SPEED_MPS
        })
        .collect()
}

/// Stamped 3-D poses (z = 0) of `(time, pose)` pairs.
pub fn stamped(poses: impl IntoIterator<Item = (f64, Pose2)>) -> Vec<StampedPose> {
    poses
        .into_iter()
        .map(|(time, pose)| StampedPose {
            time,
            pose: pose.to_pose3(0.0),
        })
        .collect()
}

/// The independent true poses among `truth`, by the bits of their time.
pub fn true_poses(truth: &[(f64, Pose2, TruthKind)]) -> BTreeMap<u64, Pose2> {
    poses_of_kind(truth, TruthKind::True)
}

/// The reference poses (another system's estimate, [`TruthKind::Reference`]) of a run by the
/// bits of their times.
pub fn reference_poses(truth: &[(f64, Pose2, TruthKind)]) -> BTreeMap<u64, Pose2> {
    poses_of_kind(truth, TruthKind::Reference)
}

fn poses_of_kind(truth: &[(f64, Pose2, TruthKind)], kind: TruthKind) -> BTreeMap<u64, Pose2> {
    truth
        .iter()
        .filter(|(_, _, k)| *k == kind)
        .map(|(t, p, _)| (t.to_bits(), *p))
        .collect()
}

/// ATE of `est` against a run's truth poses (`True` preferred, else `Reference`, else the
/// GPS fixes `gps`, paired within half a second); `None` when fewer than 3 poses pair. Against
/// GPS fixes the estimate's point compared is the antenna's, `gps_antenna` in the robot frame
/// ([`slam_sensors::DatasetInfo::gps_antenna`]).
pub fn path_errors(
    truth: &[(f64, Pose2, TruthKind)],
    gps: &[(f64, Vector2<f64>)],
    gps_antenna: &Vector2<f64>,
    est: &[StampedPose],
) -> Result<Option<TrajectoryErrors>> {
    let of_kind = |kind: TruthKind| -> Vec<StampedPose> {
        stamped(
            truth
                .iter()
                .filter(|(_, _, k)| *k == kind)
                .map(|(t, p, _)| (*t, *p)),
        )
    };
    let jumps = gps_jumps(gps);
    let gps_rejected = jumps.iter().filter(|&&jump| jump).count();
    let gps: Vec<StampedPose> = gps
        .iter()
        .zip(&jumps)
        .filter(|(_, jump)| !**jump)
        .map(|((t, p), _)| StampedPose {
            time: *t,
            pose: slam_core::Pose3::new(Vector3::new(p.x, p.y, 0.0), 0.0, 0.0, 0.0),
        })
        .collect();
    let antenna = slam_core::Pose3::new(
        Vector3::new(gps_antenna.x, gps_antenna.y, 0.0),
        0.0,
        0.0,
        0.0,
    );
    let at_antenna: Vec<StampedPose>;
    let (gt, against, max_dt, est, reference_rejected) = match of_kind(TruthKind::True) {
        gt if !gt.is_empty() => (gt, "ground truth", 1e-6, est, 0),
        _ => match of_kind(TruthKind::Reference) {
            reference if !reference.is_empty() => {
                (reference, "reference poses of the data", 1e-6, est, 0)
            }
            _ => {
                at_antenna = est
                    .iter()
                    .map(|s| StampedPose {
                        time: s.time,
                        pose: s.pose.compose(&antenna),
                    })
                    .collect();
                let against = if gps_rejected > 0 {
                    "GPS fixes (positions only; the receiver's jumps left out)"
                } else {
                    "GPS fixes (positions only)"
                };
                (gps, against, 0.5, &at_antenna[..], gps_rejected)
            }
        },
    };
    if gt.len() < 3 {
        return Ok(None);
    }
    let pairs = associate(&gt, est, max_dt);
    if pairs.len() < 3 {
        return Ok(None);
    }
    let aligned = ate(&gt, est, &pairs, AlignMode::Se3)?;
    let unaligned = ate(&gt, est, &pairs, AlignMode::None)?;
    Ok(Some(TrajectoryErrors {
        ate_rmse_m: aligned.errors.rmse,
        ate_rmse_unaligned_m: unaligned.errors.rmse,
        ate: aligned.errors,
        against,
        alignment: aligned.alignment,
        reference_rejected,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GPS fixes taken at an antenna 3 m ahead of the robot origin, on a path that drives
    /// out and back on two parallel lanes: compared at the antenna the estimate matches them
    /// exactly; compared at the robot origin no rigid alignment can hide the offset (it points
    /// one way on the way out and the other way back).
    #[test]
    fn gps_fixes_are_compared_at_the_antenna() {
        let antenna = Vector2::new(3.0, 0.5);
        let poses: Vec<(f64, Pose2)> = (0..40)
            .map(|k| {
                let (x, y, theta) = if k < 20 {
                    (k as f64, 0.0, 0.0)
                } else {
                    ((39 - k) as f64, 10.0, std::f64::consts::PI)
                };
                (k as f64, Pose2::new(x, y, theta))
            })
            .collect();
        let gps: Vec<(f64, Vector2<f64>)> = poses
            .iter()
            .map(|(t, p)| (*t, p.transform_point(&antenna)))
            .collect();
        let est = stamped(poses.iter().copied());
        let at_antenna = path_errors(&[], &gps, &antenna, &est).unwrap().unwrap();
        let at_origin = path_errors(&[], &gps, &Vector2::zeros(), &est)
            .unwrap()
            .unwrap();
        assert_eq!(at_antenna.against, "GPS fixes (positions only)");
        assert!(at_antenna.ate_rmse_m < 1e-9, "{}", at_antenna.ate_rmse_m);
        assert!(at_origin.ate_rmse_m > 2.0, "{}", at_origin.ate_rmse_m);
    }

    /// A fix far off on its own is left out of the ATE and counted; a fast move that stays
    /// (a gap in the fixes, or a receiver that re-converged elsewhere) is kept.
    #[test]
    fn gps_jumps_are_left_out_and_counted() {
        let poses: Vec<(f64, Pose2)> = (0..40)
            .map(|k| {
                let x = k as f64;
                (x, Pose2::new(x, 0.05 * x * x, 0.0))
            })
            .collect();
        let est = stamped(poses.iter().copied());
        let mut gps: Vec<(f64, Vector2<f64>)> = poses
            .iter()
            .map(|(t, p)| (*t, Vector2::new(p.x, p.y)))
            .collect();
        let clean = path_errors(&[], &gps, &Vector2::zeros(), &est)
            .unwrap()
            .unwrap();
        gps[20].1.y += 140.0;
        let with_jump = path_errors(&[], &gps, &Vector2::zeros(), &est)
            .unwrap()
            .unwrap();
        assert_eq!(with_jump.reference_rejected, 1);
        assert_eq!(with_jump.ate.count, clean.ate.count - 1);
        assert!(with_jump.ate_rmse_m < 1e-9, "{}", with_jump.ate_rmse_m);
        assert!(with_jump.against.contains("jumps left out"));
        // From fix 20 on, every fix 140 m off: the first is reached fast but left slowly.
        for fix in gps.iter_mut().skip(21) {
            fix.1.y += 140.0;
        }
        let moved = path_errors(&[], &gps, &Vector2::zeros(), &est)
            .unwrap()
            .unwrap();
        assert_eq!(moved.reference_rejected, 0);
        assert_eq!(moved.ate.count, clean.ate.count);
        assert!(moved.ate_rmse_m > 10.0, "{}", moved.ate_rmse_m);
    }
}
