//! Laser odometry: each scan matched to the previous one by robust point-to-line ICP, with the
//! wheel odometry between them as a Gaussian prior; the match replaces that odometry.
//!
//! A front-end of any estimator (`[data.laser_odometry]` in the `slam` config): the estimator
//! sees ordinary [`PoseIncrement`]s, one per matched scan, whose covariance is the posterior of
//! the match. The match (Gauss-Newton on `sum rho(n_i . (R p_i + t - q_i)) + prior`):
//!
//! - the reference points `q_i` are the previous scan's, each with the normal of the line
//!   through it and its neighbours in beam order;
//! - each current point `p_i` is paired with its nearest reference point within a gate; the
//!   residual is the distance along that point's normal; `rho` is the Cauchy loss; the
//!   nearest point is found exactly, in a uniform grid laid out densely over the reference
//!   points (gridded again only when the local map changes, at a key scan);
//! - coarse to fine: the gate and the Cauchy scale start 4 times wider and halve at each
//!   iteration;
//! - the points' information is divided by `information_divisor`: neighbouring beams see the
//!   same surfaces, so their errors are not independent, and a covariance from independent
//!   points is overconfident.
//!
//! A match is refused (and the odometry kept) when too few points pair up, the normal equations
//! are singular, or the match lies more than `max_mahalanobis` (squared) from the odometry under
//! the odometry's covariance.
//!
//! The prior's covariance is the compound of the covariances of the motions between the two
//! scans, or, with `interval_noise`, an [`OdometryNoise`] model applied to the whole interval
//! (`configs/carmen-walls.toml`: ten times the default deviations, a weak prior, as real
//! odometry slips and drifts beyond its model).

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use slam_core::{Pose2, Pose3, grid, wrap_angle};

use crate::error::{Result, SensorError};
use crate::events::{Dataset, Event, EventStream, Pump, Step, TimedEvent};
use crate::odometry::{OdometryNoise, PoseIncrement};

/// Settings of the laser odometry; `Default` gives values that work on indoor SICK logs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaserOdometryParams {
    /// A current point pairs with a reference point within this distance, m.
    pub gate: f64,
    /// Deviation of a point from its partner's line, m (the Cauchy scale).
    pub point_sigma: f64,
    /// Readings farther than this are not used, m.
    pub max_range: f64,
    /// Gauss-Newton iterations at most.
    pub iterations: usize,
    /// Paired points needed for a match.
    pub min_matched: usize,
    /// The points' information is divided by this (their errors are correlated). On the Intel
    /// lab log (`cargo run --release -p slam-sensors --example laser_odometry_nees`) the
    /// matches' NEES has mean 20 / median 11 with 1, 5.0 / 3.2 with the default 4, and
    /// 2.8 / 2.0 with 10 (chi-square(3): 3 / 2.4); with 10 the heading error grows from 0.57
    /// to 0.65 degrees per match (the prior weighs more) and IPSLAM on the log did worse.
    pub information_divisor: f64,
    /// A match farther than this squared Mahalanobis distance from the odometry (under the
    /// odometry's covariance) is refused; the default is the 99.9 % point of chi-square(3).
    pub max_mahalanobis: f64,
    /// Scans in the local map each scan is matched to: the last `local_map_scans` key scans,
    /// placed by their matched poses. 1 matches each scan to the previous key scan only; with
    /// the keyframe thresholds at 0 (the defaults) that is the previous scan, as before the
    /// local map existed (the IPSLAM figures of BENCHMARKS.md were taken so).
    /// `configs/carmen-walls.toml` uses 50 key scans 0.2 m / 0.1 rad apart: less drift on the
    /// simulated world and on the real buildings.
    pub local_map_scans: usize,
    /// A scan becomes a key scan (joins the local map) when it lies this far from the last
    /// key scan, m ...
    pub keyframe_distance: f64,
    /// ... or has turned this much from it, rad.
    pub keyframe_angle: f64,
    /// A current point pairs only with a reference point whose normal lies within this angle
    /// of its own (both from their scan neighbours), degrees; 90 turns the check off.
    pub max_normal_angle_deg: f64,
    /// A point's normal is fitted to its neighbours (two beams on each side) within `gate`,
    /// or within this many metres per metre of the point's range where that is farther
    /// (0: `gate` only). Beams fan out with range: at 1 degree spacing, neighbours on a wall
    /// 9 m away lie 0.16 m apart head-on and farther at a slant, so with `gate` alone (0.3 m)
    /// far points get no normal and are left out of the reference, and the corridor walls
    /// ahead, which hold the heading best, are lost. 0.1 accepts neighbours two beams away
    /// on walls seen at up to 70 degrees of incidence at 1-degree spacing. On the four Radish
    /// logs with noisy odometry (seed 1), laser odometry alone with a local map of 50 key
    /// scans ends 0.35-0.91 m from the reference (SE(2)-aligned ATE) with 0.1, against
    /// 0.66-2.69 m with 0 (BENCHMARKS.md, "Real buildings").
    pub normal_reach_per_metre: f64,
    /// Extra starting headings on each side of the odometry's, at most (0: the odometry's
    /// only); a match tries only those within three standard deviations of the odometry's
    /// heading (none after a short, straight motion) ...
    pub heading_starts: usize,
    /// ... this far apart, degrees; the match is the lowest of the minima reached.
    pub heading_start_step_deg: f64,
    /// When the best match pairs fewer than half of the scan's points (the odometry's
    /// heading was further off than the starts reach, as after a fast spin on the spot), the
    /// starts go on outwards, up to this many on each side in all (still within three
    /// standard deviations of the odometry's heading), and the lowest minimum of all wins;
    /// 0 (the default): no retry. A well-paired match never retries, so the cost is paid
    /// only where a match is poor.
    pub retry_heading_starts: usize,
    /// With starting headings tried: a minimum more than one start step in heading from the
    /// best one whose objective (a negative log-likelihood) is within this of the best's
    /// makes the match ambiguous. Its covariance then grows by the outer product of that
    /// minimum's offset from the best, so that the filter, with its map, decides between
    /// the two turns instead of taking the scans' choice as sure. 0 (the default): off.
    pub ambiguity_gap: f64,
    /// The odometry's noise over one scan interval, applied to the compound of the motions
    /// between two scans (as MRPT's CARMEN import does); unset (the default): the compound
    /// of the motions' own covariances. A log that records odometry 15 times per scan (the
    /// Radish logs' own `ODOM` lines) otherwise gets a prior about 4 times too narrow, as the
    /// motion model's deviations grow with the motion and 15 short motions add in quadrature.
    /// With it, a refused match's odometry goes out as one increment with this covariance.
    pub interval_noise: Option<OdometryNoise>,
}

