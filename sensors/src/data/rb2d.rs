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
//! Event times are `k * dt` seconds with `dt` the `PARAM dt`. Records are sorted by step,
//! and within one step come `ODOM`, then `OBS`, then `GT`; a record out of that order is a
//! "step going backwards" error. A record that needs a parameter (`ODOM`: `dt`, `sigma_v`,
//! `sigma_w`; `OBS`: `dt`, `sigma_r`, `sigma_b`; `GT`: `dt`) before its `PARAM` line is an
//! error too, as are unknown records and parameter names, wrong field counts, and
//! non-numeric or non-finite values, each with `file:line` and the reason.

use std::path::Path;

use slam_core::nalgebra::{Matrix3, Vector2, Vector3};
use slam_core::{Observation, Pose2, Pose3};

use super::{Fields, count_skipped, numbered_lines, read_text};
use crate::error::Result;
use crate::events::{Clock, Dataset, Event, KnownLandmark, TruthKind};
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
    /// `(step, rank)` of the last `ODOM` (0), `OBS` (1) or `GT` (2).
    last: Option<(u64, u8)>,
    /// The step and the observations of the `OBS` lines read last.
    pending: Option<(u64, Vec<Observation>)>,
}

/// Reads an rb2d log; see the [module](self) for the records and what is rejected.
///
/// ```
/// use slam_sensors::data::read_rb2d;
/// use slam_sensors::{Event, TruthKind};
/// let path = std::env::temp_dir().join(format!("rb2d-doc-{}.txt", std::process::id()));
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
/// # std::fs::remove_file(&path).unwrap();
/// ```
pub fn read_rb2d(path: &Path) -> Result<Dataset> {
    let text = read_text(path)?;
    let name = path
        .file_name()
        .unwrap_or(path.as_os_str())
        .to_string_lossy();
    let mut dataset = Dataset::new(name, Clock::Seconds);
    let mut state = State::default();
    for (line, content) in numbered_lines(&text) {
        let trimmed = content.trim();
        if trimmed.starts_with('#') {
            count_skipped(&mut dataset, "#");
        } else if !trimmed.is_empty() {
            read_record(
                &Fields::whitespace(path, line, content),
                &mut state,
                &mut dataset,
            )?;
        }
    }
    flush(&mut state, &mut dataset);
    Ok(dataset)
}

fn read_record(fields: &Fields, state: &mut State, dataset: &mut Dataset) -> Result<()> {
    match fields.first() {
        "PARAM" => state.params.set(fields),
        "LM" => read_landmark(fields, dataset),
        "ODOM" => read_odometry(fields, state, dataset),
        "OBS" => read_observation(fields, state, dataset),
        "GT" => read_truth(fields, state, dataset),
        other => Err(fields.error(format!(
            "unknown record `{other}` (expected PARAM, LM, ODOM, OBS or GT)"
        ))),
    }
}

/// Emits the pending observations, if any.
fn flush(state: &mut State, dataset: &mut Dataset) {
    if let Some((step, observations)) = state.pending.take() {
        let dt = state.params.values[0].map_or(0.0, |(v, _)| v);
        dataset.push(step as f64 * dt, Event::Observations(observations));
    }
}

/// The step of a record of `rank` (ODOM 0, OBS 1, GT 2), checked against the previous one;
/// a step record other than another `OBS` of the same step flushes the pending observations.
fn step(fields: &Fields, rank: u8, state: &mut State, dataset: &mut Dataset) -> Result<u64> {
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
        flush(state, dataset);
    }
    state.last = Some((k, rank));
    Ok(k)
}

fn read_landmark(fields: &Fields, dataset: &mut Dataset) -> Result<()> {
    fields.expect_len(4, "LM id x y")?;
    let id = fields.u64(1, "landmark id")?;
    let [x, y] = fields.f64s(2, "landmark position")?;
    dataset.landmarks.push(KnownLandmark {
        id,
        position: Vector2::new(x, y),
    });
    Ok(())
}

fn read_odometry(fields: &Fields, state: &mut State, dataset: &mut Dataset) -> Result<()> {
    fields.expect_len(6, "ODOM k dt dx dy dth")?;
    let [dt, dx, dy, dth] = fields.f64s(2, "odometry")?;
    let time_step = state.params.get("dt", fields)?;
    let sigma_v = state.params.get("sigma_v", fields)?;
    let sigma_w = state.params.get("sigma_w", fields)?;
    if dt <= 0.0 {
        return Err(fields.error(format!("ODOM dt must be positive, got {dt}")));
    }
    let k = step(fields, 0, state, dataset)?;
    if k == 0 {
        return Err(fields.error("ODOM step must be at least 1 (it leads from pose k-1 to pose k)"));
    }
    let motion = motion(dt, dx, dy, dth, sigma_v, sigma_w).map_err(|e| fields.wrap(e))?;
    dataset.push(k as f64 * time_step, Event::Motion(motion));
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

fn read_observation(fields: &Fields, state: &mut State, dataset: &mut Dataset) -> Result<()> {
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
    let k = step(fields, 1, state, dataset)?;
    let model =
        RangeBearing::new(range, bearing, sigma_r, sigma_b).map_err(|e| fields.wrap(e.into()))?;
    let observation = Observation {
        robot_from_sensor: Pose3::identity(),
        measurement: Box::new(model),
        landmark_id,
    };
    state
        .pending
        .get_or_insert_with(|| (k, Vec::new()))
        .1
        .push(observation);
    Ok(())
}

fn read_truth(fields: &Fields, state: &mut State, dataset: &mut Dataset) -> Result<()> {
    fields.expect_len(5, "GT k x y th")?;
    let [x, y, theta] = fields.f64s(2, "pose")?;
    let time_step = state.params.get("dt", fields)?;
    let k = step(fields, 2, state, dataset)?;
    let pose = Pose2::new(x, y, theta);
    dataset.push(
        k as f64 * time_step,
        Event::GroundTruth {
            pose,
            kind: TruthKind::True,
        },
    );
    Ok(())
}
