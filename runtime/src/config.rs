//! The run configuration (TOML). Every table and key is optional; an unknown key is an error
//! that names it.
//!
//! ```toml
//! [data]
//! spec = "sim"            # sim, world:FILE, carmen:FILE, mcap:FILE, victoria-park:DIR, mrclam:DIR[:ROBOT], rb2d:FILE
//! seed = 1                # simulation seed
//!
//! [estimator]
//! type = "ekf"            # the word that selects a registered estimator: ekf, fastslam,
//!                         # ipslam, dead-reckoning, or one a linked crate registers
//! association = "nearest-neighbour"   # or "jcbb"; further keys: the estimator's settings
//!
//! [frontend]              # type: a registered front-end; default: the estimator's
//! walls = true            # (for "features") laser scans -> wall segments
//! wall_representation = "mspace"      # or "endpoints" (slam-examples), or a table
//!
//! [[postprocess]]         # stages run after the estimator, e.g. type = "em-polygon"
//!
//! [output]
//! dir = "slam-out"
//! plots = true
//! grid = false            # map.pgm + map.yaml, the occupancy grid (runs with a laser)
//! grid_resolution = 0.05  # its cell side, m
//! grid_max_range = 30.0   # beams are cast this far at most (free only beyond), m
//! g2o = false             # graph.g2o, the pose graph with landmarks and walls
//! mcap = false            # run.mcap, the run for Foxglove (Foxglove schemas, JSON)
//! mcap_map_interval_s = 1.0   # data time between two maps in run.mcap, s
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use slam_estimators::EkfParams;

use crate::data::DataConfig;
use crate::error::{Result, RuntimeError};
use crate::estimators::EstimatorConfig;
use crate::frontend::FrontendConfig;
use crate::postprocess::PostProcessConfig;

/// The `[output]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Output folder.
    pub dir: PathBuf,
    /// Draw `map.svg` and `map.png`.
    pub plots: bool,
    /// Write the occupancy grid of the scans placed by the estimated poses, `map.pgm` and
    /// `map.yaml` (ROS map_server format); a run without laser scans has none.
    pub grid: bool,
    /// Cell side of the occupancy grid, m.
    pub grid_resolution: f64,
    /// Longest beam cast into the grid, m: a longer reading, or a reading at the laser's
    /// maximum range, marks the cells up to this distance free and nothing occupied (so that
    /// beams through windows and doors do not grow the grid by the laser's full range).
    pub grid_max_range: f64,
    /// Write the pose graph with the landmarks and walls, `graph.g2o`.
    pub g2o: bool,
    /// Write `run.mcap`, the run for Foxglove (poses, scans, map, covariance ellipses).
    pub mcap: bool,
    /// Data time between two maps in `run.mcap`, s (0: at every time step).
    pub mcap_map_interval_s: f64,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            dir: PathBuf::from("slam-out"),
            plots: true,
            grid: false,
            grid_resolution: 0.05,
            grid_max_range: 30.0,
            g2o: false,
            mcap: false,
            mcap_map_interval_s: 1.0,
        }
    }
}

impl OutputConfig {
    /// Checks the values: a positive grid resolution and range, a map interval of zero or
    /// more.
    pub fn validate(&self) -> Result<()> {
        if !(self.grid_resolution.is_finite() && self.grid_resolution > 0.0) {
            return Err(RuntimeError::setting(
                "output",
                format!(
                    "grid_resolution = {}: give a positive cell side in metres",
                    self.grid_resolution
                ),
            ));
        }
        if !(self.grid_max_range.is_finite() && self.grid_max_range > 0.0) {
            return Err(RuntimeError::setting(
                "output",
                format!(
                    "grid_max_range = {}: give a positive distance in metres",
                    self.grid_max_range
                ),
            ));
        }
        if !(self.mcap_map_interval_s.is_finite() && self.mcap_map_interval_s >= 0.0) {
            return Err(RuntimeError::setting(
                "output",
                format!(
                    "mcap_map_interval_s = {}: give zero or more seconds",
                    self.mcap_map_interval_s
                ),
            ));
        }
        Ok(())
    }
}