impl Default for LaserOdometryParams {
    fn default() -> Self {
        LaserOdometryParams {
            gate: 0.3,
            point_sigma: 0.05,
            max_range: 20.0,
            iterations: 30,
            min_matched: 30,
            information_divisor: 4.0,
            max_mahalanobis: 16.27,
            local_map_scans: 1,
            keyframe_distance: 0.0,
            keyframe_angle: 0.0,
            max_normal_angle_deg: 90.0,
            normal_reach_per_metre: 0.0,
            heading_starts: 0,
            heading_start_step_deg: 2.0,
            retry_heading_starts: 0,
            ambiguity_gap: 0.0,
            interval_noise: None,
        }
    }
}

impl LaserOdometryParams {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<()> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let checks = [
            (positive(self.gate), "gate > 0"),
            (positive(self.point_sigma), "point_sigma > 0"),
            (positive(self.max_range), "max_range > 0"),
            (self.iterations >= 1, "iterations >= 1"),
            (self.min_matched >= 3, "min_matched >= 3"),
            (
                positive(self.information_divisor),
                "information_divisor > 0",
            ),
            (positive(self.max_mahalanobis), "max_mahalanobis > 0"),
            (
                positive(self.max_normal_angle_deg) && self.max_normal_angle_deg <= 90.0,
                "0 < max_normal_angle_deg <= 90",
            ),
            (
                self.normal_reach_per_metre.is_finite() && self.normal_reach_per_metre >= 0.0,
                "normal_reach_per_metre >= 0",
            ),
            (
                positive(self.heading_start_step_deg),
                "heading_start_step_deg > 0",
            ),
            (
                self.ambiguity_gap.is_finite() && self.ambiguity_gap >= 0.0,
                "ambiguity_gap >= 0",
            ),
            (self.local_map_scans >= 1, "local_map_scans >= 1"),
            (
                self.keyframe_distance.is_finite() && self.keyframe_distance >= 0.0,
                "keyframe_distance >= 0",
            ),
            (
                self.keyframe_angle.is_finite() && self.keyframe_angle >= 0.0,
                "keyframe_angle >= 0",
            ),
        ];
        if let Some((_, what)) = checks.iter().find(|(ok, _)| !ok) {
            return Err(SensorError::InvalidArgument(format!(
                "laser odometry: {what}"
            )));
        }
        if let Some(noise) = &self.interval_noise {
            noise.validate().map_err(|e| match e {
                SensorError::InvalidArgument(message) => SensorError::InvalidArgument(format!(
                    "laser odometry: interval_noise: {message}"
                )),
                other => other,
            })?;
        }
        Ok(())
    }
}

/// A scan matched to a reference scan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanMatch {
    /// The current scan's sensor pose in the reference scan's sensor frame.
    pub reference_from_current: Pose2,
    /// Its covariance (the posterior of points and prior).
    pub covariance: Matrix3<f64>,
    /// Points paired at the last iteration.
    pub matched: usize,
    /// Whether the match came from the starts beyond `heading_starts` that a poor match
    /// tries ([`LaserOdometryParams::retry_heading_starts`]).
    pub retried: bool,
    /// Whether another minimum came nearly as low and widened the covariance
    /// ([`LaserOdometryParams::ambiguity_gap`]).
    pub ambiguous: bool,
}

/// What [`laser_odometry`] did (or a [`laser_odometry_stream`] has done so far).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LaserOdometryReport {
    /// Scans whose preceding odometry was replaced by a match.
    pub matched: usize,
    /// Of those, matches found by the wider starts of a retry
    /// ([`LaserOdometryParams::retry_heading_starts`]).
    pub retried: usize,
    /// Of those, matches with another minimum nearly as low, whose covariance was widened
    /// ([`LaserOdometryParams::ambiguity_gap`]).
    pub ambiguous: usize,
    /// Scans whose match was refused; their odometry was kept.
    pub refused: usize,
    /// Ground-truth or reference poses left out because they fall between two scans: the
    /// estimate there still lacks the motion held back for the next match, so comparing them
    /// would count that motion as error.
    pub truth_between_scans: usize,
}

/// One line for a run's summary: `laser odometry: M scans matched, R matches refused
/// (odometry kept)`, and how many true or reference poses between scans were not compared.
///
/// ```
/// use slam_sensors::laser_odometry::LaserOdometryReport;
/// let report = LaserOdometryReport {
///     matched: 5,
///     retried: 0,
///     ambiguous: 0,
///     refused: 1,
///     truth_between_scans: 0,
/// };
/// assert_eq!(
///     report.to_string(),
///     "laser odometry: 5 scans matched, 1 matches refused (odometry kept)"
/// );
/// let report = LaserOdometryReport { retried: 2, ambiguous: 1, ..report };
/// assert_eq!(
///     report.to_string(),
///     "laser odometry: 5 scans matched (2 from wider starting headings, 1 ambiguous), 1 \
///      matches refused (odometry kept)"
/// );
/// ```
impl std::fmt::Display for LaserOdometryReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "laser odometry: {} scans matched", self.matched)?;
        let mut notes = Vec::new();
        if self.retried > 0 {
            notes.push(format!("{} from wider starting headings", self.retried));
        }
        if self.ambiguous > 0 {
            notes.push(format!("{} ambiguous", self.ambiguous));
        }
        if !notes.is_empty() {
            write!(f, " ({})", notes.join(", "))?;
        }
        write!(f, ", {} matches refused (odometry kept)", self.refused)?;
        match self.truth_between_scans {
            0 => Ok(()),
            n => write!(
                f,
                "; {n} true or reference poses between scans not compared (the estimate moves \
                 at scans)"
            ),
        }
    }
}

/// `(-v_y, v_x)`.
fn perp(v: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(-v.y, v.x)
}

