//! Dataset readers: each turns a dataset into one event stream, read one line at a time
//! ([`crate::EventStream`], `stream_*`) or collected in memory ([`crate::Dataset`], `read_*`:
//! the same events).
//!
//! | reader | data | clock | events |
//! |---|---|---|---|
//! | [`stream_carmen`], [`read_carmen`] | CARMEN logs (plain or gzip), e.g. the Radish "corrected" logs | logger timestamps, s (line numbers, [`Clock::Sequence`], where they cannot order the events) | scans, reference poses, pose increments |
//! | [`stream_mcap`], [`read_mcap`] | ROS 2 bags (MCAP, CDR): `LaserScan`, `Odometry`, reference poses, `/tf_static` | header stamps, seconds | scans, reference poses, pose increments |
//! | [`stream_victoria_park`], [`read_victoria_park`] | Victoria Park (`converted/` CSV files) | seconds | Ackermann motion, pole observations, GPS |
//! | [`stream_mrclam`], [`read_mrclam`] | UTIAS MR.CLAM dataset 1, one robot | seconds | unicycle motion, range-bearing observations, landmark map |
//! | [`read_tum`] | TUM trajectories (`t x y z qx qy qz qw`) | seconds | stamped poses (not an event stream) |
//! | [`stream_rb2d`], [`read_rb2d`] | rb2d text logs (`shared/formats/rb2d.md`) | `k * dt` seconds | motion, range-bearing observations, true poses, landmark map |
//!
//! [`odometry_from_poses`] is a stream adapter: it replaces a log's motion by noisy odometry
//! built from its reference poses.
//!
//! Conventions shared by every reader:
//!
//! - A malformed line is an error that names `file:line` (1-based) and the reason; readers
//!   never panic on their input. A `stream_*` call fails for what it can know up front (bad
//!   options, missing files, bad headers); a malformed line further down is an `Err` item of
//!   the stream when it gets there, after the events of the lines before it.
//! - A [`Event::Motion`] carries the time at which the motion **ends**, as the simulator does:
//!   the increment from time `t0` to `t1` is stamped `t1`. When a measurement falls strictly
//!   inside an odometry interval, the interval is split there: motion up to the measurement,
//!   the measurement, then the rest of the interval with the same controls.
//! - Lines that carry nothing the reader uses are counted in [`crate::Dataset::skipped`]
//!   ([`crate::EventStream::skipped`] while streaming).
//!
//! [`Clock::Sequence`]: crate::Clock::Sequence

pub mod carmen;
mod cdr;
pub mod mcap;
pub mod mrclam;
pub mod pose_odometry;
pub mod rb2d;
mod stamps;
pub mod tum;
mod units;
pub mod victoria_park;

pub use self::mcap::{McapOptions, read_mcap, stream_mcap};
pub use carmen::{CarmenOptions, NO_RETURN_BAND, read_carmen, stream_carmen};
pub use mrclam::{MrclamOptions, read_mrclam, stream_mrclam};
pub use pose_odometry::{PoseOdometryParams, odometry_from_poses};
pub use rb2d::{read_rb2d, stream_rb2d};
pub use tum::{StampedPose, read_tum, write_atomically, write_atomically_with, write_tum};
pub use victoria_park::{VictoriaParkOptions, read_victoria_park, stream_victoria_park};

use std::borrow::Cow;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::error::{Result, SensorError};
use crate::events::{Event, TimedEvent};

/// One line of a data file split into fields, with its location for error messages.
pub(crate) struct Fields<'a> {
    file: &'a Path,
    line: usize,
    text: &'a str,
    /// The first [`INLINE_FIELDS`] fields, or all of them when `spilled` is empty.
    inline: [&'a str; INLINE_FIELDS],
    /// How many of `inline` are fields.
    count: usize,
    /// All fields of a line with more than [`INLINE_FIELDS`] (empty otherwise: most lines
    /// of a log are short, and this keeps them free of allocations).
    spilled: Vec<&'a str>,
}

/// Fields of a line kept without allocating.
const INLINE_FIELDS: usize = 12;

impl<'a> Fields<'a> {
    /// Fields separated by ASCII whitespace (spaces and tabs: the logs are ASCII text, and a
    /// byte-wise split does not decode characters).
    pub(crate) fn whitespace(file: &'a Path, line: usize, text: &'a str) -> Self {
        Self::from_iter(file, line, text, text.split_ascii_whitespace())
    }

