//! The standard record of a run: the estimate at every time step (what the trajectory
//! outputs need), the truth and GPS fixes the data give (what the evaluation needs), and
//! running totals of the updates, and a fixed-size sample of the scan readings (for the map
//! quality figures). Nothing else grows with the length of the log.

use serde::Serialize;
use slam_core::nalgebra::{Matrix3, Vector2};
use std::collections::BTreeMap;

use slam_core::{Estimator, Pose2, Skips, UpdateReport};
use slam_sensors::{Event, TimedEvent, TruthKind};

use crate::error::Result;
use crate::eval::{
    ChiSquareAccumulator, Record, ScanSample, TrajectoryErrors, path_errors, stamped,
};
use crate::session::Observer;

/// Totals of the estimator's update reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct UpdateTotals {
    /// Observations paired with a feature.
    pub associated: usize,
    /// Observations that started a feature.
    pub new_features: usize,
    /// Observations dropped.
    pub rejected: usize,
}

/// An [`Observer`] that keeps the standard record of a run.
#[derive(Clone, Debug, Default)]
pub struct Recorder {
    /// The estimate after every time step.
    pub estimates: Vec<Record>,
    /// Ground truth or reference poses of the data.
    pub truth: Vec<(f64, Pose2, TruthKind)>,
    /// GPS fixes of the data.
    pub gps: Vec<(f64, Vector2<f64>)>,
    /// Where the GPS antenna sits in the robot frame (the data's
    /// [`slam_sensors::DatasetInfo::gps_antenna`]).
    pub gps_antenna: Vector2<f64>,
    /// NIS of every paired observation.
    pub nis: ChiSquareAccumulator,
    /// Totals of the update reports.
    pub updates: UpdateTotals,
    /// What the updates left out, by reason.
    pub skipped: Skips,
    /// Events processed.
    pub events: usize,
    /// A fixed-size sample of the scan readings, for the map quality figures.
    pub scan_sample: ScanSample,
}

impl Observer for Recorder {
    fn event(
        &mut self,
        event: &TimedEvent,
        update: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        self.events += 1;
        match &event.event {
            Event::GroundTruth { pose, kind } => self.truth.push((event.time, *pose, *kind)),
            Event::Gps(fix) => self.gps.push((event.time, *fix)),
            Event::Scan {
                scan,
                robot_from_sensor,
            } => self.scan_sample.add(event.time, scan, robot_from_sensor),
            _ => {}
        }
        if let Some(report) = update {
            self.updates.associated += report.associated;
            self.updates.new_features += report.new_features;
            self.updates.rejected += report.rejected;
            for &(value, dof) in &report.nis {
                self.nis.add(value, dof)?;
            }
            self.skipped.merge(&report.skipped);
        }
        Ok(())
    }

    fn step_end(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        let c = estimator.pose_covariance();
        self.estimates.push(Record {
            time,
            pose: estimator.pose(),
            covariance: Matrix3::from_fn(|i, j| c[(i, j)]),
        });
        Ok(())
    }
}

impl Recorder {
    /// The independent true poses of the run, by the bits of their time.
    pub fn true_poses(&self) -> BTreeMap<u64, Pose2> {
        crate::eval::true_poses(&self.truth)
    }

    /// The path a map belongs to: `map_path` where there is one (a particle filter's path of
    /// the particle whose map is kept), else the recorded estimates.
    pub fn map_poses(&self, map_path: Option<&[(f64, Pose2)]>) -> Vec<(f64, Pose2)> {
        match map_path {
            Some(path) => path.to_vec(),
            None => self.estimates.iter().map(|r| (r.time, r.pose)).collect(),
        }
    }

    /// ATE of `path` (a map path, or any poses of the run's times) against the run's truth.
    pub fn path_errors(&self, path: &[(f64, Pose2)]) -> Result<Option<TrajectoryErrors>> {
        path_errors(
            &self.truth,
            &self.gps,
            &self.gps_antenna,
            &stamped(path.iter().copied()),
        )
    }

    /// ATE of the recorded estimates against the run's truth (true poses, else reference
    /// poses, else GPS fixes).
    pub fn trajectory_errors(&self) -> Result<Option<TrajectoryErrors>> {
        let estimates = stamped(self.estimates.iter().map(|r| (r.time, r.pose)));
        path_errors(&self.truth, &self.gps, &self.gps_antenna, &estimates)
    }
}
