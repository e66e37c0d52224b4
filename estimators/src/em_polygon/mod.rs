//! Polygonal approximation of registered laser points by split-and-merge EM segment fitting
//! (SMEMSF; Latecki & Lakaemper, "Polygonal approximation of laser range data based on
//! perceptual grouping and EM", ICRA 2006).
//!
//! A post-processing estimator: registered scan points in (scans placed by an estimator's
//! trajectory or by poses a dataset gives), line segments and polylines out. Starting from
//! the two diagonals of the points' bounding box, [`fit_polygons`] iterates
//!
//! 1. EMSF ([`emsf`], section II-A): E-step on point-to-segment distances, M-step by
//!    weighted orthogonal regression (eq. 1), trimming to the support set;
//! 2. LSS (section II-C): cut the segments into subsegments of length `2r`, remove those
//!    whose square holds `<= C` points, keep the connected remainders;
//! 3. EMSF again;
//! 4. merge (section III) by the perceptual-grouping cost `2 parC + 1/4 colC + 1/2 proxC`;
//! 5. model selection (`select_segments`, an addition to the paper, below),
//!
//! until the mean point-to-nearest-segment distance is stable. Then a last EMSF whose M-step
//! ignores points farther than `3 sigma` puts lines pulled off their wall by far points back
//! on it, a last LSS with `C = 0` removes the empty parts of the segments (EMSF trims each
//! segment to all of its support set, which can stretch it to a few stray points far away),
//! the segments that save less distance than one segment's share are removed (model
//! selection, `select_segments`; an addition to the paper, see below), and the segments are
//! ordered into polylines.
//!
//! **Scales chosen from the data at every iteration** (the paper computes `2r` and `C`
//! "dynamically" without giving formulas; these are this implementation's choices):
//!
//! - `sigma`, the deviation of the E-step (`w_ij ~ exp(-d^2 / 2 sigma^2)`; the paper writes
//!   it with `sigma = 1` in its units), is the robust spread of the point-to-nearest-segment
//!   distances `d_i` of the current model, `1.4826 median_i d_i`, but at most
//!   `sigma_shrink` (1/2) times the previous iteration's and at least the noise of the
//!   points: large while the model is poor (soft assignments), then annealed down to the
//!   noise. The noise is measured once from the points alone, not from the model (whose
//!   residuals are as wide as the `sigma` it was fitted with): the median deviation across
//!   the line fitted to each line-like neighbourhood of a sample of the points (`noise.rs`;
//!   `sigma_min` is only a guard below it, and the floor with `measure_noise = false`).
//!   Without the shrinking, a poor model keeps a large `sigma`, hence a large `r`, and the
//!   split never discriminates. The stop condition (the mean point-to-nearest-segment
//!   distance changes by less than `tolerance`) is tested once `sigma` no longer shrinks.
//! - `r = clamp(max(split_scale sigma, subsegment_points * spacing / 2), r_min, r_max)`, with
//!   `spacing` the total segment length over the number of points in their support sets: a
//!   square of side `2r` around a subsegment then holds the points of a wall along it (they
//!   lie within about `2 sigma` of the line), few of a wall that crosses it, and on average
//!   at least `subsegment_points` (10) points, so that sparse data are not cut to pieces.
//! - `C = max(min_support, support_fraction * median of the positive subsegment supports)`:
//!   a subsegment is kept when its square holds more than that fraction of the typical
//!   support of a subsegment lying on structure.
//!
//! **Model selection** (`select.rs`): a segment's saving is how much the points' total
//! distance to their nearest segment would grow without it. A segment is removed when its
//! saving is below the total distance over the number of other segments, which lowers the
//! product mean distance x segments (a relative change of either counts the same), cheapest
//! first, in rounds, until none qualifies. The distances of points that the model before the
//! selection leaves farther than `3 sigma` from every segment (returns in open space,
//! clutter) are left out of the total, or their large, fixed share would make every segment
//! look cheap. It runs in every iteration (so that the split's new pieces must earn their
//! place each time and the segment count settles) and once more after the final split.
//!
//! **A given accuracy, fewest segments** (`max_mean_distance`, off by default; an addition
//! to the paper): after the selection, the segments that save least are removed, cheapest
//! first, while the mean point-to-nearest-segment distance stays within the bound (the
//! "min-#" form of polygonal approximation, solved greedily; `select.rs`). Segments whose
//! removals together would exceed it are taken back and removed in smaller rounds, and the
//! bound holds after the ends are joined. It trades distance for compactness where the user
//! asks: on the Intel lab's corrected poses 468 segments at 3.4 cm by default, 293 at 5.0 cm
//! with a bound of 5 cm (BENCHMARKS.md).
//!
//! The E-step is not a dense points x segments loop: a grid over the segments gives each
//! point its candidate segments (those within `sqrt(d_min^2 + (4 sigma)^2)`; farther ones
//! have relative weights below `3.4e-4` and are taken as 0), and points are processed in
//! parallel (rayon) in fixed chunks whose partial sums are added in order, so results do not
//! depend on the number of threads.