    /// Comma-separated fields, each trimmed.
    pub(crate) fn csv(file: &'a Path, line: usize, text: &'a str) -> Self {
        Self::from_iter(file, line, text, text.split(',').map(str::trim))
    }

    fn from_iter(
        file: &'a Path,
        line: usize,
        text: &'a str,
        fields: impl Iterator<Item = &'a str>,
    ) -> Self {
        let mut out = Fields {
            file,
            line,
            text,
            inline: [""; INLINE_FIELDS],
            count: 0,
            spilled: Vec::new(),
        };
        for field in fields {
            if out.count < INLINE_FIELDS {
                out.inline[out.count] = field;
            } else {
                if out.spilled.is_empty() {
                    out.spilled.extend_from_slice(&out.inline);
                }
                out.spilled.push(field);
            }
            out.count += 1;
        }
        out
    }

    /// All fields, in order.
    pub(crate) fn all(&self) -> &[&'a str] {
        if self.spilled.is_empty() {
            &self.inline[..self.count]
        } else {
            &self.spilled
        }
    }

    /// Number of fields.
    pub(crate) fn len(&self) -> usize {
        self.all().len()
    }

    /// The 1-based line number.
    pub(crate) fn line(&self) -> usize {
        self.line
    }

    /// The first field, or `""` for an empty line.
    pub(crate) fn first(&self) -> &'a str {
        self.all().first().copied().unwrap_or("")
    }

    /// A parse error at this line.
    pub(crate) fn error(&self, message: impl Into<String>) -> SensorError {
        SensorError::parse(self.file, self.line, message)
    }

    /// A parse error at field `index` (its column), or at the end of the line when the line
    /// has no such field.
    pub(crate) fn field_error(&self, index: usize, message: impl Into<String>) -> SensorError {
        let offset = match self.all().get(index) {
            // A field is a slice of the line's text: its offset is the distance between them.
            Some(field) => (field.as_ptr() as usize).saturating_sub(self.text.as_ptr() as usize),
            None => self.text.len(),
        };
        let column = self.text.get(..offset).map_or(1, |s| s.chars().count() + 1);
        SensorError::parse_at(self.file, self.line, column, message)
    }

    /// A constructor's error reported at this line.
    pub(crate) fn wrap(&self, error: SensorError) -> SensorError {
        at(self.file, self.line, error)
    }

    /// Fails unless the line has exactly `expected` fields.
    pub(crate) fn expect_len(&self, expected: usize, what: &str) -> Result<()> {
        if self.all().len() == expected {
            Ok(())
        } else {
            Err(self.error(format!(
                "{what}: expected {expected} fields, got {}",
                self.all().len()
            )))
        }
    }

    /// Field `index` (0-based), or an error naming `what` when the line is too short.
    pub(crate) fn get(&self, index: usize, what: &str) -> Result<&'a str> {
        self.all().get(index).copied().ok_or_else(|| {
            self.field_error(
                index,
                format!(
                    "missing field {} ({what}): the line has only {} fields",
                    index + 1,
                    self.all().len()
                ),
            )
        })
    }

    /// Field `index` as a finite number.
    pub(crate) fn f64(&self, index: usize, what: &str) -> Result<f64> {
        let value: f64 = self.parse(index, what, "a number")?;
        if value.is_finite() {
            Ok(value)
        } else {
            Err(self.field_error(
                index,
                format!(
                    "field {} ({what}): value `{}` is not finite",
                    index + 1,
                    self.all()[index]
                ),
            ))
        }
    }

    /// Field `index` as a number, finite or not (`nan`, `inf`).
    pub(crate) fn number(&self, index: usize, what: &str) -> Result<f64> {
        self.parse(index, what, "a number")
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
            self.field_error(
                index,
                format!(
                    "field {} ({what}): expected {kind}, got `{text}`",
                    index + 1
                ),
            )
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

/// The longest line a reader takes, bytes: a longer one is an error, so that a file with no
/// line breaks (a binary file given by mistake) is not read whole into memory.
pub const MAX_LINE_BYTES: usize = 16 << 20;

/// The lines of a text file, read one at a time: gunzipped when the file starts with the gzip
/// magic bytes `1f 8b`, with 1-based numbers, `\n` and `\r\n` endings stripped as
/// [`str::lines`] does, and invalid UTF-8 replaced as [`read_text`] does.
pub(crate) struct Lines {
    path: PathBuf,
    reader: Box<dyn BufRead + Send>,
    number: usize,
    buffer: Vec<u8>,
    done: bool,
}

impl Lines {
    /// Opens `path`; an I/O error (missing file, unreadable start) names it.
    pub(crate) fn open(path: &Path) -> Result<Lines> {
        let io = |e| SensorError::io(path, e);
        let mut file = std::fs::File::open(path).map_err(io)?;
        let mut magic = [0u8; 2];
        let mut read = 0;
        while read < magic.len() {
            match file.read(&mut magic[read..]) {
                Ok(0) => break,
                Ok(n) => read += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(io(e)),
            }
        }
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        let reader: Box<dyn BufRead + Send> = if read == 2 && magic == [0x1f, 0x8b] {
            Box::new(BufReader::new(flate2::read::MultiGzDecoder::new(file)))
        } else {
            Box::new(BufReader::new(file))
        };
        Ok(Lines {
            path: path.to_path_buf(),
            reader,
            number: 0,
            buffer: Vec::new(),
            done: false,
        })
    }

    /// The file.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// The number of the last line read (0 before the first).
    pub(crate) fn number(&self) -> usize {
        self.number
    }
}

impl Lines {
    /// The next line as [`Iterator::next`] gives it, borrowed from the reader's buffer when
    /// it is valid UTF-8 (no allocation per line).
    pub(crate) fn next_line(&mut self) -> Option<Result<(usize, Cow<'_, str>)>> {
        if self.done {
            return None;
        }
        self.buffer.clear();
        let limit = MAX_LINE_BYTES as u64 + 1;
        match (&mut self.reader)
            .take(limit)
            .read_until(b'\n', &mut self.buffer)
        {
            Ok(0) => {
                self.done = true;
                None
            }
            Ok(n) if n > MAX_LINE_BYTES => {
                self.done = true;
                Some(Err(SensorError::parse(
                    &self.path,
                    self.number + 1,
                    format!(
                        "line longer than {} MiB (is this a text log?)",
                        MAX_LINE_BYTES >> 20
                    ),
                )))
            }
            Ok(_) => {
                self.number += 1;
                let mut bytes = self.buffer.as_slice();
                if let Some(rest) = bytes.strip_suffix(b"\n") {
                    bytes = rest.strip_suffix(b"\r").unwrap_or(rest);
                }
                let text = match std::str::from_utf8(bytes) {
                    Ok(text) => Cow::Borrowed(text),
                    Err(_) => String::from_utf8_lossy(bytes),
                };
                Some(Ok((self.number, text)))
            }
            Err(e) => {
                self.done = true;
                Some(Err(SensorError::io(&self.path, e)))
            }
        }
    }
}

impl Iterator for Lines {
    /// `(line number, text)`, or the I/O error that ends the file.
    type Item = Result<(usize, String)>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_line()
            .map(|next| next.map(|(number, text)| (number, text.into_owned())))
    }
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

/// Intervals between consecutive odometry rows `(line, time, control)`: row `k` holds from its
/// time to row `k + 1`'s. The last row has no duration and gives no interval. Times must be
/// non-decreasing (a row going backwards is an error naming its line); equal times give
/// intervals of zero duration.
pub(crate) struct Intervals<C, R> {
    file: PathBuf,
    rows: R,
    previous: Option<(usize, f64, C)>,
}

impl<C, R> Intervals<C, R> {
    pub(crate) fn new(file: &Path, rows: R) -> Self {
        Intervals {
            file: file.to_path_buf(),
            rows,
            previous: None,
        }
    }
}

impl<C: Copy, R: Iterator<Item = Result<(usize, f64, C)>>> Iterator for Intervals<C, R> {
    type Item = Result<Interval<C>>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let row = match self.rows.next()? {
                Ok(row) => row,
                Err(e) => return Some(Err(e)),
            };
            let Some((line, start, control)) = self.previous.replace(row) else {
                continue;
            };
            let (next_line, end, _) = row;
            if end < start {
                return Some(Err(SensorError::parse(
                    &self.file,
                    next_line,
                    format!("time goes backwards: {end} after {start}"),
                )));
            }
            return Some(Ok(Interval {
                start,
                end,
                control,
                line,
            }));
        }
    }
}

