//! The noise level of the points about the lines they lie on, measured from the points alone
//! (no segment model): the deviation across local line fits.
//!
//! For a sample of the points, the neighbourhood of radius `rho` is grown (1 cm, doubling,
//! up to [`LARGEST_RADIUS`]) until it holds at least [`MIN_POINTS`] points and is elongated
//! like a stretch of wall: the deviation along its principal direction at least
//! [`ELONGATION`] times the deviation across it. The deviation across (the root of the
//! smallest eigenvalue of the neighbourhood's scatter, with `n / (n - 2)` for the two degrees
//! of freedom of the line) is that neighbourhood's noise; the noise level is their median.
//! Neighbourhoods that never look like a line (corners, clutter, isolated returns) give
//! none. The registration error of overlapping scans is part of what is measured: it is part
//! of the scatter of the registered points about their wall.

use rayon::prelude::*;
use slam_core::nalgebra::Vector2;

use super::grid::PointGrid;

/// Smallest neighbourhood radius tried, m.
const FIRST_RADIUS: f64 = 0.01;
/// Largest neighbourhood radius tried, m (a neighbourhood not line-like at this size gives
/// no measurement).
const LARGEST_RADIUS: f64 = 2.56;
/// Fewest points in a measuring neighbourhood.
const MIN_POINTS: usize = 8;
/// Deviation along over deviation across of a line-like neighbourhood.
const ELONGATION: f64 = 4.0;
/// Most sample points (every `ceil(n / MAX_SAMPLES)`-th point is one).
const MAX_SAMPLES: usize = 20_000;

/// The measured noise level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct NoiseLevel {
    /// Median deviation across the line-like neighbourhoods, m.
    pub sigma: f64,
    /// Number of line-like neighbourhoods measured.
    pub neighbourhoods: usize,
}

/// The noise level of `points` (module documentation), `None` when fewer than 10
/// neighbourhoods are line-like.
pub(crate) fn noise_level(points: &[Vector2<f64>]) -> Option<NoiseLevel> {
    if points.len() < MIN_POINTS {
        return None;
    }
    let (lo, hi) = super::emsf::bounds(points, &[]);
    let stride = points.len().div_ceil(MAX_SAMPLES);
    let mut pending: Vec<Vector2<f64>> = points.iter().step_by(stride).copied().collect();
    let mut measured: Vec<f64> = Vec::new();
    let mut radius = FIRST_RADIUS;
    while radius <= LARGEST_RADIUS * (1.0 + 1e-9) && !pending.is_empty() {
        let grid = PointGrid::new(points, lo, hi, radius);
        let results: Vec<Option<f64>> = pending
            .par_iter()
            .map(|centre| deviation_across(&grid, centre, radius))
            .collect();
        let mut still = Vec::with_capacity(pending.len());
        for (centre, result) in pending.into_iter().zip(results) {
            match result {
                Some(sigma) => measured.push(sigma),
                None => still.push(centre),
            }
        }
        pending = still;
        radius *= 2.0;
    }
    let neighbourhoods = measured.len();
    if neighbourhoods < 10 {
        return None;
    }
    let k = neighbourhoods / 2;
    let (_, median, _) = measured.select_nth_unstable_by(k, f64::total_cmp);
    Some(NoiseLevel {
        sigma: *median,
        neighbourhoods,
    })
}

/// The deviation across the line fitted to the points within `radius` of `centre`, when
/// they are at least [`MIN_POINTS`] and line-like.
fn deviation_across(grid: &PointGrid, centre: &Vector2<f64>, radius: f64) -> Option<f64> {
    let (mut n, mut sx, mut sy, mut sxx, mut sxy, mut syy) = (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
    grid.for_each_in_disc(centre, radius, |p| {
        let d = p - centre;
        n += 1;
        sx += d.x;
        sy += d.y;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    });
    if n < MIN_POINTS {
        return None;
    }
    let count = n as f64;
    let (mx, my) = (sx / count, sy / count);
    let (a, b, c) = (
        sxx / count - mx * mx,
        sxy / count - mx * my,
        syy / count - my * my,
    );
    // Eigenvalues of [[a, b], [b, c]].
    let half_trace = 0.5 * (a + c);
    let root = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    let (largest, smallest) = (half_trace + root, (half_trace - root).max(0.0));
    (largest >= ELONGATION * ELONGATION * smallest && largest > 0.0)
        .then(|| (smallest * count / (count - 2.0)).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic standard normal draws (Box-Muller on splitmix64).
    fn normals(seed: u64, count: usize) -> Vec<f64> {
        let mut state = seed;
        let mut uniform = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..count)
            .map(|_| {
                let (u, v) = (uniform().max(1e-300), uniform());
                (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
            })
            .collect()
    }

    /// The walls of a 6 m x 4 m room, a point every `step`, with Gaussian noise of deviation
    /// `sigma` across the wall.
    fn room(step: f64, sigma: f64, seed: u64) -> Vec<Vector2<f64>> {
        let corners = [(0.0, 0.0), (6.0, 0.0), (6.0, 4.0), (0.0, 4.0), (0.0, 0.0)];
        let mut points = Vec::new();
        for w in corners.windows(2) {
            let (a, b) = (Vector2::new(w[0].0, w[0].1), Vector2::new(w[1].0, w[1].1));
            let d = b - a;
            let normal = Vector2::new(-d.y, d.x) / d.norm();
            let count = (d.norm() / step) as usize;
            for (k, e) in normals(seed + points.len() as u64, count)
                .into_iter()
                .enumerate()
            {
                points.push(a + d * (k as f64 / count as f64) + normal * (sigma * e));
            }
        }
        points
    }

    #[test]
    fn the_noise_of_walls_is_measured_at_any_density() {
        for (step, sigma) in [(0.005, 0.01), (0.02, 0.02), (0.05, 0.03), (0.01, 0.002)] {
            let level = noise_level(&room(step, sigma, 3)).unwrap();
            assert!(
                (level.sigma / sigma - 1.0).abs() < 0.15,
                "step {step}, sigma {sigma}: measured {level:?}"
            );
        }
    }

    #[test]
    fn scattered_points_give_no_noise_level() {
        // A regular 2-D lattice: no neighbourhood is line-like.
        let points: Vec<_> = (0..400)
            .map(|k| Vector2::new((k % 20) as f64 * 0.1, (k / 20) as f64 * 0.1))
            .collect();
        assert_eq!(noise_level(&points), None);
    }
}
