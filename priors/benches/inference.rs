//! One inference (Algorithm 1 around Algorithm 2) of the rectangular prior on a simulated
//! square room, 360-degree scans of 180 and 361 readings with 3 clutter outliers, and on real
//! scans of the Intel lab (the radish corrected CARMEN log beside the repository, scans 0 and
//! 600, range sigma 2 cm, as `slam prior --sigma-range 0.02` runs them); and the
//! degrees-of-freedom analysis of each result.
//!
//! `cargo bench -p slam-priors --bench inference`

use std::hint::black_box;
use std::path::Path;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use slam_priors::scene::{ScanSpec, Scene};
use slam_priors::{Library, Params, ScanInput, analyze, infer};
use slam_sensors::Event;
use slam_sensors::data::{CarmenOptions, stream_carmen};

/// The Intel lab log, under the real datasets folder (DATASETS.md).
const INTEL: &str = "radish-carmen-corrected/intel-corrected.log.gz";

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

/// Scans `wanted` (0-based, in stream order) of the Intel log; none when the log is absent.
fn intel(wanted: &[usize]) -> Vec<(usize, ScanInput)> {
    // `SLAM_DATA_DIR` (relative to the workspace root), by default `../shared/datasets`.
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let data = std::env::var_os("SLAM_DATA_DIR").unwrap_or_else(|| "../shared/datasets".into());
    let path = workspace.join(data).join(INTEL);
    if !path.exists() {
        eprintln!(
            "{} not found: the Intel scans are not benched",
            path.display()
        );
        return Vec::new();
    }
    let last = wanted.iter().copied().max().unwrap_or(0);
    let mut scans = Vec::new();
    let mut count = 0;
    for event in stream_carmen(&path, &CarmenOptions::default()).expect("readable log") {
        if let Event::Scan { scan, .. } = event.expect("valid log").event {
            if wanted.contains(&count) {
                scans.push((
                    count,
                    ScanInput::from_scan(&scan, 0.02).expect("valid scan"),
                ));
            }
            if count == last {
                break;
            }
            count += 1;
        }
    }
    scans
}

fn bench(c: &mut Criterion) {
    let library = Library::shipped().expect("shipped priors");
    let prior = library.compile("Rectangular prior").expect("prior");
    let params = Params::default();
    let mut cases: Vec<(String, ScanInput)> = [180, 361]
        .into_iter()
        .map(|beams| (format!("square {beams}"), scan(beams)))
        .collect();
    for (k, input) in intel(&[0, 600]) {
        cases.push((format!("intel scan {k}"), input));
    }
    let mut group = c.benchmark_group("rectangular prior");
    group.sample_size(10);
    for (name, input) in &cases {
        group.bench_with_input(BenchmarkId::new("infer", name), input, |b, input| {
            b.iter(|| infer(&prior, black_box(input), &params).expect("inference"))
        });
        let solution = infer(&prior, input, &params).expect("inference");
        group.bench_with_input(BenchmarkId::new("dof", name), &solution, |b, s| {
            b.iter(|| analyze(&prior, black_box(s)).expect("dof"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
