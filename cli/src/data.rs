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

impl DataSpec {
    /// Loads the data; simulations use `seed`.
    pub fn load(&self, seed: u64) -> Result<Loaded> {
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
                plain(read_victoria_park(dir, &VictoriaParkOptions::default())?)
            }
            DataSpec::Mrclam(dir, robot) => {
                plain(read_mrclam(dir, *robot, &MrclamOptions::default())?)
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