/// A point event (a measurement, a GPS fix) with its time and the line it comes from.
#[derive(Debug)]
pub(crate) struct Point {
    /// The line, for errors.
    pub line: usize,
    /// Seconds.
    pub time: f64,
    /// The event.
    pub event: Event,
}

/// The points of one file, checked to be in time order (by [`f64::total_cmp`], the order
/// that [`merge_by_time`] relies on); a point going backwards is an error naming its line.
pub(crate) fn in_time_order<I: Iterator<Item = Result<Point>>>(
    file: &Path,
    points: I,
) -> impl Iterator<Item = Result<Point>> + use<I> {
    let file = file.to_path_buf();
    let mut last: Option<f64> = None;
    points.map(move |point| {
        let point = point?;
        if let Some(before) = last
            && point.time.total_cmp(&before).is_lt()
        {
            return Err(SensorError::parse(
                &file,
                point.line,
                format!("time goes backwards: {} after {before}", point.time),
            ));
        }
        last = Some(point.time);
        Ok(point)
    })
}

/// Two time-ordered point streams merged by time; on equal times `first`'s points come first
/// (the order of a stable sort of `first` followed by `second`).
pub(crate) fn merge_points<A, B>(first: A, second: B) -> impl Iterator<Item = Result<Point>>
where
    A: Iterator<Item = Result<Point>>,
    B: Iterator<Item = Result<Point>>,
{
    let (mut a, mut b) = (first.peekable(), second.peekable());
    std::iter::from_fn(move || match (a.peek(), b.peek()) {
        (Some(Err(_)), _) | (Some(Ok(_)), None) => a.next(),
        (_, Some(Err(_))) | (None, _) => b.next(),
        (Some(Ok(x)), Some(Ok(y))) => {
            if x.time.total_cmp(&y.time).is_le() {
                a.next()
            } else {
                b.next()
            }
        }
    })
}

