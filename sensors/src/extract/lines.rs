//! Scan -> wall segments: split-and-merge with a total-least-squares fit, the covariance of
//! each line from the range noise, and real / not-real endpoints.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Matrix2, Vector2};

use crate::models::WallObservation;
use crate::scan::{LaserScan, ScanPoint};

use super::{Neighbour, clusters, far_or_unknown};

/// Settings of [`extract_segments`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LineExtractorParams {
    /// Standard deviation of a range reading, m (sets the line covariance and thresholds).
    pub sigma_range: f64,
    /// Consecutive points farther apart than `max_gap + gap_per_metre * range` start a new
    /// cluster, m.
    pub max_gap: f64,
    /// See `max_gap`, m per m of range.
    pub gap_per_metre: f64,
    /// A cluster splits where a point lies farther than this from the chord, m; at least
    /// `4 sigma_range` is used.
    pub split_distance: f64,
    /// Fewest points in a segment.
    pub min_points: usize,
    /// Shortest segment, m.
    pub min_length: f64,
    /// Adjacent segments whose ends are this close and whose lines differ by more than
    /// `min_corner_angle` meet in a corner, m.
    pub corner_gap: f64,
    /// Smallest angle between two walls forming a corner, rad.
    pub min_corner_angle: f64,
    /// A neighbouring reading at least this far beyond the line's extension shows that the
    /// wall ends there (a jump edge), m.
    pub jump: f64,
    /// Clusters shorter than this that stand free of their surroundings (both neighbouring
    /// readings farther by `jump`, or no return) are objects such as pillars, not walls, m.
    pub min_free_standing_length: f64,
    /// Widen a segment's covariance by its fit: by the residual variance of its points over
    /// `sigma_range^2` when that exceeds 1, so that a rough or slightly curved real wall is not
    /// taken as exactly known (off by default: a simulated wall is exactly straight).
    pub scale_by_residuals: bool,
}

impl Default for LineExtractorParams {
    fn default() -> Self {
        LineExtractorParams {
            sigma_range: 0.02,
            max_gap: 0.3,
            gap_per_metre: 0.05,
            split_distance: 0.08,
            min_points: 8,
            min_length: 0.4,
            corner_gap: 0.3,
            min_corner_angle: slam_features::wall::MIN_CORNER_ANGLE_DEG.to_radians(),
            jump: 0.3,
            min_free_standing_length: 1.0,
            scale_by_residuals: false,
        }
    }
}

/// One extracted segment in the sensor frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtractedSegment {
    /// Direction from the sensor to the line, rad.
    pub alpha: f64,
    /// Distance from the sensor to the line, m (non-negative).
    pub rho: f64,
    /// Covariance of `(alpha, rho)` from the range noise.
    pub cov: Matrix2<f64>,
    /// First and last points projected onto the line, in scan order.
    pub ends: [Vector2<f64>; 2],
    /// Whether each end is a real end of the wall (corner or jump edge).
    pub real: [bool; 2],
    /// Whether each real end is a corner with the neighbouring segment (else a jump edge).
    pub corner: [bool; 2],
    /// Beam indices of the first and last point.
    pub beams: [usize; 2],
    /// Number of points.
    pub points: usize,
    /// How well each end is localized along the wall, m: for a real end its deviation (see
    /// [`extract_segments`]), otherwise the distance between the end point and its inner
    /// neighbour.
    pub end_spacing: [f64; 2],
}

impl ExtractedSegment {
    /// Length between the projected ends, m.
    pub fn length(&self) -> f64 {
        (self.ends[1] - self.ends[0]).norm()
    }

    /// The [`WallObservation`] of this segment. A real end's deviation along the wall is the
    /// one its placement found (edge interval or corner propagation); the other ends get the
    /// larger of the range noise and the spacing of the points there.
    pub fn to_observation(&self, sigma_range: f64) -> slam_core::Result<WallObservation> {
        let mut sigma_endpoints = self.end_spacing.map(|s| s.max(sigma_range));
        for (sigma, (&real, &spacing)) in sigma_endpoints
            .iter_mut()
            .zip(self.real.iter().zip(&self.end_spacing))
        {
            if real && spacing > 0.0 {
                *sigma = spacing;
            }
        }
        WallObservation::new(
            self.alpha,
            self.rho,
            self.cov,
            self.ends,
            self.real,
            sigma_endpoints,
        )
    }
}

/// A total-least-squares line fit and its range Jacobian.
#[derive(Clone, Debug)]
struct LineFit {
    normal: Vector2<f64>,
    rho: f64,
    centroid: Vector2<f64>,
    tangent: Vector2<f64>,
    /// Eigenvalues of the scatter matrix: across (smallest) and along the line.
    lambda: (f64, f64),
}

impl LineFit {
    fn new(points: &[ScanPoint]) -> Option<Self> {
        let n = points.len() as f64;
        let centroid = points.iter().map(|p| p.position).sum::<Vector2<f64>>() / n;
        let mut scatter = Matrix2::zeros();
        for p in points {
            let q = p.position - centroid;
            scatter += q * q.transpose();
        }
        let eigen = scatter.symmetric_eigen();
        let (small, large) = if eigen.eigenvalues[0] <= eigen.eigenvalues[1] {
            (0, 1)
        } else {
            (1, 0)
        };
        let mut normal: Vector2<f64> = eigen.eigenvectors.column(small).into_owned();
        if !normal.iter().all(|v| v.is_finite())
            || eigen.eigenvalues[large] <= eigen.eigenvalues[small]
        {
            return None;
        }
        let mut rho = normal.dot(&centroid);
        if rho < 0.0 {
            normal = -normal;
            rho = -rho;
        }
        Some(LineFit {
            tangent: Vector2::new(-normal.y, normal.x),
            normal,
            rho,
            centroid,
            lambda: (eigen.eigenvalues[small], eigen.eigenvalues[large]),
        })
    }

