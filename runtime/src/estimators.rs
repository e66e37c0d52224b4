//! Estimators found by name: the `type` of the config's `[estimator]` table names an
//! [`EstimatorConfig`] registered through `typetag`, and the other keys are its settings.
//!
//! Registered here: `"ekf"` ([`slam_estimators::EkfParams`]), `"fastslam"`
//! ([`slam_estimators::FastSlamParams`]), `"ipslam"` ([`slam_estimators::IpslamParams`]) and
//! `"dead-reckoning"` ([`slam_estimators::DeadReckoningParams`]). A crate of its own
//! registers another with `#[typetag::serde(name = "...")] impl EstimatorConfig for ...`;
//! the `slam` command, linked with that crate, runs it from the TOML word.
//!
//! ```
//! use slam_runtime::{Config, EstimatorConfig};
//! let config = Config::from_toml("[estimator]\ntype = \"fastslam\"\nparticles = 10\n", "inline")?;
//! assert_eq!(config.estimator.default_frontend(), "features");
//! # Ok::<(), slam_runtime::RuntimeError>(())
//! ```

use std::fmt::Debug;
use std::sync::Arc;

use slam_core::nalgebra::{DMatrix, Vector2};
use slam_core::{Estimator, Feature, Observation, Pose2};
use slam_estimators::{
    Cluster, DeadReckoning, DeadReckoningParams, Ekf, EkfParams, FastSlam, FastSlamParams, Ipslam,
    IpslamParams, LineMapTypes,
};
use slam_features::PpcaLine;
use slam_sensors::models::LinePoint;

use crate::error::Result;

/// Where an estimator starts: the first pose of the data and its covariance
/// (`(x, y, heading)`, 3 x 3).
#[derive(Clone, Debug, PartialEq)]
pub struct Start {
    /// The start pose.
    pub pose: Pose2,
    /// Its covariance.
    pub covariance: DMatrix<f64>,
}

/// An estimator's settings, registered by name: what `[estimator] type = "..."` selects.
#[typetag::serde(tag = "type")]
pub trait EstimatorConfig: Debug + Send + Sync + dyn_clone::DynClone {
    /// Checks the settings before any data is read.
    fn validate(&self) -> Result<()>;

    /// The estimator, starting at `start`.
    fn build(&self, start: &Start) -> Result<Box<dyn Estimator<Pose2>>>;

    /// The registered front-end whose observations the estimator takes when the config's
    /// `[frontend]` table names no `type` (default: `"features"`, the laser and camera
    /// feature extractors).
    fn default_frontend(&self) -> &'static str {
        "features"
    }
}

dyn_clone::clone_trait_object!(EstimatorConfig);

#[typetag::serde(name = "ekf")]
impl EstimatorConfig for EkfParams {
    fn validate(&self) -> Result<()> {
        Ok(EkfParams::validate(self)?)
    }

    fn build(&self, start: &Start) -> Result<Box<dyn Estimator<Pose2>>> {
        Ok(Box::new(Ekf::new(
            start.pose,
            start.covariance.clone(),
            self.clone(),
        )?))
    }
}

#[typetag::serde(name = "fastslam")]
impl EstimatorConfig for FastSlamParams {
    fn validate(&self) -> Result<()> {
        Ok(FastSlamParams::validate(self)?)
    }

    fn build(&self, start: &Start) -> Result<Box<dyn Estimator<Pose2>>> {
        Ok(Box::new(FastSlam::new(
            start.pose,
            start.covariance.clone(),
            self.clone(),
        )?))
    }
}

/// IPSLAM's line maps as [`PpcaLine`]s, its scan points as [`LinePoint`] observations (the
/// `"scan-points"` front-end).
#[derive(Debug)]
struct PpcaLines;

impl LineMapTypes for PpcaLines {
    fn cluster_feature(&self, c: &Cluster) -> slam_core::Result<Box<dyn Feature>> {
        let line =
            PpcaLine::from_cluster(c.mean, c.direction, c.principal_variance, c.sigma2, c.count)?;
        Ok(Box::new(line))
    }

    fn scan_point(&self, observation: &Observation) -> Option<Vector2<f64>> {
        LinePoint::point_of(observation)
    }
}

#[typetag::serde(name = "ipslam")]
impl EstimatorConfig for IpslamParams {
    fn validate(&self) -> Result<()> {
        Ok(IpslamParams::validate(self)?)
    }

    fn build(&self, start: &Start) -> Result<Box<dyn Estimator<Pose2>>> {
        Ok(Box::new(Ipslam::new(
            start.pose,
            start.covariance.clone(),
            self.clone(),
            Arc::new(PpcaLines),
        )?))
    }

    /// IPSLAM builds its map from the scan's returns.
    fn default_frontend(&self) -> &'static str {
        "scan-points"
    }
}

#[typetag::serde(name = "dead-reckoning")]
impl EstimatorConfig for DeadReckoningParams {
    fn validate(&self) -> Result<()> {
        Ok(())
    }

    fn build(&self, start: &Start) -> Result<Box<dyn Estimator<Pose2>>> {
        Ok(Box::new(DeadReckoning::new(
            start.pose,
            start.covariance.clone(),
        )?))
    }

    /// Dead reckoning uses no observation: nothing is extracted.
    fn default_frontend(&self) -> &'static str {
        "none"
    }
}
