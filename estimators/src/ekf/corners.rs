//! Shared corners (paper section VI, eq. 33): two features whose shareable blocks (wall
//! ends) are fully estimated and statistically the same point are constrained together, then
//! share the block, and the covariance is re-parameterized onto the shared rows. Which blocks
//! may join is the shared lifecycle's rule ([`crate::lifecycle::corners`]).

use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{CoordBlock, Error, FeatureId, Result, RobotPose, RowOwner, SharedBlockId};

use super::Ekf;
use super::jacobians::project_out;
use crate::lifecycle::corners::{block_estimated, corner_partners};

/// Variance of the constraint that makes two blocks one corner, m^2 (1 cm). Tight, but not
/// perfect: the constraint is projected like every other measurement to observe no world
/// motion, and with a perfect constraint that small change of direction gave metre jumps.
const JOIN_CONSTRAINT_VARIANCE: f64 = 1e-4;

/// The two blocks being joined, with their features' state rows.
struct JoinPair {
    f: FeatureId,
    kf: usize,
    g: FeatureId,
    kg: usize,
    rows_f: Vec<usize>,
    rows_g: Vec<usize>,
}

impl<P: RobotPose> Ekf<P> {
    /// Joins the free shareable blocks of feature `id` with those of other features that are
    /// the same point (section VI).
    pub(super) fn join_corners_of(&mut self, id: FeatureId) -> Result<()> {
        if !self.is_confirmed(id) {
            return Ok(());
        }
        for k in self.map.get(id)?.shareable_blocks() {
            if self.map.links(id)?[k].is_some() || !block_estimated(self.map.get(id)?, k)? {
                continue;
            }
            let confirmed = |other: FeatureId| self.is_confirmed(other);
            let partners =
                corner_partners(&self.map, id, k, self.params.corner_distance, &confirmed)?;
            for (other, j) in partners {
                if self.join(id, k, other, j)? {
                    break;
                }
            }
        }
        Ok(())
    }

    /// Joins block `kf` of `f` and block `kg` of `g` if they are statistically the same
    /// point: a near-perfect constraint update makes them agree, then the map shares the
    /// block and the covariance is re-parameterized onto the shared rows (eq. 33).
    fn join(&mut self, f: FeatureId, kf: usize, g: FeatureId, kg: usize) -> Result<bool> {
        let (rows_f, rows_g) = match (
            self.rows.get(&RowOwner::Feature(f)),
            self.rows.get(&RowOwner::Feature(g)),
        ) {
            (Some(a), Some(b)) => (a.clone(), b.clone()),
            _ => return Ok(false),
        };
        let pair = JoinPair {
            f,
            kf,
            g,
            kg,
            rows_f,
            rows_g,
        };
        if !self.constrain_together(&pair)? {
            return Ok(false);
        }
        match self.share(&pair) {
            Ok(()) => {}
            // The constraint moved the two ends to where their midpoint would turn a feature
            // around (a short wall's end pulled past its other end). The map refused the
            // share and is unchanged; the ends stay two blocks, held together by the
            // constraint.
            Err(Error::Degenerate(_)) => {
                self.skips
                    .count("corners: the shared point would turn a feature around (not joined)");
                return Ok(false);
            }
            Err(error) => return Err(error),
        }
        self.corners_joined += 1;
        Ok(true)
    }

    /// Tests whether the two blocks are the same point (both features accept the shared
    /// value, and their difference passes the gate) and, if so, constrains them together by a
    /// tight update. Returns whether they were.
    fn constrain_together(&mut self, pair: &JoinPair) -> Result<bool> {
        let (value_f, e_f) = self.block_and_dual(pair.f, pair.kf)?;
        let (value_g, e_g) = self.block_and_dual(pair.g, pair.kg)?;
        let dim = value_f.len();
        // Dry run: both features must accept the shared value.
        let midpoint = (&value_f + &value_g) / 2.0;
        for (id, k) in [(pair.f, pair.kf), (pair.g, pair.kg)] {
            let mut candidate = slam_core::dyn_clone::clone_box(self.map.get(id)?);
            let block = CoordBlock::from_slice(
                candidate.coordinates().blocks()[k].kind(),
                midpoint.as_slice(),
            )?;
            if candidate.set_block(k, block).is_err() || candidate.share_block(k).is_err() {
                return Ok(false);
            }
        }
        let (nf, ng) = (pair.rows_f.len(), pair.rows_g.len());
        let mut h = DMatrix::zeros(dim, nf + ng);
        h.view_mut((0, 0), e_f.shape()).copy_from(&e_f);
        h.view_mut((0, nf), e_g.shape()).copy_from(&(-&e_g));
        let indices: Vec<usize> = pair.rows_f.iter().chain(&pair.rows_g).copied().collect();
        self.constrain_if_same(&indices, h, &(&value_f - &value_g))
    }

