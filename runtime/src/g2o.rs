//! The pose graph of `slam run --g2o` (`[output] g2o = true`): `graph.g2o` in the text format
//! of g2o (read by g2o, GTSAM's `readG2o`, and most pose-graph tools). [`G2oObserver`]
//! collects during a run what the graph needs beyond the trajectory; [`g2o_text`] makes the
//! text of the finished run (the command writes it as `graph.g2o`).
//!
//! - `VERTEX_SE2 k x y theta`: the pose estimated at the end of time step `k` (the poses of
//!   `trajectory.tum`, in order, ids `0 .. N-1`).
//! - `EDGE_SE2 k k+1 dx dy dtheta I11 I12 I13 I22 I23 I33`: the relative motion between the
//!   consecutive estimated poses (`⊖x_k ⊕ x_k+1`, so the graph is at rest at the estimates),
//!   with the information matrix (upper triangle, row by row) the inverse of the covariance of
//!   the odometry between the two steps: the motion models' own noise `C_d` propagated
//!   through their Jacobians, plus a floor of `(1 mm)²` and `(0.001 rad)²` on the diagonal so
//!   that a step without motion stays invertible. (A filter keeps no cross-covariance between
//!   consecutive poses, so the estimated covariances cannot give it.)
//! - `VERTEX_XY` + `EDGE_SE2_XY k l dx dy I11 I12 I22`: each confirmed point feature or pole
//!   at its final estimated position; the edge goes from the pose of the step in which the
//!   feature entered the map (the estimators do not report which step saw which feature
//!   last), its measurement is the final position in that pose's frame, its information the
//!   inverse of the feature's final position covariance rotated into that frame (the
//!   identity where the estimator has no covariance, said in a comment).
//! - Walls: two `VERTEX_XY` per confirmed wall (its end points, without edges: they are
//!   geometry, not measurements) and a comment line `# WALL <feature id> <v1> <v2>`, which
//!   g2o readers skip.
//!
//! Every vertex comes before every edge (g2o needs its vertices first), and the comments
//! (a header, the walls) come last: GTSAM's `readG2o` stops reading edges at the first line
//! it does not know, a comment included.

use std::fmt::Write as _;

use slam_core::nalgebra::{Matrix2, Matrix3};
use slam_core::{Estimator, Pose2, Shape, UpdateReport};
use slam_sensors::{Event, TimedEvent};

use crate::error::{Result, RuntimeError};
use crate::eval::{Record, anchor_covariance, confirmed};
use crate::run::RunOutput;
use crate::session::Observer;

/// Standard deviation added to each axis of an odometry edge's covariance, m (and rad).
const EDGE_FLOOR_SIGMA: f64 = 1e-3;

/// The [`Observer`] that keeps what `graph.g2o` needs beyond the trajectory: the odometry
/// covariance of each time step and the step in which each feature entered the map.
#[derive(Debug, Default)]
pub struct G2oObserver {
    /// Per ended step, the covariance of the odometry since the previous step's end.
    step_odometry: Vec<Matrix3<f64>>,
    /// The odometry of the open step, in the frame of the previous step's pose.
    relative: Pose2,
    covariance: Matrix3<f64>,
    /// Per feature id, the first step whose end saw it in the map.
    first_seen: Vec<Option<usize>>,
}

impl Observer for G2oObserver {
    fn event(
        &mut self,
        event: &TimedEvent,
        _: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        if let Event::Motion(motion) = &event.event {
            let prediction = motion
                .predict(&self.relative)
                .map_err(|e| RuntimeError::from(e).at("odometry of graph.g2o", event.time))?;
            let j = &prediction.d_pose_d_pose;
            let jd = &prediction.d_pose_d_control;
            let c = Matrix3::from_fn(|i, k| self.covariance[(i, k)]);
            let propagated =
                j * slam_core::nalgebra::DMatrix::from_fn(3, 3, |i, k| c[(i, k)]) * j.transpose()
                    + jd * &prediction.cov_control * jd.transpose();
            if propagated.shape() == (3, 3) {
                self.covariance = Matrix3::from_fn(|i, k| propagated[(i, k)]);
            }
            self.relative = prediction.pose;
        }
        Ok(())
    }

    fn step_end(&mut self, _: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        let step = self.step_odometry.len();
        self.step_odometry.push(self.covariance);
        self.covariance = Matrix3::zeros();
        self.relative = Pose2::identity();
        for (id, _) in estimator.map().iter() {
            if id.0 >= self.first_seen.len() {
                self.first_seen.resize(id.0 + 1, None);
            }
            self.first_seen[id.0].get_or_insert(step);
        }
        Ok(())
    }
}

