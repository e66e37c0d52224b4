//! The update step after association: feature lifecycle (sightings, growth, triangulation),
//! the batch EKF update (eqs. 28-32 and 24), extents, corners and pruning.

use std::collections::BTreeSet;

use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{
    Error, FeatureId, MapToSensor, Observation, Result, RobotPose, RowOwner, UpdateReport,
    linearize,
};

use crate::lifecycle::{
    BoundingBox, growth_prior, placed_by_triangulation, ready_subspace, stack_priors,
};

use super::{
    Decision, Ekf, Pairing, Track, View, add_to_pose, coordinate_generators, project_out, stack,
};

/// Largest `|B (x_new - x_old)|` accepted for a change outside the M-space.
const OUTSIDE_MSPACE_TOLERANCE: f64 = 1e-6;

/// Variance of the constraint that makes two blocks one corner, m^2 (1 cm). Tight, but not
/// perfect: the constraint is projected like every other measurement to observe no world
/// motion, and with a perfect constraint that small change of direction gave metre jumps.
const JOIN_CONSTRAINT_VARIANCE: f64 = 1e-4;

impl<P: RobotPose> Ekf<P> {
    /// Carries out the decisions of one step (see the module documentation).
    pub(super) fn apply_decisions(
        &mut self,
        observations: &[Observation],
        decisions: Vec<Decision>,
    ) -> Result<UpdateReport> {
        let mut report = UpdateReport::default();
        let mut batch: Vec<Pairing> = Vec::new();
        let mut seen: Vec<(usize, FeatureId)> = Vec::new();
        let mut grown = BTreeSet::new();
        let mut new_observations = Vec::new();
        for (index, decision) in decisions.into_iter().enumerate() {
            match decision {
                Decision::Pair(pairing) => {
                    let id = pairing.feature;
                    let observation = &observations[index];
                    report.associated += 1;
                    if self.is_confirmed(id) {
                        let s = self.innovation_covariance(&pairing, false);
                        if let Some(s_inv) = s.try_inverse() {
                            let nis = (pairing.eta.transpose() * s_inv * &pairing.eta)[(0, 0)];
                            report.nis.push((nis, pairing.eta.len()));
                        }
                        batch.push(pairing);
                    }
                    self.note_sighting(id, observation)?;
                    if self.grow(id, observation)? {
                        grown.insert(id);
                    }
                    seen.push((index, id));
                }
                Decision::New => new_observations.push(index),
                Decision::Reject => report.rejected += 1,
            }
        }
        for index in new_observations {
            let observation = &observations[index];
            match self.start_feature(observation)? {
                Some(id) => {
                    report.new_features += 1;
                    if self.grow(id, observation)? {
                        grown.insert(id);
                    }
                    seen.push((index, id));
                }
                None => report.rejected += 1,
            }
        }
        // Pairings of features that grew this step are linearized again, on their new rows.
        batch.retain(|p| !grown.contains(&p.feature));
        for &(index, id) in &seen {
            if grown.contains(&id)
                && self.is_confirmed(id)
                && let Ok(pairing) = self.linearize(&observations[index], id)
            {
                batch.push(pairing);
            }
        }
        batch.append(&mut self.view_batch);
        if self.params.observability_constraint {
            for pairing in &mut batch {
                pairing.h = project_out(&pairing.h, &self.cov.generators(&pairing.indices));
            }
        }
        report.rejected += self.update_batch(batch)?;
        for &(index, id) in &seen {
            self.extend(id, &observations[index])?;
        }
        if self.params.join_corners {
            let touched: BTreeSet<FeatureId> = seen.iter().map(|&(_, id)| id).collect();
            for id in touched {
                self.join_corners_of(id)?;
            }
        }
        self.prune_tentative()?;
        Ok(report)
    }

