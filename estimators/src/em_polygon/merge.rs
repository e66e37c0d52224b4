//! Line segment merging by perceptual grouping (the paper's section III).
//!
//! The merged segment `ms(L1, L2)` is built as in the paper: with `L1 = AB` and `L2 = CD`
//! oriented so that `AB . CD >= 0`, its direction is that of `AB + CD`; its line is placed
//! so that `d1 l1 = d2 l2` (`l_i` the lengths, `d_i` the distances of the midpoints to the
//! line), and it spans the projections of both segments.
//!
//! The cost is `C = 2 parC + 1/4 colC + 1/2 proxC` (the paper's weights). The paper takes
//! the three measures from its reference [11], which it does not reproduce; here they are
//! made dimensionless against the scales of the current iteration:
//!
//! - `parC = angle(L1, L2) / angle_scale` (the acute angle between the two directions),
//! - `colC = max(d1, d2) / (noise / 2)`, the larger distance of the two midpoints to the
//!   merged line (how far the segments are from lying on one line; their angle is measured
//!   by `parC`), in units of half the noise of the points (the measured noise, or
//!   `EmPolygonParams::sigma_min` without it): two fits of one wall differ by much less than
//!   the noise; the annealed `sigma` is not used, as early in the run it is metres and would
//!   merge the two walls of a corridor),
//! - `proxC = gap / r`, the gap between the two segments' projections on the merged line (0
//!   when they overlap), in units of the split half-length `r`.
//!
//! Pairs with `C <= 1` are merged, cheapest first.

use slam_core::nalgebra::Vector2;

use super::Segment;

/// The scales the merge cost is measured in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct MergeScales {
    /// Angle that alone makes `parC = 1`, rad.
    pub angle: f64,
    /// Point deviation: half of it alone makes `colC = 1`, m.
    pub sigma: f64,
    /// Gap that alone makes `proxC = 1`, m.
    pub r: f64,
}

/// The merged segment `ms(L1, L2)` and the cost of replacing `L1` and `L2` by it.
pub(crate) fn merge_pair(a: &Segment, b: &Segment, scales: &MergeScales) -> Option<(Segment, f64)> {
    let ab = a.end - a.start;
    let mut cd = b.end - b.start;
    let (mut c, mut d) = (b.start, b.end);
    if ab.dot(&cd) < 0.0 {
        cd = -cd;
        std::mem::swap(&mut c, &mut d);
    }
    let (l1, l2) = (ab.norm(), cd.norm());
    let sum = ab + cd;
    if !(l1 > 0.0 && l2 > 0.0 && sum.norm() > 0.0) {
        return None;
    }
    let direction = sum / sum.norm();
    let normal = Vector2::new(-direction.y, direction.x);
    let (m1, m2) = ((a.start + a.end) / 2.0, (c + d) / 2.0);
    // Offsets along the normal; the line's offset is their length-weighted mean, so that
    // d1 l1 = d2 l2.
    let (s1, s2) = (normal.dot(&m1), normal.dot(&m2));
    let offset = (l1 * s1 + l2 * s2) / (l1 + l2);
    let along = |p: &Vector2<f64>| direction.dot(p);
    let (t1a, t1b) = (along(&a.start), along(&a.end));
    let (t2a, t2b) = (along(&c), along(&d));
    let t_min = t1a.min(t1b).min(t2a).min(t2b);
    let t_max = t1a.max(t1b).max(t2a).max(t2b);
    let merged = Segment {
        start: normal * offset + direction * t_min,
        end: normal * offset + direction * t_max,
        support: a.support + b.support,
    };
    let cos = (ab.dot(&cd) / (l1 * l2)).clamp(-1.0, 1.0);
    let angle = cos.acos();
    // d1 and d2, the distances of the midpoints to the merged line.
    let col = (s1 - offset).abs().max((s2 - offset).abs());
    let gap = (t1a.min(t1b) - t2a.max(t2b))
        .max(t2a.min(t2b) - t1a.max(t1b))
        .max(0.0);
    let cost =
        2.0 * angle / scales.angle + 0.25 * col / (0.5 * scales.sigma) + 0.5 * gap / scales.r;
    (merged.is_finite() && cost.is_finite()).then_some((merged, cost))
}

