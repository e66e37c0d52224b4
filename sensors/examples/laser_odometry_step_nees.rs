//! The laser odometry stream's increments against the truth: the NEES of the motion between
//! scans that have a true or reference pose at their own time, under the covariance the stream
//! gives it, over one scan interval and compounded over longer stretches. 3 (1 per axis) for a
//! calibrated covariance.
//!
//! This is the stream a filter sees with `[data.laser_odometry]` (a local map of key scans,
//! not the scan-to-scan matches of the `laser_odometry_nees` example), with the settings of a
//! `slam` config's `[data.laser_odometry]` table. Each further argument is a seed of the
//! built-in world or the path of a CARMEN log with reference poses (a Radish corrected log, or
//! one made noisy by `noisy_carmen.py`). Against reference poses, the reference's own error
//! between two scans counts as the odometry's: it weighs most over one interval, and less as
//! the compounded covariance grows over longer stretches.
//!
//! ```sh
//! cargo run --release -p slam-sensors --example laser_odometry_step_nees -- \
//!     configs/carmen-walls.toml 1 2 3 /tmp/rb/logs/fhw-1.log
//! ```

use std::path::Path;

use slam_core::nalgebra::{Matrix3, Vector3};
use slam_core::{MotionModel, Pose2, nalgebra::DMatrix, wrap_angle};
use slam_sensors::data::{CarmenOptions, read_carmen};
use slam_sensors::events::{Dataset, Event};
use slam_sensors::laser_odometry::{LaserOdometryParams, laser_odometry};
use slam_sensors::sim::{World, simulate};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// The motion over one stretch between scans: the true (or reference) motion, the stream's
/// compounded motion and its covariance.
#[derive(Clone, Copy)]
struct Stretch {
    real: Pose2,
    estimate: Pose2,
    covariance: Matrix3<f64>,
}

/// Scan intervals compounded into the stretches whose errors are printed.
const HORIZONS: [usize; 4] = [1, 10, 50, 200];

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let config = args
        .next()
        .ok_or("usage: laser_odometry_step_nees CONFIG [SEED | CARMEN_LOG]...")?;
    let table: toml::Value = toml::from_str(&std::fs::read_to_string(&config)?)?;
    let params: LaserOdometryParams = table
        .get("data")
        .and_then(|data| data.get("laser_odometry"))
        .ok_or_else(|| format!("{config} has no [data.laser_odometry] table"))?
        .clone()
        .try_into()?;
    println!(
        "data, scan intervals per stretch: stretches, NEES mean / median (chi-square(3): \
         3 / 2.37), per axis x / y / heading (1 each), median deviation x / y (mm) / heading \
         (degrees)"
    );
    for source in args {
        let data = match source.parse::<u64>() {
            Ok(seed) => simulate(&World::default_world(), seed)?.dataset,
            Err(_) => read_carmen(Path::new(&source), &CarmenOptions::default())?,
        };
        let (matched, _) = laser_odometry(data, &params)?;
        let intervals = scan_intervals(&matched)?;
        for horizon in HORIZONS {
            let stretches: Vec<Stretch> = intervals
                .chunks_exact(horizon)
                .map(|chunk| chunk.iter().copied().reduce(join).expect("a full chunk"))
                .collect();
            if !stretches.is_empty() {
                println!("{source}, {horizon}: {}", summary(&stretches));
            }
        }
        println!("{source}: {}", heading_drift(&intervals));
    }
    Ok(())
}

/// Deviations beyond which a scan interval's heading error counts as an outlier.
const OUTLIER_SIGMAS: f64 = 5.0;

/// Where the heading error comes from, as one line: the intervals whose heading error is
/// beyond [`OUTLIER_SIGMAS`] of the deviation the stream claims (how many, the sum of their
/// errors against the sum of all, the largest: interval, degrees, deviations); the errors'
/// least-squares slope on each interval's own turn (a turn scale error); and the running sum
/// of the errors every 50 intervals (the drift of the path's heading, the reference's
/// jitter aside).
fn heading_drift(intervals: &[Stretch]) -> String {
    let errors: Vec<(usize, f64, f64)> = intervals
        .iter()
        .enumerate()
        .map(|(k, stretch)| {
            let error = wrap_angle(stretch.estimate.theta - stretch.real.theta);
            let sigma = stretch.covariance[(2, 2)].max(0.0).sqrt();
            (k, error, error / sigma)
        })
        .collect();
    let total: f64 = errors.iter().map(|(_, error, _)| error).sum();
    let mut outliers: Vec<(usize, f64, f64)> = errors
        .iter()
        .copied()
        .filter(|(_, _, sigmas)| sigmas.abs() > OUTLIER_SIGMAS)
        .collect();
    let outlying: f64 = outliers.iter().map(|(_, error, _)| error).sum();
    outliers.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let largest: Vec<String> = outliers
        .iter()
        .take(5)
        .map(|(k, error, sigmas)| format!("{k}: {:+.2} ({sigmas:+.0})", error.to_degrees()))
        .collect();
    let (mut product, mut turned) = (0.0, 0.0);
    for (stretch, (_, error, _)) in intervals.iter().zip(&errors) {
        product += error * stretch.real.theta;
        turned += stretch.real.theta * stretch.real.theta;
    }
    let mut running = 0.0;
    let mut drift = Vec::new();
    for (k, error, _) in &errors {
        running += error;
        if (k + 1) % 50 == 0 {
            drift.push(format!("{:+.1}", running.to_degrees()));
        }
    }
    format!(
        "{} of {} intervals beyond {OUTLIER_SIGMAS} deviations in heading, their errors summing \
         to {:+.2} of the {:+.2} degrees of all (largest: {}); heading error per radian turned \
         in an interval {:+.2} %; running sum every 50 intervals: {} degrees",
        outliers.len(),
        intervals.len(),
        outlying.to_degrees(),
        total.to_degrees(),
        largest.join(", "),
        100.0 * product / turned.max(f64::MIN_POSITIVE),
        drift.join(" ")
    )
}

