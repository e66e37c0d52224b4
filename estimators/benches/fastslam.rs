//! One FastSLAM step of [`slam_estimators::FastSlam`] against particle count and map size.
//!
//! Range-bearing point landmarks (`slam_sensors::models::RangeBearing`, the 2-D use of
//! `slam_features::Point`) on a golden-angle spiral around a robot that stands still. The
//! filter is built once per (particles, landmarks) outside the timed loop: every landmark is
//! observed twice with known ids. The timed routine is one prediction (every particle draws
//! its increment) plus one update with 16 observations: known ids (`known`) or the
//! per-particle gated nearest neighbour (`nearest`). The resampling threshold is 1.0, so
//! every timed update resamples: its cost (sharing maps, not copying them) is included.
//!
//! ```sh
//! CARGO_TARGET_DIR=/work/target-bench cargo bench -p slam-estimators --bench fastslam
//! ```
//! Results and their discussion: `BENCHMARKS.md`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, SamplingMode, criterion_group, criterion_main};
use slam_core::nalgebra::DMatrix;
use slam_core::{Estimator, Observation, Pose2, Pose3};
use slam_estimators::{FastSlam, FastSlamParams};
use slam_sensors::models::RangeBearing;
use slam_sensors::odometry::{Integration, Unicycle};

/// (particles, landmarks) of the timed cases.
const CASES: [(usize, usize); 7] = [
    (10, 100),
    (100, 100),
    (1000, 100),
    (100, 25),
    (100, 400),
    (100, 1600),
    (1000, 1600),
];
/// Observations per timed update.
const PER_UPDATE: usize = 16;
const SIGMA_RANGE: f64 = 0.1;
const SIGMA_BEARING_DEG: f64 = 1.0;

/// A deterministic uniform number in `[-1, 1)` (splitmix64), for reproducible noise.
fn noise(seed: u64) -> f64 {
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// One observation of landmark `i` of `n` (spiral, ranges 2 m to 20 m).
fn observation(i: usize, n: usize, draw: u64, known: bool) -> Observation {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let range = 2.0 + 18.0 * ((i as f64 + 0.5) / n as f64).sqrt();
    let bearing = i as f64 * golden;
    let sigma_bearing = SIGMA_BEARING_DEG.to_radians();
    let seed = (i as u64) << 8 | draw;
    let measurement = RangeBearing::new(
        range + 0.3 * SIGMA_RANGE * noise(2 * seed),
        bearing + 0.3 * sigma_bearing * noise(2 * seed + 1),
        SIGMA_RANGE,
        sigma_bearing,
    )
    .expect("a valid range-bearing measurement");
    Observation {
        robot_from_sensor: Pose3::identity(),
        measurement: Box::new(measurement),
        landmark_id: known.then_some(i as u64),
    }
}

/// A robot standing still for 0.1 s with small noise.
fn still() -> Unicycle {
    Unicycle::new(0.0, 0.0, 0.1, 0.002, 0.05f64.to_radians(), Integration::Arc)
        .expect("a valid unicycle")
}

fn prepared(particles: usize, n: usize) -> FastSlam<Pose2> {
    let params = FastSlamParams {
        particles,
        resample_threshold: 1.0,
        ..Default::default()
    };
    let mut filter =
        FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), params).expect("a filter");
    for pass in 0..2u64 {
        for start in (0..n).step_by(100) {
            let batch: Vec<Observation> = (start..(start + 100).min(n))
                .map(|i| observation(i, n, 100 + pass, true))
                .collect();
            filter.predict(&still()).expect("prediction");
            filter.update(&batch).expect("update");
        }
    }
    assert_eq!(filter.map().len(), n);
    filter
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("fastslam_step");
    group.sampling_mode(SamplingMode::Flat);
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(4));
    for (particles, n) in CASES {
        let mut filter = prepared(particles, n);
        for known in [true, false] {
            let steps: Vec<Vec<Observation>> = (0..n.div_ceil(PER_UPDATE))
                .map(|g| {
                    (0..PER_UPDATE)
                        .map(|j| observation((g * PER_UPDATE + j) % n, n, j as u64, known))
                        .collect()
                })
                .collect();
            let name = if known { "known" } else { "nearest" };
            let mut k = 0;
            group.bench_function(BenchmarkId::new(name, format!("{particles}p-{n}lm")), |b| {
                b.iter(|| {
                    filter.predict(&still()).expect("prediction");
                    let report = filter.update(&steps[k % steps.len()]).expect("update");
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
