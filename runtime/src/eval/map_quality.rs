//! Map quality without ground truth, for any run with laser scans and walls: how well the
//! wall map explains the scans placed by the estimated poses, and how much of it is drawn
//! twice.
//!
//! - **Scan points to walls**: every valid reading of every scan (a fixed-size uniform sample
//!   of them, [`ScanSample`], so that memory does not grow with the log), placed by the pose
//!   estimated at its time, and its distance to the nearest wall segment; the median and the
//!   90th percentile. Clutter, people and glass fall far from every wall and only move the
//!   upper percentiles; a wall map that is blurred, shifted or rotated moves the median.
//! - **Doubled length**: the part of a wall feature's length that another wall feature
//!   overlaps within [`DOUBLED_DISTANCE_M`] and [`DOUBLED_ANGLE_DEG`] (a corridor wall
//!   mapped twice), as a fraction of the total wall length. Also given for pairs that run the
//!   same way only (for M-space walls: the same free side), which leaves out the two faces of
//!   a thin wall seen from the rooms on either side.

use serde::Serialize;
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{Pose2, Pose3, Shape, grid};
use slam_sensors::LaserScan;

/// A second wall this close to a wall (at both ends of their overlap) doubles it, m.
pub const DOUBLED_DISTANCE_M: f64 = 0.10;
/// ... and at most this far from parallel, degrees.
pub const DOUBLED_ANGLE_DEG: f64 = 5.0;

/// Scan readings kept for the map quality figures, by default.
pub const DEFAULT_SAMPLE_SIZE: usize = 50_000;

/// A uniform sample of fixed size of all valid scan readings of a run (reservoir sampling,
/// deterministic), each kept in the robot frame with its time, to be placed later by the pose
/// of that time.
///
/// ```
/// use slam_core::{Pose2, Pose3};
/// use slam_runtime::eval::ScanSample;
/// use slam_sensors::LaserScan;
/// let scan = LaserScan::new(-1.0, 0.01, vec![2.0; 201], 0.0, 30.0).unwrap();
/// let mut sample = ScanSample::new(100);
/// for t in 0..10 {
///     sample.add(t as f64, &scan, &Pose3::identity());
/// }
/// assert_eq!(sample.seen(), 2010);
/// assert_eq!(sample.len(), 100);
/// // Placed by the pose of each reading's time: all 2 m from the origin.
/// let world = sample.placed(|_| Some(Pose2::identity()));
/// assert!(world.iter().all(|p| (p.norm() - 2.0).abs() < 1e-9));
/// ```
#[derive(Clone, Debug)]
pub struct ScanSample {
    capacity: usize,
    seen: u64,
    state: u64,
    points: Vec<(f64, Vector2<f64>)>,
}

impl Default for ScanSample {
    fn default() -> Self {
        ScanSample::new(DEFAULT_SAMPLE_SIZE)
    }
}

impl ScanSample {
    /// An empty sample that keeps at most `capacity` readings.
    pub fn new(capacity: usize) -> Self {
        ScanSample {
            capacity,
            seen: 0,
            state: 0x9E37_79B9_7F4A_7C15,
            points: Vec::with_capacity(capacity.min(DEFAULT_SAMPLE_SIZE)),
        }
    }

    /// Valid readings offered so far.
    pub fn seen(&self) -> u64 {
        self.seen
    }

    /// Readings kept.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether no reading is kept.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Offers every valid reading of `scan` (a laser at `robot_from_sensor`) taken at `time`.
    pub fn add(&mut self, time: f64, scan: &LaserScan, robot_from_sensor: &Pose3) {
        let rotation = robot_from_sensor.rotation();
        for point in scan.points() {
            let in_robot = robot_from_sensor.translation
                + rotation * Vector3::new(point.position.x, point.position.y, 0.0);
            self.offer(time, in_robot.xy());
        }
    }

    /// Reservoir sampling (Vitter's algorithm R) with a fixed-seed xorshift generator.
    fn offer(&mut self, time: f64, point: Vector2<f64>) {
        self.seen += 1;
        if self.points.len() < self.capacity {
            self.points.push((time, point));
            return;
        }
        self.state ^= self.state << 13;
        self.state ^= self.state >> 7;
        self.state ^= self.state << 17;
        let slot = self.state % self.seen;
        if let Some(kept) = self.points.get_mut(slot as usize) {
            *kept = (time, point);
        }
    }

