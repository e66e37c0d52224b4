//! Dataset readers: each turns a dataset into one [`crate::Dataset`] event stream.
//!
//! | reader | data | clock | events |
//! |---|---|---|---|
//! | [`read_carmen`] | CARMEN logs (plain or gzip), e.g. the Radish "corrected" logs | line numbers ([`Clock::Sequence`]) | scans, reference poses, pose increments |
//! | [`read_victoria_park`] | Victoria Park (`converted/` CSV files) | seconds | Ackermann motion, pole observations, GPS |
//! | [`read_mrclam`] | UTIAS MR.CLAM dataset 1, one robot | seconds | unicycle motion, range-bearing observations, landmark map |
//! | [`read_tum`] | TUM trajectories (`t x y z qx qy qz qw`) | seconds | stamped poses (not an event stream) |
//! | [`read_rb2d`] | rb2d text logs (`shared/formats/rb2d.md`) | `k * dt` seconds | motion, range-bearing observations, true poses, landmark map |
//!
//! Conventions shared by every reader:
//!
//! - A malformed line is an error that names `file:line` (1-based) and the reason; readers
//!   never panic on their input.
//! - A [`Event::Motion`] carries the time at which the motion **ends**, as the simulator does:
//!   the increment from time `t0` to `t1` is stamped `t1`. When a measurement falls strictly
//!   inside an odometry interval, the interval is split there: motion up to the measurement,
//!   the measurement, then the rest of the interval with the same controls.
//! - Lines that carry nothing the reader uses are counted in [`crate::Dataset::skipped`].
//!
//! [`Clock::Sequence`]: crate::Clock::Sequence

pub mod carmen;
pub mod mrclam;
pub mod rb2d;
pub mod tum;
pub mod victoria_park;

pub use carmen::{CarmenOptions, read_carmen};
pub use mrclam::{MrclamOptions, read_mrclam};
pub use rb2d::read_rb2d;
pub use tum::{StampedPose, read_tum, write_atomically, write_tum};
pub use victoria_park::{VictoriaParkOptions, read_victoria_park};

use std::io::Read;
use std::path::Path;
use std::str::FromStr;

use crate::error::{Result, SensorError};
use crate::events::{Dataset, Event};

/// One row of a control log: `(line number, time s, (first control, second control))`.
type ControlRow = (usize, f64, (f64, f64));

/// One line of a data file split into fields, with its location for error messages.
pub(crate) struct Fields<'a> {
    file: &'a Path,
    line: usize,
    fields: Vec<&'a str>,
}

impl<'a> Fields<'a> {
    /// Fields separated by any whitespace (spaces and tabs).
    pub(crate) fn whitespace(file: &'a Path, line: usize, text: &'a str) -> Self {
        Fields {
            file,
            line,
            fields: text.split_whitespace().collect(),
        }
    }

    /// Comma-separated fields, each trimmed.
    pub(crate) fn csv(file: &'a Path, line: usize, text: &'a str) -> Self {
        Fields {
            file,
            line,
            fields: text.split(',').map(str::trim).collect(),
        }
    }

    /// Number of fields.
    pub(crate) fn len(&self) -> usize {
        self.fields.len()
    }

    /// The 1-based line number.
    pub(crate) fn line(&self) -> usize {
        self.line
    }

    /// The first field, or `""` for an empty line.
    pub(crate) fn first(&self) -> &'a str {
        self.fields.first().copied().unwrap_or("")
    }

    /// A parse error at this line.
    pub(crate) fn error(&self, message: impl Into<String>) -> SensorError {
        SensorError::parse(self.file, self.line, message)
    }

    /// A constructor's error reported at this line.
    pub(crate) fn wrap(&self, error: SensorError) -> SensorError {
        at(self.file, self.line, error)
    }

    /// Fails unless the line has exactly `expected` fields.
    pub(crate) fn expect_len(&self, expected: usize, what: &str) -> Result<()> {
        if self.fields.len() == expected {
            Ok(())
        } else {
            Err(self.error(format!(
                "{what}: expected {expected} fields, got {}",
                self.fields.len()
            )))
        }
    }

    /// Field `index` (0-based), or an error naming `what` when the line is too short.
    pub(crate) fn get(&self, index: usize, what: &str) -> Result<&'a str> {
        self.fields.get(index).copied().ok_or_else(|| {
            self.error(format!(
                "missing field {} ({what}): the line has only {} fields",
                index + 1,
                self.fields.len()
            ))
        })
    }

    /// Field `index` as a finite number.
    pub(crate) fn f64(&self, index: usize, what: &str) -> Result<f64> {
        let value: f64 = self.parse(index, what, "a number")?;
        if value.is_finite() {
            Ok(value)
        } else {
            Err(self.error(format!(
                "field {} ({what}): value `{}` is not finite",
                index + 1,
                self.fields[index]
            )))
        }
    }

    /// Fields `index..index + N` as finite numbers.
    pub(crate) fn f64s<const N: usize>(&self, index: usize, what: &str) -> Result<[f64; N]> {
        let mut values = [0.0; N];
        for (k, value) in values.iter_mut().enumerate() {
            *value = self.f64(index + k, what)?;
        }
        Ok(values)
    }

    /// Field `index` as a non-negative integer.
    pub(crate) fn usize(&self, index: usize, what: &str) -> Result<usize> {
        self.parse(index, what, "a non-negative integer")
    }

    /// Field `index` as a non-negative integer id.
    pub(crate) fn u64(&self, index: usize, what: &str) -> Result<u64> {
        self.parse(index, what, "a non-negative integer")
    }

    /// Field `index` as a signed integer.
    pub(crate) fn i64(&self, index: usize, what: &str) -> Result<i64> {
        self.parse(index, what, "an integer")
    }

    fn parse<T: FromStr>(&self, index: usize, what: &str, kind: &str) -> Result<T> {
        let text = self.get(index, what)?;
        text.parse().map_err(|_| {
            self.error(format!(
                "field {} ({what}): expected {kind}, got `{text}`",
                index + 1
            ))
        })
    }
}

