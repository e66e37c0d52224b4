//! Merging duplicates: two confirmed features that are one physical feature (a wall mapped
//! twice after drift, a tree started twice) become one.
//!
//! The test is in the features' M-spaces with their joint covariance: the feature type gives
//! the residual that is zero when the two coincide and its Jacobians
//! ([`slam_core::Feature::coincidence`]); through `B~` (own rows) and the identity (shared
//! blocks) these become a row block `H` on the state, and the pair is a duplicate when
//! `r^T (H C H^T + t^2 I)^-1 r` passes the `merge_probability` gate of chi-square (`t` the
//! `merge_tolerance`). The pair is then constrained together by an update with the residual
//! measured zero (variance `1e-4 + t^2`; like a corner join), the kept feature grows over
//! the other's extent ([`slam_core::Feature::absorbed`]), and the other's rows are
//! marginalized out (deleted from the state): every correlation of the kept feature, with the
//! pose and with the rest of the map, stays as the constraint left it.
//!
//! The feature kept is the one seen more often, unless only the other holds shared blocks
//! (corners): then that one is kept. When both hold corners (a wall mapped twice round a
//! loop, each copy joined to the corner at its own end), the removed one's corners pass to
//! the kept one: each joins the kept feature's free, estimated end nearest to it, by the
//! tight constraint and re-parameterization of a corner join, and the removed feature leaves
//! the corner's members. Where the kept feature has no such end the pair stays two.

use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{Error, FeatureId, Result, RobotPose, RowOwner, Shape, SharedBlockId};

use super::Ekf;
use super::jacobians::project_out;
use crate::lifecycle::corners::heir_block;
use crate::lifecycle::{MERGE_ANGLE, MERGE_CONSTRAINT_VARIANCE};

/// For each shared block a removed duplicate holds, the block of the kept feature that joins
/// it (`None`: the kept feature holds that shared block already).
type Handover = Vec<(SharedBlockId, Option<usize>)>;

/// How two features found to be one are merged.
struct MergePlan {
    keep: FeatureId,
    drop: FeatureId,
    /// How `drop`'s shared blocks pass to `keep`.
    handover: Handover,
}

impl<P: RobotPose> Ekf<P> {
    /// Merges feature `id` with every confirmed feature that is the same one (see the module
    /// documentation). `id` itself may be merged away. A feature the data identify (a
    /// landmark id) is never merged.
    pub(super) fn merge_duplicates_of(&mut self, id: FeatureId) -> Result<()> {
        let known = self
            .tracks
            .get(&id)
            .is_some_and(|t| t.landmark_id.is_some());
        if !self.params.merge_duplicates
            || known
            || self.map.get(id).is_err()
            || !self.is_confirmed(id)
        {
            return Ok(());
        }
        for other in self.merge_candidates(id)? {
            if self.map.get(id).is_err() {
                break;
            }
            if self.map.get(other).is_ok() {
                self.try_merge(id, other)?;
            }
        }
        Ok(())
    }

    /// The confirmed features of `id`'s kind whose shape overlaps its shape within
    /// `merge_distance`, or, for point-like features (trees, points), farther (up to
    /// `association_margin`) when the two are so uncertain that the joint test could still
    /// find them one: within the gate of twice the sum of their own coincidence covariances,
    /// which bounds the joint one from above. Segments (walls, lines) never go beyond
    /// `merge_distance`: a newly confirmed wall is uncertain mostly through the pose that
    /// placed it, and merging it with a wall 30 cm away on that ground turned the path by
    /// degrees on a real log (freiburg-079).
    fn merge_candidates(&self, id: FeatureId) -> Result<Vec<FeatureId>> {
        let feature = self.map.get(id)?;
        let Some(shape) = feature.shape() else {
            return Ok(Vec::new());
        };
        let point_like = matches!(
            shape,
            Shape::Pole { .. } | Shape::Point { .. } | Shape::PlanarPoint { .. }
        );
        let (own, dim) = self.coincidence_variance(id);
        let gate = self.gates.gate(self.params.merge_probability, dim.max(1))?;
        Ok(self
            .map
            .iter()
            .filter(|(other, f)| {
                // The separation first: it rules out all but a few of the map's features, and
                // is cheaper than the confirmation lookup.
                if *other == id || f.kind() != feature.kind() {
                    return false;
                }
                let Some(d) = f
                    .shape()
                    .and_then(|s| shape.overlap_separation(&s, MERGE_ANGLE))
                else {
                    return false;
                };
                let near = d <= self.params.merge_distance
                    || (point_like
                        && d <= self.params.association_margin
                        && d * d <= gate * 2.0 * (own + self.coincidence_variance(*other).0));
                near && self.is_confirmed(*other)
            })
            .map(|(other, _)| other)
            .collect())
    }

