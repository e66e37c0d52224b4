//! Loop consistency without ground truth or a map: how well the scans of places the robot
//! came back to agree with each other, once placed by a path.
//!
//! Every kept scan reading ([`ScanSample`]) is placed by the pose of its time. For up to
//! [`REVISIT_MAX_MEASURED`] of them, evenly spread over the sample, the neighbours are the
//! readings within [`REVISIT_RADIUS_M`] that were taken at least [`REVISIT_GAP_M`] of travel
//! away along the path (so on another pass, not by the scans just before or after it). Where at least [`REVISIT_MIN_NEIGHBOURS`] such neighbours lie
//! along a line (the larger eigenvalue of their scatter at least [`REVISIT_LINE_RATIO`] times
//! the smaller: a wall or another straight surface), the reading's distance to that line is
//! one measurement. Their median is small when the passes register onto each other and grows
//! with every misplaced pass; it needs neither walls nor reference poses, so it scores the
//! estimate and a dataset's reference poses alike (a corrected log's poses are another
//! SLAM system's estimate, not independent truth).
//!
//! It cannot see an error that every pass shares (a map bent the same way each time) nor one
//! in a place visited once.

use rustc_hash::FxHashMap;
use serde::Serialize;
use slam_core::nalgebra::Vector2;
use slam_core::{Pose2, grid};

use super::{ScanSample, nearest_rank};

/// Readings closer than this along the path are not each other's neighbours, m.
pub const REVISIT_GAP_M: f64 = 10.0;
/// A reading's neighbours lie within this distance of it, m.
pub const REVISIT_RADIUS_M: f64 = 0.3;
/// Fewest neighbours that define a surface.
pub const REVISIT_MIN_NEIGHBOURS: usize = 6;
/// At most this many readings, evenly spread over the sample, are measured (each against
/// all the kept readings): enough for the median, and cheap (the sample holds 50,000).
pub const REVISIT_MAX_MEASURED: usize = 5_000;
/// Neighbours lie along a line when their scatter's larger eigenvalue is at least this many
/// times the smaller (deviation along at least 4 times the deviation across).
pub const REVISIT_LINE_RATIO: f64 = 16.0;

/// How well the passes over the same places agree (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RevisitConsistency {
    /// Measured readings with a line of neighbours from another pass (the measurements).
    pub readings: usize,
    /// Median distance of those readings to their neighbours' line, m.
    pub median_m: f64,
    /// Mean of those distances, m.
    pub mean_m: f64,
    /// 90th percentile of those distances, m.
    pub p90_m: f64,
}

/// The loop consistency of the sampled scan readings placed by `path` (poses by time, in
/// time order; a reading is placed by the pose of its time exactly, and left out when the
/// path has none). `None` when no reading has a line of neighbours from another pass (a run
/// that never comes back, or no scans).
///
/// ```
/// use slam_core::{Pose2, Pose3};
/// use slam_runtime::eval::{ScanSample, revisit_consistency};
/// use slam_sensors::LaserScan;
/// // A wall 2 m ahead, scanned on the way out and again after a 40 m loop.
/// let ranges = (0..201).map(|k| 2.0 / (-0.5 + 0.005 * k as f64).cos()).collect();
/// let scan = LaserScan::new(-0.5, 0.5, ranges, 0.0, 30.0).unwrap();
/// let mut sample = ScanSample::new(10_000);
/// sample.add(0.0, &scan, &Pose3::identity());
/// sample.add(1.0, &scan, &Pose3::identity());
/// let path_of = |shift: f64| {
///     vec![
///         (0.0, Pose2::identity()),
///         (0.5, Pose2::new(20.0, 0.0, 0.0)),
///         (1.0, Pose2::new(-shift, 0.0, 0.0)),
///     ]
/// };
/// let aligned = revisit_consistency(&sample, &path_of(0.0)).unwrap();
/// assert!(aligned.median_m < 1e-3);
/// // The second pass placed 5 cm short: its readings sit 5 cm off the first pass's wall.
/// let shifted = revisit_consistency(&sample, &path_of(0.05)).unwrap();
/// assert!((shifted.median_m - 0.05).abs() < 0.01, "{shifted:?}");
/// ```
pub fn revisit_consistency(
    sample: &ScanSample,
    path: &[(f64, Pose2)],
) -> Option<RevisitConsistency> {
    let travelled = travelled(path);
    let placed: Vec<(Vector2<f64>, f64)> = sample
        .readings()
        .iter()
        .filter_map(|(time, in_robot)| {
            let k = path.partition_point(|(t, _)| *t < *time);
            let (t, pose) = path.get(k)?;
            (*t == *time).then(|| (pose.transform_point(in_robot), travelled[k]))
        })
        .collect();
    let cell = |p: &Vector2<f64>| grid::cell_of(p, REVISIT_RADIUS_M);
    let mut grid: FxHashMap<(i64, i64), Vec<usize>> = FxHashMap::default();
    for (i, (p, _)) in placed.iter().enumerate() {
        grid.entry(cell(p)).or_default().push(i);
    }
    let mut distances = Vec::new();
    let mut neighbours = Vec::new();
    let stride = placed.len().div_ceil(REVISIT_MAX_MEASURED).max(1);
    for (p, at) in placed.iter().step_by(stride) {
        neighbours.clear();
        let (cx, cy) = cell(p);
        for key in (cx - 1..=cx + 1).flat_map(|x| (cy - 1..=cy + 1).map(move |y| (x, y))) {
            let Some(members) = grid.get(&key) else {
                continue;
            };
            // Plain arithmetic, the cheap test first: this loop runs millions of times.
            neighbours.extend(members.iter().filter_map(|&j| {
                let (q, at_q) = &placed[j];
                if (at_q - at).abs() < REVISIT_GAP_M {
                    return None;
                }
                let (dx, dy) = (q.x - p.x, q.y - p.y);
                (dx * dx + dy * dy <= REVISIT_RADIUS_M * REVISIT_RADIUS_M).then_some(*q)
            }));
        }
        if let Some(distance) = distance_to_line(p, &neighbours) {
            distances.push(distance);
        }
    }
    summary(distances)
}

