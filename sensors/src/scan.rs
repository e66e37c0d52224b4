//! A planar laser scan.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::Vector2;

use crate::error::{Result, SensorError};

/// The most beams a simulated laser may have (a resource limit; real 2-D lasers have a few
/// thousand at most).
pub const MAX_BEAMS: usize = 100_000;

/// One sweep of a planar laser: ranges at equally spaced bearings in the sensor frame
/// (counter-clockwise from `angle_min`, 0 straight ahead).
///
/// A reading is **valid** when it is finite, above `min_range` and below `max_range`; invalid
/// readings (NaN, infinite, negative, zero, max-range "no return") are kept in `ranges` so that
/// indices match the beams, and skipped by [`LaserScan::points`].
///
/// ```
/// use slam_sensors::LaserScan;
/// let scan = LaserScan::new(-1.0, 1.0, vec![2.0, f64::NAN, 80.0], 0.05, 80.0).unwrap();
/// assert_eq!(scan.points().len(), 1);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserScan {
    /// Bearing of the first beam, rad.
    pub angle_min: f64,
    /// Angle between consecutive beams, rad (positive).
    pub angle_increment: f64,
    /// Measured ranges, m, one per beam.
    pub ranges: Vec<f64>,
    /// Readings at or below this are invalid, m.
    pub min_range: f64,
    /// Readings at or above this are "no return", m.
    pub max_range: f64,
}

/// A valid reading as a point in the sensor frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanPoint {
    /// Beam index.
    pub index: usize,
    /// Range, m.
    pub range: f64,
    /// Bearing, rad.
    pub bearing: f64,
    /// `(range cos bearing, range sin bearing)`.
    pub position: Vector2<f64>,
}

impl LaserScan {
    /// A scan whose beams span `angle_min ..= angle_max` evenly.
    pub fn new(
        angle_min: f64,
        angle_max: f64,
        ranges: Vec<f64>,
        min_range: f64,
        max_range: f64,
    ) -> Result<Self> {
        if ranges.is_empty() {
            return Err(SensorError::InvalidArgument(
                "a scan needs at least one beam".into(),
            ));
        }
        let increment = if ranges.len() > 1 {
            (angle_max - angle_min) / (ranges.len() - 1) as f64
        } else {
            0.0
        };
        LaserScan::with_increment(angle_min, increment, ranges, min_range, max_range)
    }

    /// A scan from its first bearing and the spacing of the beams.
    pub fn with_increment(
        angle_min: f64,
        angle_increment: f64,
        ranges: Vec<f64>,
        min_range: f64,
        max_range: f64,
    ) -> Result<Self> {
        let finite = [angle_min, angle_increment, min_range, max_range]
            .iter()
            .all(|v| v.is_finite());
        if !finite || angle_increment < 0.0 || min_range < 0.0 || max_range <= min_range {
            return Err(SensorError::InvalidArgument(format!(
                "scan geometry: angle_min {angle_min}, increment {angle_increment}, \
                 range limits {min_range}..{max_range}"
            )));
        }
        Ok(LaserScan {
            angle_min,
            angle_increment,
            ranges,
            min_range,
            max_range,
        })
    }

    /// Bearing of beam `index`.
    pub fn bearing(&self, index: usize) -> f64 {
        self.angle_min + self.angle_increment * index as f64
    }

    /// Whether a range value is a usable return.
    pub fn is_valid(&self, range: f64) -> bool {
        range.is_finite() && range > self.min_range && range < self.max_range
    }

    /// Marks as no return (NaN) the valid readings of a laser mounted at `robot_from_sensor`
    /// whose point lies below the laser and less than `clearance` (m) above the floor, the
    /// plane z = 0 of the robot frame: a tilted scan plane meets the floor along a straight
    /// line, which is not a wall. A level mount loses nothing (all its points lie at its own
    /// height). Returns the number of readings marked.
    ///
    /// ```
    /// use slam_core::{Pose3, nalgebra::Vector3};
    /// use slam_sensors::LaserScan;
    /// // A laser 0.3 m up, pitched down 10 degrees: the floor ahead at 0.3 / sin(10 deg).
    /// let mount = Pose3::new(Vector3::new(0.0, 0.0, 0.3), 0.0, 10f64.to_radians(), 0.0);
    /// let mut scan = LaserScan::new(-0.1, 0.1, vec![1.0, 1.7276, 1.0], 0.05, 8.0).unwrap();
    /// assert_eq!(scan.drop_floor_readings(&mount, 0.05), 1);
    /// assert!(scan.ranges[1].is_nan() && scan.ranges[0] == 1.0);
    /// // A level laser, even one whose height is unknown (0), keeps every reading.
    /// let mut level = LaserScan::new(-0.1, 0.1, vec![1.0, 1.7276, 1.0], 0.05, 8.0).unwrap();
    /// assert_eq!(level.drop_floor_readings(&Pose3::identity(), 0.05), 0);
    /// ```
    pub fn drop_floor_readings(
        &mut self,
        robot_from_sensor: &slam_core::Pose3,
        clearance: f64,
    ) -> usize {
        let rotation = robot_from_sensor.rotation();
        let height = robot_from_sensor.translation.z;
        // The height of a point at range r on beam b: height + r (R (cos b, sin b, 0))_z.
        let (r20, r21) = (rotation[(2, 0)], rotation[(2, 1)]);
        let mut dropped = 0;
        for index in 0..self.ranges.len() {
            let range = self.ranges[index];
            if !self.is_valid(range) {
                continue;
            }
            let bearing = self.bearing(index);
            let rise = range * (r20 * bearing.cos() + r21 * bearing.sin());
            if rise < -1e-9 && height + rise < clearance {
                self.ranges[index] = f64::NAN;
                dropped += 1;
            }
        }
        dropped
    }

    /// The valid readings as points, in beam order.
    pub fn points(&self) -> Vec<ScanPoint> {
        self.ranges
            .iter()
            .enumerate()
            .filter(|(_, r)| self.is_valid(**r))
            .map(|(index, &range)| {
                let bearing = self.bearing(index);
                ScanPoint {
                    index,
                    range,
                    bearing,
                    position: Vector2::new(range * bearing.cos(), range * bearing.sin()),
                }
            })
            .collect()
    }
}
