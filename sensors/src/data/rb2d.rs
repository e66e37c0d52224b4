//! rb2d: a plain-text 2-D range-bearing SLAM log (`shared/formats/rb2d.md`).
//!
//! One record per line, fields separated by spaces, `#` comment lines (counted in
//! [`Dataset::skipped`] under `"#"`), blank lines ignored:
//!
//! | record | becomes |
//! |---|---|
//! | `PARAM name value` | `dt`, `sigma_v`, `sigma_w`, `sigma_r`, `sigma_b`, `max_range`; each at most once |
//! | `LM id x y` | a [`KnownLandmark`] in [`Dataset::landmarks`] |
//! | `ODOM k dt dx dy dth` | [`Event::Motion`]: a [`Unicycle`] `(dx/dt, dth/dt)` with Euler integration when `dy == 0`, otherwise a [`PoseIncrement`] with covariance `diag((sigma_v dt)^2, (sigma_v dt)^2, (sigma_w dt)^2)` |
//! | `OBS k id range bearing` | all `OBS` of one step form one [`Event::Observations`] of [`RangeBearing`]s, `landmark_id` `Some(id)` for `id >= 0`, `None` for `-1` |
//! | `GT k x y th` | [`Event::GroundTruth`] of kind [`TruthKind::True`] |
//!
//! An `OBS` whose range is not positive, or beyond `PARAM max_range` by more than 5
//! `sigma_r`, is a glitch of the sensor: it is skipped and counted
//! ([`EventStream::skipped_readings`]), the rest of the line is still checked. The first pass
//! (which also collects the `LM` lines) checks the units: bearings or headings in degrees, and
//! ranges or odometry in centimetres or millimetres (against `max_range`, and against the
//! distances between the `GT` poses and the `LM` landmarks where the log has both) are errors
//! of [`stream_rb2d`] naming the file and the unit. A file without any record is an error too.
//!
//! Event times are `k * dt` seconds with `dt` the `PARAM dt`. Records are sorted by step,
//! and within one step come `ODOM`, then `OBS`, then `GT`; a record out of that order is a
//! "step going backwards" error. A record that needs a parameter (`ODOM`: `dt`, `sigma_v`,
//! `sigma_w`; `OBS`: `dt`, `sigma_r`, `sigma_b`; `GT`: `dt`) before its `PARAM` line is an
//! error too, as are unknown records and parameter names, wrong field counts, and
//! non-numeric or non-finite values, each with `file:line` and the reason.
//!
//! [`rb2d_text`] and [`write_rb2d`] write a [`Dataset`] as an rb2d log that this reader turns
//! back into the same odometry increments, observations and true poses.

use std::collections::VecDeque;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use slam_core::nalgebra::{Matrix3, Vector2, Vector3};
use slam_core::{Observation, Pose2, Pose3};

use super::units::Rb2dEvidence;
use super::{Fields, Lines, write_atomically};
use crate::error::{Result, SensorError};
use crate::events::{
    Clock, Dataset, DatasetInfo, Event, EventStream, KnownLandmark, Pump, SkipCounter, Step,
    TimedEvent, TruthKind,
};
use crate::models::RangeBearing;
use crate::odometry::{Integration, PoseIncrement, Unicycle};

/// Parameter names in the order of [`Params::values`].
const PARAM_NAMES: [&str; 6] = [
    "dt",
    "sigma_v",
    "sigma_w",
    "sigma_r",
    "sigma_b",
    "max_range",
];

/// The `PARAM` values seen so far, with the line that set each.
#[derive(Default)]
struct Params {
    values: [Option<(f64, usize)>; 6],
}

