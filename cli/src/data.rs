//! Data specifications (`sim`, `world:FILE`, `carmen:FILE`, `victoria-park:DIR`,
//! `mrclam:DIR[:ROBOT]`, `rb2d:FILE`) and loading them into an event stream.

use std::path::PathBuf;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use slam_core::Pose2;
use slam_sensors::Dataset;
use slam_sensors::data::{
    CarmenOptions, MrclamOptions, VictoriaParkOptions, read_carmen, read_mrclam, read_rb2d,
    read_victoria_park,
};
use slam_sensors::sim::{TrueMap, World, simulate};

use crate::error::{CliError, Result};

/// Where the data come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DataSpec {
    /// The built-in default world, simulated.
    Sim,
    /// A world description file, simulated.
    World(PathBuf),
    /// A CARMEN log, plain or gzipped.
    Carmen(PathBuf),
    /// The Victoria Park dataset folder.
    VictoriaPark(PathBuf),
    /// A UTIAS MR.CLAM folder and robot number (1 to 5).
    Mrclam(PathBuf, u8),
    /// An rb2d log.
    Rb2d(PathBuf),
}

impl FromStr for DataSpec {
    type Err = CliError;

    fn from_str(text: &str) -> Result<Self> {
        let (kind, rest) = text.split_once(':').unwrap_or((text, ""));
        let path = || {
            if rest.is_empty() {
                Err(CliError::Usage(format!(
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
            "victoria-park" => Ok(DataSpec::VictoriaPark(path()?)),
            "rb2d" => Ok(DataSpec::Rb2d(path()?)),
            "mrclam" => {
                let (dir, robot) = match rest.rsplit_once(':') {
                    Some((dir, robot)) if robot.parse::<u8>().is_ok() => (dir, robot),
                    _ => (rest, "1"),
                };
                let robot: u8 = robot
                    .parse()
                    .map_err(|_| CliError::Usage(format!("bad robot number in `{text}`")))?;
                if dir.is_empty() {
                    return Err(CliError::Usage(format!(
                        "data spec `{text}` needs a folder"
                    )));
                }
                Ok(DataSpec::Mrclam(PathBuf::from(dir), robot))
            }
            _ => Err(CliError::Usage(format!(
                "unknown data spec `{text}`: use sim, world:FILE, carmen:FILE, victoria-park:DIR, \
                 mrclam:DIR[:ROBOT] or rb2d:FILE"
            ))),
        }
    }
}

/// A loaded dataset and, for simulations, the truth behind it.
#[derive(Debug)]
pub struct Loaded {
    /// The event stream.
    pub dataset: Dataset,
    /// The true map, when the data come from a simulated world.
    pub truth: Option<TrueMap>,
    /// The true trajectory, when known.
    pub trajectory: Option<Vec<Pose2>>,
    /// The range noise of the simulated laser, when the data are simulated with one.
    pub laser_sigma_range: Option<f64>,
}

/// Noise settings of the Victoria Park reader (`[data.victoria_park]`); see
/// [`VictoriaParkOptions`] for what each means.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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

/// Odometry built from a log's reference poses with seeded noise (`[data.odometry_from_poses]`),
/// for logs whose motion is not raw odometry (the Radish corrected logs): before each scan, the
/// increment from the previous scan's reference pose to this one's, with Gaussian noise of
/// deviation `translation_per_metre * d + floor_translation` on x and y and
/// `rotation_per_radian * |a| + rotation_per_metre * d + floor_rotation` on the heading (`d` the
/// distance, `a` the turn), drawn from a stream of the `[data] seed`. The data's own motion
/// events are dropped; the reference poses stay as the reference for the ATE.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseOdometryConfig {
    /// Translation deviation per metre travelled.
    pub translation_per_metre: f64,
    /// Heading deviation per radian turned.
    pub rotation_per_radian: f64,
    /// Heading deviation per metre travelled, rad/m.
    pub rotation_per_metre: f64,
    /// Smallest translation deviation, m.
    pub floor_translation: f64,
    /// Smallest heading deviation, rad.
    pub floor_rotation: f64,
}

impl Default for PoseOdometryConfig {
    fn default() -> Self {
        PoseOdometryConfig {
            translation_per_metre: 0.05,
            rotation_per_radian: 0.05,
            rotation_per_metre: 0.02,
            floor_translation: 0.005,
            floor_rotation: 0.002,
        }
    }
}

/// Replaces the motion of `dataset` by odometry from its reference poses (see
/// [`PoseOdometryConfig`]); each scan's pose is the ground-truth event at the scan's time.
pub fn odometry_from_poses(
    dataset: Dataset,
    noise: &PoseOdometryConfig,
    seed: u64,
) -> Result<Dataset> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use slam_sensors::{Event, TimedEvent};
    let values = [
        noise.translation_per_metre,
        noise.rotation_per_radian,
        noise.rotation_per_metre,
        noise.floor_translation,
        noise.floor_rotation,
    ];
    if values.iter().any(|v| !v.is_finite() || *v < 0.0) || values[3] <= 0.0 || values[4] <= 0.0 {
        return Err(CliError::Usage(
            "[data.odometry_from_poses]: deviations must be finite and >= 0, floors > 0".into(),
        ));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(0x0D0_0E7);
    let Dataset {
        name,
        events,
        clock,
        landmarks,
        skipped,
    } = dataset;
    let mut out = Vec::with_capacity(events.len());
    let mut previous: Option<Pose2> = None;
    let mut iter = events.into_iter().peekable();
    let mut motions = 0usize;
    while let Some(timed) = iter.next() {
        match &timed.event {
            Event::Motion(_) => continue,
            Event::Scan { .. } => {
                let pose = iter.peek().and_then(|next| match &next.event {
                    Event::GroundTruth { pose, .. } if next.time == timed.time => Some(*pose),
                    _ => None,
                });
                if let Some(pose) = pose {
                    if let Some(before) = previous {
                        let relative = before.inverse().compose(&pose);
                        let d = relative.translation().norm();
                        let a = relative.theta.abs();
                        let sigma_t = noise.translation_per_metre * d + noise.floor_translation;
                        let sigma_r = noise.rotation_per_radian * a
                            + noise.rotation_per_metre * d
                            + noise.floor_rotation;
                        let mut draw = || -> f64 { StandardNormal.sample(&mut rng) };
                        let noisy = Pose2::new(
                            relative.x + sigma_t * draw(),
                            relative.y + sigma_t * draw(),
                            relative.theta + sigma_r * draw(),
                        );
                        let cov = slam_core::nalgebra::Matrix3::from_diagonal(
                            &slam_core::nalgebra::Vector3::new(
                                sigma_t * sigma_t,
                                sigma_t * sigma_t,
                                sigma_r * sigma_r,
                            ),
                        );
                        let increment = slam_sensors::odometry::PoseIncrement::new(noisy, cov)?;
                        out.push(TimedEvent {
                            time: timed.time,
                            event: Event::Motion(Box::new(increment)),
                        });
                        motions += 1;
                    }
                    previous = Some(pose);
                }
            }
            _ => {}
        }
        out.push(timed);
    }
    if motions == 0 {
        return Err(CliError::Usage(format!(
            "[data.odometry_from_poses]: {name} has no scan with a reference pose"
        )));
    }
    Ok(Dataset {
        name,
        events: out,
        clock,
        landmarks,
        skipped,
    })
}

/// Settings of the dataset readers.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReaderOptions {
    /// Victoria Park.
    pub victoria_park: VictoriaParkConfig,
    /// MR.CLAM.
    pub mrclam: MrclamConfig,
}

impl DataSpec {
    /// Loads the data with the readers' default settings; simulations use `seed`.
    pub fn load(&self, seed: u64) -> Result<Loaded> {
        self.load_with(seed, &ReaderOptions::default())
    }

    /// Loads the data; simulations use `seed`.
    pub fn load_with(&self, seed: u64, options: &ReaderOptions) -> Result<Loaded> {
        let simulated = |world: &World| -> Result<Loaded> {
            let run = simulate(world, seed)?;
            Ok(Loaded {
                dataset: run.dataset,
                truth: Some(run.truth),
                trajectory: Some(run.trajectory),
                laser_sigma_range: world.laser.as_ref().map(|l| l.sigma_range),
            })
        };
        let plain = |dataset: Dataset| Loaded {
            dataset,
            truth: None,
            trajectory: None,
            laser_sigma_range: None,
        };
        Ok(match self {
            DataSpec::Sim => simulated(&World::default_world())?,
            DataSpec::World(path) => simulated(&World::from_file(path)?)?,
            DataSpec::Carmen(path) => plain(read_carmen(path, &CarmenOptions::default())?),
            DataSpec::VictoriaPark(dir) => {
                let v = &options.victoria_park;
                let reader = VictoriaParkOptions {
                    sigma_speed: v.sigma_speed,
                    sigma_steering: v.sigma_steering_deg.to_radians(),
                    sigma_range: v.sigma_range,
                    sigma_bearing: v.sigma_bearing_deg.to_radians(),
                    sigma_radius: v.sigma_radius,
                    ..VictoriaParkOptions::default()
                };
                plain(read_victoria_park(dir, &reader)?)
            }
            DataSpec::Mrclam(dir, robot) => {
                let m = &options.mrclam;
                let reader = MrclamOptions {
                    sigma_v: m.sigma_v,
                    sigma_omega: m.sigma_omega,
                    sigma_range: m.sigma_range,
                    sigma_bearing: m.sigma_bearing,
                    ..MrclamOptions::default()
                };
                plain(read_mrclam(dir, *robot, &reader)?)
            }
            DataSpec::Rb2d(path) => plain(read_rb2d(path)?),
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
        assert!("bag:x".parse::<DataSpec>().is_err());
    }
}
