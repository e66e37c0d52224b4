//! Calibration of the laser odometry's covariance on a CARMEN log with reference poses: every
//! pair of consecutive scans is matched from the reference increment plus seeded odometry
//! noise (the `slam` command's `[data.odometry_from_poses]` defaults: 5 % of the distance,
//! 5 % of the turn plus 0.02 rad per metre), and the match's error against the reference
//! increment is normalized by the covariance it reports (NEES; 3 for a calibrated covariance),
//! for several values of `information_divisor`. It also chains the matches and reports the
//! heading and position drift at the end, against chaining the noisy odometry.
//!
//! ```sh
//! cargo run --release -p slam-sensors --example laser_odometry_nees -- \
//!     [LOG (default ../shared/datasets/radish-carmen-corrected/intel-corrected.log.gz)] [SEEDS (3)]
//! ```

use std::path::PathBuf;

use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use slam_core::nalgebra::{Matrix3, Vector2, Vector3};
use slam_core::{Pose2, wrap_angle};
use slam_sensors::data::{CarmenOptions, read_carmen};
use slam_sensors::events::Event;
use slam_sensors::laser_odometry::{LaserOdometryParams, match_scans};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().unwrap_or_else(|| {
        "../shared/datasets/radish-carmen-corrected/intel-corrected.log.gz".into()
    }));
    let seeds: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(3);
    let dataset = read_carmen(&path, &CarmenOptions::default())?;
    // Each scan's points (sensor frame) and the reference pose that follows it.
    let mut scans: Vec<(Vec<Vector2<f64>>, Pose2)> = Vec::new();
    let mut points: Option<Vec<Vector2<f64>>> = None;
    let params = LaserOdometryParams::default();
    for timed in &dataset.events {
        match &timed.event {
            Event::Scan { scan, .. } => {
                points = Some(
                    scan.points()
                        .into_iter()
                        .filter(|p| p.range <= params.max_range)
                        .map(|p| p.position)
                        .collect(),
                );
            }
            Event::GroundTruth { pose, .. } => {
                if let Some(p) = points.take() {
                    scans.push((p, *pose));
                }
            }
            _ => {}
        }
    }
    println!(
        "{}: {} scans with reference poses",
        path.display(),
        scans.len()
    );
    println!(
        "divisor  seed  matched  NEES mean  NEES median  heading err sd [deg]  drift: laser heading [deg] / position [m], odometry heading / position"
    );
    for divisor in [1.0, 4.0, 10.0, 20.0] {
        for seed in 1..=seeds {
            report(&scans, divisor, seed);
        }
    }
    Ok(())
}

fn report(scans: &[(Vec<Vector2<f64>>, Pose2)], divisor: f64, seed: u64) {
    let params = LaserOdometryParams {
        information_divisor: divisor,
        ..Default::default()
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut nees = Vec::new();
    let mut heading_errors = Vec::new();
    let (mut laser, mut odometry) = (scans[0].1, scans[0].1);
    for pair in scans.windows(2) {
        let truth = pair[0].1.between(&pair[1].1);
        let d = truth.translation().norm();
        let sigma_t = 0.05 * d + 0.005;
        let sigma_r = 0.05 * truth.theta.abs() + 0.02 * d + 0.002;
        let mut draw = || -> f64 { StandardNormal.sample(&mut rng) };
        let guess = Pose2::new(
            truth.x + sigma_t * draw(),
            truth.y + sigma_t * draw(),
            truth.theta + sigma_r * draw(),
        );
        let prior = Matrix3::from_diagonal(&Vector3::new(
            sigma_t * sigma_t,
            sigma_t * sigma_t,
            sigma_r * sigma_r,
        ));
        odometry = odometry.compose(&guess);
        match match_scans(&pair[0].0, &pair[1].0, &guess, &prior, &params) {
            Ok(Some(m)) => {
                let e = Vector3::new(
                    m.reference_from_current.x - truth.x,
                    m.reference_from_current.y - truth.y,
                    wrap_angle(m.reference_from_current.theta - truth.theta),
                );
                if let Some(information) = m.covariance.try_inverse() {
                    nees.push(e.dot(&(information * e)));
                }
                heading_errors.push(e.z);
                laser = laser.compose(&m.reference_from_current);
            }
            _ => laser = laser.compose(&guess),
        }
    }
    let end = scans[scans.len() - 1].1;
    let drift = |p: &Pose2| {
        (
            wrap_angle(p.theta - end.theta).to_degrees(),
            (p.translation() - end.translation()).norm(),
        )
    };
    let mean = nees.iter().sum::<f64>() / nees.len().max(1) as f64;
    nees.sort_by(f64::total_cmp);
    let median = nees.get(nees.len() / 2).copied().unwrap_or(f64::NAN);
    let sd = (heading_errors.iter().map(|e| e * e).sum::<f64>()
        / heading_errors.len().max(1) as f64)
        .sqrt()
        .to_degrees();
    let (lh, lp) = drift(&laser);
    let (oh, op) = drift(&odometry);
    println!(
        "{divisor:7.1}  {seed:4}  {:7}  {mean:9.2}  {median:11.2}  {sd:20.2}  {lh:6.1} / {lp:5.2}, {oh:6.1} / {op:5.2}",
        nees.len()
    );
}