impl Params {
    fn set(&mut self, fields: &Fields) -> Result<()> {
        fields.expect_len(3, "PARAM")?;
        let name = fields.get(1, "name")?;
        let Some(index) = PARAM_NAMES.iter().position(|n| *n == name) else {
            return Err(fields.error(format!(
                "unknown parameter `{name}` (expected one of {})",
                PARAM_NAMES.join(", ")
            )));
        };
        let value = fields.f64(2, "value")?;
        // dt, the range deviations and max_range must be positive; odometry deviations may be 0.
        let zero_allowed = matches!(name, "sigma_v" | "sigma_w");
        if value < 0.0 || (value == 0.0 && !zero_allowed) {
            return Err(fields.error(format!("parameter {name} must be positive, got {value}")));
        }
        if let Some((_, line)) = self.values[index] {
            return Err(fields.error(format!("parameter {name} already set at line {line}")));
        }
        self.values[index] = Some((value, fields.line()));
        Ok(())
    }

    /// The value of `name`, or an error when the record at `fields` comes before it.
    fn get(&self, name: &str, fields: &Fields) -> Result<f64> {
        let index = PARAM_NAMES.iter().position(|n| *n == name).unwrap_or(0);
        self.values[index].map(|(v, _)| v).ok_or_else(|| {
            fields.error(format!(
                "{} needs PARAM {name}, which has not been given yet",
                fields.first()
            ))
        })
    }
}

/// Where the reader is in the log: the last step record, for the order checks, and the
/// observations of the current step.
#[derive(Default)]
struct State {
    params: Params,
    /// Where skipped readings are counted.
    skipped: SkipCounter,
    /// `(step, rank)` of the last `ODOM` (0), `OBS` (1) or `GT` (2).
    last: Option<(u64, u8)>,
    /// The step and the observations of the `OBS` lines read last.
    pending: Option<(u64, Vec<Observation>)>,
}

/// Reads an rb2d log; see the [module](self) for the records and what is rejected. This is
/// [`stream_rb2d`] collected.
///
/// ```
/// use slam_sensors::data::read_rb2d;
/// use slam_sensors::{Event, TruthKind};
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("rb2d-doc.txt");
/// std::fs::write(&path, "# a tiny log\n\
///     PARAM dt 0.1\nPARAM sigma_v 0.05\nPARAM sigma_w 0.01\nPARAM sigma_r 0.1\nPARAM sigma_b 0.02\n\
///     LM 3 5.0 0.0\n\
///     OBS 0 3 5.0 0.0\n\
///     ODOM 1 0.1 0.1 0.0 0.0\n\
///     OBS 1 3 4.9 0.0\nOBS 1 -1 7.0 1.0\n\
///     GT 1 0.1 0.0 0.0\n").unwrap();
/// let data = read_rb2d(&path).unwrap();
/// let counts = data.counts();
/// assert_eq!((counts.motion, counts.observation_events, counts.observations), (1, 2, 3));
/// assert_eq!(data.landmarks.len(), 1);
/// let last = data.events.last().unwrap();
/// assert!((last.time - 0.1).abs() < 1e-12);
/// assert!(matches!(last.event, Event::GroundTruth { kind: TruthKind::True, .. }));
/// ```
pub fn read_rb2d(path: &Path) -> Result<Dataset> {
    stream_rb2d(path)?.into_dataset()
}

/// Reads an rb2d log one line at a time: the events of [`read_rb2d`], in the same order.
///
/// The `LM` lines, which may stand anywhere in the file, are collected by a first quick pass
/// for [`DatasetInfo::landmarks`]. A missing or unreadable file is an error of this call; a
/// malformed line (an `LM` line too) is an `Err` item when the stream reaches it.
pub fn stream_rb2d(path: &Path) -> Result<EventStream> {
    let mut landmarks = Vec::new();
    let mut evidence = Rb2dEvidence::default();
    let mut records = 0usize;
    let mut lines = Lines::open(path)?;
    while let Some(next) = lines.next_line() {
        let (line, content) = next?;
        let fields = Fields::whitespace(path, line, &content);
        let first = fields.first();
        if first.is_empty() || first.starts_with('#') {
            continue;
        }
        records += 1;
        evidence.add(fields.all());
        if first == "LM"
            && let Ok(landmark) = parse_landmark(&fields)
        {
            landmarks.push(landmark);
        }
    }
    if records == 0 {
        return Err(SensorError::Input(format!(
            "{}: no rb2d record (PARAM, LM, ODOM, OBS or GT): the file is empty or has only \
             comments",
            path.display()
        )));
    }
    evidence.check(path)?;
    let name = path
        .file_name()
        .unwrap_or(path.as_os_str())
        .to_string_lossy()
        .into_owned();
    let info = DatasetInfo {
        name,
        clock: Clock::Seconds,
        landmarks,
        gps_antenna: slam_core::nalgebra::Vector2::zeros(),
    };
    let skipped = SkipCounter::default();
    let reader = Rb2dReader {
        path: path.to_path_buf(),
        lines: Lines::open(path)?,
        skipped: skipped.clone(),
        state: State {
            skipped: skipped.clone(),
            ..State::default()
        },
    };
    Ok(EventStream::new(info, Pump::new(reader)).with_skipped(skipped))
}