/// The stretches from each scan with a truth to the next.
fn scan_intervals(dataset: &Dataset) -> Result<Vec<Stretch>> {
    let mut intervals = Vec::new();
    let (mut truth, mut scan_time): (Option<(f64, Pose2)>, Option<f64>) = (None, None);
    let mut truth_at_last_scan: Option<Pose2> = None;
    // The motion since the last scan with a truth, compounded, and its covariance.
    let mut increment: Option<(Pose2, Matrix3<f64>)> = None;
    for timed in &dataset.events {
        match &timed.event {
            Event::GroundTruth { pose, .. } => truth = Some((timed.time, *pose)),
            Event::Scan { .. } => scan_time = Some(timed.time),
            Event::Motion(motion) => increment = Some(compound(increment, motion.as_ref())?),
            _ => {}
        }
        // Truth and scan of the same time, in either order.
        let (Some(time), Some((truth_time, now))) = (scan_time, truth) else {
            continue;
        };
        if time != truth_time {
            continue;
        }
        if let (Some(before), Some((estimate, covariance))) = (truth_at_last_scan, increment) {
            intervals.push(Stretch {
                real: before.between(&now),
                estimate,
                covariance,
            });
        }
        (increment, scan_time, truth_at_last_scan) = (None, None, Some(now));
    }
    Ok(intervals)
}

/// `first` followed by `second` (eq. 26 for the covariance).
fn join(first: Stretch, second: Stretch) -> Stretch {
    let (estimate, d_first, d_second) = first.estimate.compose_with_jacobians(&second.estimate);
    Stretch {
        real: first.real.compose(&second.real),
        estimate,
        covariance: d_first * first.covariance * d_first.transpose()
            + d_second * second.covariance * d_second.transpose(),
    }
}

/// `so_far` followed by `motion`, with the covariance of the compound (eq. 26).
fn compound(
    so_far: Option<(Pose2, Matrix3<f64>)>,
    motion: &dyn MotionModel<Pose2>,
) -> Result<(Pose2, Matrix3<f64>)> {
    let (pose, covariance) = so_far.unwrap_or((Pose2::identity(), Matrix3::zeros()));
    let prediction = motion.predict(&pose)?;
    let covariance = prediction.propagate_covariance(&DMatrix::from_iterator(
        3,
        3,
        covariance.iter().copied(),
    ))?;
    Ok((
        prediction.pose,
        Matrix3::from_iterator(covariance.iter().copied()),
    ))
}

/// The stretches' NEES (mean / median), per-axis squared errors over variances and median
/// deviations, as one line.
fn summary(stretches: &[Stretch]) -> String {
    let mut nees = Vec::new();
    let (mut per_axis, mut deviations) = ([0.0; 3], [Vec::new(), Vec::new(), Vec::new()]);
    for stretch in stretches {
        let error = Vector3::new(
            stretch.estimate.x - stretch.real.x,
            stretch.estimate.y - stretch.real.y,
            wrap_angle(stretch.estimate.theta - stretch.real.theta),
        );
        let Some(information) = stretch.covariance.try_inverse() else {
            continue;
        };
        nees.push(error.dot(&(information * error)));
        for axis in 0..3 {
            let variance = stretch.covariance[(axis, axis)];
            per_axis[axis] += error[axis] * error[axis] / variance / stretches.len() as f64;
            deviations[axis].push(variance.max(0.0).sqrt());
        }
    }
    let [x, y, heading] = deviations.map(median);
    format!(
        "{}, {:.2} / {:.2}, {:.2} / {:.2} / {:.2}, {:.1} / {:.1} / {:.3}",
        nees.len(),
        nees.iter().sum::<f64>() / nees.len().max(1) as f64,
        median(nees),
        per_axis[0],
        per_axis[1],
        per_axis[2],
        1e3 * x,
        1e3 * y,
        heading.to_degrees()
    )
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}
