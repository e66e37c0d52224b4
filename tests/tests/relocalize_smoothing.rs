//! The `relocalize` stage end to end on a simulated office: its placements smoothed with the
//! odometry between scans (`smooth = true`, the default) give a path at least as close to the
//! truth as the placements alone and the filter, and its figures report how many placements
//! the smoothing outvoted.

mod common;

use slam_runtime::PostProcessOutput;
use slam_sensors::sim::World;

use common::{TempWorld, run_toml};

/// The built-in office's corridor to the south room, into it and back (about 30 m, five turns).
fn south_room() -> TempWorld {
    let mut world = World::default_world();
    world.camera = None;
    world.robot.waypoints = vec![
        [14.5, 7.5],
        [14.5, 3.5],
        [17.5, 2.5],
        [17.5, 4.5],
        [14.5, 4.0],
        [14.5, 7.5],
    ];
    TempWorld::new(world)
}

fn relocalized(smooth: bool) -> (f64, PostProcessOutput) {
    let world = south_room();
    let text = format!(
        "{}\n[[postprocess]]\ntype = \"relocalize\"\nsmooth = {smooth}\n",
        world.data_table(3)
    );
    let (_, mut output, metrics) = run_toml(&text);
    let filter = metrics.ate_rmse_m.expect("the simulation has truth");
    let stage = output.postprocess.remove(0);
    (filter, stage)
}

#[test]
fn smoothed_placements_are_as_close_to_the_truth_as_the_placements_alone() {
    let (filter, smoothed) = relocalized(true);
    let (_, alone) = relocalized(false);
    let ate = |s: &PostProcessOutput| s.metrics["ate_rmse_after_m"].as_f64().unwrap();
    eprintln!(
        "filter {filter:.4} m, placements alone {:.4} m, smoothed {:.4} m ({})",
        ate(&alone),
        ate(&smoothed),
        smoothed.summary
    );
    assert!(smoothed.metrics["outvoted"].as_u64().is_some());
    // The office's walls are all real: the rays see through none of them, and the stage's
    // map keeps every feature.
    assert_eq!(smoothed.metrics["seen_through"]["walls"].as_u64(), Some(0));
    assert_eq!(smoothed.map.len(), alone.map.len());
    assert_eq!(alone.metrics["outvoted"].as_u64(), Some(0));
    assert!(ate(&smoothed) <= ate(&alone) * 1.1 + 1e-3);
    assert!(ate(&smoothed) <= filter * 1.1 + 1e-3);
}