    fn alpha(&self) -> f64 {
        self.normal.y.atan2(self.normal.x)
    }

    fn distance(&self, p: &Vector2<f64>) -> f64 {
        self.signed_distance(p).abs()
    }

    /// Distance of `p` from the line, positive on the far side from the sensor.
    fn signed_distance(&self, p: &Vector2<f64>) -> f64 {
        self.normal.dot(p) - self.rho
    }

    fn project(&self, p: &Vector2<f64>) -> Vector2<f64> {
        p - self.normal * (self.normal.dot(p) - self.rho)
    }

    /// Covariance of `(alpha, rho)` for independent range errors `sigma` (first-order
    /// perturbation of the scatter matrix's eigenvector).
    fn covariance(&self, points: &[ScanPoint], sigma: f64) -> Matrix2<f64> {
        let n = points.len() as f64;
        let gap = self.lambda.0 - self.lambda.1; // negative
        let perp_n = Vector2::new(-self.normal.y, self.normal.x);
        let mut cov = Matrix2::zeros();
        for p in points {
            let u = p.position / p.range; // beam direction
            let q = p.position - self.centroid;
            let t = self.tangent;
            let kappa = (t.dot(&q) * self.normal.dot(&u) + self.normal.dot(&q) * t.dot(&u)) / gap;
            let j = Vector2::new(
                perp_n.dot(&t) * kappa,
                kappa * t.dot(&self.centroid) + self.normal.dot(&u) / n,
            );
            cov += j * j.transpose() * (sigma * sigma);
        }
        cov
    }
}

/// Wall segments of a scan by split-and-merge; max-range and invalid readings are skipped.
///
/// Clusters of consecutive valid points are split recursively where a point lies farther
/// than the split distance from the chord of its cluster part (iterative end-point fit);
/// adjacent parts whose union still fits one line are merged back; each segment's line is a
/// total-least-squares fit with its covariance from the range noise, without the runs of
/// readings at its ends that lie off the line of the rest (the first readings of a side wall
/// or a step within the split distance), which still count in its extent. An end is **real** when
/// it meets the next segment in a corner, or when the neighbouring reading lies beyond the
/// line's extension (the wall visibly ends there); ends at the edge of the field of view, next
/// to an occluding object or next to a missing reading are not real. Short clusters standing
/// free of their surroundings (pillars, trees) are not walls and are left out.
///
/// ```
/// use slam_sensors::{LaserScan, extract::{extract_segments, LineExtractorParams}};
/// // A wall at x = 2 seen across 90 degrees.
/// let n = 91;
/// let ranges = (0..n).map(|i| {
///     let bearing = -std::f64::consts::FRAC_PI_4 + i as f64 * std::f64::consts::FRAC_PI_2 / 90.0;
///     2.0 / bearing.cos()
/// }).collect();
/// let scan = LaserScan::new(-std::f64::consts::FRAC_PI_4, std::f64::consts::FRAC_PI_4, ranges, 0.0, 30.0).unwrap();
/// let segments = extract_segments(&scan, &LineExtractorParams::default());
/// assert_eq!(segments.len(), 1);
/// assert!((segments[0].rho - 2.0).abs() < 1e-9 && segments[0].alpha.abs() < 1e-9);
/// assert_eq!(segments[0].real, [false, false]); // both ends at the edge of the field of view
/// ```
pub fn extract_segments(scan: &LaserScan, params: &LineExtractorParams) -> Vec<ExtractedSegment> {
    let points = scan.points();
    let split = params.split_distance.max(4.0 * params.sigma_range);
    // Inclusive index ranges into `points`: each part's extent and the readings fitted.
    let mut parts: Vec<((usize, usize), (usize, usize))> = Vec::new();
    for (first, last) in clusters(&points, scan, params.max_gap, params.gap_per_metre) {
        if is_free_standing_object(scan, &points[first], &points[last], params) {
            continue;
        }
        let mut cluster_parts = Vec::new();
        split_recursively(
            &points,
            first,
            last,
            split,
            params.min_points,
            &mut cluster_parts,
        );
        let merged = merge_collinear(&points, cluster_parts, split);
        let ambiguous = AMBIGUOUS_SIGMAS * params.sigma_range;
        parts.extend(
            separate_at_corners(
                &points,
                separate_at_corners(&points, merged, ambiguous),
                ambiguous,
            )
            .into_iter()
            .map(|part| (part, trim_ends(&points, part, params.sigma_range))),
        );
    }
    let mut segments: Vec<ExtractedSegment> = parts
        .into_iter()
        .filter_map(|((a, b), (fa, fb))| segment_fitted(&points[a..=b], &points[fa..=fb], params))
        .filter(|s| s.points >= params.min_points && s.length() >= params.min_length)
        .collect();
    mark_real_ends(scan, &mut segments, params);
    segments
}