    /// The kept readings: each one's time and its place in the robot frame.
    pub(crate) fn readings(&self) -> &[(f64, Vector2<f64>)] {
        &self.points
    }

    /// The kept readings in the world frame, each placed by `pose_at(time)`; readings without
    /// a pose are left out.
    pub fn placed(&self, pose_at: impl Fn(f64) -> Option<Pose2>) -> Vec<Vector2<f64>> {
        self.points
            .iter()
            .filter_map(|(time, point)| pose_at(*time).map(|pose| pose.transform_point(point)))
            .collect()
    }
}

/// The map quality figures (see the module documentation).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MapQuality {
    /// Wall features scored.
    pub walls: usize,
    /// Their total length, m.
    pub wall_length_m: f64,
    /// Length of walls overlapped by a second wall (within 10 cm and 5 degrees), m.
    pub doubled_length_m: f64,
    /// `doubled_length_m / wall_length_m`.
    pub doubled_fraction: f64,
    /// The part of `doubled_length_m` where the two walls run the same way (the same free
    /// side for M-space walls: not the two faces of a thin wall), m.
    pub doubled_same_side_length_m: f64,
    /// `doubled_same_side_length_m / wall_length_m`.
    pub doubled_same_side_fraction: f64,
    /// Scan readings the distances are taken from (a uniform sample of all of them).
    pub scan_points: usize,
    /// Median distance of a scan reading to the nearest wall, m.
    pub median_point_to_wall_m: Option<f64>,
    /// 90th percentile of the same, m.
    pub p90_point_to_wall_m: Option<f64>,
}

/// The figures for `walls` (segments in the world frame) and `points` (scan readings in the
/// world frame).
///
/// ```
/// use slam_core::nalgebra::Vector2;
/// use slam_runtime::eval::map_quality;
/// let v = |x: f64, y: f64| Vector2::new(x, y);
/// // A 4 m wall drawn twice, 5 cm apart, over its first 2 m.
/// let walls = [(v(0.0, 0.0), v(4.0, 0.0)), (v(0.0, 0.05), v(2.0, 0.05))];
/// let points = [v(1.0, 0.02), v(3.0, -0.01), v(3.5, 0.5)];
/// let quality = map_quality(&walls, &points);
/// assert_eq!(quality.walls, 2);
/// assert!((quality.wall_length_m - 6.0).abs() < 1e-12);
/// assert!((quality.doubled_length_m - 4.0).abs() < 1e-12); // 2 m of each
/// assert_eq!(quality.doubled_same_side_length_m, quality.doubled_length_m);
/// assert!((quality.median_point_to_wall_m.unwrap() - 0.02).abs() < 1e-12);
/// ```
pub fn map_quality(walls: &[(Vector2<f64>, Vector2<f64>)], points: &[Vector2<f64>]) -> MapQuality {
    let walls: Vec<(Vector2<f64>, Vector2<f64>)> = walls
        .iter()
        .copied()
        .filter(|(a, b)| a.iter().chain(b.iter()).all(|v| v.is_finite()))
        .collect();
    let wall_length_m: f64 = walls.iter().map(|(a, b)| (b - a).norm()).sum();
    let doubled = |same_side| -> f64 {
        (0..walls.len())
            .map(|i| doubled_length(&walls, i, same_side))
            .sum()
    };
    let (doubled_length_m, doubled_same_side_length_m) = (doubled(false), doubled(true));
    let fraction = |length: f64| {
        if wall_length_m > 0.0 {
            length / wall_length_m
        } else {
            0.0
        }
    };
    let mut distances: Vec<f64> = if walls.is_empty() {
        Vec::new()
    } else {
        let grid = SegmentGrid::new(&walls, 1.0);
        points.iter().map(|p| grid.distance(p)).collect()
    };
    distances.sort_by(f64::total_cmp);
    let percentile = |q: f64| super::nearest_rank(&distances, q);
    MapQuality {
        walls: walls.len(),
        wall_length_m,
        doubled_length_m,
        doubled_fraction: fraction(doubled_length_m),
        doubled_same_side_length_m,
        doubled_same_side_fraction: fraction(doubled_same_side_length_m),
        scan_points: distances.len(),
        median_point_to_wall_m: percentile(0.5),
        p90_point_to_wall_m: percentile(0.9),
    }
}

