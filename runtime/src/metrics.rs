//! The metrics of a whole run (what `metrics.json` holds): trajectory error against the
//! data's truth, map error against a true map or known landmarks, NEES and NIS, counts.

use std::collections::BTreeMap;
use std::sync::atomic::AtomicBool;

use serde::Serialize;
use slam_core::{Pose2, Skips};
use slam_sensors::TruthKind;
use slam_sensors::laser_odometry::LaserOdometryReport;

use crate::config::Config;
use crate::error::Result;
use crate::eval::{
    ChiSquareSummary, CloseLandmarks, ErrorStats, MapError, MapQuality, REVISIT_GAP_M,
    REVISIT_RADIUS_M, RevisitConsistency, TrajectoryErrors, anchored_pose_nees, chi_square_summary,
    close_landmarks, confirmed_wall_segments, feature_counts, map_error_against_landmarks,
    map_error_against_truth, map_quality, pose_nees, reference_poses, revisit_consistency,
    singular_steps,
};
use crate::frontend::FrontendCounts;
use crate::health::Divergence;
use crate::record::UpdateTotals;
use crate::run::InputReport;
use crate::run::RunOutput;
use crate::session::Observer;

/// The Mahalanobis distance within which two poles or points count as one landmark mapped
/// twice (`close_landmarks`).
const CLOSE_LANDMARK_DISTANCE: f64 = 3.0;

/// Everything in `metrics.json`.
#[derive(Clone, Debug, Serialize)]
pub struct RunMetrics {
    /// The data's name.
    pub data: String,
    /// The estimator's name.
    pub estimator: &'static str,
    /// `"complete"`, `"interrupted"` (stopped before the end of the data, e.g. by Ctrl-C: the
    /// outputs are those of the steps run) or `"diverged"` (the filter diverged: see
    /// `divergence`).
    pub status: &'static str,
    /// The time of the last event processed, when the run was interrupted.
    pub interrupted_at: Option<f64>,
    /// Where and why the filter diverged, if it did.
    pub divergence: Option<Divergence>,
    /// The `[data] seed`.
    pub seed: u64,
    /// Time steps with an estimate.
    pub steps: usize,
    /// Events processed.
    pub events: usize,
    /// Seconds spent stepping.
    pub wall_time_s: f64,
    /// Mean wall time per time step, ms.
    pub time_per_step_ms: f64,
    /// ATE after SE(3) alignment, m.
    pub ate_rmse_m: Option<f64>,
    /// ATE without alignment, m.
    pub ate_rmse_unaligned_m: Option<f64>,
    /// What the ATE compares against.
    pub ate_against: Option<&'static str>,
    /// Reference fixes the ATE left out as jumps of a GPS receiver
    /// ([`crate::eval::gps_jumps`]).
    pub ate_reference_rejected: Option<usize>,
    /// Full statistics of the aligned ATE.
    pub ate: Option<ErrorStats>,
    /// ATE (aligned RMSE) of the path the map belongs to, where it is not the estimates' (a
    /// particle filter: the path of the particle whose map is kept), m.
    pub map_path_ate_rmse_m: Option<f64>,
    /// Map error after the trajectory's ATE alignment (where the map is compared with a
    /// true map), m.
    pub map_error_m: Option<f64>,
    /// The same without alignment, m.
    pub map_error_unaligned_m: Option<f64>,
    /// The map error in detail.
    pub map_error: Option<MapError>,
    /// Robot pose NEES (3 dof) at every step with a true pose whose covariance is not
    /// singular (`null` with the reason in `unavailable` when there is none).
    pub nees: Option<ChiSquareSummary>,
    /// Where the covariance of the NEES comes from: `"gaussian"` or `"particle cloud"`.
    pub nees_covariance: &'static str,
    /// Steps with a true pose left out of the NEES because their covariance is singular (a
    /// pose known exactly; a collapsed particle cloud).
    pub nees_singular_steps: usize,
    /// Robot pose NEES (3 dof) against the data's reference poses (another system's
    /// estimate, such as a corrected log's poses), where the data has no true poses: both
    /// paths expressed from their first common pose ([`crate::eval::anchored_pose_nees`]).
    /// The reference's own error counts as the estimate's, so a consistent filter scores
    /// somewhat above 1 per degree of freedom; far above it, the filter is overconfident.
    pub nees_reference: Option<ChiSquareSummary>,
    /// NIS of every paired observation (`null` with the reason in `unavailable` when the
    /// estimator reported none).
    pub nis: Option<ChiSquareSummary>,
    /// How well the wall map explains the scans and how much of it is doubled (runs with
    /// laser scans and walls; no truth needed).
    pub map_quality: Option<MapQuality>,
    /// How well the scans of places visited more than once agree, placed by the path the map
    /// belongs to and by the data's reference poses (runs with laser scans; no truth or map
    /// needed; [`crate::eval::revisit_consistency`]).
    pub revisit_consistency: Option<RevisitFigures>,
    /// Pairs of confirmed poles or points within a Mahalanobis distance of 3 of each other
    /// (landmarks mapped twice), by the estimator's joint covariance when it has one; `null`
    /// with fewer than two such features.
    pub close_landmarks: Option<CloseLandmarks>,
    /// Features by type and M-space dimension.
    pub features: BTreeMap<String, BTreeMap<usize, usize>>,
    /// Totals of the update reports.
    pub updates: UpdateTotals,
    /// What the estimator left out, by reason.
    pub skipped: Skips,
    /// What the front-end produced and dropped.
    pub frontend: FrontendCounts,
    /// What the data reader skipped (lines by first word, impossible readings by reason) and
    /// its warnings.
    pub input: InputReport,
    /// The matches of `[data.laser_odometry]`.
    pub laser_odometry: Option<LaserOdometryReportView>,
    /// The figures of the post-processing stages, by name.
    pub postprocess: BTreeMap<String, serde_json::Value>,
    /// Metrics that could not be computed (left `null` above), with the reason: e.g. the ATE
    /// of a path whose poses lie on one line, which no alignment determines.
    pub unavailable: BTreeMap<&'static str, String>,
    /// The configuration of the run.
    pub config: Config,
}