mod emsf;
mod grid;
mod merge;
mod noise;
mod polyline;
mod select;
mod split;

use serde::{Deserialize, Serialize};
use slam_core::Error;
use slam_core::nalgebra::Vector2;

/// A line segment of the model, in the points' frame (metres).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    /// One end.
    pub start: Vector2<f64>,
    /// The other end.
    pub end: Vector2<f64>,
    /// Number of points whose nearest segment it is (in a [`PolygonMap`]; at the last EMSF
    /// during the fit; 0 when not yet fitted).
    pub support: usize,
}

impl Segment {
    /// A segment from `start` to `end` with no support yet.
    pub fn new(start: Vector2<f64>, end: Vector2<f64>) -> Self {
        Segment {
            start,
            end,
            support: 0,
        }
    }

    /// Length, m.
    pub fn length(&self) -> f64 {
        (self.end - self.start).norm()
    }

    /// Distance from `p` to the segment, m.
    pub fn distance(&self, p: &Vector2<f64>) -> f64 {
        grid::point_segment_distance_sq(p, &self.start, &self.end).sqrt()
    }

    fn is_finite(&self) -> bool {
        self.start
            .iter()
            .chain(self.end.iter())
            .all(|v| v.is_finite())
    }
}

/// Segments joined end to end.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Polyline {
    /// The segments in order, by index into [`PolygonMap::segments`], each with `true` when
    /// it is walked from its end to its start.
    pub segments: Vec<(usize, bool)>,
    /// The vertices in order (one more than the segments for an open polyline, as many for a
    /// closed one).
    pub vertices: Vec<Vector2<f64>>,
    /// Whether the last vertex joins the first.
    pub closed: bool,
}

