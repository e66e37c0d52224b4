//! A landmark's EKF arithmetic on stack matrices for the common sizes (an innovation of at
//! most 3 rows, an M-space of at most 4 dimensions): the formulas of
//! [`super::landmark::Landmark::likelihood`] and
//! [`super::landmark::Landmark::update_linearized`] without a heap allocation per product.
//! Other sizes return `None` and take the dynamic path; the two are compared in the tests.

use slam_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use slam_core::{assign_matrix, assign_vector};

use crate::particles::log_normal;

/// `(ln N(eta; 0, S), eta^T S^-1 eta)` with `S = H P H^T + C` (or `2 C` when `h` has no
/// columns). `None` when the size is not a stack size; `Some(None)` when `S` is not positive
/// definite or the value not finite.
pub(super) fn log_likelihood(
    eta: &DVector<f64>,
    cov_eta: &DMatrix<f64>,
    h: &DMatrix<f64>,
    cov: &DMatrix<f64>,
) -> Option<Option<(f64, f64)>> {
    macro_rules! sized {
        ($($m:literal, $n:literal);*) => {
            match (eta.len(), h.ncols()) {
                (1, 0) => Some(tentative::<1>(eta, cov_eta)),
                (2, 0) => Some(tentative::<2>(eta, cov_eta)),
                (3, 0) => Some(tentative::<3>(eta, cov_eta)),
                $(($m, $n) => Some(confirmed::<$m, $n>(eta, cov_eta, h, cov)),)*
                _ => None,
            }
        };
    }
    if !consistent(eta, cov_eta, h, cov) {
        return None;
    }
    sized!(1, 1; 1, 2; 1, 3; 1, 4; 2, 1; 2, 2; 2, 3; 2, 4; 3, 1; 3, 2; 3, 3; 3, 4)
}

/// The EKF step `dx = -K eta` and the Joseph-form covariance of
/// [`super::landmark::Landmark::update_linearized`]. `None` when the size is not a stack
/// size; `Some(None)` when `S` is not positive definite.
#[cfg(test)]
pub(super) fn update(
    eta: &DVector<f64>,
    cov_eta: &DMatrix<f64>,
    h: &DMatrix<f64>,
    cov: &DMatrix<f64>,
) -> Option<Option<(DVector<f64>, DMatrix<f64>)>> {
    let (mut dx, mut updated) = (DVector::zeros(0), DMatrix::zeros(0, 0));
    update_into(eta, cov_eta, h, cov, &mut dx, &mut updated)
        .map(|written| written.map(|()| (dx, updated)))
}

/// [`update`] written into `dx` and `updated` (their storage reused).
pub(super) fn update_into(
    eta: &DVector<f64>,
    cov_eta: &DMatrix<f64>,
    h: &DMatrix<f64>,
    cov: &DMatrix<f64>,
    dx: &mut DVector<f64>,
    updated: &mut DMatrix<f64>,
) -> Option<Option<()>> {
    macro_rules! sized {
        ($($m:literal, $n:literal);*) => {
            match (eta.len(), h.ncols()) {
                $(($m, $n) => Some(step::<$m, $n>(eta, cov_eta, h, cov).map(|(d, c)| {
                    assign_vector(dx, d.as_slice());
                    assign_matrix(updated, &c);
                })),)*
                _ => None,
            }
        };
    }
    if !consistent(eta, cov_eta, h, cov) {
        return None;
    }
    sized!(1, 1; 1, 2; 1, 3; 1, 4; 2, 1; 2, 2; 2, 3; 2, 4; 3, 1; 3, 2; 3, 3; 3, 4)
}

/// Whether the shapes chain: `eta` m, `C` m x m, `H` m x n, `P` n x n.
fn consistent(
    eta: &DVector<f64>,
    cov_eta: &DMatrix<f64>,
    h: &DMatrix<f64>,
    cov: &DMatrix<f64>,
) -> bool {
    cov_eta.shape() == (eta.len(), eta.len())
        && h.nrows() == eta.len()
        && cov.shape() == (h.ncols(), h.ncols())
}

fn tentative<const M: usize>(eta: &DVector<f64>, cov_eta: &DMatrix<f64>) -> Option<(f64, f64)> {
    let c = SMatrix::<f64, M, M>::from_column_slice(cov_eta.as_slice());
    log_normal(
        &SVector::<f64, M>::from_column_slice(eta.as_slice()),
        &(c * 2.0),
    )
}

fn confirmed<const M: usize, const N: usize>(
    eta: &DVector<f64>,
    cov_eta: &DMatrix<f64>,
    h: &DMatrix<f64>,
    cov: &DMatrix<f64>,
) -> Option<(f64, f64)> {
    let h = SMatrix::<f64, M, N>::from_column_slice(h.as_slice());
    let p = SMatrix::<f64, N, N>::from_column_slice(cov.as_slice());
    let c = SMatrix::<f64, M, M>::from_column_slice(cov_eta.as_slice());
    let s = h * p * h.transpose() + c;
    log_normal(&SVector::<f64, M>::from_column_slice(eta.as_slice()), &s)
}

