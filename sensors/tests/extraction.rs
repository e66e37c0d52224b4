//! The scan front-ends on simulated scans of the default world: extracted walls match the
//! true walls (angle within 1 degree, distance within 3 cm at 5 cm range noise), their
//! covariances are consistent, real ends sit at true wall ends, and poles have the right
//! radius (within 2 cm).

use slam_core::nalgebra::Vector2;
use slam_core::{Pose2, Pose3, RobotPose, wrap_angle};
use slam_sensors::extract::{
    LineExtractorParams, PoleExtractorParams, extract_poles, extract_segments,
};
use slam_sensors::sim::{TrueMap, World, simulate};
use slam_sensors::{Event, LaserScan};

/// The 99.9% quantile of the chi-square distribution with 2 degrees of freedom.
const CHI2_2_999: f64 = 13.8;

/// Scans with their true sensor pose, every `stride`-th scan of a default-world run.
fn scans(sigma_range: f64, stride: usize, seed: u64) -> (Vec<(LaserScan, Pose2, Pose3)>, TrueMap) {
    let mut world = World::default_world();
    world.camera = None;
    if let Some(laser) = world.laser.as_mut() {
        laser.sigma_range = sigma_range;
    }
    let run = simulate(&world, seed).unwrap();
    let mut pose = Pose2::identity();
    let mut out = Vec::new();
    for e in run.dataset.events {
        match e.event {
            Event::GroundTruth { pose: p, .. } => pose = p,
            Event::Scan {
                scan,
                robot_from_sensor,
            } => out.push((scan, pose, robot_from_sensor)),
            _ => {}
        }
    }
    let picked = out.into_iter().step_by(stride).collect();
    (picked, run.truth)
}

/// The true wall's line `(alpha, rho)` in the sensor frame, as the extractor reports lines.
fn line_in_sensor(a: Vector2<f64>, b: Vector2<f64>, sensor: &Pose2) -> (f64, f64) {
    let (a, b) = (
        sensor.inverse_transform_point(&a),
        sensor.inverse_transform_point(&b),
    );
    let d = b - a;
    let mut n = Vector2::new(-d.y, d.x).normalize();
    if n.dot(&a) < 0.0 {
        n = -n;
    }
    (n.y.atan2(n.x), n.dot(&a))
}

fn distance_to_segment(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let e = b - a;
    let t = ((p - a).dot(&e) / e.norm_squared()).clamp(0.0, 1.0);
    (p - (a + e * t)).norm()
}

