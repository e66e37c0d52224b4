//! Ordering the final segments into polylines (the paper's "partially ordering the line
//! segments into polylines"): segment ends closer than a join distance are paired, nearest
//! pairs first, each end at most once; chains of paired segments become polylines whose
//! shared vertices are the intersections of the two lines (or the middle of the two ends
//! when the lines meet farther away than the join distance).

use slam_core::nalgebra::{Matrix2, Vector2};

use super::{Polyline, Segment};

/// End `e` of segment `s` is `2 s + e` (`e = 0` start, `1` end).
fn end_point(segments: &[Segment], end: usize) -> Vector2<f64> {
    let s = &segments[end / 2];
    if end.is_multiple_of(2) {
        s.start
    } else {
        s.end
    }
}

/// Where the lines of segments `a` and `b` meet, if they are not (nearly) parallel.
fn intersection(a: &Segment, b: &Segment) -> Option<Vector2<f64>> {
    let (u, v) = (a.end - a.start, b.end - b.start);
    let m = Matrix2::from_columns(&[u, -v]);
    if (u.perp(&v)).abs() <= 1e-6 * u.norm() * v.norm() {
        return None;
    }
    let t = m.try_inverse()? * (b.start - a.start);
    Some(a.start + u * t.x)
}

/// Orders `segments` into polylines joining ends within `join` of each other, and moves the
/// joined ends onto their common vertex. Every segment belongs to exactly one polyline.
pub(crate) fn order(segments: &mut [Segment], join: f64) -> Vec<Polyline> {
    let partner = partners(segments, join);
    move_to_vertices(segments, &partner, join);
    // Walk the chains: first from free ends (open polylines), then the remaining cycles.
    let n = segments.len();
    let mut visited = vec![false; n];
    let mut polylines = Vec::new();
    for s in 0..n {
        for end in [2 * s, 2 * s + 1] {
            if !visited[s] && partner[end] == usize::MAX {
                polylines.push(walk(segments, &partner, end, &mut visited));
            }
        }
    }
    for s in 0..n {
        if !visited[s] {
            polylines.push(walk(segments, &partner, 2 * s, &mut visited));
        }
    }
    polylines
}

/// The end each end (`2 s` start, `2 s + 1` end of segment `s`) is joined to, `usize::MAX`
/// for a free end: pairs of ends of different segments within `join`, nearest first (a sweep
/// along x finds the candidates).
fn partners(segments: &[Segment], join: f64) -> Vec<usize> {
    let n = segments.len();
    let mut ends: Vec<usize> = (0..2 * n).collect();
    ends.sort_by(|&a, &b| {
        end_point(segments, a)
            .x
            .total_cmp(&end_point(segments, b).x)
            .then(a.cmp(&b))
    });
    let mut pairs = Vec::new();
    for (k, &a) in ends.iter().enumerate() {
        let pa = end_point(segments, a);
        for &b in &ends[k + 1..] {
            let pb = end_point(segments, b);
            if pb.x - pa.x > join {
                break;
            }
            let d = (pa - pb).norm();
            if a / 2 != b / 2 && d <= join {
                pairs.push((d, a.min(b), a.max(b)));
            }
        }
    }
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let mut partner = vec![usize::MAX; 2 * n];
    for (_, a, b) in pairs {
        if partner[a] == usize::MAX && partner[b] == usize::MAX {
            partner[a] = b;
            partner[b] = a;
        }
    }
    partner
}

/// Moves each joined pair of ends onto their common vertex: the lines' intersection when it
/// lies within `join` of both, else their midpoint.
fn move_to_vertices(segments: &mut [Segment], partner: &[usize], join: f64) {
    let mut vertex = vec![None; partner.len()];
    for a in 0..partner.len() {
        let b = partner[a];
        if b == usize::MAX || b < a {
            continue;
        }
        let (pa, pb) = (end_point(segments, a), end_point(segments, b));
        let middle = (pa + pb) / 2.0;
        let v = intersection(&segments[a / 2], &segments[b / 2])
            .filter(|v| (v - pa).norm() <= join && (v - pb).norm() <= join)
            .unwrap_or(middle);
        vertex[a] = Some(v);
        vertex[b] = Some(v);
    }
    for (end, v) in vertex.iter().enumerate() {
        if let Some(v) = v {
            let s = &mut segments[end / 2];
            if end.is_multiple_of(2) {
                s.start = *v;
            } else {
                s.end = *v;
            }
        }
    }
}

/// The polyline entered through end `first_end` (of segment `first_end / 2`), following the
/// joins until a free end or back to the start (a closed polyline).
fn walk(
    segments: &[Segment],
    partner: &[usize],
    first_end: usize,
    visited: &mut [bool],
) -> Polyline {
    let mut order = Vec::new();
    let mut vertices = vec![end_point(segments, first_end)];
    let mut end = first_end;
    loop {
        let s = end / 2;
        visited[s] = true;
        let exit = end ^ 1;
        order.push((s, end % 2 == 1));
        vertices.push(end_point(segments, exit));
        let next = partner[exit];
        if next == usize::MAX || visited[next / 2] {
            let closed = next != usize::MAX && next == first_end;
            if closed {
                vertices.pop();
            }
            return Polyline {
                segments: order,
                vertices,
                closed,
            };
        }
        end = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::em_polygon::seg;

    #[test]
    fn a_square_is_one_closed_polyline_and_a_lone_segment_another() {
        let mut segments = vec![
            seg((0.05, 0.0), (0.95, 0.0)),
            seg((1.0, 1.0), (1.0, 0.05)),
            seg((0.0, 1.0), (0.95, 1.0)),
            seg((0.0, 0.05), (0.0, 0.95)),
            seg((5.0, 5.0), (6.0, 5.0)),
        ];
        let polylines = order(&mut segments, 0.2);
        assert_eq!(polylines.len(), 2, "{polylines:?}");
        let lone = polylines.iter().find(|p| p.segments.len() == 1).unwrap();
        assert!(!lone.closed && lone.vertices.len() == 2);
        let square = polylines.iter().find(|p| p.segments.len() == 4).unwrap();
        assert!(square.closed && square.vertices.len() == 4);
        // Corners snapped to the line intersections.
        for corner in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            let c = Vector2::new(corner.0, corner.1);
            assert!(
                square.vertices.iter().any(|v| (v - c).norm() < 1e-9),
                "{corner:?}"
            );
        }
        assert!((segments[0].start - Vector2::new(0.0, 0.0)).norm() < 1e-9);
    }
}
