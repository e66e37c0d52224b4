//! Model selection after the fit: segments that save less distance than they cost are
//! removed (an addition to the paper, whose maps are compact because its data are clean).
//!
//! A segment's saving is the total increase of the point-to-nearest-segment distances
//! were it removed: over its support set, the distance to the second nearest segment minus
//! the distance to it. With `D` the total distance and `n` the number of segments, removing
//! a segment of saving `c` lowers the product `D n` (mean distance times model size, so that a
//! relative change of either counts the same) when `c < D / (n - 1)` (equality is taken as removal, so that a segment saving
//! nothing goes from a perfect fit): a segment must
//! save at least the distance budget of one segment. Segments are removed cheapest first,
//! `D` and `n` updated after each removal, in rounds of at most a tenth of the segments
//! (savings are recomputed between rounds; within a round, a segment that takes over the
//! points of a removed one is not removed), until no segment qualifies ([`prune`]).
//!
//! With a bound on the mean distance (`EmPolygonParams::max_mean_distance`), the same rounds
//! remove the cheapest segments while the total distance of all points stays within the
//! bound times their number ([`prune_to_mean`]).

use rayon::prelude::*;
use slam_core::nalgebra::Vector2;

use super::Segment;
use super::emsf::{CHUNK, bounds};
use super::grid::SegmentGrid;

/// Largest fraction of the segments removed in one round.
const ROUND_FRACTION: f64 = 0.1;

/// Each point's nearest segment, its distance, and the second nearest segment and its
/// distance (`u32::MAX` and infinity where there is none).
struct TwoNearest {
    owner: Vec<u32>,
    distance: Vec<f64>,
    runner_up: Vec<u32>,
    runner_up_distance: Vec<f64>,
}

fn two_nearest(points: &[Vector2<f64>], segments: &[Segment]) -> TwoNearest {
    let (lo, hi) = bounds(points, segments);
    let grid = SegmentGrid::new(segments, lo, hi);
    let parts: Vec<Vec<(u32, f64, u32, f64)>> = points
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut seen = vec![u32::MAX; segments.len()];
            chunk
                .iter()
                .enumerate()
                .map(
                    |(k, p)| match grid.two_nearest(segments, p, &mut seen, k as u32) {
                        Some(((j, d), Some((j2, d2)))) => (j, d.sqrt(), j2, d2.sqrt()),
                        Some(((j, d), None)) => (j, d.sqrt(), u32::MAX, f64::INFINITY),
                        None => (u32::MAX, f64::INFINITY, u32::MAX, f64::INFINITY),
                    },
                )
                .collect()
        })
        .collect();
    let mut result = TwoNearest {
        owner: Vec::with_capacity(points.len()),
        distance: Vec::with_capacity(points.len()),
        runner_up: Vec::with_capacity(points.len()),
        runner_up_distance: Vec::with_capacity(points.len()),
    };
    for (j, d, j2, d2) in parts.into_iter().flatten() {
        result.owner.push(j);
        result.distance.push(d);
        result.runner_up.push(j2);
        result.runner_up_distance.push(d2);
    }
    result
}

/// Each segment's saving (the increase of the total distance were it removed alone) and the
/// segments that would take over its points.
fn savings_and_heirs(nearest: &TwoNearest, n: usize) -> (Vec<f64>, Vec<Vec<u32>>) {
    let mut saving = vec![0.0; n];
    let mut heirs: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (k, &j) in nearest.owner.iter().enumerate() {
        if let Some(s) = saving.get_mut(j as usize) {
            *s += nearest.runner_up_distance[k] - nearest.distance[k];
            let j2 = nearest.runner_up[k];
            let h = &mut heirs[j as usize];
            if j2 != u32::MAX && h.last() != Some(&j2) {
                h.push(j2);
            }
        }
    }
    (saving, heirs)
}

/// One round of removals, cheapest first: at most `most` segments, while `allowed(saving,
/// total, remaining)` holds for the next one (`total` the distance so far, updated by each
/// removal's saving). A segment that takes over the points of a removed one is not removed
/// in the same round. Returns which segments stay and how many went.
fn removal_round(
    nearest: &TwoNearest,
    n: usize,
    mut total: f64,
    most: usize,
    allowed: impl Fn(f64, f64, usize) -> bool,
) -> (Vec<bool>, usize) {
    let (saving, heirs) = savings_and_heirs(nearest, n);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| saving[a].total_cmp(&saving[b]).then(a.cmp(&b)));
    let mut keep = vec![true; n];
    let mut protected = vec![false; n];
    let mut remaining = n;
    let mut removed = 0;
    for &j in &order {
        // Savings are finite or infinite (no second segment), never NaN.
        if removed >= most || remaining < 2 || !allowed(saving[j], total, remaining) {
            break;
        }
        if protected[j] {
            continue;
        }
        keep[j] = false;
        for &h in &heirs[j] {
            protected[h as usize] = true;
        }
        total += saving[j];
        remaining -= 1;
        removed += 1;
    }
    (keep, removed)
}

