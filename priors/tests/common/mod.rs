//! Helpers shared by the integration tests.
#![allow(dead_code)]

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use slam_priors::scene::{ScanSpec, Scene, Shape, SimulatedScan};

/// A 360-degree scan of `beams` beams from `pose`, starting at bearing `angle_min`.
pub fn full_scan(
    scene: &Scene,
    pose: [f64; 3],
    angle_min: f64,
    beams: usize,
    sigma: f64,
    outliers: usize,
    seed: u64,
) -> SimulatedScan {
    let spec = ScanSpec {
        world_from_sensor: pose,
        angle_min,
        angle_increment: std::f64::consts::TAU / beams as f64,
        beams,
        sigma,
        outliers,
        max_range: 30.0,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    scene.simulate(&spec, &mut rng).expect("valid spec")
}

/// A circle scene.
pub fn circle(centre: [f64; 2], radius: f64) -> Shape {
    Shape::Circle { centre, radius }
}

/// Smallest absolute difference of two angles.
pub fn angle_error(a: f64, b: f64) -> f64 {
    let d = a - b;
    d.sin().atan2(d.cos()).abs()
}