/// `v` with every number in Rust's shortest round-trip form.
fn numbers(values: &[f64]) -> String {
    values
        .iter()
        .map(f64::to_string)
        .collect::<Vec<_>>()
        .join(" ")
}

/// The information matrix of a covariance, if it is invertible and finite.
fn information3(covariance: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    covariance
        .try_inverse()
        .filter(|m| m.iter().all(|v| v.is_finite()))
}

/// `graph.g2o` of a finished run (see the module documentation).
pub fn g2o_text(output: &RunOutput, observer: &G2oObserver) -> String {
    graph_text(
        &output.name,
        output.estimator.as_ref(),
        &output.record.estimates,
        observer,
    )
}

/// `graph.g2o` of the estimates of data `name` and the final map of `estimator`.
fn graph_text(
    name: &str,
    estimator: &dyn Estimator<Pose2>,
    estimates: &[Record],
    observer: &G2oObserver,
) -> String {
    let n = estimates.len();
    let mut vertices = String::new();
    let mut edges = String::new();
    let mut notes = Vec::new();
    // Writing to a String cannot fail.
    for (k, record) in estimates.iter().enumerate() {
        let p = record.pose;
        let _ = writeln!(vertices, "VERTEX_SE2 {k} {}", numbers(&[p.x, p.y, p.theta]));
    }
    let floor = Matrix3::from_diagonal_element(EDGE_FLOOR_SIGMA * EDGE_FLOOR_SIGMA);
    for k in 1..n {
        let motion = estimates[k - 1].pose.between(&estimates[k].pose);
        let covariance = observer
            .step_odometry
            .get(k)
            .copied()
            .unwrap_or_else(Matrix3::zeros)
            + floor;
        let info = information3(&covariance)
            .unwrap_or_else(|| floor.map(|v| if v > 0.0 { 1.0 / v } else { 0.0 }));
        let _ = writeln!(
            edges,
            "EDGE_SE2 {} {k} {} {}",
            k - 1,
            numbers(&[motion.x, motion.y, motion.theta]),
            numbers(&[
                info[(0, 0)],
                info[(0, 1)],
                info[(0, 2)],
                info[(1, 1)],
                info[(1, 2)],
                info[(2, 2)]
            ])
        );
    }
    let mut next = n;
    let mut without_covariance = 0;
    let mut walls = 0;
    let mut landmarks = 0;
    for (id, feature) in estimator.map().iter() {
        if !confirmed(estimator, id) || n == 0 {
            continue;
        }
        match feature.shape() {
            Some(Shape::Wall { start, end }) => {
                notes.push(format!("# WALL {} {next} {}", id.0, next + 1));
                let _ = writeln!(
                    vertices,
                    "VERTEX_XY {next} {}",
                    numbers(&[start.x, start.y])
                );
                let _ = writeln!(
                    vertices,
                    "VERTEX_XY {} {}",
                    next + 1,
                    numbers(&[end.x, end.y])
                );
                next += 2;
                walls += 1;
            }
            Some(
                shape @ (Shape::Pole { .. } | Shape::Point { .. } | Shape::PlanarPoint { .. }),
            ) => {
                let position = shape.anchor();
                let step = observer
                    .first_seen
                    .get(id.0)
                    .copied()
                    .flatten()
                    .unwrap_or(n - 1)
                    .min(n - 1);
                let pose = estimates[step].pose;
                let local = pose.inverse_transform_point(&position);
                let rotation = pose.rotation();
                let info = anchor_covariance(estimator, id)
                    .map(|c| rotation.transpose() * c * rotation)
                    .and_then(|c: Matrix2<f64>| c.try_inverse())
                    .filter(|m| m.iter().all(|v| v.is_finite()));
                let info = info.unwrap_or_else(|| {
                    without_covariance += 1;
                    Matrix2::identity()
                });
                let _ = writeln!(
                    vertices,
                    "VERTEX_XY {next} {}",
                    numbers(&[position.x, position.y])
                );
                let _ = writeln!(
                    edges,
                    "EDGE_SE2_XY {step} {next} {} {}",
                    numbers(&[local.x, local.y]),
                    numbers(&[info[(0, 0)], info[(0, 1)], info[(1, 1)]])
                );
                next += 1;
                landmarks += 1;
            }
            _ => {}
        }
    }
    let mut text = vertices;
    text.push_str(&edges);
    let _ = write!(
        text,
        "# graph.g2o of mspace-slam `slam run`: data {name}, estimator {}. Comments come last: \
         GTSAM's readG2o stops reading edges at the first line it does not know.\n\
         # {n} VERTEX_SE2 (the estimated pose at the end of each time step, ids 0..{last}),\n\
         # {edges_n} EDGE_SE2 (relative motion between consecutive estimates; information: \
         inverse odometry noise + floor),\n\
         # {landmarks} VERTEX_XY + EDGE_SE2_XY (point features and poles, final positions, from \
         the pose of the step that first mapped them),\n\
         # {walls} walls as two VERTEX_XY end points each (no edges), named by '# WALL id v1 v2'\n",
        estimator.name(),
        last = n.saturating_sub(1),
        edges_n = n.saturating_sub(1),
    );
    if without_covariance > 0 {
        let _ = writeln!(
            text,
            "# {without_covariance} landmark edges have the identity as information: the \
             estimator gave no invertible covariance of their position"
        );
    }
    for note in notes {
        text.push_str(&note);
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::FeatureId;

    /// The step in which feature `id` entered the map.
    fn first_seen(observer: &G2oObserver, id: FeatureId) -> Option<usize> {
        observer.first_seen.get(id.0).copied().flatten()
    }
    use crate::{Config, Start};
    use slam_core::MotionModel;
    use slam_core::nalgebra::DMatrix;

    /// A motion increment with fixed noise (a straight step of 1 m).
    #[derive(Debug)]
    struct Step;

    impl MotionModel<Pose2> for Step {
        fn control(&self) -> slam_core::nalgebra::DVector<f64> {
            slam_core::nalgebra::DVector::from_vec(vec![1.0, 0.0, 0.0])
        }

        fn apply_control(
            &self,
            pose: &Pose2,
            control: &slam_core::nalgebra::DVector<f64>,
        ) -> slam_core::Result<Pose2> {
            Ok(pose.compose(&Pose2::new(control[0], control[1], control[2])))
        }

        fn predict(&self, pose: &Pose2) -> slam_core::Result<slam_core::MotionPrediction<Pose2>> {
            let (moved, d_pose, d_control) =
                pose.compose_with_jacobians(&Pose2::new(1.0, 0.0, 0.0));
            Ok(slam_core::MotionPrediction {
                pose: moved,
                d_pose_d_pose: DMatrix::from_fn(3, 3, |i, k| d_pose[(i, k)]),
                d_pose_d_control: DMatrix::from_fn(3, 3, |i, k| d_control[(i, k)]),
                cov_control: DMatrix::from_diagonal(&slam_core::nalgebra::DVector::from_vec(vec![
                    0.01, 0.04, 0.0025,
                ])),
            })
        }
    }

    #[test]
    fn odometry_edges_carry_the_inverse_motion_noise_in_upper_triangular_order() {
        let start = Start {
            pose: Pose2::identity(),
            covariance: DMatrix::zeros(3, 3),
        };
        let config = Config::from_toml("[estimator]\ntype = \"dead-reckoning\"\n", "t").unwrap();
        let mut estimator = config.estimator.build(&start).unwrap();
        let mut observer = G2oObserver::default();
        let mut record = crate::Recorder::default();
        for k in 0..3 {
            let event = TimedEvent {
                time: k as f64,
                event: Event::Motion(Box::new(Step)),
            };
            estimator.predict(&Step).unwrap();
            observer.event(&event, None, estimator.as_ref()).unwrap();
            observer.step_end(k as f64, estimator.as_ref()).unwrap();
            record.step_end(k as f64, estimator.as_ref()).unwrap();
        }
        assert_eq!(observer.step_odometry.len(), 3);
        let c = observer.step_odometry[1];
        assert!((c[(0, 0)] - 0.01).abs() < 1e-12 && (c[(2, 2)] - 0.0025).abs() < 1e-12);
        assert_eq!(first_seen(&observer, FeatureId(0)), None);
        // The text of the graph.
        let text = graph_text("t", estimator.as_ref(), &record.estimates, &observer);
        let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
        assert_eq!(lines[0], "VERTEX_SE2 0 1 0 0");
        assert_eq!(lines[2], "VERTEX_SE2 2 3 0 0");
        let edge: Vec<&str> = lines[3].split(' ').collect();
        assert_eq!(&edge[..6], ["EDGE_SE2", "0", "1", "1", "0", "0"]);
        assert_eq!(edge.len(), 12);
        let info: Vec<f64> = edge[6..].iter().map(|v| v.parse().unwrap()).collect();
        let floor = EDGE_FLOOR_SIGMA * EDGE_FLOOR_SIGMA;
        let expected = [
            1.0 / (0.01 + floor),
            0.0,
            0.0,
            1.0 / (0.04 + floor),
            0.0,
            1.0 / (0.0025 + floor),
        ];
        for (got, want) in info.iter().zip(expected) {
            assert!((got - want).abs() < 1e-9 * want.abs().max(1.0), "{info:?}");
        }
        assert_eq!(lines.len(), 5);
    }
}
