//! One estimator run over an event stream: motion to `predict`, raw data through the
//! front-end to `update`, and a record of the estimate at every time step.

use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use slam_core::nalgebra::{DMatrix, Matrix3, Vector2};
use slam_core::{Estimator, Pose2};
use slam_estimators::{Ekf, FastSlam, Ipslam};
use slam_sensors::{Dataset, Event, TruthKind};

use crate::config::{Config, EstimatorConfig};
use crate::error::{CliError, Result};
use crate::frontend::{Frontend, FrontendCounts};

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

/// Totals of the estimator's update reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct UpdateTotals {
    /// Observations paired with a feature.
    pub associated: usize,
    /// Observations that started a feature.
    pub new_features: usize,
    /// Observations dropped.
    pub rejected: usize,
}

/// What one run produced.
pub struct RunResult {
    /// The estimator at the end (its map and last pose).
    pub estimator: Box<dyn Estimator<Pose2>>,
    /// The estimate after every time step.
    pub estimates: Vec<Record>,
    /// The path the map belongs to, at the times of `estimates`, where it is not theirs (a
    /// particle filter: the path of the particle whose map is kept).
    pub map_path: Option<Vec<(f64, Pose2)>>,
    /// Ground truth or reference poses of the data.
    pub truth: Vec<(f64, Pose2, TruthKind)>,
    /// GPS fixes of the data.
    pub gps: Vec<(f64, Vector2<f64>)>,
    /// Normalized innovation squared of every paired observation, with its dimension.
    pub nis: Vec<(f64, usize)>,
    /// Totals of the update reports.
    pub updates: UpdateTotals,
    /// What the front-end extracted.
    pub frontend: FrontendCounts,
    /// Seconds spent in the loop (front-end and estimator).
    pub wall_time_s: f64,
    /// Events processed.
    pub events: usize,
}

/// The estimator a config selects, starting at `pose` with covariance `covariance`.
pub fn make_estimator(
    config: &EstimatorConfig,
    pose: Pose2,
    covariance: Matrix3<f64>,
) -> Result<Box<dyn Estimator<Pose2>>> {
    let covariance = DMatrix::from_column_slice(3, 3, covariance.as_slice());
    match config {
        EstimatorConfig::Ekf(params) => Ok(Box::new(Ekf::new(pose, covariance, params.clone())?)),
        // The poses of an em-polygon run with `poses = "ekf"` come from its EKF.
        EstimatorConfig::EmPolygon(p) => Ok(Box::new(Ekf::new(pose, covariance, p.ekf.clone())?)),
        EstimatorConfig::FastSlam(params) => {
            Ok(Box::new(FastSlam::new(pose, covariance, params.clone())?))
        }
        EstimatorConfig::Ipslam(params) => Ok(Box::new(Ipslam::new(
            pose,
            covariance,
            params.clone(),
            std::sync::Arc::new(PpcaLines),
        )?)),
    }
}

/// IPSLAM's line maps as `slam_features::PpcaLine`s, its scan points as
/// `slam_sensors::models::LinePoint` observations.
struct PpcaLines;

impl slam_estimators::LineMapTypes for PpcaLines {
    fn cluster_feature(
        &self,
        c: &slam_estimators::Cluster,
    ) -> slam_core::Result<Box<dyn slam_core::Feature>> {
        let line = slam_features::PpcaLine::from_cluster(
            c.mean,
            c.direction,
            c.principal_variance,
            c.sigma2,
            c.count,
        )?;
        Ok(Box::new(line))
    }

    fn scan_point(&self, observation: &slam_core::Observation) -> Option<Vector2<f64>> {
        observation
            .measurement
            .as_any()
            .downcast_ref::<slam_sensors::models::LinePoint>()
            .map(|p| p.point)
    }
}

/// The first pose of the data: the first truth pose if it comes before any motion, else the
/// origin.
fn initial_pose(dataset: &Dataset) -> Pose2 {
    for e in &dataset.events {
        match &e.event {
            Event::Motion(_) => break,
            Event::GroundTruth { pose, .. } => return *pose,
            _ => {}
        }
    }
    Pose2::identity()
}

/// A progress bar over `len` events, hidden when `quiet` (and by indicatif when stderr is not
/// a terminal).
pub fn progress_bar(len: usize, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len as u64);
    if let Ok(style) = ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} events ({eta} left) {msg}",
    ) {
        bar.set_style(style);
    }
    bar
}

