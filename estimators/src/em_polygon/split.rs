//! Line Segment Split (LSS, the paper's section II-C): each segment is cut into subsegments
//! of length about `2r`; a subsegment's support is the number of points in the square of
//! side `2r` centred on it; subsegments with support `<= C` are removed and the connected
//! remainders of each segment become new segments.

use rayon::prelude::*;
use slam_core::nalgebra::Vector2;

use super::Segment;
use super::grid::PointGrid;

/// What one split did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct SplitReport {
    /// The support threshold `C` used.
    pub threshold: f64,
    /// Subsegments examined.
    pub subsegments: usize,
    /// Subsegments removed.
    pub removed: usize,
}

/// The subsegments of `s`: their count `l = ceil(length / 2r)` (at least 1) and length.
fn subdivision(s: &Segment, r: f64) -> (usize, f64) {
    let length = (s.end - s.start).norm();
    let count = ((length / (2.0 * r)).ceil() as usize).clamp(1, 1 << 20);
    (count, length / count as f64)
}

/// LSS with half-length `r`; `threshold(supports)` computes `C` from the supports of all
/// subsegments of all segments.
pub(crate) fn split(
    points: &[Vector2<f64>],
    segments: &[Segment],
    r: f64,
    threshold: impl Fn(&[usize]) -> f64,
) -> (Vec<Segment>, SplitReport) {
    if segments.is_empty() || points.is_empty() {
        return (Vec::new(), SplitReport::default());
    }
    let (lo, hi) = super::emsf::bounds(points, segments);
    let grid = PointGrid::new(points, lo, hi, r);
    // (2.1) Support of every subsegment, segment by segment.
    let supports: Vec<Vec<usize>> = segments
        .par_iter()
        .map(|s| {
            let (count, piece) = subdivision(s, r);
            let direction = (s.end - s.start) / (s.end - s.start).norm();
            (0..count)
                .map(|k| {
                    let centre = s.start + direction * (piece * (k as f64 + 0.5));
                    grid.count_in_box(&centre, &direction, r, r)
                })
                .collect()
        })
        .collect();
    let all: Vec<usize> = supports.iter().flatten().copied().collect();
    let c = threshold(&all);
    // (2.2) Removal, and the connected remainders as new segments.
    let mut out = Vec::new();
    let mut removed = 0;
    for (s, support) in segments.iter().zip(&supports) {
        let (_, piece) = subdivision(s, r);
        let direction = (s.end - s.start) / (s.end - s.start).norm();
        let mut run: Option<(usize, usize)> = None;
        let close = |run: (usize, usize), out: &mut Vec<Segment>| {
            let start = s.start + direction * (piece * run.0 as f64);
            let end = s.start + direction * (piece * run.1 as f64);
            out.push(Segment {
                start,
                end,
                support: 0,
            });
        };
        for (k, &value) in support.iter().enumerate() {
            if (value as f64) > c {
                run = Some(run.map_or((k, k + 1), |(a, _)| (a, k + 1)));
            } else {
                removed += 1;
                if let Some(done) = run.take() {
                    close(done, &mut out);
                }
            }
        }
        if let Some(done) = run {
            close(done, &mut out);
        }
    }
    let report = SplitReport {
        threshold: c,
        subsegments: all.len(),
        removed,
    };
    (out, report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gap_in_the_points_splits_the_segment() {
        // Points on y = 0 for x in [0, 4] and [6, 10]; one segment over all of it.
        let points: Vec<_> = (0..=100)
            .map(|k| Vector2::new(k as f64 * 0.1, 0.0))
            .filter(|p| p.x <= 4.0 || p.x >= 6.0)
            .collect();
        let segment = Segment {
            start: Vector2::new(0.0, 0.0),
            end: Vector2::new(10.0, 0.0),
            support: 0,
        };
        // Subsegments of 0.5 m; those over the gap hold at most the one point at its edge.
        let (pieces, report) = split(&points, &[segment], 0.25, |_| 1.0);
        assert_eq!(pieces.len(), 2, "{pieces:?}");
        assert_eq!((report.subsegments, report.removed), (20, 4));
        assert!((pieces[0].end.x - 4.0).abs() < 1e-9, "{pieces:?}");
        assert!((pieces[1].start.x - 6.0).abs() < 1e-9, "{pieces:?}");
    }
}
