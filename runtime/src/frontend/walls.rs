//! How an extracted wall segment becomes an observation of a wall feature, found by name:
//! `wall_representation = "mspace"` ([`MspaceWalls`], `slam_features::Wall`), or a
//! representation registered elsewhere (`"endpoints"`, the naive walls of `slam-examples`).
//! The key takes the name alone or a table with `type` and the representation's settings.

use std::fmt::Debug;

use serde::{Deserialize, Deserializer, Serialize};
use slam_core::DynMeasurementModel;
use slam_sensors::extract::ExtractedSegment;

/// A wall representation, registered by name: the observation of one extracted segment.
#[typetag::serde(tag = "type")]
pub trait WallModel: Debug + Send + Sync + dyn_clone::DynClone {
    /// Checks the settings before any data is read (default: nothing to check).
    fn validate(&self) -> slam_core::Result<()> {
        Ok(())
    }

    /// The observation of `segment` (sensor frame; its covariance already as the front-end
    /// wants it), for a laser of range deviation `sigma_range`, m.
    fn observation(
        &self,
        segment: &ExtractedSegment,
        sigma_range: f64,
    ) -> slam_core::Result<Box<dyn DynMeasurementModel>>;
}

dyn_clone::clone_trait_object!(WallModel);

/// M-space walls (`slam_features::Wall`): dimensions 0, 2, 3, 4 and shared corners.
///
/// `wall_representation = "mspace"`, or a table with its settings:
///
/// ```
/// use slam_runtime::Config;
/// let text = "[frontend.wall_representation]\ntype = \"mspace\"\nmax_gap = 2.0\n";
/// let config = Config::from_toml(text, "inline")?;
/// # let _ = config;
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MspaceWalls {
    /// Largest gap between a wall's open end and a segment still taken as that wall, m
    /// (default [`slam_sensors::models::MAX_GAP`], 0.5: a doorway separates two walls; real
    /// buildings do better with 2, a corridor wall kept whole across its doors).
    pub max_gap: f64,
}

impl Default for MspaceWalls {
    fn default() -> Self {
        MspaceWalls {
            max_gap: slam_sensors::models::MAX_GAP,
        }
    }
}

#[typetag::serde(name = "mspace")]
impl WallModel for MspaceWalls {
    fn observation(
        &self,
        segment: &ExtractedSegment,
        sigma_range: f64,
    ) -> slam_core::Result<Box<dyn DynMeasurementModel>> {
        Ok(Box::new(
            segment
                .to_observation(sigma_range)?
                .with_max_gap(self.max_gap)?,
        ))
    }

    fn validate(&self) -> slam_core::Result<()> {
        if self.max_gap.is_finite() && self.max_gap >= 0.0 {
            Ok(())
        } else {
            Err(slam_core::Error::InvalidArgument(format!(
                "max_gap must be finite and at least 0, got {}",
                self.max_gap
            )))
        }
    }
}

/// Deserializes a registered value from its name alone (`"mspace"`) or from a table with
/// `type` and its settings.
pub(crate) fn by_name<'de, D>(deserializer: D) -> Result<Box<dyn WallModel>, D::Error>
where
    D: Deserializer<'de>,
{
    let value = toml::Value::deserialize(deserializer)?;
    let table = match value {
        toml::Value::String(name) => {
            let mut table = toml::Table::new();
            table.insert("type".into(), toml::Value::String(name));
            table
        }
        toml::Value::Table(table) => table,
        other => {
            return Err(serde::de::Error::custom(format!(
                "a wall representation is a name or a table with `type`, not {other}"
            )));
        }
    };
    Box::<dyn WallModel>::deserialize(toml::Value::Table(table)).map_err(serde::de::Error::custom)
}
