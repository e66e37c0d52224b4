//! The replay log of `slam run --mcap` (`[output] mcap = true`): `run.mcap`, written as the run
//! goes, with Foxglove's schemas in JSON encoding, so that Foxglove (or any MCAP reader)
//! replays the run step by step.
//!
//! | topic | schema | when |
//! |---|---|---|
//! | `/tf` | `foxglove.FrameTransform` `map` → `base_link` | each time step's end |
//! | `/pose` | `foxglove.PoseInFrame` (frame `map`) | each time step's end |
//! | `/pose_covariance` | `foxglove.SceneUpdate`: the 95 % ellipse of x, y as a line strip | each time step's end |
//! | `/scan` | `foxglove.LaserScan` (frame `base_link`, the laser's mounting as its pose) | each scan |
//! | `/map` | `foxglove.SceneUpdate`: one entity per confirmed feature (`feature-<id>`): walls and lines as line lists, points and poles as spheres with their 95 % position ellipse as a line strip | every `mcap_map_interval_s` of data time and at the end, holding the features drawn 5 mm or more away from where they were last sent, and deletions of those gone |
//!
//! Message times are the data's times in nanoseconds (a negative time is written as 0); a
//! scan reading that is not finite is written as 0 (JSON has no infinity); positions and
//! ranges are rounded to 0.1 mm. The
//! writer keeps one chunk (about 1 MiB) in memory; the chunks are not compressed (no C
//! compression library is linked).
//!
//! [`McapLog`] is an [`Observer`]: a program with its own session loop writes the same file by
//! passing it to the run and calling [`McapLog::finish`] at the end.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::eval::{anchor_covariance, confirmed};
use crate::{Observer, RuntimeError};
use serde_json::{Value, json};
use slam_core::nalgebra::{Matrix2, Vector2, Vector3};
use slam_core::{Estimator, Pose2, Pose3, Shape, UpdateReport};
use slam_sensors::{Event, LaserScan, TimedEvent};

/// The scale of a 2-D covariance ellipse holding 95 % of the probability: `sqrt(chi2_2(0.95))`.
const ELLIPSE_SCALE: f64 = 2.447_746_830_680_816;
/// How far a feature's drawing (an end, a centre, an ellipse's half-axis) moves before
/// `/map` sends it again, m.
const MAP_CHANGE_M: f64 = 0.005;
/// Points of an ellipse's line strip (the first repeated at the end).
const ELLIPSE_POINTS: usize = 25;

