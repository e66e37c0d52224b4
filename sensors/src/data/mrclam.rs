//! UTIAS MR.CLAM dataset 1 (Leung et al., IJRR 2011): five robots, fifteen barcoded
//! cylindrical landmarks with surveyed positions.
//!
//! Files of the dataset folder (header lines start with `#`; columns are separated by tabs
//! and/or spaces):
//!
//! | file | columns | use |
//! |---|---|---|
//! | `Barcodes.dat` | subject, barcode | maps the barcodes seen to subjects |
//! | `Landmark_Groundtruth.dat` | subject, x, y, x_std, y_std | [`Dataset::landmarks`] (id = subject) |
//! | `Robot{N}_Odometry.dat` | time, v, omega | [`Unicycle`] motion |
//! | `Robot{N}_Measurement.dat` | time, barcode, range, bearing | [`RangeBearing`] observations |
//!
//! Odometry rows are velocity commands (about 66 Hz): row `k` holds from its time to row
//! `k + 1`'s (the last row gives no motion; rows with equal times give zero-length motion).
//! Measurements with the same timestamp form one [`Event::Observations`]; subjects 6 to 20
//! are landmarks and get `landmark_id = Some(subject)`. Measurements of robots (subjects 1 to
//! 5) are skipped and counted under `"robot"`, measurements of barcodes that `Barcodes.dat`
//! does not list under `"unknown barcode"`, and measurements of listed subjects outside both
//! ranges under `"other subject"`. Observation times that fall strictly inside an odometry
//! interval split it (see [`crate::data`]). Times are Unix seconds ([`Clock::Seconds`]).
//! There is no robot ground truth here (the Vicon files are not in the store).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use slam_core::nalgebra::Vector2;
use slam_core::{Observation, Pose3};

use super::{Fields, Intervals, Lines, Point, at, check_sigmas, merge_by_time, missing};
use crate::error::{Result, SensorError};
use crate::events::{Clock, Dataset, DatasetInfo, Event, EventStream, KnownLandmark, SkipCounter};
use crate::models::RangeBearing;
use crate::odometry::{Integration, Unicycle};

/// How to read MR.CLAM. The noise values are starting points, not calibrated.
#[derive(Clone, Debug)]
pub struct MrclamOptions {
    /// Standard deviation of the commanded forward speed, m/s. Default 0.1.
    pub sigma_v: f64,
    /// Standard deviation of the commanded yaw rate, rad/s. Default 0.2.
    pub sigma_omega: f64,
    /// How a command becomes a pose increment. Default [`Integration::Arc`].
    pub integration: Integration,
    /// Standard deviation of a range, m. Default 0.1.
    pub sigma_range: f64,
    /// Standard deviation of a bearing, rad. Default 0.05.
    pub sigma_bearing: f64,
    /// Where the camera sits on the robot. Default: the robot origin (the dataset's ranges and
    /// bearings are given from the robot centre).
    pub robot_from_sensor: Pose3,
}

impl Default for MrclamOptions {
    fn default() -> Self {
        MrclamOptions {
            sigma_v: 0.1,
            sigma_omega: 0.2,
            integration: Integration::Arc,
            sigma_range: 0.1,
            sigma_bearing: 0.05,
            robot_from_sensor: Pose3::identity(),
        }
    }
}

/// Subjects 1 to 5 are robots.
const ROBOTS: std::ops::RangeInclusive<u64> = 1..=5;
/// Subjects 6 to 20 are landmarks.
const LANDMARKS: std::ops::RangeInclusive<u64> = 6..=20;

/// One parsed measurement row.
struct Measurement {
    line: usize,
    time: f64,
    barcode: u64,
    range: f64,
    bearing: f64,
}

/// Reads robot `robot` (1 to 5) of MR.CLAM dataset 1 from the folder `dir`. This is
/// [`stream_mrclam`] collected.
///
/// A robot outside 1..=5 is an [`SensorError::InvalidArgument`]; a missing file an I/O error
/// naming it; a malformed line (wrong field count, non-numeric or non-finite value,
/// non-positive range, times going backwards) an error naming `file:line`.
pub fn read_mrclam(dir: &Path, robot: u8, options: &MrclamOptions) -> Result<Dataset> {
    stream_mrclam(dir, robot, options)?.into_dataset()
}

