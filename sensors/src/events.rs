//! The common stream of timestamped events that every dataset reader and the simulator yield,
//! and that every estimator consumes: whole in memory ([`Dataset`]) or one event at a time
//! ([`EventStream`]).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use slam_core::nalgebra::Vector2;
use slam_core::{MotionModel, Observation, Pose2, Pose3};

use crate::error::Result;
use crate::scan::LaserScan;

/// What happened at one time.
#[derive(Debug)]
pub enum Event {
    /// A dead-reckoning increment since the previous `Motion` event (eqs. 25-27).
    Motion(Box<dyn MotionModel<Pose2>>),
    /// A raw laser scan, for an extraction front-end to turn into observations.
    Scan {
        /// The scan.
        scan: LaserScan,
        /// Where the laser sits on the robot.
        robot_from_sensor: Pose3,
    },
    /// A raw ceiling-camera image, for the image front-end.
    Image {
        /// The image.
        image: crate::camera::GrayImage,
        /// Intrinsics of the camera that took it.
        camera: crate::camera::PinholeCamera,
        /// Where the camera sits on the robot.
        robot_from_sensor: Pose3,
    },
    /// Measurements ready for an estimator (extracted, or given by the dataset).
    Observations(Vec<Observation>),
    /// The true pose of the robot (simulation, rb2d), or a reference pose from another system
    /// (the SLAM-corrected poses of the Radish logs).
    GroundTruth {
        /// The pose.
        pose: Pose2,
        /// Whether it is independent truth or another estimator's output.
        kind: TruthKind,
    },
    /// A GPS fix in the dataset's local metric frame.
    Gps(Vector2<f64>),
}

/// How trustworthy a [`Event::GroundTruth`] pose is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TruthKind {
    /// Independent ground truth (simulator, motion capture, a generator's truth).
    True,
    /// The output of another SLAM system, usable as a reference only.
    Reference,
}

/// An event and its time in seconds. Events are in time order; when a dataset's clock is
/// unusable the time is the event's sequence number and [`Dataset::clock`] says so.
#[derive(Debug)]
pub struct TimedEvent {
    /// Seconds (or sequence number).
    pub time: f64,
    /// The event.
    pub event: Event,
}

/// Where the times of a [`Dataset`] come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Clock {
    /// Seconds from the data.
    Seconds,
    /// Line or record order only.
    Sequence,
}

/// A known landmark position, for map-error evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct KnownLandmark {
    /// The landmark's id as the data name it.
    pub id: u64,
    /// Position in the map frame, m.
    pub position: Vector2<f64>,
}

/// A whole dataset as one event stream, plus what it says about itself.
#[derive(Debug)]
pub struct Dataset {
    /// Short description, e.g. the file name.
    pub name: String,
    /// The events, in time order.
    pub events: Vec<TimedEvent>,
    /// Where the times come from.
    pub clock: Clock,
    /// Surveyed or generated landmark positions, when the data have them.
    pub landmarks: Vec<KnownLandmark>,
    /// Lines that were not used, counted by their first word (e.g. `NEFF`, `PARAM`).
    pub skipped: BTreeMap<String, usize>,
    /// Readings skipped as physically impossible, counted by reason (see [`crate::data`]).
    pub skipped_readings: BTreeMap<String, usize>,
    /// Warnings about the data (e.g. implausible units).
    pub warnings: Vec<String>,
}

impl Dataset {
    /// An empty dataset named `name`.
    pub fn new(name: impl Into<String>, clock: Clock) -> Self {
        Dataset {
            name: name.into(),
            events: Vec::new(),
            clock,
            landmarks: Vec::new(),
            skipped: Default::default(),
            skipped_readings: Default::default(),
            warnings: Vec::new(),
        }
    }

    /// Appends an event.
    pub fn push(&mut self, time: f64, event: Event) {
        self.events.push(TimedEvent { time, event });
    }

    /// Counts events of each kind, for summaries and tests.
    pub fn counts(&self) -> EventCounts {
        let mut counts = EventCounts::default();
        for e in &self.events {
            match &e.event {
                Event::Motion(_) => counts.motion += 1,
                Event::Scan { .. } => counts.scans += 1,
                Event::Image { .. } => counts.images += 1,
                Event::Observations(o) => {
                    counts.observation_events += 1;
                    counts.observations += o.len();
                }
                Event::GroundTruth { .. } => counts.ground_truth += 1,
                Event::Gps(_) => counts.gps += 1,
            }
        }
        counts
    }
}