    /// One batch update (eqs. 28-32, 24). A state change that some feature cannot take (it
    /// would turn a wall or line around: a wrong association or a step far outside the
    /// linear range) is not applied; the pairings of those features are dropped and the
    /// rest is updated again. Returns the number of pairings dropped.
    fn update_batch(&mut self, mut batch: Vec<Pairing>) -> Result<usize> {
        let mut dropped = 0;
        while !batch.is_empty() {
            let pairings: Vec<&Pairing> = batch.iter().collect();
            let (indices, h, r, eta) = stack(&pairings);
            let prepared = self.cov.prepare_update(&indices, &h, &r, &eta)?;
            // `apply_state_change` is all or nothing: on error the state is unchanged.
            if self.apply_state_change(&prepared.dx).is_ok() {
                self.cov.commit(prepared);
                break;
            }
            let refused = self.refusing_features(&prepared.dx)?;
            let before = batch.len();
            batch.retain(|p| !refused.contains(&p.feature));
            if batch.len() == before {
                // The refusing features were not measured: the step moves them through
                // correlations only. Nothing safe is left to update.
                dropped += batch.len();
                break;
            }
            dropped += before - batch.len();
        }
        Ok(dropped)
    }

    /// The features that refuse the perturbation `dx` would give them (the slow path, after
    /// a refused update).
    fn refusing_features(&self, dx: &DVector<f64>) -> Result<BTreeSet<FeatureId>> {
        let mut refused = BTreeSet::new();
        for (owner, rows) in &self.rows {
            if let RowOwner::Feature(id) = owner {
                let owned = DVector::from_fn(rows.len(), |k, _| dx[rows[k]]);
                let mut candidate = slam_core::dyn_clone::clone_box(self.map.get(*id)?);
                if candidate.apply_perturbation(&owned).is_err() {
                    refused.insert(*id);
                }
            }
        }
        if refused.is_empty() {
            let perturbations: Vec<(RowOwner, DVector<f64>)> = self
                .rows
                .iter()
                .map(|(owner, rows)| (*owner, DVector::from_fn(rows.len(), |k, _| dx[rows[k]])))
                .collect();
            let mut map = self.map.clone();
            if map.apply(&perturbations).is_err() {
                for (owner, _) in &perturbations {
                    if let RowOwner::Shared(id) = owner {
                        for (member, _) in &self.map.shared_block(*id)?.members {
                            refused.insert(*member);
                        }
                    }
                }
            }
        }
        Ok(refused)
    }

    /// `x += dx`: the pose by its parameters, every feature by `x_f += B~ dx_p` (eq. 24) and
    /// every shared block by its identity rows.
    /// All or nothing: on error the state is unchanged.
    pub(super) fn apply_state_change(&mut self, dx: &DVector<f64>) -> Result<()> {
        let d = P::DIM;
        let pose = add_to_pose(&self.pose, &dx.as_slice()[..d])?;
        let perturbations: Vec<(RowOwner, DVector<f64>)> = self
            .rows
            .iter()
            .map(|(owner, rows)| (*owner, DVector::from_fn(rows.len(), |k, _| dx[rows[k]])))
            .collect();
        self.map.apply(&perturbations)?;
        self.pose = pose;
        Ok(())
    }

    /// The feature `observation` would start, placed from the current pose.
    fn start_feature(&mut self, observation: &Observation) -> Result<Option<FeatureId>> {
        let world_from_sensor = self.pose.world_from_sensor(&observation.robot_from_sensor);
        let Ok(Some(feature)) = observation
            .measurement
            .initial_feature_dyn(&world_from_sensor)
        else {
            return Ok(None);
        };
        let id = self.map.insert(feature)?;
        self.tracks.insert(
            id,
            Track {
                landmark_id: observation.landmark_id,
                ..Track::default()
            },
        );
        if let Some(landmark) = observation.landmark_id {
            self.ids.insert(landmark, id);
        }
        self.note_sighting(id, observation)?;
        Ok(Some(id))
    }