    /// Gates the difference of two blocks (`h` its Jacobian on the state rows `indices`) and,
    /// if they are the same point, makes it zero by a tight update; all or nothing (a join
    /// that would turn a feature around is not made). Returns whether it was applied.
    fn constrain_if_same(
        &mut self,
        indices: &[usize],
        mut h: DMatrix<f64>,
        difference: &DVector<f64>,
    ) -> Result<bool> {
        let dim = difference.len();
        let c = self.cov.gather(indices, indices);
        let sigma = &h * c * h.transpose();
        let Some(sigma_inv) = sigma.try_inverse() else {
            self.skips.count("corners: singular difference covariance");
            return Ok(false);
        };
        let d2 = (difference.transpose() * sigma_inv * difference)[(0, 0)];
        let gate = self.gates.gate(self.params.gate_probability, dim)?;
        if d2.is_nan() || d2 > gate {
            return Ok(false);
        }
        let noise = DMatrix::identity(dim, dim) * JOIN_CONSTRAINT_VARIANCE;
        if self.params.observability_constraint {
            h = project_out(&h, &self.cov.generators(indices));
        }
        let prepared = self.cov.prepare_update(indices, &h, &noise, difference)?;
        if self.apply_state_change(&prepared.dx).is_err() {
            self.skips
                .count("corners: the join would move a feature where it cannot go");
            return Ok(false);
        }
        self.cov.commit(prepared);
        Ok(true)
    }

    /// Joins free block `k` of feature `id` to the existing shared block `shared` if they
    /// are statistically the same point (a duplicate's corner passing to the wall kept by a
    /// merge): a tight constraint update, then the feature shares the block and its own rows
    /// are re-parameterized (eq. 33); the shared block's rows stay as they are. Returns
    /// whether it was joined.
    pub(super) fn join_existing(
        &mut self,
        id: FeatureId,
        k: usize,
        shared: SharedBlockId,
    ) -> Result<bool> {
        let Some(rows_f) = self.rows.get(&RowOwner::Feature(id)).cloned() else {
            return Ok(false);
        };
        let rows_s = self
            .rows
            .get(&RowOwner::Shared(shared))
            .cloned()
            .ok_or_else(|| Error::Invariant(format!("shared block {} has no rows", shared.0)))?;
        let (value_f, e_f) = self.block_and_dual(id, k)?;
        let corner = self.map.shared_block(shared)?.value;
        let mut candidate = slam_core::dyn_clone::clone_box(self.map.get(id)?);
        if candidate.set_block(k, corner).is_err() || candidate.share_block(k).is_err() {
            return Ok(false);
        }
        let (nf, dim) = (rows_f.len(), value_f.len());
        let mut h = DMatrix::zeros(dim, nf + dim);
        h.view_mut((0, 0), e_f.shape()).copy_from(&e_f);
        h.view_mut((0, nf), (dim, dim))
            .copy_from(&(-DMatrix::<f64>::identity(dim, dim)));
        let indices: Vec<usize> = rows_f.iter().chain(&rows_s).copied().collect();
        let difference = value_f - DVector::from_column_slice(corner.as_slice());
        if !self.constrain_if_same(&indices, h, &difference)? {
            return Ok(false);
        }
        let dual_old = self.map.get(id)?.dual()?;
        self.map.join_shared(id, k, shared)?;
        let t = self.map.get(id)?.projection()? * dual_old;
        let before = self.cov.dim();
        let remap = self.cov.reparameterize(&rows_f, &t)?;
        self.rows.remove(&RowOwner::Feature(id));
        for rows in self.rows.values_mut() {
            for row in rows.iter_mut() {
                *row = remap[*row]
                    .ok_or_else(|| Error::Invariant("a kept state row was dropped".into()))?;
            }
        }
        if t.nrows() > 0 {
            let rows = (0..t.nrows())
                .map(|i| {
                    remap[before + i].ok_or_else(|| {
                        Error::Invariant("a row appended by a corner join was lost".into())
                    })
                })
                .collect::<Result<Vec<usize>>>()?;
            self.rows.insert(RowOwner::Feature(id), rows);
        }
        Ok(true)
    }

