//! Setup shared by the range-bearing benches (`ekf_update`, `fastslam`): point landmarks on
//! a golden-angle spiral around a robot that stands still at the origin, observed with small
//! deterministic noise.

use slam_core::{Observation, Pose3};
use slam_sensors::models::RangeBearing;
use slam_sensors::odometry::{Integration, Unicycle};
use std::sync::Arc;

/// Observations per timed update.
pub const PER_UPDATE: usize = 16;
/// Measurement noise: range (m) and bearing (deg).
pub const SIGMA_RANGE: f64 = 0.1;
pub const SIGMA_BEARING_DEG: f64 = 1.0;

/// A deterministic uniform number in `[-1, 1)` (splitmix64), for reproducible noise.
pub fn noise(seed: u64) -> f64 {
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Landmark `i` of `n`: a golden-angle spiral around the robot (at the origin), ranges
/// from 2 m to 20 m, returned as the measured range and bearing.
fn landmark(i: usize, n: usize) -> (f64, f64) {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let range = 2.0 + 18.0 * ((i as f64 + 0.5) / n as f64).sqrt();
    (range, i as f64 * golden)
}

/// One observation of landmark `i` of `n`, off by up to `noise_scale` standard deviations
/// of deterministic noise (`draw` varies it), with the landmark id `landmark_id`.
pub fn observation(
    i: usize,
    n: usize,
    draw: u64,
    noise_scale: f64,
    landmark_id: Option<u64>,
) -> Observation {
    let (range, bearing) = landmark(i, n);
    let sigma_bearing = SIGMA_BEARING_DEG.to_radians();
    let seed = (i as u64) << 8 | draw;
    let measurement = RangeBearing::new(
        range + noise_scale * SIGMA_RANGE * noise(2 * seed),
        bearing + noise_scale * sigma_bearing * noise(2 * seed + 1),
        SIGMA_RANGE,
        sigma_bearing,
    )
    .expect("a valid range-bearing measurement");
    Observation {
        robot_from_sensor: Pose3::identity(),
        measurement: Arc::new(measurement),
        landmark_id,
    }
}

/// The odometry of a robot standing still for 0.1 s, with noise `sigma_v` (m/s) and
/// `sigma_w` (rad/s): the pose does not move (so the measurements stay valid), its
/// covariance grows.
pub fn still(sigma_v: f64, sigma_w: f64) -> Unicycle {
    Unicycle::new(0.0, 0.0, 0.1, sigma_v, sigma_w, Integration::Arc).expect("a valid unicycle")
}

/// The observation batches that build a map of `n` landmarks: every landmark observed once
/// in pass `pass`, in batches of up to 100, by `observe(i, draw)` with `draw = 100 + pass`.
pub fn build_batches(
    n: usize,
    pass: u64,
    observe: impl Fn(usize, u64) -> Observation,
) -> Vec<Vec<Observation>> {
    (0..n)
        .step_by(100)
        .map(|start| {
            (start..(start + 100).min(n))
                .map(|i| observe(i, 100 + pass))
                .collect()
        })
        .collect()
}

/// The timed steps: `ceil(n / 16)` updates of 16 distinct landmarks each, cycling through
/// the map (with wrap-around when 16 does not divide `n`); `observe(i, j)` observes landmark
/// `i` as the `j`-th of its update.
pub fn steps(n: usize, observe: impl Fn(usize, u64) -> Observation) -> Vec<Vec<Observation>> {
    (0..n.div_ceil(PER_UPDATE))
        .map(|g| {
            (0..PER_UPDATE)
                .map(|j| observe((g * PER_UPDATE + j) % n, j as u64))
                .collect()
        })
        .collect()
}