/// The state of a [`stream_rb2d`] stream.
struct Rb2dReader {
    /// The file (for messages).
    path: PathBuf,
    lines: Lines,
    skipped: SkipCounter,
    state: State,
}

impl Step for Rb2dReader {
    fn step(&mut self, out: &mut VecDeque<TimedEvent>) -> Result<bool> {
        let Some(next) = self.lines.next_line() else {
            flush(&mut self.state, out);
            return Ok(false);
        };
        let (line, content) = next?;
        let trimmed = content.trim();
        if trimmed.starts_with('#') {
            self.skipped.count("#");
        } else if !trimmed.is_empty() {
            let fields = Fields::whitespace(&self.path, line, &content);
            read_record(&fields, &mut self.state, out)?;
        }
        Ok(true)
    }
}

fn push(out: &mut VecDeque<TimedEvent>, time: f64, event: Event) {
    out.push_back(TimedEvent { time, event });
}

fn read_record(fields: &Fields, state: &mut State, out: &mut VecDeque<TimedEvent>) -> Result<()> {
    match fields.first() {
        "PARAM" => state.params.set(fields),
        // Collected before the stream starts; checked again here to report errors in order.
        "LM" => parse_landmark(fields).map(|_| ()),
        "ODOM" => read_odometry(fields, state, out),
        "OBS" => read_observation(fields, state, out),
        "GT" => read_truth(fields, state, out),
        other => Err(fields.error(format!(
            "unknown record `{other}` (expected PARAM, LM, ODOM, OBS or GT)"
        ))),
    }
}

/// Emits the pending observations, if any.
fn flush(state: &mut State, out: &mut VecDeque<TimedEvent>) {
    if let Some((step, observations)) = state.pending.take() {
        let dt = state.params.values[0].map_or(0.0, |(v, _)| v);
        push(out, step as f64 * dt, Event::Observations(observations));
    }
}

/// The step of a record of `rank` (ODOM 0, OBS 1, GT 2), checked against the previous one;
/// a step record other than another `OBS` of the same step flushes the pending observations.
fn step(
    fields: &Fields,
    rank: u8,
    state: &mut State,
    out: &mut VecDeque<TimedEvent>,
) -> Result<u64> {
    let k = fields.u64(1, "step")?;
    if let Some((last_k, last_rank)) = state.last {
        let same_obs_step = rank == 1 && last_rank == 1 && k == last_k;
        if (k, rank) <= (last_k, last_rank) && !same_obs_step {
            const NAMES: [&str; 3] = ["ODOM", "OBS", "GT"];
            let reason = if k < last_k {
                format!("step going backwards: step {k} after step {last_k}")
            } else {
                format!(
                    "step going backwards: {} of step {k} after {} of the same step \
                     (the order within a step is ODOM, OBS, GT, each of ODOM and GT once)",
                    NAMES[usize::from(rank)],
                    NAMES[usize::from(last_rank)]
                )
            };
            return Err(fields.error(reason));
        }
    }
    if state
        .pending
        .as_ref()
        .is_some_and(|(pk, _)| !(rank == 1 && *pk == k))
    {
        flush(state, out);
    }
    state.last = Some((k, rank));
    Ok(k)
}

fn parse_landmark(fields: &Fields) -> Result<KnownLandmark> {
    fields.expect_len(4, "LM id x y")?;
    let id = fields.u64(1, "landmark id")?;
    let [x, y] = fields.f64s(2, "landmark position")?;
    Ok(KnownLandmark {
        id,
        position: Vector2::new(x, y),
    })
}

