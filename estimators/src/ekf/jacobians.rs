//! Jacobian helpers of the EKF: the unobservable directions of the pose and of feature
//! coordinates (for the observability constraint), the projection that removes them, and the
//! stacking of pairings into one batch measurement.

use slam_core::nalgebra::{DMatrix, DVector};
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
/// (left as it is when `N^T N` is singular).
pub(super) fn project_out(h: &DMatrix<f64>, n: &DMatrix<f64>) -> DMatrix<f64> {
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
    let mut indices: Vec<usize> = pairings
        .iter()
        .flat_map(|p| p.indices.iter().copied())
        .collect();
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