/// Wall segments of a scan from a segmentation made elsewhere (e.g. a structure prior):
/// `groups` lists, per wall, the beam indices of the readings that belong to it, in scan
/// order (readings left out of every group are outliers).
///
/// Each group is fitted and described exactly as [`extract_segments`] describes its parts:
/// the same total-least-squares line and `(alpha, rho)` covariance from
/// `params.sigma_range`, the same end spacing, the same corner and jump-edge detection of
/// real ends between consecutive segments. Only the decision of which readings form a wall
/// differs: a group is fitted whole, since the segmentation that made it has decided which
/// readings are the wall's (split-and-merge leaves runs of end readings off the line of the
/// rest out of the fit). So that a group bridging a gap is not one wall, a group is cut
/// where two of its consecutive readings lie farther apart than `max_gap + gap_per_metre *
/// range` (the clustering rule of [`extract_segments`], applied to the group's own readings,
/// so a reading left out as an outlier does not cut it); the pieces are then filtered as in
/// [`extract_segments`]: free-standing short objects are left out, and pieces with fewer
/// than `min_points` readings or shorter than `min_length` are dropped. Invalid readings and
/// beam indices outside the scan are ignored.
///
/// ```
/// use slam_sensors::{LaserScan, extract::{extract_segments, segments_from_readings, LineExtractorParams}};
/// // A wall at x = 2 seen across 90 degrees, as one group: the same segment as split-and-merge.
/// let n = 91;
/// let ranges = (0..n).map(|i| {
///     let bearing = -std::f64::consts::FRAC_PI_4 + i as f64 * std::f64::consts::FRAC_PI_2 / 90.0;
///     2.0 / bearing.cos()
/// }).collect();
/// let scan = LaserScan::new(-std::f64::consts::FRAC_PI_4, std::f64::consts::FRAC_PI_4, ranges, 0.0, 30.0).unwrap();
/// let params = LineExtractorParams::default();
/// let given = segments_from_readings(&scan, &[(0..n).collect()], &params);
/// assert_eq!(given, extract_segments(&scan, &params));
/// ```
pub fn segments_from_readings(
    scan: &LaserScan,
    groups: &[Vec<usize>],
    params: &LineExtractorParams,
) -> Vec<ExtractedSegment> {
    let points = scan.points();
    // Position in `points` of each beam's valid reading.
    let mut of_beam = vec![None; scan.ranges.len()];
    for (k, p) in points.iter().enumerate() {
        of_beam[p.index] = Some(k);
    }
    let mut segments: Vec<ExtractedSegment> = Vec::new();
    for group in groups {
        let members: Vec<ScanPoint> = group
            .iter()
            .filter_map(|&beam| of_beam.get(beam).copied().flatten())
            .map(|k| points[k])
            .collect();
        let mut start = 0;
        for k in 1..=members.len() {
            let breaks = k == members.len() || {
                let (a, b) = (&members[k - 1], &members[k]);
                b.index <= a.index
                    || (b.position - a.position).norm()
                        > params.max_gap + params.gap_per_metre * a.range.max(b.range)
            };
            if !breaks {
                continue;
            }
            let piece = &members[start..k];
            start = k;
            let (Some(first), Some(last)) = (piece.first(), piece.last()) else {
                continue;
            };
            if is_free_standing_object(scan, first, last, params) {
                continue;
            }
            if let Some(s) = segment(piece, params)
                .filter(|s| s.points >= params.min_points && s.length() >= params.min_length)
            {
                segments.push(s);
            }
        }
    }
    segments.sort_by_key(|s| s.beams[0]);
    mark_real_ends(scan, &mut segments, params);
    segments
}

/// A short cluster whose neighbouring readings both lie well behind it: a pillar, a tree or
/// a box, not a wall.
fn is_free_standing_object(
    scan: &LaserScan,
    first: &ScanPoint,
    last: &ScanPoint,
    params: &LineExtractorParams,
) -> bool {
    if (last.position - first.position).norm() >= params.min_free_standing_length {
        return false;
    }
    let behind = |beam: Option<usize>, range: f64| match beam.map(|b| far_or_unknown(scan, b)) {
        Some(Neighbour::Range(r)) => r > range + params.jump,
        Some(Neighbour::NoReturn) => true,
        _ => false,
    };
    behind(first.index.checked_sub(1), first.range) && behind(Some(last.index + 1), last.range)
}

fn split_recursively(
    points: &[ScanPoint],
    first: usize,
    last: usize,
    split: f64,
    min_points: usize,
    out: &mut Vec<(usize, usize)>,
) {
    if last < first + 1 {
        return;
    }
    let (a, b) = (points[first].position, points[last].position);
    let chord = b - a;
    let length = chord.norm();
    let (worst, distance) = (first + 1..last)
        .map(|k| {
            let d = points[k].position - a;
            let off = if length > 0.0 {
                (chord.x * d.y - chord.y * d.x).abs() / length
            } else {
                d.norm()
            };
            (k, off)
        })
        .fold((first, 0.0), |best, c| if c.1 > best.1 { c } else { best });
    if distance > split && worst > first && worst < last {
        split_recursively(points, first, worst, split, min_points, out);
        split_recursively(points, worst, last, split, min_points, out);
    } else if last + 1 - first >= min_points.clamp(2, 3) {
        out.push((first, last));
    }
}

/// Merges neighbouring parts of one cluster whose union fits one line within the split
/// distance.
fn merge_collinear(
    points: &[ScanPoint],
    parts: Vec<(usize, usize)>,
    split: f64,
) -> Vec<(usize, usize)> {
    let mut merged: Vec<(usize, usize)> = Vec::with_capacity(parts.len());
    for part in parts {
        if let Some(last) = merged.last_mut() {
            let adjacent = part.0 <= last.1 + 1;
            if adjacent {
                let union = &points[last.0..=part.1];
                let fits = LineFit::new(union)
                    .is_some_and(|fit| union.iter().all(|p| fit.distance(&p.position) <= split));
                if fits {
                    last.1 = part.1;
                    continue;
                }
            }
        }
        merged.push(part);
    }
    merged
}

/// Readings closer than this many range deviations to the neighbouring segment's line are
/// ambiguous at a corner and left out of both fits.
const AMBIGUOUS_SIGMAS: f64 = 3.0;

/// How many readings on each side of a corner the boundary may move.
const CORNER_WINDOW: usize = 12;