/// Reference points (in beam order, sensor frame) with the unit normals of the lines through
/// them and their neighbours ([`normals`]); points without a normal are left out.
fn with_normals(
    points: &[Vector2<f64>],
    params: &LaserOdometryParams,
) -> Vec<(Vector2<f64>, Vector2<f64>)> {
    points
        .iter()
        .zip(normals(points, params.gate, params.normal_reach_per_metre))
        .filter_map(|(p, n)| n.map(|n| (*p, n)))
        .collect()
}

/// The unit normal at each point of a scan (in beam order, sensor frame): of the line through
/// the point and its neighbours (two beams on each side) within `reach`, or within
/// `reach_per_metre` times the point's range where that is farther; `None` with fewer than
/// two such neighbours.
fn normals(points: &[Vector2<f64>], reach: f64, reach_per_metre: f64) -> Vec<Option<Vector2<f64>>> {
    let mut out = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        let lo = i.saturating_sub(2);
        let hi = (i + 3).min(points.len());
        let reach = reach.max(reach_per_metre * p.norm());
        let near: Vec<&Vector2<f64>> = points[lo..hi]
            .iter()
            .filter(|q| (*q - p).norm() <= reach)
            .collect();
        if near.len() < 3 {
            out.push(None);
            continue;
        }
        let mean = near.iter().fold(Vector2::zeros(), |a, q| a + *q) / near.len() as f64;
        let scatter = near.iter().fold(Matrix2::zeros(), |a, q| {
            let d = *q - mean;
            a + d * d.transpose()
        });
        let eigen = scatter.symmetric_eigen();
        let smallest = if eigen.eigenvalues[0] <= eigen.eigenvalues[1] {
            0
        } else {
            1
        };
        let normal: Vector2<f64> = eigen.eigenvectors.column(smallest).into_owned();
        out.push((normal.norm().is_finite() && normal.norm() > 0.0).then(|| normal.normalize()));
    }
    out
}

/// Side of a [`Grid`] cell, m: fine enough that the nearest point of a converged match is
/// found within the query's own cell and its eight neighbours.
const GRID_CELL: f64 = 0.05;

/// Most cells a [`Grid`] lays out densely, per point and in all; a wider extent gets
/// coarser cells (the search is exact for any cell size, only its speed changes). Laying out
/// the cells costs their number: a sparse log's key scans, far apart, would otherwise make a
/// grid mostly of empty cells at every scan.
const MAX_GRID_CELLS_PER_POINT: usize = 32;
const MAX_GRID_CELLS: usize = 1 << 22;

/// A uniform grid over reference points for nearest-neighbour queries, laid out densely over
/// the points' bounding box: the points sorted by cell (in their own order within a cell) and
/// each cell's range of them, so that a query costs an index, not a hash, per cell visited
/// (most of a match's queries are far from any point in its first, wide-gated iterations).
struct Grid {
    /// The cell side asked for; `cell` is coarser for a wide extent.
    fine_cell: f64,
    cell: f64,
    /// The cell coordinates of cell 0 (the bounding box's lowest corner).
    origin: (i64, i64),
    /// Columns and rows of cells.
    width: i64,
    height: i64,
    /// Cell `c`'s points are `points[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    /// The points and their unit normals, sorted by cell (contiguous for the search).
    points: Vec<(Vector2<f64>, Vector2<f64>)>,
    /// Scratch of [`Grid::fill`], kept for the next fill (a local map is gridded again at
    /// every key scan): the points in their given order, their cells and the sort's cursors.
    unsorted: Vec<(Vector2<f64>, Vector2<f64>)>,
    keys: Vec<(i64, i64)>,
    next: Vec<u32>,
}

impl Grid {
    fn new(points: Vec<(Vector2<f64>, Vector2<f64>)>, cell: f64) -> Self {
        let mut grid = Grid {
            fine_cell: cell,
            cell,
            origin: (0, 0),
            width: 0,
            height: 0,
            starts: vec![0],
            points: Vec::new(),
            unsorted: Vec::new(),
            keys: Vec::new(),
            next: Vec::new(),
        };
        grid.fill(points);
        grid
    }

    /// Grids `points` in place of the previous ones, reusing the memory.
    fn fill(&mut self, points: impl IntoIterator<Item = (Vector2<f64>, Vector2<f64>)>) {
        self.unsorted.clear();
        self.unsorted.extend(points);
        let mut cell = self.fine_cell;
        loop {
            self.keys.clear();
            self.keys
                .extend(self.unsorted.iter().map(|(p, _)| grid::cell_of(p, cell)));
            let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
            for &(x, y) in &self.keys {
                lo = (lo.0.min(x), lo.1.min(y));
                hi = (hi.0.max(x), hi.1.max(y));
            }
            // Wide enough to hold any extent (far-apart points make the i64 span overflow).
            let (width, height) = if self.keys.is_empty() {
                (0, 0)
            } else {
                (
                    hi.0 as i128 - lo.0 as i128 + 1,
                    hi.1 as i128 - lo.1 as i128 + 1,
                )
            };
            let most =
                (MAX_GRID_CELLS_PER_POINT * self.unsorted.len()).clamp(1 << 12, MAX_GRID_CELLS);
            if width as f64 * height as f64 > most as f64 {
                cell *= 2.0;
                continue;
            }
            let (width, height) = (width as i64, height as i64);
            let cells = width * height;
            // A counting sort: each cell's points keep their order.
            self.starts.clear();
            self.starts.resize(cells as usize + 1, 0);
            let index = |(x, y): (i64, i64)| ((y - lo.1) * width + (x - lo.0)) as usize;
            for &key in &self.keys {
                self.starts[index(key) + 1] += 1;
            }
            for c in 1..self.starts.len() {
                self.starts[c] += self.starts[c - 1];
            }
            self.next.clear();
            self.next.extend_from_slice(&self.starts);
            self.points.clear();
            self.points
                .resize(self.keys.len(), (Vector2::zeros(), Vector2::zeros()));
            for (point, &key) in self.unsorted.iter().zip(&self.keys) {
                let slot = &mut self.next[index(key)];
                self.points[*slot as usize] = *point;
                *slot += 1;
            }
            self.cell = cell;
            self.origin = lo;
            self.width = width;
            self.height = height;
            return;
        }
    }

