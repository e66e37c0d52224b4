//! The state covariance of an EKF, in faer: the one module where faer types live
//! (DESIGN.md: "large dense covariance work in faer, kept behind one internal module").
//!
//! Only the **lower triangle** (with the diagonal) of the correlated rows is stored and kept
//! up to date; reads go through [`StateCovariance::get`], which mirrors. The update
//! `C -= W W^T` then touches the lower half of that block once per step (faer's triangular
//! matmul), which is as fast as memory bandwidth allows (`../shared/DEPENDENCIES.md`: about
//! 3.3 ms at n = 3000).
//!
//! **Rows that nothing correlates** (a tree's radius: its residual depends on the radius
//! alone, and its prior is uncorrelated) are kept apart, as a variance, not as a row and a
//! column of zeros in the dense block. A measurement row whose Jacobian touches only such a
//! row, with noise uncorrelated with the other rows, updates it on its own (the dense update
//! with that row and column included would give the same result: the covariance and the
//! noise are block-diagonal); anything that would correlate it (another measurement row
//! touching it, a cross-covariance, a re-parameterization) first moves it into the dense
//! block. On Victoria Park a third of the state and of every update's rank are radii, so the
//! dense downdate, `O(n^2 m)`, shrinks to about `(2/3)^3` of the work.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{Accum, Mat, Par};
use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{Error, Result};

/// Where a state row's covariance is kept.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    /// Row and column `k` of the dense lower triangle.
    Dense(usize),
    /// A row uncorrelated with every other row: its variance.
    Alone(f64),
}

/// A symmetric positive semi-definite covariance over the state rows `0..dim`, with the
/// directions the measurements cannot observe (see [`StateCovariance::generators`]).
#[derive(Clone, Debug)]
pub(crate) struct StateCovariance {
    /// Lower triangle valid over the dense rows (in the order of `dense_rows`); entries above
    /// the diagonal are unspecified.
    lower: Mat<f64>,
    /// Rows and columns reserved (faer keeps its capacity private).
    capacity: usize,
    /// Where each state row is kept.
    slots: Vec<Slot>,
    /// The state row of each dense row. The first state rows (the pose, created by
    /// [`StateCovariance::dense`]) are the first dense rows, in order: rows are appended at
    /// the end and [`StateCovariance::compact`] keeps the order.
    dense_rows: Vec<usize>,
    /// `dim x 3`: the state change of a world translation along x, along y and a rotation
    /// about z, as the filter's linearizations have carried it (observability-constrained
    /// EKF, Huang, Mourikis & Roumeliotis 2010): each row is set when the row is created and
    /// then follows the same linear maps as the covariance (prediction, re-parameterization),
    /// never the updates.
    generators: DMatrix<f64>,
    /// The pose transition `J = J_k ... J_1` of the predictions since the cross-covariance
    /// of the pose with the other rows was last brought up to date, or `None` when it is:
    /// the true `C_pr` is the stored one times `J^T`. Odometry usually comes faster than the
    /// sensors (10 predictions per laser frame on Victoria Park), so the `O(n)` pass of the
    /// prediction runs once per update instead of once per prediction.
    pending: Option<DMatrix<f64>>,
}

/// An EKF update computed but not yet applied to the covariance.
#[derive(Debug)]
pub(crate) struct PreparedUpdate {
    /// `W = C H^T L^{-T}` over the dense rows (`dense rows x m`).
    w: Mat<f64>,
    /// The new variances of the rows updated on their own: `(state row, variance)`.
    alone: Vec<(usize, f64)>,
    /// The state change `dx` (eq. 31).
    pub(crate) dx: DVector<f64>,
}

impl StateCovariance {
    /// A zero covariance of dimension `dim` (every row dense).
    #[cfg(test)]
    pub(crate) fn zeros(dim: usize) -> Self {
        StateCovariance {
            lower: Mat::zeros(dim, dim),
            capacity: dim,
            slots: (0..dim).map(Slot::Dense).collect(),
            dense_rows: (0..dim).collect(),
            generators: DMatrix::zeros(dim, 3),
            pending: None,
        }
    }

    /// The covariance `block` with unobservable directions `generators`, every row in the
    /// dense block (the pose: [`StateCovariance::predict`] works on the first rows there).
    pub(crate) fn dense(block: &DMatrix<f64>, generators: &DMatrix<f64>) -> Self {
        let mut cov = StateCovariance {
            lower: Mat::zeros(0, 0),
            capacity: 0,
            slots: Vec::new(),
            dense_rows: Vec::new(),
            generators: DMatrix::zeros(0, 3),
            pending: None,
        };
        cov.append_rows(block, None, generators, false);
        cov
    }

