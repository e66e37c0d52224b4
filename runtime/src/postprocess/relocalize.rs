//! `[[postprocess]] type = "relocalize"`: every scan placed again against the **final** wall
//! map, so that the path and the map agree.
//!
//! A filter estimates the pose of a step against the map of that step; the map moves later
//! (a loop closes, walls merge), and the early poses are not revisited. This stage takes
//! the confirmed walls of the finished map and, for every laser scan, the pose that best
//! fits the scan's returns to those walls: the maximum a posteriori pose under a prior with
//! the estimate's covariance and a Cauchy-weighted point-to-wall distance per return
//! (Gauss-Newton, returns paired with their nearest wall within a gate that narrows over the
//! iterations). Scans are taken in order. Each is placed twice, starting from its estimate
//! and from its estimate moved by the correction of the scan before (corrections vary
//! slowly along the path: a stretch driven before a loop closed may sit far from where the
//! final map puts it); the prior is the estimate for both, and the placement with the lower
//! objective (the returns' misfit plus the prior's term) is kept. A carried start therefore
//! cannot drag the path along what the walls leave free (a corridor's length).
//!
//! Then the path of the scans is smoothed (`smooth`): each placement is a measurement of its
//! scan's pose, with the information of its returns divided by `information_divisor` plus
//! that of its prior (the estimate's covariance: it keeps the estimate along what the walls
//! leave free, a corridor's length; the priors of consecutive scans are not independent, but
//! wherever the walls constrain the pose they weigh little beside its returns), and the
//! odometry between consecutive scans (the compound of the motion events between them, with
//! its covariance) links the poses. A Cauchy loss on each placement's Mahalanobis distance
//! (scale `outlier_scale`) lets the odometry and the other placements outvote a placement
//! that fits the wrong walls, even a run of them, and a scan with too few returns near a wall
//! follows the odometry from its placed neighbours. Steps between scans keep the correction of
//! the scan before them.
//!
//! Last, the scans placed by that path test the walls: a ray that crosses a wall (at least
//! 0.2 m inside its ends) and returns at least 0.3 m beyond it sees through it. A confirmed
//! wall that more than `max_see_through` of at least 20 rays (on it or through it) see
//! through is not a surface where the map puts it (a line fitted across furniture, a
//! zigzag's peaks, a wall placed off) and is left out of the stage's map
//! (`relocalize/map.json`). The filter's map is not changed.
//!
//! It writes the relocalized path (`relocalize/trajectory.tum`), its map and its figures:
//! ATE against the data's poses and the median distance of the scan readings to the walls
//! (all the confirmed walls the scans were placed against), before and after, the placements
//! outvoted and the walls left out (`relocalize/metrics.json`). The run's own
//! `trajectory.tum` stays the filter's.
//!
//! ```toml
//! [[postprocess]]
//! type = "relocalize"
//! max_range = 20.0     # returns beyond this range are not used, m (0: all are)
//! beam_step = 2        # every second return is used
//! sigma = 0.03         # scale of the Cauchy weight of a return's distance to its wall, m
//! gate = 0.4           # pairing reach at the first iteration, m (then gate / k) ...
//! final_gate = 0.1     # ... but never below this, m
//! iterations = 8
//! min_pairs = 10       # a scan with fewer paired returns is not placed
//! smooth = true        # the placements and the odometry between scans smoothed together
//! information_divisor = 4.0  # a placement's information: its returns' divided by this
//! outlier_scale = 3.0  # Mahalanobis distance at which a placement's weight halves
//! max_see_through = 0.5  # walls more of whose rays pass through are left out (1: none)
//! ```

use std::time::Instant;

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Matrix3, Vector2, Vector3};
use slam_core::{Estimator, FeatureId, FeatureMap, Pose2, Pose3, Shape, UpdateReport};
use slam_sensors::{Event, LaserScan, TimedEvent};

use super::chain::{ChainNode, Odometry, PoseMeasurement, smooth_chain};
use super::see_through::ray_evidence;
use super::{FinishedRun, PostProcess, PostProcessConfig, PostProcessOutput};
use crate::error::{Result, RuntimeError};
use crate::eval::{
    MapQuality, RevisitConsistency, SegmentGrid, confirmed, map_quality, revisit_consistency,
};
use crate::session::Observer;

/// The `[[postprocess]]` table of `type = "relocalize"`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RelocalizeConfig {
    /// Returns beyond this range are not used, m (0: all are).
    pub max_range: f64,
    /// Every `beam_step`-th return of a scan is used.
    pub beam_step: usize,
    /// Scale of the Cauchy weight of a return's distance to its wall, m.
    pub sigma: f64,
    /// Pairing reach at the first iteration, m; at iteration `k` (from 1) it is `gate / k`.
    pub gate: f64,
    /// The smallest pairing reach, m.
    pub final_gate: f64,
    /// Gauss-Newton iterations per scan at most.
    pub iterations: usize,
    /// A scan with fewer returns paired with a wall is not placed.
    pub min_pairs: usize,
    /// Smooth the placed path: each scan's placement as a measurement of its pose, the
    /// odometry between scans linking them (a placement that disagrees with its neighbours
    /// and the odometry is outvoted).
    pub smooth: bool,
    /// A placement's information is that of its returns divided by this (neighbouring
    /// returns see the same surfaces; their errors are not independent).
    pub information_divisor: f64,
    /// The Mahalanobis distance from the smoothed pose at which a placement's weight halves
    /// (Cauchy loss).
    pub outlier_scale: f64,
    /// A confirmed wall that more than this fraction of the rays crossing or ending on it
    /// (at least 20) see through, placed by the relocalized path, is left out of the stage's
    /// map (1: every wall is kept).
    pub max_see_through: f64,
}

