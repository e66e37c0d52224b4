//! Calibration of the laser wall extractor against the simulator's truth: for every segment
//! extracted from the built-in world's scans, the error of its line `(alpha, rho)` and of its
//! real ends against the true wall, normalized by the covariance the extractor reports.
//!
//! A well calibrated extractor has a mean line NIS of 2 (two degrees of freedom) and a mean
//! squared normalized end error of 1, in every bin.
//!
//! ```sh
//! cargo run --release -p slam-sensors --example segment_calibration -- [SEEDS [WORLD.toml [rough]]]
//! ```
//!
//! `WORLD.toml` replaces the built-in world; `rough` turns on `scale_by_residuals` (as
//! `configs/carmen-walls.toml` does). The signed line-angle error, split by the side the
//! segment lies on, shows a bias: a filter turns the robot by minus that angle.

use slam_core::nalgebra::Vector2;
use slam_core::{Pose2, wrap_angle};
use slam_sensors::events::Event;
use slam_sensors::extract::{LineExtractorParams, extract_segments};
use slam_sensors::sim::{World, simulate};

/// Running sums of a normalized error.
#[derive(Default, Clone)]
struct Bin {
    n: usize,
    sum: f64,
    above: usize,
}

impl Bin {
    fn add(&mut self, value: f64, critical: f64) {
        self.n += 1;
        self.sum += value;
        if value > critical {
            self.above += 1;
        }
    }

    fn line(&self, label: &str) -> String {
        let mean = if self.n > 0 {
            self.sum / self.n as f64
        } else {
            f64::NAN
        };
        let tail = 100.0 * self.above as f64 / self.n.max(1) as f64;
        format!(
            "{label:>28}: n {:6}  mean {mean:6.2}  >99% {tail:5.1}%",
            self.n
        )
    }
}

/// The bin of `value` among the bins below `edges[0]`, `edges[1]`, `edges[2]` and above.
fn bin(value: f64, edges: [f64; 3]) -> usize {
    edges.iter().take_while(|&&edge| value >= edge).count()
}

/// A true wall in the sensor frame: its normal form and ends.
fn wall_in_sensor(world_from_sensor: &Pose2, a: &Vector2<f64>, b: &Vector2<f64>) -> WallLine {
    let a_s = world_from_sensor.inverse_transform_point(a);
    let b_s = world_from_sensor.inverse_transform_point(b);
    let t = (b_s - a_s).normalize();
    let mut n = Vector2::new(-t.y, t.x);
    let mut rho = n.dot(&a_s);
    if rho < 0.0 {
        n = -n;
        rho = -rho;
    }
    WallLine {
        alpha: n.y.atan2(n.x),
        rho,
        ends: [a_s, b_s],
        tangent: t,
    }
}

struct WallLine {
    alpha: f64,
    rho: f64,
    ends: [Vector2<f64>; 2],
    tangent: Vector2<f64>,
}

