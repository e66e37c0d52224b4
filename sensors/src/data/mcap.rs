//! ROS 2 bags stored as MCAP: laser scans, odometry and reference poses, CDR-encoded.
//!
//! Topics read (names from [`McapOptions`]):
//!
//! - the scan topic (`sensor_msgs/msg/LaserScan`, default `/scan`): each message gives an
//!   [`Event::Scan`]. Beam `i` is at `angle_min + i * angle_increment` (a negative increment is
//!   turned around, with the beams in reverse order); a reading at or above `range_max` is "no
//!   return", as a max-range reading of a CARMEN log, and so is one at or below `range_min`;
//!   readings that are not finite or negative are counted in [`Dataset::skipped_readings`]
//!   (ROS writes `+inf` for no return, `-inf` for too close, `nan` for an error).
//! - the odometry topic (`nav_msgs/msg/Odometry`, default `/odom`): each message after the
//!   first gives an [`Event::Motion`], the [`PoseIncrement`] from the previous message's pose
//!   (as the `ODOM` lines of a CARMEN log).
//! - the reference topic (`geometry_msgs/msg/PoseStamped` or `nav_msgs/msg/Odometry`, none by
//!   default): each message gives an [`Event::GroundTruth`] of kind [`TruthKind::Reference`]
//!   (as the robot pose of a CARMEN laser line: another system's estimate, for the ATE).
//! - [`TF_STATIC_TOPIC`] (`tf2_msgs/msg/TFMessage`), when the bag has it: the laser's mount is
//!   the chain of static transforms from [`McapOptions::base_frame`] to the scan's
//!   `header.frame_id`, taken from the `/tf_static` messages before the frame's first scan.
//!   Without such a chain, the mount is [`McapOptions::laser_mount`], else the identity; a note
//!   of the run says which ([`EventStream::notes`]).
//!
//! Messages on other topics are counted in [`Dataset::skipped`] by topic. A configured topic
//! that the bag does not have, or has with another schema or an encoding other than `cdr`, is
//! an error naming the topic, what was found and the topics present (from the file's summary
//! section before any message is read; from the channels met while reading when the file has
//! no summary).
//!
//! **Order and times.** Events come in the order of the file (the recording order, in which
//! `ros2 bag play` replays), like the CARMEN reader's line order; their times are the messages'
//! header stamps, in seconds ([`Clock::Seconds`]), repaired where they go back exactly as the
//! CARMEN reader repairs logger timestamps (`data/stamps.rs`: odometry waits for the next
//! scan, which bounds its time; one stamped far out of order takes the time after it; a late
//! scan takes the time already reached), so that a bag made from a CARMEN log gives the same
//! events at the same times. A warning counts the repairs.
//!
//! **Streaming.** The file is read from start to end through a buffered reader
//! (`mcap::sans_io::LinearReader`, no memory map): at most one chunk is held in memory.
//! Chunks compressed with zstd (the default of the Python and C++ writers) or lz4 are
//! decompressed by pure-Rust decoders (ruzstd, lz4_flex).

use std::collections::{HashMap, VecDeque};
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::{Path, PathBuf};

use ::mcap::records::Record;
use ::mcap::sans_io::decompressor::{DecompressResult, Decompressor};
use ::mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use ::mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use ::mcap::{McapError, McapResult};
use slam_core::nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use slam_core::{Pose2, Pose3};

use super::cdr;
use super::stamps::Times;
use crate::error::{Result, SensorError};
use crate::events::{
    Clock, Dataset, DatasetInfo, Event, EventStream, Pump, SkipCounter, Step, TimedEvent, TruthKind,
};
use crate::odometry::{OdometryNoise, PoseIncrement};
use crate::scan::LaserScan;

/// The topic of the static transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";

/// The largest record (and decompressed chunk) the reader takes, bytes: a larger one is an
/// error rather than an allocation.
pub const MAX_RECORD_BYTES: usize = 1 << 30;

const LASER_SCAN: &str = "sensor_msgs/msg/LaserScan";
const ODOMETRY: &str = "nav_msgs/msg/Odometry";
const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";
const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";

/// How to read a ROS 2 bag.
#[derive(Clone, Debug, PartialEq)]
pub struct McapOptions {
    /// The `sensor_msgs/msg/LaserScan` topic (required). Default `/scan`.
    pub scan_topic: String,
    /// The `nav_msgs/msg/Odometry` topic; empty: none. Default `/odom`.
    pub odom_topic: String,
    /// The topic of reference poses (`geometry_msgs/msg/PoseStamped` or
    /// `nav_msgs/msg/Odometry`); empty (the default): none.
    pub reference_topic: String,
    /// The robot's frame, the root of the laser's transform chain. Default `base_link`.
    pub base_frame: String,
    /// The laser's mount when `/tf_static` does not give it; `None`: the identity.
    pub laser_mount: Option<Pose3>,
    /// Noise of the odometry pose increments.
    pub odometry_noise: OdometryNoise,
}

impl Default for McapOptions {
    fn default() -> Self {
        McapOptions {
            scan_topic: "/scan".into(),
            odom_topic: "/odom".into(),
            reference_topic: String::new(),
            base_frame: "base_link".into(),
            laser_mount: None,
            odometry_noise: OdometryNoise::default(),
        }
    }
}