    /// The range in `points` of cell `(x, y)` (empty outside the bounding box).
    fn cell_range(&self, x: i64, y: i64) -> std::ops::Range<usize> {
        let (column, row) = (x - self.origin.0, y - self.origin.1);
        if column < 0 || row < 0 || column >= self.width || row >= self.height {
            return 0..0;
        }
        let c = (row * self.width + column) as usize;
        self.starts[c] as usize..self.starts[c + 1] as usize
    }

    /// The nearest point within `reach` of `z` whose normal passes `accept`: the cells are
    /// searched in square rings around `z`'s, and the search stops once the best point is
    /// nearer than any cell of the next ring can hold.
    fn nearest(
        &self,
        z: &Vector2<f64>,
        reach: f64,
        accept: impl Fn(&Vector2<f64>) -> bool,
    ) -> Option<&(Vector2<f64>, Vector2<f64>)> {
        let (cx, cy) = grid::cell_of(z, self.cell);
        let rings = grid::ceil_i64(reach / self.cell);
        let mut best: Option<(f64, usize)> = None;
        let visit = |x: i64, y: i64, best: &mut Option<(f64, usize)>| {
            let range = self.cell_range(x, y);
            let first = range.start;
            for (k, (point, normal)) in self.points[range].iter().enumerate() {
                let d = (point - z).norm_squared();
                if d <= reach * reach && best.is_none_or(|(b, _)| d < b) && accept(normal) {
                    *best = Some((d, first + k));
                }
            }
        };
        for ring in 0..=rings {
            for (x, y) in grid::ring_cells(cx, cy, ring) {
                visit(x, y, &mut best);
            }
            // Every point outside the square of cells searched so far is at least as far from
            // `z` as the square's nearest side (less a margin for rounding).
            let cleared = grid::clearance(z, self.cell, (cx, cy), ring) - 1e-9;
            if best.is_some_and(|(b, _)| cleared > 0.0 && b <= cleared * cleared) {
                break;
            }
        }
        best.map(|(_, i)| &self.points[i])
    }
}

/// Matches `current` to `reference` (each in its own sensor frame), starting at and pulled
/// towards `guess` (the current sensor pose in the reference sensor frame) with covariance
/// `guess_covariance`. `Ok(None)` when too few points pair up or the normal equations are
/// singular; an error for a non-finite or non-positive-definite `guess_covariance`.
///
/// ```
/// use slam_core::{Pose2, nalgebra::{Matrix3, Vector2}};
/// use slam_sensors::laser_odometry::{LaserOdometryParams, match_scans};
/// // Two walls of a corner seen from (0, 0) and from 0.2 m further along x.
/// let corner = |x0: f64| -> Vec<Vector2<f64>> {
///     let mut points: Vec<Vector2<f64>> =
///         (0..60).map(|i| Vector2::new(4.0 - x0, -2.0 + 0.05 * i as f64)).collect();
///     points.extend((0..60).map(|i| Vector2::new(1.0 - x0 + 0.05 * i as f64, 1.0)));
///     points
/// };
/// let guess = Pose2::new(0.15, 0.03, 0.01);
/// let prior = Matrix3::from_diagonal(&[1.0, 1.0, 1.0].into());
/// let matched = match_scans(&corner(0.0), &corner(0.2), &guess, &prior,
///     &LaserOdometryParams::default()).unwrap().unwrap();
/// assert!((matched.reference_from_current.x - 0.2).abs() < 2e-3);
/// assert!(matched.reference_from_current.y.abs() < 2e-3);
/// assert!(matched.reference_from_current.theta.abs() < 1e-3);
/// ```
pub fn match_scans(
    reference: &[Vector2<f64>],
    current: &[Vector2<f64>],
    guess: &Pose2,
    guess_covariance: &Matrix3<f64>,
    params: &LaserOdometryParams,
) -> Result<Option<ScanMatch>> {
    params.validate()?;
    let reference = Grid::new(with_normals(reference, params), GRID_CELL);
    match_to_points(&reference, current, guess, guess_covariance, params)
}

/// [`match_scans`] with the reference given as a grid of points with unit normals (e.g. a
/// local map of several scans, all in one frame): `current`'s pose in that frame. With
/// `heading_starts > 0` the same objective is minimised from the guess and from the guess
/// turned by `±k * heading_start_step_deg` (k = 1..=K: the turns within three standard
/// deviations of the guess's heading, at most `heading_starts`), and the lowest
/// minimum wins: a large turn whose odometry heading is a few degrees off no longer ends in a
/// nearby local minimum. A match that pairs fewer than half of `current`'s points (or none)
/// tries the starts beyond those, out to `retry_heading_starts` (within the same three
/// standard deviations), and the lowest minimum of all wins.
fn match_to_points(
    reference: &Grid,
    current: &[Vector2<f64>],
    guess: &Pose2,
    guess_covariance: &Matrix3<f64>,
    params: &LaserOdometryParams,
) -> Result<Option<ScanMatch>> {
    slam_core::ensure_finite(guess.to_vector().as_slice(), "scan match guess")?;
    slam_core::ensure_finite(guess_covariance.as_slice(), "scan match prior")?;
    let prior_information = guess_covariance.try_inverse().ok_or_else(|| {
        SensorError::InvalidArgument("scan match prior covariance is singular".into())
    })?;
    let problem = MatchProblem {
        current,
        current_normals: if params.max_normal_angle_deg < 90.0 {
            normals(current, params.gate, params.normal_reach_per_metre)
        } else {
            vec![None; current.len()]
        },
        min_normal_cosine: params.max_normal_angle_deg.to_radians().cos(),
        guess,
        prior_information,
        params,
        grid: reference,
    };
    let step = params.heading_start_step_deg.to_radians();
    let heading_sigma = guess_covariance[(2, 2)].max(0.0).sqrt();
    let reach = (3.0 * heading_sigma / step).floor() as usize;
    let starts = params.heading_starts.min(reach);
    let (mut best, screened) = problem.lowest_minimum(0..=starts, step);
    // A match that pairs fewer than half of the scan's points began too far from the truth
    // (the odometry's heading further off than the starts reach): the starts go on outwards.
    let mut retried = false;
    let retry_starts = params.retry_heading_starts.min(reach);
    let poor = best.as_ref().is_none_or(|b| 2 * b.matched < current.len());
    if poor
        && retry_starts > starts
        && let (Some(wider), _) = problem.lowest_minimum(starts + 1..=retry_starts, step)
        && best.as_ref().is_none_or(|b| wider.cost < b.cost)
    {
        best = Some(wider);
        retried = true;
    }
    let Some(best) = best else {
        return Ok(None);
    };
    let Some(mut covariance) = best.information.try_inverse() else {
        return Ok(None);
    };
    // Another minimum nearly as low: the scans cannot tell the two turns apart, so the match
    // says so, and the filter's map decides.
    let mut ambiguous = false;
    if params.ambiguity_gap > 0.0 && starts > 0 {
        // Unless the retry replaced it, `best` went on from the lowest screened minimum.
        let spread = problem.ambiguity(&best, screened, !retried, step, params.ambiguity_gap);
        ambiguous = spread != Matrix3::zeros();
        covariance += spread;
    }
    Ok(Some(ScanMatch {
        reference_from_current: best.pose,
        covariance: (covariance + covariance.transpose()) * 0.5,
        matched: best.matched,
        retried,
        ambiguous,
    }))
}

