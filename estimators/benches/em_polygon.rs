//! Run time of [`slam_estimators::fit_polygons`] (split-and-merge EM segment fitting) against
//! the number of points, 10k to 500k.
//!
//! The points are a synthetic floor plan of the size of the Intel lab (about 30 m x 30 m):
//! a 5 x 5 grid of 6 m rooms, each wall with a 1 m doorway in its middle, points spread
//! uniformly along the walls with +-2 cm of noise, plus 2 % of clutter spread over the
//! floor. The building is the same at every size: more points means denser walls, as when
//! more scans are registered, so the number of segments stays about the same and the run
//! time shows the cost per point of the E-step (a grid over the segments gives each point its
//! candidate segments; points are processed in parallel).
//!
//! ```sh
//! CARGO_TARGET_DIR=/work/target-bench cargo bench -p slam-estimators --bench em_polygon
//! ```
//! Results: `BENCHMARKS.md`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{
    BenchmarkId, Criterion, SamplingMode, Throughput, criterion_group, criterion_main,
};
use slam_core::nalgebra::Vector2;
use slam_estimators::{EmPolygonParams, fit_polygons};

/// Deterministic uniform numbers in `[0, 1)` (splitmix64).
struct Uniform(u64);

impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The walls of the floor plan: each room side split around a 1 m doorway.
fn walls() -> Vec<(Vector2<f64>, Vector2<f64>)> {
    let (rooms, size, door) = (5, 6.0, 1.0);
    let mut walls = Vec::new();
    for k in 0..=rooms {
        for m in 0..rooms {
            let c = k as f64 * size;
            let (a, b) = (m as f64 * size, (m + 1) as f64 * size);
            let mid = (a + b) / 2.0;
            // Outer walls are closed; inner walls have a doorway.
            let pieces = if k == 0 || k == rooms {
                vec![(a, b)]
            } else {
                vec![(a, mid - door / 2.0), (mid + door / 2.0, b)]
            };
            for (s, e) in pieces {
                walls.push((Vector2::new(c, s), Vector2::new(c, e)));
                walls.push((Vector2::new(s, c), Vector2::new(e, c)));
            }
        }
    }
    walls
}

fn floor_plan(n: usize) -> Vec<Vector2<f64>> {
    let walls = walls();
    let total: f64 = walls.iter().map(|(a, b)| (b - a).norm()).sum();
    let mut u = Uniform(42);
    let clutter = n / 50;
    let mut points = Vec::with_capacity(n);
    while points.len() < n - clutter {
        // A wall chosen in proportion to its length.
        let mut t = u.next() * total;
        for (a, b) in &walls {
            let length = (b - a).norm();
            if t <= length {
                let d = (b - a) / length;
                let normal = Vector2::new(-d.y, d.x);
                points.push(a + d * t + normal * (0.04 * (u.next() - 0.5)));
                break;
            }
            t -= length;
        }
    }
    while points.len() < n {
        points.push(Vector2::new(30.0 * u.next(), 30.0 * u.next()));
    }
    points
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("em_polygon");
    group
        .sampling_mode(SamplingMode::Flat)
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(10));
    let params = EmPolygonParams::default();
    for n in [10_000, 50_000, 100_000, 200_000, 500_000] {
        let points = floor_plan(n);
        let map = fit_polygons(&points, &params).expect("the floor plan is valid input");
        eprintln!(
            "{n} points: {} segments, {} iterations, mean distance {:.4} m",
            map.segments.len(),
            map.iterations.len(),
            map.mean_distance.unwrap_or(f64::NAN)
        );
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::from_parameter(n), &points, |b, points| {
            b.iter(|| fit_polygons(black_box(points), &params))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