/// What the messages of a channel are read as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Scan,
    Odometry,
    /// Reference poses, from an Odometry (`true`) or a PoseStamped message.
    Reference {
        odometry: bool,
    },
    TfStatic,
}

/// A channel's topic, schema and encoding, for the checks and error messages.
#[derive(Clone, Debug)]
struct ChannelInfo {
    topic: String,
    schema: String,
    encoding: String,
}

impl ChannelInfo {
    fn describe(&self) -> String {
        let schema = if self.schema.is_empty() {
            "no schema"
        } else {
            &self.schema
        };
        format!("{} ({schema}, {})", self.topic, self.encoding)
    }
}

/// The configured topics, each with the option that names it and the schemas it takes.
struct Topics {
    wanted: Vec<(String, &'static str, &'static [&'static str])>,
}

impl Topics {
    fn new(options: &McapOptions) -> Self {
        let mut wanted = vec![(options.scan_topic.clone(), "scan_topic", &[LASER_SCAN][..])];
        if !options.odom_topic.is_empty() {
            wanted.push((options.odom_topic.clone(), "odom_topic", &[ODOMETRY][..]));
        }
        if !options.reference_topic.is_empty() {
            wanted.push((
                options.reference_topic.clone(),
                "reference_topic",
                &[POSE_STAMPED, ODOMETRY][..],
            ));
        }
        Topics { wanted }
    }

    /// The role of a channel, or an error when a configured topic (or `/tf_static`) has the
    /// wrong schema or encoding; `None` for a topic not read.
    fn role(
        &self,
        channel: &ChannelInfo,
        present: &str,
    ) -> std::result::Result<Option<Role>, String> {
        let (option, schemas): (&str, &[&str]) = match self
            .wanted
            .iter()
            .find(|(topic, _, _)| *topic == channel.topic)
        {
            Some((_, option, schemas)) => (option, schemas),
            None if channel.topic == TF_STATIC_TOPIC => ("the static transforms", &[TF_MESSAGE]),
            None => return Ok(None),
        };
        if !schemas.contains(&channel.schema.as_str()) || channel.encoding != "cdr" {
            return Err(format!(
                "topic {} ({option}) is {}, expected {} in cdr; the topics are {present}",
                channel.topic,
                channel.describe(),
                schemas.join(" or ")
            ));
        }
        Ok(Some(match channel.schema.as_str() {
            LASER_SCAN => Role::Scan,
            TF_MESSAGE => Role::TfStatic,
            ODOMETRY if option == "odom_topic" => Role::Odometry,
            schema => Role::Reference {
                odometry: schema == ODOMETRY,
            },
        }))
    }

    /// An error for each configured topic not among `channels`.
    fn check_present(
        &self,
        channels: &[ChannelInfo],
        present: &str,
    ) -> std::result::Result<(), String> {
        for (topic, option, schemas) in &self.wanted {
            if !channels.iter().any(|c| c.topic == *topic) {
                return Err(format!(
                    "no topic {topic} ({option}, {}); the topics are {present}",
                    schemas.join(" or ")
                ));
            }
        }
        Ok(())
    }
}

/// `a (schema, encoding), b (...)`, or `none`.
fn describe_all(channels: &[ChannelInfo]) -> String {
    let mut all: Vec<String> = channels.iter().map(ChannelInfo::describe).collect();
    all.sort();
    all.dedup();
    if all.is_empty() {
        "none".into()
    } else {
        all.join(", ")
    }
}

/// Reads a ROS 2 bag (MCAP): the events of [`stream_mcap`], collected.
pub fn read_mcap(path: &Path, options: &McapOptions) -> Result<Dataset> {
    stream_mcap(path, options)?.into_dataset()
}

/// Reads a ROS 2 bag (MCAP) one record at a time (see the [module](self) documentation).
///
/// Bad options, a missing or unreadable file, and (when the file has a summary section) a
/// missing topic or one with the wrong schema are errors of this call; a malformed message is
/// an `Err` item when the stream reaches it, naming the file, the message's topic and its
/// number in the file.
pub fn stream_mcap(path: &Path, options: &McapOptions) -> Result<EventStream> {
    check_options(options)?;
    let input = |message: String| SensorError::Input(format!("{}: {message}", path.display()));
    let topics = Topics::new(options);
    let skipped = SkipCounter::default();
    let summary = read_summary(path)?;
    if let Some(channels) = &summary {
        let present = describe_all(channels);
        topics.check_present(channels, &present).map_err(input)?;
        for channel in channels {
            topics.role(channel, &present).map_err(input)?;
        }
    } else {
        skipped.note(format!(
            "{}: no summary section (an unfinished recording?): topics are checked as they \
             come",
            path.display()
        ));
    }
    let file = File::open(path).map_err(|e| SensorError::io(path, e))?;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default().with_record_length_limit(MAX_RECORD_BYTES),
    );
    for name in ["zstd", "lz4"] {
        reader
            .add_decompressor(WholeChunk::new(name))
            .map_err(|e| input(e.to_string()))?;
    }
    let name = path
        .file_name()
        .unwrap_or(path.as_os_str())
        .to_string_lossy()
        .into_owned();
    let info = DatasetInfo {
        name,
        clock: Clock::Seconds,
        landmarks: Vec::new(),
        gps_antenna: slam_core::nalgebra::Vector2::zeros(),
    };
    let state = McapReader {
        path: path.to_path_buf(),
        file: BufReader::with_capacity(1 << 16, file),
        reader,
        options: options.clone(),
        topics,
        schemas: HashMap::new(),
        channels: HashMap::new(),
        seen: Vec::new(),
        messages: 0,
        records: 0,
        transforms: HashMap::new(),
        mounts: HashMap::new(),
        previous_odometry: None,
        times: Times::default(),
        skipped: skipped.clone(),
        number: String::new(),
    };
    Ok(EventStream::new(info, Pump::new(state)).with_skipped(skipped))
}

fn check_options(options: &McapOptions) -> Result<()> {
    if options.scan_topic.is_empty() {
        return Err(SensorError::InvalidArgument(
            "MCAP: scan_topic must name a topic".into(),
        ));
    }
    if let Some(mount) = &options.laser_mount
        && !mount.is_finite()
    {
        return Err(SensorError::InvalidArgument(format!(
            "MCAP: laser_mount must be finite, got {mount:?}"
        )));
    }
    Ok(())
}

/// The channels listed in the file's summary section, or `None` when it has none.
fn read_summary(path: &Path) -> Result<Option<Vec<ChannelInfo>>> {
    let io = |e| SensorError::io(path, e);
    let mut file = File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    let mut reader = SummaryReader::new_with_options(
        SummaryReaderOptions::default()
            .with_file_size(size)
            .with_record_length_limit(MAX_RECORD_BYTES),
    );
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(event) => event,
            // No footer, or one that points nowhere: read the file from its start instead.
            Err(_) => return Ok(None),
        };
        match event {
            SummaryReadEvent::ReadRequest(need) => {
                let read = file.read(reader.insert(need)).map_err(io)?;
                reader.notify_read(read);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let at = file.seek(to).map_err(io)?;
                reader.notify_seeked(at);
            }
        }
    }
    let Some(summary) = reader.finish() else {
        return Ok(None);
    };
    if summary.channels.is_empty() {
        // A summary without channel records says nothing about the topics.
        return Ok(None);
    }
    let mut channels: Vec<ChannelInfo> = summary
        .channels
        .values()
        .map(|c| ChannelInfo {
            topic: c.topic.clone(),
            schema: c.schema.as_ref().map_or(String::new(), |s| s.name.clone()),
            encoding: c.message_encoding.clone(),
        })
        .collect();
    channels.sort_by(|a, b| a.topic.cmp(&b.topic));
    Ok(Some(channels))
}