/// The whole file as text, gunzipped when it starts with the gzip magic bytes `1f 8b`.
/// Invalid UTF-8 is replaced (it can only appear where a number was expected, and then the
/// number fails to parse with a line number).
pub(crate) fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| SensorError::io(path, e))?;
    if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut plain = Vec::new();
        flate2::read::MultiGzDecoder::new(bytes.as_slice())
            .read_to_end(&mut plain)
            .map_err(|e| SensorError::io(path, e))?;
        return Ok(String::from_utf8_lossy(&plain).into_owned());
    }
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

/// The lines of a text with their 1-based numbers (`\r\n` endings are stripped).
pub(crate) fn numbered_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l))
}

/// A "not found" I/O error on `path`, for files a reader needs.
pub(crate) fn missing(path: &Path, what: &str) -> SensorError {
    SensorError::io(
        path,
        std::io::Error::new(std::io::ErrorKind::NotFound, format!("{what} not found")),
    )
}

/// Checks that option values are finite and positive (`strict`) or non-negative.
pub(crate) fn check_sigmas(what: &str, values: &[(&str, f64)], strict: bool) -> Result<()> {
    for &(name, value) in values {
        let ok = value.is_finite() && if strict { value > 0.0 } else { value >= 0.0 };
        if !ok {
            let bound = if strict { "positive" } else { "non-negative" };
            return Err(SensorError::InvalidArgument(format!(
                "{what}: {name} must be finite and {bound}, got {value}"
            )));
        }
    }
    Ok(())
}

/// The reason of an error from a model constructor, without the "invalid argument" prefix,
/// to be reported at a line.
pub(crate) fn reason(error: &SensorError) -> String {
    match error {
        SensorError::InvalidArgument(message)
        | SensorError::Core(slam_core::Error::InvalidArgument(message)) => message.clone(),
        other => other.to_string(),
    }
}

/// `error` reported at `file:line`.
pub(crate) fn at(file: &Path, line: usize, error: SensorError) -> SensorError {
    SensorError::parse(file, line, reason(&error))
}

/// Counts one unused line under `key`.
pub(crate) fn count_skipped(dataset: &mut Dataset, key: &str) {
    *dataset.skipped.entry(key.to_string()).or_default() += 1;
}

/// Controls held constant from `start` to `end` (one odometry row and the next row's time).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Interval<C> {
    /// Start time, s.
    pub start: f64,
    /// End time, s (not before `start`).
    pub end: f64,
    /// The controls.
    pub control: C,
    /// The line of the odometry row, for errors.
    pub line: usize,
}

/// Checks that times are non-decreasing, naming the first line where one goes backwards.
pub(crate) fn check_non_decreasing(file: &Path, rows: &[(usize, f64)]) -> Result<()> {
    for pair in rows.windows(2) {
        let ((_, t0), (line, t1)) = (pair[0], pair[1]);
        if t1 < t0 {
            return Err(SensorError::parse(
                file,
                line,
                format!("time goes backwards: {t1} after {t0}"),
            ));
        }
    }
    Ok(())
}

/// Intervals between consecutive odometry rows `(line, time, control)`: row `k` holds from its
/// time to row `k + 1`'s. The last row has no duration and gives no interval. Times must be
/// non-decreasing; equal times give intervals of zero duration.
pub(crate) fn intervals<C: Copy>(
    file: &Path,
    rows: &[(usize, f64, C)],
) -> Result<Vec<Interval<C>>> {
    let times: Vec<(usize, f64)> = rows.iter().map(|&(line, t, _)| (line, t)).collect();
    check_non_decreasing(file, &times)?;
    Ok(rows
        .windows(2)
        .map(|w| Interval {
            start: w[0].1,
            end: w[1].1,
            control: w[0].2,
            line: w[0].0,
        })
        .collect())
}

