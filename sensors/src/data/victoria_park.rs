//! Victoria Park (Guivant & Nebot): a truck driving through a park, tree trunks as poles.
//!
//! Reads the text version in the dataset's `converted/` folder (see the dataset's
//! `SOURCE.md`); each file starts with a header line that must match exactly:
//!
//! | file | header | use |
//! |---|---|---|
//! | `odometry.csv` | `time_ms,speed_mps,steering_rad` | [`Ackermann`] motion |
//! | `laser_frame_times.csv` | `frame,time_s` | one observation event per frame |
//! | `tree_detections.csv` | `frame,time_s,range_m,bearing_rad,diameter_m` | [`PoleObservation`]s |
//! | `gps.csv` | `time_ms,Lo_m,La_m` | [`Event::Gps`] `(Lo_m, La_m)` |
//!
//! Odometry row `k` holds its speed and steering from its time until row `k + 1`'s; the last
//! row has no duration and gives no motion. Laser frames and GPS fixes that fall strictly
//! inside an interval split it (see [`crate::data`]). Every laser frame gives one
//! [`Event::Observations`], also when it holds no detection (19 frames of the real data).
//!
//! Bearings in `tree_detections.csv` are in the laser's own convention, 0 to pi with pi/2
//! straight ahead; the reader subtracts pi/2 to get the sensor-frame bearing (0 ahead,
//! counter-clockwise positive). The radius is half the detected diameter. There is no ground
//! truth; the GPS is intermittent and jumps.

use std::path::{Path, PathBuf};

use slam_core::Observation;
use slam_core::nalgebra::Vector2;

use super::{
    Fields, at, check_sigmas, intervals, merge_by_time, missing, numbered_lines, read_text,
};
use crate::error::{Result, SensorError};
use crate::events::{Clock, Dataset, Event};
use crate::models::PoleObservation;
use crate::odometry::{Ackermann, AckermannParams};

/// How to read Victoria Park. The noise values are starting points, not calibrated.
#[derive(Clone, Debug)]
pub struct VictoriaParkOptions {
    /// The truck's geometry (wheelbase, encoder offset, laser mount).
    pub vehicle: AckermannParams,
    /// Standard deviation of the encoder speed, m/s. Default 0.5.
    pub sigma_speed: f64,
    /// Standard deviation of the steering angle, rad. Default 3 degrees.
    pub sigma_steering: f64,
    /// Standard deviation of a trunk's range, m. Default 0.2.
    pub sigma_range: f64,
    /// Standard deviation of a trunk's bearing, rad. Default 1 degree.
    pub sigma_bearing: f64,
    /// Standard deviation of a trunk's radius, m. Default 0.05.
    pub sigma_radius: f64,
}

impl Default for VictoriaParkOptions {
    fn default() -> Self {
        VictoriaParkOptions {
            vehicle: AckermannParams::default(),
            sigma_speed: 0.5,
            sigma_steering: 3f64.to_radians(),
            sigma_range: 0.2,
            sigma_bearing: 1f64.to_radians(),
            sigma_radius: 0.05,
        }
    }
}

const ODOMETRY: (&str, &str) = ("odometry.csv", "time_ms,speed_mps,steering_rad");
const FRAMES: (&str, &str) = ("laser_frame_times.csv", "frame,time_s");
const DETECTIONS: (&str, &str) = (
    "tree_detections.csv",
    "frame,time_s,range_m,bearing_rad,diameter_m",
);
const GPS: (&str, &str) = ("gps.csv", "time_ms,Lo_m,La_m");

/// Largest difference between a detection's time and its frame's time, s.
const TIME_TOLERANCE: f64 = 1e-9;

/// Reads Victoria Park from the dataset root (holding `converted/`) or from the `converted/`
/// folder itself. Times are seconds ([`Clock::Seconds`]); see the [module](self) for the
/// events.
///
/// Malformed lines (wrong header, field count, non-numeric or non-finite values, a steering
/// angle the [`Ackermann`] model rejects, a detection whose frame or time disagrees with
/// `laser_frame_times.csv`, a non-positive range or diameter, odometry times going
/// backwards) are errors naming `file:line`.
pub fn read_victoria_park(dir: &Path, options: &VictoriaParkOptions) -> Result<Dataset> {
    check_options(options)?;
    let dir = data_folder(dir)?;
    let odometry = read_odometry(&dir.join(ODOMETRY.0), options)?;
    let frame_times = read_frame_times(&dir.join(FRAMES.0))?;
    let detections = read_detections(&dir.join(DETECTIONS.0), &frame_times, options)?;
    let gps = read_gps(&dir.join(GPS.0))?;

    let mut points: Vec<(f64, Event)> = frame_times
        .into_iter()
        .zip(detections)
        .map(|(t, obs)| (t, Event::Observations(obs)))
        .collect();
    points.extend(gps.into_iter().map(|(t, p)| (t, Event::Gps(p))));

    let odometry_file = dir.join(ODOMETRY.0);
    let intervals = intervals(&odometry_file, &odometry)?;
    let mut dataset = Dataset::new("Victoria Park", Clock::Seconds);
    merge_by_time(&mut dataset, &intervals, points, |interval, dt| {
        let (speed, steering) = interval.control;
        ackermann(speed, steering, dt, options)
            .map(|a| Event::Motion(Box::new(a)))
            .map_err(|e| at(&odometry_file, interval.line, e))
    })?;
    Ok(dataset)
}

