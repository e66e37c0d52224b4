//! Runs with `[data.laser_odometry]` on the simulated office, which has a true pose at every
//! step and a scan at every other. The estimate moves only at scans (the wheel odometry
//! between two scans waits for the next match), so only the truth at scans is compared with
//! it; compared there, the EKF with walls on the laser odometry (`configs/carmen-walls.toml`)
//! is cautious.

mod common;

use slam_sensors::Event;
use slam_sensors::sim::World;

use common::{TempWorld, run_toml};

#[test]
fn truth_between_scans_is_left_out_and_the_walls_on_laser_odometry_are_consistent() {
    let mut world = World::default_world();
    world.camera = None;
    world.robot.waypoints.truncate(3);
    let world = TempWorld::new(world);
    let truths = world
        .events(1)
        .iter()
        .filter(|e| matches!(e, Event::GroundTruth { .. }))
        .count();
    let config = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../configs/carmen-walls.toml"
    ))
    .expect("the config reads");
    // The filter alone: the relocalization stage is not what this checks.
    let filter = &config[..config.find("[[postprocess]]").unwrap_or(config.len())];
    let (_, _, metrics) = run_toml(&format!("{}\n{filter}", world.data_table(1)));
    let laser = metrics.laser_odometry.expect("the run has laser odometry");
    let nees = metrics.nees.expect("the simulation has truth");
    eprintln!("{laser:?}, of {truths} true poses; pose NEES {nees:?}");
    assert!(
        laser.truth_between_scans > truths / 3,
        "{laser:?} of {truths}"
    );
    // Every other true pose is compared (but where the covariance is singular: the first).
    assert_eq!(
        nees.count + metrics.nees_singular_steps + laser.truth_between_scans,
        truths
    );
    // Cautious, as each of its sources is (0.14; compared at the steps between scans as well,
    // with the pose of the scan before, this run scored 0.96, and the whole office 3.2).
    assert!(nees.mean_per_dof < 0.5, "{nees:?}");
}