/// Moves the boundary between adjacent parts of one cluster to where the readings change
/// from one line to the other (least squares over a window around the split), then leaves
/// out the readings near the corner that lie within `ambiguous` of the other part's line.
///
/// The split point of the end-point fit is the reading farthest from the chord, which noise
/// can move by a few readings, and it belongs to both parts; readings of the other wall
/// near the corner then pull each line towards the corner. Left in, they bias the line fit
/// by more than its covariance allows (a mean line NIS of 3.0 instead of 2 for segments
/// ending in a corner in the simulated world: `cargo run --release -p slam-sensors
/// --example segment_calibration`).
fn separate_at_corners(
    points: &[ScanPoint],
    parts: Vec<(usize, usize)>,
    ambiguous: f64,
) -> Vec<(usize, usize)> {
    let mut bounds = parts.clone();
    for i in 1..parts.len() {
        let ((a0, a1), (b0, b1)) = (parts[i - 1], parts[i]);
        if b0 > a1 + 1 || b1 <= a0 + 1 {
            continue;
        }
        let (Some(line_a), Some(line_b)) = (
            LineFit::new(&points[a0..=a1]),
            LineFit::new(&points[b0..=b1]),
        ) else {
            continue;
        };
        // The last reading of the first part: readings up to it go to line A, the rest to B.
        let lo = a1.saturating_sub(CORNER_WINDOW).max(a0 + 1);
        let hi = (b0 + CORNER_WINDOW).min(b1 - 1);
        let cost = |last_of_a: usize| -> f64 {
            (lo..=hi + 1)
                .map(|k| {
                    let p = &points[k].position;
                    if k <= last_of_a {
                        line_a.distance(p).powi(2)
                    } else {
                        line_b.distance(p).powi(2)
                    }
                })
                .sum()
        };
        let Some(split) = (lo..=hi).min_by(|&x, &y| cost(x).total_cmp(&cost(y))) else {
            continue;
        };
        let mut last_a = split;
        while last_a > a0 && line_b.distance(&points[last_a].position) < ambiguous {
            last_a -= 1;
        }
        let mut first_b = split + 1;
        while first_b < b1 && line_a.distance(&points[first_b].position) < ambiguous {
            first_b += 1;
        }
        bounds[i - 1].1 = last_a;
        bounds[i].0 = first_b;
    }
    bounds.into_iter().filter(|(a, b)| b > a).collect()
}

/// A run of end readings whose mean offset from the line of the rest of the part exceeds
/// this many standard errors is left out of the part.
const END_RUN_SIGMAS: f64 = 4.0;

/// Leaves out, at each end of a part, the run of readings that lies off the line of the
/// rest: readings of another surface within the split distance, such as the first few
/// readings of a side wall where a wall meets it out of the scan's view (the end-point fit
/// leaves up to `4 sigma_range` of it in, rounding the corner).
///
/// For each run length `k` up to half the part (at most [`CORNER_WINDOW`]), the rest of the
/// part is fitted and the sum of the run's offsets from that line is compared with its
/// deviation (the readings' range noise across the line, `sigma |n . u|` for the beam
/// direction `u`, and the fitted line's error at their positions); the run with the
/// largest ratio above [`END_RUN_SIGMAS`] is left out, and the ends are tried again until
/// neither changes, as long as half of the part's readings stay. Where the rest fits its
/// line worse than the range noise, the noise is scaled up by that ratio, so that a rough
/// wall is not trimmed for its roughness. The run stays in the segment's extent (its ends);
/// only the line leaves it out.
///
/// Left in, such runs tilt the line by several of its deviations, always the same way for a
/// wall seen past a recess. On a ring corridor with a door recess every 6 m and 5 cm range
/// noise (`scripts/loop-size.py`), the segments on the recessed side had a mean signed angle
/// error of +0.89 degrees and 12 % of all segments a line NIS beyond the 99 % bound; with
/// the runs left out, -0.24 degrees and 2.1 % (`cargo run --release -p slam-sensors
/// --example segment_calibration -- 1 RING.toml rough`).
fn trim_ends(points: &[ScanPoint], part: (usize, usize), sigma: f64) -> (usize, usize) {
    let (mut first, mut last) = part;
    // At least half of the part's readings stay in its fit.
    let keep = ((last + 2 - first) / 2).max(3);
    loop {
        let head = end_run(points, (first, last), sigma, keep, true);
        first += head;
        let tail = end_run(points, (first, last), sigma, keep, false);
        last -= tail;
        if head == 0 && tail == 0 {
            return (first, last);
        }
    }
}

/// The length of the run at one end of `part` (its head, or else its tail) that lies off the
/// line of the rest (see [`trim_ends`]); 0 when none does.
fn end_run(
    points: &[ScanPoint],
    (first, last): (usize, usize),
    sigma: f64,
    keep: usize,
    head: bool,
) -> usize {
    let count = last + 1 - first;
    let limit = count.saturating_sub(keep).min(CORNER_WINDOW);
    let mut best = (0, END_RUN_SIGMAS);
    for k in 1..=limit {
        let (run, rest) = if head {
            (&points[first..first + k], &points[first + k..=last])
        } else {
            (&points[last + 1 - k..=last], &points[first..=last - k])
        };
        let Some(fit) = LineFit::new(rest) else {
            continue;
        };
        // A reading's range noise across the line (small at grazing incidence, where the
        // readings spread along the wall).
        let across = |p: &ScanPoint| (sigma * fit.normal.dot(&p.position) / p.range).powi(2);
        let m = rest.len() as f64;
        let noise_variance = rest.iter().map(across).sum::<f64>() / m;
        let residual_variance = rest
            .iter()
            .map(|p| fit.signed_distance(&p.position).powi(2))
            .sum::<f64>()
            / (m - 2.0).max(1.0);
        let scale = (residual_variance / noise_variance).max(1.0);
        // The fitted line's error grows away from its centroid with the rest's spread.
        let spread: f64 = rest
            .iter()
            .map(|p| fit.tangent.dot(&(p.position - fit.centroid)).powi(2))
            .sum();
        let offsets: f64 = run.iter().map(|p| fit.signed_distance(&p.position)).sum();
        let own_variance: f64 = run.iter().map(across).sum();
        let along: f64 = run
            .iter()
            .map(|p| fit.tangent.dot(&(p.position - fit.centroid)))
            .sum();
        let k = k as f64;
        let variance =
            scale * (own_variance + noise_variance * (k * k / m + along * along / spread));
        let z = offsets.abs() / variance.sqrt();
        if z > best.1 {
            best = (k as usize, z);
        }
    }
    best.0
}