fn check_options(options: &VictoriaParkOptions) -> Result<()> {
    check_sigmas(
        "Victoria Park options",
        &[
            ("sigma_range", options.sigma_range),
            ("sigma_bearing", options.sigma_bearing),
            ("sigma_radius", options.sigma_radius),
        ],
        true,
    )?;
    check_sigmas(
        "Victoria Park options",
        &[
            ("sigma_speed", options.sigma_speed),
            ("sigma_steering", options.sigma_steering),
        ],
        false,
    )
}

/// `dir/converted` when it holds the odometry, else `dir` when it does.
fn data_folder(dir: &Path) -> Result<PathBuf> {
    let converted = dir.join("converted");
    if converted.join(ODOMETRY.0).is_file() {
        Ok(converted)
    } else if dir.join(ODOMETRY.0).is_file() {
        Ok(dir.to_path_buf())
    } else {
        Err(missing(
            dir,
            "Victoria Park data (converted/odometry.csv or odometry.csv)",
        ))
    }
}

fn ackermann(
    speed: f64,
    steering: f64,
    dt: f64,
    options: &VictoriaParkOptions,
) -> Result<Ackermann> {
    Ackermann::new(
        speed,
        steering,
        dt,
        options.sigma_speed,
        options.sigma_steering,
        options.vehicle.clone(),
    )
}

/// Reads a CSV file whose first line must be `header`, and hands each data line (with the
/// expected number of fields) to `row`. Blank lines are ignored.
fn read_csv(path: &Path, header: &str, mut row: impl FnMut(&Fields) -> Result<()>) -> Result<()> {
    let text = read_text(path)?;
    let columns = header.split(',').count();
    let mut lines = numbered_lines(&text);
    let first = lines.next().map_or("", |(_, l)| l);
    let first = first.trim_start_matches('\u{feff}').trim();
    if first != header {
        return Err(SensorError::parse(
            path,
            1,
            format!("expected the header `{header}`, got `{first}`"),
        ));
    }
    for (line, content) in lines.filter(|(_, l)| !l.trim().is_empty()) {
        let fields = Fields::csv(path, line, content);
        fields.expect_len(columns, header)?;
        row(&fields)?;
    }
    Ok(())
}

/// `(line, time s, (speed, steering))` per row; each row's controls are checked.
fn read_odometry(path: &Path, options: &VictoriaParkOptions) -> Result<Vec<super::ControlRow>> {
    let mut rows = Vec::new();
    read_csv(path, ODOMETRY.1, |f| {
        let [time_ms, speed, steering] = f.f64s(0, "odometry")?;
        ackermann(speed, steering, 0.0, options).map_err(|e| f.wrap(e))?;
        rows.push((f.line(), time_ms / 1000.0, (speed, steering)));
        Ok(())
    })?;
    Ok(rows)
}

/// The time of each frame, indexed by frame number (which must count 0, 1, 2, ...).
fn read_frame_times(path: &Path) -> Result<Vec<f64>> {
    let mut times = Vec::new();
    read_csv(path, FRAMES.1, |f| {
        let frame = f.usize(0, "frame")?;
        if frame != times.len() {
            return Err(f.error(format!("expected frame {}, got {frame}", times.len())));
        }
        times.push(f.f64(1, "time_s")?);
        Ok(())
    })?;
    Ok(times)
}

/// The observations of each frame.
fn read_detections(
    path: &Path,
    frame_times: &[f64],
    options: &VictoriaParkOptions,
) -> Result<Vec<Vec<Observation>>> {
    let mut frames: Vec<Vec<Observation>> = frame_times.iter().map(|_| Vec::new()).collect();
    let sigmas = [
        options.sigma_range,
        options.sigma_bearing,
        options.sigma_radius,
    ];
    read_csv(path, DETECTIONS.1, |f| {
        let frame = f.usize(0, "frame")?;
        let [time, range, bearing, diameter] = f.f64s(1, "detection")?;
        let Some(&frame_time) = frame_times.get(frame) else {
            return Err(f.error(format!(
                "frame {frame} is not in {} ({} frames)",
                FRAMES.0,
                frame_times.len()
            )));
        };
        if (time - frame_time).abs() > TIME_TOLERANCE {
            return Err(f.error(format!(
                "frame {frame} is at {frame_time} s in {}, not {time} s",
                FRAMES.0
            )));
        }
        let bearing = bearing - std::f64::consts::FRAC_PI_2;
        let pole = PoleObservation::new(range, bearing, diameter / 2.0, sigmas)
            .map_err(|e| f.wrap(e.into()))?;
        frames[frame].push(Observation {
            robot_from_sensor: options.vehicle.robot_from_laser(),
            measurement: Box::new(pole),
            landmark_id: None,
        });
        Ok(())
    })?;
    Ok(frames)
}

