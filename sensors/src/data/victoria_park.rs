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
//! The files are read side by side and merged by time, so each must be in order: odometry,
//! laser frame and GPS times non-decreasing, detections grouped by frame in frame order.
//!
//! Bearings in `tree_detections.csv` are in the laser's own convention, 0 to pi with pi/2
//! straight ahead; the reader subtracts pi/2 to get the sensor-frame bearing (0 ahead,
//! counter-clockwise positive). The radius is half the detected diameter. There is no ground
//! truth; the GPS is intermittent and jumps.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use slam_core::Observation;
use slam_core::nalgebra::Vector2;

use super::{
    Fields, Intervals, Lines, Point, at, check_sigmas, in_time_order, merge_by_time, merge_points,
    missing,
};
use crate::error::{Result, SensorError};
use crate::events::{Clock, Dataset, DatasetInfo, Event, EventStream, SkipCounter};
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
    /// Standard deviation of a trunk's range, m. Default 0.5: the detector's range is the
    /// middle beam's plus half the trunk width it measured, so it carries the width's error
    /// and the trunk's shape; the reference EKF codes on this dataset use 0.5-1 m.
    pub sigma_range: f64,
    /// Standard deviation of a trunk's bearing, rad. Default 1 degree.
    pub sigma_bearing: f64,
    /// Standard deviation of a trunk's radius, m. Default 0.15: the width is counted in
    /// 0.5-degree beams (a step of 0.4 m in diameter at 50 m), and a trunk seen from another
    /// side or height is wider or narrower; the radius only decides association.
    pub sigma_radius: f64,
}

