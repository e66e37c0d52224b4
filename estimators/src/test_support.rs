//! Observations the unit tests of several estimators build alike.

use slam_core::nalgebra::{Matrix2, Vector2};
use slam_core::{Observation, Pose3};
use slam_sensors::models::WallObservation;
use std::sync::Arc;

/// A wall seen from the origin along `y = offset`, from `x = a` to `x = b`.
pub(crate) fn wall_sighting(offset: f64, a: f64, b: f64) -> Observation {
    wall_sighting_with(offset, a, b, Matrix2::new(1e-4, 0.0, 0.0, 4e-4))
}

/// [`wall_sighting`] with the segment's covariance `covariance`.
pub(crate) fn wall_sighting_with(
    offset: f64,
    a: f64,
    b: f64,
    covariance: Matrix2<f64>,
) -> Observation {
    segment_sighting(
        Vector2::new(a, offset),
        Vector2::new(b, offset),
        covariance,
        [false, false],
    )
}

/// A wall seen from the origin from `a` to `b` with the segment's covariance `covariance`,
/// its ends real (where a corner can form) as `real` says.
pub(crate) fn segment_sighting(
    a: Vector2<f64>,
    b: Vector2<f64>,
    covariance: Matrix2<f64>,
    real: [bool; 2],
) -> Observation {
    let measurement = WallObservation::from_segment(a, b, covariance, real, [0.05, 0.05]).unwrap();
    Observation {
        robot_from_sensor: Pose3::identity(),
        measurement: Arc::new(measurement),
        landmark_id: None,
    }
}