/// How many events of each kind a dataset holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EventCounts {
    /// Motion increments.
    pub motion: usize,
    /// Laser scans.
    pub scans: usize,
    /// Camera images.
    pub images: usize,
    /// Observation events (one per time step with measurements).
    pub observation_events: usize,
    /// Individual observations.
    pub observations: usize,
    /// Ground-truth or reference poses.
    pub ground_truth: usize,
    /// GPS fixes.
    pub gps: usize,
}

/// What a dataset says about itself before its events are read.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetInfo {
    /// Short description, e.g. the file name.
    pub name: String,
    /// Where the times come from.
    pub clock: Clock,
    /// Surveyed or generated landmark positions, when the data have them.
    pub landmarks: Vec<KnownLandmark>,
    /// Where the GPS antenna sits in the robot frame (x forward, y left), m: the point of the
    /// robot whose path the [`Event::Gps`] fixes measure. Zero when the data have no GPS.
    pub gps_antenna: Vector2<f64>,
}

/// What a reader left out or doubts, shared between a reader and its [`EventStream`] (cloning
/// shares the counts): unused lines counted by their first word, readings skipped as
/// physically impossible counted by reason (the input policy of [`crate::data`]), and
/// warnings about the data (implausible units, ...).
#[derive(Clone, Debug, Default)]
pub struct SkipCounter(Arc<Mutex<Skipped>>);

/// The contents of a [`SkipCounter`].
#[derive(Clone, Debug, Default)]
struct Skipped {
    lines: BTreeMap<String, usize>,
    readings: BTreeMap<String, usize>,
    warnings: Vec<String>,
    notes: Vec<String>,
}

/// At most this many distinct warnings are kept (a warning is about the data, not a line).
const MAX_WARNINGS: usize = 32;

impl SkipCounter {
    /// A counter starting at `counts` unused lines.
    pub fn new(counts: BTreeMap<String, usize>) -> Self {
        SkipCounter(Arc::new(Mutex::new(Skipped {
            lines: counts,
            ..Skipped::default()
        })))
    }

    /// Counts one unused line under `key`.
    pub fn count(&self, key: &str) {
        increment(&mut self.lock().lines, key);
    }

    /// Counts one reading skipped for `reason` (e.g. `"rb2d OBS: range not positive"`).
    pub fn count_reading(&self, reason: &str) {
        increment(&mut self.lock().readings, reason);
    }

    /// Keeps a warning about the data (once; at most a few dozen are kept).
    pub fn warn(&self, warning: impl Into<String>) {
        let warning = warning.into();
        let mut skipped = self.lock();
        if skipped.warnings.len() < MAX_WARNINGS && !skipped.warnings.contains(&warning) {
            skipped.warnings.push(warning);
        }
    }

    /// Keeps a note on how the data were read (e.g. where a sensor's mount came from), once;
    /// at most a few dozen are kept.
    pub fn note(&self, note: impl Into<String>) {
        let note = note.into();
        let mut skipped = self.lock();
        if skipped.notes.len() < MAX_WARNINGS && !skipped.notes.contains(&note) {
            skipped.notes.push(note);
        }
    }

    /// The notes so far.
    pub fn notes(&self) -> Vec<String> {
        self.lock().notes.clone()
    }

    /// The unused lines so far, by first word.
    pub fn get(&self) -> BTreeMap<String, usize> {
        self.lock().lines.clone()
    }

    /// The skipped readings so far, by reason.
    pub fn readings(&self) -> BTreeMap<String, usize> {
        self.lock().readings.clone()
    }