    /// A bound on the largest variance of a feature's coincidence residual (the trace of its
    /// covariance from the feature's own rows, plus `merge_tolerance` squared), in the
    /// residual's units squared, and the residual's dimension; `(0, 0)` when it has no
    /// coincidence with itself or no rows.
    fn coincidence_variance(&self, id: FeatureId) -> (f64, usize) {
        let Ok(feature) = self.map.get(id) else {
            return (0.0, 0);
        };
        let Ok(Some(coincidence)) = feature.coincidence(feature) else {
            return (0.0, 0);
        };
        let Ok((indices, h)) = self.coordinate_rows(id, &coincidence.d_self) else {
            return (0.0, 0);
        };
        let c = self.cov.gather(&indices, &indices);
        let dim = coincidence.residual.len();
        let variance = (&h * c * h.transpose()).trace() + self.params.merge_tolerance.powi(2);
        (variance, dim)
    }

    /// Merges `a` and `b` if they pass the test; returns whether they were merged.
    fn try_merge(&mut self, a: FeatureId, b: FeatureId) -> Result<bool> {
        let Some(MergePlan {
            keep,
            drop,
            handover,
        }) = self.merge_plan(a, b)?
        else {
            return Ok(false);
        };
        let Some(coincidence) = self.map.get(keep)?.coincidence(self.map.get(drop)?)? else {
            return Ok(false);
        };
        let (mut indices, h_keep) = self.coordinate_rows(keep, &coincidence.d_self)?;
        let (indices_drop, h_drop) = self.coordinate_rows(drop, &coincidence.d_other)?;
        indices.extend(indices_drop);
        let (m, nk) = (coincidence.residual.len(), h_keep.ncols());
        let mut h = DMatrix::zeros(m, indices.len());
        h.view_mut((0, 0), (m, nk)).copy_from(&h_keep);
        h.view_mut((0, nk), (m, h_drop.ncols())).copy_from(&h_drop);
        let residual = coincidence.residual;
        let c = self.cov.gather(&indices, &indices);
        let tolerance = DMatrix::identity(m, m) * self.params.merge_tolerance.powi(2);
        let Some(s_inv) = (&h * c * h.transpose() + &tolerance).try_inverse() else {
            self.skips.count("merge: singular difference covariance");
            return Ok(false);
        };
        let d2 = (residual.transpose() * s_inv * &residual)[(0, 0)];
        let gate = self.gates.gate(self.params.merge_probability, m)?;
        if d2.is_nan() || d2 > gate {
            return Ok(false);
        }
        if !self.constrain_merged(&indices, h, &residual)? {
            return Ok(false);
        }
        if let Some(extension) = self.map.get(keep)?.absorbed(self.map.get(drop)?)? {
            self.apply_extension(keep, extension)?;
        }
        for (shared, block) in handover {
            if let Some(k) = block
                && !self.join_existing(keep, k, shared)?
            {
                self.skips
                    .count("merge: a corner of the duplicate could not pass to the wall kept");
                return Ok(false);
            }
        }
        let sightings = self.tracks.get(&drop).map_or(0, |t| t.sightings);
        if let Some(track) = self.tracks.get_mut(&keep) {
            track.sightings += sightings;
        }
        self.drop_feature(drop)?;
        self.features_merged += 1;
        Ok(true)
    }