fn segment(points: &[ScanPoint], params: &LineExtractorParams) -> Option<ExtractedSegment> {
    segment_fitted(points, points, params)
}

/// The segment over the readings `extent` (its ends, beams and reading count) whose line and
/// covariance are fitted to `fitted`, a run of them.
fn segment_fitted(
    extent: &[ScanPoint],
    fitted: &[ScanPoint],
    params: &LineExtractorParams,
) -> Option<ExtractedSegment> {
    let points = fitted;
    let fit = LineFit::new(points)?;
    let (first, last) = (extent.first()?, extent.last()?);
    let spacing = |a: &ScanPoint, b: Option<&ScanPoint>| {
        b.map_or(params.sigma_range, |b| (a.position - b.position).norm())
    };
    Some(ExtractedSegment {
        alpha: fit.alpha(),
        rho: fit.rho,
        cov: fit.covariance(points, params.sigma_range) * residual_scale(&fit, points, params),
        ends: [fit.project(&first.position), fit.project(&last.position)],
        real: [false, false],
        corner: [false, false],
        beams: [first.index, last.index],
        points: extent.len(),
        end_spacing: [
            spacing(first, extent.get(1)),
            spacing(last, extent.iter().rev().nth(1)),
        ],
    })
}

/// How much worse than the range noise the points fit their line: the residual variance over
/// `sigma_range^2` (at least 1), when [`LineExtractorParams::scale_by_residuals`] is set,
/// else 1. A rough or slightly curved wall gets a wider covariance.
fn residual_scale(fit: &LineFit, points: &[ScanPoint], params: &LineExtractorParams) -> f64 {
    if !params.scale_by_residuals || points.len() <= 2 {
        return 1.0;
    }
    let sum: f64 = points
        .iter()
        .map(|p| fit.distance(&p.position).powi(2))
        .sum();
    let variance = sum / (points.len() - 2) as f64;
    (variance / params.sigma_range.powi(2)).max(1.0)
}

/// A real end's position and its deviation along the wall, m.
type PlacedEnd = (Vector2<f64>, f64);

/// Flags corners between consecutive segments and jump edges, and places each real end
/// where the wall most likely ends: a corner at the intersection of the two lines, an edge
/// halfway between the last point on the wall and where the next beam's ray crosses the
/// line (the true edge lies anywhere between them; the last point alone would put it
/// systematically short by half a beam spacing), when that crossing lies within the
/// clustering gap ([`sees_past_the_end`]). An edge's deviation along the wall is that
/// of the interval, `width / sqrt(12)`, with the range noise along the wall; a corner's is
/// propagated from the two lines' covariances.
fn mark_real_ends(
    scan: &LaserScan,
    segments: &mut [ExtractedSegment],
    params: &LineExtractorParams,
) {
    let mut placed: Vec<[Option<PlacedEnd>; 2]> = vec![[None, None]; segments.len()];
    let mut corners = vec![[false, false]; segments.len()];
    for i in 0..segments.len() {
        for (side, slot) in placed[i].iter_mut().enumerate() {
            let corner = corner_with_neighbour(segments, i, side, params);
            corners[i][side] = corner.is_some();
            let edge = if corner.is_some() {
                None
            } else {
                sees_past_the_end(scan, &segments[i], side, params).map(|(position, sigma)| {
                    // The range noise of the last reading, along the wall.
                    let tangent = Vector2::new(-segments[i].alpha.sin(), segments[i].alpha.cos());
                    let beam = segments[i].ends[side].normalize();
                    let along = params.sigma_range * tangent.dot(&beam).abs();
                    (position, sigma.hypot(along))
                })
            };
            *slot = corner.or(edge);
        }
    }
    for ((segment, ends), corner) in segments.iter_mut().zip(placed).zip(corners) {
        segment.corner = corner;
        for (side, end) in ends.into_iter().enumerate() {
            if let Some((position, sigma)) = end {
                segment.real[side] = true;
                segment.ends[side] = position;
                segment.end_spacing[side] = sigma;
            }
        }
    }
}

/// The corner where segment `i` meets its neighbour on `side` (the intersection of the two
/// lines, with its deviation along segment `i` from both lines' covariances), if they meet in
/// one.
fn corner_with_neighbour(
    segments: &[ExtractedSegment],
    i: usize,
    side: usize,
    params: &LineExtractorParams,
) -> Option<PlacedEnd> {
    let neighbour = if side == 0 {
        i.checked_sub(1)
    } else {
        Some(i + 1)
    };
    let other = neighbour.and_then(|j| segments.get(j))?;
    let mine = segments[i].ends[side];
    let theirs = other.ends[1 - side];
    let angle = (segments[i].alpha - other.alpha).sin().abs().asin();
    if (mine - theirs).norm() > params.corner_gap || angle < params.min_corner_angle {
        return None;
    }
    // (cos a1, sin a1) . p = rho1 and (cos a2, sin a2) . p = rho2.
    let (a1, a2) = (segments[i].alpha, other.alpha);
    let det = (a2 - a1).sin();
    if det.abs() < 1e-9 {
        return None;
    }
    let (r1, r2) = (segments[i].rho, other.rho);
    let corner = intersection(a1, r1, a2, r2);
    // A corner that is not near both ends is not this corner.
    if (corner - mine).norm() > params.corner_gap {
        return None;
    }
    let sigma = corner_sigma_along(&segments[i], other);
    sigma.is_finite().then_some((corner, sigma))
}