/// Reads robot `robot` of MR.CLAM dataset 1 one line at a time: the events of
/// [`read_mrclam`], in the same order, from the odometry and measurement files merged by
/// time.
///
/// Bad arguments, a missing file and any error in the small `Barcodes.dat` and
/// `Landmark_Groundtruth.dat` (read whole, for [`DatasetInfo::landmarks`]) are errors of this
/// call; a malformed line of the robot's files is an `Err` item when the stream reaches it.
pub fn stream_mrclam(dir: &Path, robot: u8, options: &MrclamOptions) -> Result<EventStream> {
    check_options(robot, options)?;
    let barcodes = read_barcodes(&existing(dir, "Barcodes.dat")?)?;
    let landmarks = read_landmarks(&existing(dir, "Landmark_Groundtruth.dat")?)?;
    let odometry_file = existing(dir, &format!("Robot{robot}_Odometry.dat"))?;
    let odometry = Table::open(&odometry_file, 3, "time v omega")?;
    let measurement_file = existing(dir, &format!("Robot{robot}_Measurement.dat"))?;
    let measurements = Table::open(&measurement_file, 4, "time barcode range bearing")?;

    let rows = {
        let options = options.clone();
        odometry.rows(move |f| {
            let [time, v, omega] = f.f64s(0, "odometry")?;
            unicycle(v, omega, 0.0, &options).map_err(|e| f.wrap(e))?;
            Ok((f.line(), time, (v, omega)))
        })
    };
    let intervals = Intervals::new(&odometry_file, rows);
    let skipped = SkipCounter::default();
    let groups = Groups {
        measurements: measurement_rows(measurements).peekable(),
        file: measurement_file,
        barcodes,
        options: options.clone(),
        skipped: skipped.clone(),
    };
    let options = options.clone();
    let events = merge_by_time(intervals, groups, move |interval, dt| {
        let (v, omega) = interval.control;
        unicycle(v, omega, dt, &options)
            .map(|u| Event::Motion(Box::new(u)))
            .map_err(|e| at(&odometry_file, interval.line, e))
    });
    let info = DatasetInfo {
        name: format!("MR.CLAM robot {robot}"),
        clock: Clock::Seconds,
        landmarks,
        gps_antenna: slam_core::nalgebra::Vector2::zeros(),
    };
    Ok(EventStream::new(info, events).with_skipped(skipped))
}

fn check_options(robot: u8, options: &MrclamOptions) -> Result<()> {
    if !ROBOTS.contains(&u64::from(robot)) {
        return Err(SensorError::InvalidArgument(format!(
            "MR.CLAM robot must be 1 to 5, got {robot}"
        )));
    }
    if !options.robot_from_sensor.is_finite() {
        return Err(SensorError::InvalidArgument(
            "MR.CLAM options: robot_from_sensor must be finite".into(),
        ));
    }
    check_sigmas(
        "MR.CLAM options",
        &[
            ("sigma_range", options.sigma_range),
            ("sigma_bearing", options.sigma_bearing),
        ],
        true,
    )?;
    check_sigmas(
        "MR.CLAM options",
        &[
            ("sigma_v", options.sigma_v),
            ("sigma_omega", options.sigma_omega),
        ],
        false,
    )
}

/// `dir/name`, or a "not found" error naming it.
fn existing(dir: &Path, name: &str) -> Result<std::path::PathBuf> {
    let path = dir.join(name);
    if path.is_file() {
        Ok(path)
    } else {
        Err(missing(&path, "MR.CLAM file"))
    }
}

fn unicycle(v: f64, omega: f64, dt: f64, options: &MrclamOptions) -> Result<Unicycle> {
    Unicycle::new(
        v,
        omega,
        dt,
        options.sigma_v,
        options.sigma_omega,
        options.integration,
    )
}

/// The data lines of a file (not `#` headers, not blank), each checked to have `columns`
/// fields.
struct Table {
    lines: Lines,
    columns: usize,
    what: &'static str,
}

impl Table {
    fn open(path: &Path, columns: usize, what: &'static str) -> Result<Table> {
        Ok(Table {
            lines: Lines::open(path)?,
            columns,
            what,
        })
    }

