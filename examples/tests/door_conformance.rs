//! The doorway, a feature defined outside `slam-features`, passes the conformance suite.

use proptest::prelude::*;
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::testing::{ConformanceParams, assert_measurement_conforms, check_feature};
use slam_core::{Feature, Pose2, Pose3, test_feature_conformance};
use slam_examples::{Door, DoorObservation};

test_feature_conformance!(
    door_conforms,
    Door::new(Vector2::new(3.0, 1.0), Vector2::new(3.2, 0.1)).unwrap()
);

#[test]
fn door_observation_conforms_at_every_dimension() {
    let observation = DoorObservation::new([3.1, 0.35, 2.9, -0.2], 0.02, 0.01).unwrap();
    let robot = Pose2::new(0.3, -0.2, 0.1);
    let mount = Pose3::new(Vector3::new(0.15, 0.0, 0.4), 0.05, 0.02, -0.01);
    let mut door = Door::new(Vector2::new(3.0, 1.2), Vector2::new(3.1, 0.2)).unwrap();
    assert_measurement_conforms(&observation, &door, &robot, &mount);
    door.activate("centre").unwrap();
    assert_measurement_conforms(&observation, &door, &robot, &mount);
    door.activate("shape").unwrap();
    assert_measurement_conforms(&observation, &door, &robot, &mount);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn doors_conform_or_refuse(x in -30.0..30.0f64, y in -30.0..30.0f64, w in 0.0..3.0f64, a in -3.1..3.1f64) {
        let left = Vector2::new(x, y);
        let right = left + w * Vector2::new(a.cos(), a.sin());
        match Door::new(left, right) {
            Ok(door) => {
                check_feature(&door, &ConformanceParams::default())
                    .map_err(|f| TestCaseError::fail(f.to_string()))?;
            }
            Err(_) => prop_assert!(w < Door::MIN_WIDTH),
        }
    }
}