/// The fewest rays (on a wall or through it) that decide whether it is seen through.
const MIN_RAYS: usize = 20;

/// Gauss-Newton iterations of the smoothing at most.
const CHAIN_ITERATIONS: usize = 30;

impl Default for RelocalizeConfig {
    fn default() -> Self {
        RelocalizeConfig {
            max_range: 20.0,
            beam_step: 2,
            sigma: 0.03,
            gate: 0.4,
            final_gate: 0.1,
            iterations: 8,
            min_pairs: 10,
            smooth: true,
            information_divisor: 4.0,
            outlier_scale: 3.0,
            max_see_through: 0.5,
        }
    }
}

#[typetag::serde(name = "relocalize")]
impl PostProcessConfig for RelocalizeConfig {
    fn validate(&self) -> Result<()> {
        let positive = [
            ("sigma", self.sigma),
            ("gate", self.gate),
            ("final_gate", self.final_gate),
            ("information_divisor", self.information_divisor),
            ("outlier_scale", self.outlier_scale),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(RuntimeError::setting(
                    "postprocess",
                    format!("relocalize {name} must be positive, got {value}"),
                ));
            }
        }
        if !(self.max_range.is_finite() && self.max_range >= 0.0) {
            return Err(RuntimeError::setting(
                "postprocess",
                format!(
                    "relocalize max_range must be 0 or positive, got {}",
                    self.max_range
                ),
            ));
        }
        if !(self.max_see_through > 0.0 && self.max_see_through <= 1.0) {
            return Err(RuntimeError::setting(
                "postprocess",
                format!(
                    "relocalize max_see_through must be in (0, 1], got {}",
                    self.max_see_through
                ),
            ));
        }
        if self.beam_step == 0 || self.iterations == 0 {
            return Err(RuntimeError::setting(
                "postprocess",
                "relocalize beam_step and iterations must be at least 1",
            ));
        }
        if self.final_gate > self.gate {
            return Err(RuntimeError::setting(
                "postprocess",
                format!(
                    "relocalize final_gate ({}) must not exceed gate ({})",
                    self.final_gate, self.gate
                ),
            ));
        }
        Ok(())
    }

    fn build(&self) -> Result<Box<dyn PostProcess>> {
        self.validate()?;
        Ok(Box::new(Relocalize {
            config: self.clone(),
            scans: Vec::new(),
            pending_odometry: None,
        }))
    }
}

/// A scan's kept returns in the robot frame, with its time and the odometry since the scan
/// before.
struct RobotScan {
    time: f64,
    /// Where the sensor sits in the robot frame (the rays start there).
    origin: Vector2<f64>,
    in_robot: Vec<Vector2<f64>>,
    /// The compound of the motion events since the scan before (`None` for the first scan
    /// and where no motion came between).
    odometry: Option<(Pose2, Matrix3<f64>)>,
}

/// The stage at work: it keeps every scan's used returns and the odometry between scans.
struct Relocalize {
    config: RelocalizeConfig,
    scans: Vec<RobotScan>,
    /// The compound of the motion events since the last scan and its covariance.
    pending_odometry: Option<(Pose2, Matrix3<f64>)>,
}

impl Observer for Relocalize {
    fn event(
        &mut self,
        event: &TimedEvent,
        _: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        self.record(event)
    }
}

impl Relocalize {
    /// Keeps what the stage needs of an event: a scan's returns, a motion's increment.
    fn record(&mut self, event: &TimedEvent) -> Result<()> {
        match &event.event {
            Event::Scan {
                scan,
                robot_from_sensor,
            } => {
                let odometry = self.pending_odometry.take();
                self.scans.push(RobotScan {
                    time: event.time,
                    origin: robot_from_sensor.translation.xy(),
                    in_robot: self.returns_in_robot(scan, robot_from_sensor),
                    odometry: odometry.filter(|_| !self.scans.is_empty()),
                });
            }
            Event::Motion(motion) => {
                let (pose, covariance) = self
                    .pending_odometry
                    .unwrap_or((Pose2::identity(), Matrix3::zeros()));
                let prediction = motion.predict(&pose)?;
                let covariance = prediction.propagate_covariance(&DMatrix::from_column_slice(
                    3,
                    3,
                    covariance.as_slice(),
                ))?;
                self.pending_odometry = Some((
                    prediction.pose,
                    Matrix3::from_column_slice(covariance.as_slice()),
                ));
            }
            _ => {}
        }
        Ok(())
    }

    /// The used returns of a scan in the robot frame.
    fn returns_in_robot(&self, scan: &LaserScan, robot_from_sensor: &Pose3) -> Vec<Vector2<f64>> {
        let max_range = self.config.max_range;
        let rotation = robot_from_sensor.rotation();
        scan.points()
            .iter()
            .filter(|p| max_range <= 0.0 || p.range <= max_range)
            .step_by(self.config.beam_step)
            .map(|p| {
                let q = robot_from_sensor.translation
                    + rotation * Vector3::new(p.position.x, p.position.y, 0.0);
                q.xy()
            })
            .collect()
    }
}