/// The point on both lines `(cos a, sin a) . p = r`; not finite for parallel lines.
fn intersection(a1: f64, r1: f64, a2: f64, r2: f64) -> Vector2<f64> {
    let det = (a2 - a1).sin();
    Vector2::new(
        (r1 * a2.sin() - r2 * a1.sin()) / det,
        (r2 * a1.cos() - r1 * a2.cos()) / det,
    )
}

/// Deviation along `mine` of its intersection with `other`, from both lines' `(alpha, rho)`
/// covariances (central differences of the intersection, first order).
fn corner_sigma_along(mine: &ExtractedSegment, other: &ExtractedSegment) -> f64 {
    let tangent = Vector2::new(-mine.alpha.sin(), mine.alpha.cos());
    let along =
        |params: [f64; 4]| tangent.dot(&intersection(params[0], params[1], params[2], params[3]));
    let at = [mine.alpha, mine.rho, other.alpha, other.rho];
    let mut gradient = [0.0; 4];
    for (k, slot) in gradient.iter_mut().enumerate() {
        let step = 1e-6;
        let (mut plus, mut minus) = (at, at);
        plus[k] += step;
        minus[k] -= step;
        *slot = (along(plus) - along(minus)) / (2.0 * step);
    }
    let g1 = Vector2::new(gradient[0], gradient[1]);
    let g2 = Vector2::new(gradient[2], gradient[3]);
    let variance =
        (g1.transpose() * mine.cov * g1)[(0, 0)] + (g2.transpose() * other.cov * g2)[(0, 0)];
    variance.max(0.0).sqrt()
}

