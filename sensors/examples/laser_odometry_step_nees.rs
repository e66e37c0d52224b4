//! The laser odometry stream's increments against the truth, one scan interval at a time: the
//! NEES of each increment (between consecutive scans that have a true or reference pose at
//! their own time) under the covariance the stream gives it, and the mean of each axis's
//! squared error over its variance. 3 (1 per axis) for a calibrated covariance.
//!
//! This is the stream a filter sees with `[data.laser_odometry]` (a local map of key scans,
//! not the scan-to-scan matches of the `laser_odometry_nees` example), with the settings of a
//! `slam` config's `[data.laser_odometry]` table. Each further argument is a seed of the
//! built-in world or the path of a CARMEN log with reference poses (a Radish corrected log, or
//! one made noisy by `noisy_carmen.py`).
//!
//! ```sh
//! cargo run --release -p slam-sensors --example laser_odometry_step_nees -- \
//!     configs/carmen-walls.toml 1 2 3 /tmp/rb/logs/fhw-1.log
//! ```

use std::path::Path;

use slam_core::nalgebra::{DMatrix, Matrix3, Vector3};
use slam_core::{MotionModel, Pose2, wrap_angle};
use slam_sensors::data::{CarmenOptions, read_carmen};
use slam_sensors::events::{Dataset, Event};
use slam_sensors::laser_odometry::{LaserOdometryParams, laser_odometry};
use slam_sensors::sim::{World, simulate};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// An increment's NEES, each axis's squared error over its variance, and each axis's
/// deviation (m, m, rad).
type IncrementError = (f64, [f64; 3], [f64; 3]);

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
        "data: increments, NEES mean / median (chi-square(3): 3 / 2.37), per axis x / y / heading \
         (1 each), median deviation x / y (mm) / heading (degrees)"
    );
    for source in args {
        let data = match source.parse::<u64>() {
            Ok(seed) => simulate(&World::default_world(), seed)?.dataset,
            Err(_) => read_carmen(Path::new(&source), &CarmenOptions::default())?,
        };
        let (matched, _) = laser_odometry(data, &params)?;
        let errors = increment_errors(&matched)?;
        let nees: Vec<f64> = errors.iter().map(|(nees, ..)| *nees).collect();
        let axis = |a: usize| mean(errors.iter().map(|(_, per_axis, _)| per_axis[a]));
        let deviation = |a: usize| median(errors.iter().map(|(_, _, sigma)| sigma[a]).collect());
        println!(
            "{source}: {}, {:.2} / {:.2}, {:.2} / {:.2} / {:.2}, {:.1} / {:.1} / {:.3}",
            nees.len(),
            mean(nees.iter().copied()),
            median(nees),
            axis(0),
            axis(1),
            axis(2),
            1e3 * deviation(0),
            1e3 * deviation(1),
            deviation(2).to_degrees()
        );
    }
    Ok(())
}

/// Per scan interval: the increment's NEES and each axis's squared error over its variance.
fn increment_errors(dataset: &Dataset) -> Result<Vec<IncrementError>> {
    let mut errors = Vec::new();
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
        if let (Some(before), Some((estimate, covariance))) = (truth_at_last_scan, increment)
            && let Some(information) = covariance.try_inverse()
        {
            let real = before.between(&now);
            let error = Vector3::new(
                estimate.x - real.x,
                estimate.y - real.y,
                wrap_angle(estimate.theta - real.theta),
            );
            let per_axis = [0, 1, 2].map(|a| error[a] * error[a] / covariance[(a, a)]);
            let sigma = [0, 1, 2].map(|a| covariance[(a, a)].max(0.0).sqrt());
            errors.push((error.dot(&(information * error)), per_axis, sigma));
        }
        (increment, scan_time, truth_at_last_scan) = (None, None, Some(now));
    }
    Ok(errors)
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

fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, count) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    sum / count.max(1) as f64
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}
