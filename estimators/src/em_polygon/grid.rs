//! Uniform grids: candidate segments for the E-step (so that it is not a dense
//! points x segments loop) and point counts in squares for the split step.

use slam_core::nalgebra::Vector2;

use super::Segment;

/// Distance from `p` to the segment `a b` (to `a` when the segment has no length).
pub(crate) fn point_segment_distance_sq(
    p: &Vector2<f64>,
    a: &Vector2<f64>,
    b: &Vector2<f64>,
) -> f64 {
    let e = b - a;
    let len_sq = e.norm_squared();
    let t = if len_sq > 0.0 {
        ((p - a).dot(&e) / len_sq).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + e * t)).norm_squared()
}

/// A uniform grid over a rectangle: `nx x ny` cells of side `h`, in compressed rows
/// (`start[c]..start[c + 1]` index `items` for cell `c`).
#[derive(Debug)]
struct Cells {
    origin: Vector2<f64>,
    h: f64,
    nx: usize,
    ny: usize,
}

impl Cells {
    /// A grid of cell side `h` over `lo..hi` (at most `max_cells` cells: `h` grows if needed).
    fn new(lo: Vector2<f64>, hi: Vector2<f64>, h: f64, max_cells: usize) -> Self {
        let extent = (hi - lo).map(|v| v.max(0.0));
        let mut h = h.max(1e-9 * (1.0 + extent.max()));
        loop {
            let nx = (extent.x / h).floor() as usize + 1;
            let ny = (extent.y / h).floor() as usize + 1;
            if nx.saturating_mul(ny) <= max_cells.max(1) {
                return Cells {
                    origin: lo,
                    h,
                    nx,
                    ny,
                };
            }
            h *= 1.5;
        }
    }

    /// Cell coordinates of `p`, clamped into the grid.
    fn cell_of(&self, p: &Vector2<f64>) -> (usize, usize) {
        let c = (p - self.origin) / self.h;
        let clamp = |v: f64, n: usize| {
            if v.is_nan() || v <= 0.0 {
                0
            } else {
                (v.floor() as usize).min(n - 1)
            }
        };
        (clamp(c.x, self.nx), clamp(c.y, self.ny))
    }

    fn index(&self, (i, j): (usize, usize)) -> usize {
        j * self.nx + i
    }

    fn centre(&self, (i, j): (usize, usize)) -> Vector2<f64> {
        self.origin + Vector2::new(i as f64 + 0.5, j as f64 + 0.5) * self.h
    }
}

/// Compressed cell lists built from `(cell, item)` pairs.
fn compress(count: usize, mut pairs: Vec<(usize, u32)>) -> (Vec<u32>, Vec<u32>) {
    pairs.sort_unstable();
    let mut start = vec![0u32; count + 1];
    for &(c, _) in &pairs {
        start[c + 1] += 1;
    }
    for c in 0..count {
        start[c + 1] += start[c];
    }
    (start, pairs.into_iter().map(|(_, item)| item).collect())
}

/// The segments of the current model by grid cell: every cell a segment passes through
/// lists it.
#[derive(Debug)]
pub(crate) struct SegmentGrid {
    cells: Cells,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl SegmentGrid {
    /// Indexes `segments` over the rectangle `lo..hi` (which holds every point and segment);
    /// the cell side is chosen so that there are about two cells per segment.
    pub(crate) fn new(segments: &[Segment], lo: Vector2<f64>, hi: Vector2<f64>) -> Self {
        let extent = hi - lo;
        let floor = 1e-3 * (1.0 + extent.max());
        let area = extent.x.max(floor) * extent.y.max(floor);
        let h = (area / (2.0 * segments.len().max(1) as f64)).sqrt();
        let cells = Cells::new(lo, hi, h, 4_000_000);
        let reach = cells.h * std::f64::consts::FRAC_1_SQRT_2 * 1.000_001;
        let mut pairs = Vec::new();
        for (k, s) in segments.iter().enumerate() {
            let (i0, j0) = cells.cell_of(&s.start.inf(&s.end));
            let (i1, j1) = cells.cell_of(&s.start.sup(&s.end));
            for j in j0..=j1 {
                for i in i0..=i1 {
                    // A cell the segment crosses has its centre within half a diagonal.
                    let d = point_segment_distance_sq(&cells.centre((i, j)), &s.start, &s.end);
                    if d <= reach * reach {
                        pairs.push((cells.index((i, j)), k as u32));
                    }
                }
            }
        }
        let (start, items) = compress(cells.nx * cells.ny, pairs);
        SegmentGrid {
            cells,
            start,
            items,
        }
    }

    /// Visits the segments listed in the cells around `p`, ring of cells by ring outwards,
    /// each once (`seen`, one stamp per segment, initially all `u32::MAX`, and `stamp`, unique
    /// per query): `visit(state, (k, squared distance of segment k to p))`. After each ring it stops when `done(state, reach_sq)`,
    /// where every segment not visited yet is at least `sqrt(reach_sq)` from `p`.
    #[allow(clippy::too_many_arguments)] // the query, its stamps, and the visitor's three parts
    fn walk_rings<S>(
        &self,
        segments: &[Segment],
        p: &Vector2<f64>,
        seen: &mut [u32],
        stamp: u32,
        state: &mut S,
        visit: impl Fn(&mut S, Nearest),
        done: impl Fn(&S, f64) -> bool,
    ) {
        let (ci, cj) = self.cells.cell_of(p);
        let max_ring = self.cells.nx.max(self.cells.ny);
        for ring in 0..=max_ring {
            let (i0, i1) = (ci as isize - ring as isize, ci as isize + ring as isize);
            let (j0, j1) = (cj as isize - ring as isize, cj as isize + ring as isize);
            for j in j0.max(0)..=j1.min(self.cells.ny as isize - 1) {
                let on_edge_row = j == j0 || j == j1;
                let step = if on_edge_row { 1 } else { (i1 - i0).max(1) };
                let mut i = i0;
                while i <= i1 {
                    if i >= 0 && i < self.cells.nx as isize {
                        let c = self.cells.index((i as usize, j as usize));
                        for &k in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
                            if seen[k as usize] != stamp {
                                seen[k as usize] = stamp;
                                let s = &segments[k as usize];
                                visit(state, (k, point_segment_distance_sq(p, &s.start, &s.end)));
                            }
                        }
                    }
                    i += step;
                }
            }
            // Segments not met yet lie in outer rings, at least `ring * h` away.
            let reach = ring as f64 * self.cells.h;
            if done(state, reach * reach) {
                break;
            }
        }
    }