/// Merges a motion stream with point events (measurements, GPS fixes) by time, appending to
/// `dataset`.
///
/// Points are stably sorted by time. A point at or before an interval's start comes before
/// that interval; a point strictly inside an interval splits it: `motion(start..t)`, the
/// point, then `motion(t..end)` with the same controls. Points after the last interval come
/// last. `make(interval, dt)` builds the motion event of a piece of duration `dt`; each
/// motion event is stamped with the time its piece ends.
pub(crate) fn merge_by_time<C>(
    dataset: &mut Dataset,
    intervals: &[Interval<C>],
    mut points: Vec<(f64, Event)>,
    mut make: impl FnMut(&Interval<C>, f64) -> Result<Event>,
) -> Result<()> {
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut points = points.into_iter().peekable();
    for interval in intervals {
        while let Some((time, event)) = points.next_if(|p| p.0 <= interval.start) {
            dataset.push(time, event);
        }
        let mut from = interval.start;
        while let Some((time, event)) = points.next_if(|p| p.0 < interval.end) {
            if time > from {
                dataset.push(time, make(interval, time - from)?);
                from = time;
            }
            dataset.push(time, event);
        }
        dataset.push(interval.end, make(interval, interval.end - from)?);
    }
    for (time, event) in points {
        dataset.push(time, event);
    }
    Ok(())
}

/// A fresh, empty folder under the system temp dir for one test, removed when dropped.
#[cfg(test)]
pub(crate) fn test_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("slam-sensors-unit-{name}-"))
        .tempdir()
        .unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::Clock;
    use slam_core::nalgebra::Vector2;

    fn gps(x: f64) -> Event {
        Event::Gps(Vector2::new(x, 0.0))
    }

    /// (time, "M"/"G", duration-or-x) of every event.
    fn trace(dataset: &Dataset, durations: &[f64]) -> Vec<(f64, char, f64)> {
        let mut k = 0;
        dataset
            .events
            .iter()
            .map(|e| match &e.event {
                Event::Motion(_) => {
                    k += 1;
                    (e.time, 'M', durations[k - 1])
                }
                Event::Gps(v) => (e.time, 'G', v.x),
                _ => unreachable!(),
            })
            .collect()
    }

    #[test]
    fn points_split_motion_intervals() {
        let rows = [(2, 0.0, ()), (3, 1.0, ()), (4, 2.0, ())];
        let intervals = intervals(Path::new("odo"), &rows).unwrap();
        assert_eq!(intervals.len(), 2);
        let points = vec![
            (2.5, gps(4.0)),
            (0.5, gps(1.0)),
            (-1.0, gps(0.0)),
            (1.0, gps(2.0)),
            (0.5, gps(1.5)),
        ];
        let mut dataset = Dataset::new("t", Clock::Seconds);
        let mut durations = Vec::new();
        merge_by_time(&mut dataset, &intervals, points, |_, dt| {
            durations.push(dt);
            Ok(Event::Motion(Box::new(
                crate::odometry::Unicycle::new(0.0, 0.0, dt, 0.0, 0.0, Default::default()).unwrap(),
            )))
        })
        .unwrap();
        let expected = vec![
            (-1.0, 'G', 0.0),
            (0.5, 'M', 0.5),
            (0.5, 'G', 1.0),
            (0.5, 'G', 1.5),
            (1.0, 'M', 0.5),
            (1.0, 'G', 2.0),
            (2.0, 'M', 1.0),
            (2.5, 'G', 4.0),
        ];
        assert_eq!(trace(&dataset, &durations), expected);
    }

    #[test]
    fn times_going_backwards_are_errors() {
        let rows = [(5, 1.0, ()), (6, 0.5, ())];
        let e = intervals(Path::new("odo.dat"), &rows)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("odo.dat:6: time goes backwards"), "{e}");
    }

    #[test]
    fn fields_report_file_line_and_reason() {
        let f = Fields::whitespace(Path::new("a.log"), 7, "X 1.5 abc inf");
        assert_eq!(f.f64(1, "x").unwrap(), 1.5);
        assert_eq!(
            f.f64(2, "y").unwrap_err().to_string(),
            "a.log:7: field 3 (y): expected a number, got `abc`"
        );
        assert!(
            f.f64(3, "z")
                .unwrap_err()
                .to_string()
                .contains("not finite")
        );
        assert!(
            f.f64(4, "w")
                .unwrap_err()
                .to_string()
                .contains("missing field 5")
        );
        assert!(
            f.expect_len(3, "X")
                .unwrap_err()
                .to_string()
                .contains("expected 3 fields, got 4")
        );
    }

    #[test]
    fn gzip_is_detected() {
        use std::io::Write;
        let dir = test_dir("gzip");
        let path = dir.path().join("a.gz");
        let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        encoder.write_all(b"hello\nworld\n").unwrap();
        std::fs::write(&path, encoder.finish().unwrap()).unwrap();
        assert_eq!(read_text(&path).unwrap(), "hello\nworld\n");
        std::fs::write(dir.path().join("b"), b"plain").unwrap();
        assert_eq!(read_text(&dir.path().join("b")).unwrap(), "plain");
    }
}
