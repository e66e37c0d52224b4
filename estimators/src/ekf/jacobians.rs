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

/// `H - H N (N^T N)^-1 N^T`: the Jacobian that observes nothing along the columns of `n`
/// (left as it is when `N^T N` is singular). `n` has 3 columns (the planar generators); the
/// 3 x 3 Gram matrix is inverted in closed form.
pub(super) fn project_out(h: &DMatrix<f64>, n: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = h.clone();
    project_out_in_place(&mut out, n.as_view());
    out
}

/// [`project_out`] written over `h` (no allocation for 3 directions): each row's `H N (N^T
/// N)^-1` depends on that row alone, so the rows are projected one after the other.
pub(super) fn project_out_in_place(h: &mut DMatrix<f64>, n: DMatrixView<'_, f64>) {
    if n.ncols() != 3 || n.nrows() != h.ncols() {
        *h = project_out_dense(h, &n.clone_owned());
        return;
    }
    let mut gram = Matrix3::zeros();
    for a in 0..3 {
        for b in 0..3 {
            gram[(a, b)] = n.column(a).dot(&n.column(b));
        }
    }
    let Some(inverse) = gram.try_inverse() else {
        return;
    };
    for i in 0..h.nrows() {
        // Row i of H N (N^T N)^-1.
        let mut row = [0.0; 3];
        for (a, value) in row.iter_mut().enumerate() {
            *value = (0..h.ncols()).map(|k| h[(i, k)] * n[(k, a)]).sum();
        }
        let mut hn = [0.0; 3];
        for (b, value) in hn.iter_mut().enumerate() {
            *value = (0..3).map(|a| row[a] * inverse[(a, b)]).sum();
        }
        for j in 0..h.ncols() {
            h[(i, j)] -= (0..3).map(|b| hn[b] * n[(j, b)]).sum::<f64>();
        }
    }
}

/// [`project_out`] for any number of directions, by nalgebra products.
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
        let h = DMatrix::from_fn(2, 5, |i, j| ((i * 5 + j) as f64 * 0.7).sin());
        let n = DMatrix::from_fn(5, 3, |i, j| ((i * 3 + j) as f64 * 1.3).cos() + i as f64);
        let fast = project_out(&h, &n);
        let dense = project_out_dense(&h, &n);
        assert!((&fast - &dense).amax() < 1e-12, "{fast} {dense}");
        assert!((&fast * &n).amax() < 1e-12);
        let singular = DMatrix::zeros(5, 3);
        assert_eq!(project_out(&h, &singular), h);
    }
}