fn read_odometry(fields: &Fields, state: &mut State, out: &mut VecDeque<TimedEvent>) -> Result<()> {
    fields.expect_len(6, "ODOM k dt dx dy dth")?;
    let [dt, dx, dy, dth] = fields.f64s(2, "odometry")?;
    let time_step = state.params.get("dt", fields)?;
    let sigma_v = state.params.get("sigma_v", fields)?;
    let sigma_w = state.params.get("sigma_w", fields)?;
    if dt <= 0.0 {
        return Err(fields.error(format!("ODOM dt must be positive, got {dt}")));
    }
    let k = step(fields, 0, state, out)?;
    if k == 0 {
        return Err(fields.error("ODOM step must be at least 1 (it leads from pose k-1 to pose k)"));
    }
    let motion = motion(dt, dx, dy, dth, sigma_v, sigma_w).map_err(|e| fields.wrap(e))?;
    push(out, k as f64 * time_step, Event::Motion(motion));
    Ok(())
}

fn motion(
    dt: f64,
    dx: f64,
    dy: f64,
    dth: f64,
    sigma_v: f64,
    sigma_w: f64,
) -> Result<Box<dyn slam_core::MotionModel<Pose2>>> {
    if dy == 0.0 {
        let unicycle = Unicycle::new(dx / dt, dth / dt, dt, sigma_v, sigma_w, Integration::Euler)?;
        return Ok(Box::new(unicycle));
    }
    let (sv, sw) = (sigma_v * dt, sigma_w * dt);
    let cov = Matrix3::from_diagonal(&Vector3::new(sv * sv, sv * sv, sw * sw));
    Ok(Box::new(PoseIncrement::new(Pose2::new(dx, dy, dth), cov)?))
}

fn read_observation(
    fields: &Fields,
    state: &mut State,
    out: &mut VecDeque<TimedEvent>,
) -> Result<()> {
    fields.expect_len(5, "OBS k id range bearing")?;
    let id = fields.i64(2, "landmark id")?;
    let [range, bearing] = fields.f64s(3, "range and bearing")?;
    state.params.get("dt", fields)?;
    let sigma_r = state.params.get("sigma_r", fields)?;
    let sigma_b = state.params.get("sigma_b", fields)?;
    let landmark_id = match id {
        -1 => None,
        id => Some(u64::try_from(id).map_err(|_| {
            fields.error(format!("landmark id must be -1 or non-negative, got {id}"))
        })?),
    };
    let k = step(fields, 1, state, out)?;
    if let Some(reason) = impossible_range(range, sigma_r, &state.params) {
        state.skipped.count_reading(reason);
        return Ok(());
    }
    let model =
        RangeBearing::new(range, bearing, sigma_r, sigma_b).map_err(|e| fields.wrap(e.into()))?;
    let observation = Observation {
        robot_from_sensor: Pose3::identity(),
        measurement: Arc::new(model),
        landmark_id,
    };
    state
        .pending
        .get_or_insert_with(|| (k, Vec::new()))
        .1
        .push(observation);
    Ok(())
}

/// Why an `OBS` range is physically impossible (a glitch to skip), if it is.
fn impossible_range(range: f64, sigma_r: f64, params: &Params) -> Option<&'static str> {
    let max_range = params.values[5].map(|(v, _)| v);
    if range <= 0.0 {
        Some("rb2d OBS: range not positive")
    } else if max_range.is_some_and(|m| range > m + 5.0 * sigma_r) {
        Some("rb2d OBS: range beyond max_range + 5 sigma_r")
    } else {
        None
    }
}

fn read_truth(fields: &Fields, state: &mut State, out: &mut VecDeque<TimedEvent>) -> Result<()> {
    fields.expect_len(5, "GT k x y th")?;
    let [x, y, theta] = fields.f64s(2, "pose")?;
    let time_step = state.params.get("dt", fields)?;
    let k = step(fields, 2, state, out)?;
    let pose = Pose2::new(x, y, theta);
    push(
        out,
        k as f64 * time_step,
        Event::GroundTruth {
            pose,
            kind: TruthKind::True,
        },
    );
    Ok(())
}

