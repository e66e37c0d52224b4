//! The dense state covariance of an EKF, in faer: the one module where faer types live
//! (DESIGN.md: "large dense covariance work in faer, kept behind one internal module").
//!
//! Only the **lower triangle** (with the diagonal) is stored and kept up to date; reads go
//! through [`StateCovariance::get`], which mirrors. The update `C -= W W^T` then touches the
//! lower half of `C` once per step (faer's triangular matmul), which is as fast as memory
//! bandwidth allows (`../shared/DEPENDENCIES.md`: about 3.3 ms at n = 3000).

use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{Accum, Mat, Par};
use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{Error, Result};

/// A symmetric positive semi-definite covariance over the state rows `0..dim`, with the
/// directions the measurements cannot observe (see [`StateCovariance::generators`]).
#[derive(Clone, Debug)]
pub(crate) struct StateCovariance {
    /// Lower triangle valid; entries above the diagonal are unspecified.
    lower: Mat<f64>,
    /// Rows and columns reserved (faer keeps its capacity private).
    capacity: usize,
    /// `dim x 3`: the state change of a world translation along x, along y and a rotation
    /// about z, as the filter's linearizations have carried it (observability-constrained
    /// EKF, Huang, Mourikis & Roumeliotis 2010): each row is set when the row is created and
    /// then follows the same linear maps as the covariance (prediction, re-parameterization),
    /// never the updates.
    generators: DMatrix<f64>,
}

impl StateCovariance {
    /// A zero covariance of dimension `dim`.
    pub(crate) fn zeros(dim: usize) -> Self {
        StateCovariance {
            lower: Mat::zeros(dim, dim),
            capacity: dim,
            generators: DMatrix::zeros(dim, 3),
        }
    }

    /// The number of state rows.
    pub(crate) fn dim(&self) -> usize {
        self.lower.nrows()
    }

    /// Entry `(i, j)` (either triangle).
    pub(crate) fn get(&self, i: usize, j: usize) -> f64 {
        if i >= j {
            self.lower[(i, j)]
        } else {
            self.lower[(j, i)]
        }
    }

    /// The block `C[rows, cols]` as a small dense matrix.
    pub(crate) fn gather(&self, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
        DMatrix::from_fn(rows.len(), cols.len(), |a, b| self.get(rows[a], cols[b]))
    }

    /// `C[:, cols]` as a faer matrix (`dim x cols.len()`).
    fn columns(&self, cols: &[usize]) -> Mat<f64> {
        let n = self.dim();
        let mut out = Mat::zeros(n, cols.len());
        for (b, &j) in cols.iter().enumerate() {
            let column = out.col_as_slice_mut(b);
            // Rows below the diagonal: contiguous in column j.
            column[j..n].copy_from_slice(&self.lower.col_as_slice(j)[j..n]);
            // Rows above: row j of the lower triangle.
            for (i, value) in column.iter_mut().enumerate().take(j) {
                *value = self.lower[(j, i)];
            }
        }
        out
    }

    /// The unobservable directions on the rows `indices` (`indices.len() x 3`).
    pub(crate) fn generators(&self, indices: &[usize]) -> DMatrix<f64> {
        self.generators.select_rows(indices)
    }

    /// Appends `block.nrows()` rows with covariance `block`, cross-covariance `cross`
    /// (`block.nrows() x dim`, or zero when `None`) with the existing rows, and unobservable
    /// directions `generators` (`block.nrows() x 3`); returns their indices. Capacity grows
    /// geometrically, so appending is amortized `O(dim)` per row.
    pub(crate) fn append(
        &mut self,
        block: &DMatrix<f64>,
        cross: Option<&DMatrix<f64>>,
        generators: &DMatrix<f64>,
    ) -> std::ops::Range<usize> {
        let old = self.dim();
        let added = block.nrows();
        let new = old + added;
        let mut stacked = DMatrix::zeros(new, 3);
        stacked.rows_mut(0, old).copy_from(&self.generators);
        if generators.shape() == (added, 3) {
            stacked.rows_mut(old, added).copy_from(generators);
        }
        self.generators = stacked;
        if self.capacity < new {
            self.capacity = new.max(2 * old).max(16);
            self.lower.reserve(self.capacity, self.capacity);
        }
        self.lower.resize_with(new, new, |_, _| 0.0);
        for a in 0..added {
            for b in 0..=a {
                self.lower[(old + a, old + b)] = 0.5 * (block[(a, b)] + block[(b, a)]);
            }
            if let Some(cross) = cross {
                for j in 0..old {
                    self.lower[(old + a, j)] = cross[(a, j)];
                }
            }
        }
        old..new
    }