/// Settings of [`fit_polygons`]; `Default` gives the values used on the Radish indoor logs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmPolygonParams {
    /// Measure the noise of the points about their walls from the data (local line fits,
    /// no model) and anneal `sigma` down to it; `false`: down to `sigma_min`.
    pub measure_noise: bool,
    /// Smallest E-step deviation `sigma`, m: a guard below the measured noise (with
    /// `measure_noise = false`, the noise of the registered points).
    pub sigma_min: f64,
    /// Points farther than `outlier_sigmas * sigma` from every segment get no weight in the
    /// M-step (`None`, the default: all points count, as in the paper). They stay in the
    /// support sets, so that trimming still stretches segments over unexplained points and
    /// the split finds the structure there. On the Intel log a limit of 3 leaves more points
    /// unexplained (mean distance 9.9 cm against 2.8 cm, BENCHMARKS.md).
    pub outlier_sigmas: Option<f64>,
    /// `sigma` shrinks at least by this factor per iteration until it reaches `sigma_min`
    /// (annealing).
    pub sigma_shrink: f64,
    /// The split half-length is `r = split_scale * sigma` ...
    pub split_scale: f64,
    /// ... and at least half the length that holds this many points at the mean density of
    /// points along the segments (sparse points need longer subsegments) ...
    pub subsegment_points: f64,
    /// ... bounded below by this, m ...
    pub r_min: f64,
    /// ... and above by this, m.
    pub r_max: f64,
    /// The support threshold `C` is this fraction of the median positive subsegment support
    /// ...
    pub support_fraction: f64,
    /// ... and at least this many points: with 2 (the default) a subsegment needs three
    /// points to count as support, since any two points lie on a line. Not a scale: lower
    /// values keep subsegments held by one or two stray returns (on the sparse acapulco log,
    /// 0 leaves a mean distance of 69 cm against 37 cm, BENCHMARKS.md).
    pub min_support: f64,
    /// Angle between two segments that alone gives the merge cost 1 (`2 parC = 1`), degrees.
    /// Smaller values merge less.
    pub merge_angle_deg: f64,
    /// Largest number of iterations (EMSF, LSS, EMSF, merge, selection).
    pub max_iterations: usize,
    /// Stop when the mean point-to-nearest-segment distance changes by less than this
    /// fraction between two iterations.
    pub tolerance: f64,
    /// Segment ends closer than `join_scale * r` are joined into polylines.
    pub join_scale: f64,
    /// At every iteration and after the fit, remove the segments that save less distance
    /// than the distance budget of one segment (they lower mean distance x segments; an
    /// addition to the paper).
    pub select_segments: bool,
    /// After the fit (and after `select_segments`), remove the segments that save least,
    /// cheapest first, while the mean point-to-nearest-segment distance stays at most this,
    /// m: the fewest segments at a given accuracy, for a compact map (`None`, the default:
    /// no such step). The bound is checked on the joined segments of the result: joining
    /// moves ends, so the removal is redone against a bound lowered by the excess (up to
    /// four times). Nothing is removed when the fit's mean is already above it.
    #[serde(default)]
    pub max_mean_distance: Option<f64>,
}

impl Default for EmPolygonParams {
    fn default() -> Self {
        EmPolygonParams {
            measure_noise: true,
            sigma_min: 0.005,
            sigma_shrink: 0.5,
            outlier_sigmas: None,
            split_scale: 2.0,
            subsegment_points: 10.0,
            r_min: 0.01,
            r_max: 1.0,
            support_fraction: 0.1,
            min_support: 2.0,
            merge_angle_deg: 20.0,
            max_iterations: 30,
            tolerance: 0.01,
            join_scale: 2.0,
            select_segments: true,
            max_mean_distance: None,
        }
    }
}

impl EmPolygonParams {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<(), Error> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let checks = [
            (positive(self.sigma_min), "sigma_min > 0"),
            (
                positive(self.sigma_shrink) && self.sigma_shrink <= 1.0,
                "sigma_shrink in (0, 1]",
            ),
            (
                self.outlier_sigmas.is_none_or(|o| o > 0.0),
                "outlier_sigmas > 0",
            ),
            (positive(self.split_scale), "split_scale > 0"),
            (
                self.subsegment_points.is_finite() && self.subsegment_points >= 0.0,
                "subsegment_points >= 0",
            ),
            (positive(self.r_min), "r_min > 0"),
            (
                positive(self.r_max) && self.r_max >= self.r_min,
                "r_max >= r_min",
            ),
            (
                self.support_fraction.is_finite() && self.support_fraction >= 0.0,
                "support_fraction >= 0",
            ),
            (
                self.min_support.is_finite() && self.min_support >= 0.0,
                "min_support >= 0",
            ),
            (
                positive(self.merge_angle_deg) && self.merge_angle_deg <= 180.0,
                "merge_angle_deg in (0, 180]",
            ),
            (self.max_iterations >= 1, "max_iterations >= 1"),
            (
                self.tolerance.is_finite() && self.tolerance >= 0.0,
                "tolerance >= 0",
            ),
            (
                self.join_scale.is_finite() && self.join_scale >= 0.0,
                "join_scale >= 0",
            ),
            (
                self.max_mean_distance.is_none_or(positive),
                "max_mean_distance > 0",
            ),
        ];
        match checks.iter().find(|(ok, _)| !ok) {
            Some((_, what)) => Err(Error::InvalidArgument(format!(
                "EM polygon parameters: {what} is required"
            ))),
            None => Ok(()),
        }
    }
}

