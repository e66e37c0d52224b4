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
use slam_core::{Estimator, Observation, Pose2};
use slam_estimators::{FastSlam, FastSlamParams};
use slam_sensors::odometry::Unicycle;

mod common;
use common::{build_batches, steps};

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

/// One observation of landmark `i` of `n` (spiral, ranges 2 m to 20 m), with its id if
/// `known`.
fn observation(i: usize, n: usize, draw: u64, known: bool) -> Observation {
    common::observation(i, n, draw, 0.3, known.then_some(i as u64))
}

/// A robot standing still for 0.1 s with small noise.
fn still() -> Unicycle {
    common::still(0.002, 0.05f64.to_radians())
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
        for batch in build_batches(n, pass, |i, draw| observation(i, n, draw, true)) {
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
            let steps = steps(n, |i, draw| observation(i, n, draw, known));
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