    /// The next data line, handed to `row`.
    fn next_row<T>(&mut self, row: impl FnOnce(&Fields) -> Result<T>) -> Option<Result<T>> {
        loop {
            let (line, content) = match self.lines.next()? {
                Ok(next) => next,
                Err(e) => return Some(Err(e)),
            };
            let trimmed = content.trim();
            if trimmed.is_empty() || trimmed.starts_with('#') {
                continue;
            }
            let fields = Fields::whitespace(self.lines.path(), line, &content);
            return Some(
                fields
                    .expect_len(self.columns, self.what)
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

/// Hands each data line of a whole (small) file to `row`.
fn read_table(
    path: &Path,
    columns: usize,
    what: &'static str,
    mut row: impl FnMut(&Fields) -> Result<()>,
) -> Result<()> {
    let mut table = Table::open(path, columns, what)?;
    while let Some(result) = table.next_row(&mut row) {
        result?;
    }
    Ok(())
}

/// Barcode -> subject.
fn read_barcodes(path: &Path) -> Result<HashMap<u64, u64>> {
    let mut map = HashMap::new();
    read_table(path, 2, "subject barcode", |f| {
        let subject = f.u64(0, "subject")?;
        let barcode = f.u64(1, "barcode")?;
        if map.insert(barcode, subject).is_some() {
            return Err(f.error(format!("barcode {barcode} is listed twice")));
        }
        Ok(())
    })?;
    Ok(map)
}

fn read_landmarks(path: &Path) -> Result<Vec<KnownLandmark>> {
    let mut landmarks = Vec::new();
    read_table(path, 5, "subject x y x_std y_std", |f| {
        let id = f.u64(0, "subject")?;
        let [x, y, _, _] = f.f64s(1, "landmark")?;
        landmarks.push(KnownLandmark {
            id,
            position: Vector2::new(x, y),
        });
        Ok(())
    })?;
    Ok(landmarks)
}

/// The measurement rows, checked to be in time order.
fn measurement_rows(table: Table) -> impl Iterator<Item = Result<Measurement>> {
    let mut previous: Option<f64> = None;
    table.rows(move |f| {
        let time = f.f64(0, "time")?;
        let barcode = f.u64(1, "barcode")?;
        let [range, bearing] = f.f64s(2, "range and bearing")?;
        if let Some(previous) = previous.filter(|p| time < *p) {
            return Err(f.error(format!("time goes backwards: {time} after {previous}")));
        }
        previous = Some(time);
        Ok(Measurement {
            line: f.line(),
            time,
            barcode,
            range,
            bearing,
        })
    })
}

/// One observation event per timestamp with at least one landmark measurement; other
/// measurements are counted in `skipped`.
struct Groups<M: Iterator> {
    measurements: std::iter::Peekable<M>,
    file: PathBuf,
    barcodes: HashMap<u64, u64>,
    options: MrclamOptions,
    skipped: SkipCounter,
}

impl<M: Iterator<Item = Result<Measurement>>> Groups<M> {
    /// The observations of the measurements at `time` (the first of them is `first`).
    fn group(&mut self, first: Measurement) -> Result<Vec<Observation>> {
        let time = first.time;
        let mut observations = Vec::new();
        let mut next = Some(first);
        while let Some(m) = next.take() {
            match self.barcodes.get(&m.barcode) {
                Some(&subject) if LANDMARKS.contains(&subject) && m.range <= 0.0 => {
                    self.skipped.count_reading("MR.CLAM: range not positive");
                }
                Some(&subject) if LANDMARKS.contains(&subject) => {
                    observations.push(observation(&self.file, &m, subject, &self.options)?);
                }
                Some(subject) if ROBOTS.contains(subject) => self.skipped.count("robot"),
                Some(_) => self.skipped.count("other subject"),
                None => self.skipped.count("unknown barcode"),
            }
            let same_time = |m: &Result<Measurement>| m.as_ref().is_ok_and(|m| m.time == time);
            if let Some(m) = self.measurements.next_if(same_time) {
                next = Some(m?);
            }
        }
        Ok(observations)
    }
}

impl<M: Iterator<Item = Result<Measurement>>> Iterator for Groups<M> {
    type Item = Result<Point>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let first = match self.measurements.next()? {
                Ok(m) => m,
                Err(e) => return Some(Err(e)),
            };
            let (line, time) = (first.line, first.time);
            match self.group(first) {
                Ok(observations) if observations.is_empty() => {}
                Ok(observations) => {
                    return Some(Ok(Point {
                        line,
                        time,
                        event: Event::Observations(observations),
                    }));
                }
                Err(e) => return Some(Err(e)),
            }
        }
    }
}

fn observation(
    file: &Path,
    m: &Measurement,
    subject: u64,
    options: &MrclamOptions,
) -> Result<Observation> {
    let model = RangeBearing::new(
        m.range,
        m.bearing,
        options.sigma_range,
        options.sigma_bearing,
    )
    .map_err(|e| at(file, m.line, e.into()))?;
    Ok(Observation {
        robot_from_sensor: options.robot_from_sensor,
        measurement: Arc::new(model),
        landmark_id: Some(subject),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "# UTIAS\n# produced by\n# Format:\n# columns\n";

    fn write_dir(name: &str, replace: &[(&str, &str)]) -> tempfile::TempDir {
        let dir = super::super::test_dir(&format!("mrclam-{name}"));
        let files = [
            (
                "Barcodes.dat",
                "  1 \t   5 \n  2 \t  14 \n  6 \t  72 \n  7 \t  27 \n",
            ),
            (
                "Landmark_Groundtruth.dat",
                "  6 \t 5.7 \t 4.9 \t 0.0002 \t 0.0004 \n  7 \t 5.2 \t 5.5 \t 0.0001 \t 0.0003 \n",
            ),
            (
                "Robot1_Odometry.dat",
                "10.000 \t 0.1 \t 0.0 \n10.500 \t 0.2 \t 0.1 \n11.000 \t 0.0 \t 0.0 \n",
            ),
            (
                "Robot1_Measurement.dat",
                "10.250 \t 72 \t 2.0 \t 0.1 \n10.250 \t 27 \t 3.0 \t -0.1 \n10.250 \t 14 \t 1.0 \t 0.0 \n10.500 \t 99 \t 1.0 \t 0.0 \n10.750 \t 5 \t 1.0 \t 0.0 \n10.750 \t 27 \t 3.0 \t 0.2 \n",
            ),
        ];
        for (file, body) in files {
            let body = replace
                .iter()
                .find(|(f, _)| *f == file)
                .map_or(body, |(_, b)| b);
            std::fs::write(dir.path().join(file), format!("{HEADER}{body}")).unwrap();
        }
        dir
    }

    #[test]
    fn groups_and_splits() {
        let dir = write_dir("ok", &[]);
        let data = read_mrclam(dir.path(), 1, &MrclamOptions::default()).unwrap();
        assert_eq!(data.landmarks.len(), 2);
        let trace: Vec<(f64, usize)> = data
            .events
            .iter()
            .map(|e| match &e.event {
                Event::Motion(_) => (e.time, 0),
                Event::Observations(o) => (e.time, o.len()),
                _ => unreachable!(),
            })
            .collect();
        assert_eq!(
            trace,
            [
                (10.25, 0),
                (10.25, 2),
                (10.5, 0),
                (10.75, 0),
                (10.75, 1),
                (11.0, 0)
            ]
        );
        let Event::Observations(o) = &data.events[1].event else {
            panic!()
        };
        assert_eq!((o[0].landmark_id, o[1].landmark_id), (Some(6), Some(7)));
        assert_eq!(
            (data.skipped["robot"], data.skipped["unknown barcode"]),
            (2, 1)
        );
    }

    #[test]
    fn bad_input_is_an_error_naming_file_and_line() {
        assert!(read_mrclam(write_dir("robot", &[]).path(), 6, &MrclamOptions::default()).is_err());
        let e = read_mrclam(
            write_dir("missing", &[]).path(),
            2,
            &MrclamOptions::default(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("Robot2_Odometry.dat"), "{e}");
        let cases = [
            (
                "Robot1_Odometry.dat",
                "10.0 \t 0.1\n",
                "Robot1_Odometry.dat:5: time v omega: expected 3 fields, got 2",
            ),
            (
                "Robot1_Odometry.dat",
                "10.0 0.1 0\n9.0 0.1 0\n",
                "Robot1_Odometry.dat:6: time goes backwards",
            ),
            (
                "Robot1_Measurement.dat",
                "10.0 72 abc 0.1\n",
                "Robot1_Measurement.dat:5:9: field 3 (range and bearing): expected a number",
            ),
            (
                "Robot1_Measurement.dat",
                "10.0 7.5 1 0.1\n",
                "Robot1_Measurement.dat:5:6: field 2 (barcode): expected a non-negative integer",
            ),
            (
                "Landmark_Groundtruth.dat",
                "6 1 inf 0 0\n",
                "Landmark_Groundtruth.dat:5:5: field 3 (landmark): value `inf` is not finite",
            ),
            (
                "Barcodes.dat",
                "1 5\n2 5\n",
                "Barcodes.dat:6: barcode 5 is listed twice",
            ),
        ];
        for (k, (file, body, expected)) in cases.iter().enumerate() {
            let dir = write_dir(&format!("bad{k}"), &[(file, body)]);
            let e = read_mrclam(dir.path(), 1, &MrclamOptions::default())
                .unwrap_err()
                .to_string();
            assert!(e.contains(expected), "{e} vs {expected}");
        }
    }

    #[test]
    fn a_negative_range_is_skipped_and_counted() {
        let dir = write_dir("negative", &[]);
        let whole = read_mrclam(dir.path(), 1, &MrclamOptions::default()).unwrap();
        let dir = write_dir(
            "negative",
            &[("Robot1_Measurement.dat", "10.0 72 -1 0.1\n")],
        );
        let data = read_mrclam(dir.path(), 1, &MrclamOptions::default()).unwrap();
        assert_eq!(data.skipped_readings["MR.CLAM: range not positive"], 1);
        assert!(whole.skipped_readings.is_empty());
    }
}
