//! One inference (Algorithm 1 around Algorithm 2) of the rectangular prior on a simulated
//! square room, 360-degree scans of 180 and 361 readings with 3 clutter outliers; and the
//! degrees-of-freedom analysis of the result.
//!
//! `cargo bench -p slam-priors --bench inference`

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use slam_priors::scene::{ScanSpec, Scene};
use slam_priors::{Library, Params, ScanInput, analyze, infer};

fn scan(beams: usize) -> ScanInput {
    let spec = ScanSpec {
        world_from_sensor: [1.7, 2.2, 0.3],
        angle_min: -std::f64::consts::PI,
        angle_increment: std::f64::consts::TAU / beams as f64,
        beams,
        sigma: 0.01,
        outliers: 3,
        max_range: 30.0,
    };
    let sim = Scene::rectangle(4.0, 4.0)
        .simulate_seeded(&spec, 1)
        .expect("valid scene");
    ScanInput::from_scan(&sim.scan, 0.01).expect("valid scan")
}

fn bench(c: &mut Criterion) {
    let library = Library::shipped().expect("shipped priors");
    let prior = library.compile("Rectangular prior").expect("prior");
    let params = Params::default();
    let mut group = c.benchmark_group("rectangular prior, square room");
    group.sample_size(10);
    for beams in [180, 361] {
        let input = scan(beams);
        group.bench_with_input(BenchmarkId::new("infer", beams), &input, |b, input| {
            b.iter(|| infer(&prior, black_box(input), &params).expect("inference"))
        });
        let solution = infer(&prior, &input, &params).expect("inference");
        group.bench_with_input(BenchmarkId::new("dof", beams), &solution, |b, s| {
            b.iter(|| analyze(&prior, black_box(s)).expect("dof"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