/// Iterations every starting heading runs before the best goes on: the gate is at its final
/// width from the third.
const SCREENING_ITERATIONS: usize = 3;

/// One scan-to-points match: the objective (robust point-to-line terms and the odometry
/// prior) and the nearest-neighbour grid of the reference, built once and shared by the
/// starts and the gates.
struct MatchProblem<'a> {
    current: &'a [Vector2<f64>],
    current_normals: Vec<Option<Vector2<f64>>>,
    min_normal_cosine: f64,
    guess: &'a Pose2,
    prior_information: Matrix3<f64>,
    params: &'a LaserOdometryParams,
    grid: &'a Grid,
}

/// A local minimum of a [`MatchProblem`].
#[derive(Clone)]
struct Minimum {
    pose: Pose2,
    information: Matrix3<f64>,
    matched: usize,
    /// The objective at `pose` at the final gate (unpaired points cost as at the gate).
    cost: f64,
}

impl<'a> MatchProblem<'a> {
    /// The lowest minimum from the guess turned by `k` start steps, for each `k` in `ks`, on
    /// both sides (`k = 0`: the guess itself), and every start's screened minimum. A single
    /// start (the guess alone) runs all the iterations; otherwise every start runs until the
    /// gate has narrowed to its final width, and the best one by the objective there goes on
    /// to convergence.
    fn lowest_minimum(
        &self,
        ks: std::ops::RangeInclusive<usize>,
        step: f64,
    ) -> (Option<Minimum>, Vec<Minimum>) {
        let iterations = self.params.iterations;
        let single = *ks.start() == 0 && *ks.end() == 0;
        let screening = if single {
            iterations
        } else {
            iterations.min(SCREENING_ITERATIONS)
        };
        let mut screened: Vec<Minimum> = Vec::new();
        for k in ks {
            for sign in if k == 0 { &[1.0][..] } else { &[1.0, -1.0][..] } {
                let g = self.guess;
                let start = Pose2::new(g.x, g.y, g.theta + sign * k as f64 * step);
                screened.extend(self.minimise(start, 0, screening));
            }
        }
        // The first of equal objectives, as the starts' order gives them.
        let lowest = screened
            .iter()
            .enumerate()
            .fold(None, |lowest: Option<(usize, f64)>, (i, m)| match lowest {
                Some((_, cost)) if cost <= m.cost => lowest,
                _ => Some((i, m.cost)),
            })
            .map(|(i, _)| i);
        let best = match lowest {
            Some(i) if single || iterations <= SCREENING_ITERATIONS => Some(screened[i].clone()),
            Some(i) => self.minimise(screened[i].pose, SCREENING_ITERATIONS, iterations),
            None => None,
        };
        (best, screened)
    }

    /// The spread of the minima that compete with `best`: each screened minimum more than
    /// `step` in heading from a lower one goes on to convergence, and each minimum reached
    /// more than `step` from `best` with an objective within `gap` of `best`'s adds, once,
    /// the outer product of its offset from `best` (as if it lay one standard deviation
    /// away). With `from_lowest`, `best` is the lowest screened minimum's convergence, which
    /// is not run again.
    fn ambiguity(
        &self,
        best: &Minimum,
        mut screened: Vec<Minimum>,
        from_lowest: bool,
        step: f64,
        gap: f64,
    ) -> Matrix3<f64> {
        screened.sort_by(|a, b| a.cost.total_cmp(&b.cost));
        let mut distinct: Vec<Pose2> = Vec::new();
        for m in &screened {
            if distinct
                .iter()
                .all(|d| wrap_angle(d.theta - m.pose.theta).abs() > step)
            {
                distinct.push(m.pose);
            }
        }
        let mut spread = Matrix3::zeros();
        let mut counted: Vec<f64> = Vec::new();
        for start in distinct.into_iter().skip(usize::from(from_lowest)) {
            let Some(m) = self.minimise(start, SCREENING_ITERATIONS, self.params.iterations) else {
                continue;
            };
            let offset = Vector3::new(
                m.pose.x - best.pose.x,
                m.pose.y - best.pose.y,
                wrap_angle(m.pose.theta - best.pose.theta),
            );
            // Two starts that end in one minimum count it once.
            let new = counted.iter().all(|&c| (c - offset.z).abs() > step);
            if offset.z.abs() > step && m.cost < best.cost + gap && new {
                counted.push(offset.z);
                spread += offset * offset.transpose();
            }
        }
        spread
    }

