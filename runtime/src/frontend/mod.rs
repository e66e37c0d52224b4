//! Front-ends: raw sensor frames in, observations of the map's feature types out.
//!
//! A [`Frontend`] turns each event of a dataset (a laser scan, a camera image, observations
//! the data give) into the observations its estimator takes. Front-ends are found by name
//! ([`FrontendConfig`], the `type` of the config's `[frontend]` table; when it names none,
//! the estimator's [`crate::EstimatorConfig::default_frontend`]):
//!
//! - `"features"` ([`FeaturesFrontendConfig`]): laser scans to walls and poles, ceiling
//!   images to lines and lamps, and the observations the data give;
//! - `"scan-points"` ([`ScanPointsConfig`]): every valid laser return as a
//!   [`slam_sensors::models::LinePoint`] (IPSLAM's input);
//! - `"none"` ([`NoFrontendConfig`]): nothing (dead reckoning).
//!
//! How walls are represented is itself found by name ([`WallModel`], the `"features"`
//! front-end's `wall_representation`).

mod features;
mod points;
mod prior;
mod walls;

use std::collections::BTreeMap;
use std::fmt::Debug;

use serde::{Deserialize, Serialize};
use slam_core::Observation;
use slam_sensors::Event;

use crate::error::Result;

pub use features::{FeaturesFrontendConfig, PriorSegmentationConfig, WallSegmentation};
pub use points::ScanPointsConfig;
pub use prior::{load_prior, prior_library};
pub use walls::{MspaceWalls, WallModel};

/// What a front-end may know of the data before it starts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SensorInfo {
    /// The range deviation of a simulated laser, m (real logs do not say).
    pub laser_sigma_range: Option<f64>,
    /// Whether the data hold raw scans or images (else only ready-made observations).
    pub raw_sensors: bool,
}

/// Counts of what a front-end produced and dropped, by name.
pub type FrontendCounts = BTreeMap<String, usize>;

/// A front-end at work: one event in, the observations for the estimator out.
pub trait Frontend: Send {
    /// The observations of one event (none for an event it does not handle).
    fn observe(&mut self, event: &Event) -> Result<Vec<Observation>>;

    /// What it produced and dropped so far.
    fn counts(&self) -> FrontendCounts;
}

/// A front-end's settings, registered by name: what `[frontend] type = "..."` selects.
#[typetag::serde(tag = "type")]
pub trait FrontendConfig: Debug + Send + Sync + dyn_clone::DynClone {
    /// Checks the settings before any data is read (e.g. that a structure prior loads).
    fn validate(&self) -> Result<()> {
        Ok(())
    }

    /// The front-end, for data described by `sensors`.
    fn build(&self, sensors: &SensorInfo) -> Result<Box<dyn Frontend>>;
}

dyn_clone::clone_trait_object!(FrontendConfig);

/// The `"none"` front-end: no observation at all.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoFrontendConfig {}

#[typetag::serde(name = "none")]
impl FrontendConfig for NoFrontendConfig {
    fn build(&self, _: &SensorInfo) -> Result<Box<dyn Frontend>> {
        Ok(Box::new(NoFrontend))
    }
}

/// A front-end that observes nothing.
struct NoFrontend;

impl Frontend for NoFrontend {
    fn observe(&mut self, _: &Event) -> Result<Vec<Observation>> {
        Ok(Vec::new())
    }

    fn counts(&self) -> FrontendCounts {
        FrontendCounts::new()
    }
}
