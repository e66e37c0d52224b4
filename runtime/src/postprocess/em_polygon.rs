//! `[[postprocess]] type = "em-polygon"`: EM polygonal approximation of the registered laser
//! points ([`slam_estimators::em_polygon`], Latecki & Lakaemper 2006) after any estimator.
//!
//! The scans are placed by the run's estimate (`poses = "estimate"`: the path the map belongs
//! to) or by the poses the data give (`poses = "given"`: the SLAM-corrected poses of the
//! Radish logs, or a simulation's true poses). Every valid return becomes a point in the map
//! frame; the fitted segments become `slam_features::Wall`s (M-space dimension 4: line and
//! both ends), the polyline joints shared corners (eq. 33).
//!
//! ```toml
//! [estimator]
//! type = "dead-reckoning"  # the estimate is not used with poses = "given"
//! [[postprocess]]
//! type = "em-polygon"
//! poses = "given"          # or "estimate"
//! max_range = 0            # drop returns beyond this range, m (0: keep all)
//! [postprocess.fit]        # slam_estimators::EmPolygonParams
//! sigma_min = 0.02
//! ```

use std::time::Instant;

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{CoordBlock, Estimator, FeatureMap, Pose2, Pose3, UpdateReport};
use slam_estimators::em_polygon::PolygonMap;
use slam_estimators::{EmPolygonParams, fit_polygons};
use slam_features::Wall;
use slam_sensors::{Event, TimedEvent, TruthKind};

use super::{FinishedRun, PostProcess, PostProcessConfig, PostProcessOutput};
use crate::error::{Result, RuntimeError};
use crate::session::Observer;

/// Where the poses that place the scans come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PoseSource {
    /// The run's estimate: the path its map belongs to.
    #[default]
    Estimate,
    /// The poses the data give (true poses, else reference poses).
    Given,
}

/// The `[[postprocess]]` table of `type = "em-polygon"`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmPolygonConfig {
    /// Where the scan poses come from.
    pub poses: PoseSource,
    /// Returns beyond this range are dropped, m (0: none is).
    pub max_range: f64,
    /// Settings of the fit.
    pub fit: EmPolygonParams,
}

#[typetag::serde(name = "em-polygon")]
impl PostProcessConfig for EmPolygonConfig {
    fn validate(&self) -> Result<()> {
        if !(self.max_range.is_finite() && self.max_range >= 0.0) {
            return Err(RuntimeError::setting(
                "postprocess",
                format!(
                    "em-polygon max_range must be 0 or positive, got {}",
                    self.max_range
                ),
            ));
        }
        Ok(self.fit.validate()?)
    }

    fn build(&self) -> Result<Box<dyn PostProcess>> {
        self.validate()?;
        Ok(Box::new(EmPolygon {
            config: self.clone(),
            scans: Vec::new(),
        }))
    }
}

/// A scan's returns (sensor frame) with its time and mount.
struct TimedScan {
    time: f64,
    points: Vec<Vector2<f64>>,
    robot_from_sensor: Pose3,
}

/// The stage at work: it keeps every scan's returns within range.
struct EmPolygon {
    config: EmPolygonConfig,
    scans: Vec<TimedScan>,
}

/// The stage's figures (`em-polygon/metrics.json`).
#[derive(Serialize)]
struct Metrics {
    poses: PoseSource,
    scans: usize,
    points: usize,
    segments: usize,
    polylines: usize,
    closed_polylines: usize,
    /// Polyline joints that became shared wall corners.
    shared_corners: usize,
    /// Mean distance of the points to their nearest segment, m.
    mean_point_to_segment_m: Option<f64>,
    /// Median of the same, m.
    median_point_to_segment_m: Option<f64>,
    /// Points per segment endpoint (points : 2 segments).
    compression_ratio: Option<f64>,
    /// Noise of the points about their walls measured from the data, m.
    noise_level_m: Option<f64>,
    /// Segments removed by the model selection after the fit.
    pruned_segments: usize,
    iterations: usize,
    converged: bool,
    /// Seconds of the fit alone.
    fit_time_s: f64,
    iteration_stats: Vec<slam_estimators::em_polygon::IterationStats>,
}

impl Observer for EmPolygon {
    fn event(
        &mut self,
        event: &TimedEvent,
        _: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        if let Event::Scan {
            scan,
            robot_from_sensor,
        } = &event.event
        {
            let max_range = self.config.max_range;
            let points = scan
                .points()
                .iter()
                .filter(|p| max_range <= 0.0 || p.range <= max_range)
                .map(|p| p.position)
                .collect();
            self.scans.push(TimedScan {
                time: event.time,
                points,
                robot_from_sensor: *robot_from_sensor,
            });
        }
        Ok(())
    }
}

