//! An estimator registered outside the framework (dead reckoning that also places the
//! landmarks the data name, as features of a type of its own) runs from a TOML string by its
//! registered name, and its features are scored and drawn like built-in ones.

mod common;

use std::collections::{BTreeMap, HashMap};

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Vector2, Vector3};
use slam_core::{
    CoordBlock, Coordinates, Error, Estimator, Feature, FeatureId, FeatureMap, Growth, Ink, Mark,
    MotionModel, Observation, Pose2, RobotPose, RowOwner, Shape, Sketch, Subspace, UpdateReport,
};
use slam_runtime::{EstimatorConfig, RuntimeError, Start};
// The registrations below go through the runtime's re-export of typetag. The macro's
// expansion names the crate `typetag`, so the re-export must be in scope under that name:
// `#[slam_runtime::typetag::serde]` alone does not compile without a typetag dependency.
use slam_runtime::typetag;
use slam_sensors::models::RangeBearing;

use common::{TempWorld, parse_error, run_toml, short_rb2d_circle};

const NAME: &str = "test-sighting-odometry";
const XY: Subspace = Subspace {
    name: "xy",
    rows: 2,
    description: "x and y of the beacon",
};

/// A floor beacon: one 2-D point; M-space 0 while tentative, 2 once placed.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Beacon {
    coordinates: Coordinates,
    placed: bool,
}

impl Beacon {
    fn at(position: Vector2<f64>) -> slam_core::Result<Self> {
        Ok(Beacon {
            coordinates: Coordinates::new(vec![CoordBlock::Point2(position)])?,
            placed: false,
        })
    }

    fn position(&self) -> Vector2<f64> {
        match self.coordinates.blocks() {
            [CoordBlock::Point2(p)] => *p,
            _ => Vector2::new(f64::NAN, f64::NAN),
        }
    }
}

#[slam_runtime::typetag::serde(name = "test-beacon")]
impl Feature for Beacon {
    fn kind(&self) -> &'static str {
        "test-beacon"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> slam_core::Result<()> {
        if !matches!(coordinates.blocks(), [CoordBlock::Point2(_)]) {
            return Err(Error::InvalidArgument("a beacon is one 2-D point".into()));
        }
        self.coordinates = coordinates;
        Ok(())
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        if self.placed { vec![XY] } else { vec![] }
    }

    fn growth_options(&self) -> Vec<Subspace> {
        if self.placed { vec![] } else { vec![XY] }
    }

    fn activate(&mut self, subspace: &str) -> slam_core::Result<Growth> {
        if self.placed || subspace != XY.name {
            return Err(Error::InvalidArgument(format!(
                "a beacon cannot grow by `{subspace}`"
            )));
        }
        self.placed = true;
        Ok(Growth {
            subspace: XY,
            rows: 0..2,
        })
    }

    fn projection(&self) -> slam_core::Result<DMatrix<f64>> {
        Ok(DMatrix::identity(self.mspace_dim(), 2))
    }

    fn shape(&self) -> Option<Shape> {
        Some(Shape::PlanarPoint {
            position: self.position(),
        })
    }

    fn sketch(&self) -> Sketch {
        Sketch::new("test beacons", Ink::Pole).with(Mark::Circle {
            centre: self.position(),
            radius: 0.3,
            ink: Ink::Pole,
            filled: false,
        })
    }
}

/// The settings: a beacon is placed (confirmed) once its landmark was sighted this often.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct SightingOdometryConfig {
    min_sightings: usize,
}

impl Default for SightingOdometryConfig {
    fn default() -> Self {
        SightingOdometryConfig { min_sightings: 3 }
    }
}

#[slam_runtime::typetag::serde(name = "test-sighting-odometry")]
impl EstimatorConfig for SightingOdometryConfig {
    fn validate(&self) -> slam_runtime::Result<()> {
        if self.min_sightings == 0 {
            return Err(RuntimeError::setting(
                "estimator",
                "test-sighting-odometry: min_sightings must be at least 1",
            ));
        }
        Ok(())
    }

    fn build(&self, start: &Start) -> slam_runtime::Result<Box<dyn Estimator<Pose2>>> {
        Ok(Box::new(SightingOdometry {
            pose: start.pose,
            covariance: start.covariance.clone(),
            min_sightings: self.min_sightings,
            map: FeatureMap::new(),
            beacons: HashMap::new(),
            landmarks: HashMap::new(),
        }))
    }
}