/// What one iteration (EMSF, LSS, EMSF, merge, selection) did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterationStats {
    /// E-step deviation `sigma`, m.
    pub sigma: f64,
    /// Split half-length `r`, m.
    pub r: f64,
    /// Support threshold `C`, points.
    pub support_threshold: f64,
    /// Subsegments examined and removed by the split.
    pub subsegments: (usize, usize),
    /// Segments after the split.
    pub after_split: usize,
    /// Merges done.
    pub merges: usize,
    /// Segments removed by the model selection after the merge.
    #[serde(default)]
    pub pruned: usize,
    /// Segments at the end of the iteration.
    pub segments: usize,
    /// Mean point-to-nearest-segment distance at the end of the iteration, m.
    pub mean_distance: f64,
}

/// The result of [`fit_polygons`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolygonMap {
    /// The segments (joined ends moved onto their common polyline vertex), none shorter
    /// than [`MIN_LENGTH`].
    pub segments: Vec<Segment>,
    /// The segments ordered into polylines; every segment is in exactly one.
    pub polylines: Vec<Polyline>,
    /// Number of input points.
    pub points: usize,
    /// Mean distance of the points to their nearest segment, m (`None` without segments).
    pub mean_distance: Option<f64>,
    /// Median of the same distances, m.
    pub median_distance: Option<f64>,
    /// Points per segment endpoint, `points / (2 segments)` (the paper's compression ratio).
    pub compression_ratio: Option<f64>,
    /// Noise of the points about their walls measured from the data (`None` when not
    /// measured or no neighbourhood was line-like), m: the floor of the annealed `sigma`.
    #[serde(default)]
    pub noise_level: Option<f64>,
    /// Segments removed by the last model selection, after the final split.
    #[serde(default)]
    pub pruned: usize,
    /// Statistics of every iteration.
    pub iterations: Vec<IterationStats>,
    /// Whether the stop condition was met before `max_iterations`.
    pub converged: bool,
}

/// Shortest segment in a result, m.
pub const MIN_LENGTH: f64 = 1e-3;

/// Checks the points: at least one, all finite.
fn check_points(points: &[Vector2<f64>]) -> Result<(), Error> {
    if points.is_empty() {
        return Err(Error::InvalidArgument(
            "EM polygon: no points to approximate".into(),
        ));
    }
    match points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        Some(i) => Err(Error::NonFinite(format!(
            "EM polygon input point {i} ({}, {})",
            points[i].x, points[i].y
        ))),
        None => Ok(()),
    }
}

/// The robust spread `1.4826 * median` of finite distances (0 for none).
fn robust_spread(distances: &[f64]) -> f64 {
    1.4826 * median(distances).unwrap_or(0.0)
}

fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|d| d.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let k = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(k, f64::total_cmp);
    Some(*m)
}

fn mean(values: &[f64]) -> Option<f64> {
    let finite: Vec<f64> = values.iter().copied().filter(|d| d.is_finite()).collect();
    (!finite.is_empty()).then(|| finite.iter().sum::<f64>() / finite.len() as f64)
}

/// One EMSF step (E-step, M-step, trimming; section II-A) with E-step deviation `sigma`:
/// what plain EM segment fitting repeats. Points farther than `outlier_sigmas * sigma` from
/// every segment get no weight in the M-step (`None`: all count). Segments left with fewer than two
/// support points are dropped.
///
/// ```
/// use slam_core::nalgebra::Vector2;
/// use slam_estimators::em_polygon::{Segment, emsf};
/// let points: Vec<_> = (0..50).map(|k| Vector2::new(k as f64 * 0.1, 1.0)).collect();
/// let start = [Segment::new(Vector2::new(0.0, 0.0), Vector2::new(5.0, 2.0))];
/// let fitted = emsf(&points, &start, 0.5, None)?;
/// assert!((fitted[0].start.y - 1.0).abs() < 1e-9 && (fitted[0].length() - 4.9).abs() < 1e-9);
/// # Ok::<(), slam_core::Error>(())
/// ```
pub fn emsf(
    points: &[Vector2<f64>],
    segments: &[Segment],
    sigma: f64,
    outlier_sigmas: Option<f64>,
) -> Result<Vec<Segment>, Error> {
    check_points(points)?;
    if !(sigma.is_finite() && sigma > 0.0 && outlier_sigmas.is_none_or(|o| o > 0.0)) {
        return Err(Error::InvalidArgument(format!(
            "EMSF deviation and outlier distance must be positive, got {sigma} and \
             {outlier_sigmas:?}"
        )));
    }
    if let Some(i) = segments.iter().position(|s| !s.is_finite()) {
        return Err(Error::NonFinite(format!("EMSF input segment {i}")));
    }
    Ok(emsf::emsf_step(points, segments, sigma, outlier_sigmas).0)
}