impl Default for VictoriaParkOptions {
    fn default() -> Self {
        VictoriaParkOptions {
            vehicle: AckermannParams::default(),
            sigma_speed: 0.5,
            sigma_steering: 3f64.to_radians(),
            sigma_range: 0.5,
            sigma_bearing: 1f64.to_radians(),
            sigma_radius: 0.15,
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
/// events. This is [`stream_victoria_park`] collected.
///
/// Malformed lines (wrong header, field count, non-numeric or non-finite values, a steering
/// angle the [`Ackermann`] model rejects, a detection whose frame or time disagrees with
/// `laser_frame_times.csv`, a non-positive range or diameter, odometry times going
/// backwards) are errors naming `file:line`.
pub fn read_victoria_park(dir: &Path, options: &VictoriaParkOptions) -> Result<Dataset> {
    stream_victoria_park(dir, options)?.into_dataset()
}

/// Reads Victoria Park one line at a time: the events of [`read_victoria_park`], in the same
/// order, from one reader per file merged by time.
///
/// Bad options, a missing data folder or file and a wrong header are errors of this call; a
/// malformed line is an `Err` item when the stream reaches it. The merge needs each file in
/// time order: laser frame times and GPS times going backwards, and detections out of frame
/// order, are errors naming `file:line`.
pub fn stream_victoria_park(dir: &Path, options: &VictoriaParkOptions) -> Result<EventStream> {
    check_options(options)?;
    let dir = data_folder(dir)?;
    let odometry_file = dir.join(ODOMETRY.0);
    let odometry = Csv::open(&odometry_file, ODOMETRY.1)?;
    let frames_file = dir.join(FRAMES.0);
    let frames = Csv::open(&frames_file, FRAMES.1)?;
    let detections_file = dir.join(DETECTIONS.0);
    let detections = Csv::open(&detections_file, DETECTIONS.1)?;
    let gps_file = dir.join(GPS.0);
    let gps = Csv::open(&gps_file, GPS.1)?;

    let rows = {
        let options = options.clone();
        odometry.rows(move |f| {
            let [time_ms, speed, steering] = f.f64s(0, "odometry")?;
            ackermann(speed, steering, 0.0, &options).map_err(|e| f.wrap(e))?;
            Ok((f.line(), time_ms / 1000.0, (speed, steering)))
        })
    };
    let intervals = Intervals::new(&odometry_file, rows);
    let skipped = SkipCounter::default();
    let observations = FrameObservations {
        frames,
        detections: Detections(detections).peekable(),
        detections_file,
        options: options.clone(),
        count: 0,
        skipped: skipped.clone(),
    };
    let fixes = gps.rows(|f| {
        let [time_ms, lo, la] = f.f64s(0, "GPS")?;
        Ok(Point {
            line: f.line(),
            time: time_ms / 1000.0,
            event: Event::Gps(Vector2::new(lo, la)),
        })
    });
    let points = merge_points(
        in_time_order(&frames_file, observations),
        in_time_order(&gps_file, fixes),
    );
    let gps_antenna = options.vehicle.gps_antenna();
    let options = options.clone();
    let events = merge_by_time(intervals, points, move |interval, dt| {
        let (speed, steering) = interval.control;
        ackermann(speed, steering, dt, &options)
            .map(|a| Event::Motion(Box::new(a)))
            .map_err(|e| at(&odometry_file, interval.line, e))
    });
    let info = DatasetInfo {
        name: "Victoria Park".into(),
        clock: Clock::Seconds,
        landmarks: Vec::new(),
        gps_antenna,
    };
    Ok(EventStream::new(info, events).with_skipped(skipped))
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

/// The data lines of a CSV file whose first line must be `header` (a leading BOM and
/// surrounding blanks aside); blank lines are skipped, and each line must have the header's
/// number of fields.
struct Csv {
    lines: Lines,
    header: &'static str,
    columns: usize,
}

impl Csv {
    /// Opens `path` and checks its header.
    fn open(path: &Path, header: &'static str) -> Result<Csv> {
        let mut lines = Lines::open(path)?;
        let first = lines.next().transpose()?.map_or(String::new(), |(_, l)| l);
        let first = first.trim_start_matches('\u{feff}').trim();
        if first != header {
            return Err(SensorError::parse(
                path,
                1,
                format!("expected the header `{header}`, got `{first}`"),
            ));
        }
        Ok(Csv {
            lines,
            header,
            columns: header.split(',').count(),
        })
    }

    /// The next data line, handed to `row` with its fields checked for their number.
    fn next_row<T>(&mut self, row: impl FnOnce(&Fields) -> Result<T>) -> Option<Result<T>> {
        loop {
            let (line, content) = match self.lines.next()? {
                Ok(next) => next,
                Err(e) => return Some(Err(e)),
            };
            if content.trim().is_empty() {
                continue;
            }
            let fields = Fields::csv(self.lines.path(), line, &content);
            return Some(
                fields
                    .expect_len(self.columns, self.header)
                    .and_then(|()| row(&fields)),
            );
        }
    }

    /// Every data line through `row`.
    fn rows<T>(
        mut self,
        mut row: impl FnMut(&Fields) -> Result<T>,
    ) -> impl Iterator<Item = Result<T>> {
        std::iter::from_fn(move || self.next_row(&mut row))
    }
}

/// One line of `tree_detections.csv`.
struct Detection {
    line: usize,
    frame: usize,
    time: f64,
    range: f64,
    bearing: f64,
    diameter: f64,
}

/// The lines of `tree_detections.csv`.
struct Detections(Csv);

impl Iterator for Detections {
    type Item = Result<Detection>;

    fn next(&mut self) -> Option<Self::Item> {
        self.0.next_row(|f| {
            let frame = f.usize(0, "frame")?;
            let [time, range, bearing, diameter] = f.f64s(1, "detection")?;
            Ok(Detection {
                line: f.line(),
                frame,
                time,
                range,
                bearing,
                diameter,
            })
        })
    }
}

/// One [`Event::Observations`] per line of `laser_frame_times.csv` (frames numbered 0, 1,
/// 2, ...), holding the detections of that frame.
struct FrameObservations {
    frames: Csv,
    detections: std::iter::Peekable<Detections>,
    detections_file: PathBuf,
    options: VictoriaParkOptions,
    /// Frames read so far.
    count: usize,
    /// Where skipped detections are counted.
    skipped: SkipCounter,
}

impl FrameObservations {
    /// The observations of frame `frame` at `frame_time`: the detections that follow, up to
    /// the first of a later frame.
    fn observations(&mut self, frame: usize, frame_time: f64) -> Result<Vec<Observation>> {
        let sigmas = [
            self.options.sigma_range,
            self.options.sigma_bearing,
            self.options.sigma_radius,
        ];
        let file = &self.detections_file;
        let mut observations = Vec::new();
        // The detections up to this frame, and an error that comes first.
        let this_frame = |d: &Result<Detection>| d.as_ref().is_ok_and(|d| d.frame <= frame);
        while let Some(next) = self.detections.next_if(|d| d.is_err() || this_frame(d)) {
            let d = next?;
            if d.frame < frame {
                return Err(SensorError::parse(
                    file,
                    d.line,
                    format!(
                        "frame {} after frame {frame}: detections must be in frame order",
                        d.frame
                    ),
                ));
            }
            if (d.time - frame_time).abs() > TIME_TOLERANCE {
                return Err(SensorError::parse(
                    file,
                    d.line,
                    format!(
                        "frame {frame} is at {frame_time} s in {}, not {} s",
                        FRAMES.0, d.time
                    ),
                ));
            }
            if d.range <= 0.0 || d.diameter <= 0.0 {
                let reason = if d.range <= 0.0 {
                    "Victoria Park detection: range not positive"
                } else {
                    "Victoria Park detection: diameter not positive"
                };
                self.skipped.count_reading(reason);
                continue;
            }
            let bearing = d.bearing - std::f64::consts::FRAC_PI_2;
            let pole = PoleObservation::new(d.range, bearing, d.diameter / 2.0, sigmas)
                .map_err(|e| at(file, d.line, e.into()))?;
            observations.push(Observation {
                robot_from_sensor: self.options.vehicle.robot_from_laser(),
                measurement: Arc::new(pole),
                landmark_id: None,
            });
        }
        Ok(observations)
    }
}

impl Iterator for FrameObservations {
    type Item = Result<Point>;

    fn next(&mut self) -> Option<Self::Item> {
        let expected = self.count;
        let row = self.frames.next_row(|f| {
            let frame = f.usize(0, "frame")?;
            if frame != expected {
                return Err(f.error(format!("expected frame {expected}, got {frame}")));
            }
            Ok((f.line(), f.f64(1, "time_s")?))
        });
        let Some(row) = row else {
            // Detections left over name frames that are not in the file.
            let (line, frame) = match self.detections.next()? {
                Ok(d) => (d.line, d.frame),
                Err(e) => return Some(Err(e)),
            };
            return Some(Err(SensorError::parse(
                &self.detections_file,
                line,
                format!(
                    "frame {frame} is not in {} ({} frames)",
                    FRAMES.0, self.count
                ),
            )));
        };
        Some(row.and_then(|(line, time)| {
            self.count += 1;
            let observations = self.observations(expected, time)?;
            Ok(Point {
                line,
                time,
                event: Event::Observations(observations),
            })
        }))
    }
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
                "gps.csv:2:3: field 2 (GPS): expected a number, got `x`",
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
