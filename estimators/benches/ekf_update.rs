//! One EKF update of [`slam_estimators::Ekf`] against map size.
//!
//! Range-bearing point landmarks (`slam_sensors::models::RangeBearing`, the 2-D use of
//! `slam_features::Point`) with known ids, so no association search: the state has `3 + 2n`
//! rows for `n` landmarks. The filter is built once per size outside the timed loop: every
//! landmark is observed twice, in batches of 100 with an odometry prediction between batches,
//! so the covariance is dense (every landmark correlated with the pose and the others).
//!
//! `Ekf` does not implement `Clone`, so the timed routine is one **predict + update pair** on
//! the same filter: a still-standing unicycle prediction (noise only, O(n)), then one update
//! with 16 observations of known landmarks (the rb2d benchmark's typical step). The state
//! size stays constant because every landmark is already in the state; consecutive
//! iterations cycle through the landmarks 16 at a time. The `ekf_predict` group times the
//! prediction alone, to show its share, and `downdate_reference` times the covariance
//! downdate `C -= W W^T` alone (faer, lower triangle), the O(n^2) core of the update.
//!
//! ```sh
//! CARGO_TARGET_DIR=/work/target-bench cargo bench -p slam-estimators --bench ekf_update
//! ```
//! Results and their discussion: `BENCHMARKS.md`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, SamplingMode, criterion_group, criterion_main};
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::{Accum, Par};
use slam_core::nalgebra::DMatrix;
use slam_core::{Estimator, Feature, Observation, Pose2, downcast_feature};
use slam_estimators::{Ekf, EkfParams};
use slam_features::Point;
use slam_sensors::odometry::Unicycle;

mod common;
use common::{PER_UPDATE, build_batches, noise};

/// Map sizes of the main group.
const SIZES: [usize; 6] = [50, 100, 200, 500, 1000, 2000];
/// Map sizes of the group without the observability constraint.
const SIZES_NO_OC: [usize; 2] = [500, 2000];

/// One observation of landmark `i` of `n`, with small deterministic noise (`draw` varies it).
fn observation(i: usize, n: usize, draw: u64) -> Observation {
    common::observation(i, n, draw, 0.5, Some(i as u64))
}

/// The odometry of a robot standing still for 0.1 s: the pose does not move (so the
/// measurements stay valid), the pose covariance grows.
fn still() -> Unicycle {
    common::still(0.05, 2f64.to_radians())
}

/// A filter with `n` landmarks and a dense covariance (`3 + 2n` rows).
fn prepared_filter(n: usize, params: EkfParams) -> Ekf<Pose2> {
    let mut ekf = Ekf::new(Pose2::identity(), DMatrix::zeros(3, 3), params).expect("a filter");
    let motion = still();
    for pass in 0..2u64 {
        for batch in build_batches(n, pass, |i, draw| observation(i, n, draw)) {
            ekf.predict(&motion).expect("prediction");
            let report = ekf.update(&batch).expect("update");
            assert_eq!(report.rejected, 0, "n = {n}: {report:?}");
        }
    }
    assert_eq!(ekf.state_dim(), 3 + 2 * n, "n = {n}");
    assert_eq!(ekf.map().len(), n);
    for (_, feature) in ekf.map().iter() {
        let point = downcast_feature::<Point>(feature).expect("every feature is a Point");
        assert_eq!(point.mspace_dim(), 2, "the 2-D use of the point");
    }
    // Dense: the first landmark is correlated with the last one.
    let c = ekf.covariance();
    assert!(
        c[(3, 3 + 2 * n - 2)].abs() > 0.0,
        "n = {n}: covariance not dense"
    );
    ekf
}

/// The timed steps: `ceil(n / 16)` updates of 16 distinct landmarks each, cycling through
/// the map (with wrap-around when 16 does not divide `n`).
fn steps(n: usize) -> Vec<Vec<Observation>> {
    common::steps(n, |i, draw| observation(i, n, draw))
}

