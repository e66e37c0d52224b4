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
pub(super) type LineMap = PVec<MapCluster>;

/// A cluster of a particle's map with its sightings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct MapCluster {
    /// The PPCA cluster.
    pub cluster: Cluster,
    /// Scans whose clusters it holds (a union of two map clusters adds theirs).
    pub sightings: u32,
    /// The last of those scans (the filter's count of processed scans).
    pub last_seen: usize,
}

/// What one particle did with one scan.
#[derive(Default)]
pub(super) struct ScanOutcome {
    pub log_likelihood: f64,
    pub merged: usize,
    pub added: usize,
    /// Merges of two map clusters (step 5).
    pub fused: usize,
    /// Unconfirmed map clusters pruned (step 6).
    pub pruned: usize,
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
        particle.map.iter().map(|(_, k)| &k.cluster),
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

/// Steps 1-6 of the module documentation of [`super`] for one particle and the scan number
/// `scan`: the scan's weight against the map before the scan, then its clusters merged into
/// corresponding ones or added, then the map clusters of one line merged and the unconfirmed
/// ones pruned (when configured).
pub(super) fn process<P: RobotPose>(
    particle: &mut Particle<P, LineMap>,
    params: &IpslamParams,
    robot_from_sensor: &Pose3,
    scan_clusters: &[(Cluster, Vec<Vector2<f64>>)],
    points: &[Vector2<f64>],
    scan: usize,
) -> ScanOutcome {
    let (heading, translation) = planar(&particle.pose.world_from_sensor(robot_from_sensor));
    let (s, c) = heading.sin_cos();
    let place = |p: &Vector2<f64>| Vector2::new(c * p.x - s * p.y, s * p.x + c * p.y) + translation;
    // Old clusters that the scan can reach.
    let nearby: Vec<(usize, Cluster)> = particle
        .map
        .iter()
        .filter(|(_, k)| {
            let k = &k.cluster;
            (k.mean - translation).norm() <= params.max_range + 3.0 * k.principal_variance.sqrt()
        })
        .map(|(slot, k)| (slot, k.cluster))
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
    // The map's clusters near the scan, as they stand after the merges and additions.
    let mut near = nearby;
    let mut changed: Vec<usize> = Vec::new();
    for (_, i, j) in pairs {
        if old_used[i] || new_used[j] {
            continue;
        }
        let (slot, old) = near[i];
        let (new, members) = &placed[j];
        let merged = ppca::merge(&old, new, members);
        // A merge that makes a thick cluster (two walls at a corner) is refused.
        if merged.sigma2.sqrt() > params.new_cluster_max_sigma {
            continue;
        }
        old_used[i] = true;
        new_used[j] = true;
        let sightings = particle.map.get(slot).map_or(0, |k| k.sightings);
        particle.map.set(
            slot,
            Some(MapCluster {
                cluster: merged,
                sightings: sightings.saturating_add(1),
                last_seen: scan,
            }),
        );
        near[i].1 = merged;
        changed.push(slot);
        outcome.merged += 1;
    }
    for (j, (new, _)) in placed.into_iter().enumerate() {
        if !new_used[j]
            && new.count >= params.new_cluster_min_points
            && new.sigma2.sqrt() <= params.new_cluster_max_sigma
        {
            let slot = particle.map.push(MapCluster {
                cluster: new,
                sightings: 1,
                last_seen: scan,
            });
            near.push((slot, new));
            changed.push(slot);
            outcome.added += 1;
        }
    }
    if params.merge_map_clusters {
        outcome.fused = fuse(&mut particle.map, &mut near, changed, params);
    }
    if params.prune_unconfirmed_after > 0 {
        outcome.pruned = prune(
            &mut particle.map,
            &near,
            scan,
            params.prune_unconfirmed_after,
        );
    }
    outcome
}

/// Step 6 of the module documentation of [`super`] (an addition): the clusters of `near`
/// (slots of `map`) seen in one scan only, `after` or more scans ago, become holes. Returns
/// how many.
fn prune(map: &mut LineMap, near: &[(usize, Cluster)], scan: usize, after: usize) -> usize {
    let mut pruned = 0;
    for (slot, _) in near {
        let stale = map
            .get(*slot)
            .is_some_and(|k| k.sightings <= 1 && scan.saturating_sub(k.last_seen) >= after);
        if stale {
            map.set(*slot, None);
            pruned += 1;
        }
    }
    pruned
}

/// Step 5 of the module documentation of [`super`] (an addition): each cluster in `changed`
/// (slots of `map`) is merged with the other cluster of `near` (the map's clusters near the
/// scan, with their current values; updated) that lies on the same line ([`same_line`]) and
/// gives the thinnest union, by the exact merge of their moments ([`ppca::combine`]); a merge
/// whose non-principal deviation is above `map_merge_max_sigma` (or, when that is `None`,
/// `new_cluster_max_sigma`) is refused. The union keeps
/// the lower slot with the sum of the sightings, the other slot becomes a hole, and the union
/// is tested again. Returns the number of merges.
pub(super) fn fuse(
    map: &mut LineMap,
    near: &mut Vec<(usize, Cluster)>,
    mut changed: Vec<usize>,
    params: &IpslamParams,
) -> usize {
    let cos_limit = params.map_merge_angle_deg.to_radians().cos();
    let max_sigma = params
        .map_merge_max_sigma
        .unwrap_or(params.new_cluster_max_sigma);
    let mut fused = 0;
    while let Some(slot) = changed.pop() {
        // A slot merged away earlier is no longer in `near`.
        let Some(a_index) = near.iter().position(|(s, _)| *s == slot) else {
            continue;
        };
        let a = near[a_index].1;
        let mut best: Option<(usize, Cluster)> = None;
        for (k, (_, b)) in near.iter().enumerate() {
            if k == a_index || !same_line(&a, b, cos_limit, params.max_normal_distance) {
                continue;
            }
            let Some(union) = ppca::combine(&a, b) else {
                continue;
            };
            if union.sigma2.sqrt() > max_sigma {
                continue;
            }
            if best.is_none_or(|(_, kept)| union.sigma2 < kept.sigma2) {
                best = Some((k, union));
            }
        }
        let Some((b_index, union)) = best else {
            continue;
        };
        let (kept, dropped) = (slot.min(near[b_index].0), slot.max(near[b_index].0));
        let (sightings, last_seen) = [kept, dropped]
            .iter()
            .filter_map(|s| map.get(*s))
            .fold((0u32, 0usize), |(n, t), k| {
                (n.saturating_add(k.sightings), t.max(k.last_seen))
            });
        map.set(
            kept,
            Some(MapCluster {
                cluster: union,
                sightings,
                last_seen,
            }),
        );
        map.set(dropped, None);
        near.retain(|(s, _)| *s != dropped);
        if let Some(entry) = near.iter_mut().find(|(s, _)| *s == kept) {
            entry.1 = union;
        }
        changed.push(kept);
        fused += 1;
    }
    fused
}

/// Whether two clusters are pieces of one line: principal directions with `|cos| >=
/// cos_limit`, the shorter one's centre within `max_normal_distance` of the longer one's
/// line, and their segments ([`Cluster::ends`]) overlapping or coming within
/// `max_normal_distance` of each other along the line.
fn same_line(a: &Cluster, b: &Cluster, cos_limit: f64, max_normal_distance: f64) -> bool {
    let cos = a.direction.dot(&b.direction);
    if cos.abs() < cos_limit {
        return false;
    }
    // The other centre against the longer cluster's line: a short cluster's direction is
    // poorly known, and tilted by a degree or two it puts a distant centre far off its line.
    let offset = b.mean - a.mean;
    let longer = if a.principal_variance >= b.principal_variance {
        a
    } else {
        b
    };
    let normal = Vector2::new(-longer.direction.y, longer.direction.x);
    if offset.dot(&normal).abs() > max_normal_distance {
        return false;
    }
    // Along a's line: a covers [-ha, ha], b [t - hb |cos|, t + hb |cos|].
    let half = |k: &Cluster| (3.0 * k.principal_variance).sqrt();
    let gap = offset.dot(&a.direction).abs() - half(a) - half(b) * cos.abs();
    gap <= max_normal_distance
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal, Uniform};