/// The loop consistency of a run's scans, as `metrics.json` holds it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RevisitFigures {
    /// Readings taken closer than this along the path are not compared, m.
    pub gap_m: f64,
    /// Neighbours lie within this distance, m.
    pub radius_m: f64,
    /// The scans placed by the path the map belongs to (`null`: no place seen twice).
    pub estimate: Option<RevisitConsistency>,
    /// The same scans placed by the data's reference or true poses, where it has them: the
    /// same figure for the poses the ATE compares against.
    pub reference: Option<RevisitConsistency>,
}

/// The laser odometry's counts, as `metrics.json` holds them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct LaserOdometryReportView {
    /// Scans whose preceding odometry was replaced by a match.
    pub matched: usize,
    /// Of those, matches found by a retry's wider starting headings (a poor first match).
    pub retried: usize,
    /// Of those, matches with another minimum nearly as low (their covariance widened).
    pub ambiguous: usize,
    /// Scans whose match was refused (their odometry was kept).
    pub refused: usize,
    /// Ground-truth or reference poses between scans, left out of the evaluation (the
    /// estimate moves only at scans).
    pub truth_between_scans: usize,
}

impl From<&LaserOdometryReport> for LaserOdometryReportView {
    fn from(report: &LaserOdometryReport) -> Self {
        LaserOdometryReportView {
            matched: report.matched,
            retried: report.retried,
            ambiguous: report.ambiguous,
            refused: report.refused,
            truth_between_scans: report.truth_between_scans,
        }
    }
}