fn kept(segments: &[Segment], keep: &[bool]) -> Vec<Segment> {
    segments
        .iter()
        .zip(keep)
        .filter_map(|(s, &k)| k.then_some(*s))
        .collect()
}

fn round_size(n: usize) -> usize {
    ((ROUND_FRACTION * n as f64).ceil() as usize).max(1)
}

/// Removes the segments that save less than the distance budget of one segment (module
/// documentation). Returns the remaining segments and the number removed.
pub(crate) fn prune(
    points: &[Vector2<f64>],
    mut segments: Vec<Segment>,
    explained: f64,
) -> (Vec<Segment>, usize) {
    let mut removed_total = 0;
    let mut baseline: Option<Vec<f64>> = None;
    while segments.len() > 1 {
        let nearest = two_nearest(points, &segments);
        // The distances of the points the full model leaves unexplained are not counted in
        // the budget, only their increases.
        let baseline = baseline.get_or_insert_with(|| {
            nearest
                .distance
                .iter()
                .map(|&d| if d > explained { d } else { 0.0 })
                .collect()
        });
        let n = segments.len();
        let total: f64 = nearest
            .owner
            .iter()
            .zip(nearest.distance.iter().zip(baseline.iter()))
            .filter(|(j, _)| (**j as usize) < n)
            .map(|(_, (d, b))| d - b)
            .sum();
        let (keep, removed) = removal_round(&nearest, n, total, round_size(n), |c, d, m| {
            c <= d / (m - 1) as f64
        });
        if removed == 0 {
            break;
        }
        removed_total += removed;
        segments = kept(&segments, &keep);
    }
    (segments, removed_total)
}

