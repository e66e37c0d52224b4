//! A whole run from a [`Config`]: open the data, build the estimator, the front-end and the
//! post-processing stages by name, step through the events with the standard [`Recorder`],
//! finish the stages. What the `slam run` command does, minus the files.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::Serialize;

use slam_core::nalgebra::DMatrix;
use slam_core::{Estimator, Pose2};
use slam_sensors::laser_odometry::LaserOdometryReport;
use slam_sensors::sim::TrueMap;
use slam_sensors::{Event, KnownLandmark, TimedEvent};

use crate::config::Config;
use crate::error::{Result, RuntimeError};
use crate::estimators::Start;
use crate::frontend::FrontendCounts;
use crate::health::{Divergence, DivergenceMonitor};
use crate::postprocess::{FinishedRun, PostProcess, PostProcessOutput};
use crate::record::Recorder;
use crate::session::{Observer, Session};

/// Everything a run produced.
pub struct RunOutput {
    /// The data's name.
    pub name: String,
    /// The estimator at the end (its map and last pose).
    pub estimator: Box<dyn Estimator<Pose2>>,
    /// The standard record (estimates, truth, GPS fixes, update totals).
    pub record: Recorder,
    /// The path the map belongs to, at the times of the estimates, where it is not theirs (a
    /// particle filter: the path of the particle whose map is kept).
    pub map_path: Option<Vec<(f64, Pose2)>>,
    /// What the front-end produced and dropped.
    pub frontend: FrontendCounts,
    /// Seconds spent stepping (front-end and estimator; reading the data not included).
    pub wall_time_s: f64,
    /// The true map, when the data are simulated.
    pub truth_map: Option<TrueMap>,
    /// Surveyed or generated landmark positions of the data.
    pub landmarks: Vec<KnownLandmark>,
    /// The matches of `[data.laser_odometry]`.
    pub laser_odometry: Option<LaserOdometryReport>,
    /// What the post-processing stages produced, in their order.
    pub postprocess: Vec<PostProcessOutput>,
    /// What the data reader skipped and doubts.
    pub input: InputReport,
    /// The first divergence of the filter, if it diverged (the run went on to the end).
    pub divergence: Option<Divergence>,
    /// The time of the last event processed when the run was stopped before the end of the
    /// data ([`run_until`]), if it was.
    pub interrupted_at: Option<f64>,
}

/// What the data reader left out or doubts (the input policy of [`slam_sensors::data`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct InputReport {
    /// Lines not used, by their first word.
    pub skipped_lines: BTreeMap<String, usize>,
    /// Readings skipped as physically impossible, by reason.
    pub skipped_readings: BTreeMap<String, usize>,
    /// Warnings about the data (e.g. implausible units).
    pub warnings: Vec<String>,
    /// Notes on how the data were read (e.g. where the laser mount came from).
    pub notes: Vec<String>,
}

impl InputReport {
    fn of(counter: &slam_sensors::SkipCounter) -> Self {
        InputReport {
            skipped_lines: counter.get(),
            skipped_readings: counter.readings(),
            warnings: counter.warnings(),
            notes: counter.notes(),
        }
    }
}

/// Runs `config`: `observer` watches the session besides the standard record (e.g. a
/// progress bar).
///
/// ```no_run
/// use slam_runtime::{Config, run};
/// let output = run(&Config::default(), &mut ())?;
/// println!("{} steps", output.record.estimates.len());
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
pub fn run(config: &Config, observer: &mut dyn Observer) -> Result<RunOutput> {
    run_until(config, observer, &AtomicBool::new(false))
}

/// [`run`], stopped at the next event once `stop` is set (e.g. by Ctrl-C): the open time step
/// ends, the stages finish, and [`RunOutput::interrupted_at`] says where it stopped.
pub fn run_until(
    config: &Config,
    observer: &mut dyn Observer,
    stop: &AtomicBool,
) -> Result<RunOutput> {
    config.validate()?;
    let data = config.data.open()?;
    let name = data.events.info.name.clone();
    let landmarks = data.events.info.landmarks.clone();
    let gps_antenna = data.events.info.gps_antenna;
    let counter = data.events.skip_counter();
    let mut events = data.events;
    let (pose, before_motion) = initial_pose(&mut events)?;
    let (mut session, mut stages) = build(config, pose, &data.sensors)?;
    let mut record = Recorder {
        gps_antenna,
        ..Recorder::default()
    };
    let mut monitor = DivergenceMonitor::default();
    let limit = match config.data.max_events {
        0 => usize::MAX,
        n => n,
    };
    let all = before_motion.into_iter().map(Ok).chain(events).take(limit);
    let (wall_time_s, interrupted_at) = {
        let mut observers: Vec<&mut dyn Observer> = vec![&mut record, &mut monitor, observer];
        for stage in &mut stages {
            observers.push(stage.as_mut());
        }
        timed_run(&mut session, all, &mut observers, stop)?
    };
    if record.events == 0 {
        let why = match interrupted_at {
            Some(_) => "the run was stopped before the first event".to_string(),
            None => format!(
                "the data gave no event (lines skipped: {:?})",
                counter.get()
            ),
        };
        return Err(RuntimeError::Data(format!("{name}: {why}")));
    }
    let (estimator, frontend) = session.into_parts();
    let map_path = map_path(estimator.as_ref(), &record)?;
    let finished = FinishedRun {
        name: &name,
        record: &record,
        estimator: estimator.as_ref(),
        map_path: map_path.as_deref(),
    };
    let mut postprocess = stages
        .into_iter()
        .map(|stage| stage.finish(&finished))
        .collect::<Result<Vec<_>>>()?;
    distinct_names(&mut postprocess);
    Ok(RunOutput {
        name,
        estimator,
        map_path,
        frontend: frontend.counts(),
        wall_time_s,
        truth_map: data.truth,
        landmarks,
        laser_odometry: data.laser_odometry.map(|c| c.report()),
        record,
        postprocess,
        input: InputReport::of(&counter),
        divergence: monitor.divergence().cloned(),
        interrupted_at,
    })
}