/// Dead reckoning; each range-bearing sighting with a landmark id is placed in the world by
/// the current pose, and the beacon of that landmark sits at the mean of its sightings.
#[derive(Debug)]
struct SightingOdometry {
    pose: Pose2,
    covariance: DMatrix<f64>,
    min_sightings: usize,
    map: FeatureMap,
    /// Landmark id -> (feature, number of sightings, sum of the sighted positions).
    beacons: HashMap<u64, (FeatureId, usize, Vector2<f64>)>,
    /// Feature -> landmark id.
    landmarks: HashMap<FeatureId, u64>,
}

impl SightingOdometry {
    /// Files one sighting of `landmark` at `position`; true when it started a beacon.
    fn sight(&mut self, landmark: u64, position: Vector2<f64>) -> slam_core::Result<bool> {
        let (id, count, sum) = match self.beacons.get(&landmark) {
            Some(&(id, count, sum)) => (id, count + 1, sum + position),
            None => {
                let id = self.map.insert(Box::new(Beacon::at(position)?))?;
                self.landmarks.insert(id, landmark);
                (id, 1, position)
            }
        };
        self.beacons.insert(landmark, (id, count, sum));
        let mut beacon = Beacon::at(sum / count as f64)?;
        beacon.placed = self.map.get(id)?.mspace_dim() > 0;
        self.map.replace(id, Box::new(beacon))?;
        if count == self.min_sightings {
            self.map.activate(id, XY.name)?;
        }
        Ok(count == 1)
    }
}

