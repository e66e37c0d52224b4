//! Expectation Maximization Segment Fitting (EMSF, the paper's section II-A): the E-step on
//! point-to-segment distances, the M-step by weighted orthogonal regression (eq. 1) and the
//! trimming of each line to the projection of its support set.

use rayon::prelude::*;
use slam_core::nalgebra::{Matrix2, Vector2};

use super::Segment;
use super::grid::SegmentGrid;

/// Points per parallel work item. Fixed (not derived from the thread count) so that the
/// partial sums, added in chunk order, are the same on every machine: results are
/// deterministic.
pub(crate) const CHUNK: usize = 4096;

/// Candidate segments of a point are those within `sqrt(d_min^2 + (CUTOFF sigma)^2)`: any
/// other segment has a weight below `exp(-CUTOFF^2 / 2) = 3.4e-4` of the nearest one's.
const CUTOFF: f64 = 4.0;

/// What one E-step found for each point.
#[derive(Clone, Debug, Default)]
pub(crate) struct Assignment {
    /// Index of the segment of largest weight (the point's support set, section II-A 3.1),
    /// `u32::MAX` when there is no segment.
    pub owner: Vec<u32>,
    /// Distance to that (the nearest) segment, m.
    pub distance: Vec<f64>,
}

/// Weighted moments of one segment's points, about a reference point (for accuracy).
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    w: f64,
    x: f64,
    y: f64,
    xx: f64,
    xy: f64,
    yy: f64,
}

impl Moments {
    fn add(&mut self, w: f64, d: Vector2<f64>) {
        self.w += w;
        self.x += w * d.x;
        self.y += w * d.y;
        self.xx += w * d.x * d.x;
        self.xy += w * d.x * d.y;
        self.yy += w * d.y * d.y;
    }

    fn merge(&mut self, o: &Moments) {
        self.w += o.w;
        self.x += o.x;
        self.y += o.y;
        self.xx += o.xx;
        self.xy += o.xy;
        self.yy += o.yy;
    }
}

/// The bounding box of points and segments, for the grids.
pub(crate) fn bounds(
    points: &[Vector2<f64>],
    segments: &[Segment],
) -> (Vector2<f64>, Vector2<f64>) {
    let mut lo = Vector2::repeat(f64::INFINITY);
    let mut hi = Vector2::repeat(f64::NEG_INFINITY);
    for p in points
        .iter()
        .chain(segments.iter().flat_map(|s| [&s.start, &s.end]))
    {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (lo, hi)
}

/// The E-step alone: each point's nearest segment and distance (no weights).
pub(crate) fn assign(points: &[Vector2<f64>], segments: &[Segment]) -> Assignment {
    if segments.is_empty() {
        return Assignment {
            owner: vec![u32::MAX; points.len()],
            distance: vec![f64::INFINITY; points.len()],
        };
    }
    let (lo, hi) = bounds(points, segments);
    let grid = SegmentGrid::new(segments, lo, hi);
    let parts: Vec<(Vec<u32>, Vec<f64>)> = points
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut seen = vec![u32::MAX; segments.len()];
            let mut out = Vec::new();
            let mut owner = Vec::with_capacity(chunk.len());
            let mut distance = Vec::with_capacity(chunk.len());
            for (k, p) in chunk.iter().enumerate() {
                let best = grid.candidates(segments, p, 0.0, &mut seen, k as u32, &mut out);
                let (j, d) = best.unwrap_or((u32::MAX, f64::INFINITY));
                owner.push(j);
                distance.push(d.sqrt());
            }
            (owner, distance)
        })
        .collect();
    let mut result = Assignment::default();
    for (owner, distance) in parts {
        result.owner.extend(owner);
        result.distance.extend(distance);
    }
    result
}