/// The stage's figures (`relocalize/metrics.json`).
#[derive(Serialize)]
struct Metrics {
    /// Scans kept.
    scans: usize,
    /// Scans whose pose was re-estimated.
    relocalized: usize,
    /// Scans not placed (fewer than `min_pairs` returns near a wall): they keep the
    /// correction of the scan before, or with smoothing follow the odometry from their placed
    /// neighbours.
    kept: usize,
    /// Placements the smoothing outvoted (weight below one half: farther than
    /// `outlier_scale` from the smoothed pose); 0 without smoothing.
    outvoted: usize,
    /// Confirmed walls the scans were fitted to.
    walls: usize,
    /// The walls left out of the stage's map: seen through by more than `max_see_through` of
    /// their rays.
    seen_through: SeenThrough,
    /// The map figures of the confirmed walls kept in the stage's map, with the scan readings
    /// placed by the relocalized path.
    map_kept: Option<MapQuality>,
    /// Mean and largest change of position, m, and mean change of heading, rad.
    mean_shift_m: f64,
    max_shift_m: f64,
    mean_turn_rad: f64,
    /// ATE (SE(2)-aligned RMSE, m) of the estimate and of the relocalized path against the
    /// data's poses, where the data have some.
    ate_rmse_before_m: Option<f64>,
    ate_rmse_after_m: Option<f64>,
    /// Median distance of the run's sample of scan readings to the nearest wall, placed by
    /// the estimate and by the relocalized path, m.
    median_point_to_wall_before_m: Option<f64>,
    median_point_to_wall_after_m: Option<f64>,
    /// How well the scans of places visited more than once agree, placed by the estimate and
    /// by the relocalized path ([`crate::eval::revisit_consistency`]).
    revisits_before: Option<RevisitConsistency>,
    revisits_after: Option<RevisitConsistency>,
    /// Seconds of the relocalization alone.
    time_s: f64,
}

/// A wall segment: its two ends, world frame.
type Segment = (Vector2<f64>, Vector2<f64>);

/// Every scan placed against the walls.
struct Placements {
    /// The correction (on the left) of each scan with an estimate, at its time.
    corrections: Vec<(f64, Pose2)>,
    /// Scans placed.
    placed: usize,
    /// Placements the smoothing outvoted.
    outvoted: usize,
}

/// Walls left out of the stage's map because the rays see through them.
#[derive(Clone, Copy, Debug, Default, Serialize)]
struct SeenThrough {
    /// How many.
    walls: usize,
    /// Their total length, m.
    length_m: f64,
}

impl PostProcess for Relocalize {
    fn finish(self: Box<Self>, run: &FinishedRun<'_>) -> Result<PostProcessOutput> {
        if self.scans.is_empty() {
            return Err(RuntimeError::Data(format!(
                "{}: no laser scans, nothing for relocalize to place",
                run.name
            )));
        }
        let estimator = run.estimator;
        let (ids, walls) = confirmed_walls(estimator);
        if walls.is_empty() {
            return Err(RuntimeError::Data(format!(
                "{}: the map has no confirmed wall, nothing for relocalize to fit the scans to",
                run.name
            )));
        }
        let clock = Instant::now();
        let before = run.map_poses();
        let covariance_at = |time: f64| {
            let records = &run.record.estimates;
            let k = records.partition_point(|r| r.time < time);
            records
                .get(k)
                .filter(|r| r.time == time)
                .map_or(Matrix3::zeros(), |r| r.covariance)
        };
        let covariances: Vec<Matrix3<f64>> = self
            .scans
            .iter()
            .map(|scan| covariance_at(scan.time))
            .collect();
        let Placements {
            corrections,
            placed,
            outvoted,
        } = self.place_all(&walls, &before, &covariances, run.name)?;
        let after = corrected(&before, &corrections);
        let (map, dropped, kept) =
            self.without_seen_through(estimator.map(), (&ids, &walls), &after)?;
        let time_s = clock.elapsed().as_secs_f64();
        let mut metrics = self.metrics(run, &walls, &before, &after, (placed, outvoted), time_s)?;
        let points = run
            .record
            .scan_sample
            .placed(|t| pose_exactly_at(&after, t));
        metrics.seen_through = dropped;
        metrics.map_kept = Some(map_quality(&kept, &points));
        let summary = summary(&metrics);
        Ok(PostProcessOutput {
            name: "relocalize".into(),
            map,
            points,
            path: after,
            metrics: serde_json::to_value(&metrics)
                .map_err(|e| RuntimeError::Invariant(format!("relocalize metrics: {e}")))?,
            summary,
        })
    }
}

