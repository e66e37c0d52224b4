//! Scan matching of a particle's pose to the particle's own cluster map (the `scan-match`
//! proposal, an addition to the paper in the manner of Grisetti et al. 2007): the pose
//! predicted by the motion model is moved to the nearest minimum of the robust point-to-line
//! distances of the scan to the clusters plus the motion model's Gaussian prior.

use slam_core::nalgebra::{Matrix3, Vector2, Vector3};
use slam_core::{Pose3, RobotPose};

use super::ppca::Cluster;

/// Settings of [`refine`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct MatchSettings {
    /// A point is matched to a cluster within this distance of its line, m.
    pub gate: f64,
    /// ... and within this distance beyond the cluster's ends, m.
    pub end_margin: f64,
    /// Deviation of a point from its cluster's line, m (the Cauchy scale of the residuals).
    pub point_sigma: f64,
    /// Gauss-Newton iterations at most.
    pub iterations: usize,
    /// Matched points needed for a correction.
    pub min_matched: usize,
}

/// `(-v_y, v_x)`.
fn perp(v: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(-v.y, v.x)
}

/// The clusters whose segments (extended by the gate) come within `reach` of `origin`.
pub(super) fn reachable<'a>(
    clusters: impl Iterator<Item = &'a Cluster>,
    origin: &Vector2<f64>,
    reach: f64,
) -> Vec<Cluster> {
    clusters
        .filter(|k| {
            let (a, b) = k.ends();
            distance_to_segment(origin, &a, &b) <= reach
        })
        .copied()
        .collect()
}

fn distance_to_segment(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let ab = b - a;
    let t = if ab.norm_squared() > 0.0 {
        ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).norm()
}

/// The signed distance of `z` from the line of the nearest cluster whose extended segment
/// it falls on, and that line's unit normal; `None` beyond `gate`.
fn nearest_line(
    clusters: &[Cluster],
    z: &Vector2<f64>,
    gate: f64,
    end_margin: f64,
) -> Option<(f64, Vector2<f64>)> {
    let mut best: Option<(f64, Vector2<f64>)> = None;
    for k in clusters {
        let d = z - k.mean;
        let half = (3.0 * k.principal_variance).sqrt() + end_margin;
        if d.dot(&k.direction).abs() > half {
            continue;
        }
        let normal = perp(&k.direction);
        let e = d.dot(&normal);
        if e.abs() <= gate && best.is_none_or(|(b, _)| e.abs() < b.abs()) {
            best = Some((e, normal));
        }
    }
    best
}

/// A matched planar sensor pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Matched {
    /// Heading, rad.
    pub heading: f64,
    /// Position, m.
    pub translation: Vector2<f64>,
    /// The information matrix of `(x, y, heading)` at the match (Gauss-Newton's `J^T W J` plus
    /// the prior's).
    pub information: Matrix3<f64>,
}

/// The planar sensor pose that minimizes the Cauchy-weighted squared distances of `points`
/// (sensor frame) to their nearest cluster lines plus the prior `N((heading, translation),
/// diag(prior_information)^-1)`; `None` when fewer than `min_matched` points match or the
/// normal equations are singular.
pub(super) fn refine(
    clusters: &[Cluster],
    points: &[Vector2<f64>],
    (heading, translation): (f64, Vector2<f64>),
    prior_information: &Vector3<f64>,
    settings: &MatchSettings,
) -> Option<Matched> {
    let (mut theta, mut t) = (heading, translation);
    let mut information = Matrix3::zeros();
    let mut matched_last = 0;
    for iteration in 0..settings.iterations {
        // Coarse to fine: the gate and the Cauchy scale start 4 times wider and halve at
        // each iteration, so that a pose whose scan lies a gate or more off its lines still
        // finds them.
        let widening = (4.0 * 0.5f64.powi(iteration as i32)).max(1.0);
        let gate = settings.gate * widening;
        let scale = settings.point_sigma * widening;
        let inv_var = scale.powi(-2);
        let (s, c) = theta.sin_cos();
        let mut h = Matrix3::from_diagonal(prior_information);
        let offset = Vector3::new(t.x - translation.x, t.y - translation.y, theta - heading);
        let mut g = prior_information.component_mul(&offset);
        let mut matched = 0;
        for p in points {
            let arm = Vector2::new(c * p.x - s * p.y, s * p.x + c * p.y);
            let z = arm + t;
            let Some((e, normal)) = nearest_line(clusters, &z, gate, settings.end_margin) else {
                continue;
            };
            matched += 1;
            let robust = 1.0 / (1.0 + (e / scale).powi(2));
            let j = Vector3::new(normal.x, normal.y, normal.dot(&perp(&arm)));
            h += j * j.transpose() * (robust * inv_var);
            g += j * (e * robust * inv_var);
        }
        matched_last = matched;
        if matched < settings.min_matched {
            return None;
        }
        information = h;
        let step = -h.cholesky()?.solve(&g);
        t += Vector2::new(step.x, step.y);
        theta += step.z;
        if widening == 1.0 && step.xy().norm() < 1e-4 && step.z.abs() < 1e-5 {
            break;
        }
    }
    (matched_last >= settings.min_matched).then_some(Matched {
        heading: theta,
        translation: t,
        information,
    })
}

