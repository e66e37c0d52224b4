//! Jacobian helpers of the EKF: the unobservable directions of the pose and of feature
//! coordinates (for the observability constraint), the projection that removes them, and the
//! stacking of pairings into one batch measurement.

use slam_core::nalgebra::{DMatrix, DMatrixView, DVector, Matrix3};
use slam_core::{CoordBlock, Coordinates, RobotPose};

use super::Pairing;

/// The change of the pose parameters under a world translation along x, along y and a
/// rotation about z (`P::DIM x 3`).
pub(super) fn pose_generators<P: RobotPose>(pose: &P) -> DMatrix<f64> {
    let g = pose.planar_motion_generators();
    DMatrix::from_fn(P::DIM, 3, |i, j| g[j].get(i).copied().unwrap_or(0.0))
}

/// The change of coordinates under a world translation along x, along y and a rotation
/// about z (`dim(x_f) x 3`).
pub(super) fn coordinate_generators(coordinates: &Coordinates) -> DMatrix<f64> {
    let mut g = DMatrix::zeros(coordinates.dim(), 3);
    for (k, block) in coordinates.blocks().iter().enumerate() {
        let offset = coordinates.offset(k);
        let (x, y) = match block {
            CoordBlock::Point2(p) => (p.x, p.y),
            CoordBlock::Point3(p) => (p.x, p.y),
            CoordBlock::Scalar(_) => continue,
        };
        g[(offset, 0)] = 1.0;
        g[(offset + 1, 1)] = 1.0;
        g[(offset, 2)] = -y;
        g[(offset + 1, 2)] = x;
    }
    g
}

/// Each row `h` of `H` less `h N_s (N_s^T N_s)^+ N_s^T`, where `N_s` is `N` on the row's
/// support (the columns `h` depends on): the closest Jacobian that observes nothing along the
/// columns of `n` (`H N = 0`) without observing a state row the measurement does not depend on.
/// Projecting over every column instead would give a wall's line measurement weight on the
/// wall's end rows through their generators; an end just activated with a variance of 1e4 m^2
/// then takes a step of metres from a measurement that says nothing about it. `n` has one
/// row per column of `H` (the planar generators of those state rows).
pub(super) fn project_out(h: &DMatrix<f64>, n: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = h.clone();
    project_out_in_place(&mut out, n.as_view());
    out
}

/// [`project_out`] written over `h`: each row's projection depends on that row alone, so the
/// rows are projected one after the other (no allocation for up to 3 directions).
pub(super) fn project_out_in_place(h: &mut DMatrix<f64>, n: DMatrixView<'_, f64>) {
    debug_assert_eq!(
        n.nrows(),
        h.ncols(),
        "one generator row per Jacobian column"
    );
    if n.ncols() > 3 || n.nrows() != h.ncols() {
        *h = project_out_dense(h, &n.clone_owned());
        return;
    }
    // The Gram matrix's pseudo-inverse over every column, shared by the rows that depend on
    // every column (a point's or a line's measurement).
    let mut full_inverse = None;
    for i in 0..h.nrows() {
        let scale = h.row(i).amax();
        let in_support = |value: f64| value.abs() > SUPPORT_TOLERANCE * scale;
        let inverse = if h.row(i).iter().all(|&value| in_support(value)) {
            *full_inverse.get_or_insert_with(|| gram_pseudo_inverse(&n, |_| true))
        } else {
            gram_pseudo_inverse(&n, |k| in_support(h[(i, k)]))
        };
        // Row i of H N (N_s^T N_s)^+.
        let mut row = [0.0; 3];
        for (a, value) in row.iter_mut().enumerate().take(n.ncols()) {
            *value = (0..h.ncols()).map(|k| h[(i, k)] * n[(k, a)]).sum();
        }
        let mut hn = [0.0; 3];
        for (b, value) in hn.iter_mut().enumerate() {
            *value = (0..3).map(|a| row[a] * inverse[(a, b)]).sum();
        }
        for j in 0..h.ncols() {
            if in_support(h[(i, j)]) {
                h[(i, j)] -= (0..n.ncols()).map(|b| hn[b] * n[(j, b)]).sum::<f64>();
            }
        }
    }
}

/// `(N_s^T N_s)^+` for the rows `k` of `n` (at most 3 columns) with `in_support(k)`.
fn gram_pseudo_inverse(
    n: &DMatrixView<'_, f64>,
    in_support: impl Fn(usize) -> bool,
) -> Matrix3<f64> {
    let mut gram = Matrix3::<f64>::zeros();
    for k in (0..n.nrows()).filter(|&k| in_support(k)) {
        for a in 0..n.ncols() {
            for b in 0..n.ncols() {
                gram[(a, b)] += n[(k, a)] * n[(k, b)];
            }
        }
    }
    symmetric_pseudo_inverse(gram)
}