/// The distance travelled along `path` up to each of its poses, m.
fn travelled(path: &[(f64, Pose2)]) -> Vec<f64> {
    let mut total = 0.0;
    let mut previous: Option<Vector2<f64>> = None;
    path.iter()
        .map(|(_, pose)| {
            let here = pose.translation();
            if let Some(before) = previous {
                total += (here - before).norm();
            }
            previous = Some(here);
            total
        })
        .collect()
}

/// The distance of `p` from the line through `neighbours`, when there are enough of them and
/// they lie along a line.
fn distance_to_line(p: &Vector2<f64>, neighbours: &[Vector2<f64>]) -> Option<f64> {
    if neighbours.len() < REVISIT_MIN_NEIGHBOURS {
        return None;
    }
    let n = neighbours.len() as f64;
    let centre = neighbours.iter().sum::<Vector2<f64>>() / n;
    let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
    for q in neighbours {
        let d = q - centre;
        xx += d.x * d.x;
        xy += d.x * d.y;
        yy += d.y * d.y;
    }
    // Eigenvalues of the 2 x 2 scatter [[xx, xy], [xy, yy]] in closed form.
    let half_trace = 0.5 * (xx + yy);
    let root = (0.25 * (xx - yy) * (xx - yy) + xy * xy).sqrt();
    let (smaller, larger) = (half_trace - root, half_trace + root);
    if !(larger > 0.0 && larger >= REVISIT_LINE_RATIO * smaller.max(0.0)) {
        return None;
    }
    // The eigenvector of the smaller eigenvalue: the line's normal.
    let normal = if xy.abs() > f64::EPSILON * larger {
        Vector2::new(xy, smaller - xx)
    } else if xx <= yy {
        Vector2::new(1.0, 0.0)
    } else {
        Vector2::new(0.0, 1.0)
    };
    Some(((p - centre).dot(&normal) / normal.norm()).abs())
}