/// The `PARAM` values of an rb2d log (units: m, rad, s). The range-bearing values are
/// optional: a log without observations needs none of them.
#[derive(Clone, Debug, PartialEq)]
pub struct Rb2dParams {
    /// Nominal step, s (`PARAM dt`): step `k` is at time `k dt`.
    pub dt: f64,
    /// Forward speed noise, m/s (`PARAM sigma_v`).
    pub sigma_v: f64,
    /// Yaw rate noise, rad/s (`PARAM sigma_w`).
    pub sigma_w: f64,
    /// Range noise, m (`PARAM sigma_r`); needed when there are observations.
    pub sigma_r: Option<f64>,
    /// Bearing noise, rad (`PARAM sigma_b`); needed when there are observations.
    pub sigma_b: Option<f64>,
    /// Sensor range, m (`PARAM max_range`).
    pub max_range: Option<f64>,
}

impl Rb2dParams {
    fn check(&self) -> Result<()> {
        let positive = [("dt", Some(self.dt)), ("sigma_r", self.sigma_r)]
            .into_iter()
            .chain([("sigma_b", self.sigma_b), ("max_range", self.max_range)]);
        for (name, value) in positive {
            if let Some(v) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(SensorError::InvalidArgument(format!(
                    "rb2d parameter {name} must be finite and positive, got {v}"
                )));
            }
        }
        for (name, v) in [("sigma_v", self.sigma_v), ("sigma_w", self.sigma_w)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SensorError::InvalidArgument(format!(
                    "rb2d parameter {name} must be finite and non-negative, got {v}"
                )));
            }
        }
        Ok(())
    }
}

/// The records of one step.
#[derive(Default)]
struct StepRecords {
    odometry: Option<Pose2>,
    observations: Vec<(i64, f64, f64)>,
    truth: Option<Pose2>,
}

/// The rb2d text of `dataset` (see [`write_rb2d`]); `comment` becomes `#` lines at the top.
pub fn rb2d_text(dataset: &Dataset, params: &Rb2dParams, comment: &str) -> Result<String> {
    params.check()?;
    let mut steps: std::collections::BTreeMap<u64, StepRecords> = Default::default();
    for event in &dataset.events {
        let k = step_of(event.time, params.dt)?;
        let records = steps.entry(k).or_default();
        let invalid = |message: String| {
            Err(SensorError::InvalidArgument(format!(
                "rb2d, step {k} (time {}): {message}",
                event.time
            )))
        };
        match &event.event {
            Event::Motion(motion) => {
                if k == 0 {
                    return invalid("a motion cannot end at step 0".into());
                }
                if records.odometry.is_some() {
                    return invalid(
                        "two motions end at this step (rb2d has one ODOM per step)".into(),
                    );
                }
                records.odometry = Some(motion.predict(&Pose2::identity())?.pose);
            }
            Event::Observations(observations) => {
                for observation in observations {
                    match range_bearing(observation, params) {
                        Ok(record) => records.observations.push(record),
                        Err(message) => return invalid(message),
                    }
                }
            }
            Event::GroundTruth {
                pose,
                kind: TruthKind::True,
            } => {
                if records.truth.is_some() {
                    return invalid("two true poses at this step".into());
                }
                records.truth = Some(*pose);
            }
            Event::GroundTruth { .. }
            | Event::Scan { .. }
            | Event::Image { .. }
            | Event::Gps(_) => {}
        }
    }
    let mut text = String::new();
    // Writing to a String cannot fail.
    for line in comment.lines() {
        let _ = writeln!(text, "# {line}");
    }
    let optional = [
        ("sigma_r", params.sigma_r),
        ("sigma_b", params.sigma_b),
        ("max_range", params.max_range),
    ];
    let given = [
        ("dt", Some(params.dt)),
        ("sigma_v", Some(params.sigma_v)),
        ("sigma_w", Some(params.sigma_w)),
    ];
    for (name, value) in given.into_iter().chain(optional) {
        if let Some(value) = value {
            let _ = writeln!(text, "PARAM {name} {value}");
        }
    }
    for landmark in &dataset.landmarks {
        let p = landmark.position;
        let _ = writeln!(text, "LM {} {} {}", landmark.id, p.x, p.y);
    }
    for (k, records) in &steps {
        if let Some(d) = records.odometry {
            let _ = writeln!(text, "ODOM {k} {} {} {} {}", params.dt, d.x, d.y, d.theta);
        }
        for (id, range, bearing) in &records.observations {
            let _ = writeln!(text, "OBS {k} {id} {range} {bearing}");
        }
        if let Some(p) = records.truth {
            let _ = writeln!(text, "GT {k} {} {} {}", p.x, p.y, p.theta);
        }
    }
    Ok(text)
}