/// The distance of every point to its nearest segment (infinite without segments), found
/// with a grid over the segments.
pub fn nearest_distances(points: &[Vector2<f64>], segments: &[Segment]) -> Vec<f64> {
    emsf::assign(points, segments).distance
}

/// The two diagonals of the points' bounding box: the paper's starting model.
fn diagonals(lo: Vector2<f64>, hi: Vector2<f64>) -> Vec<Segment> {
    vec![
        Segment::new(lo, hi),
        Segment::new(Vector2::new(lo.x, hi.y), Vector2::new(hi.x, lo.y)),
    ]
}

/// Split-and-merge EM segment fitting (SMEMSF, section II-B) of `points`, from the two
/// diagonals of their bounding box, then ordering into polylines.
///
/// Errors: no points, a non-finite point, or parameters out of range. Points that all lie
/// on one spot (bounding box under a micrometre) give a map without segments.
///
/// ```
/// use slam_core::nalgebra::Vector2;
/// use slam_estimators::em_polygon::{EmPolygonParams, fit_polygons};
/// // An L: two walls of 4 m and 3 m, one point every centimetre.
/// let mut points: Vec<_> = (0..=400).map(|k| Vector2::new(k as f64 * 0.01, 0.0)).collect();
/// points.extend((1..=300).map(|k| Vector2::new(0.0, k as f64 * 0.01)));
/// let map = fit_polygons(&points, &EmPolygonParams::default())?;
/// assert_eq!(map.segments.len(), 2);
/// assert_eq!(map.polylines.len(), 1);
/// assert!(map.mean_distance.unwrap() < 0.01);
/// # Ok::<(), slam_core::Error>(())
/// ```
pub fn fit_polygons(
    points: &[Vector2<f64>],
    params: &EmPolygonParams,
) -> Result<PolygonMap, Error> {
    check_points(points)?;
    let (lo, hi) = emsf::bounds(points, &[]);
    fit_polygons_from(points, diagonals(lo, hi), params)
}

/// [`fit_polygons`] from the given starting segments instead of the diagonals.
pub fn fit_polygons_from(
    points: &[Vector2<f64>],
    initial: Vec<Segment>,
    params: &EmPolygonParams,
) -> Result<PolygonMap, Error> {
    params.validate()?;
    check_points(points)?;
    if let Some(i) = initial.iter().position(|s| !s.is_finite()) {
        return Err(Error::NonFinite(format!("EM polygon starting segment {i}")));
    }
    let (lo, hi) = emsf::bounds(points, &[]);
    let mut result = PolygonMap {
        segments: Vec::new(),
        polylines: Vec::new(),
        points: points.len(),
        mean_distance: None,
        median_distance: None,
        compression_ratio: None,
        noise_level: None,
        pruned: 0,
        iterations: Vec::new(),
        converged: false,
    };
    if (hi - lo).max() < 1e-6 {
        // One spot: no line structure.
        result.converged = true;
        return Ok(result);
    }
    result.noise_level = params
        .measure_noise
        .then(|| noise::noise_level(points))
        .flatten()
        .map(|level| level.sigma);
    let floor = result.noise_level.unwrap_or(0.0).max(params.sigma_min);
    let iterated = iterate(points, initial, params, floor, &mut result);
    let (segments, polylines, pruned) = finish(points, iterated, params);
    result.pruned = pruned;
    result.polylines = polylines;
    summarize(points, segments, &mut result);
    Ok(result)
}