impl Estimator<Pose2> for SightingOdometry {
    fn name(&self) -> &'static str {
        NAME
    }

    fn predict(&mut self, motion: &dyn MotionModel<Pose2>) -> slam_core::Result<()> {
        let prediction = motion.predict(&self.pose)?;
        self.covariance = prediction.propagate_covariance(&self.covariance)?;
        self.pose = prediction.pose;
        Ok(())
    }

    fn update(&mut self, observations: &[Observation]) -> slam_core::Result<UpdateReport> {
        let mut report = UpdateReport::default();
        for o in observations {
            let rb = o.measurement.as_any().downcast_ref::<RangeBearing>();
            let (Some(landmark), Some(rb)) = (o.landmark_id, rb) else {
                report.rejected += 1;
                continue;
            };
            let (s, c) = rb.bearing.sin_cos();
            let hit = self
                .pose
                .world_from_sensor(&o.robot_from_sensor)
                .transform_point(&Vector3::new(rb.range * c, rb.range * s, 0.0));
            if self.sight(landmark, hit.xy())? {
                report.new_features += 1;
            } else {
                report.associated += 1;
            }
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

fn config_text(world: &TempWorld, estimator: &str) -> String {
    format!("{}\n[estimator]\n{estimator}\n", world.data_table(3))
}

/// How often each landmark is sighted in the world's run with seed 3.
fn sightings(world: &TempWorld) -> BTreeMap<u64, usize> {
    let mut counts = BTreeMap::new();
    for id in world.observation_batches(3).into_iter().flatten() {
        *counts
            .entry(id.expect("rb2d observations carry ids"))
            .or_default() += 1;
    }
    counts
}

#[test]
fn our_estimator_runs_by_its_name_and_is_given_every_observation() {
    let world = short_rb2d_circle(120);
    let (config, output, metrics) = run_toml(&config_text(
        &world,
        &format!("type = \"{NAME}\"\nmin_sightings = 4"),
    ));
    assert_eq!(metrics.estimator, NAME);
    assert_eq!(config.estimator.default_frontend(), "features");
    assert_eq!(metrics.steps, 121);
    // Every observation of the data reached the estimator and was filed: the update
    // reports add up to the observations the simulation made.
    let seen = sightings(&world);
    let total: usize = seen.values().sum();
    let u = metrics.updates;
    assert_eq!(u.rejected, 0, "{u:?}");
    assert_eq!(u.new_features, seen.len(), "{u:?}");
    assert_eq!(u.associated + u.new_features, total, "{u:?}");
    // Landmarks sighted at least 4 times are placed (dimension 2), the others tentative.
    let placed = seen.values().filter(|&&n| n >= 4).count();
    let mut expected = BTreeMap::from([(2, placed)]);
    if placed < seen.len() {
        expected.insert(0, seen.len() - placed);
    }
    assert_eq!(metrics.features.get("test-beacon"), Some(&expected));
    assert!(placed >= 10, "{placed} beacons placed");
    // The poses are dead reckoning's, exactly.
    let (_, baseline, _) = run_toml(&config_text(&world, "type = \"dead-reckoning\""));
    let poses = |o: &slam_runtime::RunOutput| -> Vec<Pose2> {
        o.record.estimates.iter().map(|r| r.pose).collect()
    };
    assert_eq!(poses(&output), poses(&baseline));
    assert_eq!(output.estimator.pose(), baseline.estimator.pose());
}

#[test]
fn its_own_feature_type_is_scored_against_the_data_landmarks() {
    let world = short_rb2d_circle(120);
    let (_, output, metrics) = run_toml(&config_text(&world, &format!("type = \"{NAME}\"")));
    let error = metrics
        .map_error
        .as_ref()
        .unwrap_or_else(|| panic!("no map error: {:?}", metrics.unavailable));
    let seen = sightings(&world);
    let placed: Vec<u64> = seen
        .iter()
        .filter(|&(_, &n)| n >= 3)
        .map(|(&id, _)| id)
        .collect();
    // Every placed beacon, and only those, is compared with its landmark by id.
    assert_eq!(error.count, placed.len());
    assert_eq!(
        error.by_landmark.keys().copied().collect::<Vec<_>>(),
        placed
    );
    assert_eq!(error.by_type.keys().collect::<Vec<_>>(), ["test-beacon"]);
    // Placed by dead reckoning from 0.1 m / 1 degree sightings: within a metre or so.
    assert!(error.rms_m > 0.0 && error.rms_m < 1.0, "{error:?}");
    // Against the true landmark positions by hand: the same errors.
    for (id, feature) in output.estimator.map().iter() {
        let Some(landmark) = output.estimator.landmark_id(id) else {
            panic!("beacon {id:?} has no landmark id");
        };
        let Some(expected) = error.by_landmark.get(&landmark) else {
            continue;
        };
        let truth = output
            .landmarks
            .iter()
            .find(|l| l.id == landmark)
            .unwrap()
            .position;
        let Some(Shape::PlanarPoint { position }) = feature.shape() else {
            panic!("not a planar point: {:?}", feature.shape());
        };
        assert!(((position - truth).norm() - expected).abs() < 1e-9);
    }
}

#[test]
fn its_own_feature_type_is_drawn_and_written_by_the_command() {
    let world = short_rb2d_circle(60);
    let out = tempfile::tempdir().unwrap();
    let text = format!(
        "{}\n[output]\ndir = {}\nplots = true\n",
        config_text(&world, &format!("type = \"{NAME}\"")),
        toml::Value::String(out.path().display().to_string())
    );
    let config = slam_runtime::Config::from_toml(&text, "inline").unwrap();
    let summary = slam_cli::run_config(&config, true).unwrap();
    assert!(summary.contains("61 steps"), "{summary}");
    let svg = std::fs::read_to_string(out.path().join("map.svg")).unwrap();
    let map_json = std::fs::read_to_string(out.path().join("map.json")).unwrap();
    let beacons = map_json.matches("\"test-beacon\"").count();
    assert!(beacons > 0, "{map_json}");
    // The legend counts the placed beacons under the sketch's label.
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("metrics.json")).unwrap())
            .unwrap();
    let placed = metrics["features"]["test-beacon"]["2"].as_u64().unwrap();
    assert!(placed > 0, "{}", metrics["features"]);
    assert!(
        svg.contains(&format!("{placed} test beacons")),
        "legend entry `{placed} test beacons` missing from map.svg"
    );
}

#[test]
fn an_unknown_estimator_or_setting_is_an_error_naming_it() {
    let error = parse_error("[estimator]\ntype = \"no-such-estimator\"\n");
    assert!(error.contains("no-such-estimator"), "{error}");
    let error = parse_error(&format!(
        "[estimator]\ntype = \"{NAME}\"\nmin_sighting = 2\n"
    ));
    assert!(error.contains("min_sighting"), "{error}");
}

#[test]
fn its_settings_are_checked_before_the_data_are_read() {
    let text = format!(
        "[data]\nspec = \"world:/no/such/world.toml\"\n[estimator]\ntype = \"{NAME}\"\n\
         min_sightings = 0\n"
    );
    let config = slam_runtime::Config::from_toml(&text, "inline").unwrap();
    let error = slam_runtime::run(&config, &mut ())
        .err()
        .expect("the run fails");
    assert!(error.to_string().contains("min_sightings"), "{error}");
}