    /// Counts a sighting: the subspaces it reveals, and a view kept while the feature can
    /// still grow.
    fn note_sighting(&mut self, id: FeatureId, observation: &Observation) -> Result<()> {
        let world_from_sensor = self.pose.world_from_sensor(&observation.robot_from_sensor);
        let feature = self.map.get(id)?;
        let x_o = MapToSensor::new(&world_from_sensor)?.transform(feature.coordinates())?;
        let revealed = observation
            .measurement
            .revealed_subspaces_dyn(feature, &x_o)
            .unwrap_or_default();
        let can_grow =
            observation.measurement.triangulates_dyn() && !feature.growth_options().is_empty();
        let pose_covariance = slam_core::Estimator::pose_covariance(self);
        let step = self.step;
        let max_views = self.params.max_views;
        let track = self.tracks.entry(id).or_default();
        track.sightings += 1;
        track.last_seen = step;
        for name in revealed {
            *track.revealed.entry(name).or_default() += 1;
        }
        if can_grow {
            if track.views.len() >= max_views {
                // Keep the first view (the widest baseline so far) and the most recent ones.
                track.views.remove(1);
            }
            track.views.push(View {
                pose_covariance: pose_covariance.clone(),
                world_from_sensor,
                world_from_robot: self.pose,
                robot_from_sensor: observation.robot_from_sensor,
                measurement: observation.measurement.clone_box(),
            });
        } else {
            track.views.clear();
        }
        Ok(())
    }

    /// Grows feature `id` by every subspace revealed often enough, or by triangulation from
    /// its views; new rows get their prior covariance. Returns whether it grew.
    fn grow(&mut self, id: FeatureId, observation: &Observation) -> Result<bool> {
        let threshold = match self.tracks.get(&id) {
            Some(track) if track.landmark_id.is_some() => 1,
            _ => self.params.confirm_after,
        };
        let old_dim = self.map.get(id)?.mspace_dim();
        let mut priors = Vec::new();
        loop {
            let options = self.map.get(id)?.growth_options();
            let track = self.tracks.entry(id).or_default();
            let Some(subspace) = ready_subspace(&options, &track.revealed, threshold) else {
                break;
            };
            track.revealed.remove(subspace.name);
            let growth = self.map.activate(id, subspace.name)?;
            priors.push(growth_prior(
                self.map.get(id)?,
                &growth,
                self.params.new_row_variance,
            ));
        }
        let mut new_dim = self.map.get(id)?.mspace_dim();
        let mut triangulated = false;
        if new_dim == old_dim
            && observation.measurement.triangulates_dyn()
            && self.triangulate(id, observation)?
        {
            new_dim = self.map.get(id)?.mspace_dim();
            let added = new_dim - old_dim;
            priors.push(DMatrix::identity(added, added) * self.params.new_row_variance);
            triangulated = true;
        }
        if new_dim == old_dim {
            return Ok(false);
        }
        let added = new_dim - old_dim;
        let block = stack_priors(&priors, added)?;
        let feature = self.map.get(id)?;
        let generators = feature.projection()?.rows(old_dim, added)
            * coordinate_generators(feature.coordinates());
        let range = self.cov.append(&block, None, &generators);
        self.rows
            .entry(RowOwner::Feature(id))
            .or_default()
            .extend(range);
        if triangulated {
            let views = self.view_pairings(id, old_dim)?;
            self.view_batch.extend(views);
        }
        if self.map.get(id)?.growth_options().is_empty()
            && let Some(track) = self.tracks.get_mut(&id)
        {
            track.views.clear();
        }
        Ok(true)
    }

