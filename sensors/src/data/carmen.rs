//! CARMEN laser logs (plain text or gzip), such as the Radish "corrected" logs.
//!
//! Lines read (fields separated by whitespace):
//!
//! - `FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname
//!   logger_timestamp`: front laser. The line has no field of view; the beams are taken to span
//!   180 degrees starting at -90 degrees (on the robot's right), spaced `pi / (n - 1)` for an
//!   odd count (181, 361: both ends included) and `pi / n` for an even count (180, 360: the
//!   SICK's half-open sweep). This is a heuristic: nothing in the line says which it is.
//! - `RLASER`: the same layout, for a rear laser facing backwards.
//! - `ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range
//!   accuracy remission_mode n r_1 .. r_n m rem_1 .. rem_m laser_x laser_y laser_theta robot_x
//!   robot_y robot_theta laser_tv laser_rv forward_safety_dist side_safety_dist turn_axis
//!   ipc_timestamp ipc_hostname logger_timestamp`: the beams start at `start_angle`, spaced by
//!   `angular_resolution`; the mount is the laser pose relative to the robot pose.
//! - `ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp`: consecutive
//!   poses give [`PoseIncrement`]s.
//!
//! Every other line (`NEFF`, `PARAM`, `SYNC`, `TRUEPOS`, `#` comments, ...) is skipped and
//! counted in [`Dataset::skipped`] by its first word (comments under `"#"`, words that are not
//! a message name, such as binary garbage, under `"(not a CARMEN message)"`); blank lines are
//! ignored. A file without any of the four records above is an error (an empty file, or
//! something else given as a CARMEN log).
//!
//! **Input policy** (see [`crate::data`]). A laser reading that is negative or not finite
//! (`nan`, `inf`: some tools write those for "no return") is a glitch: the beam counts as no
//! return, and the reading is counted in [`Dataset::skipped_readings`]. Units are checked on
//! the first [`UNIT_SCANS`] laser lines: readings whose median is above
//! [`MAX_PLAUSIBLE_MEDIAN_M`] are an error (centimetres or millimetres for metres), and so is
//! a `ROBOTLASER1` line whose angles span more than a turn (degrees for radians); when most of
//! those scans have no reading below their maximum range, a warning names the maximum range.
//!
//! **Poses are references, not truth.** The robot pose of a laser line becomes an
//! [`Event::GroundTruth`] with [`TruthKind::Reference`]: in the Radish "corrected" logs it is
//! the output of another SLAM system (GMapping), written into both the `x y theta` and the
//! `odom_*` fields. Their `ODOM` lines re-anchor the odometry at the corrected pose after
//! every scan: an `ODOM` line right after a laser line that repeats its robot pose and is
//! stamped out of order (0 or garbage) is read as a reset of the odometry frame, not as
//! motion (its increment would be the corrected pose's correction, i.e. the reference leaking
//! into the motion); the odometry continues from it, and a warning counts them. The motion
//! between scans is then the raw odometry those logs carry.
//!
//! **Times are the logger timestamps** ([`Clock::Seconds`]): the last field of each line, so
//! that outputs can be paired by time with other tools' results on the same log. Logs are
//! not always clean, and events must stay in time order:
//!
//! - An `ODOM` line stamped more than [`STAMP_OUTLIER_S`] before the latest stamp read is out
//!   of order (other than the re-anchoring lines above): its motion takes the time of the
//!   record after it.
//! - Motion between two scans never takes a time after the next scan's stamp, nor before the
//!   time already written (odometry stamps jitter by up to a second in the Intel log).
//! - A scan stamped before the time already written takes that time.
//!
//! Each of these repairs is counted in a warning at the end of the file. A log whose stamps
//! cannot order its scans is read with **line numbers as times** ([`Clock::Sequence`]), with a
//! warning that says why: all stamps equal (all zero), a scan stamped more than
//! [`STAMP_OUTLIER_S`] before the scan before it (a clock that wraps or jumps back), or more
//! than [`MAX_LATE_SCANS`] of the scans stamped at or before the scan before them (too few
//! printed digits, e.g. `1.01893e+09`). [`stream_carmen`] reads the file once up front to
//! decide.
//!
//! [`carmen_text`] and [`write_carmen`] write the scans and the dead-reckoned odometry of a
//! [`Dataset`] as `ROBOTLASER1` and `ODOM` lines that this reader reads back.

use std::collections::VecDeque;
use std::fmt::Write as _;
use std::path::Path;

use slam_core::nalgebra::Vector3;
use slam_core::{Pose2, Pose3};

use super::stamps::Times;
use super::{Fields, Lines, at, write_atomically};
use crate::error::{Result, SensorError};
use crate::events::{
    Clock, Dataset, DatasetInfo, Event, EventStream, Pump, SkipCounter, Step, TimedEvent, TruthKind,
};
use crate::odometry::{OdometryNoise, PoseIncrement};
use crate::scan::LaserScan;

/// Where the maximum range is the file's largest reading, the readings within this fraction
/// below it are "no return" too: the no-return code of the acapulco and fhw logs (Radish)
/// comes with a jitter (51.09-51.25 m, 51.05-51.1 m), and taken as returns those readings
/// drew arcs at the maximum range that the line extractor took for walls 50 m away.
pub const NO_RETURN_BAND: f64 = 0.01;

/// How to read a CARMEN log.
#[derive(Clone, Debug)]
pub struct CarmenOptions {
    /// Readings at or above this are "no return", m. `None`: a `ROBOTLASER1` line's own
    /// `maximum_range` when positive, otherwise [`NO_RETURN_BAND`] below the largest range
    /// found on any laser line of the file: max-range readings are logged as the sensor
    /// maximum (e.g. 81.83 m), some sensors with a jitter of a few centimetres (51.09-51.25 m
    /// in one log), so they all become invalid; the cost is that a genuine return that close
    /// to the maximum is dropped too.
    pub max_range: Option<f64>,
    /// Readings at or below this are invalid, m. Default 0.
    pub min_range: f64,
    /// Mount of the front laser (`FLASER`). Default: the robot origin, facing forward.
    pub front_laser: Pose3,
    /// Mount of the rear laser (`RLASER`). Default: the robot origin, facing backwards (yaw pi).
    pub rear_laser: Pose3,
    /// Noise of the `ODOM` pose increments.
    pub odometry_noise: OdometryNoise,
}