/// Where the iterations ended: the segments, the last split scale `r` and deviation.
struct Iterated {
    segments: Vec<Segment>,
    r: f64,
    sigma: f64,
}

/// The iterations of EMSF, split, EMSF and merge until the mean distance stops changing
/// (outside annealing) or `max_iterations`; their statistics go to `result`.
fn iterate(
    points: &[Vector2<f64>],
    initial: Vec<Segment>,
    params: &EmPolygonParams,
    floor: f64,
    result: &mut PolygonMap,
) -> Iterated {
    let mut segments = initial;
    let mut distances = nearest_distances(points, &segments);
    let mut previous_mean: Option<f64> = None;
    let mut r = params.r_min;
    let mut previous_sigma = f64::INFINITY;
    let mut last_sigma = floor;
    for _ in 0..params.max_iterations {
        let sigma = robust_spread(&distances)
            .min(params.sigma_shrink * previous_sigma)
            .max(floor);
        let annealing = sigma < previous_sigma * (1.0 - 1e-9) && previous_sigma.is_finite();
        previous_sigma = sigma;
        last_sigma = sigma;
        let (next, stats, next_distances) = iteration(points, &segments, sigma, floor, params);
        segments = next;
        distances = next_distances;
        r = stats.r;
        let mean_distance = stats.mean_distance;
        result.iterations.push(stats);
        if segments.is_empty() {
            break;
        }
        if let Some(previous) = previous_mean
            && !annealing
            && (mean_distance - previous).abs() <= params.tolerance * previous
        {
            result.converged = true;
            break;
        }
        previous_mean = Some(mean_distance);
    }
    Iterated {
        segments,
        r,
        sigma: last_sigma,
    }
}

/// One iteration at deviation `sigma`: 1) EMSF, 2) the line-segment split at a scale from
/// the deviation and the density of points, 3) EMSF, 4) merge. Returns the segments, the
/// iteration's statistics and every point's distance to its nearest segment.
fn iteration(
    points: &[Vector2<f64>],
    segments: &[Segment],
    sigma: f64,
    floor: f64,
    params: &EmPolygonParams,
) -> (Vec<Segment>, IterationStats, Vec<f64>) {
    let segments = emsf::emsf_step(points, segments, sigma, params.outlier_sigmas).0;
    // The split scale: from the deviation, and long enough that a subsegment holds
    // `subsegment_points` points at the mean density along the segments.
    let length: f64 = segments.iter().map(Segment::length).sum();
    let support: usize = segments.iter().map(|s| s.support).sum();
    let spacing = if support > 0 {
        length / support as f64
    } else {
        0.0
    };
    let r = (params.split_scale * sigma)
        .max(0.5 * params.subsegment_points * spacing)
        .clamp(params.r_min, params.r_max);
    let (split, report) = split::split(points, &segments, r, |supports| {
        support_threshold(supports, params)
    });
    let after_split = split.len();
    let segments = emsf::emsf_step(points, &split, sigma, params.outlier_sigmas).0;
    let scales = merge::MergeScales {
        angle: params.merge_angle_deg.to_radians(),
        sigma: floor,
        r,
    };
    let (segments, merges) = merge::merge_all(segments, &scales);
    // Model selection inside the loop too, so that the split's new pieces must earn their
    // place every iteration: the segment count then settles (a fixed point) instead of
    // growing until the distance stops changing.
    let (segments, pruned) = if params.select_segments {
        select::prune(points, segments, 3.0 * sigma)
    } else {
        (segments, 0)
    };
    let distances = nearest_distances(points, &segments);
    let stats = IterationStats {
        sigma,
        r,
        support_threshold: report.threshold,
        subsegments: (report.subsegments, report.removed),
        after_split,
        merges,
        pruned,
        segments: segments.len(),
        mean_distance: mean(&distances).unwrap_or(f64::INFINITY),
    };
    (segments, stats, distances)
}