    /// `n` points spread evenly along `from`-`to`, jittered along by a tenth of their spacing
    /// and across by `sigma`.
    fn wall(from: Vector2<f64>, to: Vector2<f64>, n: usize, sigma: f64) -> Vec<Vector2<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let across = Normal::new(0.0, sigma).unwrap();
        let jitter = Uniform::new(-0.05, 0.05).unwrap();
        let d = to - from;
        let normal = Vector2::new(-d.y, d.x).normalize();
        (0..n)
            .map(|k| {
                let t = (k as f64 + 0.5 + jitter.sample(&mut rng)) / n as f64;
                from + d * t + normal * across.sample(&mut rng)
            })
            .collect()
    }

    /// A map of the clusters fitted to `walls`, fused after the last one was added as a scan
    /// would have done; returns the clusters left and the number of merges.
    fn fused(walls: &[Vec<Vector2<f64>>], params: &IpslamParams) -> (Vec<Cluster>, usize) {
        let mut map = LineMap::default();
        let mut near = Vec::new();
        for (scan, points) in walls.iter().enumerate() {
            let cluster = Cluster::fit(points).unwrap();
            let slot = map.push(MapCluster {
                cluster,
                sightings: 1,
                last_seen: scan,
            });
            near.push((slot, cluster));
        }
        let last = near.len() - 1;
        let merges = fuse(&mut map, &mut near, vec![last], params);
        let clusters: Vec<Cluster> = map.iter().map(|(_, c)| c.cluster).collect();
        // The map and the list of clusters near the scan agree.
        assert_eq!(near.iter().map(|(_, c)| *c).collect::<Vec<_>>(), clusters);
        let sightings: u32 = map.iter().map(|(_, c)| c.sightings).sum();
        assert_eq!(sightings as usize, walls.len());
        (clusters, merges)
    }

    fn v(x: f64, y: f64) -> Vector2<f64> {
        Vector2::new(x, y)
    }

    #[test]
    fn two_halves_of_a_wall_fuse_into_the_cluster_of_all_its_points() {
        let points = wall(v(1.0, 2.0), v(7.0, 3.0), 300, 0.01);
        let all = Cluster::fit(&points).unwrap();
        // Split where the two halves touch, and with a gap of 5 cm between them.
        for (cut_a, cut_b) in [(150, 150), (140, 143)] {
            let walls = [points[..cut_a].to_vec(), points[cut_b..].to_vec()];
            let (clusters, merges) = fused(&walls, &IpslamParams::default());
            assert_eq!((clusters.len(), merges), (1, 1), "cut at {cut_a}/{cut_b}");
            let union = clusters[0];
            let expected = if cut_a == cut_b {
                all
            } else {
                let kept: Vec<_> = walls.concat();
                Cluster::fit(&kept).unwrap()
            };
            assert_eq!(union.count, expected.count);
            assert!((union.mean - expected.mean).norm() < 1e-9);
            assert!(union.direction.dot(&expected.direction).abs() > 1.0 - 1e-12);
            assert!((union.principal_variance - expected.principal_variance).abs() < 1e-9);
            assert!((union.sigma2 - expected.sigma2).abs() < 1e-12);
        }
        // Three pieces: the last one added bridges the other two, and all three fuse.
        let walls = [
            points[..100].to_vec(),
            points[200..].to_vec(),
            points[100..200].to_vec(),
        ];
        let (clusters, merges) = fused(&walls, &IpslamParams::default());
        assert_eq!((clusters.len(), merges), (1, 2));
        assert!((clusters[0].sigma2 - all.sigma2).abs() < 1e-12);
    }

    #[test]
    fn parallel_walls_apart_do_not_fuse() {
        let params = IpslamParams::default();
        let first = wall(v(0.0, 0.0), v(5.0, 0.0), 200, 0.01);
        // Two sightings of one wall 2 cm apart fuse; two walls 0.3 m apart (a thin partition
        // and the wall behind it, or a corridor drawn twice) do not, nor 0.15 m apart with the
        // default settings (the union would be 7.5 cm thick).
        for (offset, expected) in [(0.02, 1), (0.15, 2), (0.3, 2), (0.5, 2)] {
            let second = wall(v(1.0, offset), v(6.0, offset), 200, 0.01);
            let (clusters, _) = fused(&[first.clone(), second], &params);
            assert_eq!(clusters.len(), expected, "offset {offset} m");
        }
        // A union thicker than `map_merge_max_sigma` is refused: the sightings 2 cm apart
        // make a union about 1.4 cm thick.
        let thin = IpslamParams {
            map_merge_max_sigma: Some(0.01),
            ..params.clone()
        };
        let second = wall(v(1.0, 0.02), v(6.0, 0.02), 200, 0.01);
        let (clusters, _) = fused(&[first.clone(), second], &thin);
        assert_eq!(clusters.len(), 2);
        // Collinear but 1 m apart along the line: no overlap, no fusion.
        let beyond = wall(v(6.0, 0.0), v(9.0, 0.0), 120, 0.01);
        let (clusters, _) = fused(&[first, beyond], &params);
        assert_eq!(clusters.len(), 2);
    }

    #[test]
    fn a_short_sighting_a_few_degrees_off_a_long_wall_fuses_with_it() {
        let params = IpslamParams {
            max_normal_distance: 0.1,
            ..IpslamParams::default()
        };
        let long = wall(v(0.0, 0.0), v(5.0, 0.0), 250, 0.01);
        // 0.6 m near the long wall's end, turned 4 degrees and 2 cm off its line: a sighting
        // placed by a slightly wrong pose. The long wall's centre lies 0.15 m from the short
        // piece's line (its direction, from 0.6 m, says little so far away), the short
        // piece's centre 2 cm from the long wall's line.
        let turn = 4f64.to_radians();
        let (centre, half) = (v(4.3, -0.02), 0.3);
        let along = v(turn.cos(), turn.sin()) * half;
        let short = wall(centre - along, centre + along, 60, 0.01);
        let (clusters, merges) = fused(&[long.clone(), short], &params);
        assert_eq!((clusters.len(), merges), (1, 1));
        // The same piece 0.15 m off the line, parallel, is another wall (a partition face).
        let (centre, along) = (v(4.3, 0.15), v(1.0, 0.0) * half);
        let apart = wall(centre - along, centre + along, 60, 0.01);
        let (clusters, _) = fused(&[long, apart], &params);
        assert_eq!(clusters.len(), 2);
    }

    #[test]
    fn corners_do_not_fuse() {
        let params = IpslamParams::default();
        let along_x = wall(v(0.0, 0.0), v(3.0, 0.0), 120, 0.01);
        // An L corner, and a shallow one: 10 degrees, within the angle of the test, and each
        // centre 0.26 m from the other's line, within `max_normal_distance`; the union is
        // 0.10 m thick.
        let up = wall(v(3.0, 0.0), v(3.0, 3.0), 120, 0.01);
        let turn = 10f64.to_radians();
        let bent = wall(
            v(3.0, 0.0),
            v(3.0 + 3.0 * turn.cos(), 3.0 * turn.sin()),
            120,
            0.01,
        );
        for second in [&up, &bent] {
            let (clusters, merges) = fused(&[along_x.clone(), second.clone()], &params);
            assert_eq!((clusters.len(), merges), (2, 0));
        }
        // With the thickness limit raised the shallow corner fuses (the limit is what
        // refuses it), the L corner still not (the angle).
        let loose = IpslamParams {
            map_merge_max_sigma: Some(0.5),
            ..params
        };
        let (clusters, _) = fused(&[along_x.clone(), bent], &loose);
        assert_eq!(clusters.len(), 1);
        let (clusters, _) = fused(&[along_x, up], &loose);
        assert_eq!(clusters.len(), 2);
    }

    #[test]
    fn clusters_of_one_scan_are_pruned_once_stale() {
        let cluster = Cluster::fit(&wall(v(0.0, 0.0), v(2.0, 0.0), 40, 0.01)).unwrap();
        let mut map = LineMap::default();
        let mut near = Vec::new();
        // Seen once at scan 0, twice with the last at scan 1, once at scan 3.
        for (sightings, last_seen) in [(1, 0), (2, 1), (1, 3)] {
            let slot = map.push(MapCluster {
                cluster,
                sightings,
                last_seen,
            });
            near.push((slot, cluster));
        }
        assert_eq!(prune(&mut map, &near, 4, 5), 0);
        assert_eq!(prune(&mut map, &near, 5, 5), 1);
        let left: Vec<usize> = map.iter().map(|(slot, _)| slot).collect();
        assert_eq!(left, vec![1, 2]);
        assert_eq!(prune(&mut map, &near, 100, 5), 1);
        assert_eq!(map.iter().count(), 1);
    }
}