    /// The prediction step (eqs. 26-27) on the pose rows `0..d`:
    /// `C_rr = J_rr C_rr J_rr^T + added`, `C_rp = J_rr C_rp`.
    pub(crate) fn predict(&mut self, d_pose_d_pose: &DMatrix<f64>, added: &DMatrix<f64>) {
        let d = d_pose_d_pose.nrows();
        let n = self.dim();
        let pose: Vec<usize> = (0..d).collect();
        let c_rr = self.gather(&pose, &pose);
        let new_rr = d_pose_d_pose * c_rr * d_pose_d_pose.transpose() + added;
        for i in 0..d {
            for j in 0..=i {
                self.lower[(i, j)] = 0.5 * (new_rr[(i, j)] + new_rr[(j, i)]);
            }
        }
        let moved = d_pose_d_pose * self.generators.rows(0, d);
        self.generators.rows_mut(0, d).copy_from(&moved);
        // Rows d.. of columns 0..d hold C_pr = C_rp^T; C_pr <- C_pr J_rr^T, column by
        // column (contiguous in the column-major lower triangle).
        let old: Vec<Vec<f64>> = (0..d)
            .map(|l| self.lower.col_as_slice(l)[d..n].to_vec())
            .collect();
        for k in 0..d {
            let column = &mut self.lower.col_as_slice_mut(k)[d..n];
            column.fill(0.0);
            for (l, old_column) in old.iter().enumerate() {
                let weight = d_pose_d_pose[(k, l)];
                for (value, old_value) in column.iter_mut().zip(old_column) {
                    *value += old_value * weight;
                }
            }
        }
    }

    /// The EKF update (eqs. 28-32) for a linearized measurement touching the state rows
    /// `indices`: `h` is `J_eta,state` restricted to those columns (`m x indices.len()`),
    /// `r` the innovation noise `C_eta` and `eta` the innovation.
    ///
    /// With `S = H C H^T + R = L L^T` and `W = C H^T L^{-T}`, the state change is
    /// `dx = -W L^{-1} eta` (eq. 31) and the covariance becomes `C - W W^T` (eq. 32), a
    /// symmetric rank-m downdate that keeps `C` symmetric by construction (the symmetric
    /// equivalent of the Joseph form for the optimal gain). Returns `dx` over all rows.
    #[cfg(test)]
    pub(crate) fn update(
        &mut self,
        indices: &[usize],
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
        eta: &DVector<f64>,
    ) -> Result<DVector<f64>> {
        let prepared = self.prepare_update(indices, h, r, eta)?;
        let dx = prepared.dx.clone();
        self.commit(prepared);
        Ok(dx)
    }