    /// The segments whose squared distance to `p` is at most `d_min^2 + extra_sq`, where
    /// `d_min` is the distance to the nearest segment, as `(index, squared distance)` in
    /// `out` (cleared first). `seen` and `stamp` as in [`SegmentGrid::walk_rings`]. Returns
    /// the nearest one.
    pub(crate) fn candidates(
        &self,
        segments: &[Segment],
        p: &Vector2<f64>,
        extra_sq: f64,
        seen: &mut [u32],
        stamp: u32,
        out: &mut Vec<(u32, f64)>,
    ) -> Option<(u32, f64)> {
        out.clear();
        let mut state: (Option<Nearest>, &mut Vec<(u32, f64)>) = (None, out);
        self.walk_rings(
            segments,
            p,
            seen,
            stamp,
            &mut state,
            |(best, out), found| {
                out.push(found);
                if closer(found, *best) {
                    *best = Some(found);
                }
            },
            |(best, _), reach_sq| best.is_some_and(|(_, d)| reach_sq >= d + extra_sq),
        );
        let (best, out) = state;
        let (_, d_min) = best?;
        out.retain(|&(_, d)| d <= d_min + extra_sq);
        out.sort_unstable_by_key(|&(k, _)| k);
        best
    }

    /// The nearest and the second nearest segment to `p`, as `(index, squared distance)`
    /// (the second `None` with a single segment). `seen` and `stamp` as in
    /// [`SegmentGrid::walk_rings`].
    pub(crate) fn two_nearest(
        &self,
        segments: &[Segment],
        p: &Vector2<f64>,
        seen: &mut [u32],
        stamp: u32,
    ) -> Option<(Nearest, Option<Nearest>)> {
        let mut state: (Option<Nearest>, Option<Nearest>) = (None, None);
        self.walk_rings(
            segments,
            p,
            seen,
            stamp,
            &mut state,
            |(best, second), found| {
                if closer(found, *best) {
                    *second = *best;
                    *best = Some(found);
                } else if closer(found, *second) {
                    *second = Some(found);
                }
            },
            |(_, second), reach_sq| second.is_some_and(|(_, d)| reach_sq >= d),
        );
        let (best, second) = state;
        best.map(|b| (b, second))
    }
}

/// A segment's index and its squared distance to a point.
pub(crate) type Nearest = (u32, f64);

/// Whether `found` is nearer than `than` (ties to the lower index; anything is nearer than
/// nothing).
fn closer((k, d): Nearest, than: Option<Nearest>) -> bool {
    than.is_none_or(|(tk, td)| d < td || (d == td && k < tk))
}

/// Points by grid cell, to count the points in a small square quickly.
#[derive(Debug)]
pub(crate) struct PointGrid {
    cells: Cells,
    start: Vec<u32>,
    /// The points, ordered by cell.
    points: Vec<Vector2<f64>>,
}

impl PointGrid {
    /// Bins `points` (all inside `lo..hi`) into cells of side about `h`.
    pub(crate) fn new(points: &[Vector2<f64>], lo: Vector2<f64>, hi: Vector2<f64>, h: f64) -> Self {
        let cells = Cells::new(lo, hi, h, 4 * points.len().max(1024));
        let pairs: Vec<(usize, u32)> = points
            .iter()
            .enumerate()
            .map(|(k, p)| (cells.index(cells.cell_of(p)), k as u32))
            .collect();
        let (start, items) = compress(cells.nx * cells.ny, pairs);
        let points = items.iter().map(|&k| points[k as usize]).collect();
        PointGrid {
            cells,
            start,
            points,
        }
    }