    /// The number of state rows.
    pub(crate) fn dim(&self) -> usize {
        self.slots.len()
    }

    /// The number of rows in the dense block.
    fn dense_dim(&self) -> usize {
        self.lower.nrows()
    }

    /// Entry `(i, j)` (either triangle).
    pub(crate) fn get(&self, i: usize, j: usize) -> f64 {
        match (self.slots[i], self.slots[j]) {
            (Slot::Dense(a), Slot::Dense(b)) => {
                let (row, col) = (a.max(b), a.min(b));
                match &self.pending {
                    // A pose row against another: the stored entries times the pending J^T.
                    Some(j) if col < j.nrows() && row >= j.nrows() => (0..j.ncols())
                        .map(|l| self.lower[(row, l)] * j[(col, l)])
                        .sum(),
                    _ => self.lower[(row, col)],
                }
            }
            (Slot::Alone(variance), _) if i == j => variance,
            _ => 0.0,
        }
    }

    /// The block `C[rows, cols]` as a small dense matrix.
    pub(crate) fn gather(&self, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
        DMatrix::from_fn(rows.len(), cols.len(), |a, b| self.get(rows[a], cols[b]))
    }

    /// The dense block's columns `dense_cols` as a faer matrix (`dense rows x cols.len()`).
    fn columns(&self, dense_cols: &[usize]) -> Mat<f64> {
        let n = self.dense_dim();
        let mut out = Mat::zeros(n, dense_cols.len());
        for (b, &j) in dense_cols.iter().enumerate() {
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

    /// [`StateCovariance::generators`] written into `out`, column-major (`indices.len() x
    /// 3`), its storage reused.
    pub(crate) fn generators_into(&self, indices: &[usize], out: &mut Vec<f64>) {
        out.clear();
        for column in 0..3 {
            out.extend(indices.iter().map(|&row| self.generators[(row, column)]));
        }
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
        self.append_rows(block, cross, generators, true)
    }

    /// [`StateCovariance::append`]; with `allow_alone` a new row that nothing correlates is
    /// kept apart from the dense block.
    fn append_rows(
        &mut self,
        block: &DMatrix<f64>,
        cross: Option<&DMatrix<f64>>,
        generators: &DMatrix<f64>,
        allow_alone: bool,
    ) -> std::ops::Range<usize> {
        self.flush();
        let old = self.dim();
        let added = block.nrows();
        let new = old + added;
        let mut stacked = DMatrix::zeros(new, 3);
        stacked.rows_mut(0, old).copy_from(&self.generators);
        if generators.shape() == (added, 3) {
            stacked.rows_mut(old, added).copy_from(generators);
        }
        self.generators = stacked;
        if let Some(cross) = cross {
            for j in 0..old {
                if (0..added).any(|a| cross[(a, j)] != 0.0) {
                    self.promote(j);
                }
            }
        }
        let alone: Vec<bool> = (0..added)
            .map(|a| {
                allow_alone
                    && (0..added).all(|b| b == a || (block[(a, b)] == 0.0 && block[(b, a)] == 0.0))
                    && cross.is_none_or(|cross| cross.row(a).iter().all(|&v| v == 0.0))
            })
            .collect();
        let first_dense = self.dense_dim();
        self.grow_dense(alone.iter().filter(|&&a| !a).count());
        let mut next_dense = first_dense;
        for (a, &is_alone) in alone.iter().enumerate() {
            if is_alone {
                self.slots.push(Slot::Alone(block[(a, a)]));
            } else {
                self.slots.push(Slot::Dense(next_dense));
                self.dense_rows.push(old + a);
                next_dense += 1;
            }
        }
        for a in 0..added {
            let Slot::Dense(row) = self.slots[old + a] else {
                continue;
            };
            for b in 0..added {
                if let Slot::Dense(col) = self.slots[old + b]
                    && col <= row
                {
                    self.lower[(row, col)] = 0.5 * (block[(a, b)] + block[(b, a)]);
                }
            }
            if let Some(cross) = cross {
                for j in 0..old {
                    if let Slot::Dense(col) = self.slots[j] {
                        self.lower[(row, col)] = cross[(a, j)];
                    }
                }
            }
        }
        old..new
    }

    /// Adds `added` zero rows and columns to the dense block (amortized `O(dense rows)` each).
    fn grow_dense(&mut self, added: usize) {
        let new = self.dense_dim() + added;
        if self.capacity < new {
            self.capacity = new.max(2 * self.dense_dim()).max(16);
            self.lower.reserve(self.capacity, self.capacity);
        }
        self.lower.resize_with(new, new, |_, _| 0.0);
    }

    /// Moves state row `row` into the dense block (a no-op when it is there).
    fn promote(&mut self, row: usize) {
        self.flush();
        if let Slot::Alone(variance) = self.slots[row] {
            let k = self.dense_dim();
            self.grow_dense(1);
            self.lower[(k, k)] = variance;
            self.slots[row] = Slot::Dense(k);
            self.dense_rows.push(row);
        }
    }

    /// The prediction step (eqs. 26-27) on the pose rows `0..d`:
    /// `C_rr = J_rr C_rr J_rr^T + added`, `C_rp = J_rr C_rp` (the latter deferred, see
    /// `pending`).
    pub(crate) fn predict(&mut self, d_pose_d_pose: &DMatrix<f64>, added: &DMatrix<f64>) {
        let d = d_pose_d_pose.nrows();
        if self.pending.as_ref().is_some_and(|j| j.nrows() != d) {
            self.flush();
        }
        debug_assert!((0..d).all(|i| self.slots[i] == Slot::Dense(i)));
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
        // C_pr <- C_pr J_rr^T, deferred: the transitions compose until something reads or
        // changes the cross-covariance in place (`flush`).
        self.pending = Some(match self.pending.take() {
            Some(pending) => d_pose_d_pose * pending,
            None => d_pose_d_pose.clone(),
        });
    }

    /// Brings the pose's cross-covariance up to date with the pending transition `J`:
    /// `C_pr <- C_pr J^T`, row by row in one pass over the pose's columns (contiguous in the
    /// column-major lower triangle; rows kept apart have no cross-covariance with the pose).
    /// The filter calls it before an update's association, which reads the cross-covariance
    /// many times.
    pub(crate) fn flush(&mut self) {
        let Some(j) = self.pending.take() else {
            return;
        };
        let d = j.nrows();
        let n = self.dense_dim();
        if d == 3 {
            let (c0, rest) = self.lower.as_mut().split_at_col_mut(1);
            let (c1, c2) = rest.split_at_col_mut(1);
            let (c0, c1, c2) = (c0.col_mut(0), c1.col_mut(0), c2.col_mut(0));
            let (Some(c0), Some(c1), Some(c2)) = (
                c0.try_as_col_major_mut(),
                c1.try_as_col_major_mut(),
                c2.try_as_col_major_mut(),
            ) else {
                self.predict_cross_general(&j);
                return;
            };
            let rows = c0.as_slice_mut()[d..n]
                .iter_mut()
                .zip(&mut c1.as_slice_mut()[d..n])
                .zip(&mut c2.as_slice_mut()[d..n]);
            for ((a, b), c) in rows {
                let (x, y, z) = (*a, *b, *c);
                *a = j[(0, 0)] * x + j[(0, 1)] * y + j[(0, 2)] * z;
                *b = j[(1, 0)] * x + j[(1, 1)] * y + j[(1, 2)] * z;
                *c = j[(2, 0)] * x + j[(2, 1)] * y + j[(2, 2)] * z;
            }
        } else {
            self.predict_cross_general(&j);
        }
    }

    /// `C_pr <- C_pr J_rr^T` for any pose dimension, column by column.
    fn predict_cross_general(&mut self, d_pose_d_pose: &DMatrix<f64>) {
        let d = d_pose_d_pose.nrows();
        let n = self.dense_dim();
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

    /// The state change and gain of [`StateCovariance::update`], without changing the
    /// covariance (it may move rows into the dense block, which changes no value):
    /// [`StateCovariance::commit`] applies it once the state change is accepted.
    ///
    /// The measurement rows that touch only one row kept apart (and whose noise is
    /// uncorrelated with the other rows) update that row on their own; the others make one
    /// dense update.
    pub(crate) fn prepare_update(
        &mut self,
        indices: &[usize],
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
        eta: &DVector<f64>,
    ) -> Result<PreparedUpdate> {
        self.flush();
        let m = h.nrows();
        if h.ncols() != indices.len() || r.shape() != (m, m) || eta.len() != m {
            return Err(Error::DimensionMismatch {
                what: "EKF update".into(),
                expected: m,
                got: eta.len(),
            });
        }
        let separate = self.separate_groups(indices, h, r);
        let mut in_group = vec![false; m];
        for (_, rows) in &separate {
            for &row in rows {
                in_group[row] = true;
            }
        }
        let dense_measurement_rows: Vec<usize> = (0..m).filter(|&row| !in_group[row]).collect();
        let mut dx = DVector::<f64>::zeros(self.dim());
        let w = self.prepare_dense(indices, h, r, eta, &dense_measurement_rows, &mut dx)?;
        let mut alone = Vec::with_capacity(separate.len());
        for (t, rows) in &separate {
            let state_row = indices[*t];
            let Slot::Alone(variance) = self.slots[state_row] else {
                return Err(Error::Invariant("a separate update on a dense row".into()));
            };
            let (change, new_variance) = alone_update(variance, *t, rows, h, r, eta)?;
            dx[state_row] = change;
            alone.push((state_row, new_variance));
        }
        if !dx.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite("EKF state change".into()));
        }
        Ok(PreparedUpdate { w, alone, dx })
    }

    /// The columns `t` of `h` on rows kept apart that a group of measurement rows updates on
    /// its own, with those rows; every other kept-apart column that `h` touches is moved into
    /// the dense block.
    fn separate_groups(
        &mut self,
        indices: &[usize],
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
    ) -> Vec<(usize, Vec<usize>)> {
        let m = h.nrows();
        // The one column each measurement row touches, if it touches exactly one.
        let only_column: Vec<Option<usize>> = (0..m)
            .map(|row| {
                let mut touched = (0..indices.len()).filter(|&t| h[(row, t)] != 0.0);
                match (touched.next(), touched.next()) {
                    (Some(t), None) => Some(t),
                    _ => None,
                }
            })
            .collect();
        let mut groups = Vec::new();
        for (t, &state_row) in indices.iter().enumerate() {
            if !matches!(self.slots[state_row], Slot::Alone(_)) {
                continue;
            }
            let rows: Vec<usize> = (0..m).filter(|&row| h[(row, t)] != 0.0).collect();
            if rows.is_empty() {
                continue;
            }
            let confined = rows.iter().all(|&row| only_column[row] == Some(t));
            let listed_once = indices.iter().filter(|&&i| i == state_row).count() == 1;
            let noise_apart = rows.iter().all(|&a| {
                (0..m).all(|b| rows.contains(&b) || (r[(a, b)] == 0.0 && r[(b, a)] == 0.0))
            });
            if confined && listed_once && noise_apart {
                groups.push((t, rows));
            } else {
                self.promote(state_row);
            }
        }
        groups
    }

    /// The dense update on the measurement rows `rows` (their columns all on dense rows):
    /// writes its state change into `dx` and returns `W` over the dense rows.
    fn prepare_dense(
        &self,
        indices: &[usize],
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
        eta: &DVector<f64>,
        rows: &[usize],
        dx: &mut DVector<f64>,
    ) -> Result<Mat<f64>> {
        let n = self.dense_dim();
        let m = rows.len();
        if m == 0 {
            return Ok(Mat::zeros(n, 0));
        }
        // (column of h, dense row) of every column on a dense row.
        let columns: Vec<(usize, usize)> = indices
            .iter()
            .enumerate()
            .filter_map(|(t, &i)| match self.slots[i] {
                Slot::Dense(k) => Some((t, k)),
                Slot::Alone(_) => None,
            })
            .collect();
        let dense_cols: Vec<usize> = columns.iter().map(|&(_, k)| k).collect();
        // C H^T on the touched columns only (the pose's and the observed features' rows):
        // one product of n x |T| by |T| x m.
        let c_cols = self.columns(&dense_cols);
        // Every measurement row and every column of `h` in order (the usual batch): `h^T`
        // and `R` are copies of the whole matrices.
        let whole = rows.len() == h.nrows()
            && columns.len() == h.ncols()
            && rows.iter().enumerate().all(|(i, &row)| row == i)
            && columns.iter().enumerate().all(|(i, &(t, _))| t == i);
        let h_t = if whole {
            faer::MatRef::from_column_major_slice(h.as_slice(), m, columns.len())
                .transpose()
                .to_owned()
        } else {
            Mat::<f64>::from_fn(columns.len(), m, |c, q| h[(rows[q], columns[c].0)])
        };
        let mut pht = Mat::<f64>::zeros(n, m);
        faer::linalg::matmul::matmul(
            pht.as_mut(),
            Accum::Replace,
            c_cols.as_ref(),
            h_t.as_ref(),
            1.0,
            Par::Seq,
        );
        // S = H C H^T + R, symmetrized, and its lower Cholesky factor L.
        let pht_touched = Mat::<f64>::from_fn(columns.len(), m, |c, q| pht[(columns[c].1, q)]);
        let mut s = if whole {
            faer::MatRef::from_column_major_slice(r.as_slice(), m, m).to_owned()
        } else {
            Mat::<f64>::from_fn(m, m, |a, b| r[(rows[a], rows[b])])
        };
        faer::linalg::matmul::matmul(
            s.as_mut(),
            Accum::Add,
            h_t.transpose(),
            pht_touched.as_ref(),
            1.0,
            Par::Seq,
        );
        let l = lower_cholesky(s)
            .ok_or_else(|| Error::Singular("innovation covariance S of an EKF update".into()))?;
        // W = C H^T L^{-T}: W^T = L^{-1} (C H^T)^T by forward substitution, in place on the
        // transposed view of C H^T (m^2 n / 2 operations, in faer).
        if (0..m).any(|i| l[(i, i)] == 0.0) {
            return Err(Error::Singular("Cholesky factor of S".into()));
        }
        let mut w = pht;
        solve_lower_triangular_in_place(l.as_ref(), w.as_mut().transpose_mut(), Par::Seq);
        let mut whitened = Mat::<f64>::from_fn(m, 1, |q, _| eta[rows[q]]);
        solve_lower_triangular_in_place(l.as_ref(), whitened.as_mut(), Par::Seq);
        let mut dense_dx = vec![0.0; n];
        for k in 0..m {
            let weight = whitened[(k, 0)];
            for (value, w_ik) in dense_dx.iter_mut().zip(w.col_as_slice(k)) {
                *value -= w_ik * weight;
            }
        }
        for (&state_row, value) in self.dense_rows.iter().zip(dense_dx) {
            dx[state_row] = value;
        }
        Ok(w)
    }

    /// Applies a prepared update: the dense downdate `C -= W W^T` and the new variances of
    /// the rows updated on their own.
    pub(crate) fn commit(&mut self, prepared: PreparedUpdate) {
        self.flush();
        if prepared.w.ncols() > 0 && prepared.w.nrows() == self.dense_dim() {
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
        for (row, variance) in prepared.alone {
            if let Slot::Alone(old) = &mut self.slots[row] {
                *old = variance;
            }
        }
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
        self.flush();
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
        let mut cross = t * &c_old_all; // new x all
        // The old rows are dropped below: no cross-covariance with them is kept.
        for &i in old {
            cross.column_mut(i).fill(0.0);
        }
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
    /// The rows move into the dense block.
    pub(crate) fn transform_rows(&mut self, rows: &[usize], t: &DMatrix<f64>) -> Result<()> {
        self.flush();
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
        for &i in rows {
            self.promote(i);
        }
        for (a, &i) in rows.iter().enumerate() {
            let Slot::Dense(row) = self.slots[i] else {
                return Err(Error::Invariant("a transformed row is not dense".into()));
            };
            for j in 0..n {
                // Rows kept apart are uncorrelated with these: their entries are zero.
                if let Slot::Dense(col) = self.slots[j] {
                    self.lower[(row.max(col), row.min(col))] = new_rows[(a, j)];
                }
            }
        }
        Ok(())
    }

    /// Removes the rows flagged in `dropped`; returns the old-to-new index map.
    pub(crate) fn compact(&mut self, dropped: &[bool]) -> Vec<Option<usize>> {
        self.flush();
        let n = self.dim();
        let is_dropped = |i: usize| dropped.get(i).copied().unwrap_or(false);
        let mut map = vec![None; n];
        let mut kept = Vec::with_capacity(n);
        for (i, slot) in map.iter_mut().enumerate() {
            if !is_dropped(i) {
                *slot = Some(kept.len());
                kept.push(i);
            }
        }
        // The kept dense rows, in their dense order (so the pose stays first).
        let kept_dense: Vec<usize> = (0..self.dense_dim())
            .filter(|&k| !is_dropped(self.dense_rows[k]))
            .collect();
        // In place, in the storage's order (column-major): entry (a, b) of the kept block
        // comes from (i, j) with i >= a and j >= b, which lies at or after it in storage and
        // is read before anything is written there. The reserved capacity stays, so the
        // dense block grows again without a new allocation.
        let m = kept_dense.len();
        for (b, &j) in kept_dense.iter().enumerate() {
            for (a, &i) in kept_dense.iter().enumerate().skip(b) {
                self.lower[(a, b)] = self.lower[(i, j)];
            }
            for a in 0..b {
                self.lower[(a, b)] = 0.0;
            }
        }
        self.lower.truncate(m, m);
        let mut slots: Vec<Slot> = kept.iter().map(|&i| self.slots[i]).collect();
        let mut dense_rows = Vec::with_capacity(kept_dense.len());
        for (new_dense, &k) in kept_dense.iter().enumerate() {
            let Some(new_row) = map[self.dense_rows[k]] else {
                continue;
            };
            slots[new_row] = Slot::Dense(new_dense);
            dense_rows.push(new_row);
        }
        self.slots = slots;
        self.dense_rows = dense_rows;
        self.generators = self.generators.select_rows(&kept);
        map
    }

    /// The whole covariance as a dense symmetric matrix (tests and small states only).
    pub(crate) fn to_dense(&self) -> DMatrix<f64> {
        let n = self.dim();
        DMatrix::from_fn(n, n, |i, j| self.get(i, j))
    }
}

/// The update of one row kept apart, of variance `variance`, by the measurement rows `rows`
/// (which touch only column `t` of `h`): eqs. 28-32 for a one-row state, in the same form as
/// the dense update. Returns the state change and the new variance.
fn alone_update(
    variance: f64,
    t: usize,
    rows: &[usize],
    h: &DMatrix<f64>,
    r: &DMatrix<f64>,
    eta: &DVector<f64>,
) -> Result<(f64, f64)> {
    let k = rows.len();
    let h_column = DVector::from_fn(k, |a, _| h[(rows[a], t)]);
    let r_block = DMatrix::from_fn(k, k, |a, b| r[(rows[a], rows[b])]);
    let s = &h_column * h_column.transpose() * variance + r_block;
    let s = 0.5 * (&s + s.transpose());
    let cholesky = s
        .cholesky()
        .ok_or_else(|| Error::Singular("innovation covariance S of an EKF update".into()))?;
    let l = cholesky.l();
    let singular = || Error::Singular("Cholesky factor of S".into());
    let w = l
        .solve_lower_triangular(&(h_column * variance))
        .ok_or_else(singular)?;
    let eta_rows = DVector::from_fn(k, |a, _| eta[rows[a]]);
    let whitened = l.solve_lower_triangular(&eta_rows).ok_or_else(singular)?;
    Ok((-w.dot(&whitened), variance - w.dot(&w)))
}

/// The lower Cholesky factor of the symmetric part of `s` (`None` when that is not positive
/// definite), on one thread.
fn lower_cholesky(mut s: Mat<f64>) -> Option<Mat<f64>> {
    let m = s.nrows();
    for j in 0..m {
        for i in j + 1..m {
            s[(i, j)] = 0.5 * (s[(i, j)] + s[(j, i)]);
        }
    }
    let par = Par::Seq;
    let mut memory = MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
        m,
        par,
        Default::default(),
    ));
    llt::factor::cholesky_in_place(
        s.as_mut(),
        Default::default(),
        par,
        MemStack::new(&mut memory),
        Default::default(),
    )
    .ok()?;
    for j in 1..m {
        for i in 0..j {
            s[(i, j)] = 0.0;
        }
    }
    Some(s)
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

    /// The `n x n` map of [`StateCovariance::transform_rows`]: `t` on `rows`, identity elsewhere.
    fn rows_transform(n: usize, rows: &[usize], t: &DMatrix<f64>) -> DMatrix<f64> {
        let mut f = DMatrix::identity(n, n);
        for (a, &i) in rows.iter().enumerate() {
            for (b, &j) in rows.iter().enumerate() {
                f[(i, j)] = t[(a, b)];
            }
        }
        f
    }

    /// The `n x n` transition of [`StateCovariance::predict`]: `j` on the pose rows.
    fn pose_transition(n: usize, j: &DMatrix<f64>) -> DMatrix<f64> {
        let mut f = DMatrix::identity(n, n);
        f.view_mut((0, 0), j.shape()).copy_from(j);
        f
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
        let f = pose_transition(7, &j);
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

    /// Compaction works in place and keeps the storage: the kept block is the old one's rows
    /// and columns, nothing of the dropped rows shows through after the block grows again
    /// into the same storage, and an update afterwards is the textbook one.
    #[test]
    fn compact_in_place_then_grow_again() {
        let c = random_spd(10, 11);
        let mut cov = from_dense(&c);
        let dropped = [
            false, false, false, true, false, true, true, false, false, true,
        ];
        let map = cov.compact(&dropped);
        let kept: Vec<usize> = (0..10).filter(|&i| !dropped[i]).collect();
        assert_eq!(map[4], Some(3));
        let expected = c.select_rows(&kept).select_columns(&kept);
        assert_eq!(cov.to_dense(), expected);
        // Three rows back, correlated with the kept ones: the storage is reused.
        let extra = random_spd(3, 12);
        let cross = DMatrix::from_fn(3, 6, |i, j| 0.01 * (1 + i + 2 * j) as f64);
        cov.append(&extra, Some(&cross), &DMatrix::zeros(3, 3));
        let mut grown = DMatrix::zeros(9, 9);
        grown.view_mut((0, 0), (6, 6)).copy_from(&expected);
        grown.view_mut((6, 6), (3, 3)).copy_from(&extra);
        grown.view_mut((6, 0), (3, 6)).copy_from(&cross);
        grown.view_mut((0, 6), (6, 3)).copy_from(&cross.transpose());
        assert_eq!(cov.to_dense(), grown);
        let h = DMatrix::from_row_slice(1, 3, &[0.5, -1.0, 0.25]);
        let r = DMatrix::from_element(1, 1, 0.04);
        let eta = DVector::from_element(1, 0.1);
        let dx = cov.update(&[0, 4, 7], &h, &r, &eta).unwrap();
        let mut h_full = DMatrix::zeros(1, 9);
        for (b, &j) in [0, 4, 7].iter().enumerate() {
            h_full[(0, j)] = h[(0, b)];
        }
        let s = &h_full * &grown * h_full.transpose() + &r;
        let k = &grown * h_full.transpose() * s.try_inverse().unwrap();
        assert!((dx + &k * &eta).amax() < 1e-12);
        assert!((cov.to_dense() - (&grown - &k * &h_full * &grown)).amax() < 1e-12);
    }

    #[test]
    fn transform_rows_matches_the_dense_product() {
        let c = random_spd(7, 11);
        let mut cov = from_dense(&c);
        let rows = [5, 2];
        let t = DMatrix::from_row_slice(2, 2, &[1.0, 0.3, -0.2, 1.5]);
        cov.transform_rows(&rows, &t).unwrap();
        let f = rows_transform(7, &rows, &t);
        let expected = &f * &c * f.transpose();
        assert!((cov.to_dense() - expected).amax() < 1e-12);
    }

    /// The textbook update (eqs. 28-32) on a full dense matrix: `(dx, C')`.
    fn textbook(
        c: &DMatrix<f64>,
        indices: &[usize],
        h_small: &DMatrix<f64>,
        r: &DMatrix<f64>,
        eta: &DVector<f64>,
    ) -> (DVector<f64>, DMatrix<f64>) {
        let mut h = DMatrix::zeros(h_small.nrows(), c.nrows());
        for (b, &j) in indices.iter().enumerate() {
            h.column_mut(j).copy_from(&h_small.column(b));
        }
        let s = &h * c * h.transpose() + r;
        let k = c * h.transpose() * s.try_inverse().unwrap();
        (-&k * eta, c - &k * &h * c)
    }

    #[test]
    fn rows_kept_apart_update_like_the_dense_filter() {
        let mut cov = StateCovariance::dense(&random_spd(5, 13), &DMatrix::zeros(5, 3));
        let apart = DMatrix::from_diagonal(&DVector::from_vec(vec![0.3, 0.5, 0.2]));
        assert_eq!(cov.append(&apart, None, &DMatrix::zeros(3, 3)), 5..8);
        assert!((5..8).all(|i| matches!(cov.slots[i], Slot::Alone(_))));
        let mut c = cov.to_dense();
        // Rows 0-1 touch dense rows and row 5 (which must join the dense block), row 2 only
        // row 6 (apart), rows 3-4 only row 7, with correlated noise between them (apart).
        let indices = [0, 1, 5, 6, 7];
        let h = DMatrix::from_row_slice(
            5,
            5,
            &[
                1.0, 0.5, -0.7, 0.0, 0.0, //
                0.2, -1.0, 0.3, 0.0, 0.0, //
                0.0, 0.0, 0.0, 1.0, 0.0, //
                0.0, 0.0, 0.0, 0.0, 1.0, //
                0.0, 0.0, 0.0, 0.0, -2.0,
            ],
        );
        let mut r = DMatrix::from_diagonal(&DVector::from_vec(vec![0.04, 0.09, 0.01, 0.02, 0.03]));
        r[(3, 4)] = 0.01;
        r[(4, 3)] = 0.01;
        let eta = DVector::from_vec(vec![0.3, -0.2, 0.1, -0.05, 0.2]);
        let dx = cov.update(&indices, &h, &r, &eta).unwrap();
        let (expected_dx, expected_c) = textbook(&c, &indices, &h, &r, &eta);
        assert!((dx - expected_dx).amax() < 1e-12);
        assert!((cov.to_dense() - &expected_c).amax() < 1e-12);
        assert!(matches!(cov.slots[5], Slot::Dense(_)));
        assert!(matches!(cov.slots[6], Slot::Alone(_)));
        assert!(matches!(cov.slots[7], Slot::Alone(_)));
        // Noise correlated with a dense row's brings row 6 into the dense block.
        c = expected_c;
        let indices = [0, 6];
        let h = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 1.0]);
        let r = DMatrix::from_row_slice(2, 2, &[0.04, 0.01, 0.01, 0.02]);
        let eta = DVector::from_vec(vec![0.1, -0.1]);
        let dx = cov.update(&indices, &h, &r, &eta).unwrap();
        let (expected_dx, expected_c) = textbook(&c, &indices, &h, &r, &eta);
        assert!((dx - expected_dx).amax() < 1e-12);
        assert!((cov.to_dense() - &expected_c).amax() < 1e-12);
        assert!(matches!(cov.slots[6], Slot::Dense(_)));
        assert!(matches!(cov.slots[7], Slot::Alone(_)));
    }