/// The whole configuration: data, estimator, front-end, post-processing stages, outputs.
///
/// ```
/// use slam_runtime::Config;
/// let config = Config::from_toml("[estimator]\ntype = \"ipslam\"\nparticles = 20\n", "inline")?;
/// // IPSLAM takes the scan's returns: its front-end is chosen by default.
/// let table = toml::Value::try_from(&config.frontend).unwrap();
/// assert_eq!(table["type"].as_str(), Some("scan-points"));
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(try_from = "ConfigRepr")]
pub struct Config {
    /// Where the data come from.
    pub data: DataConfig,
    /// Which estimator, with its settings.
    pub estimator: Box<dyn EstimatorConfig>,
    /// How raw sensor data become observations.
    pub frontend: Box<dyn FrontendConfig>,
    /// Stages run after the estimator.
    pub postprocess: Vec<Box<dyn PostProcessConfig>>,
    /// What is written where.
    pub output: OutputConfig,
}

impl Default for Config {
    fn default() -> Self {
        // The default front-end of the default estimator; a built-in name resolves.
        let estimator: Box<dyn EstimatorConfig> = Box::new(EkfParams::default());
        Config {
            data: DataConfig::default(),
            frontend: Box::new(crate::frontend::FeaturesFrontendConfig::default()),
            estimator,
            postprocess: Vec::new(),
            output: OutputConfig::default(),
        }
    }
}

/// The configuration as written: the front-end table is resolved once the estimator is
/// known (its default front-end fills a missing `type`).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ConfigRepr {
    #[serde(default)]
    data: DataConfig,
    #[serde(default = "default_estimator")]
    estimator: Box<dyn EstimatorConfig>,
    #[serde(default)]
    frontend: Option<toml::Table>,
    #[serde(default)]
    postprocess: Vec<Box<dyn PostProcessConfig>>,
    #[serde(default)]
    output: OutputConfig,
}

fn default_estimator() -> Box<dyn EstimatorConfig> {
    Box::new(EkfParams::default())
}

impl TryFrom<ConfigRepr> for Config {
    type Error = String;

    fn try_from(repr: ConfigRepr) -> std::result::Result<Self, String> {
        let frontend = resolve_frontend(repr.frontend.unwrap_or_default(), repr.estimator.as_ref())
            .map_err(|e| format!("[frontend] {e}"))?;
        Ok(Config {
            data: repr.data,
            estimator: repr.estimator,
            frontend,
            postprocess: repr.postprocess,
            output: repr.output,
        })
    }
}

/// The front-end of a `[frontend]` table; a table without `type` is the estimator's default
/// front-end.
fn resolve_frontend(
    mut table: toml::Table,
    estimator: &dyn EstimatorConfig,
) -> std::result::Result<Box<dyn FrontendConfig>, toml::de::Error> {
    if !table.contains_key("type") {
        table.insert(
            "type".into(),
            toml::Value::String(estimator.default_frontend().into()),
        );
    }
    Box::<dyn FrontendConfig>::deserialize(toml::Value::Table(table))
}

impl Config {
    /// Parses a TOML configuration; unknown keys and names, and values of the wrong type or
    /// range, are errors naming the table and key.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self> {
        toml::from_str(text).map_err(|e| {
            let message = match toml::from_str::<toml::Table>(text) {
                // Valid TOML that is not a valid config: name the key at fault.
                Ok(table) => blame(&table, &e),
                Err(_) => e.to_string(),
            };
            RuntimeError::config(origin, message)
        })
    }

    /// Reads a TOML configuration file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            RuntimeError::config(path.display().to_string(), format!("cannot read it: {e}"))
        })?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// The configuration as TOML, with every default written out.
    pub fn to_toml(&self) -> Result<String> {
        toml::to_string(self)
            .map_err(|e| RuntimeError::Invariant(format!("writing the config: {e}")))
    }

    /// Replaces the front-end by the estimator's default one (after a change of estimator).
    pub fn use_default_frontend(&mut self) -> Result<()> {
        self.frontend = resolve_frontend(toml::Table::new(), self.estimator.as_ref())
            .map_err(|e| RuntimeError::config("defaults", format!("[frontend] {e}")))?;
        Ok(())
    }

    /// Sets one key of the `[frontend]` table (e.g. `wall_representation`), as if the TOML
    /// had said so.
    pub fn set_frontend_key(&mut self, key: &str, value: toml::Value) -> Result<()> {
        let invariant = |e: String| RuntimeError::Invariant(format!("[frontend] as TOML: {e}"));
        let mut table = match toml::Value::try_from(&self.frontend) {
            Ok(toml::Value::Table(table)) => table,
            Ok(other) => return Err(invariant(format!("not a table: {other}"))),
            Err(e) => return Err(invariant(e.to_string())),
        };
        table.insert(key.into(), value);
        self.frontend = Box::<dyn FrontendConfig>::deserialize(toml::Value::Table(table))
            .map_err(|e| RuntimeError::setting("frontend", e.to_string()))?;
        Ok(())
    }

    /// Checks the estimator's, the front-end's and the stages' settings before any data is
    /// read.
    pub fn validate(&self) -> Result<()> {
        self.output.validate()?;
        self.estimator.validate()?;
        self.frontend.validate()?;
        for stage in &self.postprocess {
            stage.validate()?;
        }
        Ok(())
    }
}

