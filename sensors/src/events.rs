//! The common stream of timestamped events that every dataset reader and the simulator yield,
//! and that every estimator consumes.

use slam_core::nalgebra::Vector2;
use slam_core::{MotionModel, Observation, Pose2, Pose3};

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
    pub skipped: std::collections::BTreeMap<String, usize>,
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
