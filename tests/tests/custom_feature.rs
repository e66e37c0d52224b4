//! A feature type defined outside `slam-features` (the doorway of `slam-examples`) lives in
//! one map with the built-in features, runs through the generic chain, and serializes.

use slam_core::nalgebra::{DVector, Vector2, Vector3};
use slam_core::{Feature, FeatureMap, Pose2, Pose3, RowOwner};
use slam_examples::{Door, DoorObservation};
use slam_features::{HLine, Point, Pole, Wall};

fn mixed_map() -> FeatureMap {
    let mut map = FeatureMap::new();
    let features: Vec<Box<dyn Feature>> = vec![
        Box::new(Wall::new(Vector2::new(0.0, 0.0), Vector2::new(5.0, 0.0)).unwrap()),
        Box::new(HLine::new(Vector3::new(0.0, 1.0, 2.5), Vector3::new(4.0, 1.0, 2.5)).unwrap()),
        Box::new(Pole::full(0.2, Vector2::new(3.0, 3.0)).unwrap()),
        Box::new(Point::full(Vector3::new(2.0, 2.0, 2.6)).unwrap()),
        Box::new(Door::new(Vector2::new(3.0, 0.5), Vector2::new(3.0, -0.5)).unwrap()),
    ];
    for feature in features {
        map.insert(feature).unwrap();
    }
    map
}

#[test]
fn a_door_runs_through_the_generic_chain_and_map() {
    let mut map = mixed_map();
    let (door_id, _) = map.iter().find(|(_, f)| f.kind() == "door").unwrap();
    let observation = DoorObservation::new([3.05, 0.17, 3.02, -0.16], 0.02, 0.01).unwrap();
    let robot = Pose2::new(0.0, 0.0, 0.0);
    // A tentative door is associated but has no rows yet.
    let lin = map
        .linearize(door_id, &observation, &robot, &Pose3::identity())
        .unwrap();
    assert!(lin.columns.is_empty());
    let door = map.get(door_id).unwrap();
    let x_o = door.coordinates().clone(); // robot at the origin: sensor frame = map frame
    let revealed =
        slam_core::DynMeasurementModel::revealed_subspaces_dyn(&observation, door, &x_o).unwrap();
    assert_eq!(revealed, vec!["centre"]);
    let growth = map.activate(door_id, "centre").unwrap();
    assert_eq!(growth.rows, 0..2);
    let lin = map
        .linearize(door_id, &observation, &robot, &Pose3::identity())
        .unwrap();
    assert_eq!(lin.columns.len(), 1);
    assert_eq!(lin.columns[0].0, RowOwner::Feature(door_id));
    // A step against the innovation moves the door's centre, as an estimator would.
    let step = -lin.measurement.eta.clone();
    map.apply(&[(
        RowOwner::Feature(door_id),
        DVector::from_column_slice(step.as_slice()),
    )])
    .unwrap();
    let after = map
        .linearize(door_id, &observation, &robot, &Pose3::identity())
        .unwrap();
    assert!(after.measurement.eta.norm() < 1e-9);
}

#[test]
fn a_mixed_map_round_trips_through_json() {
    let map = mixed_map();
    let json = serde_json::to_string_pretty(&map).unwrap();
    for kind in ["\"wall\"", "\"hline\"", "\"pole\"", "\"point\"", "\"door\""] {
        assert!(json.contains(kind), "{kind} missing from {json}");
    }
    let back: FeatureMap = serde_json::from_str(&json).unwrap();
    assert_eq!(serde_json::to_string_pretty(&back).unwrap(), json);
}

#[test]
fn a_feature_from_a_wrong_model_is_a_clear_error() {
    let map = mixed_map();
    let (wall_id, _) = map.iter().find(|(_, f)| f.kind() == "wall").unwrap();
    let observation = DoorObservation::new([3.0, 0.1, 3.0, -0.1], 0.02, 0.01).unwrap();
    let error = map
        .linearize(
            wall_id,
            &observation,
            &Pose2::identity(),
            &Pose3::identity(),
        )
        .unwrap_err();
    assert!(
        error.to_string().contains("applied to a `wall` feature"),
        "{error}"
    );
}
