//! A particle's line map: its PPCA line clusters (a persistent vector shared after
//! resampling), how a scan weighs it (eq. 18) and how the scan's clusters join it (the
//! correspondence of section III-D and the incremental PCA merge of eqs. 15-16), and the
//! `scan-match` proposal against it.

use rand_distr::{Distribution, StandardNormal};
use slam_core::nalgebra::{Matrix3, Vector2, Vector3};
use slam_core::{Pose3, RobotPose};

use super::IpslamParams;
use super::matching::{self, planar};
use super::ppca::{self, Cluster};
use crate::particles::Particle;
use crate::particles::pvec::PVec;

/// A particle's map of line clusters.
pub(super) type LineMap = PVec<Cluster>;

/// What one particle did with one scan.
#[derive(Default)]
pub(super) struct ScanOutcome {
    pub log_likelihood: f64,
    pub merged: usize,
    pub added: usize,
}

/// The `scan-match` proposal for one particle: the match of the scan to its own clusters
/// under the prior `N(pose, diag(1 / prior_information))`, then a draw from the Gaussian of
/// the match (from the prior where too few points match).
pub(super) fn match_to_own_map<P: RobotPose>(
    particle: &mut Particle<P, LineMap>,
    params: &IpslamParams,
    robot_from_sensor: &Pose3,
    points: &[Vector2<f64>],
    prior_information: &Vector3<f64>,
    rng: &mut impl rand::Rng,
) {
    let start = planar(&particle.pose.world_from_sensor(robot_from_sensor));
    let settings = params.matching();
    let clusters = matching::reachable(
        particle.map.iter().map(|(_, k)| k),
        &start.1,
        params.max_range + settings.gate + settings.end_margin,
    );
    let (centre, information) =
        match matching::refine(&clusters, points, start, prior_information, &settings) {
            Some(m) => ((m.heading, m.translation), m.information),
            None => (start, Matrix3::from_diagonal(prior_information)),
        };
    // x = L^-T z has the covariance (L L^T)^-1.
    let Some(cholesky) = information.cholesky() else {
        return;
    };
    let z = Vector3::from_fn(|_, _| -> f64 { StandardNormal.sample(rng) });
    let Some(offset) = cholesky.l().transpose().solve_upper_triangular(&z) else {
        return;
    };
    let heading = centre.0 + offset.z;
    let translation = centre.1 + offset.xy();
    if let Some(moved) =
        matching::move_sensor_to(&particle.pose, robot_from_sensor, heading, &translation)
    {
        particle.pose = moved;
    }
}

/// Steps 1-4 of the module documentation of [`super`] for one particle: the scan's weight
/// against the map before the scan, then its clusters merged into corresponding ones or
/// added.
pub(super) fn process<P: RobotPose>(
    particle: &mut Particle<P, LineMap>,
    params: &IpslamParams,
    robot_from_sensor: &Pose3,
    scan_clusters: &[(Cluster, Vec<Vector2<f64>>)],
    points: &[Vector2<f64>],
) -> ScanOutcome {
    let (heading, translation) = planar(&particle.pose.world_from_sensor(robot_from_sensor));
    let (s, c) = heading.sin_cos();
    let place = |p: &Vector2<f64>| Vector2::new(c * p.x - s * p.y, s * p.x + c * p.y) + translation;
    // Old clusters that the scan can reach.
    let nearby: Vec<(usize, Cluster)> = particle
        .map
        .iter()
        .filter(|(_, k)| {
            (k.mean - translation).norm() <= params.max_range + 3.0 * k.principal_variance.sqrt()
        })
        .map(|(slot, k)| (slot, *k))
        .collect();
    let mut outcome = ScanOutcome {
        log_likelihood: scan_log_likelihood(&nearby, points, &place, params),
        ..ScanOutcome::default()
    };
    let placed: Vec<(Cluster, Vec<Vector2<f64>>)> = scan_clusters
        .iter()
        .map(|(k, members)| {
            (
                k.transformed(heading, &translation),
                members.iter().map(place).collect(),
            )
        })
        .collect();
    let pairs = correspondences(&nearby, &placed, params);
    let mut old_used = vec![false; nearby.len()];
    let mut new_used = vec![false; placed.len()];
    for (_, i, j) in pairs {
        if old_used[i] || new_used[j] {
            continue;
        }
        let (slot, old) = nearby[i];
        let (new, members) = &placed[j];
        let merged = ppca::merge(&old, new, members);
        // A merge that makes a thick cluster (two walls at a corner) is refused.
        if merged.sigma2.sqrt() > params.new_cluster_max_sigma {
            continue;
        }
        old_used[i] = true;
        new_used[j] = true;
        particle.map.set(slot, Some(merged));
        outcome.merged += 1;
    }
    for (j, (new, _)) in placed.into_iter().enumerate() {
        if !new_used[j]
            && new.count >= params.new_cluster_min_points
            && new.sigma2.sqrt() <= params.new_cluster_max_sigma
        {
            particle.map.push(new);
            outcome.added += 1;
        }
    }
    outcome
}

/// Eq. 18 against the map before this scan: every point's log-likelihood under its best
/// cluster, floored at the outlier threshold.
fn scan_log_likelihood(
    nearby: &[(usize, Cluster)],
    points: &[Vector2<f64>],
    place: &impl Fn(&Vector2<f64>) -> Vector2<f64>,
    params: &IpslamParams,
) -> f64 {
    let floor = params.outlier_likelihood.max(1e-300).ln();
    let mut total = 0.0;
    for p in points {
        let z = place(p);
        let best = nearby
            .iter()
            .map(|(_, k)| k.log_likelihood(&z))
            .fold(f64::NEG_INFINITY, f64::max);
        total += best.max(floor);
    }
    total
}

/// Correspondences of the scan's clusters with old ones (section III-D), as
/// `(centre distance, old index, new index)` sorted for a greedy match by centre distance:
/// principal directions within `match_angle_deg`, and centres within the sum of the
/// principal variances (the paper) or, an addition, segments that overlap or touch; in
/// both cases within `max_normal_distance` of the old cluster's line.
fn correspondences(
    nearby: &[(usize, Cluster)],
    placed: &[(Cluster, Vec<Vector2<f64>>)],
    params: &IpslamParams,
) -> Vec<(f64, usize, usize)> {
    let cos_limit = params.match_angle_deg.to_radians().cos();
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (j, (new, _)) in placed.iter().enumerate() {
        for (i, (_, old)) in nearby.iter().enumerate() {
            if old.direction.dot(&new.direction).abs() < cos_limit {
                continue;
            }
            let offset = new.mean - old.mean;
            let distance = offset.norm();
            let normal = Vector2::new(-old.direction.y, old.direction.x);
            let extents = (3.0 * old.principal_variance).sqrt()
                + (3.0 * new.principal_variance).sqrt()
                + params.max_normal_distance;
            let reach = (old.principal_variance + new.principal_variance).max(extents);
            if distance <= reach && offset.dot(&normal).abs() <= params.max_normal_distance {
                pairs.push((distance, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    pairs
}