/// The interval being merged and where its motion has got to.
struct Current<C> {
    interval: Interval<C>,
    /// The time up to which its motion has been written.
    from: f64,
    /// Whether the points at or before its start have all been written.
    inside: bool,
}

/// A motion stream merged with time-ordered point events (measurements, GPS fixes), one
/// event at a time.
///
/// A point at or before an interval's start comes before that interval; a point strictly
/// inside an interval splits it: `motion(start..t)`, the point, then `motion(t..end)` with the
/// same controls. Points after the last interval come last. `make(interval, dt)` builds the
/// motion event of a piece of duration `dt`; each motion event is stamped with the time its
/// piece ends.
pub(crate) struct MergeByTime<C, I, P: Iterator, M> {
    intervals: I,
    points: std::iter::Peekable<P>,
    make: M,
    current: Option<Current<C>>,
}

/// See [`MergeByTime`].
pub(crate) fn merge_by_time<C, I, P, M>(intervals: I, points: P, make: M) -> MergeByTime<C, I, P, M>
where
    I: Iterator<Item = Result<Interval<C>>>,
    P: Iterator<Item = Result<Point>>,
    M: FnMut(&Interval<C>, f64) -> Result<Event>,
{
    MergeByTime {
        intervals,
        points: points.peekable(),
        make,
        current: None,
    }
}