fn main() {
    let seeds: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let args: Vec<String> = std::env::args().collect();
    let world = match args.get(2) {
        Some(path) => World::from_file(std::path::Path::new(path)).expect("a world file"),
        None => World::default_world(),
    };
    let laser = world.laser.clone().expect("the world has a laser");
    let params = LineExtractorParams {
        sigma_range: laser.sigma_range,
        scale_by_residuals: args.get(3).is_some_and(|a| a == "rough"),
        ..LineExtractorParams::default()
    };
    // Signed angle error (measured - true), rad, and its count, for segments on the
    // sensor's right and left (by the segment's middle), and by length.
    let mut alpha_by_side = [(0usize, 0.0f64); 2];
    let mut alpha_by_length = [(0usize, 0.0f64); 4];
    let mut flipped = 0usize;
    let mut by_points: Vec<Bin> = vec![Bin::default(); 5];
    let mut by_range: Vec<Bin> = vec![Bin::default(); 4];
    let mut by_incidence: Vec<Bin> = vec![Bin::default(); 4];
    let mut all = Bin::default();
    let mut by_ends: Vec<Bin> = vec![Bin::default(); 3];
    let mut ends_all = Bin::default();
    let mut ends_by_kind: Vec<Bin> = vec![Bin::default(); 2];
    let mut unmatched = 0usize;
    let mut rho_bias = 0.0;
    // Jump-edge ends by range of the end: (count, sum of signed error away from the wall's
    // middle, sum of squared normalized error).
    let mut jump_by_range = [(0usize, 0.0f64, 0.0f64); 4];
    for seed in 1..=seeds {
        let run = simulate(&world, seed).expect("simulates");
        let mut robot = Pose2::default();
        for timed in &run.dataset.events {
            match &timed.event {
                Event::GroundTruth { pose, .. } => robot = *pose,
                Event::Scan {
                    scan,
                    robot_from_sensor,
                } => {
                    let sensor = Pose2::new(
                        robot_from_sensor.translation.x,
                        robot_from_sensor.translation.y,
                        robot_from_sensor.yaw,
                    );
                    let world_from_sensor = robot.compose(&sensor);
                    let walls: Vec<WallLine> = run
                        .truth
                        .walls
                        .iter()
                        .map(|(a, b)| wall_in_sensor(&world_from_sensor, a, b))
                        .collect();
                    let vertices: Vec<Vector2<f64>> = walls.iter().flat_map(|w| w.ends).collect();
                    for segment in extract_segments(scan, &params) {
                        let info = match segment.cov.try_inverse() {
                            Some(i) => i,
                            None => continue,
                        };
                        // The true wall: the line both ends lie on, within the wall's extent.
                        let best = walls
                            .iter()
                            .filter(|w| {
                                // On the wall's line (collinear walls split at T-junctions
                                // are one line).
                                segment
                                    .ends
                                    .iter()
                                    .all(|e| (e - w.ends[0]).perp(&w.tangent).abs() < 0.15)
                            })
                            .map(|w| {
                                let e = Vector2::new(
                                    wrap_angle(segment.alpha - w.alpha),
                                    segment.rho - w.rho,
                                );
                                ((e.transpose() * info * e)[0], e, w)
                            })
                            .min_by(|a, b| a.0.total_cmp(&b.0));
                        let Some((nis, error, wall)) = best else {
                            unmatched += 1;
                            continue;
                        };
                        rho_bias += error.y;
                        let middle = 0.5 * (segment.ends[0] + segment.ends[1]);
                        let side = usize::from(middle.y > 0.0);
                        // A line through (nearly) the sensor can flip its normal: not a bias.
                        let angle_error = if error.x.abs() > std::f64::consts::FRAC_PI_4 {
                            flipped += 1;
                            0.0
                        } else {
                            error.x
                        };
                        alpha_by_side[side].0 += 1;
                        alpha_by_side[side].1 += angle_error;
                        let length_bin =
                            bin((segment.ends[1] - segment.ends[0]).norm(), [1.0, 2.0, 4.0]);
                        alpha_by_length[length_bin].0 += 1;
                        alpha_by_length[length_bin].1 += angle_error;
                        all.add(nis, 9.21);
                        let p = match segment.points {
                            0..=14 => 0,
                            15..=29 => 1,
                            30..=59 => 2,
                            60..=119 => 3,
                            _ => 4,
                        };
                        by_points[p].add(nis, 9.21);
                        let r = bin(segment.rho, [1.0, 2.0, 4.0]);
                        by_range[r].add(nis, 9.21);
                        // Incidence at the segment's middle: angle between beam and normal.
                        let mid = 0.5 * (segment.ends[0] + segment.ends[1]);
                        let incidence = wrap_angle(mid.y.atan2(mid.x) - segment.alpha)
                            .abs()
                            .to_degrees();
                        let i = bin(incidence, [30.0, 50.0, 65.0]);
                        by_incidence[i].add(nis, 9.21);
                        let corner_end = (0..2).any(|k| segment.real[k] && segment.corner[k]);
                        let kind = if corner_end {
                            2
                        } else {
                            usize::from(segment.real[0] || segment.real[1])
                        };
                        by_ends[kind].add(nis, 9.21);
                        let end_sigmas = segment
                            .to_observation(params.sigma_range)
                            .map_or([params.sigma_range; 2], |o| o.sigma_endpoints);
                        for (k, &sigma) in end_sigmas.iter().enumerate() {
                            if !segment.real[k] {
                                continue;
                            }
                            let end = segment.ends[k];
                            // Every wall vertex on this wall's line is where it may end
                            // (T-junctions with the outer walls split them).
                            let true_end = vertices
                                .iter()
                                .filter(|v| (*v - wall.ends[0]).perp(&wall.tangent).abs() < 0.01)
                                .min_by(|a, b| (*a - end).norm().total_cmp(&(*b - end).norm()))
                                .copied()
                                .unwrap_or(end);
                            let along = (end - true_end).dot(&wall.tangent);
                            let z2 = (along / sigma).powi(2);
                            ends_all.add(z2, 6.63);
                            // A corner (placed at the lines' intersection) or a jump edge.
                            let kind = usize::from(!segment.corner[k]);
                            ends_by_kind[kind].add(z2, 6.63);
                            if kind == 1 {
                                // Positive: the end placed beyond the true end (the wall too long).
                                let inward = (segment.ends[1 - k] - end).normalize();
                                let beyond = -(end - true_end).dot(&inward);
                                let r = bin(end.norm(), [2.0, 4.0, 6.0]);
                                jump_by_range[r].0 += 1;
                                jump_by_range[r].1 += beyond;
                                jump_by_range[r].2 += z2;
                            }
                        }
                    }
                }
                _ => {}
            }
        }
    }
    println!("line NIS (2 dof; 99% at 9.21), seeds 1..={seeds}, unmatched {unmatched}");
    println!("{}", all.line("all"));
    println!("mean rho error {:+.4} m", rho_bias / all.n.max(1) as f64);
    println!("signed angle errors (lines more than 45 degrees off, {flipped}, counted as 0):");
    let sides = alpha_by_side.iter().zip(["right", "left"]);
    let lengths = alpha_by_length
        .iter()
        .zip(["length <1 m", "1-2 m", "2-4 m", ">=4 m"]);
    for (b, l) in sides.chain(lengths) {
        println!(
            "{l:>28}: n {:6}  mean signed angle error {:+.3} deg",
            b.0,
            (b.1 / b.0.max(1) as f64).to_degrees()
        );
    }
    for (b, l) in by_points
        .iter()
        .zip(["points <15", "15-29", "30-59", "60-119", ">=120"])
    {
        println!("{}", b.line(l));
    }
    for (b, l) in by_range.iter().zip(["rho <1 m", "1-2 m", "2-4 m", ">=4 m"]) {
        println!("{}", b.line(l));
    }
    for (b, l) in by_incidence
        .iter()
        .zip(["incidence <30 deg", "30-50", "50-65", ">=65"])
    {
        println!("{}", b.line(l));
    }
    for (b, l) in by_ends
        .iter()
        .zip(["no real end", "a jump-edge end", "a corner end"])
    {
        println!("{}", b.line(l));
    }
    println!("real ends, squared normalized error along the wall (1 dof; 99% at 6.63)");
    println!("{}", ends_all.line("all real ends"));
    for (b, l) in ends_by_kind.iter().zip(["corner ends", "jump-edge ends"]) {
        println!("{}", b.line(l));
    }
    for (b, l) in jump_by_range
        .iter()
        .zip(["end <2 m", "2-4 m", "4-6 m", ">=6 m"])
    {
        println!(
            "{l:>28}: n {:6}  mean signed error beyond the true end {:+.4} m  mean z^2 {:.2}",
            b.0,
            b.1 / b.0.max(1) as f64,
            b.2 / b.0.max(1) as f64
        );
    }
}
