//! The writers of simulated runs read back: rb2d (odometry increments, observations, truth)
//! and CARMEN (scans, mounts, dead-reckoned poses).

use slam_core::Pose2;
use slam_sensors::data::carmen::{CarmenOptions, read_carmen, write_carmen};
use slam_sensors::data::rb2d::{read_rb2d, write_rb2d};
use slam_sensors::models::RangeBearing;
use slam_sensors::sim::{LandmarkSpec, World, simulate};
use slam_sensors::{Dataset, Event, LaserScan, TruthKind};

/// A fresh folder for one test's files, removed when dropped.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("slam-simulate-writers-{name}-"))
        .tempdir()
        .unwrap()
}

/// The default world as far as the pillar room (its poles are range-bearing landmarks), with a
/// few extra landmarks, without the camera (slow, and in neither file).
fn short_world() -> World {
    let mut world = World::default_world();
    world.robot.waypoints.truncate(4);
    world.camera = None;
    world.landmarks = vec![
        LandmarkSpec { x: 10.0, y: 7.0 },
        LandmarkSpec { x: 20.0, y: 3.0 },
    ];
    world
}

/// `(time, increment)` of every motion.
fn increments(data: &Dataset) -> Vec<(f64, Pose2)> {
    data.events
        .iter()
        .filter_map(|e| match &e.event {
            Event::Motion(m) => Some((e.time, m.predict(&Pose2::identity()).unwrap().pose)),
            _ => None,
        })
        .collect()
}

fn assert_same_pose(a: &Pose2, b: &Pose2, tolerance: f64) {
    let d = a.between(b).to_vector();
    assert!(d.amax() < tolerance, "{a:?} vs {b:?}");
}

#[test]
fn rb2d_reads_back_the_simulated_odometry_observations_and_truth() {
    let world = short_world();
    let run = simulate(&world, 11).unwrap();
    let dir = temp_dir("rb2d");
    let path = dir.path().join("run.rb2d");
    write_rb2d(&path, &run.dataset, &world.rb2d_params(), "test").unwrap();
    let back = read_rb2d(&path).unwrap();

    // Odometry: the simulator integrates exact arcs; the file holds each step's exact
    // increment, which reads back as the same increment.
    let (simulated, read) = (increments(&run.dataset), increments(&back));
    assert_eq!(simulated.len(), run.trajectory.len() - 1);
    assert_eq!(simulated.len(), read.len());
    for ((t0, d0), (t1, d1)) in simulated.iter().zip(&read) {
        assert_eq!(t0, t1);
        assert!((d0.to_vector() - d1.to_vector()).amax() < 1e-9);
    }

    // Observations: the same times, ids, values and noise.
    let observations = |data: &Dataset| {
        data.events
            .iter()
            .filter_map(|e| match &e.event {
                Event::Observations(o) => Some((e.time, o)),
                _ => None,
            })
            .flat_map(|(t, o)| {
                o.iter().map(move |o| {
                    let rb = o
                        .measurement
                        .as_any()
                        .downcast_ref::<RangeBearing>()
                        .unwrap();
                    (t, o.landmark_id, rb.clone())
                })
            })
            .collect::<Vec<_>>()
    };
    let (simulated, read) = (observations(&run.dataset), observations(&back));
    assert!(simulated.len() > 100, "{} observations", simulated.len());
    assert!(simulated.iter().any(|(_, id, _)| *id == Some(4))); // a [[landmarks]] point
    assert_eq!(simulated, read);

    // Truth and landmarks.
    let truth = |data: &Dataset| {
        data.events
            .iter()
            .filter_map(|e| match &e.event {
                Event::GroundTruth { pose, kind } => Some((e.time, *pose, *kind)),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    let (simulated, read) = (truth(&run.dataset), truth(&back));
    assert_eq!(simulated, read);
    assert!(read.iter().all(|(_, _, kind)| *kind == TruthKind::True));
    assert_eq!(run.dataset.landmarks, back.landmarks);
    assert_eq!(back.landmarks.len(), world.poles.len() + 2);
}

#[test]
fn carmen_reads_back_the_scans_mounts_and_dead_reckoning() {
    let world = short_world();
    let laser = world.laser.clone().unwrap();
    let run = simulate(&world, 12).unwrap();
    let dir = temp_dir("carmen");
    let path = dir.path().join("run.carmen.log");
    write_carmen(&path, &run.dataset, &world.start_pose(), "test").unwrap();
    let back = read_carmen(&path, &CarmenOptions::default()).unwrap();

    // The dead-reckoned pose at every scan of the simulation.
    let mut pose = world.start_pose();
    let mut expected: Vec<(LaserScan, Pose2)> = Vec::new();
    for e in &run.dataset.events {
        match &e.event {
            Event::Motion(m) => pose = m.predict(&pose).unwrap().pose,
            Event::Scan { scan, .. } => expected.push((scan.clone(), pose)),
            _ => {}
        }
    }
    let mut read = Vec::new();
    let mut scan = None;
    for e in &back.events {
        match &e.event {
            Event::Scan {
                scan: s,
                robot_from_sensor,
            } => scan = Some((s.clone(), *robot_from_sensor)),
            Event::GroundTruth { pose, kind } => {
                assert_eq!(*kind, TruthKind::Reference);
                let (s, mount) = scan.take().unwrap();
                read.push((s, mount, *pose));
            }
            _ => {}
        }
    }
    assert!(expected.len() > 100);
    assert_eq!(expected.len(), read.len());
    let mount = laser.robot_from_sensor();
    for ((s0, p0), (s1, m1, p1)) in expected.iter().zip(&read) {
        assert_eq!(
            (s0.angle_min, s0.angle_increment, s0.min_range, s0.max_range),
            (s1.angle_min, s1.angle_increment, s1.min_range, s1.max_range)
        );
        assert_eq!(s0.ranges.len(), s1.ranges.len());
        for (r0, r1) in s0.ranges.iter().zip(&s1.ranges) {
            assert!((r0 - r1).abs() <= 5e-4 + 1e-12, "{r0} vs {r1}");
            assert_eq!(s0.is_valid(*r0), s1.is_valid(*r1));
        }
        // The mount, but for its height (not in a CARMEN line).
        let t = m1.translation - mount.translation;
        assert!(t.x.abs() < 1e-8 && t.y.abs() < 1e-8 && (m1.yaw - mount.yaw).abs() < 1e-8);
        assert_same_pose(p0, p1, 1e-8);
    }

    // The ODOM lines give the odometry increments back, to the printed precision.
    let (simulated, read) = (increments(&run.dataset), increments(&back));
    assert_eq!(simulated.len(), read.len());
    for ((_, d0), (_, d1)) in simulated.iter().zip(&read) {
        assert!((d0.to_vector() - d1.to_vector()).amax() < 1e-8);
    }
}