/// The support threshold `C` of the split: a fraction of the median positive subsegment
/// support, at least `min_support`.
fn support_threshold(supports: &[usize], params: &EmPolygonParams) -> f64 {
    let positive: Vec<f64> = supports
        .iter()
        .filter(|&&s| s > 0)
        .map(|&s| s as f64)
        .collect();
    (params.support_fraction * median(&positive).unwrap_or(0.0)).max(params.min_support)
}

/// After the iterations: lines pulled off their wall by far points put back, empty
/// stretches removed, the selections (`select_segments`, `max_mean_distance`), ends joined
/// into polylines (dropping segments the joins collapse).
fn finish(
    points: &[Vector2<f64>],
    iterated: Iterated,
    params: &EmPolygonParams,
) -> (Vec<Segment>, Vec<Polyline>, usize) {
    // The last EMSF trims each segment to all of its support set, which can stretch it over
    // a gap to a few stray points: a last split removes the subsegments whose square holds
    // no point at all.
    // First a last EMSF whose M-step ignores points farther than 3 sigma, so that lines
    // pulled off their wall by far points lie on it again.
    let Iterated { segments, r, sigma } = iterated;
    let segments = emsf::emsf_step(points, &segments, sigma, Some(3.0)).0;
    let segments = split::split(points, &segments, r, |_| 0.0).0;
    let (segments, pruned) = if params.select_segments {
        select::prune(points, segments, 3.0 * sigma)
    } else {
        (segments, 0)
    };
    let join = params.join_scale * r;
    let Some(max_mean) = params.max_mean_distance else {
        let (joined, polylines) = join_ends(segments, join);
        return (joined, polylines, pruned);
    };
    // Joining moves ends and can drop a segment, which moves the mean a little: the bound
    // the removal works to is lowered by any excess after joining (and a thousandth of the
    // bound, so that a micrometre of excess is not chased) and the removal redone.
    let mut bound = max_mean;
    let mut attempt = 0;
    loop {
        let (kept, removed) = select::prune_to_mean(points, segments.clone(), bound);
        let (joined, polylines) = join_ends(kept, join);
        let excess = mean(&nearest_distances(points, &joined)).unwrap_or(0.0) - max_mean;
        attempt += 1;
        if excess <= 0.0 || removed == 0 || attempt == 4 {
            return (joined, polylines, pruned + removed);
        }
        bound -= excess + 1e-3 * max_mean;
    }
}

/// Ends closer than `join` joined into polylines; segments the joins collapse are dropped
/// and the ordering redone.
fn join_ends(mut segments: Vec<Segment>, join: f64) -> (Vec<Segment>, Vec<Polyline>) {
    loop {
        let mut joined = segments.clone();
        let polylines = polyline::order(&mut joined, join);
        let collapsed: Vec<bool> = joined
            .iter()
            .zip(&segments)
            .map(|(j, s)| j.length() < (0.25 * s.length()).max(MIN_LENGTH))
            .collect();
        if !collapsed.contains(&true) {
            return (joined, polylines);
        }
        segments = segments
            .into_iter()
            .zip(collapsed)
            .filter_map(|(s, c)| (!c).then_some(s))
            .collect();
    }
}

/// The segments' supports and the points' distance statistics into `result`.
fn summarize(points: &[Vector2<f64>], mut segments: Vec<Segment>, result: &mut PolygonMap) {
    let assignment = emsf::assign(points, &segments);
    for s in &mut segments {
        s.support = 0;
    }
    for &j in &assignment.owner {
        if let Some(s) = segments.get_mut(j as usize) {
            s.support += 1;
        }
    }
    let distances = assignment.distance;
    result.mean_distance = mean(&distances);
    result.median_distance = median(&distances);
    result.compression_ratio =
        (!segments.is_empty()).then(|| points.len() as f64 / (2 * segments.len()) as f64);
    result.segments = segments;
}

/// A segment from `a` to `b` given as `(x, y)` pairs, for the tests of the submodules.
#[cfg(test)]
fn seg(a: (f64, f64), b: (f64, f64)) -> Segment {
    Segment::new(Vector2::new(a.0, a.1), Vector2::new(b.0, b.1))
}

#[cfg(test)]
mod tests;
