//! Odometry built from a log's reference poses with seeded noise (`[data.odometry_from_poses]`
//! of the `slam` config), for logs whose motion is not raw odometry (the Radish corrected
//! logs).

use std::iter::Peekable;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use slam_core::Pose2;
use slam_core::nalgebra::{Matrix3, Vector3};

use crate::error::{Result, SensorError};
use crate::events::{Event, EventStream, TimedEvent};
use crate::odometry::PoseIncrement;

/// Odometry from reference poses: before each scan, the increment from the previous scan's
/// reference pose to this one's, with Gaussian noise of deviation
/// `translation_per_metre * d + floor_translation` on x and y and
/// `rotation_per_radian * |a| + rotation_per_metre * d + floor_rotation` on the heading (`d`
/// the distance, `a` the turn), drawn from a stream of the `[data] seed`. The data's own motion
/// events are dropped; the reference poses stay as the reference for the ATE.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseOdometryParams {
    /// Translation deviation per metre travelled.
    pub translation_per_metre: f64,
    /// Heading deviation per radian turned.
    pub rotation_per_radian: f64,
    /// Heading deviation per metre travelled, rad/m.
    pub rotation_per_metre: f64,
    /// Smallest translation deviation, m.
    pub floor_translation: f64,
    /// Smallest heading deviation, rad.
    pub floor_rotation: f64,
}

impl Default for PoseOdometryParams {
    fn default() -> Self {
        PoseOdometryParams {
            translation_per_metre: 0.05,
            rotation_per_radian: 0.05,
            rotation_per_metre: 0.02,
            floor_translation: 0.005,
            floor_rotation: 0.002,
        }
    }
}

impl PoseOdometryParams {
    /// Checks that the deviations are finite and non-negative and the floors positive.
    pub fn validate(&self) -> Result<()> {
        let values = [
            self.translation_per_metre,
            self.rotation_per_radian,
            self.rotation_per_metre,
            self.floor_translation,
            self.floor_rotation,
        ];
        if values.iter().any(|v| !v.is_finite() || *v < 0.0) || values[3] <= 0.0 || values[4] <= 0.0
        {
            return Err(SensorError::InvalidArgument(
                "[data.odometry_from_poses]: deviations must be finite and >= 0, floors > 0".into(),
            ));
        }
        Ok(())
    }
}

/// Replaces the motion of `stream` by odometry from its reference poses (see
/// [`PoseOdometryParams`]); each scan's pose is the ground-truth event that follows it at the
/// same time. The noise is drawn from a ChaCha8 stream of `seed`, so the same input, parameters
/// and seed give the same odometry.
///
/// Invalid parameters are an error of this call. When the whole input had no two scans with
/// reference poses (no increment at all), the stream ends with an `Err` item saying so.
///
/// ```
/// use slam_sensors::data::{PoseOdometryParams, odometry_from_poses};
/// use slam_sensors::{Clock, Dataset, Event, EventStream, LaserScan, TruthKind};
/// use slam_core::{Pose2, Pose3};
/// let mut data = Dataset::new("two scans", Clock::Sequence);
/// for (k, x) in [0.0, 1.0].into_iter().enumerate() {
///     let scan = LaserScan::new(-1.0, 1.0, vec![2.0, 3.0], 0.0, 8.0).unwrap();
///     data.push(k as f64, Event::Scan { scan, robot_from_sensor: Pose3::identity() });
///     let pose = Pose2::new(x, 0.0, 0.0);
///     data.push(k as f64, Event::GroundTruth { pose, kind: TruthKind::Reference });
/// }
/// let stream = EventStream::from_dataset(data);
/// let out = odometry_from_poses(stream, &PoseOdometryParams::default(), 1).unwrap();
/// let counts = out.into_dataset().unwrap().counts();
/// assert_eq!((counts.motion, counts.scans, counts.ground_truth), (1, 2, 2));
/// ```
pub fn odometry_from_poses(
    stream: EventStream,
    params: &PoseOdometryParams,
    seed: u64,
) -> Result<EventStream> {
    params.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(0x0D0_0E7);
    let info = stream.info.clone();
    let skipped = stream.skip_counter();
    let adapter = PoseOdometry {
        name: info.name.clone(),
        input: stream.peekable(),
        params: params.clone(),
        rng,
        previous: None,
        motions: 0,
        scan: None,
        finished: false,
    };
    Ok(EventStream::new(info, adapter).with_skipped(skipped))
}

/// The state of an [`odometry_from_poses`] stream.
struct PoseOdometry {
    name: String,
    input: Peekable<EventStream>,
    params: PoseOdometryParams,
    rng: ChaCha8Rng,
    /// The reference pose of the previous scan that had one.
    previous: Option<Pose2>,
    /// Increments written so far.
    motions: usize,
    /// A scan to write after the increment just returned.
    scan: Option<TimedEvent>,
    finished: bool,
}

impl PoseOdometry {
    /// The noisy increment from the previous scan's pose to `pose`.
    fn increment(&mut self, before: &Pose2, pose: &Pose2) -> Result<PoseIncrement> {
        let noise = &self.params;
        let relative = before.inverse().compose(pose);
        let d = relative.translation().norm();
        let a = relative.theta.abs();
        let sigma_t = noise.translation_per_metre * d + noise.floor_translation;
        let sigma_r =
            noise.rotation_per_radian * a + noise.rotation_per_metre * d + noise.floor_rotation;
        let rng = &mut self.rng;
        let mut draw = || -> f64 { StandardNormal.sample(rng) };
        let noisy = Pose2::new(
            relative.x + sigma_t * draw(),
            relative.y + sigma_t * draw(),
            relative.theta + sigma_r * draw(),
        );
        let cov = Matrix3::from_diagonal(&Vector3::new(
            sigma_t * sigma_t,
            sigma_t * sigma_t,
            sigma_r * sigma_r,
        ));
        PoseIncrement::new(noisy, cov)
    }
}

impl Iterator for PoseOdometry {
    type Item = Result<TimedEvent>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(scan) = self.scan.take() {
            return Some(Ok(scan));
        }
        loop {
            if self.finished {
                return None;
            }
            let timed = match self.input.next() {
                Some(Ok(timed)) => timed,
                Some(Err(e)) => {
                    self.finished = true;
                    return Some(Err(e));
                }
                None => {
                    self.finished = true;
                    if self.motions == 0 {
                        return Some(Err(SensorError::InvalidArgument(format!(
                            "[data.odometry_from_poses]: {} has no scan with a reference pose",
                            self.name
                        ))));
                    }
                    return None;
                }
            };
            match &timed.event {
                Event::Motion(_) => continue,
                Event::Scan { .. } => {
                    let pose = match self.input.peek() {
                        Some(Ok(next)) => match &next.event {
                            Event::GroundTruth { pose, .. } if next.time == timed.time => {
                                Some(*pose)
                            }
                            _ => None,
                        },
                        _ => None,
                    };
                    let Some(pose) = pose else {
                        return Some(Ok(timed));
                    };
                    let before = self.previous.replace(pose);
                    let Some(before) = before else {
                        return Some(Ok(timed));
                    };
                    return match self.increment(&before, &pose) {
                        Ok(increment) => {
                            self.motions += 1;
                            let time = timed.time;
                            self.scan = Some(timed);
                            Some(Ok(TimedEvent {
                                time,
                                event: Event::Motion(Box::new(increment)),
                            }))
                        }
                        Err(e) => {
                            self.finished = true;
                            Some(Err(e))
                        }
                    };
                }
                _ => return Some(Ok(timed)),
            }
        }
    }
}