impl RunMetrics {
    /// The metrics of a finished run of `config`.
    pub fn compute(output: &RunOutput, config: &Config) -> Result<Self> {
        let record = &output.record;
        let estimator = output.estimator.as_ref();
        let mut unavailable = BTreeMap::new();
        let trajectory = available(&mut unavailable, "ate", record.trajectory_errors());
        let map_error = available(
            &mut unavailable,
            "map_error",
            Self::map_error(output, trajectory.as_ref()),
        );
        let consistency = Consistency::of(output, &mut unavailable)?;
        let map_path_ate_rmse_m = match &output.map_path {
            Some(path) => available(&mut unavailable, "map_path_ate", record.path_errors(path))
                .map(|t| t.ate_rmse_m),
            None => None,
        };
        let steps = record.estimates.len();
        Ok(RunMetrics {
            data: output.name.clone(),
            estimator: estimator.name(),
            status: status(output),
            interrupted_at: output.interrupted_at,
            divergence: output.divergence.clone(),
            seed: config.data.seed,
            steps,
            events: record.events,
            wall_time_s: output.wall_time_s,
            time_per_step_ms: 1e3 * output.wall_time_s / steps.max(1) as f64,
            ate_rmse_m: trajectory.as_ref().map(|t| t.ate_rmse_m),
            ate_rmse_unaligned_m: trajectory.as_ref().map(|t| t.ate_rmse_unaligned_m),
            ate_against: trajectory.as_ref().map(|t| t.against),
            ate_reference_rejected: trajectory.as_ref().map(|t| t.reference_rejected),
            ate: trajectory.as_ref().map(|t| t.ate),
            map_path_ate_rmse_m,
            map_error_m: map_error.as_ref().map(|m| m.rms_m),
            map_error_unaligned_m: output
                .truth_map
                .as_ref()
                .map(|truth| map_error_against_truth(estimator, &truth.shapes(), None).rms_m),
            map_error,
            nees: consistency.nees,
            nees_covariance: estimator.covariance_source(),
            nees_singular_steps: consistency.singular_steps,
            nees_reference: consistency.nees_reference,
            nis: consistency.nis,
            map_quality: Self::map_quality(output),
            revisit_consistency: Self::revisits(output),
            close_landmarks: close_landmarks(estimator, CLOSE_LANDMARK_DISTANCE),
            features: feature_counts(estimator),
            updates: record.updates,
            skipped: record.skipped.clone(),
            frontend: output.frontend.clone(),
            input: output.input.clone(),
            laser_odometry: output.laser_odometry.as_ref().map(Into::into),
            postprocess: output
                .postprocess
                .iter()
                .map(|p| (p.name.clone(), p.metrics.clone()))
                .collect(),
            unavailable,
            config: config.clone(),
        })
    }

    /// The map quality figures of the confirmed walls, the scan readings placed by the path
    /// the map belongs to (the estimates, or a particle filter's map path); `None` without
    /// scans or walls.
    fn map_quality(output: &RunOutput) -> Option<MapQuality> {
        let estimator = output.estimator.as_ref();
        let walls = confirmed_wall_segments(estimator);
        let sample = &output.record.scan_sample;
        if walls.is_empty() || sample.is_empty() {
            return None;
        }
        let path = output.record.map_poses(output.map_path.as_deref());
        let pose_at = |time: f64| {
            let k = path.partition_point(|(t, _)| *t < time);
            path.get(k)
                .filter(|(t, _)| *t == time)
                .map(|(_, pose)| *pose)
        };
        Some(map_quality(&walls, &sample.placed(pose_at)))
    }

    /// The loop consistency of the scans placed by the path the map belongs to and by the
    /// data's reference poses; `None` without scans.
    fn revisits(output: &RunOutput) -> Option<RevisitFigures> {
        let sample = &output.record.scan_sample;
        if sample.is_empty() {
            return None;
        }
        let mut reference: Vec<(f64, Pose2)> = output
            .record
            .truth
            .iter()
            .map(|&(time, pose, _)| (time, pose))
            .collect();
        reference.sort_by(|a, b| a.0.total_cmp(&b.0));
        Some(RevisitFigures {
            gap_m: REVISIT_GAP_M,
            radius_m: REVISIT_RADIUS_M,
            estimate: revisit_consistency(
                sample,
                &output.record.map_poses(output.map_path.as_deref()),
            ),
            reference: revisit_consistency(sample, &reference),
        })
    }