impl Relocalize {
    /// Places every scan against `walls` (and smooths the placements, with `smooth`): the
    /// correction of each scan that has an estimate (`before`), the number of scans placed
    /// and the number of placements outvoted.
    ///
    /// Each scan is placed twice, both times with its estimate as the prior: starting from
    /// the estimate, and from the estimate moved by the correction of the last placed scan
    /// (corrections vary slowly along the path, and a stretch driven before a loop closed may
    /// sit far from where the final map puts it). The placement with the lower objective
    /// wins.
    fn place_all(
        &self,
        walls: &[(Vector2<f64>, Vector2<f64>)],
        before: &[(f64, Pose2)],
        covariances: &[Matrix3<f64>],
        name: &str,
    ) -> Result<Placements> {
        let grid = SegmentGrid::new(walls, 1.0);
        let mut corrections: Vec<(f64, Pose2)> = Vec::with_capacity(self.scans.len());
        let mut placed = 0;
        let mut world_from_estimate = Pose2::identity();
        let mut nodes: Vec<ChainNode> = Vec::with_capacity(self.scans.len());
        let mut estimates: Vec<Pose2> = Vec::with_capacity(self.scans.len());
        // Whether the scan before became a node (the odometry links to it).
        let mut chained = false;
        for (scan, covariance) in self.scans.iter().zip(covariances) {
            let Some(k) = index_at(before, scan.time) else {
                chained = false;
                continue;
            };
            let estimate = before[k].1;
            let place = |start: &Pose2| {
                relocalize(
                    &self.config,
                    (&grid, walls),
                    &scan.in_robot,
                    start,
                    (&estimate, covariance),
                )
            };
            let carried = world_from_estimate.compose(&estimate);
            let from_carried = (world_from_estimate.translation().norm() > 1e-9
                || world_from_estimate.theta != 0.0)
                .then(|| place(&carried))
                .flatten();
            let best = [place(&estimate), from_carried]
                .into_iter()
                .flatten()
                .min_by(|a, b| a.objective().total_cmp(&b.objective()));
            if let Some(placement) = best {
                world_from_estimate = placement.world_from_robot.compose(&estimate.inverse());
                placed += 1;
            }
            corrections.push((scan.time, world_from_estimate));
            nodes.push(self.chain_node(
                world_from_estimate.compose(&estimate),
                best.as_ref(),
                scan.odometry.filter(|_| chained),
            ));
            estimates.push(estimate);
            chained = true;
        }
        let outvoted = if self.config.smooth {
            smooth_corrections(&nodes, &estimates, &mut corrections, &self.config, name)?
        } else {
            0
        };
        Ok(Placements {
            corrections,
            placed,
            outvoted,
        })
    }

    /// The final map without the confirmed walls that the scans, placed by `path`, see
    /// through (more than `max_see_through` of at least [`MIN_RAYS`] rays), what was left
    /// out, and the walls kept; `ids` and `walls` are the map's confirmed walls. A wall is
    /// left out with its memberships of shared corners, unless it is the last member of one.
    fn without_seen_through(
        &self,
        map: &FeatureMap,
        (ids, walls): (&[FeatureId], &[Segment]),
        path: &[(f64, Pose2)],
    ) -> Result<(FeatureMap, SeenThrough, Vec<Segment>)> {
        let mut map = map.clone();
        let mut dropped = SeenThrough::default();
        if self.config.max_see_through >= 1.0 {
            return Ok((map, dropped, walls.to_vec()));
        }
        let scans = self.scans.iter().filter_map(|scan| {
            let pose = pose_exactly_at(path, scan.time)?;
            let ends = scan.in_robot.iter().map(|p| pose.transform_point(p));
            Some((pose.transform_point(&scan.origin), ends.collect()))
        });
        let evidence = ray_evidence(walls, scans);
        let mut kept = Vec::with_capacity(walls.len());
        for ((id, (start, end)), seen) in ids.iter().zip(walls).zip(&evidence) {
            if seen.seen_through(self.config.max_see_through, MIN_RAYS)
                && map.remove_from_shared(*id).is_ok()
            {
                dropped.walls += 1;
                dropped.length_m += (end - start).norm();
            } else {
                kept.push((*start, *end));
            }
        }
        Ok((map, dropped, kept))
    }

    /// The chain node of a scan: its pose as placed (`initial`), its placement as a
    /// measurement and the odometry from the scan before.
    fn chain_node(
        &self,
        initial: Pose2,
        placement: Option<&Placement>,
        odometry: Option<(Pose2, Matrix3<f64>)>,
    ) -> ChainNode {
        // A floor of (1 mm)^2 and (0.3 mrad)^2 keeps a standstill's odometry invertible.
        let floor = Matrix3::from_diagonal(&Vector3::new(1e-6, 1e-6, 1e-7));
        ChainNode {
            initial,
            measurement: placement.map(|p| PoseMeasurement {
                pose: p.world_from_robot,
                information: p.information / self.config.information_divisor + p.prior_information,
            }),
            odometry: odometry.and_then(|(increment, covariance)| {
                Some(Odometry {
                    increment,
                    information: (covariance + floor).try_inverse()?,
                })
            }),
        }
    }

    /// The stage's figures.
    fn metrics(
        &self,
        run: &FinishedRun<'_>,
        walls: &[(Vector2<f64>, Vector2<f64>)],
        before: &[(f64, Pose2)],
        after: &[(f64, Pose2)],
        (relocalized, outvoted): (usize, usize),
        time_s: f64,
    ) -> Result<Metrics> {
        let shifts: Vec<(f64, f64)> = before
            .iter()
            .zip(after)
            .map(|((_, b), (_, a))| {
                let d = b.between(a);
                (d.translation().norm(), d.theta.abs())
            })
            .collect();
        let n = shifts.len().max(1) as f64;
        let ate = |path: &[(f64, Pose2)]| -> Result<Option<f64>> {
            Ok(run.record.path_errors(path)?.map(|e| e.ate_rmse_m))
        };
        let median = |path: &[(f64, Pose2)]| {
            let points = run.record.scan_sample.placed(|t| pose_exactly_at(path, t));
            map_quality(walls, &points).median_point_to_wall_m
        };
        Ok(Metrics {
            scans: self.scans.len(),
            relocalized,
            kept: self.scans.len() - relocalized,
            outvoted,
            seen_through: SeenThrough::default(),
            map_kept: None,
            walls: walls.len(),
            mean_shift_m: shifts.iter().map(|s| s.0).sum::<f64>() / n,
            max_shift_m: shifts.iter().map(|s| s.0).fold(0.0, f64::max),
            mean_turn_rad: shifts.iter().map(|s| s.1).sum::<f64>() / n,
            ate_rmse_before_m: ate(before)?,
            ate_rmse_after_m: ate(after)?,
            median_point_to_wall_before_m: median(before),
            median_point_to_wall_after_m: median(after),
            revisits_before: revisit_consistency(&run.record.scan_sample, before),
            revisits_after: revisit_consistency(&run.record.scan_sample, after),
            time_s,
        })
    }
}