impl Default for CarmenOptions {
    fn default() -> Self {
        CarmenOptions {
            max_range: None,
            min_range: 0.0,
            front_laser: Pose3::identity(),
            rear_laser: Pose3::new(Vector3::zeros(), std::f64::consts::PI, 0.0, 0.0),
            odometry_noise: OdometryNoise::default(),
        }
    }
}

/// How many laser lines the unit checks look at.
pub const UNIT_SCANS: usize = 20;

/// The largest plausible median laser reading of the first [`UNIT_SCANS`] scans, m: above
/// it, the readings are taken to be in centimetres or millimetres (an error).
pub const MAX_PLAUSIBLE_MEDIAN_M: f64 = 100.0;

/// A record stamped more than this before the latest stamp read is out of order, s.
pub const STAMP_OUTLIER_S: f64 = 1.0;

/// The largest fraction of a log's scans that may be stamped at or before the scan before
/// them for its stamps to be used as times.
pub const MAX_LATE_SCANS: f64 = 0.01;

/// The key under which lines whose first word is not a message name are counted.
const NOT_A_MESSAGE: &str = "(not a CARMEN message)";

/// A laser line before its maximum range is known.
struct LaserLine {
    ranges: Vec<f64>,
    angle_min: f64,
    angle_increment: f64,
    /// The line's own maximum range (`ROBOTLASER1`), when positive.
    max_range: Option<f64>,
    robot_from_sensor: Pose3,
    robot_pose: Pose2,
}

enum Record {
    Laser(LaserLine),
    Odometry(Pose2),
}

/// A record and its logger timestamp.
struct Stamped {
    record: Record,
    stamp: f64,
}

/// Reads a CARMEN log, plain or gzip-compressed (detected by its magic bytes).
///
/// Each laser line gives an [`Event::Scan`] followed by an [`Event::GroundTruth`] of kind
/// [`TruthKind::Reference`] with the line's robot pose; each `ODOM` line after the first gives
/// an [`Event::Motion`] with the [`PoseIncrement`] from the previous `ODOM` pose (but for the
/// re-anchoring lines of the [module](self) documentation). Event times
/// are the logger timestamps, repaired or replaced by line numbers as the [module](self)
/// documentation says. Known lines with the wrong field count or with non-numeric or non-finite
/// numbers are errors naming `file:line`. This is [`stream_carmen`] collected.
///
/// ```
/// use slam_sensors::data::{CarmenOptions, read_carmen};
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("carmen-doc.log");
/// std::fs::write(&path, "# a comment\n\
///     ODOM 0 0 0 0 0 0 1.0 host 1.0\n\
///     FLASER 3 1.0 2.0 5.0 0.1 0 0 0.1 0 0 1.5 host 1.5\n\
///     ODOM 0.1 0 0 0 0 0 2.0 host 2.0\n").unwrap();
/// let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
/// let counts = data.counts();
/// assert_eq!((counts.scans, counts.ground_truth, counts.motion), (1, 1, 1));
/// assert_eq!(data.skipped["#"], 1);
/// assert_eq!(data.events[0].time, 1.5); // the FLASER line's logger timestamp
/// ```
pub fn read_carmen(path: &Path, options: &CarmenOptions) -> Result<Dataset> {
    stream_carmen(path, options)?.into_dataset()
}

/// Reads a CARMEN log one line at a time: the events of [`read_carmen`], in the same order.
///
/// The file is read once up front for its logger timestamps (are they usable as times?).
/// Bad options and a missing or unreadable file are errors of this call; a malformed line is
/// an `Err` item when the stream reaches it. When neither the options nor a laser line give
/// the maximum range, the first such line makes the stream read the whole file once more,
/// quickly, for its largest reading.
///
/// ```
/// use slam_sensors::data::{CarmenOptions, stream_carmen};
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("carmen-stream-doc.log");
/// std::fs::write(&path, "FLASER 3 1.0 2.0 5.0 0.1 0 0 0.1 0 0 1.5 host 1.5\n\
///     ODOM 0 0 0 0 0 0 x host 1.0\n").unwrap();
/// let mut stream = stream_carmen(&path, &CarmenOptions::default()).unwrap();
/// assert_eq!(stream.next().unwrap().unwrap().time, 1.5); // the scan
/// assert_eq!(stream.next().unwrap().unwrap().time, 1.5); // its reference pose
/// let e = stream.next().unwrap().unwrap_err().to_string();
/// assert!(e.ends_with("carmen-stream-doc.log:2:18: field 8 (ipc_timestamp): expected a number, got `x`"), "{e}");
/// assert!(stream.next().is_none());
/// ```
pub fn stream_carmen(path: &Path, options: &CarmenOptions) -> Result<EventStream> {
    check_options(options)?;
    let name = path
        .file_name()
        .unwrap_or(path.as_os_str())
        .to_string_lossy()
        .into_owned();
    let skipped = SkipCounter::default();
    let clock = match survey_stamps(path)? {
        Ok(()) => Clock::Seconds,
        Err(reason) => {
            skipped.warn(format!(
                "{}: the logger timestamps cannot order the events ({reason}): event times \
                 are line numbers",
                path.display()
            ));
            Clock::Sequence
        }
    };
    let lines = Lines::open(path)?;
    let info = DatasetInfo {
        name,
        clock,
        landmarks: Vec::new(),
        gps_antenna: slam_core::nalgebra::Vector2::zeros(),
    };
    let reader = CarmenReader {
        lines,
        options: options.clone(),
        skipped: skipped.clone(),
        file_max: None,
        previous_odometry: None,
        last_laser_pose: None,
        resets: 0,
        records: 0,
        scans: ScanEvidence::default(),
        times: Times::default(),
        clock,
    };
    Ok(EventStream::new(info, Pump::new(reader)).with_skipped(skipped))
}