/// The state of a [`stream_mcap`] stream.
struct McapReader {
    path: PathBuf,
    file: BufReader<File>,
    reader: LinearReader,
    options: McapOptions,
    topics: Topics,
    /// Schema names by id.
    schemas: HashMap<u16, String>,
    /// Each channel's role (`None`: not read) and description.
    channels: HashMap<u16, (Option<Role>, ChannelInfo)>,
    /// The channels met, for the error of a missing topic.
    seen: Vec<ChannelInfo>,
    /// Message records read.
    messages: u64,
    /// Messages on the scan and odometry topics.
    records: u64,
    /// Static transforms: child frame -> (parent frame, parent_from_child).
    transforms: HashMap<String, (String, Isometry3<f64>)>,
    /// The laser mount of each scan frame, once decided.
    mounts: HashMap<String, Pose3>,
    previous_odometry: Option<Pose2>,
    /// Header stamps into event times that never go back.
    times: Times,
    skipped: SkipCounter,
    /// A buffer for widening `float32` values.
    number: String,
}

impl Step for McapReader {
    fn step(&mut self, out: &mut VecDeque<TimedEvent>) -> Result<bool> {
        loop {
            let event = match self.reader.next_event() {
                None => {
                    self.times.flush(f64::INFINITY, out);
                    return self.end().map(|()| false);
                }
                Some(Err(e)) => {
                    // The events of the messages before the error come first.
                    self.times.flush(f64::INFINITY, out);
                    return Err(self.container_error(e));
                }
                Some(Ok(event)) => event,
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    let read = self
                        .file
                        .read(self.reader.insert(need))
                        .map_err(|e| SensorError::io(&self.path, e))?;
                    self.reader.notify_read(read);
                }
                LinearReadEvent::Record { data, opcode } => {
                    let record = ::mcap::parse_record(opcode, data)
                        .map_err(|e| SensorError::Input(format!("{}: {e}", self.path.display())))?;
                    // The record borrows the reader's buffer: take what is needed out of it.
                    let message = match record {
                        Record::Schema { header, .. } => {
                            self.schemas.insert(header.id, header.name);
                            None
                        }
                        Record::Channel(channel) => {
                            self.channel(channel)?;
                            None
                        }
                        Record::Message { header, data } => {
                            Some((header.channel_id, data.into_owned()))
                        }
                        _ => None,
                    };
                    if let Some((channel_id, data)) = message {
                        if let Err(error) = self.message(channel_id, &data, out) {
                            self.times.flush(f64::INFINITY, out);
                            return Err(error);
                        }
                        if !out.is_empty() {
                            return Ok(true);
                        }
                    }
                }
            }
        }
    }
}