/// The planar sensor pose `(heading, translation)` of `pose`.
pub(super) fn planar(pose: &Pose3) -> (f64, Vector2<f64>) {
    let origin = pose.transform_point(&Vector3::zeros());
    let ahead = pose.transform_point(&Vector3::x()) - origin;
    (ahead.y.atan2(ahead.x), origin.xy())
}

/// `pose` moved rigidly in the plane so that its sensor sits at `(heading, translation)`
/// (Newton steps along [`RobotPose::planar_motion_generators`]); `None` if that fails.
pub(super) fn move_sensor_to<P: RobotPose>(
    pose: &P,
    robot_from_sensor: &Pose3,
    heading: f64,
    translation: &Vector2<f64>,
) -> Option<P> {
    let mut moved = *pose;
    for _ in 0..4 {
        let (now_heading, now_translation) = planar(&moved.world_from_sensor(robot_from_sensor));
        let turn = slam_core::wrap_angle(heading - now_heading);
        let shift = translation - now_translation;
        if shift.norm() < 1e-9 && turn.abs() < 1e-12 {
            break;
        }
        // A rotation by `turn` about the world origin also moves the sensor by
        // `turn * perp(now_translation)`; the translation makes up the rest.
        let rest = shift - perp(&now_translation) * turn;
        let [gx, gy, gr] = moved.planar_motion_generators();
        let parameters: Vec<f64> = moved
            .parameters()
            .iter()
            .enumerate()
            .map(|(i, v)| v + gx[i] * rest.x + gy[i] * rest.y + gr[i] * turn)
            .collect();
        moved = P::from_parameters(&parameters).ok()?;
    }
    Some(moved)
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::Pose2;

    fn room() -> Vec<Cluster> {
        // The walls of [0, 10] x [0, 6], as clusters of points 5 cm apart.
        let wall = |a: Vector2<f64>, b: Vector2<f64>| {
            let n = ((b - a).norm() / 0.05) as usize;
            let points: Vec<Vector2<f64>> = (0..=n)
                .map(|i| a + (b - a) * (i as f64 / n as f64))
                .collect();
            Cluster::fit(&points).unwrap()
        };
        let c = [
            Vector2::new(0.0, 0.0),
            Vector2::new(10.0, 0.0),
            Vector2::new(10.0, 6.0),
            Vector2::new(0.0, 6.0),
        ];
        (0..4).map(|i| wall(c[i], c[(i + 1) % 4])).collect()
    }

    fn settings() -> MatchSettings {
        MatchSettings {
            gate: 0.5,
            end_margin: 0.2,
            point_sigma: 0.05,
            iterations: 30,
            min_matched: 20,
        }
    }

    /// A prior of 1 m and 0.5 rad.
    fn prior() -> Vector3<f64> {
        Vector3::new(1.0, 1.0, 4.0)
    }

    /// Points of the room seen from `(x, y, heading)`, in the sensor frame.
    fn scan(x: f64, y: f64, heading: f64) -> Vec<Vector2<f64>> {
        (0..360)
            .map(|k| {
                let bearing = (k as f64).to_radians();
                let range = crate::ipslam::tests::ray(Vector2::new(x, y), heading + bearing);
                Vector2::new(range * bearing.cos(), range * bearing.sin())
            })
            .collect()
    }

    #[test]
    fn a_perturbed_pose_is_matched_back_to_the_truth() {
        let points = scan(3.0, 2.0, 0.4);
        // 0.1 rad and 0.25 m off: the far wall's points lie up to 1 m off their line.
        let start = (0.5, Vector2::new(3.2, 1.85));
        let matched = refine(&room(), &points, start, &prior(), &settings()).unwrap();
        assert!((matched.heading - 0.4).abs() < 1e-3, "{matched:?}");
        assert!(
            (matched.translation - Vector2::new(3.0, 2.0)).norm() < 5e-3,
            "{matched:?}"
        );
        // The information is the prior's plus the points'.
        assert!(matched.information[(0, 0)] > 100.0 * prior()[0]);
    }

    #[test]
    fn no_map_means_no_correction() {
        let points = scan(3.0, 2.0, 0.4);
        let start = (0.4, Vector2::new(3.0, 2.0));
        assert!(refine(&[], &points, start, &prior(), &settings()).is_none());
    }

    #[test]
    fn the_robot_is_moved_so_that_its_sensor_sits_at_the_target() {
        let robot_from_sensor = Pose3::new(Vector3::new(0.3, 0.1, 0.2), 0.2, 0.0, 0.0);
        let pose = Pose2::new(12.0, -7.0, 1.0);
        let moved =
            move_sensor_to(&pose, &robot_from_sensor, 1.1, &Vector2::new(11.9, -6.8)).unwrap();
        let (heading, translation) = planar(&moved.world_from_sensor(&robot_from_sensor));
        assert!((heading - 1.1).abs() < 1e-9);
        assert!((translation - Vector2::new(11.9, -6.8)).norm() < 1e-9);
    }
}