/// The state of a [`stream_carmen`] stream.
struct CarmenReader {
    lines: Lines,
    options: CarmenOptions,
    skipped: SkipCounter,
    /// The maximum range inferred from the file's largest reading ([`NO_RETURN_BAND`] below
    /// it), once a line has needed it.
    file_max: Option<f64>,
    previous_odometry: Option<Pose2>,
    /// The robot pose of the last laser line, until the next `ODOM` line.
    last_laser_pose: Option<Pose2>,
    /// `ODOM` lines that re-anchored the odometry at a scan's reference pose.
    resets: usize,
    /// Laser and odometry lines read.
    records: usize,
    /// The unit evidence of the first scans.
    scans: ScanEvidence,
    /// Logger timestamps into event times.
    times: Times,
    /// Whether the times are the logger timestamps or line numbers.
    clock: Clock,
}

impl Step for CarmenReader {
    fn step(&mut self, out: &mut VecDeque<TimedEvent>) -> Result<bool> {
        let Some(next) = self.lines.next() else {
            self.times.flush(f64::INFINITY, out);
            return self.end().map(|()| false);
        };
        let read = next.and_then(|(line, content)| self.read_line(line, &content, out));
        if read.is_err() {
            // The events of the lines before the error come first.
            self.times.flush(f64::INFINITY, out);
        }
        read.map(|()| true)
    }
}

impl CarmenReader {
    /// Reads one line into events.
    fn read_line(
        &mut self,
        line: usize,
        content: &str,
        out: &mut VecDeque<TimedEvent>,
    ) -> Result<()> {
        let path = self.lines.path();
        let fields = Fields::whitespace(path, line, content);
        let sequence = self.clock == Clock::Sequence;
        match parse_line(&fields, &self.options)? {
            Some(Stamped {
                record: Record::Laser(laser),
                stamp,
            }) => {
                self.records += 1;
                let max_range = match self.options.max_range.or(laser.max_range) {
                    Some(max_range) => max_range,
                    None => match self.file_max {
                        Some(file_max) => file_max,
                        None => *self
                            .file_max
                            .insert(largest_range(path)? * (1.0 - NO_RETURN_BAND)),
                    },
                };
                let pose = laser.robot_pose;
                self.last_laser_pose = Some(pose);
                let (scan, robot_from_sensor) = to_scan(laser, self.options.min_range, max_range)
                    .map_err(|e| at(path, line, e))?;
                self.check_scan(&scan, line)?;
                let time = if sequence {
                    line as f64
                } else {
                    self.times.scan(stamp, out)
                };
                out.push_back(TimedEvent {
                    time,
                    event: Event::Scan {
                        scan,
                        robot_from_sensor,
                    },
                });
                out.push_back(TimedEvent {
                    time,
                    event: Event::GroundTruth {
                        pose,
                        kind: TruthKind::Reference,
                    },
                });
            }
            Some(Stamped {
                record: Record::Odometry(pose),
                stamp,
            }) => {
                self.records += 1;
                let after_scan = self.last_laser_pose.take();
                if !sequence && is_reset(after_scan, &pose, self.times.is_out_of_order(stamp)) {
                    // The odometry frame moved to the reference pose: no motion.
                    self.resets += 1;
                    self.previous_odometry = Some(pose);
                    return Ok(());
                }
                let step = match self.previous_odometry {
                    Some(previous) => Some(
                        PoseIncrement::between(&previous, &pose, &self.options.odometry_noise)
                            .map_err(|e| at(path, line, e))?,
                    ),
                    None => None,
                };
                self.previous_odometry = Some(pose);
                let event = step.map(|step| Event::Motion(Box::new(step)));
                if sequence {
                    if let Some(event) = event {
                        out.push_back(TimedEvent {
                            time: line as f64,
                            event,
                        });
                    }
                } else {
                    self.times.odometry(stamp, event, out);
                }
            }
            None if content.trim_start().starts_with('#') => self.skipped.count("#"),
            None if fields.len() > 0 => self.skipped.count(message_key(fields.first())),
            None => {}
        }
        Ok(())
    }

    /// Counts the impossible readings of a scan and gathers the unit evidence of the first
    /// scans; an error when the readings look like centimetres.
    fn check_scan(&mut self, scan: &LaserScan, line: usize) -> Result<()> {
        for &range in &scan.ranges {
            if !range.is_finite() {
                self.skipped
                    .count_reading("CARMEN laser: reading not finite (no return)");
            } else if range < 0.0 {
                self.skipped
                    .count_reading("CARMEN laser: negative reading (no return)");
            }
        }
        self.scans.add(scan);
        self.scans.check(self.lines.path(), line, &self.skipped)
    }

    /// At the end of the file: the unit checks of a short log, and an error when the file
    /// held no record at all.
    fn end(&mut self) -> Result<()> {
        let path = self.lines.path();
        let line = self.lines.number();
        if let Some(warning) = self.times.repairs() {
            self.skipped
                .warn(format!("{}: logger {warning}", path.display()));
        }
        if self.resets > 0 {
            self.skipped.warn(format!(
                "{}: {} ODOM lines right after a scan repeat its reference pose with an \
                 out-of-order stamp (the Radish corrected logs re-anchor the odometry at the \
                 corrected pose): read as a reset of the odometry frame, not as motion",
                path.display(),
                self.resets
            ));
        }
        self.scans.decide(path, line, &self.skipped)?;
        if self.records > 0 {
            return Ok(());
        }
        let skipped = self.skipped.get();
        if skipped.is_empty() {
            return Err(SensorError::Input(format!(
                "{}: no CARMEN record: the file is empty",
                path.display()
            )));
        }
        let words: Vec<String> = skipped
            .iter()
            .take(5)
            .map(|(word, n)| format!("{word} x{n}"))
            .collect();
        Err(SensorError::Input(format!(
            "{}: no CARMEN record (FLASER, RLASER, ROBOTLASER1 or ODOM) in its {line} lines \
             (first words: {}): is it a CARMEN log?",
            path.display(),
            words.join(", ")
        )))
    }
}

/// The key under which an unused line is counted: its first word when that looks like a
/// message name (letters, digits, `_`, at most 40), so that garbage cannot grow the counts.
fn message_key(word: &str) -> &str {
    let name = !word.is_empty()
        && word.len() <= 40
        && word
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if name { word } else { NOT_A_MESSAGE }
}

