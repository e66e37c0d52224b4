//! Data specifications (`sim`, `world:FILE`, `carmen:FILE`, `victoria-park:DIR`,
//! `mrclam:DIR[:ROBOT]`, `rb2d:FILE`) and loading them into an event stream.

use std::path::PathBuf;
use std::str::FromStr;

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
