//! The sensor frames of one step: where each sensor is and its Jacobians, made once per pose
//! and mount instead of once per observation (every observation of a step shares the robot
//! pose, and most share the mount).

use std::borrow::Cow;

use slam_core::{Observation, Pose3, Result, RobotPose, SensorFrame};

/// The frames of the mounts of one step's observations at one robot pose.
#[derive(Clone, Debug)]
pub(super) struct StepFrames<P> {
    /// The robot pose the frames were made at; `None` before the first step.
    pose: Option<P>,
    /// One entry per distinct mount.
    entries: Vec<FrameEntry>,
}

/// The frame of one mount.
#[derive(Clone, Debug)]
struct FrameEntry {
    robot_from_sensor: Pose3,
    world_from_sensor: Pose3,
    /// `None` where the frame cannot be made (gimbal lock, a pose that is not finite):
    /// [`StepFrames::frame`] then makes it again to return the error.
    frame: Option<SensorFrame>,
}

impl<P> Default for StepFrames<P> {
    fn default() -> Self {
        StepFrames {
            pose: None,
            entries: Vec::new(),
        }
    }
}

impl<P: RobotPose> StepFrames<P> {
    /// Makes the frames of the mounts of `observations` at `pose` (the earlier ones are
    /// dropped).
    pub(super) fn prepare(&mut self, pose: &P, observations: &[Observation]) {
        self.pose = Some(*pose);
        self.entries.clear();
        for observation in observations {
            let mount = &observation.robot_from_sensor;
            if self.entries.iter().any(|e| e.robot_from_sensor == *mount) {
                continue;
            }
            let frame = SensorFrame::new(pose, mount).ok();
            self.entries.push(FrameEntry {
                robot_from_sensor: *mount,
                world_from_sensor: frame
                    .as_ref()
                    .map_or_else(|| pose.world_from_sensor(mount), |f| *f.world_from_sensor()),
                frame,
            });
        }
    }

    /// The entry of `robot_from_sensor` if the frames were made at `pose`.
    fn entry(&self, pose: &P, robot_from_sensor: &Pose3) -> Option<&FrameEntry> {
        if self.pose.as_ref() != Some(pose) {
            return None;
        }
        self.entries
            .iter()
            .find(|e| e.robot_from_sensor == *robot_from_sensor)
    }

    /// `world_from_sensor` of a sensor at `robot_from_sensor` on a robot at `pose`.
    pub(super) fn world_from_sensor(&self, pose: &P, robot_from_sensor: &Pose3) -> Pose3 {
        match self.entry(pose, robot_from_sensor) {
            Some(entry) => entry.world_from_sensor,
            None => pose.world_from_sensor(robot_from_sensor),
        }
    }

    /// The frame of a sensor at `robot_from_sensor` on a robot at `pose`: the one made
    /// beforehand, or a new one (with its error) when there is none.
    pub(super) fn frame(
        &self,
        pose: &P,
        robot_from_sensor: &Pose3,
    ) -> Result<Cow<'_, SensorFrame>> {
        match self
            .entry(pose, robot_from_sensor)
            .and_then(|e| e.frame.as_ref())
        {
            Some(frame) => Ok(Cow::Borrowed(frame)),
            None => SensorFrame::new(pose, robot_from_sensor).map(Cow::Owned),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::Pose2;
    use slam_core::nalgebra::Vector3;
    use slam_sensors::models::RangeBearing;
    use std::sync::Arc;

    /// A frame kept for the step is the one a fresh computation gives; another pose or
    /// mount is computed afresh.
    #[test]
    fn kept_frames_equal_fresh_ones() {
        let pose = Pose2::new(1.0, -2.0, 0.7);
        let level = Pose3::new(Vector3::new(0.3, 0.1, 0.5), 0.2, 0.0, 0.0);
        let tilted = Pose3::new(Vector3::new(0.0, 0.0, 1.0), 0.0, -0.4, 0.1);
        let locked = Pose3::new(Vector3::zeros(), 0.0, std::f64::consts::FRAC_PI_2, 0.0);
        let mut frames = StepFrames::default();
        let observations: Vec<Observation> = [level, tilted, level, locked]
            .into_iter()
            .map(|mount| Observation {
                measurement: Arc::new(RangeBearing::new(2.0, 0.1, 0.1, 0.01).unwrap()),
                robot_from_sensor: mount,
                landmark_id: None,
            })
            .collect();
        frames.prepare(&pose, &observations);
        assert_eq!(frames.entries.len(), 3);
        for mount in [level, tilted] {
            let kept = frames.frame(&pose, &mount).unwrap();
            assert!(matches!(kept, Cow::Borrowed(_)));
            assert_eq!(*kept, SensorFrame::new(&pose, &mount).unwrap());
            assert_eq!(
                frames.world_from_sensor(&pose, &mount),
                pose.world_from_sensor(&mount)
            );
        }
        assert!(frames.frame(&pose, &locked).is_err());
        assert_eq!(
            frames.world_from_sensor(&pose, &locked),
            pose.world_from_sensor(&locked)
        );
        let moved = Pose2::new(1.0, -2.0, 0.8);
        let fresh = frames.frame(&moved, &level).unwrap();
        assert!(matches!(fresh, Cow::Owned(_)));
        assert_eq!(*fresh, SensorFrame::new(&moved, &level).unwrap());
    }
}