/// The message of `error` (a config that is valid TOML but not a valid config) naming the key
/// at fault: the settings tables are read through `typetag`, which loses the key of a value
/// of the wrong type, so each key is tried alone (with every `type`) until one fails.
fn blame(table: &toml::Table, error: &toml::de::Error) -> String {
    let mut leaves = Vec::new();
    leaf_paths(table, &mut Vec::new(), &mut leaves);
    let skeleton = toml::Value::Table(only_types(table));
    if let Err(e) = skeleton.clone().try_into::<Config>() {
        // A `type` itself is at fault (an unknown estimator, say): name the one the message
        // quotes, not the first key tried.
        let message = e.message().trim().to_string();
        let mut types = Vec::new();
        type_paths(table, &mut Vec::new(), &mut types);
        return types
            .iter()
            .find_map(|path| {
                let value = get_path(table, path)?.as_str()?;
                message
                    .contains(&format!("variant `{value}`"))
                    .then(|| format!("[{}] type = \"{value}\": {message}", table_name(path)))
            })
            .unwrap_or(message);
    }
    for path in leaves {
        let mut candidate = skeleton.clone();
        if let Some(value) = get_path(table, &path) {
            set_path(&mut candidate, &path, value.clone());
        }
        if let Err(e) = candidate.try_into::<Config>() {
            let value = get_path(table, &path).map_or(String::new(), |v| format!(" = {v}"));
            return format!(
                "[{}] {}{value}: {}",
                table_name(&path),
                key_name(&path),
                e.message().trim()
            );
        }
    }
    error.message().trim().to_string()
}

/// One step of a path into a TOML document.
#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

/// Every path to a value that is not a table, an array of tables or a `type` key.
fn leaf_paths(table: &toml::Table, prefix: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    for (key, value) in table {
        prefix.push(Step::Key(key.clone()));
        match value {
            toml::Value::Table(inner) => leaf_paths(inner, prefix, out),
            toml::Value::Array(items)
                if items.iter().all(toml::Value::is_table) && !items.is_empty() =>
            {
                for (i, item) in items.iter().enumerate() {
                    prefix.push(Step::Index(i));
                    if let toml::Value::Table(inner) = item {
                        leaf_paths(inner, prefix, out);
                    }
                    prefix.pop();
                }
            }
            _ if key == "type" => {}
            _ => out.push(prefix.clone()),
        }
        prefix.pop();
    }
}

/// Every path to a `type` key.
fn type_paths(table: &toml::Table, prefix: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    for (key, value) in table {
        prefix.push(Step::Key(key.clone()));
        match value {
            toml::Value::Table(inner) => type_paths(inner, prefix, out),
            toml::Value::Array(items) => {
                for (i, item) in items.iter().enumerate() {
                    if let toml::Value::Table(inner) = item {
                        prefix.push(Step::Index(i));
                        type_paths(inner, prefix, out);
                        prefix.pop();
                    }
                }
            }
            _ if key == "type" => out.push(prefix.clone()),
            _ => {}
        }
        prefix.pop();
    }
}

/// The tables of `table` with their `type` keys only (arrays of tables keep their length).
fn only_types(table: &toml::Table) -> toml::Table {
    let mut out = toml::Table::new();
    for (key, value) in table {
        match value {
            toml::Value::Table(inner) => {
                out.insert(key.clone(), toml::Value::Table(only_types(inner)));
            }
            toml::Value::Array(items)
                if items.iter().all(toml::Value::is_table) && !items.is_empty() =>
            {
                let items = items
                    .iter()
                    .map(|item| match item {
                        toml::Value::Table(inner) => toml::Value::Table(only_types(inner)),
                        other => other.clone(),
                    })
                    .collect();
                out.insert(key.clone(), toml::Value::Array(items));
            }
            _ if key == "type" => {
                out.insert(key.clone(), value.clone());
            }
            _ => {}
        }
    }
    out
}