    /// The state change and gain of [`StateCovariance::update`], without touching the
    /// covariance: [`StateCovariance::commit`] applies it once the state change is accepted.
    pub(crate) fn prepare_update(
        &self,
        indices: &[usize],
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
        eta: &DVector<f64>,
    ) -> Result<PreparedUpdate> {
        let n = self.dim();
        let m = h.nrows();
        if h.ncols() != indices.len() || r.shape() != (m, m) || eta.len() != m {
            return Err(Error::DimensionMismatch {
                what: "EKF update".into(),
                expected: m,
                got: eta.len(),
            });
        }
        if m == 0 {
            return Ok(PreparedUpdate {
                w: Mat::zeros(n, 0),
                dx: DVector::zeros(n),
            });
        }
        // C H^T over the nonzeros of H only: each measurement row touches the pose and one
        // feature's rows, so H is block-sparse and this is O(n nnz(H)) instead of O(n m |T|).
        let c_cols = self.columns(indices);
        let mut pht = Mat::<f64>::zeros(n, m);
        for (t, column) in (0..indices.len()).map(|t| (t, c_cols.col_as_slice(t))) {
            for r in 0..m {
                let weight = h[(r, t)];
                if weight != 0.0 {
                    for (target, value) in pht.col_as_slice_mut(r).iter_mut().zip(column) {
                        *target += weight * value;
                    }
                }
            }
        }
        let pht_t = DMatrix::from_fn(indices.len(), m, |a, b| pht[(indices[a], b)]);
        let s = h * pht_t + r;
        let s = 0.5 * (&s + s.transpose());
        let cholesky = s
            .cholesky()
            .ok_or_else(|| Error::Singular("innovation covariance S of an EKF update".into()))?;
        // W = C H^T L^{-T}: W^T = L^{-1} (C H^T)^T by forward substitution, in place on the
        // transposed view of C H^T (m^2 n / 2 operations, in faer).
        let l = to_faer(&cholesky.l());
        if (0..m).any(|i| l[(i, i)] == 0.0) {
            return Err(Error::Singular("Cholesky factor of S".into()));
        }
        let mut w = pht;
        solve_lower_triangular_in_place(l.as_ref(), w.as_mut().transpose_mut(), Par::Seq);
        let mut whitened = Mat::<f64>::from_fn(m, 1, |i, _| eta[i]);
        solve_lower_triangular_in_place(l.as_ref(), whitened.as_mut(), Par::Seq);
        let mut dx = DVector::<f64>::zeros(n);
        for k in 0..m {
            let weight = whitened[(k, 0)];
            for (value, w_ik) in dx.iter_mut().zip(w.col_as_slice(k)) {
                *value -= w_ik * weight;
            }
        }
        if !dx.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite("EKF state change".into()));
        }
        Ok(PreparedUpdate { w, dx })
    }

    /// Applies a prepared update's covariance downdate `C -= W W^T`.
    pub(crate) fn commit(&mut self, prepared: PreparedUpdate) {
        if prepared.w.ncols() == 0 || prepared.w.nrows() != self.dim() {
            return;
        }
        triangular::matmul(
            &mut self.lower,
            BlockStructure::TriangularLower,
            Accum::Add,
            &prepared.w,
            BlockStructure::Rectangular,
            prepared.w.transpose(),
            BlockStructure::Rectangular,
            -1.0,
            Par::Seq,
        );
    }

    /// Replaces the rows `old` by `t.nrows()` new rows `t dx_old` (a linear
    /// re-parameterization, e.g. two walls joined at a corner): appends the new rows, drops
    /// the old ones, and returns the map from old to new row indices (`None` for dropped
    /// rows; the appended rows come last, in order).
    pub(crate) fn reparameterize(
        &mut self,
        old: &[usize],
        t: &DMatrix<f64>,
    ) -> Result<Vec<Option<usize>>> {
        if t.ncols() != old.len() {
            return Err(Error::DimensionMismatch {
                what: "re-parameterization".into(),
                expected: old.len(),
                got: t.ncols(),
            });
        }
        let n = self.dim();
        let all: Vec<usize> = (0..n).collect();
        let c_old_all = self.gather(old, &all);
        let cross = t * &c_old_all; // new x all
        let c_old_old = self.gather(old, old);
        let block = t * c_old_old * t.transpose();
        let generators = t * self.generators(old);
        self.append(&block, Some(&cross), &generators);
        let mut dropped = vec![false; n + t.nrows()];
        for &i in old {
            dropped[i] = true;
        }
        Ok(self.compact(&dropped))
    }

    /// Maps the rows `rows` in place by the square `t`: `dx_rows' = t dx_rows`, so
    /// `C[rows, :] <- t C[rows, :]` and `C[rows, rows] <- t C[rows, rows] t^T`; `O(n k)`.
    pub(crate) fn transform_rows(&mut self, rows: &[usize], t: &DMatrix<f64>) -> Result<()> {
        let k = rows.len();
        if t.shape() != (k, k) {
            return Err(Error::DimensionMismatch {
                what: "row transform".into(),
                expected: k,
                got: t.nrows(),
            });
        }
        let n = self.dim();
        let all: Vec<usize> = (0..n).collect();
        let mut new_rows = t * self.gather(rows, &all);
        let block = new_rows.select_columns(rows) * t.transpose();
        for a in 0..k {
            for (b, &j) in rows.iter().enumerate() {
                new_rows[(a, j)] = 0.5 * (block[(a, b)] + block[(b, a)]);
            }
        }
        let moved = t * self.generators(rows);
        for (a, &i) in rows.iter().enumerate() {
            self.generators.row_mut(i).copy_from(&moved.row(a));
        }
        for (a, &i) in rows.iter().enumerate() {
            for j in 0..n {
                let value = new_rows[(a, j)];
                if i >= j {
                    self.lower[(i, j)] = value;
                } else {
                    self.lower[(j, i)] = value;
                }
            }
        }
        Ok(())
    }

    /// Removes the rows flagged in `dropped`; returns the old-to-new index map.
    pub(crate) fn compact(&mut self, dropped: &[bool]) -> Vec<Option<usize>> {
        let n = self.dim();
        let mut map = vec![None; n];
        let mut kept = Vec::with_capacity(n);
        for (i, slot) in map.iter_mut().enumerate() {
            if !dropped.get(i).copied().unwrap_or(false) {
                *slot = Some(kept.len());
                kept.push(i);
            }
        }
        let mut lower = Mat::zeros(kept.len(), kept.len());
        for (b, &j) in kept.iter().enumerate() {
            for (a, &i) in kept.iter().enumerate().skip(b) {
                lower[(a, b)] = self.lower[(i.max(j), i.min(j))];
            }
        }
        self.capacity = kept.len();
        self.lower = lower;
        self.generators = self.generators.select_rows(&kept);
        map
    }

    /// The whole covariance as a dense symmetric matrix (tests and small states only).
    pub(crate) fn to_dense(&self) -> DMatrix<f64> {
        let n = self.dim();
        DMatrix::from_fn(n, n, |i, j| self.get(i, j))
    }
}