#[test]
fn walls_are_recovered_at_five_centimetre_noise() {
    let sigma = 0.05;
    let (scans, truth) = scans(sigma, 15, 11);
    let params = LineExtractorParams {
        sigma_range: sigma,
        ..Default::default()
    };
    let (mut checked, mut total, mut chi2_sum, mut chi2_count, mut chi2_outliers) =
        (0, 0, 0.0, 0, 0);
    let (mut real_ends, mut real_at_true_end) = (0, 0);
    for (scan, pose, mount) in &scans {
        let sensor = pose.world_from_sensor(mount);
        let sensor2 = Pose2::new(sensor.translation.x, sensor.translation.y, sensor.yaw);
        for s in extract_segments(scan, &params) {
            // The true wall under the segment: the one closest to its midpoint in the world.
            let mid = sensor2.transform_point(&((s.ends[0] + s.ends[1]) / 2.0));
            let (a, b) = truth
                .walls
                .iter()
                .min_by(|x, y| {
                    distance_to_segment(&mid, &x.0, &x.1)
                        .total_cmp(&distance_to_segment(&mid, &y.0, &y.1))
                })
                .unwrap();
            let (alpha, rho) = line_in_sensor(*a, *b, &sensor2);
            let (d_alpha, d_rho) = (wrap_angle(s.alpha - alpha), s.rho - rho);
            // Walls the scan resolves: the extractor's own 3-sigma within the bounds.
            total += 1;
            let resolved =
                3.0 * s.cov[(0, 0)].sqrt() < 1f64.to_radians() && 3.0 * s.cov[(1, 1)].sqrt() < 0.03;
            if resolved {
                checked += 1;
                assert!(
                    d_alpha.abs() < 1f64.to_radians(),
                    "angle off by {:.3} deg: {s:?} world ends {:?} {:?} true wall {a:?} {b:?} sensor {sensor2:?}",
                    d_alpha.to_degrees(),
                    sensor2.transform_point(&s.ends[0]),
                    sensor2.transform_point(&s.ends[1])
                );
                assert!(d_rho.abs() < 0.03, "distance off by {d_rho:.3} m: {s:?}");
            }
            let e = slam_core::nalgebra::Vector2::new(d_alpha, d_rho);
            let chi2 = (e.transpose() * s.cov.try_inverse().unwrap() * e)[(0, 0)];
            chi2_count += 1;
            chi2_sum += chi2;
            chi2_outliers += usize::from(chi2 > CHI2_2_999);
            for side in 0..2 {
                if s.real[side] {
                    real_ends += 1;
                    let end = sensor2.transform_point(&s.ends[side]);
                    let near_true_end = truth
                        .walls
                        .iter()
                        .any(|(a, b)| (end - a).norm() < 0.2 || (end - b).norm() < 0.2);
                    real_at_true_end += usize::from(near_true_end);
                }
            }
        }
    }
    assert!(
        checked >= 100 && 2 * checked >= total,
        "only {checked} of {total} segments resolved"
    );
    // The line covariance from the range noise is consistent: chi-square with 2 dof, mean
    // near 2 and few beyond its 99.9% quantile.
    let mean_chi2 = chi2_sum / chi2_count as f64;
    let outliers = chi2_outliers as f64 / chi2_count as f64;
    assert!(
        mean_chi2 < 4.0 && outliers < 0.02,
        "mean chi2 {mean_chi2}, {chi2_outliers} of {chi2_count} beyond 13.8"
    );
    // Ends flagged real lie at true wall ends (corners, doorway jambs).
    let precision = real_at_true_end as f64 / real_ends as f64;
    assert!(
        real_ends >= 50 && precision >= 0.9,
        "{real_at_true_end} of {real_ends} real ends at true wall ends"
    );
    println!(
        "{checked} of {total} segments resolved, all within 1 deg / 3 cm; mean chi2 {mean_chi2:.2}, {chi2_outliers} beyond 13.8; real-end precision {precision:.3} of {real_ends}"
    );
}

#[test]
fn poles_have_the_right_radius() {
    let sigma = 0.02;
    let (scans, truth) = scans(sigma, 3, 5);
    let params = PoleExtractorParams {
        sigma_range: sigma,
        ..Default::default()
    };
    let (mut found, mut good) = (0, 0);
    for (scan, pose, mount) in &scans {
        let sensor = pose.world_from_sensor(mount);
        let sensor2 = Pose2::new(sensor.translation.x, sensor.translation.y, sensor.yaw);
        for p in extract_poles(scan, &params) {
            let centre = sensor2.transform_point(&p.centre);
            let Some((_, radius)) = truth.poles.iter().find(|(c, _)| (c - centre).norm() < 0.15)
            else {
                panic!("a pole was extracted where there is none: {centre:?} ({p:?})");
            };
            found += 1;
            good += usize::from((p.radius - radius).abs() < 0.02);
        }
    }
    assert!(found >= 30, "only {found} pole sightings");
    assert!(
        good as f64 >= 0.9 * found as f64,
        "{good} of {found} radii within 2 cm"
    );
    println!("{good} of {found} pole radii within 2 cm");
}

#[test]
fn invalid_readings_never_become_points() {
    let ranges = vec![f64::NAN, -1.0, 0.0, f64::INFINITY, 8.0, 2.0, 2.0, 2.0];
    let scan = LaserScan::new(-0.1, 0.1, ranges, 0.0, 8.0).unwrap();
    let points = scan.points();
    assert_eq!(
        points.iter().map(|p| p.index).collect::<Vec<_>>(),
        vec![5, 6, 7]
    );
    assert!(extract_segments(&scan, &LineExtractorParams::default()).is_empty());
    assert!(extract_poles(&scan, &PoleExtractorParams::default()).is_empty());
}