/// The wall segments of the estimator's confirmed features (what the map quality figures and
/// the `relocalize` stage measure against).
pub fn confirmed_wall_segments(
    estimator: &dyn slam_core::Estimator<slam_core::Pose2>,
) -> Vec<(Vector2<f64>, Vector2<f64>)> {
    let shapes: Vec<Shape> = estimator
        .map()
        .iter()
        .filter(|(id, _)| super::confirmed(estimator, *id))
        .filter_map(|(_, feature)| feature.shape())
        .collect();
    wall_segments(&shapes)
}

/// The wall segments of shapes (other kinds are left out).
pub fn wall_segments<'a>(
    shapes: impl IntoIterator<Item = &'a Shape>,
) -> Vec<(Vector2<f64>, Vector2<f64>)> {
    shapes
        .into_iter()
        .filter_map(|shape| match shape {
            Shape::Wall { start, end } => Some((*start, *end)),
            _ => None,
        })
        .collect()
}

/// Distance from `p` to the segment `a`-`b`.
fn point_to_segment(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let ab = b - a;
    let length_squared = ab.norm_squared();
    let t = if length_squared > 0.0 {
        ((p - a).dot(&ab) / length_squared).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).norm()
}

/// The length of wall `i` that another wall overlaps within the doubling tolerances (running
/// the same way only, if `same_side`): the union of the overlaps, measured along wall `i`.
fn doubled_length(walls: &[(Vector2<f64>, Vector2<f64>)], i: usize, same_side: bool) -> f64 {
    let (a, b) = walls[i];
    let length = (b - a).norm();
    if length == 0.0 {
        return 0.0;
    }
    let tangent = (b - a) / length;
    let normal = Vector2::new(-tangent.y, tangent.x);
    let cos_limit = DOUBLED_ANGLE_DEG.to_radians().cos();
    let mut intervals: Vec<(f64, f64)> = Vec::new();
    for (j, (c, d)) in walls.iter().enumerate() {
        let other = d - c;
        let other_length = other.norm();
        if j == i || other_length == 0.0 {
            continue;
        }
        let cos = other.dot(&tangent) / other_length;
        if (if same_side { cos } else { cos.abs() }) < cos_limit {
            continue;
        }
        let along = |p: &Vector2<f64>| (p - a).dot(&tangent);
        let (s0, s1) = (along(c), along(d));
        let (lo, hi) = (s0.min(s1).max(0.0), s0.max(s1).min(length));
        if hi <= lo {
            continue;
        }
        // The other wall's offset from this one at both ends of the overlap.
        let offset_at = |s: f64| {
            let t = (s - s0) / (s1 - s0);
            (c + other * t - a).dot(&normal).abs()
        };
        if offset_at(lo) <= DOUBLED_DISTANCE_M && offset_at(hi) <= DOUBLED_DISTANCE_M {
            intervals.push((lo, hi));
        }
    }
    union_length(intervals)
}

/// Total length of the union of intervals.
fn union_length(mut intervals: Vec<(f64, f64)>) -> f64 {
    intervals.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut total = 0.0;
    let mut current: Option<(f64, f64)> = None;
    for (lo, hi) in intervals {
        current = match current {
            Some((clo, chi)) if lo <= chi => Some((clo, chi.max(hi))),
            Some((clo, chi)) => {
                total += chi - clo;
                Some((lo, hi))
            }
            None => Some((lo, hi)),
        };
    }
    total + current.map_or(0.0, |(lo, hi)| hi - lo)
}

/// Wall segments binned by the grid cells their bounding boxes touch, for nearest-wall
/// queries; a query searches rings of cells outwards until no closer wall can remain.
pub(crate) struct SegmentGrid<'a> {
    cell: f64,
    walls: &'a [(Vector2<f64>, Vector2<f64>)],
    cells: rustc_hash::FxHashMap<(i64, i64), Vec<usize>>,
    /// Bounds of the occupied cells.
    lo: (i64, i64),
    hi: (i64, i64),
}