    /// Which of two features is kept and which removed, and how the removed one's shared
    /// blocks pass to the kept one: `None` when they cannot be merged (known landmarks, or
    /// both holding corners and neither able to take the other's). A merge that removes no
    /// corner is preferred, then the feature seen more often is kept.
    fn merge_plan(&self, a: FeatureId, b: FeatureId) -> Result<Option<MergePlan>> {
        let track = |id: FeatureId| self.tracks.get(&id);
        if [a, b]
            .iter()
            .any(|id| track(*id).is_some_and(|t| t.landmark_id.is_some()))
        {
            return Ok(None);
        }
        let sightings = |id: FeatureId| track(id).map_or(0, |t| t.sightings);
        let (first, second) = if sightings(b) > sightings(a) {
            (b, a)
        } else {
            (a, b)
        };
        let holds_shared =
            |id: FeatureId| -> Result<bool> { Ok(self.map.links(id)?.iter().any(Option::is_some)) };
        // (kept, removed): first the order whose removed feature holds no corner, if any.
        let mut orders = [(first, second), (second, first)];
        if holds_shared(second)? && !holds_shared(first)? {
            orders.swap(0, 1);
        }
        for (keep, drop) in orders {
            if let Some(handover) = self.handover(keep, drop)? {
                return Ok(Some(MergePlan {
                    keep,
                    drop,
                    handover,
                }));
            }
        }
        Ok(None)
    }

    /// How each shared block of `drop` passes to `keep`, or `None` when one cannot.
    fn handover(&self, keep: FeatureId, drop: FeatureId) -> Result<Option<Handover>> {
        let held = self.map.links(keep)?;
        let mut handover = Vec::new();
        let mut taken = Vec::new();
        for shared in self.map.links(drop)?.iter().flatten() {
            if held.contains(&Some(*shared)) {
                handover.push((*shared, None));
                continue;
            }
            let corner = self.map.shared_block(*shared)?.value;
            match heir_block(
                &self.map,
                keep,
                &corner,
                &taken,
                self.params.corner_distance,
            )? {
                Some(k) => {
                    taken.push(k);
                    handover.push((*shared, Some(k)));
                }
                None => return Ok(None),
            }
        }
        Ok(Some(handover))
    }

    /// A Jacobian with respect to feature `id`'s coordinates as columns on its state rows:
    /// `d B~` on the own rows and the block's columns on each shared block's rows.
    fn coordinate_rows(
        &self,
        id: FeatureId,
        d_coordinates: &DMatrix<f64>,
    ) -> Result<(Vec<usize>, DMatrix<f64>)> {
        let feature = self.map.get(id)?;
        let mut indices = Vec::new();
        let mut columns: Vec<DMatrix<f64>> = Vec::new();
        if feature.mspace_dim() > 0 {
            let rows = self
                .rows
                .get(&RowOwner::Feature(id))
                .ok_or_else(|| Error::Invariant(format!("feature {} has no state rows", id.0)))?;
            indices.extend_from_slice(rows);
            columns.push(d_coordinates * feature.dual()?);
        }
        let coordinates = feature.coordinates();
        for (k, link) in self.map.links(id)?.iter().enumerate() {
            let Some(shared) = link else { continue };
            let rows = self.rows.get(&RowOwner::Shared(*shared)).ok_or_else(|| {
                Error::Invariant(format!("shared block {} has no state rows", shared.0))
            })?;
            indices.extend_from_slice(rows);
            let width = coordinates.blocks()[k].dim();
            columns.push(
                d_coordinates
                    .columns(coordinates.offset(k), width)
                    .into_owned(),
            );
        }
        let mut h = DMatrix::zeros(d_coordinates.nrows(), indices.len());
        let mut at = 0;
        for block in columns {
            h.view_mut((0, at), block.shape()).copy_from(&block);
            at += block.ncols();
        }
        Ok((indices, h))
    }

    /// The tight update that makes the residual zero; all or nothing (a change some feature
    /// cannot take leaves the state as it was). Returns whether it was applied.
    fn constrain_merged(
        &mut self,
        indices: &[usize],
        mut h: DMatrix<f64>,
        residual: &DVector<f64>,
    ) -> Result<bool> {
        let m = residual.len();
        if self.params.observability_constraint {
            h = project_out(&h, &self.cov.generators(indices));
        }
        let variance = MERGE_CONSTRAINT_VARIANCE + self.params.merge_tolerance.powi(2);
        let noise = DMatrix::identity(m, m) * variance;
        let prepared = self.cov.prepare_update(indices, &h, &noise, residual)?;
        if self.apply_state_change(&prepared.dx).is_err() {
            self.skips
                .count("merge: the constraint would move a feature where it cannot go");
            return Ok(false);
        }
        self.cov.commit(prepared);
        Ok(true)
    }