impl McapReader {
    fn input(&self, message: impl std::fmt::Display) -> SensorError {
        SensorError::Input(format!("{}: {message}", self.path.display()))
    }

    fn container_error(&self, error: McapError) -> SensorError {
        let hint = match &error {
            McapError::UnexpectedEof => {
                " (the file ends inside a record: an unfinished recording?)"
            }
            McapError::BadMagic => " (is it an MCAP file? a ROS 2 bag folder holds one as *.mcap)",
            McapError::UnsupportedCompression(_) => " (zstd and lz4 chunks are read)",
            _ => "",
        };
        self.input(format!("{error}{hint}"))
    }

    fn channel(&mut self, channel: ::mcap::records::Channel) -> Result<()> {
        let schema = match channel.schema_id {
            0 => String::new(),
            id => self.schemas.get(&id).cloned().ok_or_else(|| {
                self.input(format!(
                    "channel {} ({}) refers to schema {id}, which no record before it defines",
                    channel.id, channel.topic
                ))
            })?,
        };
        let info = ChannelInfo {
            topic: channel.topic,
            schema,
            encoding: channel.message_encoding,
        };
        self.seen.push(info.clone());
        let present = describe_all(&self.seen);
        let role = self
            .topics
            .role(&info, &present)
            .map_err(|e| self.input(e))?;
        self.channels.insert(channel.id, (role, info));
        Ok(())
    }

    fn message(
        &mut self,
        channel_id: u16,
        data: &[u8],
        out: &mut VecDeque<TimedEvent>,
    ) -> Result<()> {
        self.messages += 1;
        let Some((role, info)) = self.channels.get(&channel_id) else {
            return Err(self.input(format!(
                "message {} is on channel {channel_id}, which no record before it defines",
                self.messages
            )));
        };
        let Some(role) = *role else {
            let topic = info.topic.clone();
            self.skipped.count(&topic);
            return Ok(());
        };
        let context = format!(
            "{}: message {} on {}",
            self.path.display(),
            self.messages,
            info.topic
        );
        let at = |e: String| SensorError::Input(format!("{context}: {e}"));
        match role {
            Role::TfStatic => {
                for t in cdr::tf_message(data).map_err(at)? {
                    let iso = isometry(&t.parent_from_child).map_err(at)?;
                    self.transforms.insert(t.child, (t.parent, iso));
                }
            }
            Role::Scan => {
                let msg = cdr::laser_scan(data).map_err(at)?;
                self.records += 1;
                let mount = self.mount(&msg.header.frame_id);
                let scan = self.scan(&msg).map_err(at)?;
                let stamp = finite_stamp(msg.header.stamp).map_err(at)?;
                let time = self.times.scan(stamp, out);
                out.push_back(TimedEvent {
                    time,
                    event: Event::Scan {
                        scan,
                        robot_from_sensor: mount,
                    },
                });
            }
            Role::Odometry => {
                let msg = cdr::odometry(data).map_err(at)?;
                self.records += 1;
                let pose = pose2(&msg.pose).map_err(at)?;
                let stamp = finite_stamp(msg.header.stamp).map_err(at)?;
                let event = match self.previous_odometry {
                    Some(previous) => Some(Event::Motion(Box::new(
                        PoseIncrement::between(&previous, &pose, &self.options.odometry_noise)
                            .map_err(|e| at(super::reason(&e)))?,
                    ))),
                    None => None,
                };
                self.previous_odometry = Some(pose);
                self.times.odometry(stamp, event, out);
            }
            Role::Reference { odometry } => {
                let msg = if odometry {
                    cdr::odometry(data)
                } else {
                    cdr::pose_stamped(data)
                }
                .map_err(at)?;
                let pose = pose2(&msg.pose).map_err(at)?;
                let time = self
                    .times
                    .other(finite_stamp(msg.header.stamp).map_err(at)?);
                out.push_back(TimedEvent {
                    time,
                    event: Event::GroundTruth {
                        pose,
                        kind: TruthKind::Reference,
                    },
                });
            }
        }
        Ok(())
    }

    /// The laser mount of scans in `frame`, decided at its first scan (with a note saying
    /// where it comes from).
    fn mount(&mut self, frame: &str) -> Pose3 {
        if let Some(mount) = self.mounts.get(frame) {
            return *mount;
        }
        let base = &self.options.base_frame;
        let (mount, source) = match self.chain(frame) {
            Some(iso) => {
                let (roll, pitch, yaw) = iso.rotation.euler_angles();
                let t = iso.translation.vector;
                (
                    Pose3::new(t, yaw, pitch, roll),
                    format!(
                        "from {TF_STATIC_TOPIC} ({base} -> {frame}: x {:.4}, y {:.4}, z {:.4} m, \
                         yaw {yaw:.4} rad)",
                        t.x, t.y, t.z
                    ),
                )
            }
            None => {
                let missing = if frame == base || frame.is_empty() {
                    String::new()
                } else {
                    format!("no {TF_STATIC_TOPIC} transform chain from {base} to {frame}: ")
                };
                match self.options.laser_mount {
                    Some(mount) => (mount, format!("{missing}from the config (laser_mount)")),
                    None => (Pose3::identity(), format!("{missing}the identity")),
                }
            }
        };
        self.skipped.note(format!(
            "{}: laser mount of frame `{frame}` {source}",
            self.path.display()
        ));
        self.mounts.insert(frame.to_string(), mount);
        mount
    }