fn step<const M: usize, const N: usize>(
    eta: &DVector<f64>,
    cov_eta: &DMatrix<f64>,
    h: &DMatrix<f64>,
    cov: &DMatrix<f64>,
) -> Option<(SVector<f64, N>, SMatrix<f64, N, N>)> {
    let eta = SVector::<f64, M>::from_column_slice(eta.as_slice());
    let h = SMatrix::<f64, M, N>::from_column_slice(h.as_slice());
    let p = SMatrix::<f64, N, N>::from_column_slice(cov.as_slice());
    let c = SMatrix::<f64, M, M>::from_column_slice(cov_eta.as_slice());
    let ph_t = p * h.transpose();
    let cholesky = (h * ph_t + c).cholesky()?;
    let k = cholesky.solve(&ph_t.transpose()).transpose();
    let dx = -(k * eta);
    let i_kh = SMatrix::<f64, N, N>::identity() - k * h;
    let updated = i_kh * p * i_kh.transpose() + k * c * k.transpose();
    Some((dx, 0.5 * (updated + updated.transpose())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// A random symmetric positive definite `n x n` matrix from `seed`.
    fn spd(n: usize, seed: u64) -> DMatrix<f64> {
        let a = random(n, n, seed);
        &a * a.transpose() + DMatrix::identity(n, n) * 0.1
    }

    fn random(rows: usize, cols: usize, seed: u64) -> DMatrix<f64> {
        let mut state = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        DMatrix::from_fn(rows, cols, |_, _| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        })
    }

    /// The dynamic formulas of `Landmark::likelihood` and `Landmark::update_linearized`.
    fn dynamic(
        eta: &DVector<f64>,
        cov_eta: &DMatrix<f64>,
        h: &DMatrix<f64>,
        cov: &DMatrix<f64>,
    ) -> ((f64, f64), DVector<f64>, DMatrix<f64>) {
        let s = h * cov * h.transpose() + cov_eta;
        let likelihood = crate::particles::log_normal(eta, &s).unwrap();
        let ph_t = cov * h.transpose();
        let s = h * &ph_t + cov_eta;
        let k = s.cholesky().unwrap().solve(&ph_t.transpose()).transpose();
        let dx = -(&k * eta);
        let i_kh = DMatrix::identity(h.ncols(), h.ncols()) - &k * h;
        let updated = &i_kh * cov * i_kh.transpose() + &k * cov_eta * k.transpose();
        (likelihood, dx, 0.5 * (&updated + updated.transpose()))
    }

    #[test]
    fn stack_sizes_agree_with_the_dynamic_formulas() {
        let mut seed = 1;
        for m in 1..=3 {
            for n in 1..=4 {
                for _ in 0..5 {
                    seed += 1;
                    let eta = DVector::from_column_slice(random(m, 1, seed).as_slice());
                    let cov_eta = spd(m, seed + 100);
                    let h = random(m, n, seed + 200);
                    let cov = spd(n, seed + 300);
                    let (likelihood, dx, updated) = dynamic(&eta, &cov_eta, &h, &cov);
                    let small = log_likelihood(&eta, &cov_eta, &h, &cov).unwrap().unwrap();
                    assert_relative_eq!(small.0, likelihood.0, epsilon = 1e-10);
                    assert_relative_eq!(small.1, likelihood.1, epsilon = 1e-10);
                    let (small_dx, small_cov) = update(&eta, &cov_eta, &h, &cov).unwrap().unwrap();
                    assert_relative_eq!(small_dx, dx, epsilon = 1e-10);
                    assert_relative_eq!(small_cov, updated, epsilon = 1e-10);
                }
                let tentative = DMatrix::zeros(m, 0);
                let eta = DVector::from_element(m, 0.3);
                let cov_eta = spd(m, seed + 400);
                let expected = crate::particles::log_normal(&eta, &(&cov_eta * 2.0)).unwrap();
                let small = log_likelihood(&eta, &cov_eta, &tentative, &DMatrix::zeros(0, 0))
                    .unwrap()
                    .unwrap();
                assert_relative_eq!(small.0, expected.0, epsilon = 1e-10);
            }
        }
    }

    #[test]
    fn other_sizes_and_bad_matrices_are_told_apart() {
        let eta = DVector::from_element(4, 0.1);
        let h = DMatrix::zeros(4, 2);
        assert!(log_likelihood(&eta, &spd(4, 1), &h, &spd(2, 2)).is_none());
        assert!(update(&eta, &spd(4, 1), &h, &spd(2, 2)).is_none());
        // A stack size whose S is not positive definite.
        let eta = DVector::from_element(2, 0.1);
        let negative = -spd(2, 3);
        let h = DMatrix::zeros(2, 2);
        assert_eq!(log_likelihood(&eta, &negative, &h, &spd(2, 4)), Some(None));
        assert!(matches!(
            update(&eta, &negative, &h, &spd(2, 4)),
            Some(None)
        ));
    }
}