/// The statistics of the measurements.
fn summary(mut distances: Vec<f64>) -> Option<RevisitConsistency> {
    distances.sort_by(f64::total_cmp);
    Some(RevisitConsistency {
        readings: distances.len(),
        median_m: nearest_rank(&distances, 0.5)?,
        mean_m: distances.iter().sum::<f64>() / distances.len() as f64,
        p90_m: nearest_rank(&distances, 0.9)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::Pose3;
    use slam_sensors::LaserScan;

    /// A room 8 m x 6 m centred on the origin scanned from `(x, y)` in the robot frame of
    /// heading 0 (a full circle of 720 beams).
    fn room_scan(x: f64, y: f64) -> LaserScan {
        let beams = 720;
        let step = std::f64::consts::TAU / beams as f64;
        let ranges = (0..beams)
            .map(|k| {
                let a = -std::f64::consts::PI + k as f64 * step;
                let (c, s) = (a.cos(), a.sin());
                let to_x = if c > 0.0 {
                    (4.0 - x) / c
                } else {
                    (-4.0 - x) / c
                };
                let to_y = if s > 0.0 {
                    (3.0 - y) / s
                } else {
                    (-3.0 - y) / s
                };
                to_x.abs().min(to_y.abs())
            })
            .collect();
        LaserScan::new(
            -std::f64::consts::PI,
            std::f64::consts::PI - step,
            ranges,
            0.0,
            30.0,
        )
        .unwrap()
    }

    /// Two passes through the room (scans at times 0-4 and 10-14) with a long excursion
    /// between them; the second pass's poses moved by `second_pass_error`.
    fn two_passes(second_pass_error: Pose2) -> (ScanSample, Vec<(f64, Pose2)>) {
        let mut sample = ScanSample::new(100_000);
        let mut path = Vec::new();
        for k in 0..5 {
            let x = -1.0 + 0.5 * k as f64;
            for (time, error) in [
                (k as f64, Pose2::identity()),
                (10.0 + k as f64, second_pass_error),
            ] {
                sample.add(time, &room_scan(x, 0.0), &Pose3::identity());
                path.push((time, error.compose(&Pose2::new(x, 0.0, 0.0))));
            }
        }
        // The excursion: 50 m away and back between the passes.
        path.push((5.0, Pose2::new(50.0, 0.0, 0.0)));
        path.sort_by(|a, b| a.0.total_cmp(&b.0));
        (sample, path)
    }

    #[test]
    fn passes_that_agree_score_zero_and_a_misplaced_pass_scores_its_error() {
        let (sample, path) = two_passes(Pose2::identity());
        let agreed = revisit_consistency(&sample, &path).unwrap();
        assert!(agreed.readings > 1000, "{agreed:?}");
        assert!(agreed.median_m < 1e-9 && agreed.p90_m < 1e-9, "{agreed:?}");
        // 4 cm along x: the end walls (x = +-4) are 4 cm off, the side walls not at all.
        let (sample, path) = two_passes(Pose2::new(0.04, 0.0, 0.0));
        let shifted = revisit_consistency(&sample, &path).unwrap();
        assert!((shifted.p90_m - 0.04).abs() < 1e-6, "{shifted:?}");
        assert!(
            shifted.mean_m > 0.005 && shifted.mean_m < 0.04,
            "{shifted:?}"
        );
        // A turn of 1 degree moves far walls more than near ones.
        let (sample, path) = two_passes(Pose2::new(0.0, 0.0, 1f64.to_radians()));
        let turned = revisit_consistency(&sample, &path).unwrap();
        assert!(turned.median_m > 0.005 && turned.p90_m < 0.08, "{turned:?}");
    }

    #[test]
    fn one_pass_has_nothing_to_agree_with() {
        let mut sample = ScanSample::new(100_000);
        let mut path = Vec::new();
        // One pass, 2 m: every reading's neighbours are from scans within the gap.
        for k in 0..5 {
            let x = -1.0 + 0.5 * k as f64;
            sample.add(k as f64, &room_scan(x, 0.0), &Pose3::identity());
            path.push((k as f64, Pose2::new(x, 0.0, 0.0)));
        }
        assert_eq!(revisit_consistency(&sample, &path), None);
        // Readings whose time has no pose are left out, not placed at the origin.
        assert_eq!(revisit_consistency(&sample, &[]), None);
    }

    #[test]
    fn neighbours_off_a_line_are_not_a_surface() {
        let p = Vector2::new(0.0, 0.1);
        let line: Vec<_> = (0..8).map(|k| Vector2::new(k as f64 * 0.05, 0.0)).collect();
        assert!((distance_to_line(&p, &line).unwrap() - 0.1).abs() < 1e-12);
        let vertical: Vec<_> = (0..8).map(|k| Vector2::new(0.2, k as f64 * 0.05)).collect();
        assert!((distance_to_line(&p, &vertical).unwrap() - 0.2).abs() < 1e-12);
        // A blob (a chair leg, a plant): no line, no measurement.
        let blob: Vec<_> = (0..8)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 8.0;
                Vector2::new(0.05 * a.cos(), 0.05 * a.sin())
            })
            .collect();
        assert_eq!(distance_to_line(&p, &blob), None);
        assert_eq!(distance_to_line(&p, &line[..5]), None);
    }
}