    /// Gauss-Newton from `start`, iterations `first..end`: the gate narrows from 4 to 1
    /// times `params.gate` over the first three.
    fn minimise(&self, start: Pose2, first: usize, end: usize) -> Option<Minimum> {
        let params = self.params;
        let mut pose = start;
        let mut last: Option<(Matrix3<f64>, usize)> = None;
        // The objective of the last iteration, summed once the loop ends: the prior's term,
        // the loss's scale and weight, and each point's residual (the gate if unpaired).
        let mut objective = (0.0, 1.0, 1.0);
        let mut residuals = Vec::with_capacity(self.current.len());
        for iteration in first..end {
            let level = iteration.min(2);
            let widening = 4.0 * 0.5f64.powi(level as i32);
            let gate = params.gate * widening;
            let scale = params.point_sigma * widening;
            let weight = 1.0 / (scale * scale * params.information_divisor);
            let rotation = pose.rotation();
            let offset = Vector3::new(
                pose.x - self.guess.x,
                pose.y - self.guess.y,
                wrap_angle(pose.theta - self.guess.theta),
            );
            let mut h = self.prior_information;
            let mut g = self.prior_information * offset;
            objective = (
                0.5 * offset.dot(&(self.prior_information * offset)),
                scale,
                weight,
            );
            residuals.clear();
            let mut matched = 0;
            for (p, own_normal) in self.current.iter().zip(&self.current_normals) {
                let arm = rotation * p;
                let z = arm + pose.translation();
                let own_normal = own_normal.map(|n| rotation * n);
                let compatible = |n: &Vector2<f64>| {
                    own_normal.is_none_or(|own| own.dot(n).abs() >= self.min_normal_cosine)
                };
                let Some((q, normal)) = self.grid.nearest(&z, gate, compatible) else {
                    residuals.push(gate);
                    continue;
                };
                matched += 1;
                let e = normal.dot(&(z - q));
                residuals.push(e);
                let robust = 1.0 / (1.0 + (e / scale).powi(2));
                let j = Vector3::new(normal.x, normal.y, normal.dot(&perp(&arm)));
                h += j * j.transpose() * (robust * weight);
                g += j * (e * robust * weight);
            }
            if matched < params.min_matched {
                return None;
            }
            let cholesky = h.cholesky()?;
            let step = -cholesky.solve(&g);
            last = Some((h, matched));
            pose = Pose2::new(pose.x + step.x, pose.y + step.y, pose.theta + step.z);
            if widening == 1.0 && step.xy().norm() < 1e-6 && step.z.abs() < 1e-7 {
                break;
            }
        }
        let (information, matched) = last?;
        let (prior_cost, scale, weight) = objective;
        let rho = |e: f64| 0.5 * weight * scale * scale * (1.0 + (e / scale).powi(2)).ln();
        let cost = residuals.iter().fold(prior_cost, |cost, &e| cost + rho(e));
        Some(Minimum {
            pose,
            information,
            matched,
            cost,
        })
    }
}

/// The planar part `(x, y, yaw)` of a laser mount; an error for a tilted laser.
fn planar_mount(robot_from_sensor: &Pose3) -> Result<Pose2> {
    let level = 1e-3;
    if robot_from_sensor.pitch.abs() > level || robot_from_sensor.roll.abs() > level {
        return Err(SensorError::InvalidArgument(format!(
            "laser odometry needs a level laser; this one has pitch {:.3} and roll {:.3} rad",
            robot_from_sensor.pitch, robot_from_sensor.roll
        )));
    }
    let t = robot_from_sensor.translation;
    Ok(Pose2::new(t.x, t.y, robot_from_sensor.yaw))
}

/// `outer ⊕ inner ⊕ ⊖outer` and its Jacobian with respect to `inner`: a motion expressed in
/// the frame `outer` maps, e.g. a sensor increment to the robot's with `outer` the mount.
fn conjugate(outer: &Pose2, inner: &Pose2) -> (Pose2, Matrix3<f64>) {
    let (moved, _, d_moved_d_inner) = outer.compose_with_jacobians(inner);
    let (result, d_result_d_moved, _) = moved.compose_with_jacobians(&outer.inverse());
    (result, d_result_d_moved * d_moved_d_inner)
}

/// The compound of `motions` from the identity and its covariance (eq. 26 applied in turn).
fn compound(motions: &[TimedEvent]) -> Result<(Pose2, Matrix3<f64>)> {
    let mut pose = Pose2::identity();
    let mut covariance = slam_core::nalgebra::DMatrix::zeros(3, 3);
    for timed in motions {
        if let Event::Motion(motion) = &timed.event {
            let prediction = motion.predict(&pose)?;
            covariance = prediction.propagate_covariance(&covariance)?;
            pose = prediction.pose;
        }
    }
    Ok((pose, Matrix3::from_iterator(covariance.iter().copied())))
}

/// Replaces the motion between consecutive scans by the match of the later scan to the
/// earlier one (see the module documentation): the motion events since the previous scan
/// become one [`PoseIncrement`] at the scan's time, just before it. Where the match is refused
/// the motion events stay. Observations, images and GPS fixes need the pose at their own time:
/// motion pending before one of them is written unchanged and the next scan starts a new chain.
/// Scans from mounts other than the previous scan's (a second laser) also start a new chain.
///
/// The estimate then moves only at scans, so ground-truth and reference poses between two
/// scans are left out ([`LaserOdometryReport::truth_between_scans`] counts them): compared with
/// an estimate that still lacks the motion held back for the next match, they would count
/// that motion as error (on the built-in world, where the truth comes at every step and a scan
/// at every other, `configs/carmen-walls.toml` with seed 1 scored an ATE of 0.049 m and a pose
/// NEES of 3.2 per degree of freedom with them, 0.035 m and 0.13 without). Truth at a scan's
/// own time follows the scan's increment; a reference that is never at a scan's time (a bag's
/// reference topic on its own clock) gives no ATE with laser odometry.
///
/// This is [`laser_odometry_stream`] collected.
pub fn laser_odometry(
    dataset: Dataset,
    params: &LaserOdometryParams,
) -> Result<(Dataset, LaserOdometryReport)> {
    let (stream, counts) = laser_odometry_stream(EventStream::from_dataset(dataset), params)?;
    let dataset = stream.into_dataset()?;
    Ok((dataset, counts.report()))
}

/// How many scans a [`laser_odometry_stream`] has matched and refused so far: a handle that
/// can be read while and after the stream is consumed (clones share the counts).
#[derive(Clone, Debug, Default)]
pub struct LaserOdometryCounts {
    matched: Arc<AtomicUsize>,
    retried: Arc<AtomicUsize>,
    ambiguous: Arc<AtomicUsize>,
    refused: Arc<AtomicUsize>,
    truth_between_scans: Arc<AtomicUsize>,
}