    /// Removes a confirmed feature that holds no shared block: its rows leave the state
    /// (marginalized out), its track and map entry go. Returns where each state row went
    /// (`None`: removed).
    pub(super) fn remove_feature(&mut self, id: FeatureId) -> Result<Vec<Option<usize>>> {
        if self.map.links(id)?.iter().any(Option::is_some) {
            return Err(Error::Invariant(format!(
                "feature {} holds a shared block and cannot be removed",
                id.0
            )));
        }
        self.drop_feature(id)
    }

    /// Removes a confirmed feature as [`Self::remove_feature`] does, and takes it out of the
    /// shared blocks it holds (each must keep another member: a merged duplicate whose
    /// corners have passed to the feature kept).
    fn drop_feature(&mut self, id: FeatureId) -> Result<Vec<Option<usize>>> {
        self.map.remove_from_shared(id)?;
        let mut remap: Vec<Option<usize>> = (0..self.cov.dim()).map(Some).collect();
        if let Some(rows) = self.rows.remove(&RowOwner::Feature(id)) {
            let mut dropped = vec![false; self.cov.dim()];
            for row in rows {
                dropped[row] = true;
            }
            remap = self.cov.compact(&dropped);
            for rows in self.rows.values_mut() {
                for row in rows.iter_mut() {
                    *row = remap[*row]
                        .ok_or_else(|| Error::Invariant("a kept state row was dropped".into()))?;
                }
            }
        }
        if let Some(track) = self.tracks.remove(&id)
            && let Some(landmark) = track.landmark_id
        {
            self.ids.remove(&landmark);
        }
        Ok(remap)
    }
}

#[cfg(test)]
mod tests {
    use slam_core::nalgebra::{DMatrix, Matrix2};
    use slam_core::{Estimator, Observation, Pose2, Pose3};
    use slam_sensors::models::PoleObservation;
    use std::sync::Arc;

    use super::super::{Decision, Ekf, EkfParams};
    use crate::test_support::{
        segment_sighting, wall_sighting as sighting, wall_sighting_with as sighting_with,
    };

    /// Two features started from two sightings in one step, with merging on or off.
    fn two_walls(merge: bool, sightings: [Observation; 2]) -> Ekf<Pose2> {
        let params = EkfParams {
            confirm_after: 1,
            merge_duplicates: merge,
            join_corners: false,
            ..EkfParams::default()
        };
        let mut ekf = Ekf::new(Pose2::identity(), DMatrix::identity(3, 3) * 1e-4, params).unwrap();
        ekf.apply_decisions(&sightings, vec![Decision::New, Decision::New])
            .unwrap();
        ekf
    }

    fn is_symmetric_psd(c: &DMatrix<f64>) -> bool {
        let symmetric = (c - c.transpose()).amax() <= 1e-9 * c.amax().max(1.0);
        let eigenvalues = c.clone().symmetric_eigenvalues();
        symmetric && eigenvalues.iter().all(|&e| e > -1e-9)
    }

    /// One wall mapped twice (two overlapping sightings within their noise) becomes one wall
    /// that covers both extents; the state loses the removed wall's rows and the covariance
    /// stays symmetric and positive semi-definite.
    #[test]
    fn a_wall_mapped_twice_is_merged() {
        let sightings = || [sighting(2.0, 0.0, 3.0), sighting(2.01, 2.0, 5.0)];
        let kept_apart = two_walls(false, sightings());
        assert_eq!(kept_apart.map().len(), 2);
        let merged = two_walls(true, sightings());
        assert_eq!(merged.features_merged(), 1);
        assert_eq!(merged.map().len(), 1);
        assert_eq!(merged.state_dim(), kept_apart.state_dim() - 2);
        assert!(is_symmetric_psd(&merged.covariance()));
        let (_, wall) = merged.map().iter().next().unwrap();
        let slam_core::Shape::Wall { start, end } = wall.shape().unwrap() else {
            panic!("not a wall");
        };
        let (lo, hi) = (start.x.min(end.x), start.x.max(end.x));
        assert!(
            lo < 0.05 && hi > 4.95,
            "the kept wall covers both: {start} {end}"
        );
        assert!((start.y - 2.005).abs() < 0.01 && (end.y - 2.005).abs() < 0.01);
    }