/// The readings of the first [`UNIT_SCANS`] scans, for the unit checks.
#[derive(Debug, Default)]
struct ScanEvidence {
    /// The median valid reading of each scan that has one.
    medians: Vec<f64>,
    /// Scans seen, and those without a valid reading.
    seen: usize,
    empty: usize,
    /// The largest maximum range of those scans.
    max_range: f64,
    decided: bool,
}

impl ScanEvidence {
    fn add(&mut self, scan: &LaserScan) {
        if self.seen >= UNIT_SCANS {
            return;
        }
        self.seen += 1;
        self.max_range = self.max_range.max(scan.max_range);
        let mut valid: Vec<f64> = scan.points().iter().map(|p| p.range).collect();
        match super::units::median(&mut valid) {
            Some(median) => self.medians.push(median),
            None => self.empty += 1,
        }
    }

    /// Decides once [`UNIT_SCANS`] scans are in.
    fn check(&mut self, file: &Path, line: usize, skipped: &SkipCounter) -> Result<()> {
        if self.seen < UNIT_SCANS {
            return Ok(());
        }
        self.decide(file, line, skipped)
    }

    /// Decides on the scans seen (once).
    fn decide(&mut self, file: &Path, line: usize, skipped: &SkipCounter) -> Result<()> {
        if self.decided || self.seen == 0 {
            return Ok(());
        }
        self.decided = true;
        let mut medians = std::mem::take(&mut self.medians);
        if let Some(median) = super::units::median(&mut medians)
            && median > MAX_PLAUSIBLE_MEDIAN_M
        {
            return Err(SensorError::parse(
                file,
                line,
                format!(
                    "the median laser reading of the first {} scans is {median:.1}: CARMEN \
                     ranges are metres, these look like centimetres or millimetres",
                    self.seen
                ),
            ));
        }
        if 2 * self.empty > self.seen {
            skipped.warn(format!(
                "{}: {} of the first {} scans have no reading below their maximum range \
                 ({} m): is the maximum range right (the ROBOTLASER1 maximum_range field, or \
                 the largest reading of the file)?",
                file.display(),
                self.empty,
                self.seen,
                self.max_range
            ));
        }
        Ok(())
    }
}

fn check_options(options: &CarmenOptions) -> Result<()> {
    let min_ok = options.min_range.is_finite() && options.min_range >= 0.0;
    let max_ok = options
        .max_range
        .is_none_or(|m| m.is_finite() && m > options.min_range);
    if min_ok && max_ok {
        Ok(())
    } else {
        Err(SensorError::InvalidArgument(format!(
            "CARMEN range limits: min_range {} must be finite and non-negative, max_range {:?} \
             finite and above it",
            options.min_range, options.max_range
        )))
    }
}

/// The largest reading of any laser line of the file (0 when there is none), from a pass
/// that reads only the readings. Lines that do not parse are left out: the stream reports
/// them when it gets there.
fn largest_range(path: &Path) -> Result<f64> {
    let mut largest = 0.0;
    for next in Lines::open(path)? {
        let (_, content) = next?;
        if let Some(line_max) = line_largest_range(&content) {
            largest = f64::max(largest, line_max);
        }
    }
    Ok(largest)
}

/// The largest finite reading of a laser line (folded from 0), or `None` for other lines and
/// for readings that do not parse as numbers.
fn line_largest_range(content: &str) -> Option<f64> {
    let mut fields = content.split_ascii_whitespace();
    let first_reading = match fields.next()? {
        "FLASER" | "RLASER" => 0,
        "ROBOTLASER1" => 7,
        _ => return None,
    };
    let mut fields = fields.skip(first_reading);
    let n: usize = fields.next()?.parse().ok()?;
    let mut largest = 0.0;
    for _ in 0..n {
        let range: f64 = fields.next()?.parse().ok()?;
        if range.is_finite() {
            largest = f64::max(largest, range);
        }
    }
    Some(largest)
}

fn to_scan(laser: LaserLine, min_range: f64, max_range: f64) -> Result<(LaserScan, Pose3)> {
    let scan = LaserScan::with_increment(
        laser.angle_min,
        laser.angle_increment,
        laser.ranges,
        min_range,
        max_range,
    )?;
    Ok((scan, laser.robot_from_sensor))
}

/// A known line as a record; `None` for a line to skip.
fn parse_line(fields: &Fields, options: &CarmenOptions) -> Result<Option<Stamped>> {
    let record = match fields.first() {
        "FLASER" => Record::Laser(parse_old_laser(fields, options.front_laser)?),
        "RLASER" => Record::Laser(parse_old_laser(fields, options.rear_laser)?),
        "ROBOTLASER1" => Record::Laser(parse_robot_laser(fields)?),
        "ODOM" => Record::Odometry(parse_odometry(fields)?),
        _ => return Ok(None),
    };
    // Every record ends with its logger timestamp (checked by the record's parser).
    let stamp = fields.f64(fields.len() - 1, "logger_timestamp")?;
    Ok(Some(Stamped { record, stamp }))
}

/// The logger timestamp of a record line (the last field), or `None` for other lines and
/// for stamps that do not parse (the reading pass reports those).
fn line_stamp(content: &str) -> Option<(bool, f64)> {
    let mut fields = content.split_ascii_whitespace();
    let scan = match fields.next()? {
        "FLASER" | "RLASER" | "ROBOTLASER1" => true,
        "ODOM" => false,
        _ => return None,
    };
    let stamp: f64 = fields.next_back()?.parse().ok()?;
    stamp.is_finite().then_some((scan, stamp))
}