    /// Places feature `id` from its views when they triangulate it and reveal subspaces it
    /// does not have. The new coordinates keep the already-estimated directions:
    /// `x_new = x_tri - B~_new P_old B_new (x_tri - x_old)`, `P_old` selecting the old rows.
    /// Returns the information of the other views about the new rows (their prior).
    fn triangulate(&mut self, id: FeatureId, observation: &Observation) -> Result<bool> {
        let Some(track) = self.tracks.get(&id) else {
            return Ok(false);
        };
        // The current observation is the last view; triangulate it with the others.
        let Some((current, others)) = track.views.split_last() else {
            return Ok(false);
        };
        let other_views: Vec<_> = others
            .iter()
            .map(|v| (v.world_from_sensor, v.measurement.as_ref()))
            .collect();
        let grown = placed_by_triangulation(
            self.map.get(id)?,
            observation.measurement.as_ref(),
            &current.world_from_sensor,
            &other_views,
        )?;
        match grown {
            Some(grown) => {
                self.map.replace(id, grown)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// The earlier views of a feature that grew by triangulation, as measurements of its new
    /// rows `old_dim..` and of the **current** pose: a view taken at `x_v` is treated as taken
    /// from the current pose moved by the estimated relative motion, with that motion's
    /// uncertainty (the growth of the pose covariance since the view) added to its noise.
    /// The views thus correlate the new rows with the pose, as the EKF needs, instead of
    /// entering as an independent prior (which makes the filter overconfident).
    fn view_pairings(&self, id: FeatureId, old_dim: usize) -> Result<Vec<Pairing>> {
        let Some(track) = self.tracks.get(&id) else {
            return Ok(Vec::new());
        };
        let Some((_, others)) = track.views.split_last() else {
            return Ok(Vec::new());
        };
        let feature = self.map.get(id)?;
        let rows = self
            .rows
            .get(&RowOwner::Feature(id))
            .map(|r| r[old_dim..].to_vec())
            .unwrap_or_default();
        let added = rows.len();
        let c_now = slam_core::Estimator::pose_covariance(self);
        let mut pairings = Vec::new();
        for view in others {
            let Ok(lin) = linearize(
                view.measurement.as_ref(),
                feature,
                &view.world_from_robot,
                &view.robot_from_sensor,
            ) else {
                continue;
            };
            let relative = psd_part(&(&c_now - &view.pose_covariance));
            let cov_eta =
                &lin.cov_eta + &lin.d_eta_d_robot * relative * lin.d_eta_d_robot.transpose();
            let m = lin.eta.len();
            let mut h = DMatrix::zeros(m, P::DIM + added);
            h.view_mut((0, 0), (m, P::DIM))
                .copy_from(&lin.d_eta_d_robot);
            h.view_mut((0, P::DIM), (m, added))
                .copy_from(&lin.d_eta_d_own.columns(old_dim, added));
            let mut indices: Vec<usize> = (0..P::DIM).collect();
            indices.extend_from_slice(&rows);
            pairings.push(Pairing {
                feature: id,
                indices,
                h,
                eta: lin.eta,
                cov_eta,
            });
        }
        Ok(pairings)
    }

    /// Applies the measurement's change outside the M-space (a wall's extent).
    fn extend(&mut self, id: FeatureId, observation: &Observation) -> Result<()> {
        let world_from_sensor = self.pose.world_from_sensor(&observation.robot_from_sensor);
        let feature = self.map.get(id)?;
        let Ok(Some(extension)) = observation
            .measurement
            .extend_dyn(feature, &world_from_sensor)
        else {
            return Ok(());
        };
        // A change the check refuses (it would move the feature inside its M-space) is not
        // applied: the estimate stays as the update left it.
        let Ok(transform) =
            self.map
                .set_coordinates_outside_mspace(id, extension, OUTSIDE_MSPACE_TOLERANCE)
        else {
            return Ok(());
        };
        if let Some(transform) = transform {
            let mut rows = Vec::new();
            for (owner, size) in &transform.owners {
                let owned = self.rows.get(owner).ok_or_else(|| {
                    Error::InvalidArgument(format!("row owner {owner:?} has no state rows"))
                })?;
                if owned.len() != *size {
                    return Err(Error::DimensionMismatch {
                        what: format!("state rows of {owner:?}"),
                        expected: owned.len(),
                        got: *size,
                    });
                }
                rows.extend_from_slice(owned);
            }
            self.cov.transform_rows(&rows, &transform.matrix)?;
        }
        Ok(())
    }

    /// Drops tentative features not seen for `tentative_lifetime` steps.
    fn prune_tentative(&mut self) -> Result<()> {
        let stale: Vec<FeatureId> = self
            .tracks
            .iter()
            .filter(|(id, track)| {
                self.step.saturating_sub(track.last_seen) > self.params.tentative_lifetime
                    && !self.is_confirmed(**id)
            })
            .map(|(id, _)| *id)
            .collect();
        for id in stale {
            self.map.remove(id)?;
            if let Some(track) = self.tracks.remove(&id)
                && let Some(landmark) = track.landmark_id
            {
                self.ids.remove(&landmark);
            }
        }
        Ok(())
    }

    /// Whether block `k` of feature `id` is fully in its own M-space (`E_k B~` has full row
    /// rank): a wall end seen as a real end.
    fn block_estimated(&self, id: FeatureId, k: usize) -> Result<bool> {
        let feature = self.map.get(id)?;
        if feature.mspace_dim() == 0 {
            return Ok(false);
        }
        let coordinates = feature.coordinates();
        let dim = coordinates.blocks()[k].dim();
        let rows = feature
            .dual()?
            .rows(coordinates.offset(k), dim)
            .into_owned();
        if rows.ncols() < dim {
            return Ok(false);
        }
        let singular = rows.singular_values();
        let largest = singular.max();
        Ok(singular.len() == dim && largest > 0.0 && singular.min() > 1e-6 * largest.max(1.0))
    }

    /// Joins the free shareable blocks of feature `id` with those of other features that are
    /// the same point (section VI).
    fn join_corners_of(&mut self, id: FeatureId) -> Result<()> {
        if !self.is_confirmed(id) {
            return Ok(());
        }
        let feature = self.map.get(id)?;
        let blocks = feature.shareable_blocks();
        for k in blocks {
            if self.map.links(id)?[k].is_some() || !self.block_estimated(id, k)? {
                continue;
            }
            let value = self.map.get(id)?.coordinates().blocks()[k];
            let here = BoundingBox::of(&slam_core::Coordinates::new(vec![value])?);
            let corner_distance = self.params.corner_distance;
            let others: Vec<(FeatureId, usize)> = self
                .map
                .iter()
                .filter(|(other, _)| *other != id && self.is_confirmed(*other))
                .filter(|(_, f)| BoundingBox::of(f.coordinates()).near(&here, corner_distance))
                .flat_map(|(other, f)| {
                    f.shareable_blocks()
                        .into_iter()
                        .filter(move |&j| {
                            let b = f.coordinates().blocks()[j];
                            b.kind() == value.kind() && distance(&b, &value) <= corner_distance
                        })
                        .map(move |j| (other, j))
                })
                .collect();
            for (other, j) in others {
                if self.map.links(other)?[j].is_some() || !self.block_estimated(other, j)? {
                    continue;
                }
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
        let (value_f, e_f) = self.block_and_dual(f, kf)?;
        let (value_g, e_g) = self.block_and_dual(g, kg)?;
        let dim = value_f.len();
        // Dry run: both features must accept the shared value.
        let midpoint = (&value_f + &value_g) / 2.0;
        for (id, k) in [(f, kf), (g, kg)] {
            let mut candidate = slam_core::dyn_clone::clone_box(self.map.get(id)?);
            let block = slam_core::CoordBlock::from_slice(
                candidate.coordinates().blocks()[k].kind(),
                midpoint.as_slice(),
            )?;
            if candidate.set_block(k, block).is_err() || candidate.share_block(k).is_err() {
                return Ok(false);
            }
        }
        let mut h = DMatrix::zeros(dim, rows_f.len() + rows_g.len());
        h.view_mut((0, 0), e_f.shape()).copy_from(&e_f);
        h.view_mut((0, rows_f.len()), e_g.shape())
            .copy_from(&(-&e_g));
        let indices: Vec<usize> = rows_f.iter().chain(&rows_g).copied().collect();
        let difference = &value_f - &value_g;
        let c = self.cov.gather(&indices, &indices);
        let sigma = &h * c * h.transpose();
        let Some(sigma_inv) = sigma.try_inverse() else {
            return Ok(false);
        };
        let d2 = (difference.transpose() * sigma_inv * &difference)[(0, 0)];
        let gate = self.gate(self.params.gate_probability, dim)?;
        if d2.is_nan() || d2 > gate {
            return Ok(false);
        }
        let noise = DMatrix::identity(dim, dim) * JOIN_CONSTRAINT_VARIANCE;
        if self.params.observability_constraint {
            h = project_out(&h, &self.cov.generators(&indices));
        }
        let dx = self.cov.update(&indices, &h, &noise, &difference)?;
        self.apply_state_change(&dx)?;

        let (value_f, e_f) = self.block_and_dual(f, kf)?;
        let (value_g, e_g) = self.block_and_dual(g, kg)?;
        let dual_f = self.map.get(f)?.dual()?;
        let dual_g = self.map.get(g)?.dual()?;
        let corner = (&value_f + &value_g) / 2.0;
        let kind = self.map.get(f)?.coordinates().blocks()[kf].kind();
        let shared = self.map.share(
            &[(f, kf), (g, kg)],
            slam_core::CoordBlock::from_slice(kind, corner.as_slice())?,
        )?;
        let b_f = self.map.get(f)?.projection()?;
        let b_g = self.map.get(g)?.projection()?;
        let (rf, rg) = (rows_f.len(), rows_g.len());
        let (nf, ng) = (b_f.nrows(), b_g.nrows());
        let mut t = DMatrix::zeros(dim + nf + ng, rf + rg);
        t.view_mut((0, 0), (dim, rf)).copy_from(&(&e_f * 0.5));
        t.view_mut((0, rf), (dim, rg)).copy_from(&(&e_g * 0.5));
        t.view_mut((dim, 0), (nf, rf)).copy_from(&(&b_f * &dual_f));
        t.view_mut((dim + nf, rf), (ng, rg))
            .copy_from(&(&b_g * &dual_g));
        let before = self.cov.dim();
        let remap = self.cov.reparameterize(&indices, &t)?;
        self.rows.remove(&RowOwner::Feature(f));
        self.rows.remove(&RowOwner::Feature(g));
        for rows in self.rows.values_mut() {
            for row in rows.iter_mut() {
                *row = remap[*row]
                    .ok_or_else(|| Error::InvalidArgument("a kept state row was dropped".into()))?;
            }
        }
        let appended = |k: usize| remap[before + k];
        let new_rows = |from: usize, count: usize| -> Result<Vec<usize>> {
            (from..from + count)
                .map(|k| appended(k).ok_or_else(|| Error::InvalidArgument("lost row".into())))
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
        self.corners_joined += 1;
        Ok(true)
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

/// Euclidean distance between two blocks of the same kind.
fn distance(a: &slam_core::CoordBlock, b: &slam_core::CoordBlock) -> f64 {
    a.as_slice()
        .iter()
        .zip(b.as_slice())
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The positive semi-definite part of a symmetric matrix (negative eigenvalues set to 0).
fn psd_part(m: &DMatrix<f64>) -> DMatrix<f64> {
    let symmetric = 0.5 * (m + m.transpose());
    let eigen = symmetric.symmetric_eigen();
    let clipped = eigen.eigenvalues.map(|v| v.max(0.0));
    &eigen.eigenvectors * DMatrix::from_diagonal(&clipped) * eigen.eigenvectors.transpose()
}