impl<'a> SegmentGrid<'a> {
    /// A grid of `cell`-sized squares over `walls`.
    pub(crate) fn new(walls: &'a [(Vector2<f64>, Vector2<f64>)], cell: f64) -> Self {
        let mut cells: rustc_hash::FxHashMap<(i64, i64), Vec<usize>> = Default::default();
        let key = |v: f64| grid::floor_i64(v / cell);
        let (mut lo, mut hi) = ((i64::MAX, i64::MAX), (i64::MIN, i64::MIN));
        for (k, (a, b)) in walls.iter().enumerate() {
            let (x0, x1) = (key(a.x.min(b.x)), key(a.x.max(b.x)));
            let (y0, y1) = (key(a.y.min(b.y)), key(a.y.max(b.y)));
            lo = (lo.0.min(x0), lo.1.min(y0));
            hi = (hi.0.max(x1), hi.1.max(y1));
            for x in x0..=x1 {
                for y in y0..=y1 {
                    let centre = Vector2::new((x as f64 + 0.5) * cell, (y as f64 + 0.5) * cell);
                    // Only cells the segment passes near (within the cell's half diagonal).
                    if point_to_segment(&centre, a, b) <= cell * std::f64::consts::FRAC_1_SQRT_2 {
                        cells.entry((x, y)).or_default().push(k);
                    }
                }
            }
        }
        SegmentGrid {
            cell,
            walls,
            cells,
            lo,
            hi,
        }
    }

    /// Distance from `p` to the nearest wall.
    fn distance(&self, p: &Vector2<f64>) -> f64 {
        let centre = self.key(p);
        let mut best = f64::INFINITY;
        let reach = (self.hi.0 - self.lo.0)
            .max(self.hi.1 - self.lo.1)
            .max((centre.0 - self.lo.0).abs())
            .max((centre.0 - self.hi.0).abs())
            .max((centre.1 - self.lo.1).abs())
            .max((centre.1 - self.hi.1).abs());
        for ring in 0..=reach {
            for (x, y) in grid::ring_cells(centre.0, centre.1, ring) {
                for &k in self.cells.get(&(x, y)).into_iter().flatten() {
                    let (a, b) = &self.walls[k];
                    best = best.min(point_to_segment(p, a, b));
                }
            }
            if best <= self.clearance(p, centre, ring) {
                break;
            }
        }
        best
    }

    /// The cell of `p`.
    fn key(&self, p: &Vector2<f64>) -> (i64, i64) {
        grid::cell_of(p, self.cell)
    }

    /// How near a wall outside the square of cells within `ring` of `p`'s cell `centre` can
    /// be: the distance to the square's nearest side (less a margin for rounding). A wall is
    /// binned in every cell it passes through, so one that none of those cells holds lies
    /// outside the square.
    fn clearance(&self, p: &Vector2<f64>, centre: (i64, i64), ring: i64) -> f64 {
        grid::clearance(p, self.cell, centre, ring) - 1e-9
    }
}

