//! Post-processing stages: work done after (and while) an estimator runs, on what the run
//! produced. A stage watches the session as an [`Observer`] (keeping what it needs, e.g. the
//! scans) and finishes with the run's poses ([`PostProcess::finish`]).
//!
//! Stages are found by name ([`PostProcessConfig`], the `type` of each `[[postprocess]]`
//! table): `"em-polygon"` ([`EmPolygonConfig`]), the polygonal approximation of the scans
//! registered by the estimated or the given poses; `"relocalize"` ([`RelocalizeConfig`]),
//! every scan placed again against the final wall map.

mod chain;
mod em_polygon;
mod relocalize;
mod see_through;

use std::fmt::Debug;

use slam_core::nalgebra::Vector2;
use slam_core::{Estimator, FeatureMap, Pose2};

use crate::error::Result;
use crate::record::Recorder;
use crate::session::Observer;

pub use em_polygon::{EmPolygonConfig, PoseSource};
pub use relocalize::RelocalizeConfig;

/// What a stage may read of a finished run.
pub struct FinishedRun<'a> {
    /// The data's name.
    pub name: &'a str,
    /// The record of the run (estimates, truth, GPS fixes).
    pub record: &'a Recorder,
    /// The estimator at the end.
    pub estimator: &'a dyn Estimator<Pose2>,
    /// The path the estimator's map belongs to, where it is not the estimates' (a particle
    /// filter's best particle).
    pub map_path: Option<&'a [(f64, Pose2)]>,
}

impl FinishedRun<'_> {
    /// The path the map belongs to: the map path where there is one, else the estimates.
    pub fn map_poses(&self) -> Vec<(f64, Pose2)> {
        self.record.map_poses(self.map_path)
    }
}

/// What a stage produced: a map to write and draw like an estimator's, the points and poses
/// it used, its own metrics and a one-line summary.
#[derive(Debug)]
pub struct PostProcessOutput {
    /// The stage's name (its outputs go to a folder of that name).
    pub name: String,
    /// Its map.
    pub map: FeatureMap,
    /// Points to draw under the map (e.g. registered scan points), world frame, m.
    pub points: Vec<Vector2<f64>>,
    /// The poses it used.
    pub path: Vec<(f64, Pose2)>,
    /// Its figures.
    pub metrics: serde_json::Value,
    /// One line for the run's summary.
    pub summary: String,
}

/// A stage at work.
pub trait PostProcess: Observer + Send {
    /// Finishes the stage with the finished run.
    fn finish(self: Box<Self>, run: &FinishedRun<'_>) -> Result<PostProcessOutput>;
}

/// A stage's settings, registered by name: what `[[postprocess]] type = "..."` selects.
#[typetag::serde(tag = "type")]
pub trait PostProcessConfig: Debug + Send + Sync + dyn_clone::DynClone {
    /// Checks the settings before any data is read (default: nothing to check).
    fn validate(&self) -> Result<()> {
        Ok(())
    }

    /// The stage, ready to watch a session.
    fn build(&self) -> Result<Box<dyn PostProcess>>;
}

dyn_clone::clone_trait_object!(PostProcessConfig);