    /// Features the data named (known landmark ids) are compared with the known landmarks;
    /// otherwise a simulated world's map is compared with its true map, after the
    /// trajectory's alignment.
    fn map_error(
        output: &RunOutput,
        trajectory: Option<&TrajectoryErrors>,
    ) -> Result<Option<MapError>> {
        let estimator = output.estimator.as_ref();
        let has_truth_poses = output.record.truth.iter().any(|t| t.2 == TruthKind::True);
        let named = estimator
            .map()
            .iter()
            .any(|(id, _)| estimator.landmark_id(id).is_some());
        let error = if named && !output.landmarks.is_empty() {
            Some(map_error_against_landmarks(
                estimator,
                &output.landmarks,
                !has_truth_poses,
            )?)
        } else {
            output.truth_map.as_ref().map(|truth| {
                map_error_against_truth(
                    estimator,
                    &truth.shapes(),
                    trajectory.map(|t| &t.alignment),
                )
            })
        };
        Ok(error.filter(|m| m.count > 0))
    }
}

/// A run in memory with its metrics: what `slam run` computes before it writes any file.
pub struct RunResults {
    /// The run (estimates, truth, the estimator with its map, stages' outputs).
    pub output: RunOutput,
    /// Its metrics (`metrics.json`).
    pub metrics: RunMetrics,
}

/// The computation of `slam run` without its files: runs `config`, with `observer` watching,
/// until the end of the data or until `stop` is set ([`crate::run_until`]), and computes the
/// run's [`RunMetrics`].
pub fn compute_run(
    config: &Config,
    observer: &mut dyn Observer,
    stop: &AtomicBool,
) -> Result<RunResults> {
    let output = crate::run::run_until(config, observer, stop)?;
    let metrics = RunMetrics::compute(&output, config)?;
    Ok(RunResults { output, metrics })
}

/// NEES and NIS of a run, with the reasons of those that are missing.
struct Consistency {
    nees: Option<ChiSquareSummary>,
    singular_steps: usize,
    nees_reference: Option<ChiSquareSummary>,
    nis: Option<ChiSquareSummary>,
}

impl Consistency {
    fn of(output: &RunOutput, unavailable: &mut BTreeMap<&'static str, String>) -> Result<Self> {
        let record = &output.record;
        let estimator = output.estimator.as_ref();
        let truth = record.true_poses();
        let nees: Vec<(f64, usize)> = pose_nees(&record.estimates, &truth)
            .into_iter()
            .map(|(_, n)| (n, 3))
            .collect();
        let nees_singular_steps = singular_steps(&record.estimates, &truth);
        if nees.is_empty() && nees_singular_steps > 0 {
            unavailable.insert(
                "nees",
                format!(
                    "the pose covariance is singular at all {nees_singular_steps} steps with a \
                     true pose ({})",
                    estimator.covariance_source()
                ),
            );
        }
        let nees_reference: Vec<(f64, usize)> = if truth.is_empty() {
            anchored_pose_nees(&record.estimates, &reference_poses(&record.truth))
                .into_iter()
                .map(|(_, n)| (n, 3))
                .collect()
        } else {
            Vec::new()
        };
        let nis = record.nis.summary();
        let updates = record.updates.associated + record.updates.new_features;
        if nis.count == 0 && updates > 0 {
            unavailable.insert(
                "nis",
                format!(
                    "the {} estimator reported no innovation for its {updates} used observations",
                    estimator.name()
                ),
            );
        }
        Ok(Consistency {
            nees: summary_of(&nees)?,
            singular_steps: nees_singular_steps,
            nees_reference: summary_of(&nees_reference)?,
            nis: (nis.count > 0).then_some(nis),
        })
    }
}

/// The summary of `(value, dof)` pairs, `None` for none.
fn summary_of(values: &[(f64, usize)]) -> Result<Option<ChiSquareSummary>> {
    if values.is_empty() {
        Ok(None)
    } else {
        chi_square_summary(values).map(Some)
    }
}

/// The status of a run: interrupted, diverged or complete.
fn status(output: &RunOutput) -> &'static str {
    if output.interrupted_at.is_some() {
        "interrupted"
    } else if output.divergence.is_some() {
        "diverged"
    } else {
        "complete"
    }
}

/// The value of a metric, or `None` with the reason kept in `unavailable`.
fn available<T>(
    unavailable: &mut BTreeMap<&'static str, String>,
    metric: &'static str,
    value: Result<Option<T>>,
) -> Option<T> {
    match value {
        Ok(value) => value,
        Err(error) => {
            unavailable.insert(metric, error.to_string());
            None
        }
    }
}