    /// Number of points `p` with `|(p - centre) . u| <= half_along` and
    /// `|(p - centre) . n| <= half_across`, where `u` is the unit `direction` and `n` its
    /// normal.
    pub(crate) fn count_in_box(
        &self,
        centre: &Vector2<f64>,
        direction: &Vector2<f64>,
        half_along: f64,
        half_across: f64,
    ) -> usize {
        let normal = Vector2::new(-direction.y, direction.x);
        let reach = Vector2::new(
            (direction.x * half_along).abs() + (normal.x * half_across).abs(),
            (direction.y * half_along).abs() + (normal.y * half_across).abs(),
        );
        let mut count = 0;
        self.for_each_in_box(centre, &reach, |p| {
            let d = p - centre;
            if d.dot(direction).abs() <= half_along && d.dot(&normal).abs() <= half_across {
                count += 1;
            }
        });
        count
    }

    /// Calls `visit` with every point within `radius` of `centre`.
    pub(crate) fn for_each_in_disc(
        &self,
        centre: &Vector2<f64>,
        radius: f64,
        mut visit: impl FnMut(&Vector2<f64>),
    ) {
        let radius_sq = radius * radius;
        self.for_each_in_box(centre, &Vector2::repeat(radius), |p| {
            if (p - centre).norm_squared() <= radius_sq {
                visit(p);
            }
        });
    }

    /// Calls `visit` with every point of the cells that overlap the box `centre +- reach`,
    /// row by row.
    fn for_each_in_box(
        &self,
        centre: &Vector2<f64>,
        reach: &Vector2<f64>,
        mut visit: impl FnMut(&Vector2<f64>),
    ) {
        let (i0, j0) = self.cells.cell_of(&(centre - reach));
        let (i1, j1) = self.cells.cell_of(&(centre + reach));
        for j in j0..=j1 {
            let row = self.cells.index((0, j));
            let (a, b) = (
                self.start[row + i0] as usize,
                self.start[row + i1 + 1] as usize,
            );
            self.points[a..b].iter().for_each(&mut visit);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::em_polygon::seg;

    #[test]
    fn grid_candidates_equal_brute_force() {
        let mut segments = Vec::new();
        for k in 0..40 {
            let x = (k % 8) as f64 * 2.5;
            let y = (k / 8) as f64 * 3.0;
            segments.push(seg(
                (x, y),
                (x + 1.0 + 0.1 * k as f64, y + 0.7 * (k % 3) as f64),
            ));
        }
        let (lo, hi) = (Vector2::new(-1.0, -1.0), Vector2::new(25.0, 16.0));
        let grid = SegmentGrid::new(&segments, lo, hi);
        let mut seen = vec![u32::MAX; segments.len()];
        let mut out = Vec::new();
        for q in 0..300 {
            let p = Vector2::new(
                (q * 37 % 260) as f64 / 10.0 - 1.0,
                (q * 53 % 170) as f64 / 10.0 - 1.0,
            );
            let extra = 0.3;
            let best = grid
                .candidates(&segments, &p, extra, &mut seen, q, &mut out)
                .unwrap();
            let all: Vec<f64> = segments
                .iter()
                .map(|s| point_segment_distance_sq(&p, &s.start, &s.end))
                .collect();
            let d_min = all.iter().copied().fold(f64::INFINITY, f64::min);
            assert_eq!(best.1, d_min);
            let expected: Vec<u32> = (0..segments.len() as u32)
                .filter(|&k| all[k as usize] <= d_min + extra)
                .collect();
            let got: Vec<u32> = out.iter().map(|c| c.0).collect();
            assert_eq!(got, expected, "point {p:?}");
            // The two nearest, against sorting all the distances (ties to the lower index).
            let mut sorted: Vec<(u32, f64)> = (0..segments.len() as u32)
                .map(|k| (k, all[k as usize]))
                .collect();
            sorted.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            let two = grid.two_nearest(&segments, &p, &mut seen, q + 1000);
            assert_eq!(two, Some((sorted[0], Some(sorted[1]))), "point {p:?}");
        }
    }

    #[test]
    fn box_counts_equal_brute_force() {
        let points: Vec<_> = (0..2000)
            .map(|k| {
                Vector2::new(
                    (k * 7919 % 1000) as f64 / 100.0,
                    (k * 104_729 % 997) as f64 / 100.0,
                )
            })
            .collect();
        let grid = PointGrid::new(&points, Vector2::zeros(), Vector2::new(10.0, 10.0), 0.4);
        let direction = Vector2::new(0.6, 0.8);
        for c in [(5.0, 5.0), (0.1, 9.9), (3.3, 7.1)] {
            let centre = Vector2::new(c.0, c.1);
            let expected = points
                .iter()
                .filter(|p| {
                    let d = *p - centre;
                    d.dot(&direction).abs() <= 0.7 && (d.x * -0.8 + d.y * 0.6).abs() <= 0.3
                })
                .count();
            assert_eq!(grid.count_in_box(&centre, &direction, 0.7, 0.3), expected);
        }
    }
}
