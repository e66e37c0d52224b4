//! The update step after association: feature lifecycle (sightings, growth, triangulation:
//! the shared rules of [`crate::lifecycle`]), the batch EKF update (eqs. 28-32 and 24),
//! extents, corners and pruning.

use std::collections::BTreeSet;
use std::sync::Arc;

use slam_core::nalgebra::{DMatrixView, DVector};
use slam_core::{
    Error, Extension, FeatureId, Observation, Result, RobotPose, RowOwner, UpdateReport,
};

use super::jacobians::{coordinate_generators, project_out_in_place, stack};
use super::{Decision, Ekf, Pairing};
use crate::lifecycle::{
    MapEntry, OUTSIDE_MSPACE_TOLERANCE, Sighting, Track, drop_views_when_grown, extension_of, grow,
};

/// What one step did to the features it saw.
#[derive(Default)]
struct StepFeatures {
    /// `(observation index, feature)` of every observation that paired or started a feature.
    seen: Vec<(usize, FeatureId)>,
    /// Features that grew this step.
    grown: BTreeSet<FeatureId>,
}

impl<P: RobotPose> Ekf<P> {
    /// Carries out the decisions of one step (see the module documentation).
    pub(super) fn apply_decisions(
        &mut self,
        observations: &[Observation],
        decisions: Vec<Decision>,
    ) -> Result<UpdateReport> {
        let mut report = UpdateReport::default();
        let mut features = StepFeatures {
            seen: Vec::with_capacity(decisions.len()),
            grown: BTreeSet::new(),
        };
        let mut batch = self.pair_and_start(observations, decisions, &mut report, &mut features)?;
        // Pairings of features that grew this step are linearized again, on their new rows.
        batch.retain(|p| !features.grown.contains(&p.feature));
        for &(index, id) in &features.seen {
            if features.grown.contains(&id) && self.is_confirmed(id) {
                match self.linearize(&observations[index], id) {
                    Ok(pairing) => batch.push(pairing),
                    Err(_) => self
                        .skips
                        .count("update: linearization on the grown rows failed"),
                }
            }
        }
        batch.append(&mut self.view_batch);
        if self.params.observability_constraint {
            for pairing in &mut batch {
                self.cov
                    .generators_into(&pairing.indices, &mut self.scratch);
                let n = DMatrixView::from_slice(&self.scratch, pairing.indices.len(), 3);
                project_out_in_place(&mut pairing.h, n);
            }
        }
        report.rejected += self.update_batch(batch)?;
        // The update may have removed a feature that could not take its step.
        features.seen.retain(|&(_, id)| self.map.get(id).is_ok());
        // The update moved the pose: the frames of the extensions below are at the new one.
        self.frames.prepare(&self.pose, observations);
        for &(index, id) in &features.seen {
            self.extend(id, &observations[index])?;
        }
        let mut touched: Vec<FeatureId> = features.seen.iter().map(|&(_, id)| id).collect();
        touched.sort_unstable();
        touched.dedup();
        if self.params.join_corners {
            for &id in &touched {
                self.join_corners_of(id)?;
            }
        }
        for id in touched {
            self.merge_duplicates_of(id)?;
        }
        self.prune_tentative()?;
        Ok(report)
    }

