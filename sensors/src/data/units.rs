//! Plausibility of units: the evidence that a log holds degrees where the format has radians,
//! or centimetres where it has metres, and the error that names the file, the record and the
//! unit (the input policy of [`crate::data`]).
//!
//! The checks only look at statistics of many readings, never at one: a single odd reading is
//! a glitch for the reader to skip and count, not evidence about units. Each check needs at
//! least [`MIN_EVIDENCE`] readings.

use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::Path;

use crate::error::SensorError;

/// The fewest readings a unit check decides on.
pub(crate) const MIN_EVIDENCE: usize = 10;

/// How many records of a kind a check keeps (bounded memory on any log).
const SAMPLES: usize = 2000;

/// The median of `values` (`None` when empty).
pub(crate) fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(values[values.len() / 2])
}

/// Angles that a format keeps in `[-pi, pi]`: how many were seen and how many were outside.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct AngleCount {
    seen: usize,
    outside: usize,
    largest: f64,
}

impl AngleCount {
    /// Counts one angle.
    pub(crate) fn add(&mut self, angle: f64) {
        self.seen += 1;
        if angle.abs() > PI + 1e-6 {
            self.outside += 1;
        }
        self.largest = self.largest.max(angle.abs());
    }

    /// An error when a quarter or more of at least [`MIN_EVIDENCE`] angles are outside
    /// `[-pi, pi]` (angles in degrees mostly are).
    pub(crate) fn check(&self, file: &Path, what: &str) -> Result<(), SensorError> {
        if self.seen >= MIN_EVIDENCE && 4 * self.outside >= self.seen {
            return Err(SensorError::Input(format!(
                "{}: {} of {} {what} are outside [-pi, pi] (largest {:.4}): they look like \
                 degrees, and the format's angles are radians",
                file.display(),
                self.outside,
                self.seen,
                self.largest
            )));
        }
        Ok(())
    }
}

/// The rb2d first pass's evidence: parameters, bearings, headings, and samples of ranges and
/// odometry with the true poses and landmarks, to compare units with the truth.
#[derive(Debug, Default)]
pub(crate) struct Rb2dEvidence {
    /// `PARAM max_range` and `sigma_r` when given.
    pub max_range: Option<f64>,
    pub sigma_r: Option<f64>,
    /// OBS bearings.
    pub bearings: AngleCount,
    /// GT headings.
    pub headings: AngleCount,
    /// OBS ranges seen, and those beyond `max_range` by more than 5 sigma.
    ranges: usize,
    ranges_beyond: usize,
    /// The first OBS with a landmark id: `(step, id, range)`.
    observations: Vec<(u64, u64, f64)>,
    /// The first ODOM increments: `(step, dx, dy, dth)`.
    odometry: Vec<(u64, f64, f64, f64)>,
    /// True poses of the steps sampled.
    truth: HashMap<u64, [f64; 3]>,
    /// Landmark positions.
    landmarks: HashMap<u64, [f64; 2]>,
}

impl Rb2dEvidence {
    /// Takes one line's fields (anything that does not parse is left to the reader).
    pub(crate) fn add(&mut self, fields: &[&str]) {
        let number = |i: usize| fields.get(i).and_then(|f| f.parse::<f64>().ok());
        let integer = |i: usize| fields.get(i).and_then(|f| f.parse::<i64>().ok());
        let finite = |v: Option<f64>| v.filter(|v| v.is_finite());
        match fields.first().copied() {
            Some("PARAM") => match (fields.get(1).copied(), finite(number(2))) {
                (Some("max_range"), Some(v)) => self.max_range = Some(v),
                (Some("sigma_r"), Some(v)) => self.sigma_r = Some(v),
                _ => {}
            },
            Some("LM") => {
                if let (Some(id), Some(x), Some(y)) =
                    (integer(1), finite(number(2)), finite(number(3)))
                    && let Ok(id) = u64::try_from(id)
                    && self.landmarks.len() < 100_000
                {
                    self.landmarks.insert(id, [x, y]);
                }
            }
            Some("OBS") => {
                if let (Some(k), Some(id), Some(range), Some(bearing)) =
                    (integer(1), integer(2), finite(number(3)), finite(number(4)))
                {
                    self.observation(k, id, range, bearing);
                }
            }
            Some("ODOM") => {
                if let (Some(k), Some(dx), Some(dy), Some(dth)) = (
                    integer(1),
                    finite(number(3)),
                    finite(number(4)),
                    finite(number(5)),
                ) && let Ok(k) = u64::try_from(k)
                    && self.odometry.len() < SAMPLES
                {
                    self.odometry.push((k, dx, dy, dth));
                }
            }
            Some("GT") => {
                if let (Some(k), Some(x), Some(y), Some(th)) = (
                    integer(1),
                    finite(number(2)),
                    finite(number(3)),
                    finite(number(4)),
                ) && let Ok(k) = u64::try_from(k)
                {
                    self.headings.add(th);
                    if self.truth.len() < 2 * SAMPLES {
                        self.truth.insert(k, [x, y, th]);
                    }
                }
            }
            _ => {}
        }
    }

