//! Where a session's events come from: a data spec (`sim`, `world:FILE`, `carmen:FILE`,
//! `mcap:FILE`, `victoria-park:DIR`, `mrclam:DIR[:ROBOT]`, `rb2d:FILE`), read as a stream of events
//! ([`EventStream`]: a run's memory does not grow with the log), with the optional changes of
//! the motion (`[data.odometry_from_poses]`, `[data.laser_odometry]`).
//!
//! Which reader reads the data is a closed set (DESIGN.md: plain enums for closed sets).

use std::path::PathBuf;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use slam_sensors::EventStream;
use slam_sensors::data::{
    CarmenOptions, McapOptions, MrclamOptions, PoseOdometryParams, VictoriaParkOptions,
    odometry_from_poses, stream_carmen, stream_mcap, stream_mrclam, stream_rb2d,
    stream_victoria_park,
};
use slam_sensors::laser_odometry::{
    LaserOdometryCounts, LaserOdometryParams, laser_odometry_stream,
};
use slam_sensors::odometry::OdometryNoise;
use slam_sensors::sim::{TrueMap, World, simulate_stream};

use crate::error::{Result, RuntimeError};
use crate::frontend::SensorInfo;

/// Where the data come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DataSpec {
    /// The built-in default world, simulated.
    Sim,
    /// A world description file, simulated.
    World(PathBuf),
    /// A CARMEN log, plain or gzipped.
    Carmen(PathBuf),
    /// A ROS 2 bag stored as MCAP (topics from `[data.mcap]`).
    Mcap(PathBuf),
    /// The Victoria Park dataset folder.
    VictoriaPark(PathBuf),
    /// A UTIAS MR.CLAM folder and robot number (1 to 5).
    Mrclam(PathBuf, u8),
    /// An rb2d log.
    Rb2d(PathBuf),
}

impl DataSpec {
    /// Whether the data are simulated (they then have a true map).
    pub fn is_simulated(&self) -> bool {
        matches!(self, DataSpec::Sim | DataSpec::World(_))
    }
}

impl FromStr for DataSpec {
    type Err = RuntimeError;

    fn from_str(text: &str) -> Result<Self> {
        let (kind, rest) = text.split_once(':').unwrap_or((text, ""));
        let usage = |message: String| RuntimeError::setting("data", message);
        let path = || {
            if rest.is_empty() {
                Err(usage(format!(
                    "data spec `{text}` needs a path after `{kind}:`"
                )))
            } else {
                Ok(PathBuf::from(rest))
            }
        };
        match kind {
            "sim" if rest.is_empty() => Ok(DataSpec::Sim),
            "world" => Ok(DataSpec::World(path()?)),
            "carmen" => Ok(DataSpec::Carmen(path()?)),
            "mcap" => Ok(DataSpec::Mcap(path()?)),
            "victoria-park" => Ok(DataSpec::VictoriaPark(path()?)),
            "rb2d" => Ok(DataSpec::Rb2d(path()?)),
            "mrclam" => {
                let (dir, robot) = match rest.rsplit_once(':') {
                    Some((dir, robot)) if robot.parse::<u8>().is_ok() => (dir, robot),
                    _ => (rest, "1"),
                };
                let robot: u8 = robot
                    .parse()
                    .map_err(|_| usage(format!("bad robot number in `{text}`")))?;
                if dir.is_empty() {
                    return Err(usage(format!("data spec `{text}` needs a folder")));
                }
                Ok(DataSpec::Mrclam(PathBuf::from(dir), robot))
            }
            _ => Err(usage(format!(
                "unknown data spec `{text}`: use sim, world:FILE, carmen:FILE, mcap:FILE, \
                 victoria-park:DIR, mrclam:DIR[:ROBOT] or rb2d:FILE"
            ))),
        }
    }
}

/// Noise settings of the Victoria Park reader (`[data.victoria_park]`); see
/// [`VictoriaParkOptions`] for what each means.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VictoriaParkConfig {
    /// Encoder speed deviation, m/s.
    pub sigma_speed: f64,
    /// Steering angle deviation, degrees.
    pub sigma_steering_deg: f64,
    /// Trunk range deviation, m.
    pub sigma_range: f64,
    /// Trunk bearing deviation, degrees.
    pub sigma_bearing_deg: f64,
    /// Trunk radius deviation, m.
    pub sigma_radius: f64,
}

impl Default for VictoriaParkConfig {
    fn default() -> Self {
        let o = VictoriaParkOptions::default();
        VictoriaParkConfig {
            sigma_speed: o.sigma_speed,
            sigma_steering_deg: o.sigma_steering.to_degrees(),
            sigma_range: o.sigma_range,
            sigma_bearing_deg: o.sigma_bearing.to_degrees(),
            sigma_radius: o.sigma_radius,
        }
    }
}

/// Noise settings of the MR.CLAM reader (`[data.mrclam]`); see [`MrclamOptions`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MrclamConfig {
    /// Forward speed deviation, m/s.
    pub sigma_v: f64,
    /// Yaw rate deviation, rad/s.
    pub sigma_omega: f64,
    /// Range deviation, m.
    pub sigma_range: f64,
    /// Bearing deviation, rad.
    pub sigma_bearing: f64,
}