    #[test]
    fn rows_kept_apart_survive_compact_transform_and_prediction() {
        let mut cov = StateCovariance::dense(&random_spd(4, 17), &DMatrix::zeros(4, 3));
        let apart = DMatrix::from_diagonal(&DVector::from_vec(vec![0.3, 0.5, 0.2]));
        cov.append(&apart, None, &DMatrix::zeros(3, 3));
        let correlated = random_spd(2, 19);
        let cross = DMatrix::from_fn(2, 7, |i, j| if j < 4 { 0.01 * (i + j) as f64 } else { 0.0 });
        cov.append(&correlated, Some(&cross), &DMatrix::zeros(2, 3));
        assert!(matches!(cov.slots[7], Slot::Dense(4)));
        let before = cov.to_dense();
        // Drop dense row 2 and row 5 (apart).
        let mut dropped = vec![false; 9];
        dropped[2] = true;
        dropped[5] = true;
        let map = cov.compact(&dropped);
        let kept: Vec<usize> = (0..9).filter(|&i| !dropped[i]).collect();
        assert_eq!(map[6], Some(4));
        assert_eq!(
            cov.to_dense(),
            before.select_rows(&kept).select_columns(&kept)
        );
        // A transform mixing a row kept apart (4, was 6) with a dense one (5, was 7).
        let before = cov.to_dense();
        let rows = [4, 5];
        let t = DMatrix::from_row_slice(2, 2, &[1.0, 0.3, -0.2, 1.5]);
        cov.transform_rows(&rows, &t).unwrap();
        let f = rows_transform(7, &rows, &t);
        let expected = &f * &before * f.transpose();
        assert!((cov.to_dense() - &expected).amax() < 1e-12);
        // The prediction leaves the rows kept apart uncorrelated with the pose.
        let j = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, -0.4, 0.0, 1.0, 0.7, 0.0, 0.0, 1.0]);
        let q = DMatrix::from_diagonal(&DVector::from_vec(vec![0.01, 0.02, 0.003]));
        cov.predict(&j, &q);
        let f = pose_transition(7, &j);
        let mut expected = &f * &expected * f.transpose();
        let mut block = expected.view_mut((0, 0), (3, 3));
        block += &q;
        assert!((cov.to_dense() - &expected).amax() < 1e-12);
        assert!(matches!(cov.slots[3], Slot::Alone(_)));
    }

    #[test]
    fn deferred_predictions_read_and_update_like_immediate_ones() {
        let c = random_spd(8, 23);
        let mut cov = from_dense(&c);
        let j1 = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, -0.4, 0.0, 1.0, 0.7, 0.0, 0.0, 1.0]);
        let j2 = DMatrix::from_row_slice(3, 3, &[1.0, 0.1, 0.2, -0.1, 1.0, -0.3, 0.0, 0.0, 1.0]);
        let q = DMatrix::from_diagonal(&DVector::from_vec(vec![0.01, 0.02, 0.003]));
        let mut expected = c.clone();
        for j in [&j1, &j2] {
            cov.predict(j, &q);
            let f = pose_transition(8, j);
            expected = &f * &expected * f.transpose();
            let mut block = expected.view_mut((0, 0), (3, 3));
            block += &q;
        }
        // Read while the cross-covariance is pending, then updated (which brings it up to date).
        assert!(cov.pending.is_some());
        assert!((cov.to_dense() - &expected).amax() < 1e-12);
        let indices = [0, 1, 2, 5, 6];
        let h = DMatrix::from_fn(2, 5, |i, j| (i + 2 * j) as f64 * 0.1 - 0.3);
        let r = DMatrix::from_row_slice(2, 2, &[0.04, 0.01, 0.01, 0.09]);
        let eta = DVector::from_vec(vec![0.3, -0.2]);
        let dx = cov.update(&indices, &h, &r, &eta).unwrap();
        let (expected_dx, expected_c) = textbook(&expected, &indices, &h, &r, &eta);
        assert!(cov.pending.is_none());
        assert!((dx - expected_dx).amax() < 1e-12);
        assert!((cov.to_dense() - expected_c).amax() < 1e-12);
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