/// `(V L V^T)^+ = V L^+ V^T` of a symmetric positive semi-definite 3 x 3 matrix, eigenvalues
/// below [`PSEUDO_INVERSE_TOLERANCE`] times the largest counting as zero; the closed-form
/// inverse when the determinant says no eigenvalue is that small (the usual case: a support
/// that holds the pose).
fn symmetric_pseudo_inverse(gram: Matrix3<f64>) -> Matrix3<f64> {
    let mean_eigenvalue = gram.trace() / 3.0;
    // Every eigenvalue is at most the trace, so a determinant above this bounds the smallest
    // from below by the tolerance times the mean.
    let well_conditioned = gram.determinant()
        > PSEUDO_INVERSE_TOLERANCE * mean_eigenvalue * (3.0 * mean_eigenvalue).powi(2);
    if let Some(inverse) = gram.try_inverse().filter(|_| well_conditioned) {
        return inverse;
    }
    let eigen = gram.symmetric_eigen();
    let largest = eigen.eigenvalues.amax();
    let mut inverse = Matrix3::zeros();
    for (k, &value) in eigen.eigenvalues.iter().enumerate() {
        if value > PSEUDO_INVERSE_TOLERANCE * largest {
            let v = eigen.eigenvectors.column(k);
            inverse += v * v.transpose() / value;
        }
    }
    inverse
}

/// A Jacobian entry at most this fraction of its row's largest is outside the row's support
/// (rounding: a wall's line measurement has entries of 1e-16 on the wall's end rows).
const SUPPORT_TOLERANCE: f64 = 1e-9;

/// Eigenvalues of the support's Gram matrix below this fraction of its largest count as zero
/// (directions the support cannot represent are left alone).
const PSEUDO_INVERSE_TOLERANCE: f64 = 1e-12;

/// `H - H N (N^T N)^-1 N^T` over every column (left as it is when `N^T N` is singular), by
/// nalgebra products: the path for more than 3 directions.
fn project_out_dense(h: &DMatrix<f64>, n: &DMatrix<f64>) -> DMatrix<f64> {
    let gram = n.transpose() * n;
    match gram.try_inverse() {
        Some(inverse) => h - h * n * inverse * n.transpose(),
        None => h.clone(),
    }
}

/// Stacks pairings into one measurement: the union of their state rows (sorted), `H` on
/// those rows, block-diagonal `C_eta` and the stacked innovation.
pub(super) fn stack(
    pairings: &[&Pairing],
) -> (Vec<usize>, DMatrix<f64>, DMatrix<f64>, DVector<f64>) {
    let mut indices = Vec::with_capacity(pairings.iter().map(|p| p.indices.len()).sum());
    indices.extend(pairings.iter().flat_map(|p| p.indices.iter().copied()));
    indices.sort_unstable();
    indices.dedup();
    let m: usize = pairings.iter().map(|p| p.eta.len()).sum();
    let mut h = DMatrix::zeros(m, indices.len());
    let mut r = DMatrix::zeros(m, m);
    let mut eta = DVector::zeros(m);
    let mut row = 0;
    for p in pairings {
        let k = p.eta.len();
        for (column, index) in p.indices.iter().enumerate() {
            // Every index of a pairing is in the sorted union.
            let Ok(target) = indices.binary_search(index) else {
                continue;
            };
            for a in 0..k {
                h[(row + a, target)] += p.h[(a, column)];
            }
        }
        r.view_mut((row, row), (k, k)).copy_from(&p.cov_eta);
        eta.rows_mut(row, k).copy_from(&p.eta);
        row += k;
    }
    (indices, h, r, eta)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed-form projection equals the dense one, and observes nothing along `n`.
    #[test]
    fn project_out_matches_the_dense_products() {
        let h = DMatrix::from_fn(2, 5, |i, j| ((i * 5 + j) as f64 * 0.7).sin() + 1.5);
        let n = DMatrix::from_fn(5, 3, |i, j| ((i * 3 + j) as f64 * 1.3).cos() + i as f64);
        let fast = project_out(&h, &n);
        let dense = project_out_dense(&h, &n);
        assert!((&fast - &dense).amax() < 1e-12, "{fast} {dense}");
        assert!((&fast * &n).amax() < 1e-12);
        let singular = DMatrix::zeros(5, 3);
        assert_eq!(project_out(&h, &singular), h);
    }

    /// A column the measurement does not depend on stays zero (the row's support is
    /// projected alone), and the result still observes nothing along `n`.
    #[test]
    fn project_out_keeps_the_columns_outside_the_support_at_zero() {
        let mut h = DMatrix::from_fn(2, 6, |i, j| ((i * 6 + j) as f64 * 0.7).sin() + 1.5);
        h.column_mut(4).fill(0.0);
        h[(1, 5)] = 1e-17;
        let n = DMatrix::from_fn(6, 3, |i, j| {
            ((i * i + 3 * j) as f64 * 0.9).cos() * (1 + i) as f64
        });
        let projected = project_out(&h, &n);
        assert_eq!(projected.column(4).amax(), 0.0);
        assert_eq!(projected[(1, 5)], 1e-17);
        // The support observes the generators before the projection.
        assert!((h.columns(0, 4) * n.rows(0, 4)).amax() > 1.0);
        let observed = &projected * &n;
        assert!(observed.amax() < 1e-9, "{observed}");
        // Over all columns, the zero column would take weight.
        assert!(project_out_dense(&h, &n).column(4).amax() > 1e-3);
    }
}