/// Writes `dataset` as an rb2d log, completely or not at all ([`write_atomically`]).
///
/// - `PARAM` lines from `params`; `LM` lines from [`Dataset::landmarks`].
/// - Every event's time must be a multiple `k dt` of `params.dt` (within 1e-6 of a step).
/// - A [`Event::Motion`] ending at step `k` becomes `ODOM k dt dx dy dth` with `(dx, dy, dth)`
///   its pose increment (the motion applied to the identity pose). A [`Unicycle`] with
///   [`Integration::Euler`] gives `dy = 0`, which the reader turns back into the same unicycle;
///   any other motion (e.g. an exact arc) gives its exact increment, which the reader turns
///   into a [`PoseIncrement`] reproducing it (with the reader's covariance for increments).
/// - Each [`RangeBearing`] observation becomes `OBS k id range bearing` (`id` -1 without a
///   landmark id); observations must have the sensor at the robot origin and the noise of
///   `params` (the file holds one `sigma_r` and one `sigma_b`), and other measurement types are
///   errors.
/// - A [`TruthKind::True`] pose becomes `GT k x y th`; reference poses, scans, images and GPS
///   fixes are not written.
///
/// Numbers are written in Rust's shortest round-trip form, so they read back exactly.
///
/// ```
/// use slam_sensors::data::rb2d::{Rb2dParams, read_rb2d, write_rb2d};
/// use slam_sensors::odometry::{Integration, Unicycle};
/// use slam_sensors::{Clock, Dataset, Event};
/// let mut data = Dataset::new("tiny", Clock::Seconds);
/// let step = Unicycle::new(1.0, 0.5, 0.1, 0.1, 0.03, Integration::Euler).unwrap();
/// data.push(0.1, Event::Motion(Box::new(step)));
/// let params = Rb2dParams { dt: 0.1, sigma_v: 0.1, sigma_w: 0.03, sigma_r: None, sigma_b: None, max_range: None };
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("rb2d-write-doc.txt");
/// write_rb2d(&path, &data, &params, "one step").unwrap();
/// let text = std::fs::read_to_string(&path).unwrap();
/// assert!(text.contains("ODOM 1 0.1 0.1 0 0.05"), "{text}");
/// assert_eq!(read_rb2d(&path).unwrap().counts().motion, 1);
/// ```
pub fn write_rb2d(
    path: &Path,
    dataset: &Dataset,
    params: &Rb2dParams,
    comment: &str,
) -> Result<()> {
    write_atomically(path, rb2d_text(dataset, params, comment)?.as_bytes())
}

/// The step `k` of an event at `time`, when `time` is `k dt`.
fn step_of(time: f64, dt: f64) -> Result<u64> {
    let k = (time / dt).round();
    if !(k >= 0.0 && (time / dt - k).abs() <= 1e-6 && k < 9.0e15) {
        return Err(SensorError::InvalidArgument(format!(
            "rb2d: event time {time} is not a non-negative multiple of dt {dt}"
        )));
    }
    Ok(k as u64)
}