impl LaserOdometryCounts {
    /// The counts so far.
    pub fn report(&self) -> LaserOdometryReport {
        LaserOdometryReport {
            matched: self.matched.load(Ordering::Relaxed),
            retried: self.retried.load(Ordering::Relaxed),
            ambiguous: self.ambiguous.load(Ordering::Relaxed),
            refused: self.refused.load(Ordering::Relaxed),
            truth_between_scans: self.truth_between_scans.load(Ordering::Relaxed),
        }
    }
}

/// [`laser_odometry`] one event at a time: the same events in the same order. Motion events
/// are held back from one scan (or observation, image, GPS fix) to the next, as the match
/// needs them; other events pass through at once. Invalid parameters are an error of this
/// call; a tilted laser or a failed match an `Err` item.
///
/// ```
/// use slam_sensors::laser_odometry::{LaserOdometryParams, laser_odometry_stream};
/// use slam_sensors::sim::{World, simulate_stream};
/// let mut world = World::default_world();
/// world.robot.waypoints.truncate(1);
/// world.camera = None;
/// let run = simulate_stream(&world, 1).unwrap();
/// let (stream, counts) =
///     laser_odometry_stream(run.events, &LaserOdometryParams::default()).unwrap();
/// let first: Vec<_> = stream.take(40).collect::<Result<_, _>>().unwrap();
/// assert_eq!(first.len(), 40);
/// assert!(counts.report().matched > 0);
/// ```
pub fn laser_odometry_stream(
    stream: EventStream,
    params: &LaserOdometryParams,
) -> Result<(EventStream, LaserOdometryCounts)> {
    params.validate()?;
    let counts = LaserOdometryCounts::default();
    let info = stream.info.clone();
    let skipped = stream.skip_counter();
    let matcher = Matcher {
        input: stream,
        params: params.clone(),
        counts: counts.clone(),
        pending: Vec::new(),
        chain: None,
    };
    let events = EventStream::new(info, Pump::new(matcher)).with_skipped(skipped);
    Ok((events, counts))
}

/// The state of a [`laser_odometry_stream`].
struct Matcher {
    input: EventStream,
    params: LaserOdometryParams,
    counts: LaserOdometryCounts,
    /// Motion events since the previous scan, and the ground truth among them (held with the
    /// motion: the estimate reaches their time only when the motion goes out).
    pending: Vec<TimedEvent>,
    /// The chain of matched scans since the last break (none before the first scan).
    chain: Option<Chain>,
}

/// A chain of matched scans from one laser: poses in the chain's own frame (the first scan's
/// sensor frame), and the local map.
struct Chain {
    /// The laser's planar mount.
    robot_from_sensor: Pose2,
    /// The previous scan's sensor pose.
    chain_from_previous: Pose2,
    /// The key scans: sensor pose and points with normals in the sensor frame, oldest first.
    key_scans: VecDeque<KeyScan>,
    /// The key scans' points in the chain frame, gridded when a match first needs them after
    /// the key scans change (most scans are not key scans).
    local_map: Grid,
    /// Whether `local_map` is out of date.
    local_map_stale: bool,
}

/// A key scan: its sensor pose in the chain frame, and its points with their normals in its
/// sensor frame.
type KeyScan = (Pose2, Vec<(Vector2<f64>, Vector2<f64>)>);

impl Chain {
    /// A chain starting at `points`, the first scan.
    fn new(
        robot_from_sensor: Pose2,
        points: &[Vector2<f64>],
        params: &LaserOdometryParams,
    ) -> Self {
        let mut chain = Chain {
            robot_from_sensor,
            chain_from_previous: Pose2::identity(),
            key_scans: VecDeque::new(),
            local_map: Grid::new(Vec::new(), GRID_CELL),
            local_map_stale: true,
        };
        chain.add_key_scan(Pose2::identity(), points, params);
        chain
    }

    /// Adds a key scan at `chain_from_sensor`, dropping the oldest beyond the map's size.
    fn add_key_scan(
        &mut self,
        chain_from_sensor: Pose2,
        points: &[Vector2<f64>],
        params: &LaserOdometryParams,
    ) {
        self.key_scans
            .push_back((chain_from_sensor, with_normals(points, params)));
        while self.key_scans.len() > params.local_map_scans {
            self.key_scans.pop_front();
        }
        self.local_map_stale = true;
    }

    /// Whether a scan at `chain_from_sensor` is far enough from the last key scan to be one.
    fn is_key(&self, chain_from_sensor: &Pose2, params: &LaserOdometryParams) -> bool {
        self.key_scans.back().is_none_or(|(last, _)| {
            let moved = last.between(chain_from_sensor);
            moved.translation().norm() >= params.keyframe_distance
                || moved.theta.abs() >= params.keyframe_angle
        })
    }

    /// The key scans' points and normals in the chain frame, gridded.
    fn local_map(&mut self) -> &Grid {
        if self.local_map_stale {
            let points = self.key_scans.iter().flat_map(|(pose, points)| {
                // `pose.transform_point`, its rotation computed once per key scan.
                let (rotation, translation) = (pose.rotation(), pose.translation());
                points
                    .iter()
                    .map(move |(p, n)| (rotation * p + translation, rotation * n))
            });
            self.local_map.fill(points);
            self.local_map_stale = false;
        }
        &self.local_map
    }
}

impl Step for Matcher {
    fn step(&mut self, out: &mut VecDeque<TimedEvent>) -> Result<bool> {
        let Some(timed) = self.input.next() else {
            out.extend(self.pending.drain(..));
            return Ok(false);
        };
        let timed = timed?;
        match &timed.event {
            Event::Motion(_) => self.pending.push(timed),
            Event::Scan {
                scan,
                robot_from_sensor,
            } => {
                let mount = planar_mount(robot_from_sensor)?;
                let points: Vec<Vector2<f64>> = scan
                    .points()
                    .into_iter()
                    .filter(|p| p.range <= self.params.max_range)
                    .map(|p| p.position)
                    .collect();
                self.on_scan(timed.time, mount, &points, out)?;
                out.push_back(timed);
            }
            Event::Observations(_) | Event::Image { .. } | Event::Gps(_) => {
                if !self.pending.is_empty() {
                    out.extend(self.pending.drain(..));
                    self.chain = None;
                }
                out.push_back(timed);
            }
            // Held behind the motion (the estimate at its time lacks that motion until the
            // next scan's match); passed on at once when no motion is held.
            Event::GroundTruth { .. } if holds_motion(&self.pending) => self.pending.push(timed),
            Event::GroundTruth { .. } => out.push_back(timed),
        }
        Ok(true)
    }
}