/// Reads the logger timestamps of the whole file: `Ok(Err(reason))` when they cannot order
/// the events (see the [module](self) documentation). An I/O error is an error; a line that
/// cannot be read ends the survey (the reading pass reports it where it is).
fn survey_stamps(path: &Path) -> Result<std::result::Result<(), String>> {
    let mut distinct: Option<(f64, bool)> = None;
    let (mut scans, mut late) = (0usize, 0usize);
    let mut previous_scan: Option<f64> = None;
    let mut jump: Option<(usize, f64, f64)> = None;
    for next in Lines::open(path)? {
        let Ok((line, content)) = next else { break };
        let Some((scan, stamp)) = line_stamp(&content) else {
            continue;
        };
        distinct = match distinct {
            None => Some((stamp, false)),
            Some((first, seen)) => Some((first, seen || stamp != first)),
        };
        if !scan {
            continue;
        }
        scans += 1;
        if let Some(before) = previous_scan {
            if stamp < before - STAMP_OUTLIER_S && jump.is_none() {
                jump = Some((line, before, stamp));
            }
            if stamp <= before {
                late += 1;
            }
        }
        previous_scan = Some(stamp);
    }
    if let Some((first, false)) = distinct {
        return Ok(Err(format!("every record is stamped {first}")));
    }
    if let Some((line, before, stamp)) = jump {
        return Ok(Err(format!(
            "the scan of line {line} is stamped {stamp}, {:.3} s before the scan before it",
            before - stamp
        )));
    }
    if scans > 1 && late as f64 > MAX_LATE_SCANS * (scans - 1) as f64 {
        return Ok(Err(format!(
            "{late} of {scans} scans are stamped at or before the scan before them: too few \
             digits?"
        )));
    }
    Ok(Ok(()))
}

/// The beam spacing of an `FLASER`/`RLASER` line with `n` beams over 180 degrees.
fn old_laser_increment(n: usize) -> f64 {
    use std::f64::consts::PI;
    match n {
        0 | 1 => 0.0,
        n if n % 2 == 1 => PI / (n - 1) as f64,
        n => PI / n as f64,
    }
}

/// The count field at `index` (e.g. the number of readings), checked against the line length
/// so that the fields it announces exist.
fn count_field(fields: &Fields, index: usize, what: &str) -> Result<usize> {
    let n = fields.usize(index, what)?;
    if n > fields.len() {
        return Err(fields.error(format!(
            "{what} is {n} but the line has only {} fields",
            fields.len()
        )));
    }
    Ok(n)
}

fn ranges(fields: &Fields, start: usize, n: usize) -> Result<Vec<f64>> {
    if n == 0 {
        return Err(fields.error("a laser line needs at least one reading"));
    }
    // A reading that is not finite is a glitch (no return), counted by the reader; one that
    // is not a number is a syntax error.
    (start..start + n)
        .map(|i| fields.number(i, "range"))
        .collect()
}

/// The trailing `ipc_timestamp ipc_hostname logger_timestamp`, starting at `index`: checked
/// to be numeric (the logger timestamp is the event time, see [`parse_line`]).
fn check_timestamps(fields: &Fields, index: usize) -> Result<()> {
    fields.f64(index, "ipc_timestamp")?;
    fields.f64(index + 2, "logger_timestamp")?;
    Ok(())
}

fn parse_old_laser(fields: &Fields, mount: Pose3) -> Result<LaserLine> {
    let tag = fields.first();
    let n = count_field(fields, 1, "number of readings")?;
    fields.expect_len(n + 11, tag)?;
    let ranges = ranges(fields, 2, n)?;
    let [x, y, theta] = fields.f64s(2 + n, "robot pose")?;
    fields.f64s::<3>(5 + n, "odometry pose")?;
    check_timestamps(fields, 8 + n)?;
    Ok(LaserLine {
        ranges,
        angle_min: -std::f64::consts::FRAC_PI_2,
        angle_increment: old_laser_increment(n),
        max_range: None,
        robot_from_sensor: mount,
        robot_pose: Pose2::new(x, y, theta),
    })
}

fn parse_robot_laser(fields: &Fields) -> Result<LaserLine> {
    let [
        _laser_type,
        start_angle,
        _fov,
        resolution,
        max_range,
        _accuracy,
        _mode,
    ] = fields.f64s(1, "laser parameters")?;
    let n = count_field(fields, 8, "number of readings")?;
    let m = count_field(fields, 9 + n, "number of remissions")?;
    fields.expect_len(n + m + 24, "ROBOTLASER1")?;
    let ranges = ranges(fields, 9, n)?;
    for i in 10 + n..10 + n + m {
        fields.f64(i, "remission")?;
    }
    let base = 10 + n + m;
    let [lx, ly, ltheta, rx, ry, rtheta] = fields.f64s(base, "laser and robot poses")?;
    fields.f64s::<5>(base + 6, "velocities and safety distances")?;
    check_timestamps(fields, base + 11)?;
    if resolution < 0.0 {
        return Err(fields.error(format!("angular resolution {resolution} is negative")));
    }
    let turn = 2.0 * std::f64::consts::PI + 1e-6;
    let span = resolution * n.saturating_sub(1) as f64;
    if start_angle.abs() > turn || span > turn {
        return Err(fields.error(format!(
            "ROBOTLASER1 angles look like degrees: start_angle {start_angle}, \
             angular_resolution {resolution} over {n} readings spans {span:.2} rad; CARMEN \
             angles are radians"
        )));
    }
    let robot_pose = Pose2::new(rx, ry, rtheta);
    let mount = robot_pose.between(&Pose2::new(lx, ly, ltheta));
    Ok(LaserLine {
        ranges,
        angle_min: start_angle,
        angle_increment: resolution,
        max_range: (max_range > 0.0).then_some(max_range),
        robot_from_sensor: mount.to_pose3(0.0),
        robot_pose,
    })
}

/// Whether an `ODOM` line at `pose` right after a laser line at `after_scan` re-anchors the
/// odometry frame rather than reporting motion: it repeats the scan's robot pose (the
/// reference pose, in the Radish corrected logs) and its stamp is out of order (0 or garbage
/// there). Its increment would be the reference's correction, not motion.
fn is_reset(after_scan: Option<Pose2>, pose: &Pose2, out_of_order: bool) -> bool {
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()));
    out_of_order
        && after_scan.is_some_and(|scan| {
            same(scan.x, pose.x) && same(scan.y, pose.y) && same(scan.theta, pose.theta)
        })
}

fn parse_odometry(fields: &Fields) -> Result<Pose2> {
    fields.expect_len(10, "ODOM")?;
    let [x, y, theta] = fields.f64s(1, "odometry pose")?;
    fields.f64s::<3>(4, "velocities")?;
    check_timestamps(fields, 7)?;
    Ok(Pose2::new(x, y, theta))
}