/// `x` rounded to 0.1 mm (or 1e-4 rad): what a viewer shows, at a third of the digits.
fn fine(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// The topics of `run.mcap` with their schema names.
pub const TOPICS: [(&str, &str); 5] = [
    ("/tf", "foxglove.FrameTransform"),
    ("/pose", "foxglove.PoseInFrame"),
    ("/pose_covariance", "foxglove.SceneUpdate"),
    ("/scan", "foxglove.LaserScan"),
    ("/map", "foxglove.SceneUpdate"),
];

/// A JSON schema naming the fields of a Foxglove message as this writer fills them.
fn schema(name: &str) -> Value {
    let time = json!({"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}});
    let object = json!({"type": "object"});
    let array = json!({"type": "array"});
    let string = json!({"type": "string"});
    let number = json!({"type": "number"});
    let properties = match name {
        "foxglove.FrameTransform" => json!({
            "timestamp": time, "parent_frame_id": string, "child_frame_id": string,
            "translation": object, "rotation": object
        }),
        "foxglove.PoseInFrame" => json!({"timestamp": time, "frame_id": string, "pose": object}),
        "foxglove.LaserScan" => json!({
            "timestamp": time, "frame_id": string, "pose": object, "start_angle": number,
            "end_angle": number, "ranges": array, "intensities": array
        }),
        _ => json!({"deletions": array, "entities": array}),
    };
    json!({"title": name, "type": "object", "properties": properties})
}

/// A time in seconds as Foxglove's `{sec, nsec}`, and in nanoseconds.
fn stamp(time: f64) -> (Value, u64) {
    let nanos = if time.is_finite() && time > 0.0 {
        (time * 1e9).round().min(u64::MAX as f64) as u64
    } else {
        0
    };
    (
        json!({"sec": nanos / 1_000_000_000, "nsec": nanos % 1_000_000_000}),
        nanos,
    )
}

/// A Foxglove quaternion of yaw, pitch and roll (z-y-x).
fn quaternion(yaw: f64, pitch: f64, roll: f64) -> Value {
    let (sy, cy) = (yaw / 2.0).sin_cos();
    let (sp, cp) = (pitch / 2.0).sin_cos();
    let (sr, cr) = (roll / 2.0).sin_cos();
    json!({
        "x": sr * cp * cy - cr * sp * sy,
        "y": cr * sp * cy + sr * cp * sy,
        "z": cr * cp * sy - sr * sp * cy,
        "w": cr * cp * cy + sr * sp * sy,
    })
}

fn point(p: Vector3<f64>) -> Value {
    json!({"x": fine(p.x), "y": fine(p.y), "z": fine(p.z)})
}

fn pose_json(translation: Vector3<f64>, yaw: f64, pitch: f64, roll: f64) -> Value {
    json!({"position": point(translation), "orientation": quaternion(yaw, pitch, roll)})
}

fn identity_pose() -> Value {
    pose_json(Vector3::zeros(), 0.0, 0.0, 0.0)
}

fn color(r: f64, g: f64, b: f64) -> Value {
    json!({"r": r, "g": g, "b": b, "a": 1.0})
}

/// The 95 % ellipse of a 2-D covariance around `centre` at height `z`, closed; `None` for a
/// covariance that is not finite.
fn ellipse(centre: Vector2<f64>, covariance: &Matrix2<f64>, z: f64) -> Option<Vec<Value>> {
    if !covariance.iter().all(|v| v.is_finite()) {
        return None;
    }
    let symmetric = (covariance + covariance.transpose()) / 2.0;
    let eigen = symmetric.symmetric_eigen();
    let root =
        eigen.eigenvectors * Matrix2::from_diagonal(&eigen.eigenvalues.map(|v| v.max(0.0).sqrt()));
    let mut points: Vec<Value> = (0..ELLIPSE_POINTS - 1)
        .map(|k| {
            let angle = std::f64::consts::TAU * k as f64 / (ELLIPSE_POINTS - 1) as f64;
            let p = centre + ELLIPSE_SCALE * root * Vector2::new(angle.cos(), angle.sin());
            point(Vector3::new(p.x, p.y, z))
        })
        .collect();
    // Closed: the first point again.
    points.push(points[0].clone());
    Some(points)
}

/// A line primitive (`kind` 0: strip, 2: list).
fn line(kind: u8, points: Vec<Value>, thickness: f64, color: Value) -> Value {
    json!({
        "type": kind, "pose": identity_pose(), "thickness": thickness,
        "scale_invariant": false, "points": points, "color": color,
        "colors": [], "indices": []
    })
}

/// A scene entity in frame `map` holding `lines` and `spheres`.
fn entity(time: &Value, id: &str, lines: Vec<Value>, spheres: Vec<Value>) -> Value {
    json!({
        "timestamp": time, "frame_id": "map", "id": id,
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": false, "metadata": [],
        "arrows": [], "cubes": [], "spheres": spheres, "cylinders": [], "lines": lines,
        "triangles": [], "texts": [], "models": []
    })
}

/// The writer of `run.mcap`: an [`Observer`] of the run, then [`McapLog::finish`].
pub struct McapLog {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    /// Channel id by topic.
    channels: BTreeMap<&'static str, u16>,
    sequence: u32,
    /// Seconds of data time between two maps.
    map_interval_s: f64,
    last_map: Option<f64>,
    last_time: Option<f64>,
    /// What each feature's entity was drawn from when last sent, by feature id.
    shown: BTreeMap<usize, Vec<f64>>,
}

impl std::fmt::Debug for McapLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapLog").field("path", &self.path).finish()
    }
}

fn write_error(path: &Path, error: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::Data(format!("writing {}: {error}", path.display()))
}

impl McapLog {
    /// Creates `path` with its schemas and channels; the map is logged every `map_interval_s`
    /// seconds of data time.
    pub fn create(path: &Path, map_interval_s: f64) -> crate::Result<Self> {
        let file = File::create(path).map_err(|e| write_error(path, e))?;
        let options = mcap::WriteOptions::new()
            .compression(None)
            .profile("")
            .library(format!("mspace-slam {}", env!("CARGO_PKG_VERSION")));
        let mut writer = options
            .create(BufWriter::new(file))
            .map_err(|e| write_error(path, e))?;
        let mut channels = BTreeMap::new();
        let mut schemas: BTreeMap<&str, u16> = BTreeMap::new();
        for (topic, name) in TOPICS {
            let schema_id = match schemas.get(name) {
                Some(id) => *id,
                None => {
                    let data = schema(name).to_string();
                    let id = writer
                        .add_schema(name, "jsonschema", data.as_bytes())
                        .map_err(|e| write_error(path, e))?;
                    schemas.insert(name, id);
                    id
                }
            };
            let channel = writer
                .add_channel(schema_id, topic, "json", &BTreeMap::new())
                .map_err(|e| write_error(path, e))?;
            channels.insert(topic, channel);
        }
        Ok(McapLog {
            writer,
            path: path.to_path_buf(),
            channels,
            sequence: 0,
            map_interval_s,
            last_map: None,
            last_time: None,
            shown: BTreeMap::new(),
        })
    }

    fn write(&mut self, topic: &'static str, nanos: u64, message: &Value) -> crate::Result<()> {
        let channel_id = *self
            .channels
            .get(topic)
            .ok_or_else(|| RuntimeError::Invariant(format!("run.mcap has no channel {topic}")))?;
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: nanos,
            publish_time: nanos,
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(&header, message.to_string().as_bytes())
            .map_err(|e| write_error(&self.path, e))
    }

    fn scan(&mut self, time: f64, scan: &LaserScan, mount: &Pose3) -> crate::Result<()> {
        let (stamp, nanos) = stamp(time);
        let last = scan.bearing(scan.ranges.len().saturating_sub(1));
        // JSON has no infinity or NaN: such readings are written as 0 (no return).
        let ranges: Vec<f64> = scan
            .ranges
            .iter()
            .map(|r| if r.is_finite() { fine(*r) } else { 0.0 })
            .collect();
        let message = json!({
            "timestamp": stamp, "frame_id": "base_link",
            "pose": pose_json(mount.translation, mount.yaw, mount.pitch, mount.roll),
            "start_angle": scan.angle_min, "end_angle": last,
            "ranges": ranges, "intensities": []
        });
        self.write("/scan", nanos, &message)
    }

    fn pose(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> crate::Result<()> {
        let world_from_robot = estimator.pose();
        if !world_from_robot.is_finite() {
            return Ok(());
        }
        let (stamp, nanos) = stamp(time);
        let translation = Vector3::new(world_from_robot.x, world_from_robot.y, 0.0);
        let transform = json!({
            "timestamp": stamp, "parent_frame_id": "map", "child_frame_id": "base_link",
            "translation": point(translation), "rotation": quaternion(world_from_robot.theta, 0.0, 0.0)
        });
        self.write("/tf", nanos, &transform)?;
        let pose = json!({
            "timestamp": stamp, "frame_id": "map",
            "pose": pose_json(translation, world_from_robot.theta, 0.0, 0.0)
        });
        self.write("/pose", nanos, &pose)?;
        let c = estimator.pose_covariance();
        let lines = if c.shape() == (3, 3) {
            let xy = Matrix2::new(c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]);
            ellipse(world_from_robot.translation(), &xy, 0.0)
                .map(|points| vec![line(0, points, 0.02, color(1.0, 0.3, 0.3))])
                .unwrap_or_default()
        } else {
            Vec::new()
        };
        let update = json!({
            "deletions": [],
            "entities": [entity(&stamp, "robot_covariance", lines, Vec::new())]
        });
        self.write("/pose_covariance", nanos, &update)
    }

    /// The confirmed map at `time`: one entity per feature (`feature-<id>`), sent again only
    /// when its drawing moved by more than [`MAP_CHANGE_M`], and deleted when the feature
    /// left the map; the first map is always written.
    fn map(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> crate::Result<()> {
        let (stamp, nanos) = stamp(time);
        let mut entities = Vec::new();
        let mut present = std::collections::BTreeSet::new();
        for (id, feature) in estimator.map().iter() {
            if !confirmed(estimator, id) {
                continue;
            }
            let (lines, spheres, signature) = match feature.shape() {
                Some(Shape::Wall { start, end }) => {
                    let ends = vec![
                        point(Vector3::new(start.x, start.y, 0.0)),
                        point(Vector3::new(end.x, end.y, 0.0)),
                    ];
                    let signature = vec![start.x, start.y, end.x, end.y];
                    (
                        vec![line(2, ends, 0.05, color(0.1, 0.1, 0.1))],
                        Vec::new(),
                        signature,
                    )
                }
                Some(Shape::Line { start, end }) => {
                    let signature = vec![start.x, start.y, start.z, end.x, end.y, end.z];
                    let ends = vec![point(start), point(end)];
                    (
                        vec![line(2, ends, 0.05, color(0.4, 0.4, 0.4))],
                        Vec::new(),
                        signature,
                    )
                }
                Some(
                    shape @ (Shape::Pole { .. } | Shape::Point { .. } | Shape::PlanarPoint { .. }),
                ) => {
                    let (centre, size) = match shape {
                        Shape::Pole { centre, radius } => {
                            (Vector3::new(centre.x, centre.y, 0.0), 2.0 * radius)
                        }
                        Shape::Point { position } => (position, 0.15),
                        Shape::PlanarPoint { position } => {
                            (Vector3::new(position.x, position.y, 0.0), 0.15)
                        }
                        _ => continue,
                    };
                    let sphere = json!({
                        "pose": pose_json(centre, 0.0, 0.0, 0.0),
                        "size": {"x": size, "y": size, "z": size},
                        "color": color(0.1, 0.5, 1.0)
                    });
                    let mut signature = vec![centre.x, centre.y, centre.z, size];
                    let covariance = anchor_covariance(estimator, id);
                    let lines = covariance
                        .and_then(|c| ellipse(centre.xy(), &c, centre.z))
                        .map(|points| vec![line(0, points, 0.02, color(0.1, 0.5, 1.0))])
                        .unwrap_or_default();
                    if let Some(c) = covariance {
                        // The ellipse's half-axes change as the square roots of these.
                        signature.extend(c.iter().map(|v| v.abs().sqrt() * ELLIPSE_SCALE));
                    }
                    (lines, vec![sphere], signature)
                }
                _ => continue,
            };
            present.insert(id.0);
            let moved = self.shown.get(&id.0).is_none_or(|shown| {
                shown.len() != signature.len()
                    || shown
                        .iter()
                        .zip(&signature)
                        .any(|(a, b)| (a - b).abs() > MAP_CHANGE_M)
            });
            if moved {
                let name = format!("feature-{}", id.0);
                entities.push(entity(&stamp, &name, lines, spheres));
                self.shown.insert(id.0, signature);
            }
        }
        let gone: Vec<usize> = self
            .shown
            .keys()
            .filter(|id| !present.contains(id))
            .copied()
            .collect();
        let deletions: Vec<Value> = gone
            .iter()
            .map(|id| json!({"timestamp": stamp, "type": 0, "id": format!("feature-{id}")}))
            .collect();
        for id in gone {
            self.shown.remove(&id);
        }
        let first = self.last_map.is_none();
        self.last_map = Some(time);
        if first || !entities.is_empty() || !deletions.is_empty() {
            let update = json!({"deletions": deletions, "entities": entities});
            self.write("/map", nanos, &update)?;
        }
        Ok(())
    }

    /// Logs the final map (unless logged at the last step already) and completes the file.
    pub fn finish(mut self, estimator: &dyn Estimator<Pose2>) -> crate::Result<()> {
        if let Some(time) = self.last_time
            && self.last_map != Some(time)
        {
            self.map(time, estimator)?;
        }
        self.writer
            .finish()
            .map_err(|e| write_error(&self.path, e))?;
        let path = self.path.clone();
        let mut inner = self.writer.into_inner();
        inner.flush().map_err(|e| write_error(&path, e))
    }
}

impl Observer for McapLog {
    fn event(
        &mut self,
        event: &TimedEvent,
        _: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> crate::Result<()> {
        if let Event::Scan {
            scan,
            robot_from_sensor,
        } = &event.event
        {
            self.scan(event.time, scan, robot_from_sensor)?;
        }
        Ok(())
    }

    fn step_end(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> crate::Result<()> {
        self.pose(time, estimator)?;
        self.last_time = Some(time);
        let due = self
            .last_map
            .is_none_or(|last| time - last >= self.map_interval_s);
        if due {
            self.map(time, estimator)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_quaternions_and_ellipses() {
        let (value, nanos) = stamp(12.5);
        assert_eq!(nanos, 12_500_000_000);
        assert_eq!(value, json!({"sec": 12, "nsec": 500_000_000}));
        assert_eq!(stamp(-1.0).1, 0);
        let q = quaternion(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        assert!((q["z"].as_f64().unwrap() - 0.5f64.sqrt()).abs() < 1e-12);
        assert!((q["w"].as_f64().unwrap() - 0.5f64.sqrt()).abs() < 1e-12);
        // A circle of radius 2.4477 sigma for sigma = 1 (x) and 0.5 (y), axis-aligned.
        let points = ellipse(
            Vector2::new(1.0, 2.0),
            &Matrix2::new(1.0, 0.0, 0.0, 0.25),
            0.0,
        )
        .unwrap();
        assert_eq!(points.len(), ELLIPSE_POINTS);
        assert_eq!(points[0], points[ELLIPSE_POINTS - 1]);
        for p in &points {
            let x = (p["x"].as_f64().unwrap() - 1.0) / 1.0;
            let y = (p["y"].as_f64().unwrap() - 2.0) / 0.5;
            // Positions are rounded to 0.1 mm.
            assert!(((x * x + y * y).sqrt() - ELLIPSE_SCALE).abs() < 5e-4);
        }
    }

    #[test]
    fn a_log_has_its_channels_and_ends_readably() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let config =
            crate::Config::from_toml("[estimator]\ntype = \"dead-reckoning\"\n", "t").unwrap();
        let start = crate::Start {
            pose: Pose2::new(1.0, 2.0, 0.5),
            covariance: slam_core::nalgebra::DMatrix::identity(3, 3) * 0.01,
        };
        let estimator = config.estimator.build(&start).unwrap();
        let mut log = McapLog::create(&path, 1.0).unwrap();
        let scan = LaserScan::new(-1.0, 1.0, vec![1.0, f64::INFINITY, 2.0], 0.1, 10.0).unwrap();
        for k in 0..3 {
            let event = TimedEvent {
                time: 0.5 * k as f64,
                event: Event::Scan {
                    scan: scan.clone(),
                    robot_from_sensor: Pose3::identity(),
                },
            };
            log.event(&event, None, estimator.as_ref()).unwrap();
            log.step_end(event.time, estimator.as_ref()).unwrap();
        }
        log.finish(estimator.as_ref()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.starts_with(mcap::MAGIC) && bytes.ends_with(mcap::MAGIC));
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let stats = summary.stats.unwrap();
        // 3 scans, 3 x (tf, pose, covariance), and the first map (empty: dead reckoning);
        // the map due at 1 s has not changed and is not sent.
        assert_eq!(stats.message_count, 3 + 9 + 1);
        let topics: Vec<String> = summary.channels.values().map(|c| c.topic.clone()).collect();
        assert_eq!(topics.len(), 5, "{topics:?}");
        let mut scans = 0;
        for message in mcap::MessageStream::new(&bytes).unwrap() {
            let message = message.unwrap();
            let value: Value = serde_json::from_slice(&message.data).unwrap();
            if message.channel.topic == "/scan" {
                scans += 1;
                assert_eq!(value["ranges"], json!([1.0, 0.0, 2.0]));
                assert_eq!(
                    message.channel.schema.as_ref().unwrap().name,
                    "foxglove.LaserScan"
                );
            }
        }
        assert_eq!(scans, 3);
    }
}
