//! One IPSLAM step of [`slam_estimators::Ipslam`] against particle count and map size.
//!
//! A 181-beam laser scan (1 degree apart, 1 cm range noise, deterministic) of a simulated
//! room, taken by a robot at its centre, with small motion noise so that the particles
//! differ. Two rooms: `room`, the 16 m x 10 m rectangle (4 walls), and `pillars`, the same
//! room with 8 square pillars of 1 m on a ring around the robot (36 walls). The filter is
//! built once per case outside the timed loop: the robot turns on the spot, 30 degrees
//! between 12 scans, so every particle holds a line map of the whole room (its clusters;
//! the bench prints how many), then stands still. The timed routine is one prediction
//! (every particle draws its increment) plus one update with the scan's 181 points: PPCA and
//! G-means on the scan, each particle's matching, weighting (eq. 18) and cluster merges,
//! and the resampling that the weights call for. `min_travel = 0` and `min_turn_deg = 0`
//! make every scan a processed scan.
//!
//! ```sh
//! CARGO_TARGET_DIR=/work/target-bench cargo bench -p slam-estimators --bench ipslam
//! ```
//! Results and their discussion: `BENCHMARKS.md`.

use std::hint::black_box;
use std::sync::Arc;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, SamplingMode, criterion_group, criterion_main};
use slam_core::nalgebra::{DMatrix, Vector2};
use slam_core::{Estimator, Feature, Observation, Pose2, Pose3};
use slam_estimators::{Cluster, Ipslam, IpslamParams, LineMapTypes};
use slam_features::PpcaLine;
use slam_sensors::models::LinePoint;
use slam_sensors::odometry::{Integration, Unicycle};

// Only the noise and the standing robot are used here, not the range-bearing helpers.
#[allow(dead_code)]
mod common;

/// Particle counts timed (201 is the Intel runs' setting in BENCHMARKS.md).
const PARTICLES: [usize; 4] = [10, 100, 201, 1000];
/// Beams of a scan, 1 degree apart over 180 degrees.
const BEAMS: usize = 181;
/// Range noise, m.
const SIGMA_RANGE: f64 = 0.01;

/// IPSLAM's line maps as [`PpcaLine`]s and its scan points as [`LinePoint`]s, as the
/// runtime's `ipslam` estimator has them.
struct PpcaLines;

impl LineMapTypes for PpcaLines {
    fn cluster_feature(&self, c: &Cluster) -> slam_core::Result<Box<dyn Feature>> {
        let line =
            PpcaLine::from_cluster(c.mean, c.direction, c.principal_variance, c.sigma2, c.count)?;
        Ok(Box::new(line))
    }

    fn scan_point(&self, observation: &Observation) -> Option<Vector2<f64>> {
        LinePoint::point_of(observation)
    }
}

/// A wall from `a` to `b`.
type Wall = (Vector2<f64>, Vector2<f64>);

/// The walls of the 16 m x 10 m room centred at the origin, with `pillars` square pillars of
/// 1 m on a ring of radius 3.5 m around the centre.
fn room(pillars: usize) -> Vec<Wall> {
    let corners =
        [(-8.0, -5.0), (8.0, -5.0), (8.0, 5.0), (-8.0, 5.0)].map(|(x, y)| Vector2::new(x, y));
    let mut walls: Vec<Wall> = (0..4).map(|k| (corners[k], corners[(k + 1) % 4])).collect();
    for p in 0..pillars {
        let angle = std::f64::consts::TAU * (p as f64 + 0.5) / pillars as f64;
        let centre = 3.5 * Vector2::new(angle.cos(), angle.sin());
        let h = 0.5;
        let square = [(-h, -h), (h, -h), (h, h), (-h, h)].map(|(x, y)| centre + Vector2::new(x, y));
        walls.extend((0..4).map(|k| (square[k], square[(k + 1) % 4])));
    }
    walls
}

/// The range from the origin along `angle` (world frame) to the nearest wall.
fn ray(walls: &[Wall], angle: f64) -> f64 {
    let d = Vector2::new(angle.cos(), angle.sin());
    walls
        .iter()
        .filter_map(|(a, b)| {
            let e = b - a;
            let denominator = d.x * e.y - d.y * e.x;
            if denominator.abs() < 1e-12 {
                return None;
            }
            // origin + t d = a + s e
            let t = (a.x * e.y - a.y * e.x) / denominator;
            let s = (a.x * d.y - a.y * d.x) / denominator;
            (t > 0.0 && (0.0..=1.0).contains(&s)).then_some(t)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The scan of `walls` from the origin at `heading`, as [`LinePoint`] observations; `draw`
/// varies the deterministic noise.
fn scan(walls: &[Wall], heading: f64, draw: u64) -> Vec<Observation> {
    (0..BEAMS)
        .map(|k| {
            let bearing = (k as f64 - 90.0).to_radians();
            let seed = (k as u64) << 16 | draw;
            let range = ray(walls, heading + bearing) + SIGMA_RANGE * common::noise(seed);
            let point = range * Vector2::new(bearing.cos(), bearing.sin());
            Observation {
                robot_from_sensor: Pose3::identity(),
                measurement: Arc::new(LinePoint::new(point, SIGMA_RANGE).expect("a scan point")),
                landmark_id: None,
            }
        })
        .collect()
}

fn prepared(particles: usize, walls: &[Wall]) -> Ipslam<Pose2> {
    let params = IpslamParams {
        particles,
        min_travel: 0.0,
        min_turn_deg: 0.0,
        ..Default::default()
    };
    let mut filter = Ipslam::new(
        Pose2::identity(),
        DMatrix::zeros(3, 3),
        params,
        Arc::new(PpcaLines),
    )
    .expect("a filter");
    for turn in 0..TURNS {
        if turn > 0 {
            filter.predict(&turning()).expect("prediction");
        }
        filter
            .update(&scan(walls, heading(turn), turn as u64))
            .expect("update");
    }
    assert!(!filter.clusters().is_empty());
    filter
}

/// Scans taken while turning on the spot.
const TURNS: usize = 12;

/// The heading of the `turn`-th scan, rad.
fn heading(turn: usize) -> f64 {
    (30.0 * turn as f64).to_radians()
}

/// A robot turning 30 degrees on the spot in 0.1 s with small noise.
fn turning() -> Unicycle {
    Unicycle::new(
        0.0,
        300f64.to_radians(),
        0.1,
        0.002,
        0.05f64.to_radians(),
        Integration::Arc,
    )
    .expect("a turn")
}

/// A robot standing still for 0.1 s with small noise.
fn still() -> Unicycle {
    common::still(0.002, 0.05f64.to_radians())
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("ipslam_step");
    group.sampling_mode(SamplingMode::Flat);
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(4));
    for (name, pillars) in [("room", 0), ("pillars", 8)] {
        let walls = room(pillars);
        let last = heading(TURNS - 1);
        let scans: Vec<Vec<Observation>> =
            (100..108).map(|draw| scan(&walls, last, draw)).collect();
        for particles in PARTICLES {
            let mut filter = prepared(particles, &walls);
            println!(
                "{name}, {particles} particles: {} clusters in the best particle's map",
                filter.clusters().len()
            );
            let mut k = 0;
            group.bench_function(BenchmarkId::new(name, format!("{particles}p")), |b| {
                b.iter(|| {
                    filter.predict(&still()).expect("prediction");
                    let report = filter.update(&scans[k % scans.len()]).expect("update");
                    k += 1;
                    black_box(report)
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