/// One EMSF step with E-step deviation `sigma`: returns the new segments (segments whose
/// support set has fewer than two points, or whose support projects onto one spot, are
/// dropped) and the E-step's assignment (for the old segments).
///
/// E-step: `w_ij = exp(-d(x_i, s_j)^2 / 2 sigma^2)`, normalized over `j` for each point,
/// evaluated over the point's candidate segments only (those within
/// `sqrt(d_min^2 + (4 sigma)^2)`, found with a grid; the others' weights are below 3.4e-4 of
/// the nearest one's and are taken as 0). M-step: the line of segment `j` goes through the
/// `w_ij`-weighted mean and its normal is the eigenvector of the smallest eigenvalue of the
/// weighted scatter matrix `M_j` (eq. 1). Trimming: the line is cut to the smallest segment
/// holding the projections of the support set `Sup(s_j) = {x_i : w_ij = max_k w_ik}`.
///
/// Points farther than `outlier_sigmas * sigma` from every segment are left out of the
/// M-step (`None`: none is, as in the paper); they stay in the support sets.
pub(crate) fn emsf_step(
    points: &[Vector2<f64>],
    segments: &[Segment],
    sigma: f64,
    outlier_sigmas: Option<f64>,
) -> (Vec<Segment>, Assignment) {
    let n = segments.len();
    if n == 0 || points.is_empty() {
        return (Vec::new(), assign(points, segments));
    }
    let (lo, hi) = bounds(points, segments);
    let grid = SegmentGrid::new(segments, lo, hi);
    let references: Vec<Vector2<f64>> = segments.iter().map(|s| (s.start + s.end) / 2.0).collect();
    let scales = Scales {
        extra_sq: (CUTOFF * sigma).powi(2),
        two_sigma_sq: 2.0 * sigma * sigma,
        outlier_sq: outlier_sigmas.map_or(f64::INFINITY, |o| (o * sigma).powi(2)),
    };
    // E-step and the M-step's sums, chunk by chunk.
    let parts: Vec<(Vec<u32>, Vec<f64>, Vec<Moments>)> = points
        .par_chunks(CHUNK)
        .map(|chunk| e_step(chunk, segments, &grid, &references, &scales))
        .collect();
    let mut assignment = Assignment::default();
    let mut moments = vec![Moments::default(); n];
    for (owner, distance, m) in parts {
        assignment.owner.extend(owner);
        assignment.distance.extend(distance);
        for (total, m) in moments.iter_mut().zip(&m) {
            total.merge(m);
        }
    }
    // M-step: weighted orthogonal regression (eq. 1).
    let lines: Vec<Option<(Vector2<f64>, Vector2<f64>)>> = moments
        .iter()
        .zip(&references)
        .map(|(m, reference)| regression_line(m, reference))
        .collect();
    // Trimming to the projection of the support set.
    let spans = support_spans(points, &assignment.owner, &lines);
    let segments = trimmed(&lines, spans);
    (segments, assignment)
}

/// The E-step's scales: the squared candidate margin `(4 sigma)^2`, `2 sigma^2`, and the
/// squared outlier distance.
struct Scales {
    extra_sq: f64,
    two_sigma_sq: f64,
    outlier_sq: f64,
}

/// The E-step over one chunk of points: each point's nearest segment and distance, and the
/// M-step's weighted moments per segment.
fn e_step(
    chunk: &[Vector2<f64>],
    segments: &[Segment],
    grid: &SegmentGrid,
    references: &[Vector2<f64>],
    scales: &Scales,
) -> (Vec<u32>, Vec<f64>, Vec<Moments>) {
    let n = segments.len();
    let mut seen = vec![u32::MAX; n];
    let mut out = Vec::new();
    let mut weights = Vec::new();
    let mut moments = vec![Moments::default(); n];
    let mut owner = Vec::with_capacity(chunk.len());
    let mut distance = Vec::with_capacity(chunk.len());
    for (k, p) in chunk.iter().enumerate() {
        let Some((best, d_min)) =
            grid.candidates(segments, p, scales.extra_sq, &mut seen, k as u32, &mut out)
        else {
            owner.push(u32::MAX);
            distance.push(f64::INFINITY);
            continue;
        };
        distance.push(d_min.sqrt());
        owner.push(best);
        if d_min > scales.outlier_sq {
            // Unexplained by the model: in the support set, but no weight.
            continue;
        }
        // Weights relative to the nearest segment's (which is 1), then normalized.
        weights.clear();
        weights.extend(
            out.iter()
                .map(|&(_, d)| (-(d - d_min) / scales.two_sigma_sq).exp()),
        );
        let total: f64 = weights.iter().sum();
        for (&(j, _), w) in out.iter().zip(&weights) {
            let j = j as usize;
            moments[j].add(w / total, p - references[j]);
        }
    }
    (owner, distance, moments)
}

