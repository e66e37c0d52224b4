//! Your own estimator, run from a TOML file through the `slam` command's own code path.
//!
//! `first-sighting` integrates the odometry and places every landmark where it is first seen:
//! the mapping baseline an EKF improves on. It is registered by name (`typetag`), so `slam
//! run` builds it from `[estimator] type = "first-sighting"`, runs it on the simulated rb2d
//! circle world, scores its map and draws it, with no line of the framework changed. A
//! program of your own does the same by linking its estimator crate and calling
//! `slam_cli::main_with` (or `slam_cli::command`).
//!
//! `cargo run --release -p slam-examples --example own_estimator`

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::DMatrix;
use slam_core::{
    Estimator, FeatureId, FeatureMap, MotionModel, Observation, Pose2, Result, RobotPose, RowOwner,
    UpdateReport,
};
use slam_runtime::{EstimatorConfig, Start};

/// The settings of `first-sighting` (it has none).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FirstSightingParams {}

#[typetag::serde(name = "first-sighting")]
impl EstimatorConfig for FirstSightingParams {
    fn validate(&self) -> slam_runtime::Result<()> {
        Ok(())
    }

    fn build(&self, start: &Start) -> slam_runtime::Result<Box<dyn Estimator<Pose2>>> {
        Ok(Box::new(FirstSighting {
            pose: start.pose,
            covariance: start.covariance.clone(),
            map: FeatureMap::new(),
            landmarks: BTreeMap::new(),
            seen: BTreeSet::new(),
        }))
    }
}

/// Dead reckoning plus a map of first sightings of known landmarks.
#[derive(Debug)]
struct FirstSighting {
    pose: Pose2,
    covariance: DMatrix<f64>,
    map: FeatureMap,
    landmarks: BTreeMap<FeatureId, u64>,
    seen: BTreeSet<u64>,
}

impl Estimator<Pose2> for FirstSighting {
    fn name(&self) -> &'static str {
        "first-sighting"
    }

    fn predict(&mut self, motion: &dyn MotionModel<Pose2>) -> Result<()> {
        let prediction = motion.predict(&self.pose)?;
        self.covariance = prediction.propagate_covariance(&self.covariance)?;
        self.pose = prediction.pose;
        Ok(())
    }

    /// A landmark seen for the first time is placed by its measurement alone, with every
    /// subspace the measurement reveals; later sightings change nothing.
    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        let mut report = UpdateReport::default();
        for o in observations {
            let Some(landmark) = o.landmark_id.filter(|id| !self.seen.contains(id)) else {
                report.rejected += 1;
                continue;
            };
            let world_from_sensor = self.pose.world_from_sensor(&o.robot_from_sensor);
            let Some(mut feature) = o.measurement.initial_feature_dyn(&world_from_sensor)? else {
                report.skipped.count("no feature placed by one measurement");
                continue;
            };
            let x_o = slam_core::MapToSensor::new(&world_from_sensor)?
                .transform(feature.coordinates())?;
            for subspace in o
                .measurement
                .revealed_subspaces_dyn(feature.as_ref(), &x_o)?
            {
                feature.activate(subspace)?;
            }
            let id = self.map.insert(feature)?;
            self.landmarks.insert(id, landmark);
            self.seen.insert(landmark);
            report.new_features += 1;
        }
        Ok(report)
    }

    fn pose(&self) -> Pose2 {
        self.pose
    }

    fn pose_covariance(&self) -> DMatrix<f64> {
        self.covariance.clone()
    }

    fn map(&self) -> &FeatureMap {
        &self.map
    }

    fn row_covariance(&self, _: RowOwner) -> Option<DMatrix<f64>> {
        None
    }

    fn landmark_id(&self, id: FeatureId) -> Option<u64> {
        self.landmarks.get(&id).copied()
    }
}

fn main() -> std::result::Result<(), Box<dyn std::error::Error>> {
    let world = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
    let dir = std::env::temp_dir().join(format!("slam-own-estimator-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let config = dir.join("first-sighting.toml");
    std::fs::write(
        &config,
        format!(
            "[data]\nspec = \"world:{}\"\n[estimator]\ntype = \"first-sighting\"\n\
             [output]\ndir = \"{}\"\n",
            world.display(),
            dir.join("out").display()
        ),
    )?;
    // The `slam run` command line, as a user would type it.
    let summary = slam_cli::command(["slam", "run", &config.display().to_string(), "--quiet"])?;
    println!("{summary}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/metrics.json"))?)?;
    println!(
        "first-sighting: {} landmarks, map error {} m; the figure is {}",
        metrics["map_error"]["count"],
        metrics["map_error_m"],
        dir.join("out/map.png").display()
    );
    assert_eq!(metrics["estimator"], "first-sighting");
    assert!(metrics["map_error_m"].as_f64().is_some_and(|e| e < 1.0));
    Ok(())
}