    fn observation(&mut self, k: i64, id: i64, range: f64, bearing: f64) {
        self.bearings.add(bearing);
        self.ranges += 1;
        let limit = self
            .max_range
            .map(|m| m + 5.0 * self.sigma_r.unwrap_or(0.0));
        if limit.is_some_and(|limit| range > limit) {
            self.ranges_beyond += 1;
        }
        if let (Ok(k), Ok(id)) = (u64::try_from(k), u64::try_from(id))
            && self.observations.len() < SAMPLES
        {
            self.observations.push((k, id, range));
        }
    }

    /// The first unit error the evidence shows, if any.
    pub(crate) fn check(&self, file: &Path) -> Result<(), SensorError> {
        self.bearings.check(file, "OBS bearings")?;
        self.headings.check(file, "GT headings")?;
        self.check_max_range(file)?;
        self.check_ranges_against_truth(file)?;
        self.check_odometry_against_truth(file)
    }

    fn check_max_range(&self, file: &Path) -> Result<(), SensorError> {
        if self.ranges >= MIN_EVIDENCE && 2 * self.ranges_beyond >= self.ranges {
            return Err(SensorError::Input(format!(
                "{}: {} of {} OBS ranges are beyond PARAM max_range {} m: are the ranges in \
                 centimetres or millimetres? rb2d ranges are metres (else PARAM max_range is \
                 wrong)",
                file.display(),
                self.ranges_beyond,
                self.ranges,
                self.max_range.unwrap_or(f64::NAN)
            )));
        }
        Ok(())
    }

    /// OBS ranges against the distances from the GT poses to the LM landmarks.
    fn check_ranges_against_truth(&self, file: &Path) -> Result<(), SensorError> {
        let mut ratios: Vec<f64> = self
            .observations
            .iter()
            .filter_map(|(k, id, range)| {
                let [x, y, _] = self.truth.get(k)?;
                let [lx, ly] = self.landmarks.get(id)?;
                let distance = (lx - x).hypot(ly - y);
                (distance > 1e-6).then_some(range / distance)
            })
            .collect();
        if ratios.len() < MIN_EVIDENCE {
            return Ok(());
        }
        ratio_error(
            file,
            "OBS ranges",
            "distances from the GT poses to the LM landmarks",
            median(&mut ratios),
        )
    }

    /// ODOM increments against the motion between consecutive GT poses.
    fn check_odometry_against_truth(&self, file: &Path) -> Result<(), SensorError> {
        let (mut moved, mut true_moved, mut turned, mut true_turned, mut n) =
            (0.0, 0.0, 0.0, 0.0, 0);
        for &(k, dx, dy, dth) in &self.odometry {
            let (Some(a), Some(b)) = (self.truth.get(&(k.wrapping_sub(1))), self.truth.get(&k))
            else {
                continue;
            };
            moved += dx.hypot(dy);
            true_moved += (b[0] - a[0]).hypot(b[1] - a[1]);
            turned += dth.abs();
            true_turned += slam_core::wrap_angle(b[2] - a[2]).abs();
            n += 1;
        }
        if n < MIN_EVIDENCE {
            return Ok(());
        }
        // Only where the robot really moved (or turned) is the ratio evidence.
        if true_moved > 1e-3 * n as f64 {
            ratio_error(
                file,
                "ODOM distances (dx, dy)",
                "the motion of the GT poses",
                Some(moved / true_moved),
            )?;
        }
        if true_turned > 1e-3 * n as f64 && turned / true_turned > 20.0 {
            return Err(SensorError::Input(format!(
                "{}: the ODOM turns (dth) are {:.0} times the turns of the GT poses: they look \
                 like degrees, and rb2d angles are radians",
                file.display(),
                turned / true_turned
            )));
        }
        Ok(())
    }
}

/// An error when `ratio` (of what a log says to what its truth says) is far from 1: 20 times
/// or more, or a twentieth or less.
fn ratio_error(
    file: &Path,
    what: &str,
    truth: &str,
    ratio: Option<f64>,
) -> Result<(), SensorError> {
    let Some(ratio) = ratio else {
        return Ok(());
    };
    if (1.0 / 20.0..20.0).contains(&ratio) {
        return Ok(());
    }
    let guess = match ratio {
        r if (50.0..200.0).contains(&r) => " (centimetres?)",
        r if (500.0..2000.0).contains(&r) => " (millimetres?)",
        _ => "",
    };
    Err(SensorError::Input(format!(
        "{}: the {what} are {ratio:.3} times the {truth} (median){guess}: the format's unit is \
         the metre",
        file.display()
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_and_angle_counts() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut []), None);
        let mut angles = AngleCount::default();
        for k in 0..20 {
            angles.add(if k < 4 { 90.0 } else { 0.5 });
        }
        assert!(angles.check(Path::new("f"), "bearings").is_ok());
        angles.add(100.0);
        angles.add(-100.0);
        let e = angles
            .check(Path::new("f"), "bearings")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("6 of 22 bearings") && e.contains("degrees"),
            "{e}"
        );
    }

    #[test]
    fn ratios_far_from_one_name_the_unit() {
        let file = Path::new("log");
        assert!(ratio_error(file, "ranges", "truth", Some(1.02)).is_ok());
        assert!(ratio_error(file, "ranges", "truth", None).is_ok());
        let e = ratio_error(file, "ranges", "truth", Some(100.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("centimetres"), "{e}");
        let e = ratio_error(file, "ranges", "truth", Some(1000.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("millimetres"), "{e}");
        assert!(ratio_error(file, "ranges", "truth", Some(0.01)).is_err());
    }
}