    /// `base_from_frame` from the static transforms, when they chain from the base frame to
    /// `frame` (the identity when `frame` is the base frame itself).
    fn chain(&self, frame: &str) -> Option<Isometry3<f64>> {
        let base = self.options.base_frame.as_str();
        let mut pose = Isometry3::identity();
        let mut current = frame;
        for _ in 0..64 {
            if current == base {
                return (frame != base).then_some(pose);
            }
            let (parent, parent_from_current) = self.transforms.get(current)?;
            pose = parent_from_current * pose;
            current = parent;
        }
        None
    }

    fn scan(&mut self, msg: &cdr::LaserScanMsg) -> std::result::Result<LaserScan, String> {
        if msg.ranges.is_empty() {
            return Err("a scan needs at least one reading".into());
        }
        let mut ranges = Vec::with_capacity(msg.ranges.len());
        for &r in &msg.ranges {
            if !r.is_finite() {
                self.skipped
                    .count_reading("MCAP laser: reading not finite (no return)");
            } else if r < 0.0 {
                self.skipped
                    .count_reading("MCAP laser: negative reading (no return)");
            }
            ranges.push(widen(r, &mut self.number));
        }
        let mut angle_min = widen(msg.angle_min, &mut self.number);
        let mut increment = widen(msg.angle_increment, &mut self.number);
        if increment < 0.0 {
            angle_min += increment * (ranges.len() - 1) as f64;
            increment = -increment;
            ranges.reverse();
        }
        let min_range = widen(msg.range_min, &mut self.number);
        let max_range = widen(msg.range_max, &mut self.number);
        LaserScan::with_increment(angle_min, increment, ranges, min_range, max_range).map_err(|e| {
            format!(
                "{} (angle_max {})",
                super::reason(&e),
                widen(msg.angle_max, &mut String::new())
            )
        })
    }

    /// At the end of the file: a configured topic that never came, or a file without scans
    /// or odometry, is an error; stamps that went back are a warning.
    fn end(&mut self) -> Result<()> {
        let present = describe_all(&self.seen);
        self.topics
            .check_present(&self.seen, &present)
            .map_err(|e| self.input(e))?;
        if let Some(repairs) = self.times.repairs() {
            self.skipped
                .warn(format!("{}: header {repairs}", self.path.display()));
        }
        if self.records == 0 {
            return Err(self.input(format!(
                "no message on {} or {}; the topics are {present}",
                self.options.scan_topic,
                if self.options.odom_topic.is_empty() {
                    "an odometry topic"
                } else {
                    &self.options.odom_topic
                }
            )));
        }
        Ok(())
    }
}

/// A `float32` as the `float64` of its shortest decimal form (`0.1f32` becomes `0.1`, not
/// `0.10000000149`): the value a person reading the bag sees, and the one a text log of the
/// same data (e.g. a CARMEN log converted to a bag) holds.
/// A header stamp, checked finite.
fn finite_stamp(stamp: f64) -> std::result::Result<f64, String> {
    if stamp.is_finite() {
        Ok(stamp)
    } else {
        Err(format!("header stamp {stamp} is not finite"))
    }
}

fn widen(value: f32, buffer: &mut String) -> f64 {
    use std::fmt::Write as _;
    if !value.is_finite() {
        return f64::from(value);
    }
    buffer.clear();
    // Writing to a String cannot fail, and the shortest form of a finite f32 parses.
    let _ = write!(buffer, "{value}");
    buffer.parse().unwrap_or(f64::from(value))
}

fn check_finite(values: &[f64], what: &str) -> std::result::Result<(), String> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(format!("{what} is not finite: {values:?}"))
    }
}

/// The planar pose of a ROS pose (its x, y and heading).
fn pose2(pose: &cdr::PoseMsg) -> std::result::Result<Pose2, String> {
    check_finite(&pose.position, "position")?;
    check_finite(&pose.orientation, "orientation")?;
    Ok(Pose2::new(pose.position[0], pose.position[1], pose.yaw()))
}