impl SegmentGrid<'_> {
    /// The wall nearest to `p` if it lies within `reach` (m), with its distance.
    pub(crate) fn nearest_within(&self, p: &Vector2<f64>, reach: f64) -> Option<(usize, f64)> {
        let centre = self.key(p);
        let rings = grid::ceil_i64(reach / self.cell) + 1;
        let mut best: Option<(usize, f64)> = None;
        for ring in 0..=rings {
            for (x, y) in grid::ring_cells(centre.0, centre.1, ring) {
                for &k in self.cells.get(&(x, y)).into_iter().flatten() {
                    let (a, b) = &self.walls[k];
                    let distance = point_to_segment(p, a, b);
                    if distance <= reach && best.is_none_or(|(_, d)| distance < d) {
                        best = Some((k, distance));
                    }
                }
            }
            if best.map_or(reach, |(_, d)| d) <= self.clearance(p, centre, ring) {
                break;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64) -> Vector2<f64> {
        Vector2::new(x, y)
    }

    #[test]
    fn the_grid_finds_the_nearest_wall_like_a_full_search() {
        let walls: Vec<_> = (0..40)
            .map(|k| {
                let a = v((k * 7 % 23) as f64 - 10.0, (k * 11 % 19) as f64 - 9.0);
                let angle = k as f64 * 0.7;
                (a, a + v(angle.cos(), angle.sin()) * (0.3 + (k % 5) as f64))
            })
            .collect();
        let grid = SegmentGrid::new(&walls, 1.0);
        for k in 0..500 {
            let p = v(
                (k * 37 % 101) as f64 * 0.4 - 20.0,
                (k * 53 % 97) as f64 * 0.4 - 19.0,
            );
            let full = walls
                .iter()
                .map(|(a, b)| point_to_segment(&p, a, b))
                .fold(f64::INFINITY, f64::min);
            assert!((grid.distance(&p) - full).abs() < 1e-12, "at {p:?}");
            // Within a reach: the same wall's distance, or none when the nearest is farther.
            for reach in [0.1, 0.5, 2.0] {
                match grid.nearest_within(&p, reach) {
                    Some((k, d)) => {
                        assert!((d - full).abs() < 1e-12, "at {p:?}");
                        let (a, b) = &walls[k];
                        assert!((point_to_segment(&p, a, b) - full).abs() < 1e-12);
                    }
                    None => assert!(full > reach, "at {p:?}: {full} within {reach}"),
                }
            }
        }
    }

    #[test]
    fn walls_apart_or_across_are_not_doubled() {
        let far = [(v(0.0, 0.0), v(4.0, 0.0)), (v(0.0, 0.2), v(4.0, 0.2))];
        assert_eq!(map_quality(&far, &[]).doubled_length_m, 0.0);
        let across = [(v(0.0, 0.0), v(4.0, 0.0)), (v(2.0, -1.0), v(2.0, 1.0))];
        assert_eq!(map_quality(&across, &[]).doubled_length_m, 0.0);
        // 10 degrees apart, crossing: not doubled.
        let angle = 10f64.to_radians();
        let tilted = [
            (v(0.0, 0.0), v(4.0, 0.0)),
            (v(0.0, 0.0), v(4.0 * angle.cos(), 4.0 * angle.sin())),
        ];
        assert_eq!(map_quality(&tilted, &[]).doubled_length_m, 0.0);
        // End to end: not doubled.
        let chained = [(v(0.0, 0.0), v(2.0, 0.0)), (v(2.0, 0.0), v(4.0, 0.0))];
        assert_eq!(map_quality(&chained, &[]).doubled_length_m, 0.0);
    }

    #[test]
    fn a_wall_inside_another_doubles_its_own_length_on_both() {
        let inner = [(v(0.0, 0.0), v(10.0, 0.0)), (v(6.0, 0.03), v(3.0, 0.03))];
        let quality = map_quality(&inner, &[]);
        assert!((quality.doubled_length_m - 6.0).abs() < 1e-12);
        assert!((quality.doubled_fraction - 6.0 / 13.0).abs() < 1e-12);
        // The inner wall runs the other way: the two faces of a thin wall.
        assert_eq!(quality.doubled_same_side_length_m, 0.0);
        assert_eq!(quality.doubled_same_side_fraction, 0.0);
    }

    #[test]
    fn no_walls_give_no_distances() {
        let quality = map_quality(&[], &[v(1.0, 1.0)]);
        assert_eq!(quality.median_point_to_wall_m, None);
        assert_eq!(quality.walls, 0);
    }

    #[test]
    fn the_sample_keeps_every_reading_until_full_then_a_uniform_share() {
        let scan = LaserScan::new(0.0, 0.01, vec![1.0; 100], 0.0, 30.0).unwrap();
        let mut sample = ScanSample::new(1000);
        for t in 0..100 {
            sample.add(t as f64, &scan, &Pose3::identity());
        }
        assert_eq!(sample.len(), 1000);
        // Each tenth of the run holds about a tenth of the sample.
        let early = sample.points.iter().filter(|(t, _)| *t < 10.0).count();
        assert!((60..=140).contains(&early), "{early}");
    }
}