impl<C, I, P, M> Iterator for MergeByTime<C, I, P, M>
where
    I: Iterator<Item = Result<Interval<C>>>,
    P: Iterator<Item = Result<Point>>,
    M: FnMut(&Interval<C>, f64) -> Result<Event>,
{
    type Item = Result<TimedEvent>;

    fn next(&mut self) -> Option<Self::Item> {
        let point = |p: Option<Result<Point>>| {
            p.map(|p| {
                p.map(|p| TimedEvent {
                    time: p.time,
                    event: p.event,
                })
            })
        };
        loop {
            let Some(current) = self.current.as_mut() else {
                match self.intervals.next() {
                    Some(Ok(interval)) => {
                        self.current = Some(Current {
                            from: interval.start,
                            interval,
                            inside: false,
                        });
                        continue;
                    }
                    Some(Err(e)) => return Some(Err(e)),
                    None => return point(self.points.next()),
                }
            };
            if !current.inside {
                match self.points.peek() {
                    Some(Err(_)) => return point(self.points.next()),
                    Some(Ok(p)) if p.time <= current.interval.start => {
                        return point(self.points.next());
                    }
                    _ => current.inside = true,
                }
            }
            return match self.points.peek() {
                Some(Err(_)) => point(self.points.next()),
                Some(Ok(p)) if p.time < current.interval.end => {
                    let time = p.time;
                    if time > current.from {
                        let dt = time - current.from;
                        current.from = time;
                        Some(
                            (self.make)(&current.interval, dt)
                                .map(|event| TimedEvent { time, event }),
                        )
                    } else {
                        point(self.points.next())
                    }
                }
                _ => {
                    let Current { interval, from, .. } = self.current.take()?;
                    let time = interval.end;
                    Some(
                        (self.make)(&interval, time - from).map(|event| TimedEvent { time, event }),
                    )
                }
            };
        }
    }
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
    use slam_core::nalgebra::Vector2;

    fn gps(line: usize, time: f64, x: f64) -> Result<Point> {
        Ok(Point {
            line,
            time,
            event: Event::Gps(Vector2::new(x, 0.0)),
        })
    }

    /// (time, "M"/"G", duration-or-x) of every event.
    fn trace(events: &[TimedEvent], durations: &[f64]) -> Vec<(f64, char, f64)> {
        let mut k = 0;
        events
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

    fn merged(
        rows: &[(usize, f64, ())],
        points: Vec<Result<Point>>,
    ) -> Result<Vec<(f64, char, f64)>> {
        let intervals = Intervals::new(Path::new("odo"), rows.iter().copied().map(Ok));
        let mut durations = Vec::new();
        let events = merge_by_time(intervals, points.into_iter(), |_, dt| {
            durations.push(dt);
            Ok(Event::Motion(Box::new(
                crate::odometry::Unicycle::new(0.0, 0.0, dt, 0.0, 0.0, Default::default()).unwrap(),
            )))
        })
        .collect::<Result<Vec<_>>>()?;
        Ok(trace(&events, &durations))
    }

    #[test]
    fn points_split_motion_intervals() {
        let rows = [(2, 0.0, ()), (3, 1.0, ()), (4, 2.0, ())];
        // Two sources, each in time order; on equal times the first one's points come first.
        let first = vec![gps(1, -1.0, 0.0), gps(2, 0.5, 1.0), gps(3, 2.5, 4.0)];
        let second = vec![gps(1, 0.5, 1.5), gps(2, 1.0, 2.0)];
        let points = merge_points(first.into_iter(), second.into_iter());
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
        assert_eq!(merged(&rows, points.collect()).unwrap(), expected);
        // No odometry: the points alone; no points: the intervals alone.
        assert_eq!(
            merged(&[], vec![gps(1, 3.0, 1.0)]).unwrap(),
            [(3.0, 'G', 1.0)]
        );
        assert_eq!(merged(&rows[..2], vec![]).unwrap(), [(1.0, 'M', 1.0)]);
    }

    #[test]
    fn times_going_backwards_are_errors() {
        let rows = [(5, 1.0, ()), (6, 0.5, ())];
        let e = merged(&rows, vec![]).unwrap_err().to_string();
        assert!(e.starts_with("odo:6: time goes backwards"), "{e}");
        let points = vec![gps(7, 1.0, 0.0), gps(8, 0.5, 0.0)];
        let e = in_time_order(Path::new("gps.csv"), points.into_iter())
            .collect::<Result<Vec<_>>>()
            .unwrap_err()
            .to_string();
        assert_eq!(e, "gps.csv:8: time goes backwards: 0.5 after 1");
    }

    #[test]
    fn fields_report_file_line_and_reason() {
        let f = Fields::whitespace(Path::new("a.log"), 7, "X 1.5 abc inf");
        assert_eq!(f.f64(1, "x").unwrap(), 1.5);
        assert_eq!(
            f.f64(2, "y").unwrap_err().to_string(),
            "a.log:7:7: field 3 (y): expected a number, got `abc`"
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
        let lines = |path: &Path| -> Vec<(usize, String)> {
            Lines::open(path).unwrap().collect::<Result<_>>().unwrap()
        };
        assert_eq!(lines(&path), [(1, "hello".into()), (2, "world".into())]);
        assert_eq!(lines(&dir.path().join("b")), [(1, "plain".into())]);
        assert!(Lines::open(&dir.path().join("absent")).is_err());
    }

    #[test]
    fn lines_end_as_str_lines_does() {
        let dir = test_dir("lines");
        let texts: [&[u8]; 8] = [
            b"",
            b"\n",
            b"a\r\nb\n\nc",
            b"a\r",
            b"a\r\r\n\r",
            b"x\xe2\x82\ny\xff\r\nz",
            b"\xef\xbb\xbfh,1\n",
            b"\x1f",
        ];
        for (k, text) in texts.iter().enumerate() {
            let path = dir.path().join(format!("t{k}"));
            std::fs::write(&path, text).unwrap();
            let streamed: Vec<(usize, String)> =
                Lines::open(&path).unwrap().collect::<Result<_>>().unwrap();
            let whole = read_text(&path).unwrap();
            let expected: Vec<(usize, String)> = numbered_lines(&whole)
                .map(|(n, l)| (n, l.to_string()))
                .collect();
            assert_eq!(streamed, expected, "{text:?}");
        }
    }
}