/// `(time s, (Lo_m, La_m))` per fix.
fn read_gps(path: &Path) -> Result<Vec<(f64, Vector2<f64>)>> {
    let mut fixes = Vec::new();
    read_csv(path, GPS.1, |f| {
        let [time_ms, lo, la] = f.f64s(0, "GPS")?;
        fixes.push((time_ms / 1000.0, Vector2::new(lo, la)));
        Ok(())
    })?;
    Ok(fixes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_dir(name: &str, files: &[(&str, &str)]) -> tempfile::TempDir {
        let dir = super::super::test_dir(&format!("vp-{name}"));
        std::fs::create_dir_all(dir.path().join("converted")).unwrap();
        let defaults = [
            (
                ODOMETRY.0,
                "time_ms,speed_mps,steering_rad\n1000,2.0,0.0\n2000,2.0,0.1\n3000,0.0,0.0\n",
            ),
            (FRAMES.0, "frame,time_s\n0,1.5\n1,2.0\n"),
            (
                DETECTIONS.0,
                "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,10.0,1.5707963267948966,0.4\n",
            ),
            (GPS.0, "time_ms,Lo_m,La_m\n500,1.0,2.0\n"),
        ];
        for (file, text) in defaults {
            let text = files
                .iter()
                .find(|(f, _)| *f == file)
                .map_or(text, |(_, t)| t);
            std::fs::write(dir.path().join("converted").join(file), text).unwrap();
        }
        dir
    }

    #[test]
    fn frames_split_the_odometry() {
        let dir = write_dir("split", &[]);
        let data = read_victoria_park(dir.path(), &VictoriaParkOptions::default()).unwrap();
        let kinds: Vec<(f64, &str)> = data
            .events
            .iter()
            .map(|e| match &e.event {
                Event::Motion(m) => (e.time, if m.control()[1] == 0.0 { "M0" } else { "M1" }),
                Event::Observations(o) => (e.time, if o.is_empty() { "O0" } else { "O1" }),
                Event::Gps(_) => (e.time, "G"),
                _ => unreachable!(),
            })
            .collect();
        assert_eq!(
            kinds,
            [
                (0.5, "G"),
                (1.5, "M0"),
                (1.5, "O1"),
                (2.0, "M0"),
                (2.0, "O0"),
                (3.0, "M1")
            ]
        );
        let Event::Observations(o) = &data.events[2].event else {
            panic!()
        };
        let expected = [10.0, 0.0, 0.2];
        assert!(
            (o[0].measurement.measurement_dyn()
                - slam_core::nalgebra::DVector::from_row_slice(&expected))
            .amax()
                < 1e-12
        );
        // The converted/ folder itself is accepted too.
        assert!(
            read_victoria_park(
                &dir.path().join("converted"),
                &VictoriaParkOptions::default()
            )
            .is_ok()
        );
    }

    #[test]
    fn malformed_rows_name_file_and_line() {
        let cases = [
            (
                ODOMETRY.0,
                "time_ms,speed,steering\n",
                "odometry.csv:1: expected the header",
            ),
            (
                ODOMETRY.0,
                "time_ms,speed_mps,steering_rad\n1000,2.0\n",
                "odometry.csv:2: time_ms,speed_mps,steering_rad: expected 3 fields, got 2",
            ),
            (
                ODOMETRY.0,
                "time_ms,speed_mps,steering_rad\n1000,2.0,1.5\n",
                "odometry.csv:2: steering angle",
            ),
            (
                ODOMETRY.0,
                "time_ms,speed_mps,steering_rad\n1000,2.0,0\n900,1,0\n",
                "odometry.csv:3: time goes backwards",
            ),
            (
                FRAMES.0,
                "frame,time_s\n0,1.5\n2,2.0\n",
                "laser_frame_times.csv:3: expected frame 1, got 2",
            ),
            (
                DETECTIONS.0,
                "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,10,1,0\n",
                "tree_detections.csv:2: pole range 10 and radius 0 must be positive",
            ),
            (
                DETECTIONS.0,
                "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.6,10,1,1\n",
                "tree_detections.csv:2: frame 0 is at 1.5 s",
            ),
            (
                DETECTIONS.0,
                "frame,time_s,range_m,bearing_rad,diameter_m\n\n5,1.5,10,1,1\n",
                "tree_detections.csv:3: frame 5 is not in",
            ),
            (
                GPS.0,
                "time_ms,Lo_m,La_m\n1,x,2\n",
                "gps.csv:2: field 2 (GPS): expected a number, got `x`",
            ),
        ];
        for (k, (file, text, expected)) in cases.iter().enumerate() {
            let dir = write_dir(&format!("bad{k}"), &[(file, text)]);
            let e = read_victoria_park(dir.path(), &VictoriaParkOptions::default())
                .unwrap_err()
                .to_string();
            assert!(e.contains(expected), "{e} vs {expected}");
        }
    }
}