    /// Makes the two blocks one shared block at their midpoint and re-parameterizes the
    /// covariance: the shared rows are the mean of the two blocks, each feature's own rows its
    /// new M-space (eq. 33).
    fn share(&mut self, pair: &JoinPair) -> Result<()> {
        let (f, g) = (pair.f, pair.g);
        let (value_f, e_f) = self.block_and_dual(f, pair.kf)?;
        let (value_g, e_g) = self.block_and_dual(g, pair.kg)?;
        let dim = value_f.len();
        let dual_f = self.map.get(f)?.dual()?;
        let dual_g = self.map.get(g)?.dual()?;
        let corner = (&value_f + &value_g) / 2.0;
        let kind = self.map.get(f)?.coordinates().blocks()[pair.kf].kind();
        let shared = self.map.share(
            &[(f, pair.kf), (g, pair.kg)],
            CoordBlock::from_slice(kind, corner.as_slice())?,
        )?;
        let b_f = self.map.get(f)?.projection()?;
        let b_g = self.map.get(g)?.projection()?;
        let (rf, rg) = (pair.rows_f.len(), pair.rows_g.len());
        let (nf, ng) = (b_f.nrows(), b_g.nrows());
        let mut t = DMatrix::zeros(dim + nf + ng, rf + rg);
        t.view_mut((0, 0), (dim, rf)).copy_from(&(&e_f * 0.5));
        t.view_mut((0, rf), (dim, rg)).copy_from(&(&e_g * 0.5));
        t.view_mut((dim, 0), (nf, rf)).copy_from(&(&b_f * &dual_f));
        t.view_mut((dim + nf, rf), (ng, rg))
            .copy_from(&(&b_g * &dual_g));
        let indices: Vec<usize> = pair.rows_f.iter().chain(&pair.rows_g).copied().collect();
        let before = self.cov.dim();
        let remap = self.cov.reparameterize(&indices, &t)?;
        self.rows.remove(&RowOwner::Feature(f));
        self.rows.remove(&RowOwner::Feature(g));
        for rows in self.rows.values_mut() {
            for row in rows.iter_mut() {
                *row = remap[*row]
                    .ok_or_else(|| Error::Invariant("a kept state row was dropped".into()))?;
            }
        }
        self.insert_shared_rows(shared, (f, nf), (g, ng), dim, |k| remap[before + k])
    }

    /// Files the rows appended by a re-parameterization: the shared block's `dim` rows, then
    /// `nf` rows of `f` and `ng` rows of `g` (`appended(k)` is the state row of appended row
    /// `k`).
    fn insert_shared_rows(
        &mut self,
        shared: SharedBlockId,
        (f, nf): (FeatureId, usize),
        (g, ng): (FeatureId, usize),
        dim: usize,
        appended: impl Fn(usize) -> Option<usize>,
    ) -> Result<()> {
        let new_rows = |from: usize, count: usize| -> Result<Vec<usize>> {
            (from..from + count)
                .map(|k| {
                    appended(k).ok_or_else(|| {
                        Error::Invariant("a row appended by a corner join was lost".into())
                    })
                })
                .collect()
        };
        self.rows
            .insert(RowOwner::Shared(shared), new_rows(0, dim)?);
        if nf > 0 {
            self.rows.insert(RowOwner::Feature(f), new_rows(dim, nf)?);
        }
        if ng > 0 {
            self.rows
                .insert(RowOwner::Feature(g), new_rows(dim + nf, ng)?);
        }
        Ok(())
    }

    /// Block `k` of feature `id` as a vector, and its rows of `B~` (`E_k B~`).
    fn block_and_dual(&self, id: FeatureId, k: usize) -> Result<(DVector<f64>, DMatrix<f64>)> {
        let feature = self.map.get(id)?;
        let coordinates = feature.coordinates();
        let block = coordinates.blocks()[k];
        let rows = feature
            .dual()?
            .rows(coordinates.offset(k), block.dim())
            .into_owned();
        Ok((DVector::from_column_slice(block.as_slice()), rows))
    }
}