impl PostProcess for EmPolygon {
    fn finish(self: Box<Self>, run: &FinishedRun<'_>) -> Result<PostProcessOutput> {
        if self.scans.is_empty() {
            return Err(RuntimeError::Data(format!(
                "{}: no laser scans, nothing for em-polygon to approximate",
                run.name
            )));
        }
        let poses = match self.config.poses {
            PoseSource::Given => given_poses(run)?,
            PoseSource::Estimate => run.map_poses(),
        };
        let points = register(&self.scans, &poses);
        let clock = Instant::now();
        let fit = fit_polygons(&points, &self.config.fit)?;
        let fit_time_s = clock.elapsed().as_secs_f64();
        let (map, shared_corners) = walls(&fit)?;
        let metrics = Metrics {
            poses: self.config.poses,
            scans: self.scans.len(),
            points: points.len(),
            segments: fit.segments.len(),
            polylines: fit.polylines.len(),
            closed_polylines: fit.polylines.iter().filter(|p| p.closed).count(),
            shared_corners,
            mean_point_to_segment_m: fit.mean_distance,
            median_point_to_segment_m: fit.median_distance,
            compression_ratio: fit.compression_ratio,
            noise_level_m: fit.noise_level,
            pruned_segments: fit.pruned,
            iterations: fit.iterations.len(),
            converged: fit.converged,
            fit_time_s,
            iteration_stats: fit.iterations.clone(),
        };
        let number =
            |v: Option<f64>, digits: usize| v.map_or("n/a".into(), |v| format!("{v:.digits$}"));
        let summary = format!(
            "em-polygon: {} points of {} scans -> {} segments in {} polylines after {} \
             iterations ({fit_time_s:.1} s); mean point-to-segment distance {} m; compression \
             {}:1",
            points.len(),
            self.scans.len(),
            fit.segments.len(),
            fit.polylines.len(),
            fit.iterations.len(),
            number(fit.mean_distance, 3),
            number(fit.compression_ratio, 0),
        );
        Ok(PostProcessOutput {
            name: "em-polygon".into(),
            map,
            points,
            path: poses,
            metrics: serde_json::to_value(&metrics)
                .map_err(|e| RuntimeError::Invariant(format!("em-polygon metrics: {e}")))?,
            summary,
        })
    }
}

/// The pose at `time`: the last pose at or before it.
fn pose_at(poses: &[(f64, Pose2)], time: f64) -> Option<Pose2> {
    let k = poses.partition_point(|(t, _)| *t <= time);
    k.checked_sub(1).map(|k| poses[k].1)
}

/// The kept returns of the scans placed by `poses`, in the map frame.
fn register(scans: &[TimedScan], poses: &[(f64, Pose2)]) -> Vec<Vector2<f64>> {
    let mut points = Vec::new();
    for s in scans {
        let Some(pose) = pose_at(poses, s.time) else {
            continue;
        };
        let world_from_sensor = pose.to_pose3(0.0).compose(&s.robot_from_sensor);
        for p in &s.points {
            let q = world_from_sensor.transform_point(&Vector3::new(p.x, p.y, 0.0));
            points.push(q.xy());
        }
    }
    points
}

/// The poses the data give: true poses when there are some, else reference poses.
fn given_poses(run: &FinishedRun<'_>) -> Result<Vec<(f64, Pose2)>> {
    let of_kind = |kind: TruthKind| -> Vec<(f64, Pose2)> {
        run.record
            .truth
            .iter()
            .filter(|(_, _, k)| *k == kind)
            .map(|(t, p, _)| (*t, *p))
            .collect()
    };
    let poses = match of_kind(TruthKind::True) {
        poses if !poses.is_empty() => poses,
        _ => of_kind(TruthKind::Reference),
    };
    if poses.is_empty() {
        return Err(RuntimeError::Data(format!(
            "{}: the data give no poses; use poses = \"estimate\" to place the scans by the \
             estimator's path",
            run.name
        )));
    }
    Ok(poses)
}

/// The fitted segments as walls (line and both ends estimated), with the polyline joints as
/// shared corners. Returns the map and the number of shared corners.
fn walls(fit: &PolygonMap) -> Result<(FeatureMap, usize)> {
    let mut map = FeatureMap::new();
    let mut ids = Vec::new();
    for (k, s) in fit.segments.iter().enumerate() {
        let wall = Wall::new(s.start, s.end)
            .and_then(|w| w.with_subspaces(&["line", "start", "end"]))
            .map_err(|e| RuntimeError::Data(format!("segment {k} cannot be a wall: {e}")))?;
        ids.push(map.insert(Box::new(wall))?);
    }
    let mut shared = 0;
    for polyline in &fit.polylines {
        let n = polyline.segments.len();
        let joints = if polyline.closed {
            n
        } else {
            n.saturating_sub(1)
        };
        for j in 0..joints {
            let (a, a_reversed) = polyline.segments[j];
            let (b, b_reversed) = polyline.segments[(j + 1) % n];
            // Leaving `a` through its end (start when walked reversed), entering `b` at its start.
            let a_end = usize::from(!a_reversed);
            let b_end = usize::from(b_reversed);
            let vertex = polyline.vertices[(j + 1) % polyline.vertices.len()];
            map.share(
                &[(ids[a], a_end), (ids[b], b_end)],
                CoordBlock::Point2(vertex),
            )?;
            shared += 1;
        }
    }
    Ok((map, shared))
}