fn get_path<'a>(table: &'a toml::Table, path: &[Step]) -> Option<&'a toml::Value> {
    let (first, rest) = path.split_first()?;
    let Step::Key(key) = first else {
        return None;
    };
    let mut value = table.get(key)?;
    for step in rest {
        value = match step {
            Step::Key(key) => value.as_table()?.get(key)?,
            Step::Index(i) => value.as_array()?.get(*i)?,
        };
    }
    Some(value)
}

fn set_path(root: &mut toml::Value, path: &[Step], leaf: toml::Value) {
    let Some((last, parents)) = path.split_last() else {
        return;
    };
    let mut current = root;
    for step in parents {
        current = match (step, current) {
            (Step::Key(key), toml::Value::Table(table)) => table
                .entry(key.clone())
                .or_insert_with(|| toml::Value::Table(toml::Table::new())),
            (Step::Index(i), toml::Value::Array(items)) => match items.get_mut(*i) {
                Some(item) => item,
                None => return,
            },
            _ => return,
        };
    }
    if let (Step::Key(key), toml::Value::Table(table)) = (last, current) {
        table.insert(key.clone(), leaf);
    }
}

/// `estimator`, `data.victoria_park`, `postprocess` (1-based index kept apart).
fn table_name(path: &[Step]) -> String {
    let parents = &path[..path.len().saturating_sub(1)];
    let mut name = String::new();
    for step in parents {
        match step {
            Step::Key(key) => {
                if !name.is_empty() {
                    name.push('.');
                }
                name.push_str(key);
            }
            Step::Index(i) => name.push_str(&format!("#{}", i + 1)),
        }
    }
    name
}

fn key_name(path: &[Step]) -> String {
    match path.last() {
        Some(Step::Key(key)) => key.clone(),
        Some(Step::Index(i)) => format!("#{}", i + 1),
        None => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_of_the_wrong_type_names_its_table_and_key() {
        let cases = [
            (
                "[estimator]\ntype = \"ekf\"\nconfirm_after = -1\n",
                "[estimator] confirm_after = -1",
            ),
            (
                "[estimator]\ntype = \"fastslam\"\nparticles = 1e11\n",
                "[estimator] particles = 1",
            ),
            ("[data]\nseed = \"one\"\n", "[data] seed = \"one\""),
            (
                "[[postprocess]]\ntype = \"em-polygon\"\n[[postprocess]]\ntype = \"em-polygon\"\nposes = 3\n",
                "[postprocess#2] poses = 3",
            ),
            // An unknown `type` is named, not the first other key.
            (
                "[data.laser_odometry]\nheading_starts = 2\n[estimator]\ntype = \"dead_reckoning\"\n",
                "[estimator] type = \"dead_reckoning\": unknown variant",
            ),
            (
                "[[postprocess]]\ntype = \"em-polygon\"\n[[postprocess]]\ntype = \"relocalise\"\n",
                "[postprocess#2] type = \"relocalise\"",
            ),
        ];
        for (text, expected) in cases {
            let error = Config::from_toml(text, "t.toml").unwrap_err().to_string();
            assert!(error.contains(expected), "{error}\nvs {expected}");
        }
    }

    #[test]
    fn output_keys_are_checked_and_unknown_ones_refused() {
        let config = Config::from_toml(
            "[output]\ngrid = true\ngrid_resolution = 0.1\ng2o = true\nmcap = true\n",
            "t",
        )
        .unwrap();
        assert!(config.output.grid && config.output.g2o && config.output.mcap);
        assert_eq!(config.output.grid_resolution, 0.1);
        let error = Config::from_toml("[output]\ngird = true\n", "t")
            .unwrap_err()
            .to_string();
        assert!(error.contains("gird"), "{error}");
        let config = Config::from_toml("[output]\ngrid_resolution = -0.05\n", "t").unwrap();
        let error = config.validate().unwrap_err().to_string();
        assert!(error.contains("grid_resolution = -0.05"), "{error}");
        let config = Config::from_toml("[output]\nmcap_map_interval_s = nan\n", "t").unwrap();
        assert!(config.validate().is_err());
    }
}