/// The session (estimator and front-end) and the post-processing stages of `config`, the
/// estimator starting at `pose`.
fn build(
    config: &Config,
    pose: Pose2,
    sensors: &crate::frontend::SensorInfo,
) -> Result<(Session, Vec<Box<dyn PostProcess>>)> {
    let [sx, sy, st] = config.data.initial_pose_sigma;
    let start = Start {
        pose,
        covariance: DMatrix::from_diagonal(&slam_core::nalgebra::DVector::from_vec(vec![
            sx * sx,
            sy * sy,
            st * st,
        ])),
    };
    let estimator = config.estimator.build(&start)?;
    let frontend = config.frontend.build(sensors)?;
    let stages = config
        .postprocess
        .iter()
        .map(|stage| stage.build())
        .collect::<Result<Vec<Box<dyn PostProcess>>>>()?;
    Ok((Session::new(estimator, frontend), stages))
}

/// Runs the session over `events` and returns the seconds spent stepping (reading and
/// generating the data excluded, as when the data were loaded first), and the time of the
/// last event processed when `stop` ended the run early.
fn timed_run(
    session: &mut Session,
    events: impl Iterator<Item = slam_sensors::Result<TimedEvent>>,
    observer: &mut dyn Observer,
    stop: &AtomicBool,
) -> Result<(f64, Option<f64>)> {
    let mut seconds = 0.0;
    let mut last = None;
    let mut interrupted = None;
    for event in events {
        if stop.load(Ordering::Relaxed) {
            interrupted = Some(last.unwrap_or(f64::NAN));
            break;
        }
        let event = event?;
        let clock = Instant::now();
        session.step(&event, observer)?;
        seconds += clock.elapsed().as_secs_f64();
        last = Some(event.time);
    }
    let clock = Instant::now();
    session.finish(observer)?;
    Ok((seconds + clock.elapsed().as_secs_f64(), interrupted))
}

/// The first pose of the data: the first truth pose if it comes before any motion, else the
/// origin; with the events read to find it, to be processed first.
fn initial_pose(
    events: &mut impl Iterator<Item = slam_sensors::Result<TimedEvent>>,
) -> Result<(Pose2, Vec<TimedEvent>)> {
    let mut read = Vec::new();
    for event in events.by_ref() {
        let event = event?;
        let found = match &event.event {
            Event::Motion(_) => Some(Pose2::identity()),
            Event::GroundTruth { pose, .. } => Some(*pose),
            _ => None,
        };
        read.push(event);
        if let Some(pose) = found {
            return Ok((pose, read));
        }
    }
    Ok((Pose2::identity(), read))
}

/// The estimator's map path paired with the estimates' times, where it has one.
fn map_path(
    estimator: &dyn Estimator<Pose2>,
    record: &Recorder,
) -> Result<Option<Vec<(f64, Pose2)>>> {
    match estimator.map_path() {
        Some(path) if path.len() == record.estimates.len() => Ok(Some(
            record
                .estimates
                .iter()
                .zip(path)
                .map(|(estimate, pose)| (estimate.time, pose))
                .collect(),
        )),
        Some(path) => Err(RuntimeError::Invariant(format!(
            "the {} estimator recorded {} poses of its map's path for {} steps",
            estimator.name(),
            path.len(),
            record.estimates.len()
        ))),
        None => Ok(None),
    }
}

/// Stages of the same name get `-2`, `-3`, ... appended in their order, so that their
/// outputs do not overwrite each other.
fn distinct_names(outputs: &mut [PostProcessOutput]) {
    for k in 1..outputs.len() {
        let (before, rest) = outputs.split_at_mut(k);
        let name = rest[0].name.clone();
        let mut n = 1;
        while before.iter().any(|o| o.name == rest[0].name) {
            n += 1;
            rest[0].name = format!("{name}-{n}");
        }
    }
}