/// Merges pairs of segments with cost `<= 1`, cheapest first, repeatedly (a merged segment
/// may merge again) until no pair qualifies. Returns the segments and the number of merges.
pub(crate) fn merge_all(segments: Vec<Segment>, scales: &MergeScales) -> (Vec<Segment>, usize) {
    let mut segments = segments;
    let mut merges = 0;
    // Two segments can only qualify when their bounding boxes, grown by the largest gap and
    // offset allowed, overlap.
    let margin = (2.0 * scales.r).max(4.0 * scales.sigma);
    loop {
        let mut order: Vec<usize> = (0..segments.len()).collect();
        let lo_x = |s: &Segment| s.start.x.min(s.end.x);
        order.sort_by(|&i, &j| {
            lo_x(&segments[i])
                .total_cmp(&lo_x(&segments[j]))
                .then(i.cmp(&j))
        });
        let mut pairs = Vec::new();
        for (k, &i) in order.iter().enumerate() {
            let a = &segments[i];
            let (a_lo, a_hi) = (a.start.inf(&a.end), a.start.sup(&a.end));
            for &j in &order[k + 1..] {
                let b = &segments[j];
                let (b_lo, b_hi) = (b.start.inf(&b.end), b.start.sup(&b.end));
                if b_lo.x > a_hi.x + margin {
                    break;
                }
                if b_lo.y > a_hi.y + margin || a_lo.y > b_hi.y + margin {
                    continue;
                }
                if let Some((merged, cost)) = merge_pair(a, b, scales)
                    && cost <= 1.0
                {
                    pairs.push((cost, i.min(j), i.max(j), merged));
                }
            }
        }
        if pairs.is_empty() {
            return (segments, merges);
        }
        pairs.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
        let mut used = vec![false; segments.len()];
        let mut merged_segments = Vec::new();
        for (_, i, j, merged) in pairs {
            if used[i] || used[j] {
                continue;
            }
            used[i] = true;
            used[j] = true;
            merged_segments.push(merged);
            merges += 1;
        }
        segments = segments
            .into_iter()
            .zip(used)
            .filter_map(|(s, used)| (!used).then_some(s))
            .chain(merged_segments)
            .collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::em_polygon::seg;

    const SCALES: MergeScales = MergeScales {
        angle: 0.35,
        sigma: 0.05,
        r: 0.2,
    };

    #[test]
    fn the_merged_line_is_closer_to_the_longer_segment() {
        // Parallel segments 0.04 apart, lengths 3 and 1: d1 l1 = d2 l2 puts the line 0.01 from
        // the long one; it spans both projections.
        let (merged, cost) = merge_pair(
            &seg((0.0, 0.0), (3.0, 0.0)),
            &seg((3.5, 0.04), (2.5, 0.04)),
            &SCALES,
        )
        .unwrap();
        assert!((merged.start.y - 0.01).abs() < 1e-12 && (merged.end.y - 0.01).abs() < 1e-12);
        assert!((merged.start.x - 0.0).abs() < 1e-12 && (merged.end.x - 3.5).abs() < 1e-12);
        // colC = 0.03 / 0.025: cost 0.25 * 1.2.
        assert!((cost - 0.3).abs() < 1e-9, "{cost}");
    }

    #[test]
    fn collinear_neighbours_merge_and_crossing_or_distant_ones_do_not() {
        let collinear = vec![seg((0.0, 0.0), (1.0, 0.0)), seg((1.1, 0.0), (2.0, 0.01))];
        assert_eq!(merge_all(collinear, &SCALES).0.len(), 1);
        let crossing = vec![seg((0.0, 0.0), (2.0, 0.0)), seg((1.0, -1.0), (1.0, 1.0))];
        assert_eq!(merge_all(crossing, &SCALES).0.len(), 2);
        let far = vec![seg((0.0, 0.0), (1.0, 0.0)), seg((2.0, 0.0), (3.0, 0.0))];
        assert_eq!(merge_all(far, &SCALES).0.len(), 2);
        let parallel = vec![seg((0.0, 0.0), (2.0, 0.0)), seg((0.0, 0.3), (2.0, 0.3))];
        assert_eq!(merge_all(parallel, &SCALES).0.len(), 2);
    }
}