/// An observation as `(id, range, bearing)`, or why rb2d cannot hold it.
fn range_bearing(
    observation: &Observation,
    params: &Rb2dParams,
) -> std::result::Result<(i64, f64, f64), String> {
    let Some(rb) = observation
        .measurement
        .as_any()
        .downcast_ref::<RangeBearing>()
    else {
        return Err(format!(
            "rb2d holds range-bearing observations only, got a measurement of a {}",
            observation.measurement.feature_type_name()
        ));
    };
    let mount = &observation.robot_from_sensor;
    if mount.to_vector().amax() > 1e-12 {
        return Err(format!(
            "rb2d observations are taken at the robot origin, this sensor is at {mount:?}"
        ));
    }
    let same = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() <= 1e-9 * b.abs());
    if !same(params.sigma_r, rb.sigma_range) || !same(params.sigma_b, rb.sigma_bearing) {
        return Err(format!(
            "observation noise (sigma_r {}, sigma_b {}) differs from the PARAM values ({:?}, {:?})",
            rb.sigma_range, rb.sigma_bearing, params.sigma_r, params.sigma_b
        ));
    }
    let id = match observation.landmark_id {
        None => -1,
        Some(id) => i64::try_from(id).map_err(|_| format!("landmark id {id} is too large"))?,
    };
    Ok((id, rb.range, rb.bearing))
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::nalgebra::Vector3;

    fn params() -> Rb2dParams {
        Rb2dParams {
            dt: 0.1,
            sigma_v: 0.1,
            sigma_w: 0.02,
            sigma_r: Some(0.1),
            sigma_b: Some(0.01),
            max_range: Some(10.0),
        }
    }

    fn observation(sigma_r: f64, mount: Pose3) -> Event {
        Event::Observations(vec![Observation {
            robot_from_sensor: mount,
            measurement: Arc::new(RangeBearing::new(3.0, 0.5, sigma_r, 0.01).unwrap()),
            landmark_id: Some(4),
        }])
    }

    #[test]
    fn records_are_ordered_within_a_step() {
        let mut data = Dataset::new("t", Clock::Seconds);
        data.push(0.0, observation(0.1, Pose3::identity()));
        let truth = |x| Event::GroundTruth {
            pose: Pose2::new(x, 0.0, 0.0),
            kind: TruthKind::True,
        };
        data.push(0.1, truth(0.1));
        data.push(0.1, observation(0.1, Pose3::identity()));
        let step = Unicycle::new(1.0, 0.0, 0.1, 0.1, 0.02, Integration::Arc).unwrap();
        data.push(0.1, Event::Motion(Box::new(step)));
        let text = rb2d_text(&data, &params(), "c").unwrap();
        let records: Vec<_> = text
            .lines()
            .filter(|l| !l.starts_with("PARAM"))
            .map(|l| l.split_whitespace().take(2).collect::<Vec<_>>().join(" "))
            .collect();
        assert_eq!(records, ["# c", "OBS 0", "ODOM 1", "OBS 1", "GT 1"]);
    }

    #[test]
    fn what_rb2d_cannot_hold_is_an_error() {
        let cases: [(f64, Event, &str); 4] = [
            (
                0.15,
                observation(0.1, Pose3::identity()),
                "not a non-negative multiple",
            ),
            (
                0.1,
                observation(0.2, Pose3::identity()),
                "differs from the PARAM",
            ),
            (
                0.1,
                observation(0.1, Pose3::new(Vector3::new(0.2, 0.0, 0.0), 0.0, 0.0, 0.0)),
                "robot origin",
            ),
            (
                0.0,
                Event::Motion(Box::new(
                    Unicycle::new(1.0, 0.0, 0.1, 0.1, 0.02, Integration::Euler).unwrap(),
                )),
                "cannot end at step 0",
            ),
        ];
        for (time, event, reason) in cases {
            let mut data = Dataset::new("t", Clock::Seconds);
            data.push(time, event);
            let e = rb2d_text(&data, &params(), "").unwrap_err().to_string();
            assert!(e.contains(reason), "{e} vs {reason}");
        }
        let mut bad = params();
        bad.sigma_r = Some(-1.0);
        let empty = Dataset::new("t", Clock::Seconds);
        assert!(rb2d_text(&empty, &bad, "").is_err());
    }
}