/// The confirmed walls of the estimator's map: their ids and segments, in map order.
fn confirmed_walls(estimator: &dyn Estimator<Pose2>) -> (Vec<FeatureId>, Vec<Segment>) {
    estimator
        .map()
        .iter()
        .filter(|(id, _)| confirmed(estimator, *id))
        .filter_map(|(id, feature)| match feature.shape()? {
            Shape::Wall { start, end } => Some((id, (start, end))),
            _ => None,
        })
        .unzip()
}

/// Smooths the placed scans' poses (`nodes`, one per correction) and replaces each scan's
/// correction by the one that takes its estimate to its smoothed pose. Returns the number of
/// placements outvoted.
fn smooth_corrections(
    nodes: &[ChainNode],
    estimates: &[Pose2],
    corrections: &mut [(f64, Pose2)],
    config: &RelocalizeConfig,
    name: &str,
) -> Result<usize> {
    if nodes.is_empty() {
        return Ok(0);
    }
    let smoothed =
        smooth_chain(nodes, config.outlier_scale, CHAIN_ITERATIONS).ok_or_else(|| {
            RuntimeError::Data(format!(
                "{name}: relocalize could not smooth the path (singular normal equations)"
            ))
        })?;
    for ((correction, pose), estimate) in corrections.iter_mut().zip(&smoothed.poses).zip(estimates)
    {
        correction.1 = pose.compose(&estimate.inverse());
    }
    Ok(nodes
        .iter()
        .zip(&smoothed.weights)
        .filter(|(node, weight)| node.measurement.is_some() && **weight < 0.5)
        .count())
}

/// The summary line of the stage.
fn summary(m: &Metrics) -> String {
    let metres = |v: Option<f64>| v.map_or("n/a".into(), |v| format!("{v:.3} m"));
    let centimetres = |v: Option<f64>| v.map_or("n/a".into(), |v| format!("{:.1} cm", 100.0 * v));
    let revisit = |v: Option<RevisitConsistency>| centimetres(v.map(|r| r.median_m));
    format!(
        "relocalize: {} of {} scans placed against {} walls, {} outvoted ({:.1} s); ATE {} -> {}; \
         median scan reading to wall {} -> {}; passes apart (median) {} -> {}; {} walls \
         ({:.0} m) seen through left out of its map",
        m.relocalized,
        m.scans,
        m.walls,
        m.outvoted,
        m.time_s,
        metres(m.ate_rmse_before_m),
        metres(m.ate_rmse_after_m),
        centimetres(m.median_point_to_wall_before_m),
        centimetres(m.median_point_to_wall_after_m),
        revisit(m.revisits_before),
        revisit(m.revisits_after),
        m.seen_through.walls,
        m.seen_through.length_m,
    )
}

/// The index of the pose at `time` exactly.
fn index_at(path: &[(f64, Pose2)], time: f64) -> Option<usize> {
    let k = path.partition_point(|(t, _)| *t < time);
    path.get(k).filter(|(t, _)| *t == time).map(|_| k)
}

/// The pose at `time` exactly.
fn pose_exactly_at(path: &[(f64, Pose2)], time: f64) -> Option<Pose2> {
    index_at(path, time).map(|k| path[k].1)
}

/// `path` with every pose moved by the correction (applied on the left) of the last scan at
/// or before it; poses before the first scan are unchanged.
fn corrected(path: &[(f64, Pose2)], corrections: &[(f64, Pose2)]) -> Vec<(f64, Pose2)> {
    let mut next = 0;
    let mut current = Pose2::identity();
    path.iter()
        .map(|&(time, pose)| {
            while next < corrections.len() && corrections[next].0 <= time {
                current = corrections[next].1;
                next += 1;
            }
            (time, current.compose(&pose))
        })
        .collect()
}

/// A scan placed against the walls: its pose and how well its returns fit them.
#[derive(Clone, Copy, Debug)]
struct Placement {
    world_from_robot: Pose2,
    /// The Cauchy cost of the returns at the final gate (a return farther than the gate from
    /// every wall costs as much as one at the gate): lower is a better fit to the map.
    misfit: f64,
    /// The prior's term at the placement: half the squared Mahalanobis distance from the
    /// estimate.
    prior_cost: f64,
    /// The information of the pose from the returns near a wall (the Gauss-Newton Hessian of
    /// their Cauchy-weighted distances at the final gate), without the prior.
    information: Matrix3<f64>,
    /// The information of the placement's prior (the estimate's covariance, inverted).
    prior_information: Matrix3<f64>,
}