    /// A tree seen at 10 m range and bearing `bearing` with range and bearing deviations
    /// `sigmas`.
    fn tree(bearing: f64, sigmas: [f64; 2]) -> Observation {
        let measurement =
            PoleObservation::new(10.0, bearing, 0.2, [sigmas[0], sigmas[1], 0.05]).unwrap();
        Observation {
            robot_from_sensor: Pose3::identity(),
            measurement: Arc::new(measurement),
            landmark_id: None,
        }
    }

    /// A wall seen from the origin from `a` to `b`, with real ends as `real` says (a corner
    /// can form at a real end).
    fn wall(a: [f64; 2], b: [f64; 2], real: [bool; 2]) -> Observation {
        segment_sighting(a.into(), b.into(), Matrix2::new(1e-4, 0.0, 0.0, 4e-4), real)
    }

    /// Starts features from `walls()` and sees them again `times` times, each paired with
    /// the feature it started; returns those features.
    fn map_walls(
        ekf: &mut Ekf<Pose2>,
        walls: impl Fn() -> Vec<Observation>,
        times: usize,
    ) -> Vec<slam_core::FeatureId> {
        let before: Vec<_> = ekf.map().iter().map(|(id, _)| id).collect();
        let first = walls();
        let new = first.iter().map(|_| Decision::New).collect();
        ekf.apply_decisions(&first, new).unwrap();
        let ids: Vec<_> = ekf
            .map()
            .iter()
            .map(|(id, _)| id)
            .filter(|id| !before.contains(id))
            .collect();
        for _ in 0..times {
            let seen = walls();
            let pose = ekf.pose;
            ekf.frames.prepare(&pose, &seen);
            let decisions = seen
                .iter()
                .zip(&ids)
                .map(|(wall, id)| Decision::Pair(ekf.linearize(wall, *id).unwrap()))
                .collect();
            ekf.apply_decisions(&seen, decisions).unwrap();
        }
        ids
    }

    /// A filter (merging off) that has mapped wall B (x 0.5-3 on y = 2) joined at (3, 2) to
    /// wall D (x = 3, up to y = 4); returns the filter and `[B, D]`.
    fn wall_b_with_corner_d() -> (Ekf<Pose2>, Vec<slam_core::FeatureId>) {
        let params = EkfParams {
            confirm_after: 1,
            merge_duplicates: false,
            ..EkfParams::default()
        };
        let mut ekf = Ekf::new(Pose2::identity(), DMatrix::identity(3, 3) * 1e-4, params).unwrap();
        let both = [true, true];
        let bd = map_walls(
            &mut ekf,
            || {
                vec![
                    wall([0.5, 2.0], [3.0, 2.0], both),
                    wall([3.0, 2.0], [3.0, 4.0], both),
                ]
            },
            2,
        );
        (ekf, bd)
    }

    /// A wall mapped twice round a loop, each copy joined to the corner at its own end: wall
    /// B (x 0.5-3 on y = 2) holds the corner with D at (3, 2), then wall A (x -1-3) is mapped
    /// with C, joined to it at (-1, 2), and ends free at (3, 2). Merging passes B's corner to
    /// A: three walls remain, A holding both corners (no own rows left), the map's shared
    /// blocks consistent and the covariance symmetric positive semi-definite. With A's end at
    /// (3, 2) not estimated (never a real end) the corner cannot pass and both stay.
    #[test]
    fn duplicates_holding_corners_at_their_own_ends_are_merged() {
        for a_end_real in [true, false] {
            let (mut ekf, bd) = wall_b_with_corner_d();
            let both = [true, true];
            let ac = map_walls(
                &mut ekf,
                || {
                    vec![
                        wall([-1.0, 2.0], [3.0, 2.0], [true, a_end_real]),
                        wall([-1.0, 4.0], [-1.0, 2.0], both),
                    ]
                },
                2,
            );
            assert_eq!(ekf.corners_joined(), 2);
            assert_eq!(ekf.map().len(), 4);
            let links = |ekf: &Ekf<Pose2>, id| ekf.map().links(id).unwrap().to_vec();
            let (wall_a, wall_b) = (ac[0], bd[0]);
            assert_eq!(links(&ekf, wall_a).iter().flatten().count(), 1);
            assert_eq!(links(&ekf, wall_b).iter().flatten().count(), 1);
            let dim = ekf.state_dim();
            ekf.params.merge_duplicates = true;
            ekf.merge_duplicates_of(wall_a).unwrap();
            ekf.map().check_consistency().unwrap();
            assert!(is_symmetric_psd(&ekf.covariance()));
            if !a_end_real {
                assert_eq!((ekf.features_merged(), ekf.map().len()), (0, 4));
                continue;
            }
            assert_eq!((ekf.features_merged(), ekf.map().len()), (1, 3));
            assert!(ekf.map().get(wall_b).is_err(), "B is the one removed");
            assert_eq!(ekf.map().get(wall_a).unwrap().mspace_dim(), 0);
            assert!(links(&ekf, wall_a).iter().all(Option::is_some));
            // A's own rows (pivot and end) and B's are gone; the two corners stay.
            assert_eq!(ekf.state_dim(), dim - 4);
        }
    }

