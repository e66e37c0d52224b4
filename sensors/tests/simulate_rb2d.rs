//! The rb2d benchmark world (`worlds/rb2d-circle.toml`): the classic range-bearing landmark
//! setting, and its rb2d log read back as the very same unicycle steps.

use std::path::Path;

use slam_core::Pose2;
use slam_sensors::Event;
use slam_sensors::data::rb2d::{read_rb2d, write_rb2d};
use slam_sensors::sim::{World, simulate};

fn circle_world() -> World {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
    World::from_file(&path).unwrap()
}

#[test]
fn the_circle_world_is_the_classic_benchmark() {
    let world = circle_world();
    assert!(world.laser.is_none() && world.camera.is_none() && world.walls.is_empty());
    let run = simulate(&world, 1).unwrap();
    let counts = run.dataset.counts();
    assert_eq!(counts.motion, 1000, "steps");
    assert_eq!((counts.ground_truth, run.trajectory.len()), (1001, 1001));
    assert_eq!((counts.scans, counts.images), (0, 0));
    assert_eq!(run.dataset.landmarks.len(), 50);
    assert!(
        run.dataset
            .landmarks
            .iter()
            .enumerate()
            .all(|(i, l)| l.id == i as u64)
    );
    // Every pose observes (every = 1); about 16 landmarks within 10 m on average.
    assert_eq!(counts.observation_events, 1001);
    let per_step = counts.observations as f64 / run.trajectory.len() as f64;
    assert!(
        (13.0..=19.0).contains(&per_step),
        "{per_step} observations per step"
    );
    // The path is an exact circle (Euler chords of 0.1 m turning 0.72 deg), two laps.
    let phi = 0.72f64.to_radians();
    let radius = 0.1 / (2.0 * (phi / 2.0).sin());
    let centre = slam_core::nalgebra::Vector2::new(0.05, radius * (phi / 2.0).cos());
    for pose in &run.trajectory {
        assert!(((pose.translation() - centre).norm() - radius).abs() < 1e-9);
    }
    assert!(run.trajectory[1000].translation().norm() < 1e-9);
    assert!(run.trajectory[500].translation().norm() < 1e-9); // end of the first lap
}

#[test]
fn its_rb2d_log_reads_back_as_the_same_unicycle_steps() {
    let world = circle_world();
    let run = simulate(&world, 7).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("circle.rb2d");
    write_rb2d(&path, &run.dataset, &world.rb2d_params(), "test").unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.lines()
            .filter(|l| l.starts_with("ODOM"))
            .all(|l| l.split_whitespace().nth(4) == Some("0")),
        "Euler steps are written with dy = 0"
    );
    let back = read_rb2d(&path).unwrap();
    let motions = |data: &slam_sensors::Dataset| {
        data.events
            .iter()
            .filter_map(|e| match &e.event {
                Event::Motion(m) => Some((
                    e.time,
                    m.control(),
                    m.predict(&Pose2::new(1.0, 2.0, 0.3)).unwrap(),
                )),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    let (simulated, read) = (motions(&run.dataset), motions(&back));
    assert_eq!(simulated.len(), read.len());
    for ((t0, c0, p0), (t1, c1, p1)) in simulated.iter().zip(&read) {
        assert_eq!(t0, t1);
        // The same unicycle: (v, omega), the same step and the same noise model.
        assert_eq!(c1.len(), 2);
        assert!((c0 - c1).amax() < 1e-9, "{c0} vs {c1}");
        assert!((p0.pose.to_vector() - p1.pose.to_vector()).amax() < 1e-9);
        assert!((&p0.cov_control - &p1.cov_control).amax() < 1e-15);
        assert!((&p0.d_pose_d_control - &p1.d_pose_d_control).amax() < 1e-9);
    }
    assert_eq!(
        back.counts().observations,
        run.dataset.counts().observations
    );
}
