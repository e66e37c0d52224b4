//! The run configuration (TOML). Every table and key is optional; an unknown key is an error
//! that names it.
//!
//! ```toml
//! [data]
//! spec = "sim"            # sim, world:FILE, carmen:FILE, victoria-park:DIR, mrclam:DIR[:ROBOT], rb2d:FILE
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
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            dir: PathBuf::from("slam-out"),
            plots: true,
        }
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
    /// Parses a TOML configuration; unknown keys and names are errors naming them.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self> {
        toml::from_str(text).map_err(|e| RuntimeError::config(origin, e.to_string()))
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
        self.estimator.validate()?;
        self.frontend.validate()?;
        for stage in &self.postprocess {
            stage.validate()?;
        }
        Ok(())
    }
}
