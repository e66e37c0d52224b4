//! Square cells of a plane for nearest-neighbour searches: which cell a point is in, the
//! cells of the square ring at a given Chebyshev distance from a cell, and how far a point is
//! from everything outside the square of rings searched so far.
//!
//! A search visits the rings around the query point's cell, ring 0 (the cell itself) first,
//! and may stop once its best distance is at most [`clearance`]: nothing in a cell outside
//! the square can be nearer.
//!
//! ```
//! use slam_core::grid::{cell_of, clearance, ring_cells};
//! use slam_core::nalgebra::Vector2;
//! let p = Vector2::new(0.25, 0.75);
//! assert_eq!(cell_of(&p, 0.5), (0, 1));
//! assert_eq!(ring_cells(0, 1, 0).collect::<Vec<_>>(), vec![(0, 1)]);
//! assert_eq!(ring_cells(0, 1, 1).count(), 8);
//! // The square of ring 0 is the cell [0, 0.5] x [0.5, 1]: its nearest side is 0.25 away.
//! assert!((clearance(&p, 0.5, (0, 1), 0) - 0.25).abs() < 1e-12);
//! ```

use nalgebra::Vector2;

/// The cell of side `cell` that holds `p`: `(floor(x / cell), floor(y / cell))`.
pub fn cell_of(p: &Vector2<f64>, cell: f64) -> (i64, i64) {
    (floor_i64(p.x / cell), floor_i64(p.y / cell))
}

/// `v.floor() as i64`, bit for bit (saturating beyond the range of `i64`, 0 for NaN), without
/// a call: at the x86-64 baseline target `f64::floor` is a library call, and the grid searches
/// take a cell index per query.
///
/// ```
/// use slam_core::grid::floor_i64;
/// for v in [-2.5, -2.0, -0.5, -0.0, 0.0, 0.5, 2.0, 2.5, f64::NAN, -1e300, 1e300] {
///     assert_eq!(floor_i64(v), v.floor() as i64);
/// }
/// ```
#[inline]
pub fn floor_i64(v: f64) -> i64 {
    let truncated = v as i64;
    truncated.saturating_sub(i64::from(truncated as f64 > v))
}

/// `v.ceil() as i64`, bit for bit, without a call (as [`floor_i64`]).
///
/// ```
/// use slam_core::grid::ceil_i64;
/// for v in [-2.5, -2.0, -0.5, -0.0, 0.0, 0.5, 2.0, 2.5, f64::NAN, -1e300, 1e300] {
///     assert_eq!(ceil_i64(v), v.ceil() as i64);
/// }
/// ```
#[inline]
pub fn ceil_i64(v: f64) -> i64 {
    let truncated = v as i64;
    truncated.saturating_add(i64::from((truncated as f64) < v))
}

/// The cells at Chebyshev distance `ring` from `(cx, cy)`: `(cx, cy)` alone for ring 0;
/// otherwise the bottom and top rows in pairs from left to right, then the left and right
/// columns in pairs from bottom to top, without the corners again.
pub fn ring_cells(cx: i64, cy: i64, ring: i64) -> impl Iterator<Item = (i64, i64)> {
    // Cells in a row of the ring (none in ring 0, which is the centre alone).
    let span = if ring == 0 { 0 } else { 2 * ring + 1 };
    let rows = (0..span).flat_map(move |i| {
        let d = i - ring;
        [(cx + d, cy - ring), (cx + d, cy + ring)]
    });
    let columns = (0..span - 2).flat_map(move |i| {
        let d = i + 1 - ring;
        [(cx - ring, cy + d), (cx + ring, cy + d)]
    });
    (ring == 0)
        .then_some((cx, cy))
        .into_iter()
        .chain(rows)
        .chain(columns)
}

/// The distance from `p` (in cell `centre` of side `cell`) to the nearest side of the square
/// of cells within `ring` cells of `centre`: a lower bound on the distance from `p` to any
/// point in a cell outside that square. At least `ring` cells, and more unless `p` lies on its
/// cell's side.
pub fn clearance(p: &Vector2<f64>, cell: f64, centre: (i64, i64), ring: i64) -> f64 {
    let low = |c: i64| (c - ring) as f64 * cell;
    let high = |c: i64| (c + ring + 1) as f64 * cell;
    (p.x - low(centre.0))
        .min(high(centre.0) - p.x)
        .min(p.y - low(centre.1))
        .min(high(centre.1) - p.y)
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The call-free floor and ceiling are `f64::floor` / `f64::ceil` cast to `i64`, on
        /// random bit patterns (infinities, NaNs and values beyond `i64` among them) and on
        /// small values.
        #[test]
        fn floor_and_ceil_are_the_library_ones(bits in proptest::num::u64::ANY, small in -1e6f64..1e6) {
            for v in [f64::from_bits(bits), small] {
                proptest::prop_assert_eq!(floor_i64(v), v.floor() as i64);
                proptest::prop_assert_eq!(ceil_i64(v), v.ceil() as i64);
            }
        }
    }

    #[test]
    fn a_ring_lists_each_of_its_cells_once() {
        for ring in 0..5i64 {
            let cells: Vec<_> = ring_cells(3, -2, ring).collect();
            let distinct: std::collections::HashSet<_> = cells.iter().collect();
            assert_eq!(cells.len(), (8 * ring).max(1) as usize);
            assert_eq!(distinct.len(), cells.len());
            assert!(
                cells
                    .iter()
                    .all(|&(x, y)| (x - 3).abs().max((y + 2).abs()) == ring)
            );
        }
    }

    #[test]
    fn rings_cover_the_square_once() {
        for ring_count in 0..5 {
            let mut seen: Vec<(i64, i64)> = (0..=ring_count)
                .flat_map(|ring| ring_cells(3, -2, ring))
                .collect();
            let total = seen.len();
            seen.sort();
            seen.dedup();
            let side = 2 * ring_count + 1;
            assert_eq!(seen.len(), total, "a cell visited twice");
            assert_eq!(total as i64, side * side);
            assert!(
                seen.iter()
                    .all(|&(x, y)| (x - 3).abs() <= ring_count && (y + 2).abs() <= ring_count)
            );
        }
    }

    #[test]
    fn nothing_outside_the_square_is_nearer_than_its_clearance() {
        let cell = 0.3;
        let p = Vector2::new(1.0, -0.41);
        let centre = cell_of(&p, cell);
        for ring in 0..4 {
            let bound = clearance(&p, cell, centre, ring);
            assert!(bound >= ring as f64 * cell - 1e-12);
            // Points on a fine lattice: those whose cell is outside the square are farther.
            for i in -40..40 {
                for j in -40..40 {
                    let q = Vector2::new(i as f64 * 0.07, j as f64 * 0.07);
                    let (x, y) = cell_of(&q, cell);
                    if (x - centre.0).abs() > ring || (y - centre.1).abs() > ring {
                        assert!((q - p).norm() >= bound - 1e-12, "ring {ring}: {q:?}");
                    }
                }
            }
        }
    }
}