    /// The warnings so far.
    pub fn warnings(&self) -> Vec<String> {
        self.lock().warnings.clone()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Skipped> {
        // A panic while counting cannot leave the counts inconsistent: use them anyway.
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

fn increment(counts: &mut BTreeMap<String, usize>, key: &str) {
    match counts.get_mut(key) {
        Some(n) => *n += 1,
        None => {
            counts.insert(key.to_string(), 1);
        }
    }
}

/// A dataset read (or simulated) one event at a time, in time order.
///
/// An iterator of `Result<TimedEvent>`: a malformed line further down a file arrives as an
/// `Err` item when the reader gets there, and the stream ends after it.
///
/// ```
/// use slam_sensors::{Clock, Dataset, Event, EventStream};
/// use slam_core::nalgebra::Vector2;
/// let mut data = Dataset::new("tiny", Clock::Seconds);
/// data.push(1.0, Event::Gps(Vector2::new(1.0, 2.0)));
/// let mut stream = EventStream::from_dataset(data);
/// assert_eq!(stream.info.name, "tiny");
/// assert_eq!(stream.next().unwrap().unwrap().time, 1.0);
/// assert!(stream.next().is_none());
/// ```
pub struct EventStream {
    /// What the dataset says about itself.
    pub info: DatasetInfo,
    events: Box<dyn Iterator<Item = Result<TimedEvent>> + Send>,
    skipped: SkipCounter,
    done: bool,
}

impl EventStream {
    /// A stream of `events`, with no skipped lines (see [`EventStream::with_skipped`]).
    pub fn new(
        info: DatasetInfo,
        events: impl Iterator<Item = Result<TimedEvent>> + Send + 'static,
    ) -> Self {
        EventStream {
            info,
            events: Box::new(events),
            skipped: SkipCounter::default(),
            done: false,
        }
    }

    /// The stream with `skipped` as its skip counts (shared with whatever counts into it).
    pub fn with_skipped(mut self, skipped: SkipCounter) -> Self {
        self.skipped = skipped;
        self
    }

    /// An in-memory dataset as a stream.
    pub fn from_dataset(dataset: Dataset) -> Self {
        let Dataset {
            name,
            events,
            clock,
            landmarks,
            skipped,
            skipped_readings,
            warnings,
        } = dataset;
        let info = DatasetInfo {
            name,
            clock,
            landmarks,
            gps_antenna: Vector2::zeros(),
        };
        let counter = SkipCounter::new(skipped);
        for (reason, n) in skipped_readings {
            for _ in 0..n {
                counter.count_reading(&reason);
            }
        }
        for warning in warnings {
            counter.warn(warning);
        }
        EventStream::new(info, events.into_iter().map(Ok)).with_skipped(counter)
    }

    /// Lines not used so far, counted by their first word (as [`Dataset::skipped`]).
    pub fn skipped(&self) -> BTreeMap<String, usize> {
        self.skipped.get()
    }

    /// Readings skipped so far as physically impossible, by reason.
    pub fn skipped_readings(&self) -> BTreeMap<String, usize> {
        self.skipped.readings()
    }

    /// Warnings about the data so far (e.g. implausible units).
    pub fn warnings(&self) -> Vec<String> {
        self.skipped.warnings()
    }

    /// Notes on how the data were read so far (e.g. where the laser mount came from).
    pub fn notes(&self) -> Vec<String> {
        self.skipped.notes()
    }

    /// The shared skip counter, for an adapter that passes it on to the stream it builds.
    pub fn skip_counter(&self) -> SkipCounter {
        self.skipped.clone()
    }

    /// Collects the remaining events into a [`Dataset`]; the first `Err` ends it.
    pub fn into_dataset(self) -> Result<Dataset> {
        let EventStream {
            info,
            events,
            skipped,
            done,
        } = self;
        let mut dataset = Dataset::new(info.name, info.clock);
        dataset.landmarks = info.landmarks;
        if !done {
            for event in events {
                dataset.events.push(event?);
            }
        }
        dataset.skipped = skipped.get();
        dataset.skipped_readings = skipped.readings();
        dataset.warnings = skipped.warnings();
        Ok(dataset)
    }
}

impl Iterator for EventStream {
    type Item = Result<TimedEvent>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let next = self.events.next();
        if !matches!(next, Some(Ok(_))) {
            self.done = true;
        }
        next
    }
}

impl std::fmt::Debug for EventStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EventStream")
            .field("info", &self.info)
            .field("skipped", &self.skipped.get())
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

/// A source of events that produces them in batches: each [`Step::step`] appends zero or
/// more events (e.g. those of one line of a file, or of one simulated time step).
pub(crate) trait Step {
    /// Appends the next events to `out`; `Ok(false)` when there are no more. Events appended
    /// before an `Err` are still yielded, before the error.
    fn step(&mut self, out: &mut std::collections::VecDeque<TimedEvent>) -> Result<bool>;
}

/// The events of a [`Step`] source, one at a time; the stream ends after an error.
pub(crate) struct Pump<S> {
    source: S,
    queue: std::collections::VecDeque<TimedEvent>,
    error: Option<crate::SensorError>,
    finished: bool,
}

impl<S: Step> Pump<S> {
    pub(crate) fn new(source: S) -> Self {
        Pump {
            source,
            queue: Default::default(),
            error: None,
            finished: false,
        }
    }
}

impl<S: Step> Iterator for Pump<S> {
    type Item = Result<TimedEvent>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(event) = self.queue.pop_front() {
                return Some(Ok(event));
            }
            if let Some(error) = self.error.take() {
                return Some(Err(error));
            }
            if self.finished {
                return None;
            }
            match self.source.step(&mut self.queue) {
                Ok(true) => {}
                Ok(false) => self.finished = true,
                Err(error) => {
                    self.finished = true;
                    self.error = Some(error);
                }
            }
        }
    }
}