/// The fewest segments, removed greedily cheapest first, that keep the mean distance of the
/// points to their nearest segment at most `max_mean` (m): polygonal approximation at a
/// given accuracy (the "min-#" problem). A round whose removals together exceed the bound
/// (each saving was measured with the others present) is taken back and tried with half as
/// many, down to one removal, whose saving is exact. Nothing is removed when the mean is
/// already above the bound. Returns the remaining segments and the number removed.
pub(crate) fn prune_to_mean(
    points: &[Vector2<f64>],
    mut segments: Vec<Segment>,
    max_mean: f64,
) -> (Vec<Segment>, usize) {
    let limit = max_mean * points.len() as f64;
    let mut removed_total = 0;
    let mut cap = usize::MAX;
    while segments.len() > 1 {
        let nearest = two_nearest(points, &segments);
        let total: f64 = nearest.distance.iter().sum();
        let n = segments.len();
        let most = round_size(n).min(cap);
        let (keep, removed) = removal_round(&nearest, n, total, most, |c, d, _| d + c <= limit);
        if removed == 0 {
            break;
        }
        let candidate = kept(&segments, &keep);
        let actual: f64 = super::nearest_distances(points, &candidate).iter().sum();
        if actual > limit {
            if most == 1 {
                break;
            }
            cap = (most / 2).max(1);
            continue;
        }
        removed_total += removed;
        segments = candidate;
    }
    (segments, removed_total)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::em_polygon::seg;

    fn along(a: (f64, f64), b: (f64, f64), count: usize) -> Vec<Vector2<f64>> {
        (0..=count)
            .map(|k| {
                let t = k as f64 / count as f64;
                Vector2::new(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
            })
            .collect()
    }

    #[test]
    fn a_redundant_segment_goes_and_the_walls_stay() {
        // Two walls of 4 m, 400 points each; a third segment lying 1 mm off the first wall's
        // left half saves almost nothing.
        let mut points = along((0.0, 0.0), (4.0, 0.0), 400);
        points.extend(along((0.0, 2.0), (4.0, 2.0), 400));
        let segments = vec![
            seg((0.0, 0.0), (4.0, 0.0)),
            seg((0.0, 2.0), (4.0, 2.0)),
            seg((0.0, 0.001), (2.0, 0.001)),
        ];
        let (kept, removed) = prune(&points, segments.clone(), f64::INFINITY);
        assert_eq!(removed, 1);
        assert_eq!(kept, segments[..2].to_vec());
    }

    #[test]
    fn a_small_object_stays_when_it_saves_more_than_a_segment_costs() {
        // Two long walls with 2 cm of scatter (alternating sides) and a short object 1 m
        // away holding 50 points: removing it would add about 50 m of distance, far more
        // than the map's distance per segment (about 0.02 m x 850 points / 3).
        let mut points: Vec<_> = along((0.0, 0.0), (4.0, 0.0), 400)
            .into_iter()
            .enumerate()
            .map(|(k, p)| p + Vector2::new(0.0, if k % 2 == 0 { 0.02 } else { -0.02 }))
            .collect();
        points.extend(along((0.0, 2.0), (4.0, 2.0), 400));
        points.extend(along((1.0, 1.0), (1.3, 1.0), 49));
        let segments = vec![
            seg((0.0, 0.0), (4.0, 0.0)),
            seg((0.0, 2.0), (4.0, 2.0)),
            seg((1.0, 1.0), (1.3, 1.0)),
        ];
        let (kept, removed) = prune(&points, segments.clone(), f64::INFINITY);
        assert_eq!((kept.len(), removed), (3, 0));
        // The same object with 2 points saves about 2 m, less than the budget: it goes.
        points.truncate(802);
        points.extend([Vector2::new(1.0, 1.0), Vector2::new(1.3, 1.0)]);
        let (kept, removed) = prune(&points, segments.clone(), f64::INFINITY);
        assert_eq!((kept.len(), removed), (2, 1));
    }

    #[test]
    fn prune_to_mean_removes_the_cheapest_segments_while_the_mean_stays_within_the_bound() {
        // Two walls (401 points each) and two objects 1 m from both, of 11 and 21 points:
        // removing them adds 11 m and 21 m to a total distance of 0 over 834 points, so a
        // mean of 11 / 834 = 1.32 cm pays for the first and 32 / 834 = 3.84 cm for both.
        let mut points = along((0.0, 0.0), (4.0, 0.0), 400);
        points.extend(along((0.0, 2.0), (4.0, 2.0), 400));
        points.extend(along((1.0, 1.0), (1.3, 1.0), 10));
        points.extend(along((2.5, 1.0), (2.8, 1.0), 20));
        let segments = vec![
            seg((0.0, 0.0), (4.0, 0.0)),
            seg((0.0, 2.0), (4.0, 2.0)),
            seg((1.0, 1.0), (1.3, 1.0)),
            seg((2.5, 1.0), (2.8, 1.0)),
        ];
        let mean = |kept: &[Segment]| {
            crate::em_polygon::nearest_distances(&points, kept)
                .iter()
                .sum::<f64>()
                / points.len() as f64
        };
        let [a, b, small, large] = [0, 1, 2, 3].map(|k| segments[k]);
        for (bound, expected) in [
            (0.012, vec![a, b, small, large]),
            (0.014, vec![a, b, large]),
            (0.038, vec![a, b, large]),
            (0.039, vec![a, b]),
            (0.5, vec![a, b]),
        ] {
            let (kept, removed) = prune_to_mean(&points, segments.clone(), bound);
            assert_eq!(removed, 4 - expected.len(), "bound {bound}");
            assert_eq!(kept, expected, "bound {bound}");
            assert!(mean(&kept) <= bound, "bound {bound}: mean {}", mean(&kept));
        }
    }

    #[test]
    fn prune_to_mean_keeps_every_bound_on_scattered_objects() {
        // Walls and 30 objects of 3-32 points at 0.3-1.2 m from the walls and each other:
        // many removals per round, whose savings interact. Every bound is kept, and a
        // larger bound never keeps more segments.
        let mut points = along((0.0, 0.0), (10.0, 0.0), 1000);
        points.extend(along((0.0, 3.0), (10.0, 3.0), 1000));
        let mut segments = vec![seg((0.0, 0.0), (10.0, 0.0)), seg((0.0, 3.0), (10.0, 3.0))];
        for k in 0..30 {
            let x = 0.3 + 0.32 * k as f64;
            let y = 0.3 + 0.03 * ((k * 7) % 31) as f64;
            points.extend(along((x, y), (x + 0.2, y), 2 + k));
            segments.push(seg((x, y), (x + 0.2, y)));
        }
        let mut previous = segments.len();
        for bound in [0.001, 0.005, 0.01, 0.02, 0.05, 0.1, 0.3] {
            let (kept, removed) = prune_to_mean(&points, segments.clone(), bound);
            let mean = crate::em_polygon::nearest_distances(&points, &kept)
                .iter()
                .sum::<f64>()
                / points.len() as f64;
            assert!(mean <= bound, "bound {bound}: mean {mean}");
            assert_eq!(kept.len() + removed, segments.len());
            assert!(kept.len() <= previous, "bound {bound}");
            previous = kept.len();
        }
        assert!(previous < segments.len());
    }
}