/// A transform as an isometry; the quaternion is normalised (a zero one is an error).
fn isometry(pose: &cdr::PoseMsg) -> std::result::Result<Isometry3<f64>, String> {
    check_finite(&pose.position, "translation")?;
    check_finite(&pose.orientation, "rotation")?;
    let [x, y, z, w] = pose.orientation;
    let q = Quaternion::new(w, x, y, z);
    if q.norm() < 1e-9 {
        return Err("rotation is a zero quaternion".into());
    }
    let [tx, ty, tz] = pose.position;
    Ok(Isometry3::from_parts(
        Translation3::from(Vector3::new(tx, ty, tz)),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// A chunk decompressor that takes a whole compressed chunk at once and hands out its
/// decompressed bytes: the reader buffers the chunk's compressed bytes first (its read hint is
/// "everything"), so one chunk at a time is in memory.
struct WholeChunk {
    name: &'static str,
    output: Vec<u8>,
    handed: usize,
    decoded: bool,
}

impl WholeChunk {
    fn new(name: &'static str) -> Self {
        WholeChunk {
            name,
            output: Vec::new(),
            handed: 0,
            decoded: false,
        }
    }

    fn decode(&mut self, src: &[u8]) -> std::result::Result<(), String> {
        let limit = MAX_RECORD_BYTES as u64 + 1;
        let mut rest = src;
        while !rest.is_empty() {
            if self.name == "zstd" && is_skippable_frame(rest) {
                let len = u32::from_le_bytes([rest[4], rest[5], rest[6], rest[7]]) as usize;
                rest = rest
                    .get(8 + len..)
                    .ok_or("a skippable zstd frame runs past the chunk")?;
                continue;
            }
            let before = rest.len();
            let budget = limit - self.output.len() as u64;
            let read = if self.name == "zstd" {
                let decoder = ruzstd::decoding::StreamingDecoder::new(&mut rest)
                    .map_err(|e| format!("zstd: {e}"))?;
                decoder.take(budget).read_to_end(&mut self.output)
            } else {
                let decoder = lz4_flex::frame::FrameDecoder::new(&mut rest);
                decoder.take(budget).read_to_end(&mut self.output)
            };
            read.map_err(|e| format!("{}: {e}", self.name))?;
            if self.output.len() > MAX_RECORD_BYTES {
                return Err(format!(
                    "a chunk decompresses to more than {MAX_RECORD_BYTES} bytes"
                ));
            }
            if rest.len() == before {
                return Err(format!("{}: no progress decoding the chunk", self.name));
            }
        }
        Ok(())
    }
}

fn is_skippable_frame(bytes: &[u8]) -> bool {
    bytes.len() >= 8
        && u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) & 0xFFFF_FFF0 == 0x184D_2A50
}

impl Decompressor for WholeChunk {
    fn next_read_size(&self) -> usize {
        if self.decoded { 0 } else { usize::MAX }
    }

    fn decompress(&mut self, src: &[u8], dst: &mut [u8]) -> McapResult<DecompressResult> {
        let mut consumed = 0;
        if !self.decoded {
            self.decode(src).map_err(McapError::DecompressionError)?;
            self.decoded = true;
            consumed = src.len();
        }
        let left = &self.output[self.handed..];
        let wrote = left.len().min(dst.len());
        dst[..wrote].copy_from_slice(&left[..wrote]);
        self.handed += wrote;
        Ok(DecompressResult { consumed, wrote })
    }

    fn reset(&mut self) -> McapResult<()> {
        self.output.clear();
        self.handed = 0;
        self.decoded = false;
        Ok(())
    }

    fn name(&self) -> &'static str {
        self.name
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::cdr::build;

    /// A minimal MCAP writer (uncompressed, no chunks, with or without a summary), enough to
    /// test the reader's handling of topics and messages; the interop tests read files written
    /// by the standard Python writer.
    struct Bag {
        bytes: Vec<u8>,
        channels: Vec<(u16, u16, String)>,
        schemas: Vec<(u16, String)>,
    }

    impl Bag {
        fn new() -> Self {
            let mut bag = Bag {
                bytes: b"\x89MCAP0\r\n".to_vec(),
                channels: Vec::new(),
                schemas: Vec::new(),
            };
            let mut header = Vec::new();
            string(&mut header, "ros2");
            string(&mut header, "test");
            bag.record(0x01, &header);
            bag
        }
        fn record(&mut self, op: u8, body: &[u8]) {
            self.bytes.push(op);
            self.bytes
                .extend_from_slice(&(body.len() as u64).to_le_bytes());
            self.bytes.extend_from_slice(body);
        }
        fn schema_record(id: u16, name: &str) -> Vec<u8> {
            let mut body = id.to_le_bytes().to_vec();
            string(&mut body, name);
            string(&mut body, "ros2msg");
            body.extend_from_slice(&0u32.to_le_bytes());
            body
        }
        fn channel_record(id: u16, schema: u16, topic: &str) -> Vec<u8> {
            let mut body = id.to_le_bytes().to_vec();
            body.extend_from_slice(&schema.to_le_bytes());
            string(&mut body, topic);
            string(&mut body, "cdr");
            body.extend_from_slice(&0u32.to_le_bytes());
            body
        }
        fn channel(&mut self, id: u16, topic: &str, schema: &str) {
            let schema_id = id + 100;
            self.record(0x03, &Self::schema_record(schema_id, schema));
            self.record(0x04, &Self::channel_record(id, schema_id, topic));
            self.schemas.push((schema_id, schema.into()));
            self.channels.push((id, schema_id, topic.into()));
        }
        fn message(&mut self, channel: u16, time: u64, data: &[u8]) {
            let mut body = channel.to_le_bytes().to_vec();
            body.extend_from_slice(&0u32.to_le_bytes());
            body.extend_from_slice(&time.to_le_bytes());
            body.extend_from_slice(&time.to_le_bytes());
            body.extend_from_slice(data);
            self.record(0x05, &body);
        }
        /// Data end, an optional summary of schemas and channels, footer, magic.
        fn finish(mut self, summary: bool) -> Vec<u8> {
            self.record(0x0F, &0u32.to_le_bytes());
            let summary_start = if summary {
                let start = self.bytes.len() as u64;
                for (id, name) in self.schemas.clone() {
                    self.record(0x03, &Self::schema_record(id, &name));
                }
                for (id, schema, topic) in self.channels.clone() {
                    self.record(0x04, &Self::channel_record(id, schema, &topic));
                }
                start
            } else {
                0
            };
            let mut footer = summary_start.to_le_bytes().to_vec();
            footer.extend_from_slice(&0u64.to_le_bytes());
            footer.extend_from_slice(&0u32.to_le_bytes());
            self.record(0x02, &footer);
            self.bytes.extend_from_slice(b"\x89MCAP0\r\n");
            self.bytes
        }
    }

    fn string(out: &mut Vec<u8>, s: &str) {
        out.extend_from_slice(&(s.len() as u32).to_le_bytes());
        out.extend_from_slice(s.as_bytes());
    }

    fn sample(summary: bool, tf: bool) -> Vec<u8> {
        let mut bag = Bag::new();
        bag.channel(1, "/scan", LASER_SCAN);
        bag.channel(2, "/odom", ODOMETRY);
        bag.channel(3, "/truth", POSE_STAMPED);
        bag.channel(4, "/imu", "sensor_msgs/msg/Imu");
        if tf {
            bag.channel(5, TF_STATIC_TOPIC, TF_MESSAGE);
            let tf = build::tf_message(&[
                ("base_link", "mount", [0.5, 0.0, 0.3], 0.0),
                (
                    "mount",
                    "laser",
                    [0.0, 0.25, 0.0],
                    std::f64::consts::FRAC_PI_2,
                ),
            ]);
            bag.message(5, 0, &tf);
        }
        bag.message(2, 1, &build::odometry(true, (1, 0), [0.0, 0.0, 0.0]));
        bag.message(4, 1, &[0, 1, 0, 0]);
        let ranges = [1.0, 30.0, f32::NAN, 0.3, -1.0];
        bag.message(
            1,
            2,
            &build::laser_scan(
                false,
                (1, 500_000_000),
                "laser",
                [0.5, -0.5, -0.25],
                [0.2, 30.0],
                &ranges,
            ),
        );
        bag.message(
            3,
            2,
            &build::pose_stamped(true, (1, 500_000_000), [1.0, 2.0, 0.5]),
        );
        // Odometry stamped a little before the scan before it: its motion takes the time
        // already reached (the CARMEN reader's repair of logger timestamps).
        bag.message(
            2,
            3,
            &build::odometry(false, (1, 250_000_000), [1.0, 0.0, 0.1]),
        );
        bag.finish(summary)
    }

    fn write(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
        let dir = super::super::test_dir(&format!("mcap-{name}"));
        let path = dir.path().join(format!("{name}.mcap"));
        std::fs::write(&path, bytes).unwrap();
        (dir, path)
    }

    fn options() -> McapOptions {
        McapOptions {
            reference_topic: "/truth".into(),
            ..McapOptions::default()
        }
    }

    #[test]
    fn a_bag_gives_the_events_of_a_carmen_log() {
        for summary in [true, false] {
            let (_dir, path) = write("events", &sample(summary, true));
            let data = read_mcap(&path, &options()).unwrap();
            assert_eq!(data.clock, Clock::Seconds);
            let kinds: Vec<(f64, &str)> = data
                .events
                .iter()
                .map(|e| {
                    let kind = match e.event {
                        Event::Scan { .. } => "scan",
                        Event::Motion(_) => "motion",
                        Event::GroundTruth { .. } => "reference",
                        _ => "other",
                    };
                    (e.time, kind)
                })
                .collect();
            assert_eq!(kinds, [(1.5, "scan"), (1.5, "reference"), (1.5, "motion")]);
            let Event::Scan {
                scan,
                robot_from_sensor,
            } = &data.events[0].event
            else {
                panic!()
            };
            // The negative increment is turned around: beams from -0.5 up, readings reversed.
            assert_eq!((scan.angle_min, scan.angle_increment), (-0.5, 0.25));
            assert_eq!(scan.ranges[..2], [-1.0, 0.3]);
            assert!(scan.ranges[2].is_nan());
            assert_eq!(scan.ranges[3..], [30.0, 1.0]);
            // 30 is range_max (no return), -1 and nan are skipped readings, 0.3 is valid.
            assert_eq!(scan.points().len(), 2);
            assert_eq!(data.skipped_readings.values().sum::<usize>(), 2);
            // The mount: base_link -> mount -> laser.
            let t = robot_from_sensor.translation;
            assert!((t - Vector3::new(0.5, 0.25, 0.3)).norm() < 1e-12, "{t}");
            assert!((robot_from_sensor.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
            let Event::GroundTruth { pose, kind } = &data.events[1].event else {
                panic!()
            };
            assert_eq!(*kind, TruthKind::Reference);
            assert!((pose.x - 1.0).abs() + (pose.y - 2.0).abs() + (pose.theta - 0.5).abs() < 1e-12);
            let Event::Motion(motion) = &data.events[2].event else {
                panic!()
            };
            let moved = motion.predict(&Pose2::identity()).unwrap().pose;
            assert!(
                (moved.x - 1.0).abs() + (moved.theta - 0.1).abs() < 1e-12,
                "{moved:?}"
            );
            assert_eq!(data.skipped["/imu"], 1);
            assert!(
                data.warnings.iter().any(|w| w.contains(
                    "timestamps repaired: 1 odometry records stamped out of order with their \
                     neighbours took a neighbour's time"
                )),
                "{:?}",
                data.warnings
            );
        }
    }

    #[test]
    fn the_mount_falls_back_to_the_config_then_the_identity() {
        let (_dir, path) = write("mount", &sample(true, false));
        let stream = stream_mcap(&path, &options()).unwrap();
        let counter = stream.skip_counter();
        let data = stream.into_dataset().unwrap();
        let Event::Scan {
            robot_from_sensor, ..
        } = &data.events[0].event
        else {
            panic!()
        };
        assert_eq!(*robot_from_sensor, Pose3::identity());
        let notes = counter.notes();
        assert!(
            notes[0]
                .contains("no /tf_static transform chain from base_link to laser: the identity"),
            "{notes:?}"
        );
        let mount = Pose3::new(Vector3::new(0.1, 0.0, 0.0), 0.2, 0.0, 0.0);
        let configured = McapOptions {
            laser_mount: Some(mount),
            ..options()
        };
        let data = read_mcap(&path, &configured).unwrap();
        let Event::Scan {
            robot_from_sensor, ..
        } = &data.events[0].event
        else {
            panic!()
        };
        assert_eq!(*robot_from_sensor, mount);
    }

    #[test]
    fn missing_topics_and_wrong_schemas_name_the_topic_and_what_is_there() {
        for summary in [true, false] {
            let (_dir, path) = write("topics", &sample(summary, true));
            let odom_as_scan = McapOptions {
                scan_topic: "/odom".into(),
                odom_topic: String::new(),
                ..McapOptions::default()
            };
            let e = read_mcap(&path, &odom_as_scan).unwrap_err().to_string();
            assert!(
                e.contains("topic /odom (scan_topic) is /odom (nav_msgs/msg/Odometry, cdr), expected sensor_msgs/msg/LaserScan in cdr; the topics are "),
                "{e}"
            );
            let absent = McapOptions {
                reference_topic: "/ground_truth".into(),
                ..McapOptions::default()
            };
            let e = read_mcap(&path, &absent).unwrap_err().to_string();
            assert!(e.contains("no topic /ground_truth (reference_topic, geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry); the topics are "), "{e}");
            assert!(e.contains("/imu (sensor_msgs/msg/Imu, cdr)"), "{e}");
            if summary {
                // Known before any message is read.
                assert!(stream_mcap(&path, &absent).is_err());
            }
        }
    }

    #[test]
    fn broken_messages_and_files_are_errors_naming_the_file() {
        let mut bag = Bag::new();
        bag.channel(1, "/scan", LASER_SCAN);
        bag.channel(2, "/odom", ODOMETRY);
        let scan = build::laser_scan(
            true,
            (1, 0),
            "laser",
            [0.0, 1.0, 0.5],
            [0.0, 5.0],
            &[1.0; 3],
        );
        bag.message(2, 1, &build::odometry(true, (1, 0), [0.0; 3]));
        bag.message(1, 2, &scan[..scan.len() - 9]);
        let (_dir, path) = write("broken", &bag.finish(true));
        let mut stream = stream_mcap(&path, &McapOptions::default()).unwrap();
        let e = stream.next().unwrap().unwrap_err().to_string();
        assert!(
            e.contains("broken.mcap: message 2 on /scan: truncated: ranges"),
            "{e}"
        );
        // A file cut in the middle: the messages before the cut, then an error.
        let whole = sample(true, false);
        let (_dir, path) = write("cut", &whole[..whole.len() * 3 / 4]);
        let result = read_mcap(&path, &options());
        let e = result.unwrap_err().to_string();
        assert!(
            e.contains("cut.mcap") && e.contains("unfinished recording"),
            "{e}"
        );
        let (_dir, path) = write("text", b"ODOM 0 0 0 0 0 0 1 h 1\n");
        let e = read_mcap(&path, &options()).unwrap_err().to_string();
        assert!(
            e.contains("text.mcap") && e.contains("is it an MCAP file?"),
            "{e}"
        );
    }

    #[test]
    fn float32_values_widen_to_their_shortest_decimal() {
        let mut buffer = String::new();
        assert_eq!(widen(0.1, &mut buffer), 0.1);
        assert_eq!(widen(81.83, &mut buffer), 81.83);
        assert_eq!(widen(-1.570_796_4, &mut buffer), -1.570_796_4);
        assert_eq!(widen(f32::INFINITY, &mut buffer), f64::INFINITY);
        assert!(widen(f32::NAN, &mut buffer).is_nan());
    }
}