/// Runs the configured estimator over `dataset`; `sigma_range` is the laser noise the
/// front-end assumes and `noise_factor` inflates the deviations of what it extracts.
pub fn run(
    config: &Config,
    dataset: Dataset,
    sigma_range: f64,
    noise_factor: f64,
    progress: &ProgressBar,
) -> Result<RunResult> {
    let start = initial_pose(&dataset);
    let [sx, sy, st] = config.data.initial_pose_sigma;
    let covariance = Matrix3::from_diagonal(&slam_core::nalgebra::Vector3::new(
        sx * sx,
        sy * sy,
        st * st,
    ));
    let mut estimator = make_estimator(&config.estimator, start, covariance)?;
    let mut frontend = Frontend::new(&config.frontend, sigma_range, noise_factor)?;
    let mut estimates = Vec::new();
    let mut truth = Vec::new();
    let mut gps = Vec::new();
    let mut nis = Vec::new();
    let mut updates = UpdateTotals::default();
    let clock = Instant::now();
    let limit = match config.data.max_events {
        0 => usize::MAX,
        n => n,
    };
    let raw_data = dataset
        .events
        .iter()
        .any(|e| matches!(e.event, Event::Scan { .. } | Event::Image { .. }));
    let use_given = config.frontend.landmarks.unwrap_or(!raw_data);
    let events: Vec<_> = dataset.events.into_iter().take(limit).collect();
    let count = events.len();
    let mut iter = events.into_iter().peekable();
    while let Some(timed) = iter.next() {
        let time = timed.time;
        let observations = match timed.event {
            Event::Motion(motion) => {
                estimator
                    .predict(motion.as_ref())
                    .map_err(|e| at_time(time, "prediction", e))?;
                Vec::new()
            }
            Event::Scan {
                scan,
                robot_from_sensor,
            } if matches!(config.estimator, EstimatorConfig::Ipslam(_)) => scan
                .points()
                .iter()
                .filter_map(|p| {
                    let point = Vector2::new(p.range * p.bearing.cos(), p.range * p.bearing.sin());
                    slam_sensors::models::LinePoint::new(point, sigma_range)
                        .ok()
                        .map(|m| slam_core::Observation {
                            robot_from_sensor,
                            measurement: Box::new(m),
                            landmark_id: None,
                        })
                })
                .collect(),
            Event::Scan {
                scan,
                robot_from_sensor,
            } => frontend.scan_observations(&scan, &robot_from_sensor),
            Event::Image {
                image,
                camera,
                robot_from_sensor,
            } => frontend.image_observations(&image, &camera, &robot_from_sensor)?,
            Event::Observations(mut observations) if use_given => {
                if config.frontend.ignore_landmark_ids {
                    for o in &mut observations {
                        o.landmark_id = None;
                    }
                }
                observations
            }
            Event::Observations(_) => Vec::new(),
            Event::GroundTruth { pose, kind } => {
                truth.push((time, pose, kind));
                Vec::new()
            }
            Event::Gps(fix) => {
                gps.push((time, fix));
                Vec::new()
            }
        };
        if !observations.is_empty() {
            let report = estimator
                .update(&observations)
                .map_err(|e| at_time(time, "update", e))?;
            updates.associated += report.associated;
            updates.new_features += report.new_features;
            updates.rejected += report.rejected;
            nis.extend(report.nis);
        }
        if iter.peek().is_none_or(|next| next.time != time) {
            estimator.end_step();
            let c = estimator.pose_covariance();
            estimates.push(Record {
                time,
                pose: estimator.pose(),
                covariance: Matrix3::from_fn(|i, j| c[(i, j)]),
            });
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    let map_path = match estimator.map_path() {
        Some(path) if path.len() == estimates.len() => Some(
            estimates
                .iter()
                .zip(path)
                .map(|(record, pose)| (record.time, pose))
                .collect(),
        ),
        Some(path) => {
            return Err(CliError::Usage(format!(
                "the {} estimator recorded {} poses of its map's path for {} steps",
                estimator.name(),
                path.len(),
                estimates.len()
            )));
        }
        None => None,
    };
    Ok(RunResult {
        estimator,
        estimates,
        map_path,
        truth,
        gps,
        nis,
        updates,
        frontend: frontend.counts,
        wall_time_s: clock.elapsed().as_secs_f64(),
        events: count,
    })
}

/// An estimator error with the time of the event that caused it.
fn at_time(time: f64, what: &str, error: slam_core::Error) -> CliError {
    CliError::Usage(format!("{what} at time {time}: {error}"))
}