    /// Of a wall holding a corner and a duplicate holding none, the corner holder is kept even
    /// when the duplicate was seen more often and could take the corner: a merge that moves
    /// no corner is preferred.
    #[test]
    fn the_corner_holder_is_kept_when_the_duplicate_holds_none() {
        let (mut ekf, bd) = wall_b_with_corner_d();
        let both = [true, true];
        let a = map_walls(&mut ekf, || vec![wall([-1.0, 2.0], [3.0, 2.0], both)], 4);
        let (wall_a, wall_b) = (a[0], bd[0]);
        assert_eq!(ekf.corners_joined(), 1);
        assert!(ekf.map().links(wall_a).unwrap().iter().all(Option::is_none));
        ekf.params.merge_duplicates = true;
        ekf.merge_duplicates_of(wall_a).unwrap();
        assert_eq!((ekf.features_merged(), ekf.map().len()), (1, 2));
        assert!(
            ekf.map().get(wall_a).is_err(),
            "the duplicate is the one removed"
        );
        let corner = ekf.map().shared_block(slam_core::SharedBlockId(0)).unwrap();
        let members: Vec<_> = corner.members.iter().map(|(id, _)| *id).collect();
        assert_eq!(members, vec![wall_b, bd[1]]);
    }

    /// Two trees 0.8 m apart (beyond `merge_distance`) started from sightings whose
    /// deviations (1 m, 6 degrees) make them one tree by the joint test: merged. The same
    /// trees seen with 5 cm and 0.3 degrees are distinct and both stay.
    #[test]
    fn uncertain_trees_farther_apart_than_merge_distance_are_merged() {
        let apart = 0.08; // rad at 10 m: 0.8 m
        let loose = two_walls(true, [tree(0.0, [1.0, 0.1]), tree(apart, [1.0, 0.1])]);
        assert_eq!(loose.features_merged(), 1);
        assert_eq!(loose.map().len(), 1);
        assert!(is_symmetric_psd(&loose.covariance()));
        let tight = two_walls(true, [tree(0.0, [0.05, 0.005]), tree(apart, [0.05, 0.005])]);
        assert_eq!(tight.features_merged(), 0);
        assert_eq!(tight.map().len(), 2);
    }

    /// Two parallel walls 30 cm apart (both sides of a corridor's clutter, a wall and a
    /// cupboard) are far outside their noise: both stay.
    #[test]
    fn distinct_parallel_walls_stay_apart() {
        let ekf = two_walls(true, [sighting(2.0, 0.0, 3.0), sighting(2.3, 1.0, 4.0)]);
        assert_eq!(ekf.features_merged(), 0);
        assert_eq!(ekf.map().len(), 2);
    }

    /// Two uncertain parallel walls 0.8 m apart (beyond `merge_distance`) whose joint test
    /// alone would call them one are not merged: a segment's uncertainty is mostly the pose
    /// that placed it, and merging on that ground bends the path (uncertain trees are, above).
    #[test]
    fn uncertain_walls_farther_apart_than_merge_distance_stay_apart() {
        let loose = Matrix2::new(0.5, 0.0, 0.0, 0.05);
        let ekf = two_walls(
            true,
            [
                sighting_with(2.0, 0.0, 3.0, loose),
                sighting_with(2.8, 0.0, 3.0, loose),
            ],
        );
        assert_eq!(ekf.features_merged(), 0);
        assert_eq!(ekf.map().len(), 2);
    }
}