/// When the reading just outside `side` of the segment lies beyond the line's extension (a
/// jump edge), the end's most likely position and deviation along the wall.
///
/// Only where the next beam would have met the line within the clustering gap of the last
/// reading (`max_gap + gap_per_metre * range`): had the wall gone on, that reading would have
/// joined the segment, so its absence places the end. Where the beam meets the line farther
/// away (a wall seen at grazing incidence, whose readings thin out), the segment ends
/// because the sampling does, and nothing says where the wall does: no real end.
fn sees_past_the_end(
    scan: &LaserScan,
    segment: &ExtractedSegment,
    side: usize,
    params: &LineExtractorParams,
) -> Option<PlacedEnd> {
    let beam = segment.beams[side];
    let next = if side == 0 {
        beam.checked_sub(1)
    } else {
        Some(beam + 1)
    };
    // None: the edge of the field of view.
    let next = next.filter(|&b| b < scan.ranges.len())?;
    let bearing = scan.bearing(next);
    let cos = (bearing - segment.alpha).cos();
    let line_range = if cos > 1e-3 {
        segment.rho / cos
    } else {
        f64::INFINITY
    };
    let jump = params.jump;
    let past = match far_or_unknown(scan, next) {
        Neighbour::Range(r) => r > line_range + jump,
        // No return: the wall would have been seen there had it continued within range.
        Neighbour::NoReturn => line_range + jump < scan.max_range,
        Neighbour::Unknown => false,
    };
    if !past || !line_range.is_finite() {
        return None;
    }
    let last = segment.ends[side];
    let crossing = Vector2::new(bearing.cos(), bearing.sin()) * line_range;
    let width = (crossing - last).norm();
    if width > params.max_gap + params.gap_per_metre * line_range.max(last.norm()) {
        return None;
    }
    Some(((last + crossing) / 2.0, width / 12f64.sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::nalgebra::DVector;
    use slam_core::testing::numeric_jacobian;

    fn points_from(ranges: &[f64], bearings: &[f64]) -> Vec<ScanPoint> {
        ranges
            .iter()
            .zip(bearings)
            .enumerate()
            .map(|(index, (&range, &bearing))| ScanPoint {
                index,
                range,
                bearing,
                position: Vector2::new(range * bearing.cos(), range * bearing.sin()),
            })
            .collect()
    }

    /// A room corner: walls x = 3 and y = 2 seen from the origin over 0..90 degrees.
    fn corner_scan() -> LaserScan {
        let n = 181;
        let increment = std::f64::consts::FRAC_PI_2 / (n - 1) as f64;
        let ranges = (0..n)
            .map(|i| {
                let b = i as f64 * increment;
                (3.0 / b.cos()).min(2.0 / b.sin())
            })
            .collect();
        LaserScan::with_increment(0.0, increment, ranges, 0.0, 30.0).unwrap()
    }

    #[test]
    fn a_wall_at_grazing_incidence_has_no_real_end_where_its_readings_thin_out() {
        // A line 0.2 m from the sensor, normal at 135 degrees, seen by beams at 50-60
        // degrees (ranges 2.3 down to 0.77 m: nearly along the beams). Beyond 60 degrees a
        // surface 5 m away; below 50 degrees no return.
        let increment = 1f64.to_radians();
        let line_range = |b: f64| 0.2 / (b - 135f64.to_radians()).cos();
        let ranges: Vec<f64> = (0..90)
            .map(|i| match i {
                50..=60 => line_range(i as f64 * increment),
                61.. => 5.0,
                _ => 30.0,
            })
            .collect();
        let scan = LaserScan::with_increment(0.0, increment, ranges, 0.0, 30.0).unwrap();
        let params = LineExtractorParams {
            sigma_range: 0.01,
            ..Default::default()
        };
        let segments = extract_segments(&scan, &params);
        let wall = segments
            .iter()
            .find(|s| s.beams == [50, 60])
            .unwrap_or_else(|| panic!("{segments:?}"));
        // Beam 49 would meet the line 2.87 m out, 0.58 m past the last reading: beyond the
        // clustering gap there (0.44 m), so the missing return does not place the end, and
        // the end stays at the last reading.
        assert!(!wall.real[0], "{wall:?}");
        let last = Vector2::new(50f64.to_radians().cos(), 50f64.to_radians().sin())
            * line_range(50f64.to_radians());
        assert!((wall.ends[0] - last).norm() < 0.01, "{wall:?}");
        // Beam 61 sees past the near end, 5 cm beyond the last reading: a jump edge.
        assert!(wall.real[1], "{wall:?}");
    }

    #[test]
    fn given_readings_are_fitted_like_split_and_merge() {
        let scan = corner_scan();
        let params = LineExtractorParams {
            sigma_range: 0.01,
            ..Default::default()
        };
        let extracted = extract_segments(&scan, &params);
        assert_eq!(extracted.len(), 2);
        // The same segmentation given from outside gives the same segments, corners included.
        let groups: Vec<Vec<usize>> = extracted
            .iter()
            .map(|s| (s.beams[0]..=s.beams[1]).collect())
            .collect();
        let given = segments_from_readings(&scan, &groups, &params);
        assert_eq!(given, extracted);
        assert_eq!(given[0].real, [false, true]);
        assert_eq!(given[1].real, [true, false]);
    }

    #[test]
    fn readings_left_out_are_outliers_and_gaps_cut_a_group() {
        let mut scan = corner_scan();
        let params = LineExtractorParams {
            sigma_range: 0.01,
            ..Default::default()
        };
        // Clutter on the first wall, left out of its group: the wall is fitted without it.
        scan.ranges[20] = 1.0;
        let corner = (2.0f64).atan2(3.0);
        let split = (0..scan.ranges.len())
            .position(|i| scan.bearing(i) > corner)
            .unwrap();
        let first: Vec<usize> = (0..split).filter(|&i| i != 20).collect();
        let second: Vec<usize> = (split..scan.ranges.len()).collect();
        let segments = segments_from_readings(&scan, &[first, second.clone()], &params);
        assert_eq!(segments.len(), 2);
        assert!(segments[0].alpha.abs() < 1e-9 && (segments[0].rho - 3.0).abs() < 1e-9);
        assert_eq!(segments[0].real, [false, true]);
        // One group over both walls without the corner's readings: the gap cuts it in two, and
        // neither piece reaches the corner, so those ends are not real.
        let far: Vec<usize> = (0..scan.ranges.len())
            .filter(|&i| i != 20 && !(split - 30..split + 30).contains(&i))
            .collect();
        let segments = segments_from_readings(&scan, &[far], &params);
        assert_eq!(segments.len(), 2);
        assert!((segments[1].alpha - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!((segments[1].rho - 2.0).abs() < 1e-9);
        // Beams outside the scan and max-range readings are ignored.
        assert!(segments_from_readings(&scan, &[vec![10_000]], &params).is_empty());
    }

    /// The analytic covariance is J J^T sigma^2 with J the derivative of (alpha, rho) w.r.t.
    /// the ranges: check J against central differences of the fit.
    #[test]
    fn line_covariance_matches_numeric_jacobian() {
        let bearings: Vec<f64> = (0..12).map(|i| -0.4 + 0.07 * i as f64).collect();
        let ranges: Vec<f64> = bearings
            .iter()
            .enumerate()
            .map(|(i, b)| 3.0 / (b - 0.2).cos() + 0.01 * ((i * 7 % 5) as f64 - 2.0))
            .collect();
        let fit_of = |r: &DVector<f64>| {
            let fit = LineFit::new(&points_from(r.as_slice(), &bearings)).unwrap();
            DVector::from_vec(vec![fit.alpha(), fit.rho])
        };
        let r0 = DVector::from_vec(ranges.clone());
        let j = numeric_jacobian(&r0, 1e-7, fit_of);
        let numeric = &j * j.transpose() * 0.02f64.powi(2);
        let analytic = LineFit::new(&points_from(&ranges, &bearings))
            .unwrap()
            .covariance(&points_from(&ranges, &bearings), 0.02);
        assert!(
            (numeric[(0, 0)] - analytic[(0, 0)]).abs()
                < 1e-6 * analytic[(0, 0)].abs().max(1e-12) + 1e-12,
            "{numeric} vs {analytic}"
        );
        let diff = (Matrix2::from_column_slice(numeric.as_slice()) - analytic).amax();
        assert!(diff < 1e-4 * analytic.amax(), "{numeric} vs {analytic}");
    }

    /// A scan over 180 degrees in 361 beams of the ranges `range_to(bearing)` with noise; a
    /// range beyond `max_range - 0.5` gives no return.
    fn noisy_half_scan(
        range_to: impl Fn(f64) -> f64,
        noise: &rand_distr::Normal<f64>,
        rng: &mut rand_chacha::ChaCha8Rng,
        max_range: f64,
    ) -> LaserScan {
        use rand_distr::Distribution;
        let angle_min = -std::f64::consts::FRAC_PI_2;
        let increment = std::f64::consts::PI / 360.0;
        let ranges: Vec<f64> = (0..361)
            .map(|i| {
                let range = range_to(angle_min + i as f64 * increment);
                if range < max_range - 0.5 {
                    range + noise.sample(rng)
                } else {
                    max_range // no return
                }
            })
            .collect();
        LaserScan::new(angle_min, -angle_min, ranges, 0.0, max_range).unwrap()
    }

    /// Segments meeting in a corner are fitted without the other wall's readings: over many
    /// noisy scans of a room corner, the line NIS against the true walls averages 2 (it
    /// averaged about 3 when the corner readings went into both fits).
    #[test]
    fn corner_segments_and_their_ends_are_calibrated() {
        use rand::SeedableRng;
        use rand_distr::Normal;
        let sigma = 0.02;
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // Walls x = 2 (alpha 0, rho 2) and y = 1 (alpha pi/2, rho 1) meet at (2, 1).
        let truth = [(0.0, 2.0), (std::f64::consts::FRAC_PI_2, 1.0)];
        let (mut sum, mut count) = (0.0, 0);
        let (mut corner_z2, mut corners) = (0.0, 0);
        for _ in 0..200 {
            let wall_ranges = |b: f64| {
                let to_a = if b.cos() > 1e-9 {
                    2.0 / b.cos()
                } else {
                    f64::INFINITY
                };
                let to_b = if b.sin() > 1e-9 {
                    1.0 / b.sin()
                } else {
                    f64::INFINITY
                };
                to_a.min(to_b)
            };
            let scan = noisy_half_scan(wall_ranges, &noise, &mut rng, 8.0);
            let params = LineExtractorParams {
                sigma_range: sigma,
                ..LineExtractorParams::default()
            };
            for segment in extract_segments(&scan, &params) {
                let (alpha, rho) = truth
                    .iter()
                    .copied()
                    .min_by(|a, b| {
                        let d = |t: (f64, f64)| (segment.alpha - t.0).sin().abs();
                        d(*a).total_cmp(&d(*b))
                    })
                    .unwrap();
                let e = Vector2::new((segment.alpha - alpha).sin().asin(), segment.rho - rho);
                let nis = (e.transpose() * segment.cov.try_inverse().unwrap() * e)[0];
                sum += nis;
                count += 1;
                // The corner end: its error along the wall against its deviation.
                let observation = segment.to_observation(sigma).unwrap();
                for side in 0..2 {
                    if segment.corner[side] {
                        let tangent = Vector2::new(-segment.alpha.sin(), segment.alpha.cos());
                        let along = tangent.dot(&(segment.ends[side] - Vector2::new(2.0, 1.0)));
                        corner_z2 += (along / observation.sigma_endpoints[side]).powi(2);
                        corners += 1;
                    }
                }
            }
        }
        let mean = sum / count as f64;
        assert!(count >= 400, "{count} segments");
        assert!((1.6..2.5).contains(&mean), "mean line NIS {mean}");
        // Calibrated corner ends (with the range noise as their deviation: about 0.04).
        let corner_mean = corner_z2 / corners as f64;
        assert!(corners >= 300, "{corners} corner ends");
        assert!(
            (0.6..1.5).contains(&corner_mean),
            "corner end z^2 {corner_mean}"
        );
    }

    /// A corridor wall (y = -1.25) past a door recess (x 4..5, 0.4 m deep), seen from the
    /// origin along the corridor with 5 cm range noise. The first readings beyond the recess
    /// lie on its far side wall (x = 5); they are within the split distance of the wall's
    /// line, and left in they tilt it, always the same way.
    #[test]
    fn readings_of_a_side_wall_at_a_segments_end_are_left_out() {
        use rand::SeedableRng;
        use rand_distr::Normal;
        let sigma = 0.05;
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let range_to = |b: f64| -> f64 {
            let (c, s) = (b.cos(), b.sin());
            if s > -1e-9 {
                return f64::INFINITY; // the corridor's other side is left out
            }
            let t = -1.25 / s;
            let x = t * c;
            if !(4.0..5.0).contains(&x) {
                return t;
            }
            // Through the recess's opening: its far side wall or its back wall.
            let to_side = if c > 1e-9 { 5.0 / c } else { f64::INFINITY };
            let to_back = -1.65 / s;
            to_side.min(to_back)
        };
        let (mut angle_sum, mut nis_sum, mut count) = (0.0, 0.0, 0);
        for _ in 0..100 {
            let scan = noisy_half_scan(range_to, &noise, &mut rng, 10.0);
            let params = LineExtractorParams {
                sigma_range: sigma,
                ..LineExtractorParams::default()
            };
            for segment in extract_segments(&scan, &params) {
                // The wall beyond the recess: alpha -pi/2, rho 1.25, its middle past x = 5.
                let middle = (segment.ends[0] + segment.ends[1]) / 2.0;
                if middle.x < 5.0 || (segment.rho - 1.25).abs() > 0.3 {
                    continue;
                }
                let e = Vector2::new(
                    slam_core::wrap_angle(segment.alpha + std::f64::consts::FRAC_PI_2),
                    segment.rho - 1.25,
                );
                angle_sum += e.x;
                nis_sum += (e.transpose() * segment.cov.try_inverse().unwrap() * e)[0];
                count += 1;
            }
        }
        assert!(
            count > 80,
            "the wall beyond the recess is found ({count} of 100)"
        );
        let mean_angle = (angle_sum / count as f64).to_degrees();
        let mean_nis = nis_sum / count as f64;
        assert!(
            mean_angle.abs() < 0.3,
            "mean angle error {mean_angle} degrees"
        );
        assert!(
            mean_nis < 3.0,
            "mean line NIS {mean_nis} (2 when calibrated)"
        );
    }
}
