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
//! points of a removed one is not removed), until no segment qualifies.

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
        let mut saving = vec![0.0; n];
        let mut total = 0.0;
        for (k, &j) in nearest.owner.iter().enumerate() {
            if let Some(s) = saving.get_mut(j as usize) {
                total += nearest.distance[k] - baseline[k];
                *s += nearest.runner_up_distance[k] - nearest.distance[k];
            }
        }
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| saving[a].total_cmp(&saving[b]).then(a.cmp(&b)));
        // Which segments take over the points of each one.
        let mut heirs: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (&j, &j2) in nearest.owner.iter().zip(&nearest.runner_up) {
            if let Some(h) = heirs.get_mut(j as usize)
                && j2 != u32::MAX
                && h.last() != Some(&j2)
            {
                h.push(j2);
            }
        }
        let most = ((ROUND_FRACTION * n as f64).ceil() as usize).max(1);
        let mut keep = vec![true; n];
        let mut protected = vec![false; n];
        let mut remaining = n;
        let mut removed = 0;
        for &j in &order {
            if removed >= most || remaining < 2 {
                break;
            }
            // Savings are finite or infinite (no second segment), never NaN.
            if saving[j] > total / (remaining - 1) as f64 {
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
        if removed == 0 {
            break;
        }
        removed_total += removed;
        segments = segments
            .into_iter()
            .zip(keep)
            .filter_map(|(s, k)| k.then_some(s))
            .collect();
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
}