/// The segments of the regression lines cut to their support spans `(t0, t1, count)`; lines
/// without a line, with fewer than two supporting points or an empty span are dropped.
fn trimmed(
    lines: &[Option<(Vector2<f64>, Vector2<f64>)>],
    spans: Vec<(f64, f64, usize)>,
) -> Vec<Segment> {
    lines
        .iter()
        .zip(spans)
        .filter_map(|(line, span)| {
            let (mean, direction) = (*line)?;
            let (t0, t1, count) = span;
            let segment = Segment {
                start: mean + direction * t0,
                end: mean + direction * t1,
                support: count,
            };
            (count >= 2 && t1 - t0 > 0.0 && segment.is_finite()).then_some(segment)
        })
        .collect()
}

/// The line of weighted orthogonal regression: `(weighted mean, unit direction)`, `None` for
/// (almost) no weight.
fn regression_line(m: &Moments, reference: &Vector2<f64>) -> Option<(Vector2<f64>, Vector2<f64>)> {
    if m.w <= 1e-9 {
        return None;
    }
    let mx = m.x / m.w;
    let my = m.y / m.w;
    let scatter = Matrix2::new(
        m.xx / m.w - mx * mx,
        m.xy / m.w - mx * my,
        m.xy / m.w - mx * my,
        m.yy / m.w - my * my,
    );
    let direction = principal_direction(&scatter)?;
    Some((reference + Vector2::new(mx, my), direction))
}

/// The eigenvector of the largest eigenvalue of a symmetric 2x2 matrix (the line's direction:
/// the normal is the eigenvector of the smallest one), with a canonical sign.
pub(crate) fn principal_direction(m: &Matrix2<f64>) -> Option<Vector2<f64>> {
    let (a, b, c) = (m[(0, 0)], m[(0, 1)], m[(1, 1)]);
    if !(a.is_finite() && b.is_finite() && c.is_finite()) {
        return None;
    }
    // Angle of the major axis: tan(2 phi) = 2b / (a - c); any direction when a = c, b = 0.
    let phi = 0.5 * (2.0 * b).atan2(a - c);
    let d = Vector2::new(phi.cos(), phi.sin());
    Some(if d.x < 0.0 || (d.x == 0.0 && d.y < 0.0) {
        -d
    } else {
        d
    })
}

/// For each line, the extent `(t_min, t_max, count)` of its support points' projections.
fn support_spans(
    points: &[Vector2<f64>],
    owner: &[u32],
    lines: &[Option<(Vector2<f64>, Vector2<f64>)>],
) -> Vec<(f64, f64, usize)> {
    let n = lines.len();
    let empty = (f64::INFINITY, f64::NEG_INFINITY, 0usize);
    let parts: Vec<Vec<(f64, f64, usize)>> = points
        .par_chunks(CHUNK)
        .zip(owner.par_chunks(CHUNK))
        .map(|(chunk, owners)| {
            let mut spans = vec![empty; n];
            for (p, &j) in chunk.iter().zip(owners) {
                let Some(Some((mean, direction))) = lines.get(j as usize) else {
                    continue;
                };
                let t = (p - mean).dot(direction);
                let span = &mut spans[j as usize];
                span.0 = span.0.min(t);
                span.1 = span.1.max(t);
                span.2 += 1;
            }
            spans
        })
        .collect();
    let mut spans = vec![empty; n];
    for part in parts {
        for (s, p) in spans.iter_mut().zip(part) {
            s.0 = s.0.min(p.0);
            s.1 = s.1.max(p.1);
            s.2 += p.2;
        }
    }
    spans
}