/// The CARMEN text of `dataset` (see [`write_carmen`]); `comment` becomes `#` lines at the top.
pub fn carmen_text(dataset: &Dataset, start: &Pose2, comment: &str) -> Result<String> {
    let mut text = String::new();
    // Writing to a String cannot fail.
    for line in comment.lines() {
        let _ = writeln!(text, "# {line}");
    }
    let mut pose = *start;
    let mut last_time = dataset.events.first().map_or(0.0, |e| e.time);
    let (mut tv, mut rv) = (0.0, 0.0);
    odometry_line(&mut text, &pose, tv, rv, last_time);
    for event in &dataset.events {
        match &event.event {
            Event::Motion(motion) => {
                let delta = motion.predict(&Pose2::identity())?.pose;
                pose = motion.predict(&pose)?.pose;
                let dt = event.time - last_time;
                (tv, rv) = if dt > 0.0 {
                    (delta.x / dt, delta.theta / dt)
                } else {
                    (0.0, 0.0)
                };
                last_time = event.time;
                odometry_line(&mut text, &pose, tv, rv, event.time);
            }
            Event::Scan {
                scan,
                robot_from_sensor,
            } => robot_laser_line(
                &mut text,
                scan,
                robot_from_sensor,
                &pose,
                (tv, rv),
                event.time,
            )?,
            _ => {}
        }
    }
    Ok(text)
}

/// Writes the laser scans and the odometry of `dataset` as a CARMEN log, completely or not at
/// all ([`write_atomically`]). Timestamps are the event times (seconds), written as both
/// `ipc_timestamp` and `logger_timestamp`, with the host name `sim`.
///
/// - The robot pose is **dead-reckoned**: it starts at `start` and each [`Event::Motion`]
///   moves it by its increment, as raw CARMEN logs carry the robot's odometry pose. An `ODOM`
///   line is written at the first event's time and after every motion, with `tv`, `rv` the
///   increment's forward distance and turn divided by the time since the previous motion.
/// - Each [`Event::Scan`] becomes a `ROBOTLASER1` line with the current dead-reckoned pose as
///   the robot pose and that pose composed with the mount as the laser pose, so that
///   [`read_carmen`] recovers the mount (its x, y and yaw: the line has no height, and a
///   tilted mount is an error). Ranges are written in millimetres (3 decimals), with more
///   digits where rounding would turn a valid reading invalid or the reverse (against the
///   line's `maximum_range`); non-finite readings are written as the maximum range. The
///   scan's `min_range` is not in the line (the reader's [`CarmenOptions::min_range`] applies).
/// - True poses, images, observations and GPS fixes are not written.
///
/// ```
/// use slam_sensors::data::carmen::{CarmenOptions, read_carmen, write_carmen};
/// use slam_sensors::{Clock, Dataset, Event, LaserScan};
/// use slam_core::{Pose2, Pose3};
/// let mut data = Dataset::new("tiny", Clock::Seconds);
/// let scan = LaserScan::new(-1.0, 1.0, vec![2.0, 3.5, 8.0], 0.0, 8.0).unwrap();
/// data.push(0.0, Event::Scan { scan: scan.clone(), robot_from_sensor: Pose3::identity() });
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("carmen-write-doc.log");
/// write_carmen(&path, &data, &Pose2::new(1.0, 2.0, 0.5), "a test").unwrap();
/// let back = read_carmen(&path, &CarmenOptions::default()).unwrap();
/// let Event::Scan { scan: read, .. } = &back.events[0].event else { panic!() };
/// assert_eq!((read.ranges.clone(), read.max_range), (scan.ranges, 8.0));
/// ```
pub fn write_carmen(path: &Path, dataset: &Dataset, start: &Pose2, comment: &str) -> Result<()> {
    write_atomically(path, carmen_text(dataset, start, comment)?.as_bytes())
}

/// `ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp`.
fn odometry_line(text: &mut String, pose: &Pose2, tv: f64, rv: f64, time: f64) {
    let _ = writeln!(
        text,
        "ODOM {:.9} {:.9} {:.9} {tv:.6} {rv:.6} 0 {time:.6} sim {time:.6}",
        pose.x, pose.y, pose.theta
    );
}

/// A `ROBOTLASER1` line (field order in the [module](self) documentation).
fn robot_laser_line(
    text: &mut String,
    scan: &LaserScan,
    mount: &Pose3,
    pose: &Pose2,
    (tv, rv): (f64, f64),
    time: f64,
) -> Result<()> {
    if mount.pitch.abs() > 1e-12 || mount.roll.abs() > 1e-12 {
        return Err(SensorError::InvalidArgument(format!(
            "a CARMEN laser line holds a level laser only, this one is tilted \
             (pitch {}, roll {})",
            mount.pitch, mount.roll
        )));
    }
    let laser = pose.compose(&Pose2::new(
        mount.translation.x,
        mount.translation.y,
        mount.yaw,
    ));
    let n = scan.ranges.len();
    let fov = scan.angle_increment * n.saturating_sub(1) as f64;
    let _ = write!(
        text,
        "ROBOTLASER1 0 {} {fov} {} {} 0 0 {n}",
        scan.angle_min, scan.angle_increment, scan.max_range
    );
    for &range in &scan.ranges {
        let _ = write!(text, " {}", range_field(range, scan));
    }
    let _ = writeln!(
        text,
        " 0 {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {tv:.6} {rv:.6} 0 0 0 {time:.6} sim {time:.6}",
        laser.x, laser.y, laser.theta, pose.x, pose.y, pose.theta
    );
    Ok(())
}