impl Default for MrclamConfig {
    fn default() -> Self {
        let o = MrclamOptions::default();
        MrclamConfig {
            sigma_v: o.sigma_v,
            sigma_omega: o.sigma_omega,
            sigma_range: o.sigma_range,
            sigma_bearing: o.sigma_bearing,
        }
    }
}

/// Topics and frames of the ROS 2 bag reader (`[data.mcap]`); see [`McapOptions`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct McapConfig {
    /// The `sensor_msgs/msg/LaserScan` topic.
    pub scan_topic: String,
    /// The `nav_msgs/msg/Odometry` topic; `""`: none.
    pub odom_topic: String,
    /// The reference pose topic (`geometry_msgs/msg/PoseStamped` or `nav_msgs/msg/Odometry`),
    /// e.g. another system's poses for the ATE; `""` (the default): none.
    pub reference_topic: String,
    /// The robot frame, where the `/tf_static` chain to the laser frame starts.
    pub base_frame: String,
    /// The laser's mount `[x, y, yaw]` (m, m, rad) when `/tf_static` does not give it;
    /// absent: the identity.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_mount: Option<[f64; 3]>,
}

impl Default for McapConfig {
    fn default() -> Self {
        let o = McapOptions::default();
        McapConfig {
            scan_topic: o.scan_topic,
            odom_topic: o.odom_topic,
            reference_topic: o.reference_topic,
            base_frame: o.base_frame,
            laser_mount: None,
        }
    }
}

impl McapConfig {
    /// The reader's options.
    pub fn options(&self) -> McapOptions {
        McapOptions {
            scan_topic: self.scan_topic.clone(),
            odom_topic: self.odom_topic.clone(),
            reference_topic: self.reference_topic.clone(),
            base_frame: self.base_frame.clone(),
            laser_mount: self.laser_mount.map(|[x, y, yaw]| {
                slam_core::Pose3::new(slam_core::nalgebra::Vector3::new(x, y, 0.0), yaw, 0.0, 0.0)
            }),
            ..McapOptions::default()
        }
    }
}

/// The `[data.carmen]` table: settings of the CARMEN reader.
///
/// ```toml
/// [data.carmen.odometry_noise]   # of the motion between two scans (slam_sensors::odometry::OdometryNoise)
/// translation_per_metre = 0.05
/// rotation_per_radian = 0.05
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CarmenConfig {
    /// Noise of the odometry increment between two scans (standard deviations growing with
    /// the motion).
    pub odometry_noise: OdometryNoise,
}

impl CarmenConfig {
    /// The reader's options; an error when a noise term is negative or not finite.
    pub fn options(&self) -> Result<CarmenOptions> {
        let n = &self.odometry_noise;
        n.validate().map_err(|e| {
            let message = match e {
                slam_sensors::SensorError::InvalidArgument(message) => message,
                other => other.to_string(),
            };
            RuntimeError::setting("data.carmen.odometry_noise", message)
        })?;
        Ok(CarmenOptions {
            odometry_noise: n.clone(),
            ..CarmenOptions::default()
        })
    }
}

/// The `[data]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Data spec (see [`DataSpec`]).
    pub spec: String,
    /// Seed of simulations and of the `odometry_from_poses` noise.
    pub seed: u64,
    /// Standard deviations `(x, y, heading)` of the initial pose (m, m, rad). Default 0: the
    /// map frame is the robot's first pose (or the simulated start, which is known).
    pub initial_pose_sigma: [f64; 3],
    /// Process at most this many events (0: all).
    pub max_events: usize,
    /// Victoria Park reader noise settings.
    pub victoria_park: VictoriaParkConfig,
    /// MR.CLAM reader noise settings.
    pub mrclam: MrclamConfig,
    /// ROS 2 bag (MCAP) topics and frames.
    pub mcap: McapConfig,
    /// CARMEN reader settings.
    pub carmen: CarmenConfig,
    /// Replace the data's motion by odometry built from its reference poses with seeded
    /// noise (for logs without raw odometry, such as the Radish corrected logs).
    pub odometry_from_poses: Option<PoseOdometryParams>,
    /// Replace the motion between consecutive scans by the match of the scans (ICP, the
    /// motion as its prior); applied after `odometry_from_poses`.
    pub laser_odometry: Option<LaserOdometryParams>,
}

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig {
            spec: "sim".into(),
            seed: 1,
            initial_pose_sigma: [0.0; 3],
            max_events: 0,
            victoria_park: VictoriaParkConfig::default(),
            mrclam: MrclamConfig::default(),
            mcap: McapConfig::default(),
            carmen: CarmenConfig::default(),
            odometry_from_poses: None,
            laser_odometry: None,
        }
    }
}