    /// Pairs (NIS, sighting, growth) and starts features; returns the pairings of confirmed
    /// features to update with.
    fn pair_and_start(
        &mut self,
        observations: &[Observation],
        decisions: Vec<Decision>,
        report: &mut UpdateReport,
        features: &mut StepFeatures,
    ) -> Result<Vec<Pairing>> {
        let mut batch: Vec<Pairing> = Vec::with_capacity(decisions.len());
        let mut new_observations = Vec::new();
        for (index, decision) in decisions.into_iter().enumerate() {
            match decision {
                Decision::Pair(pairing) => {
                    let id = pairing.feature;
                    let observation = &observations[index];
                    report.associated += 1;
                    if self.is_confirmed(id) {
                        // Association's figure when it had one: the covariance has not
                        // changed since.
                        let nis = pairing.nis.or_else(|| self.mahalanobis(&pairing, false));
                        match nis {
                            Some(nis) => report.nis.push((nis, pairing.eta.len())),
                            None => self.skips.count("NIS: singular innovation covariance"),
                        }
                        if self.seen_from_the_last_update_viewpoint(id) {
                            self.skips
                                .count("update: seen again from nearly the same viewpoint");
                            self.recycle(pairing);
                        } else {
                            batch.push(pairing);
                        }
                    } else {
                        self.recycle(pairing);
                    }
                    self.note_sighting(id, observation)?;
                    if self.grow(id, observation)? {
                        features.grown.insert(id);
                    }
                    features.seen.push((index, id));
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
                        features.grown.insert(id);
                    }
                    features.seen.push((index, id));
                }
                None => report.rejected += 1,
            }
        }
        Ok(batch)
    }

    /// Whether confirmed feature `id` was last updated from a pose within
    /// `reupdate_distance` and `reupdate_angle` of the current one; if not, the current pose
    /// becomes its last update's. A wall seen again from where it was just seen carries the
    /// same systematic error (the same clutter, the same fit), which independent updates
    /// would count again and again: the feature and the pose become overconfident, and a
    /// later view from elsewhere that disagrees turns the robot instead of the wall.
    fn seen_from_the_last_update_viewpoint(&mut self, id: FeatureId) -> bool {
        let (distance, angle) = (self.params.reupdate_distance, self.params.reupdate_angle);
        let pose = self.pose;
        let track = self.tracks.entry(id).or_default();
        let near = track.last_update.is_some_and(|last| {
            let (moved, turned) = pose.distance_and_angle(&last);
            moved < distance && turned < angle
        });
        if !near {
            track.last_update = Some(pose);
        }
        near
    }

    /// One batch update (eqs. 28-32, 24). A state change that some feature cannot take (it
    /// would turn a wall or line around: a wrong association or a step far outside the
    /// linear range) is not applied; the pairings of those features are dropped and the
    /// rest is updated again. A feature that refuses a step it takes through correlations
    /// only (no pairing of this batch measures it) is removed from the map instead, and the
    /// batch updated again: it is degenerate for the filter (a wall a few centimetres long
    /// whose free end is uncertain by a metre turns around under any step), and kept, it
    /// would refuse every later update too. Returns the number of pairings dropped.
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
            if batch.len() == before && !self.remove_unmeasured(&refused, &mut batch)? {
                // The refusing features were not measured and one of them holds a shared
                // block, so it cannot be removed. Nothing safe is left to update.
                dropped += batch.len();
                break;
            }
            dropped += before - batch.len();
        }
        self.spare_pairings.append(&mut batch);
        Ok(dropped)
    }

    /// Removes the features of `refused`, which no pairing of `batch` measures, and moves
    /// the pairings' state rows to where the rows are after the removal. `false` (nothing
    /// removed) when there is none or one of them holds a shared block.
    fn remove_unmeasured(
        &mut self,
        refused: &BTreeSet<FeatureId>,
        batch: &mut [Pairing],
    ) -> Result<bool> {
        for &id in refused {
            if self.map.links(id)?.iter().any(Option::is_some) {
                return Ok(false);
            }
        }
        for &id in refused {
            let remap = self.remove_feature(id)?;
            for pairing in batch.iter_mut() {
                for row in &mut pairing.indices {
                    *row = remap.get(*row).copied().flatten().ok_or_else(|| {
                        Error::Invariant("a measured state row was removed".into())
                    })?;
                }
            }
            self.skips
                .count("update: a feature the step would turn around was removed");
        }
        Ok(!refused.is_empty())
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
        let pose = self.pose.oplus(&dx.as_slice()[..P::DIM])?;
        self.map.apply_at_rows(
            self.rows
                .iter()
                .map(|(owner, rows)| (*owner, rows.as_slice())),
            dx.as_slice(),
        )?;
        self.pose = pose;
        Ok(())
    }

    /// The feature `observation` would start, placed from the current pose.
    fn start_feature(&mut self, observation: &Observation) -> Result<Option<FeatureId>> {
        let world_from_sensor = self
            .frames
            .world_from_sensor(&self.pose, &observation.robot_from_sensor);
        let feature = match observation
            .measurement
            .initial_feature_dyn(&world_from_sensor)
        {
            Ok(Some(feature)) => feature,
            Ok(None) => return Ok(None),
            Err(_) => {
                self.skips
                    .count("new feature: not placeable from the observation");
                return Ok(None);
            }
        };
        let id = self.map.insert(feature)?;
        self.tracks
            .insert(id, Track::started(observation.landmark_id, 0));
        if let Some(landmark) = observation.landmark_id {
            self.ids.insert(landmark, id);
        }
        self.note_sighting(id, observation)?;
        Ok(Some(id))
    }

    /// Counts a sighting on the feature's track (the shared lifecycle), keeping a view with
    /// the current pose covariance while the feature can grow by triangulation.
    fn note_sighting(&mut self, id: FeatureId, observation: &Observation) -> Result<()> {
        let triangulates = observation.measurement.triangulates_dyn();
        let frame = self
            .frames
            .frame(&self.pose, &observation.robot_from_sensor)
            .ok();
        let sighting = Sighting {
            observation,
            world_from_robot: &self.pose,
            step: self.step,
            view_measurement: triangulates.then(|| Arc::clone(&observation.measurement)),
            pose_covariance: triangulates.then(|| slam_core::Estimator::pose_covariance(self)),
            to_sensor: frame.as_ref().map(|f| &f.to_sensor),
        };
        let feature = self.map.get(id)?;
        let track = self.tracks.entry(id).or_default();
        track.sight(feature, sighting, self.params.max_views, &mut self.skips)
    }

    /// Grows feature `id` by the shared lifecycle rule; new rows enter the state with their
    /// prior, and after a triangulation the earlier views measure them. Returns whether it
    /// grew.
    fn grow(&mut self, id: FeatureId, observation: &Observation) -> Result<bool> {
        let settings = self.params.lifecycle_settings();
        let track = self.tracks.entry(id).or_default();
        let mut entry = MapEntry {
            map: &mut self.map,
            id,
        };
        let Some(grown) = grow(
            track,
            &mut entry,
            observation.measurement.as_ref(),
            &settings,
            &mut self.skips,
        )?
        else {
            return Ok(false);
        };
        let feature = self.map.get(id)?;
        let generators = feature.projection()?.rows(grown.old_dim, grown.added)
            * coordinate_generators(feature.coordinates());
        let range = self.cov.append(&grown.prior, None, &generators);
        self.rows
            .entry(RowOwner::Feature(id))
            .or_default()
            .extend(range);
        if grown.triangulated {
            let views = self.view_pairings(id, grown.old_dim)?;
            self.view_batch.extend(views);
        }
        if let Some(track) = self.tracks.get_mut(&id) {
            drop_views_when_grown(track, self.map.get(id)?);
        }
        Ok(true)
    }

    /// Applies the measurement's change outside the M-space (a wall's extent).
    fn extend(&mut self, id: FeatureId, observation: &Observation) -> Result<()> {
        let feature = self.map.get(id)?;
        let world_from_sensor = self
            .frames
            .world_from_sensor(&self.pose, &observation.robot_from_sensor);
        match extension_of(feature, observation, &world_from_sensor, &mut self.skips) {
            Some(extension) => self.apply_extension(id, extension),
            None => Ok(()),
        }
    }

    /// Moves feature `id` outside its M-space (an extension) and its covariance rows with it.
    /// A change the check refuses (it would move the feature inside its M-space) is not
    /// applied: the estimate stays as it was.
    pub(super) fn apply_extension(&mut self, id: FeatureId, extension: Extension) -> Result<()> {
        let Ok(transform) =
            self.map
                .set_coordinates_outside_mspace(id, extension, OUTSIDE_MSPACE_TOLERANCE)
        else {
            self.skips
                .count("extension: refused (it would move the feature inside its M-space)");
            return Ok(());
        };
        if let Some(transform) = transform {
            let mut rows = Vec::new();
            for (owner, size) in &transform.owners {
                let owned = self.rows.get(owner).ok_or_else(|| {
                    Error::Invariant(format!("row owner {owner:?} has no state rows"))
                })?;
                if owned.len() != *size {
                    return Err(Error::Invariant(format!(
                        "state rows of {owner:?}: {} rows, the map says {size}",
                        owned.len()
                    )));
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
                track.expired(self.step, self.params.tentative_lifetime) && !self.is_confirmed(**id)
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
}

#[cfg(test)]
mod tests {
    use slam_core::nalgebra::{DMatrix, Matrix2, Vector2};
    use slam_core::{Estimator, Observation, Pose2, Pose3, RowOwner, Shape};
    use slam_sensors::models::WallObservation;
    use std::sync::Arc;

    use super::super::{Ekf, EkfParams};

    /// The wall `y = 2`, from `x = -1` to `x = 3`, seen from a robot at `(x, 0, 0)`.
    fn wall_from(x: f64) -> Vec<Observation> {
        let measurement = WallObservation::from_segment(
            Vector2::new(-1.0 - x, 2.0),
            Vector2::new(3.0 - x, 2.0),
            Matrix2::new(1e-4, 0.0, 0.0, 4e-4),
            [false, false],
            [0.05, 0.05],
        )
        .unwrap();
        vec![Observation {
            robot_from_sensor: Pose3::identity(),
            measurement: Arc::new(measurement),
            landmark_id: None,
        }]
    }

    /// The pose's lateral variance after seeing the wall from `x = 0` four times (confirmed
    /// at the third), after once more from `x = 0` and after once from `x = later`; and the
    /// count of sightings not updated with.
    fn lateral_variances(reupdate_distance: f64, later: f64) -> (f64, f64, f64, usize) {
        let params = EkfParams {
            reupdate_distance,
            reupdate_angle: 0.1,
            ..EkfParams::default()
        };
        let mut ekf = Ekf::new(Pose2::identity(), DMatrix::identity(3, 3) * 1e-2, params).unwrap();
        for _ in 0..4 {
            ekf.update(&wall_from(0.0)).unwrap();
        }
        let first = ekf.pose_covariance()[(1, 1)];
        let mut report = ekf.update(&wall_from(0.0)).unwrap();
        let again = ekf.pose_covariance()[(1, 1)];
        ekf.pose = Pose2::new(later, 0.0, 0.0);
        report
            .skipped
            .merge(&ekf.update(&wall_from(later)).unwrap().skipped);
        let skipped = report
            .skipped
            .get("update: seen again from nearly the same viewpoint");
        (first, again, ekf.pose_covariance()[(1, 1)], skipped)
    }

    /// With `reupdate_distance` a wall seen again from where it was last updated does not
    /// update the filter; seen from farther away it does. Without it every sighting updates.
    #[test]
    fn a_feature_is_updated_again_only_from_a_new_viewpoint() {
        let (first, again, moved, skipped) = lateral_variances(0.3, 0.5);
        assert_eq!(again, first);
        assert!(moved < again, "{moved} {again}");
        assert_eq!(skipped, 1);
        let (_, again, same_place, skipped) = lateral_variances(0.3, 0.1);
        assert_eq!(same_place, again);
        assert_eq!(skipped, 2);
        let (first, every, _, skipped) = lateral_variances(0.0, 0.0);
        assert!(every < first, "{every} {first}");
        assert_eq!(skipped, 0);
    }

    /// Landmark 7 seen at 5 m, bearing `bearing`, from a robot at the origin.
    fn landmark_seen(bearing: f64) -> Vec<Observation> {
        let measurement =
            slam_sensors::models::RangeBearing::new(5.0, bearing, 0.05, 0.01).unwrap();
        vec![Observation {
            robot_from_sensor: Pose3::identity(),
            measurement: Arc::new(measurement),
            landmark_id: Some(7),
        }]
    }

    /// Where the map puts landmark 7 after four sightings at bearing 0.3 and one at `last`,
    /// and how many sightings the known-id validation gate rejected.
    fn after_outlier(gate: f64, last: f64) -> (Vector2<f64>, usize) {
        let params = EkfParams {
            known_id_gate_probability: gate,
            ..EkfParams::default()
        };
        let mut ekf = Ekf::new(Pose2::identity(), DMatrix::identity(3, 3) * 1e-4, params).unwrap();
        for _ in 0..4 {
            ekf.update(&landmark_seen(0.3)).unwrap();
        }
        let report = ekf.update(&landmark_seen(last)).unwrap();
        let rejected = report
            .skipped
            .get("association: a known landmark outside its validation gate");
        let positions: Vec<Vector2<f64>> = ekf
            .map()
            .iter()
            .filter_map(|(_, f)| match f.shape() {
                Some(Shape::Point { position }) => Some(position.xy()),
                Some(Shape::PlanarPoint { position }) => Some(position),
                _ => None,
            })
            .collect();
        assert_eq!(positions.len(), 1);
        (positions[0], rejected)
    }

    /// A known landmark seen 0.5 rad (50 bearing deviations) from where the filter puts it
    /// does not update with the gate and moves the landmark without it; a sighting within
    /// its noise passes the gate.
    #[test]
    fn a_known_landmark_far_outside_its_innovation_gate_does_not_update() {
        let (before, _) = after_outlier(0.999, 0.3);
        let (gated, rejected) = after_outlier(0.999, 0.8);
        assert_eq!(rejected, 1);
        assert_eq!(gated, before);
        let (ungated, rejected) = after_outlier(1.0, 0.8);
        assert_eq!(rejected, 0);
        assert!((ungated - before).norm() > 0.1, "{ungated} {before}");
        let (inlier, rejected) = after_outlier(0.999, 0.305);
        assert_eq!(rejected, 0);
        assert_ne!(inlier, before);
    }

    fn segment(a: Vector2<f64>, b: Vector2<f64>, real: [bool; 2]) -> Observation {
        let line_cov = Matrix2::new(1e-4, 0.0, 0.0, 4e-4);
        let measurement = WallObservation::from_segment(a, b, line_cov, real, [0.05, 0.05]);
        Observation {
            robot_from_sensor: Pose3::identity(),
            measurement: Arc::new(measurement.unwrap()),
            landmark_id: None,
        }
    }

    /// The pose's `y` after a sighting of a long wall that puts it 5 cm off (from 0.05), the
    /// count of features removed and of features left, with a 10 cm wall in the map whose
    /// end is correlated with the pose's `y` by `coupling` (a degenerate wall: the step of
    /// the pose moves its end by metres, past its start for one sign of `coupling`).
    fn with_degenerate_wall(coupling: f64) -> (f64, usize, usize) {
        let mut ekf = Ekf::new(
            Pose2::identity(),
            DMatrix::identity(3, 3) * 1e-2,
            EkfParams::default(),
        )
        .unwrap();
        let long = || {
            segment(
                Vector2::new(-1.0, 2.0),
                Vector2::new(3.0, 2.0),
                [false, false],
            )
        };
        let short = || {
            segment(
                Vector2::new(2.0, -0.3),
                Vector2::new(2.0, -0.2),
                [true, true],
            )
        };
        for _ in 0..8 {
            ekf.update(&[long(), short()]).unwrap();
        }
        let short_id = ekf.map().iter().map(|(id, _)| id).max().unwrap();
        let rows = ekf.rows[&RowOwner::Feature(short_id)].clone();
        // Line, start and end rows: the last moves the end along the wall.
        assert_eq!(rows.len(), 4);
        let end_row = rows[3];
        // The robot drives on: the pose is uncertain against the map, which can correct it.
        let noise = DMatrix::identity(3, 3) * 1e-2;
        ekf.cov.predict(&DMatrix::identity(3, 3), &noise);
        let t = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, coupling, 1.0]);
        ekf.cov.transform_rows(&[1, end_row], &t).unwrap();
        ekf.pose = Pose2::new(0.0, 0.05, 0.0);
        let report = ekf.update(&[long()]).unwrap();
        let removed = report
            .skipped
            .get("update: a feature the step would turn around was removed");
        (ekf.pose().y, removed, ekf.map().len())
    }

    /// A feature that the update's step would turn around through its correlations alone is
    /// removed, and the update goes through (before, the whole update was dropped, and every
    /// later one too: on the noisy acapulco log the filter stopped updating 30 scans before
    /// the end).
    #[test]
    fn a_degenerate_feature_moved_only_through_correlations_does_not_block_updates() {
        for (coupling, removed) in [(20.0, 1), (80.0, 1), (-20.0, 0), (-80.0, 0)] {
            let (y, removals, features) = with_degenerate_wall(coupling);
            // The long wall corrects the pose either way.
            assert!(y < 0.01, "coupling {coupling}: y {y}");
            // The short wall goes when its end would pass its start, not when it lengthens.
            assert_eq!(
                (removals, features),
                (removed, 2 - removed),
                "coupling {coupling}"
            );
        }
    }
}