impl Matcher {
    /// Matches a scan to the chain's local map and writes the increment (or the pending
    /// motion, if refused) to `out`; a scan from another mount starts a new chain.
    fn on_scan(
        &mut self,
        time: f64,
        mount: Pose2,
        points: &[Vector2<f64>],
        out: &mut VecDeque<TimedEvent>,
    ) -> Result<()> {
        let params = &self.params;
        let chain = match self.chain.as_mut() {
            Some(chain)
                if chain.robot_from_sensor.to_vector() == mount.to_vector()
                    && holds_motion(&self.pending) =>
            {
                chain
            }
            _ => {
                out.extend(self.pending.drain(..));
                self.chain = Some(Chain::new(mount, points, params));
                return Ok(());
            }
        };
        let (odometry, odometry_covariance) = interval_odometry(&self.pending, params)?;
        match match_to_local_map(chain, points, &odometry, &odometry_covariance, params)? {
            Some((increment, chain_from_current, matched)) => {
                out.push_back(TimedEvent {
                    time,
                    event: Event::Motion(Box::new(increment)),
                });
                release_truth_at(&mut self.pending, &self.counts, time, out);
                self.counts.matched.fetch_add(1, Ordering::Relaxed);
                if matched.retried {
                    self.counts.retried.fetch_add(1, Ordering::Relaxed);
                }
                if matched.ambiguous {
                    self.counts.ambiguous.fetch_add(1, Ordering::Relaxed);
                }
                chain.chain_from_previous = chain_from_current;
                if chain.is_key(&chain_from_current, params) {
                    chain.add_key_scan(chain_from_current, points, params);
                }
            }
            None => {
                if params.interval_noise.is_some() {
                    out.push_back(TimedEvent {
                        time,
                        event: Event::Motion(Box::new(PoseIncrement::new(
                            odometry,
                            odometry_covariance,
                        )?)),
                    });
                    release_truth_at(&mut self.pending, &self.counts, time, out);
                } else {
                    out.extend(self.pending.drain(..));
                }
                self.counts.refused.fetch_add(1, Ordering::Relaxed);
                // The local map no longer fits the pose chain: start afresh here.
                self.chain = Some(Chain::new(mount, points, params));
            }
        }
        Ok(())
    }
}

/// Whether motion is held back for the next scan's match.
fn holds_motion(pending: &[TimedEvent]) -> bool {
    pending
        .iter()
        .any(|timed| matches!(timed.event, Event::Motion(_)))
}

/// Empties the held events once their motion has gone out as one increment at the scan's
/// `time`: the truth of that same time follows the increment; earlier truth is left out (and
/// counted), since the estimate never was at the pose it gives.
fn release_truth_at(
    pending: &mut Vec<TimedEvent>,
    counts: &LaserOdometryCounts,
    time: f64,
    out: &mut VecDeque<TimedEvent>,
) {
    for timed in pending.drain(..) {
        if !matches!(timed.event, Event::GroundTruth { .. }) {
            continue;
        }
        if timed.time == time {
            out.push_back(timed);
        } else {
            counts.truth_between_scans.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The odometry between two scans (the compound of `pending`) and its covariance: the
/// compound's own, or `params.interval_noise` applied to the whole interval.
fn interval_odometry(
    pending: &[TimedEvent],
    params: &LaserOdometryParams,
) -> Result<(Pose2, Matrix3<f64>)> {
    let (odometry, covariance) = compound(pending)?;
    let covariance = match &params.interval_noise {
        Some(noise) => noise.covariance(&odometry),
        None => covariance,
    };
    // A floor keeps the prior invertible for a robot that stood still.
    let floor = Matrix3::from_diagonal(&Vector3::new(1e-8, 1e-8, 1e-10));
    Ok((odometry, covariance + floor))
}

/// The robot increment from the previous scan to `current` by matching `current` to the
/// chain's local map, the `odometry` since the previous scan (with its covariance) as the
/// prior; with the current scan's sensor pose in the chain frame. `None` if the match is
/// refused.
fn match_to_local_map(
    chain: &mut Chain,
    current: &[Vector2<f64>],
    odometry: &Pose2,
    odometry_covariance: &Matrix3<f64>,
    params: &LaserOdometryParams,
) -> Result<Option<(PoseIncrement, Pose2, ScanMatch)>> {
    let robot_from_sensor = chain.robot_from_sensor;
    let odometry = *odometry;
    let odometry_covariance = *odometry_covariance;
    let (sensor_motion, d_sensor_motion) = conjugate(&robot_from_sensor.inverse(), &odometry);
    let (guess, _, d_guess) = chain
        .chain_from_previous
        .compose_with_jacobians(&sensor_motion);
    let d_guess = d_guess * d_sensor_motion;
    let guess_covariance = d_guess * odometry_covariance * d_guess.transpose();
    let Some(matched) = match_to_points(
        chain.local_map(),
        current,
        &guess,
        &guess_covariance,
        params,
    )?
    else {
        return Ok(None);
    };
    let chain_from_current = matched.reference_from_current;
    let (matched_motion, _, d_matched_motion) = chain
        .chain_from_previous
        .between_with_jacobians(&chain_from_current);
    let (increment, d_increment) = conjugate(&robot_from_sensor, &matched_motion);
    let d_increment = d_increment * d_matched_motion;
    let covariance = d_increment * matched.covariance * d_increment.transpose();
    let difference = Vector3::new(
        increment.x - odometry.x,
        increment.y - odometry.y,
        wrap_angle(increment.theta - odometry.theta),
    );
    let Some(information) = odometry_covariance.try_inverse() else {
        return Ok(None);
    };
    if difference.dot(&(information * difference)) > params.max_mahalanobis {
        return Ok(None);
    }
    let covariance = (covariance + covariance.transpose()) * 0.5;
    Ok(Some((
        PoseIncrement::new(increment, covariance)?,
        chain_from_current,
        matched,
    )))
}

#[cfg(test)]
mod tests;