/// Opened data: the event stream and what is known of the data before reading it.
#[derive(Debug)]
pub struct Data {
    /// The events, in time order.
    pub events: EventStream,
    /// The true map, when the data come from a simulated world.
    pub truth: Option<TrueMap>,
    /// What a front-end may know of the sensors.
    pub sensors: SensorInfo,
    /// The matches of `[data.laser_odometry]`, counted as the stream is read.
    pub laser_odometry: Option<LaserOdometryCounts>,
}

impl DataConfig {
    /// The data spec.
    pub fn data_spec(&self) -> Result<DataSpec> {
        self.spec.parse()
    }

    /// Opens the data (a simulation uses `seed`), with the configured changes of the motion.
    pub fn open(&self) -> Result<Data> {
        let spec = self.data_spec()?;
        let (events, truth, sensors) = self.open_spec(&spec)?;
        let events = match &self.odometry_from_poses {
            Some(noise) => {
                noise.validate()?;
                odometry_from_poses(events, noise, self.seed)?
            }
            None => events,
        };
        let (events, laser_odometry) = match &self.laser_odometry {
            Some(params) => {
                let (events, counts) = laser_odometry_stream(events, params)?;
                (events, Some(counts))
            }
            None => (events, None),
        };
        Ok(Data {
            events,
            truth,
            sensors,
            laser_odometry,
        })
    }

    fn open_spec(&self, spec: &DataSpec) -> Result<(EventStream, Option<TrueMap>, SensorInfo)> {
        let simulated = |world: &World| -> Result<(EventStream, Option<TrueMap>, SensorInfo)> {
            let run = simulate_stream(world, self.seed)?;
            let sensors = SensorInfo {
                laser_sigma_range: world.laser.as_ref().map(|l| l.sigma_range),
                raw_sensors: world.laser.is_some() || world.camera.is_some(),
            };
            Ok((run.events, Some(run.truth), sensors))
        };
        let given = |raw_sensors| SensorInfo {
            laser_sigma_range: None,
            raw_sensors,
        };
        Ok(match spec {
            DataSpec::Sim => simulated(&World::default_world())?,
            DataSpec::World(path) => simulated(&World::from_file(path)?)?,
            DataSpec::Carmen(path) => (
                stream_carmen(path, &self.carmen.options()?)?,
                None,
                given(true),
            ),
            DataSpec::Mcap(path) => (stream_mcap(path, &self.mcap.options())?, None, given(true)),
            DataSpec::VictoriaPark(dir) => {
                let v = &self.victoria_park;
                let reader = VictoriaParkOptions {
                    sigma_speed: v.sigma_speed,
                    sigma_steering: v.sigma_steering_deg.to_radians(),
                    sigma_range: v.sigma_range,
                    sigma_bearing: v.sigma_bearing_deg.to_radians(),
                    sigma_radius: v.sigma_radius,
                    ..VictoriaParkOptions::default()
                };
                (stream_victoria_park(dir, &reader)?, None, given(false))
            }
            DataSpec::Mrclam(dir, robot) => {
                let m = &self.mrclam;
                let reader = MrclamOptions {
                    sigma_v: m.sigma_v,
                    sigma_omega: m.sigma_omega,
                    sigma_range: m.sigma_range,
                    sigma_bearing: m.sigma_bearing,
                    ..MrclamOptions::default()
                };
                (stream_mrclam(dir, *robot, &reader)?, None, given(false))
            }
            DataSpec::Rb2d(path) => (stream_rb2d(path)?, None, given(false)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse() {
        assert_eq!("sim".parse::<DataSpec>().unwrap(), DataSpec::Sim);
        assert_eq!(
            "mrclam:/d/MRCLAM:3".parse::<DataSpec>().unwrap(),
            DataSpec::Mrclam("/d/MRCLAM".into(), 3)
        );
        assert_eq!(
            "mrclam:/d/MRCLAM".parse::<DataSpec>().unwrap(),
            DataSpec::Mrclam("/d/MRCLAM".into(), 1)
        );
        assert!("carmen:".parse::<DataSpec>().is_err());
        assert_eq!(
            "mcap:/d/run.mcap".parse::<DataSpec>().unwrap(),
            DataSpec::Mcap("/d/run.mcap".into())
        );
        assert!("bag:x".parse::<DataSpec>().is_err());
    }

    #[test]
    fn mcap_topics_come_from_the_config_and_unknown_keys_are_errors() {
        let config = crate::Config::from_toml(
            "[data]\nspec = \"mcap:run.mcap\"\n[data.mcap]\nreference_topic = \"/truth\"\n\
             laser_mount = [0.1, 0.0, 2.5]\n",
            "t.toml",
        )
        .unwrap();
        let options = config.data.mcap.options();
        assert_eq!(
            (options.scan_topic.as_str(), options.odom_topic.as_str()),
            ("/scan", "/odom")
        );
        assert_eq!(options.reference_topic, "/truth");
        assert_eq!(options.laser_mount.unwrap().yaw, 2.5);
        let e = crate::Config::from_toml("[data.mcap]\nscan_topik = \"/x\"\n", "t.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("scan_topik"), "{e}");
    }
}