/// An EKF update computed but not yet applied to the covariance.
#[derive(Debug)]
pub(crate) struct PreparedUpdate {
    /// `W = C H^T L^{-T}` (`dim x m`).
    w: Mat<f64>,
    /// The state change `dx` (eq. 31).
    pub(crate) dx: DVector<f64>,
}

/// A faer copy of a small nalgebra matrix.
fn to_faer(m: &DMatrix<f64>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_spd(n: usize, seed: u64) -> DMatrix<f64> {
        let mut state = seed;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let a = DMatrix::from_fn(n, n, |_, _| next());
        &a * a.transpose() + DMatrix::identity(n, n) * 0.1
    }

    fn from_dense(c: &DMatrix<f64>) -> StateCovariance {
        let mut cov = StateCovariance::zeros(0);
        cov.append(c, None, &DMatrix::zeros(c.nrows(), 3));
        cov
    }

    #[test]
    fn update_matches_the_textbook_equations() {
        let n = 9;
        let c = random_spd(n, 3);
        let mut cov = from_dense(&c);
        let indices = [0, 1, 2, 6, 7];
        let h_small = DMatrix::from_fn(2, 5, |i, j| (i + 2 * j) as f64 * 0.1 - 0.3);
        let mut h = DMatrix::zeros(2, n);
        for (b, &j) in indices.iter().enumerate() {
            h.column_mut(j).copy_from(&h_small.column(b));
        }
        let r = DMatrix::from_row_slice(2, 2, &[0.04, 0.01, 0.01, 0.09]);
        let eta = DVector::from_vec(vec![0.3, -0.2]);
        let dx = cov.update(&indices, &h_small, &r, &eta).unwrap();
        let s = &h * &c * h.transpose() + &r;
        let k = &c * h.transpose() * s.try_inverse().unwrap();
        let expected_dx = -&k * &eta;
        let expected_c = &c - &k * &h * &c;
        assert!((dx - expected_dx).amax() < 1e-12);
        assert!((cov.to_dense() - expected_c).amax() < 1e-12);
    }

    #[test]
    fn predict_matches_eqs_26_27() {
        let c = random_spd(7, 5);
        let mut cov = from_dense(&c);
        let j = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, -0.4, 0.0, 1.0, 0.7, 0.0, 0.0, 1.0]);
        let q = DMatrix::from_diagonal(&DVector::from_vec(vec![0.01, 0.02, 0.003]));
        cov.predict(&j, &q);
        let mut f = DMatrix::identity(7, 7);
        f.view_mut((0, 0), (3, 3)).copy_from(&j);
        let mut expected = &f * &c * f.transpose();
        let mut block = expected.view_mut((0, 0), (3, 3));
        block += &q;
        assert!((cov.to_dense() - expected).amax() < 1e-12);
    }

    #[test]
    fn append_reparameterize_and_compact_keep_the_covariance() {
        let c = random_spd(6, 7);
        let mut cov = from_dense(&c);
        let extra = random_spd(2, 9);
        let cross = DMatrix::from_fn(2, 6, |i, j| 0.01 * (i + j) as f64);
        let rows = cov.append(&extra, Some(&cross), &DMatrix::zeros(2, 3));
        assert_eq!(rows, 6..8);
        assert!((cov.gather(&[6, 7], &[6, 7]) - &extra).amax() < 1e-15);
        assert_eq!(cov.get(2, 7), cross[(1, 2)]);
        // Replace rows 1 and 4 by their sum and difference.
        let before = cov.to_dense();
        let t = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 1.0, -1.0]);
        let map = cov.reparameterize(&[1, 4], &t).unwrap();
        assert_eq!(map[1], None);
        assert_eq!(map[4], None);
        assert_eq!(map[0], Some(0));
        assert_eq!(map[5], Some(3));
        assert_eq!(cov.dim(), 8);
        let sum_var = before[(1, 1)] + before[(4, 4)] + 2.0 * before[(1, 4)];
        assert!((cov.get(6, 6) - sum_var).abs() < 1e-12);
        let cross_sum = before[(0, 1)] + before[(0, 4)];
        assert!((cov.get(0, 6) - cross_sum).abs() < 1e-12);
    }

    #[test]
    fn transform_rows_matches_the_dense_product() {
        let c = random_spd(7, 11);
        let mut cov = from_dense(&c);
        let rows = [5, 2];
        let t = DMatrix::from_row_slice(2, 2, &[1.0, 0.3, -0.2, 1.5]);
        cov.transform_rows(&rows, &t).unwrap();
        let mut f = DMatrix::identity(7, 7);
        for (a, &i) in rows.iter().enumerate() {
            for (b, &j) in rows.iter().enumerate() {
                f[(i, j)] = t[(a, b)];
            }
        }
        let expected = &f * &c * f.transpose();
        assert!((cov.to_dense() - expected).amax() < 1e-12);
    }

    #[test]
    fn singular_innovation_is_an_error() {
        let mut cov = StateCovariance::zeros(3);
        let h = DMatrix::identity(2, 2);
        let r = DMatrix::zeros(2, 2);
        let eta = DVector::zeros(2);
        assert!(cov.update(&[0, 1], &h, &r, &eta).is_err());
    }
}