/// A range in millimetres, or with all its digits where rounding would change its validity.
fn range_field(range: f64, scan: &LaserScan) -> String {
    let range = if range.is_finite() {
        range
    } else {
        scan.max_range
    };
    let short = format!("{range:.3}");
    let keeps_validity = short
        .parse::<f64>()
        .is_ok_and(|r| scan.is_valid(r) == scan.is_valid(range));
    if keeps_validity {
        short
    } else {
        format!("{range}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn read(name: &str, text: &str, options: &CarmenOptions) -> Result<Dataset> {
        let dir = super::super::test_dir(&format!("carmen-{name}"));
        let path = dir.path().join(format!("{name}.log"));
        std::fs::write(&path, text).unwrap();
        read_carmen(&path, options)
    }

    #[test]
    fn written_ranges_keep_their_validity() {
        let scan = LaserScan::new(-1.0, 1.0, vec![1.0], 0.0, 8.0).unwrap();
        assert_eq!(range_field(2.34567, &scan), "2.346");
        assert_eq!(range_field(7.99996, &scan), "7.99996");
        assert_eq!(range_field(8.0, &scan), "8.000");
        assert_eq!(range_field(f64::NAN, &scan), "8.000");
        assert_eq!(range_field(0.0002, &scan), "0.0002");
        let tilted = Pose3::new(Vector3::zeros(), 0.0, 0.1, 0.0);
        let mut text = String::new();
        let e = robot_laser_line(
            &mut text,
            &scan,
            &tilted,
            &Pose2::identity(),
            (0.0, 0.0),
            0.0,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("tilted"), "{e}");
    }

    /// `(time, kind)` of every event: `M` motion, `S` scan (its reference pose dropped).
    fn timeline(data: &Dataset) -> Vec<(f64, char)> {
        data.events
            .iter()
            .filter_map(|e| match e.event {
                Event::Motion(_) => Some((e.time, 'M')),
                Event::Scan { .. } => Some((e.time, 'S')),
                _ => None,
            })
            .collect()
    }

    fn odom(x: f64, stamp: &str) -> String {
        format!("ODOM {x} 0 0 0 0 0 {stamp} h {stamp}\n")
    }

    fn flaser(x: f64, stamp: &str) -> String {
        format!("FLASER 3 1 2 3 {x} 0 0 {x} 0 0 {stamp} h {stamp}\n")
    }

    #[test]
    fn a_corrected_log_re_anchors_its_odometry_at_each_scan() {
        // The layout of the Radish "corrected" logs: each scan is followed by an ODOM line
        // of the scan's (corrected) pose stamped 0, and the odometry goes on from there. The
        // jump to it (0.3 -> 0.25 here) is the reference's correction, not motion.
        let text = [
            odom(0.0, "10.0"),
            odom(0.3, "10.5"),
            flaser(0.25, "10.5"),
            odom(0.25, "0"),
            "NEFF 3\n".to_string(),
            odom(0.45, "10.9"),
            odom(0.65, "11.2"),
            flaser(0.6, "11.2"),
            odom(0.6, "0"),
        ]
        .concat();
        let data = read("corrected", &text, &CarmenOptions::default()).unwrap();
        let motion: Vec<f64> = data
            .events
            .iter()
            .filter_map(|e| match &e.event {
                Event::Motion(step) => Some(step.predict(&Pose2::identity()).unwrap().pose.x),
                _ => None,
            })
            .collect();
        // 0 -> 0.3, then from the reset at 0.25: 0.45, 0.65.
        let expected = [0.3, 0.2, 0.2];
        assert_eq!(motion.len(), expected.len(), "{motion:?}");
        for (got, want) in motion.iter().zip(expected) {
            assert!((got - want).abs() < 1e-12, "{motion:?}");
        }
        assert_eq!(data.warnings.len(), 1, "{:?}", data.warnings);
        assert!(
            data.warnings[0].contains("2 ODOM lines right after a scan repeat its reference pose")
        );
        // An ODOM line at the scan's pose with a stamp in order is motion as usual (a raw log
        // whose robot stood still), and so is one stamped 0 at another pose (above).
        let still = [odom(0.0, "1.0"), flaser(0.0, "1.5"), odom(0.0, "2.0")].concat();
        let data = read("still", &still, &CarmenOptions::default()).unwrap();
        assert_eq!(timeline(&data), [(1.5, 'S'), (2.0, 'M')]);
        assert!(data.warnings.is_empty(), "{:?}", data.warnings);
    }

    #[test]
    fn times_are_logger_timestamps_repaired_where_out_of_order() {
        // ODOM lines stamped 0 or with a garbage value (3.5) that are motion (not at the
        // scan's pose: see `a_corrected_log_re_anchors_its_odometry_at_each_scan`); odometry
        // stamps jitter (10.7 after 10.9).
        let text = [
            odom(0.0, "10.0"),
            odom(0.1, "10.5"),
            flaser(0.1, "10.5"),
            odom(0.15, "0"),
            "NEFF 3\n".to_string(),
            odom(0.2, "10.9"),
            odom(0.3, "10.7"),
            odom(0.4, "11.2"),
            flaser(0.4, "11.2"),
            odom(0.45, "3.5"),
        ]
        .concat();
        let data = read("stamps", &text, &CarmenOptions::default()).unwrap();
        assert_eq!(data.clock, Clock::Seconds);
        assert_eq!(
            timeline(&data),
            [
                (10.5, 'M'),
                (10.5, 'S'),
                (10.7, 'M'), // stamped 0: the time of the record after it
                (10.7, 'M'), // 10.9, before 10.7: bounded by the record after it
                (10.7, 'M'),
                (11.2, 'M'),
                (11.2, 'S'),
                (11.2, 'M'), // stamped 3.5 at the end: the time before it
            ]
        );
        assert_eq!(data.warnings.len(), 1, "{:?}", data.warnings);
        let warning = &data.warnings[0];
        assert!(
            warning.contains("stamps.log: logger timestamps repaired"),
            "{warning}"
        );
        assert!(
            warning.contains("2 odometry records stamped more than 1 s before"),
            "{warning}"
        );
        assert!(
            warning.contains("1 odometry records stamped out of order"),
            "{warning}"
        );
        // A scan stamped before the scan before it takes that scan's time; more than 1 % of
        // such scans and the stamps are refused.
        let late = [flaser(0.0, "5.0"), odom(0.0, "5.6"), flaser(0.0, "4.5")].concat();
        let data = read("late", &late, &CarmenOptions::default()).unwrap();
        assert_eq!(data.clock, Clock::Sequence);
        let mut many: Vec<String> = (0..200)
            .map(|k| flaser(0.0, &format!("{}", 5.0 + f64::from(k))))
            .collect();
        many[100] = flaser(0.0, "103.3");
        let data = read("late-one", &many.concat(), &CarmenOptions::default()).unwrap();
        assert_eq!(data.clock, Clock::Seconds);
        let scans: Vec<f64> = timeline(&data)
            .into_iter()
            .filter(|e| e.1 == 'S')
            .map(|e| e.0)
            .collect();
        assert_eq!((scans[99], scans[100], scans[101]), (104.0, 104.0, 106.0));
        assert!(
            data.warnings[0].contains("1 scans stamped up to 0.700 s before"),
            "{:?}",
            data.warnings
        );
    }

    #[test]
    fn broken_stamps_give_line_numbers_with_a_warning() {
        let cases = [
            // All zero.
            (
                [
                    odom(0.0, "0"),
                    flaser(0.0, "0"),
                    odom(0.1, "0"),
                    flaser(0.1, "0"),
                ]
                .concat(),
                "every record is stamped 0",
            ),
            // A clock that wraps.
            (
                [flaser(0.0, "4000"), odom(0.0, "4001"), flaser(0.1, "2.5")].concat(),
                "the scan of line 3 is stamped 2.5, 3997.500 s before the scan before it",
            ),
            // Too few digits to order the scans.
            (
                (0..10)
                    .map(|k| {
                        flaser(
                            f64::from(k),
                            if k < 8 { "1.01893e+09" } else { "1.01894e+09" },
                        )
                    })
                    .collect::<String>(),
                "8 of 10 scans are stamped at or before the scan before them",
            ),
        ];
        for (k, (text, reason)) in cases.iter().enumerate() {
            let data = read(&format!("broken{k}"), text, &CarmenOptions::default()).unwrap();
            assert_eq!(data.clock, Clock::Sequence, "{reason}");
            let times: Vec<f64> = timeline(&data).iter().map(|e| e.0).collect();
            let lines: Vec<f64> = data
                .events
                .iter()
                .filter(|e| !matches!(e.event, Event::GroundTruth { .. }))
                .map(|e| e.time)
                .collect();
            assert_eq!(times, lines);
            assert!(
                times.iter().all(|t| t.fract() == 0.0 && *t >= 1.0),
                "{times:?}"
            );
            assert_eq!(data.warnings.len(), 1, "{:?}", data.warnings);
            let warning = &data.warnings[0];
            assert!(warning.contains(reason), "{warning} vs {reason}");
            assert!(
                warning.ends_with("event times are line numbers"),
                "{warning}"
            );
        }
    }

    #[test]
    fn beam_spacing_heuristic() {
        assert!((old_laser_increment(181) - PI / 180.0).abs() < 1e-15);
        assert!((old_laser_increment(180) - PI / 180.0).abs() < 1e-15);
        assert!((old_laser_increment(361) - PI / 360.0).abs() < 1e-15);
        assert_eq!(old_laser_increment(1), 0.0);
    }

    #[test]
    fn rear_laser_and_robot_laser_mounts() {
        let text = "RLASER 2 1.0 2.0 1 2 0.5 1 2 0.5 0 h 0\n\
                    ROBOTLASER1 0 -1.5 3.0 0.5 30 0.01 0 3 1 2 3 0 2 1 0.5 1 0 0 0 0 0 0 0 0 h 0\n";
        let data = read("mounts", text, &CarmenOptions::default()).unwrap();
        let Event::Scan {
            robot_from_sensor,
            scan,
        } = &data.events[0].event
        else {
            panic!()
        };
        assert!((robot_from_sensor.yaw.abs() - PI).abs() < 1e-12);
        // The largest reading of the file, less the no-return band.
        assert_eq!(scan.max_range, 3.0 * (1.0 - NO_RETURN_BAND));
        let Event::Scan {
            robot_from_sensor,
            scan,
        } = &data.events[2].event
        else {
            panic!()
        };
        assert!((robot_from_sensor.translation.x - 1.0).abs() < 1e-12);
        assert!((robot_from_sensor.translation.y - 1.0).abs() < 1e-12);
        assert!((robot_from_sensor.yaw - 0.5).abs() < 1e-12);
        assert_eq!(
            (scan.angle_min, scan.angle_increment, scan.max_range),
            (-1.5, 0.5, 30.0)
        );
        let Event::GroundTruth { pose, kind } = &data.events[1].event else {
            panic!()
        };
        assert_eq!(
            (*pose, *kind),
            (Pose2::new(1.0, 2.0, 0.5), TruthKind::Reference)
        );
    }

    #[test]
    fn max_range_readings_are_invalid() {
        let text = "FLASER 3 1.0 81.83 2.0 0 0 0 0 0 0 0 h 0\n";
        let data = read("maxrange", text, &CarmenOptions::default()).unwrap();
        let Event::Scan { scan, .. } = &data.events[0].event else {
            panic!()
        };
        assert_eq!(scan.points().len(), 2);
        assert!(!scan.is_valid(81.83));
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let cases = [
            (
                "ODOM 0 0 0 0 0 0 0 h\n",
                ":1: ODOM: expected 10 fields, got 9",
            ),
            (
                "NEFF 3\nFLASER 2 1.0 2.0 0 0 0 0 0 0 0 h\n",
                ":2: FLASER: expected 13 fields",
            ),
            (
                "FLASER 2 1.0 x 0 0 0 0 0 0 0 h 0\n",
                ":1:14: field 4 (range): expected a number, got `x`",
            ),
            (
                "FLASER 99999999999 1 h\n",
                ":1: number of readings is 99999999999",
            ),
            (
                "FLASER 0 0 0 0 0 0 0 0 h 0\n",
                ":1: a laser line needs at least one reading",
            ),
            (
                "ROBOTLASER1 0 0 3 0.1 30 0 0 2 1 2 1 0\n",
                ":1: ROBOTLASER1: expected 27 fields, got 13",
            ),
        ];
        for (k, (text, expected)) in cases.iter().enumerate() {
            let e = read(&format!("bad{k}"), text, &CarmenOptions::default())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("bad{k}.log{expected}")),
                "{e} vs {expected}"
            );
        }
    }
}