/// A prepared filter with one untimed step checked: all 16 observations are used.
fn checked_filter(n: usize, params: EkfParams) -> Ekf<Pose2> {
    let mut ekf = prepared_filter(n, params);
    ekf.predict(&still()).expect("prediction");
    let report = ekf.update(&steps(n)[0]).expect("update");
    assert_eq!(
        (report.associated, report.new_features, report.rejected),
        (PER_UPDATE, 0, 0),
        "n = {n}: {report:?}"
    );
    ekf
}

type Group<'a> = criterion::BenchmarkGroup<'a, criterion::measurement::WallTime>;

/// Times predict + update pairs on the filter of `n` landmarks, built on first use (so that
/// a filter on the command line skips building the others) and kept in `slot`.
fn time_step(group: &mut Group<'_>, n: usize, params: &EkfParams, slot: &mut Option<Ekf<Pose2>>) {
    let steps = steps(n);
    let motion = still();
    let mut k = 1;
    group.bench_function(BenchmarkId::from_parameter(n), |b| {
        let ekf = slot.get_or_insert_with(|| checked_filter(n, params.clone()));
        b.iter(|| {
            ekf.predict(&motion).expect("prediction");
            let report = ekf.update(&steps[k % steps.len()]).expect("update");
            k += 1;
            black_box(report)
        });
    });
    if let Some(ekf) = slot {
        assert_eq!(
            ekf.state_dim(),
            3 + 2 * n,
            "the state size changed while timing"
        );
    }
}

fn configure(group: &mut Group<'_>) {
    group
        .sampling_mode(SamplingMode::Flat)
        .sample_size(30)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(6));
}

fn benches(c: &mut Criterion) {
    let mut filters: Vec<(usize, Option<Ekf<Pose2>>)> = SIZES.iter().map(|&n| (n, None)).collect();

    let mut group = c.benchmark_group("ekf_update");
    configure(&mut group);
    for (n, slot) in &mut filters {
        time_step(&mut group, *n, &EkfParams::default(), slot);
    }
    group.finish();

    let mut group = c.benchmark_group("ekf_update_no_observability_constraint");
    configure(&mut group);
    let params = EkfParams {
        observability_constraint: false,
        ..Default::default()
    };
    for n in SIZES_NO_OC {
        time_step(&mut group, n, &params, &mut None);
    }
    group.finish();

    let mut group = c.benchmark_group("ekf_predict");
    configure(&mut group);
    let motion = still();
    for (n, slot) in &mut filters {
        group.bench_function(BenchmarkId::from_parameter(*n), |b| {
            let ekf = slot.get_or_insert_with(|| checked_filter(*n, EkfParams::default()));
            b.iter(|| ekf.predict(black_box(&motion)).expect("prediction"));
        });
    }
    group.finish();

    // Reference: the covariance downdate alone, as `StateCovariance::commit` does it
    // (faer's lower-triangular `C -= W W^T`, sequential), to compare with the full update
    // and with the memory-bandwidth figure of DEPENDENCIES.md (n = 3000, m = 2).
    let mut group = c.benchmark_group("downdate_reference");
    configure(&mut group);
    let step_m = 2 * PER_UPDATE;
    for (rows, m) in [
        (3000, 2),
        (4003, 2),
        (1003, step_m),
        (2003, step_m),
        (4003, step_m),
    ] {
        let label = format!("rows{rows}_m{m}");
        // Built on first use and kept: criterion calls the closure once per sample.
        let mut data = None;
        group.bench_function(BenchmarkId::from_parameter(label), |b| {
            let (lower, w) = data.get_or_insert_with(|| {
                let lower = faer::Mat::<f64>::zeros(rows, rows);
                let w = faer::Mat::<f64>::from_fn(rows, m, |i, j| 1e-3 * noise((i * m + j) as u64));
                (lower, w)
            });
            b.iter(|| {
                triangular::matmul(
                    &mut *lower,
                    BlockStructure::TriangularLower,
                    Accum::Add,
                    &*w,
                    BlockStructure::Rectangular,
                    w.transpose(),
                    BlockStructure::Rectangular,
                    -1.0,
                    Par::Seq,
                );
            });
            black_box(&*lower);
        });
    }
    group.finish();
}

criterion_group!(ekf_update, benches);
criterion_main!(ekf_update);