impl Placement {
    /// The objective the placement minimises: the returns' misfit and the prior's term.
    /// Placements of one scan from different starts are compared by it.
    fn objective(&self) -> f64 {
        self.misfit + self.prior_cost
    }
}

/// The maximum a posteriori pose of one scan (returns `in_robot`) against the walls (their
/// grid and segments), Gauss-Newton from `start`, with the estimate and its covariance as
/// prior; `None` when fewer than `min_pairs` returns lie near a wall or the normal equations
/// are singular.
///
/// The prior stays the estimate whatever the start: where the walls leave a direction open
/// (along a corridor) the placement keeps the estimate's, so a start carried from the scans
/// before cannot drag the path along it.
fn relocalize(
    config: &RelocalizeConfig,
    (grid, walls): (&SegmentGrid<'_>, &[Segment]),
    in_robot: &[Vector2<f64>],
    start: &Pose2,
    (prior, covariance): (&Pose2, &Matrix3<f64>),
) -> Option<Placement> {
    // A floor of (1 mm)^2 and (0.3 mrad)^2 keeps an exactly known pose (the start) invertible.
    let floor = Matrix3::from_diagonal(&Vector3::new(1e-6, 1e-6, 1e-7));
    let prior_information = (covariance + floor).try_inverse()?;
    let prior = prior.to_vector();
    let offset = |state: &Vector3<f64>| {
        let mut delta = state - prior;
        delta[2] = slam_core::wrap_angle(delta[2]);
        delta
    };
    let mut state = start.to_vector();
    for iteration in 1..=config.iterations {
        let gate = (config.gate / iteration as f64).max(config.final_gate);
        let world_from_robot = Pose2::new(state[0], state[1], state[2]);
        let mut hessian = prior_information;
        let mut gradient = prior_information * offset(&state);
        let mut paired = 0;
        for p in in_robot {
            let (in_world, d_pose, _) = world_from_robot.transform_point_with_jacobians(p);
            let Some((normal, residual)) = wall_residual(grid, walls, &in_world, gate) else {
                continue;
            };
            let jacobian = (normal.transpose() * d_pose).transpose();
            let weight = cauchy_weight(residual, config.sigma);
            hessian += jacobian * jacobian.transpose() * weight;
            gradient += jacobian * (weight * residual);
            paired += 1;
        }
        if paired < config.min_pairs {
            return None;
        }
        let step = hessian.cholesky()?.solve(&(-gradient));
        state += within_gate(step, gate);
        if step.amax() < 1e-6 {
            break;
        }
    }
    let world_from_robot = Pose2::new(state[0], state[1], state[2]);
    let mut paired = 0;
    let mut misfit = 0.0;
    let mut information = Matrix3::zeros();
    for p in in_robot {
        let (in_world, d_pose, _) = world_from_robot.transform_point_with_jacobians(p);
        let residual = match wall_residual(grid, walls, &in_world, config.final_gate) {
            Some((normal, residual)) => {
                paired += 1;
                let jacobian = (normal.transpose() * d_pose).transpose();
                information +=
                    jacobian * jacobian.transpose() * cauchy_weight(residual, config.sigma);
                residual
            }
            None => config.final_gate,
        };
        misfit += cauchy_cost(residual, config.sigma);
    }
    let delta = offset(&state);
    (paired >= config.min_pairs).then_some(Placement {
        world_from_robot,
        misfit,
        prior_cost: 0.5 * delta.dot(&(prior_information * delta)),
        information,
        prior_information,
    })
}

/// A Gauss-Newton step (x, y, heading) shortened, direction kept, so that it moves the
/// position by at most `gate`: the returns were paired with walls within `gate`, and those
/// pairings say nothing about a pose farther away. Along what the walls leave nearly free
/// (a corridor's length) the normal equations are weak, and a small pull of a few returns
/// would otherwise throw the pose metres along it.
fn within_gate(step: Vector3<f64>, gate: f64) -> Vector3<f64> {
    let moved = step.fixed_rows::<2>(0).norm();
    if moved > gate {
        step * (gate / moved)
    } else {
        step
    }
}

/// The unit normal of the wall nearest to `in_world` within `gate` and the signed distance of
/// the point from the wall's line.
fn wall_residual(
    grid: &SegmentGrid<'_>,
    walls: &[(Vector2<f64>, Vector2<f64>)],
    in_world: &Vector2<f64>,
    gate: f64,
) -> Option<(Vector2<f64>, f64)> {
    let (k, _) = grid.nearest_within(in_world, gate)?;
    let (a, b) = walls[k];
    let along = (b - a).try_normalize(0.0)?;
    let normal = Vector2::new(-along.y, along.x);
    Some((normal, normal.dot(&(in_world - a))))
}

/// The weight of a residual under a Cauchy loss of scale `2 sigma` (the derivative of
/// [`cauchy_cost`] divided by the residual).
fn cauchy_weight(residual: f64, sigma: f64) -> f64 {
    let scaled = residual / (2.0 * sigma);
    1.0 / ((1.0 + scaled * scaled) * sigma * sigma)
}

/// The Cauchy loss of scale `2 sigma`, in units of `sigma^2`: `2 ln(1 + (r / 2 sigma)^2)`.
fn cauchy_cost(residual: f64, sigma: f64) -> f64 {
    let scaled = residual / (2.0 * sigma);
    2.0 * (1.0 + scaled * scaled).ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    type Segment = (Vector2<f64>, Vector2<f64>);

    fn v(x: f64, y: f64) -> Vector2<f64> {
        Vector2::new(x, y)
    }

    /// A 10 m square room and the returns of a robot at `world_from_robot` inside it, one
    /// per degree, from the true pose.
    fn room_scan(world_from_robot: &Pose2) -> (Vec<Segment>, Vec<Vector2<f64>>) {
        let corners = [v(-5.0, -5.0), v(5.0, -5.0), v(5.0, 5.0), v(-5.0, 5.0)];
        let walls: Vec<_> = (0..4).map(|k| (corners[k], corners[(k + 1) % 4])).collect();
        let points = (0..360)
            .map(|deg| {
                let angle = (deg as f64).to_radians() + world_from_robot.theta;
                let direction = v(angle.cos(), angle.sin());
                let origin = world_from_robot.translation();
                // The nearest wall along the ray.
                let range = walls
                    .iter()
                    .filter_map(|(a, b)| {
                        let edge = b - a;
                        let det = direction.x * (-edge.y) + edge.x * direction.y;
                        let rel = a - origin;
                        let t = (rel.x * (-edge.y) + edge.x * rel.y) / det;
                        let s = (direction.x * rel.y - direction.y * rel.x) / det;
                        (det.abs() > 1e-12 && t > 0.0 && (0.0..=1.0).contains(&s)).then_some(t)
                    })
                    .fold(f64::INFINITY, f64::min);
                world_from_robot.inverse_transform_point(&(origin + direction * range))
            })
            .collect();
        (walls, points)
    }

    /// [`relocalize`] with the default settings: the placement of the returns `points`
    /// against `walls`, Gauss-Newton from `start`, under the prior `(estimate, covariance)`.
    fn place(
        walls: &[Segment],
        points: &[Vector2<f64>],
        start: &Pose2,
        prior: (&Pose2, &Matrix3<f64>),
    ) -> Option<Placement> {
        let grid = SegmentGrid::new(walls, 1.0);
        relocalize(
            &RelocalizeConfig::default(),
            (&grid, walls),
            points,
            start,
            prior,
        )
    }

    #[test]
    fn a_scan_is_pulled_onto_the_walls_from_a_wrong_estimate() {
        let truth = Pose2::new(1.0, -0.5, 0.3);
        let (walls, points) = room_scan(&truth);
        let estimate = Pose2::new(1.12, -0.41, 0.33);
        let loose = Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.01));
        let found = place(&walls, &points, &estimate, (&estimate, &loose))
            .unwrap()
            .world_from_robot;
        let error = truth.between(&found);
        assert!(error.translation().norm() < 1e-3, "{found:?}");
        assert!(error.theta.abs() < 1e-4, "{found:?}");
    }

    #[test]
    fn a_certain_estimate_is_kept_and_a_scan_far_from_the_walls_is_not_placed() {
        let truth = Pose2::new(1.0, -0.5, 0.3);
        let (walls, points) = room_scan(&truth);
        let estimate = Pose2::new(1.05, -0.5, 0.3);
        // A prior at the floor ((1 mm)^2) holds against 5 cm of disagreement of the returns;
        // a loose one gives way to them.
        let certain = Matrix3::zeros();
        let kept = place(&walls, &points, &estimate, (&estimate, &certain))
            .unwrap()
            .world_from_robot;
        let shift = estimate.between(&kept).translation().norm();
        assert!(shift < 0.01, "moved {shift} m");
        let loose = Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.01));
        let moved = place(&walls, &points, &estimate, (&estimate, &loose))
            .unwrap()
            .world_from_robot;
        assert!(
            truth.between(&moved).translation().norm() < 1e-3,
            "{moved:?}"
        );
        // Placed 20 m away, no return lies near a wall: no pose.
        let far = Pose2::new(-20.0, 0.0, 0.0);
        assert!(place(&walls, &points, &far, (&far, &loose)).is_none());
    }

    #[test]
    fn the_placement_that_fits_the_walls_better_has_the_lower_objective() {
        // Estimated 0.8 m off along x, beyond the gate, with a prior that allows it (the
        // filter before a loop closes): the placement from the estimate stays off the walls;
        // the one from a carried correction finds them and wins.
        let truth = Pose2::new(1.0, -0.5, 0.3);
        let (walls, points) = room_scan(&truth);
        let uncertain = Matrix3::from_diagonal(&Vector3::new(0.25, 0.25, 0.01));
        let off = Pose2::new(1.8, -0.5, 0.3);
        let carried = Pose2::new(1.03, -0.48, 0.3);
        let from = |start: &Pose2, covariance: &Matrix3<f64>| {
            place(&walls, &points, start, (&off, covariance)).unwrap()
        };
        let (from_off, from_carried) = (from(&off, &uncertain), from(&carried, &uncertain));
        let miss = |p: &Placement| truth.between(&p.world_from_robot).translation().norm();
        assert!(miss(&from_off) > 0.5, "{from_off:?}");
        assert!(miss(&from_carried) < 0.05, "{from_carried:?}");
        assert!(
            from_carried.objective() < from_off.objective(),
            "{from_carried:?} against {from_off:?}"
        );
        // With a tight prior the estimate holds: the carried placement is pulled back
        // towards it and costs more than staying.
        let tight = Matrix3::from_diagonal(&Vector3::new(1e-4, 1e-4, 1e-5));
        assert!(from(&off, &tight).objective() < from(&carried, &tight).objective());
    }

    #[test]
    fn a_carried_start_does_not_drag_the_pose_along_a_corridor() {
        // A 100 m corridor 2.5 m wide: the walls fix the heading and the lateral position,
        // not the position along it. A start carried 0.9 m along the corridor ends where the
        // estimate is along it (the prior), on the walls across it.
        let walls = vec![(v(-50.0, 0.0), v(50.0, 0.0)), (v(-50.0, 2.5), v(50.0, 2.5))];
        let truth = Pose2::new(0.0, 1.25, 0.0);
        let points: Vec<Vector2<f64>> = (1..180)
            .map(|deg| {
                let angle = (deg as f64 - 90.0).to_radians();
                let direction = v(angle.cos(), angle.sin());
                let range = if direction.y > 0.0 {
                    1.25 / direction.y
                } else {
                    -1.25 / direction.y
                };
                direction * range.min(8.0)
            })
            .filter(|p| (p.y.abs() - 1.25).abs() < 1e-9)
            .collect();
        let estimate = Pose2::new(0.1, 1.1, 0.01);
        let covariance = Matrix3::from_diagonal(&Vector3::new(0.09, 0.09, 0.001));
        let carried = Pose2::new(1.0, 1.2, 0.0);
        let placed = place(&walls, &points, &carried, (&estimate, &covariance))
            .unwrap()
            .world_from_robot;
        assert!((placed.x - estimate.x).abs() < 0.05, "{placed:?}");
        assert!((placed.y - truth.y).abs() < 0.01, "{placed:?}");
        assert!(placed.theta.abs() < 1e-3, "{placed:?}");
    }

    #[test]
    fn a_step_moves_the_position_by_at_most_the_gate() {
        let long = within_gate(Vector3::new(3.0, -4.0, 0.5), 0.4);
        assert!(
            (long.fixed_rows::<2>(0).norm() - 0.4).abs() < 1e-12,
            "{long}"
        );
        // The direction, heading included, is kept.
        assert!(
            (long - Vector3::new(3.0, -4.0, 0.5) * 0.08).amax() < 1e-12,
            "{long}"
        );
        let short = Vector3::new(0.1, 0.2, 0.3);
        assert_eq!(within_gate(short, 0.4), short);
    }

    #[test]
    fn the_odometry_between_scans_is_compounded_and_the_first_scan_has_none() {
        let mut stage = Relocalize {
            config: RelocalizeConfig::default(),
            scans: Vec::new(),
            pending_odometry: None,
        };
        let scan = || Event::Scan {
            scan: LaserScan::new(-0.5, 0.5, vec![2.0; 11], 0.0, 30.0).unwrap(),
            robot_from_sensor: Pose3::identity(),
        };
        let step = |x: f64, theta: f64, variance: f64| {
            let increment = slam_sensors::odometry::PoseIncrement::new(
                Pose2::new(x, 0.0, theta),
                Matrix3::identity() * variance,
            )
            .unwrap();
            Event::Motion(Box::new(increment))
        };
        let events = [
            (0.0, step(0.3, 0.0, 1e-4)),
            (0.0, scan()),
            (1.0, step(1.0, std::f64::consts::FRAC_PI_2, 1e-4)),
            (2.0, step(1.0, 0.0, 1e-4)),
            (2.0, scan()),
            (3.0, scan()),
        ];
        for (time, event) in events {
            stage.record(&TimedEvent { time, event }).unwrap();
        }
        assert_eq!(stage.scans.len(), 3);
        // The motion before the first scan links it to nothing.
        assert!(stage.scans[0].odometry.is_none());
        let (increment, covariance) = stage.scans[1].odometry.unwrap();
        assert!((increment.x - 1.0).abs() < 1e-12 && (increment.y - 1.0).abs() < 1e-12);
        assert!((increment.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // The second step's variance plus the first's, carried through the turn: its heading
        // variance moves the second step's end sideways by 1 m per radian.
        assert!((covariance[(2, 2)] - 2e-4).abs() < 1e-12, "{covariance}");
        assert!(
            (covariance[(0, 0)] - (2e-4 + 1e-4)).abs() < 1e-12,
            "{covariance}"
        );
        // No motion between the last two scans.
        assert!(stage.scans[2].odometry.is_none());
    }

    #[test]
    fn steps_between_scans_keep_the_last_correction() {
        let path: Vec<(f64, Pose2)> = (0..5)
            .map(|k| (k as f64, Pose2::new(k as f64, 0.0, 0.0)))
            .collect();
        let shift = Pose2::new(0.0, 0.5, 0.0);
        let corrections = [(1.0, shift), (3.0, Pose2::identity())];
        let moved = corrected(&path, &corrections);
        let ys: Vec<f64> = moved.iter().map(|(_, p)| p.y).collect();
        assert_eq!(ys, vec![0.0, 0.5, 0.5, 0.0, 0.0]);
    }

    #[test]
    fn bad_settings_are_refused() {
        for bad in [
            RelocalizeConfig {
                sigma: 0.0,
                ..Default::default()
            },
            RelocalizeConfig {
                beam_step: 0,
                ..Default::default()
            },
            RelocalizeConfig {
                max_range: f64::NAN,
                ..Default::default()
            },
            RelocalizeConfig {
                final_gate: 1.0,
                gate: 0.5,
                ..Default::default()
            },
            RelocalizeConfig {
                max_see_through: 0.0,
                ..Default::default()
            },
            RelocalizeConfig {
                max_see_through: 1.5,
                ..Default::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
