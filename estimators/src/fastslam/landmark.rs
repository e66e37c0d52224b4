//! One feature of one particle: the feature, the EKF over its own M-space rows, and its
//! lifecycle track; and a particle's map of them.

use std::collections::BTreeMap;
use std::sync::Arc;

use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{
    DynMeasurementModel, Extension, Feature, FeatureMap, Observation, OwnLinearization, Pose3,
    Result, RobotPose, SensorFrame, Skips, linearize_own_at, linearize_own_at_into,
};

use super::small;
use crate::association::BoundingBox;
use crate::lifecycle::{
    LifecycleSettings, MERGE_ANGLE, MERGE_CONSTRAINT_VARIANCE, OUTSIDE_MSPACE_TOLERANCE, Track,
    drop_views_when_grown, extension_of, grow,
};
use crate::particles::log_normal;
use crate::particles::pvec::{PVec, Summary};

/// A subtree of a particle's map summarized by the bounding box of its features.
impl<P> Summary<Landmark<P>> for BoundingBox {
    fn empty() -> Self {
        BoundingBox::default()
    }

    fn of(landmark: &Landmark<P>) -> Self {
        BoundingBox::of(landmark.feature.coordinates())
    }

    fn join(&mut self, other: &Self) {
        self.include(other);
    }
}

/// One feature of one particle.
#[derive(Clone, Debug)]
pub(super) struct Landmark<P> {
    pub feature: Box<dyn Feature>,
    /// Covariance of the own M-space perturbation (`mspace_dim` square).
    pub cov: DMatrix<f64>,
    pub track: Track<P>,
}

/// A particle's map and what it keeps besides.
#[derive(Clone, Debug)]
pub(super) struct LandmarkMap<P> {
    /// The features, with the bounding box of each subtree for the candidate search.
    pub landmarks: PVec<Landmark<P>, BoundingBox>,
    /// Known landmark ids to slots (copied on write: only when a new id appears).
    pub ids: Arc<BTreeMap<u64, usize>>,
    /// Slots of tentative features (few), for pruning.
    pub tentative: Vec<usize>,
    /// FastSLAM 2.0: the pose covariance accumulated by predictions since the pose was last
    /// drawn (the pose is their mean meanwhile).
    pub pending: Option<DMatrix<f64>>,
}

impl<P> Default for LandmarkMap<P> {
    fn default() -> Self {
        LandmarkMap {
            landmarks: PVec::default(),
            ids: Arc::new(BTreeMap::new()),
            tentative: Vec::new(),
            pending: None,
        }
    }
}

/// How [`LandmarkMap::merge_duplicates`] tests pairs.
pub(super) struct MergeSettings<'a> {
    /// Features farther apart than this are not tested, m.
    pub distance: f64,
    /// Model error on top of the pair's covariance.
    pub tolerance: f64,
    /// The chi-square gate of the coincidence residual for its dimension.
    pub gate: &'a dyn Fn(usize) -> Result<f64>,
}

impl<P: RobotPose> LandmarkMap<P> {
    /// Merges the duplicates among the confirmed features without a landmark id, each
    /// with every feature of its kind whose shape overlaps its shape within the settings'
    /// distance and that passes [`Landmark::absorb`]; the one seen more often is kept.
    /// Returns the number of features removed. A pair that cannot be tested (its
    /// coincidence or a change fails) stays two features, counted in `skips`.
    pub(super) fn merge_duplicates(
        &mut self,
        settings: &MergeSettings<'_>,
        skips: &mut Skips,
    ) -> usize {
        let slots: Vec<usize> = self.landmarks.iter().map(|(slot, _)| slot).collect();
        let mut removed = 0;
        for slot in slots {
            let mut current = slot;
            for other in self.merge_candidates(slot, settings.distance) {
                match self.try_merge(current, other, settings, skips) {
                    Ok(Some(kept)) => {
                        current = kept;
                        removed += 1;
                    }
                    Ok(None) => {}
                    Err(_) => skips.count("merge: the pair could not be tested"),
                }
            }
        }
        removed
    }

    /// The confirmed features without a landmark id of `slot`'s kind whose shape overlaps
    /// its shape within `distance`.
    fn merge_candidates(&self, slot: usize, distance: f64) -> Vec<usize> {
        let Some(landmark) = self.landmarks.get(slot) else {
            return Vec::new();
        };
        let feature = landmark.feature.as_ref();
        let Some(shape) = feature.shape() else {
            return Vec::new();
        };
        if feature.mspace_dim() == 0 || landmark.track.landmark_id.is_some() {
            return Vec::new();
        }
        let near = BoundingBox::of(feature.coordinates());
        self.landmarks
            .iter_where(|bbox| bbox.near(&near, distance))
            .into_iter()
            .filter(|(other, l, _)| {
                *other != slot
                    && l.feature.kind() == feature.kind()
                    && l.feature.mspace_dim() > 0
                    && l.track.landmark_id.is_none()
                    && l.feature
                        .shape()
                        .and_then(|s| shape.overlap_separation(&s, MERGE_ANGLE))
                        .is_some_and(|d| d <= distance)
            })
            .map(|(other, _, _)| other)
            .collect()
    }

    /// Merges the features in slots `a` and `b` if they are one; returns the slot kept.
    fn try_merge(
        &mut self,
        a: usize,
        b: usize,
        settings: &MergeSettings<'_>,
        skips: &mut Skips,
    ) -> Result<Option<usize>> {
        let (Some(first), Some(second)) = (self.landmarks.get(a), self.landmarks.get(b)) else {
            return Ok(None);
        };
        let (keep, drop) = if second.track.sightings > first.track.sightings {
            (b, a)
        } else {
            (a, b)
        };
        let (Some(mut kept), Some(dropped)) =
            (self.landmarks.get(keep).cloned(), self.landmarks.get(drop))
        else {
            return Ok(None);
        };
        // Tested on a copy: the shared map is copied on write only when the pair merges.
        if !kept.absorb(dropped, settings.tolerance, settings.gate, skips)? {
            return Ok(None);
        }
        self.landmarks.set(keep, Some(kept));
        self.landmarks.set(drop, None);
        Ok(Some(keep))
    }
}

/// A landmark update's state change and new covariance, kept by a worker so that the next
/// update writes into their storage.
#[derive(Debug, Default)]
pub(super) struct UpdateBuffers {
    dx: DVector<f64>,
    cov: DMatrix<f64>,
}

impl<P: RobotPose> Landmark<P> {
    /// The observation linearized at this feature from the sensor `frame` (the frame of the
    /// observation's sensor at the particle's pose, made once for all of its candidates),
    /// written into `spare`'s storage. `None` when the measurement cannot be linearized.
    pub(super) fn linearize(
        &self,
        observation: &Observation,
        frame: &SensorFrame,
        mut spare: OwnLinearization,
    ) -> Option<OwnLinearization> {
        linearize_own_at_into(
            observation.measurement.as_ref(),
            self.feature.as_ref(),
            &frame.to_sensor,
            &mut spare,
        )
        .ok()?;
        Some(spare)
    }

    /// `(ln N(eta; 0, S), eta^T S^-1 eta, dim eta)` of a measurement of this feature
    /// linearized as `lin`; `S = H P H^T + C_eta`, or `2 C_eta` for a tentative feature.
    /// `None` when `S` is not positive definite.
    pub(super) fn likelihood(&self, lin: &OwnLinearization) -> Option<(f64, f64, usize)> {
        let dof = lin.eta.len();
        if self.feature.mspace_dim() == 0 {
            if let Some(small) = small::log_likelihood(
                &lin.eta,
                &lin.cov_eta,
                &DMatrix::zeros(dof, 0),
                &DMatrix::zeros(0, 0),
            ) {
                return small.map(|(l, d2)| (l, d2, dof));
            }
        } else if let Some(small) =
            small::log_likelihood(&lin.eta, &lin.cov_eta, &lin.d_eta_d_own, &self.cov)
        {
            return small.map(|(l, d2)| (l, d2, dof));
        }
        let s = if self.feature.mspace_dim() == 0 {
            &lin.cov_eta * 2.0
        } else {
            &lin.d_eta_d_own * &self.cov * lin.d_eta_d_own.transpose() + &lin.cov_eta
        };
        let (l, d2) = log_normal(&lin.eta, &s)?;
        Some((l, d2, lin.eta.len()))
    }

    /// The feature's EKF update by one measurement from a known sensor pose (FastSLAM 1.0):
    /// `K = P H^T S^-1`, `dx_p = -K eta`, `x_f += B~ dx_p` (eq. 24), Joseph-form covariance.
    /// A step the feature refuses (it would turn a line around) is not applied.
    pub(super) fn update<Q: RobotPose>(
        &mut self,
        measurement: &dyn DynMeasurementModel,
        pose: &Q,
        robot_from_sensor: &Pose3,
        skips: &mut Skips,
    ) -> Result<()> {
        let n = self.feature.mspace_dim();
        if n == 0 || self.cov.shape() != (n, n) {
            return Ok(());
        }
        let lin = SensorFrame::new(pose, robot_from_sensor).and_then(|frame| {
            linearize_own_at(measurement, self.feature.as_ref(), &frame.to_sensor)
        });
        let Ok(lin) = lin else {
            skips.count("update: linearization failed");
            return Ok(());
        };
        self.update_linearized(&lin, skips);
        Ok(())
    }

    /// [`Landmark::update`] with the measurement already linearized at this feature (as it
    /// is now) from the sensor's pose. Returns whether the update was applied.
    pub(super) fn update_linearized(&mut self, lin: &OwnLinearization, skips: &mut Skips) -> bool {
        self.update_linearized_with(lin, skips, &mut UpdateBuffers::default())
    }

    /// [`Landmark::update_linearized`] through `buffers` (a worker's, reused): the new
    /// covariance is written there and swapped in, the old one's storage left for the next.
    pub(super) fn update_linearized_with(
        &mut self,
        lin: &OwnLinearization,
        skips: &mut Skips,
        buffers: &mut UpdateBuffers,
    ) -> bool {
        let n = self.feature.mspace_dim();
        if n == 0 || self.cov.shape() != (n, n) {
            return false;
        }
        if !self.ekf_step(lin, buffers) {
            skips.count("update: innovation covariance not positive definite");
            return false;
        }
        if !buffers.dx.iter().all(|v| v.is_finite()) {
            skips.count("update: non-finite state change");
            return false;
        }
        // A refused change leaves the feature as it was (the `Feature` contract, checked by
        // the conformance suite), so no copy is kept to fall back on.
        if self.feature.apply_perturbation(&buffers.dx).is_err() {
            skips.count("update: state change refused by the feature");
            return false;
        }
        std::mem::swap(&mut self.cov, &mut buffers.cov);
        true
    }

    /// Tests whether `other`, another confirmed feature of the same particle, is this same
    /// feature, and if so takes it in; returns whether it did. The EKF's test
    /// ([`crate::ekf`]'s duplicate merging) with the two independent given the particle's
    /// path: the coincidence residual `r` ([`Feature::coincidence`]) with
    /// `H_s = J_s B~_s`, `H_o = J_o B~_o` passes when
    /// `r^T (H_s P_s H_s^T + H_o P_o H_o^T + t^2 I)^-1 r <= gate`; this feature then takes
    /// `r = 0` as a measurement with noise `H_o P_o H_o^T + (1e-4 + t^2) I` (the marginal of
    /// the EKF's joint constraint), grows over the other's extent
    /// ([`Feature::absorbed`]) and adds its sightings. The caller removes `other`.
    pub(super) fn absorb(
        &mut self,
        other: &Landmark<P>,
        tolerance: f64,
        gate: &dyn Fn(usize) -> Result<f64>,
        skips: &mut Skips,
    ) -> Result<bool> {
        let Some(coincidence) = self.feature.coincidence(other.feature.as_ref())? else {
            return Ok(false);
        };
        let (own, others) = (self.feature.mspace_dim(), other.feature.mspace_dim());
        if own == 0 || others == 0 || self.cov.shape() != (own, own) {
            return Ok(false);
        }
        if other.cov.shape() != (others, others) {
            return Ok(false);
        }
        let h_self = &coincidence.d_self * self.feature.dual()?;
        let h_other = &coincidence.d_other * other.feature.dual()?;
        let m = coincidence.residual.len();
        let tolerance = DMatrix::identity(m, m) * tolerance.powi(2);
        let from_other = &h_other * &other.cov * h_other.transpose();
        let s = &h_self * &self.cov * h_self.transpose() + &from_other + &tolerance;
        let Some(s_inv) = s.try_inverse() else {
            skips.count("merge: singular difference covariance");
            return Ok(false);
        };
        let d2 = (coincidence.residual.transpose() * s_inv * &coincidence.residual)[(0, 0)];
        if d2.is_nan() || d2 > gate(m)? {
            return Ok(false);
        }
        let constraint = OwnLinearization {
            eta: coincidence.residual,
            cov_eta: from_other + tolerance + DMatrix::identity(m, m) * MERGE_CONSTRAINT_VARIANCE,
            d_eta_d_own: h_self,
        };
        if !self.update_linearized(&constraint, skips) {
            return Ok(false);
        }
        if let Some(extension) = self.feature.absorbed(other.feature.as_ref())? {
            self.apply_extension(extension, skips)?;
        }
        self.track.sightings += other.track.sightings;
        Ok(true)
    }

    /// `dx = -K eta` and the Joseph-form covariance `(I - K H) P (I - K H)^T + K C K^T`
    /// (symmetrized) for `K = P H^T S^-1`, `S = H P H^T + C`, written into `buffers`; on the
    /// stack for small sizes. `false` when `S` is not positive definite.
    fn ekf_step(&self, lin: &OwnLinearization, buffers: &mut UpdateBuffers) -> bool {
        let (h, p, c) = (&lin.d_eta_d_own, &self.cov, &lin.cov_eta);
        if let Some(small) =
            small::update_into(&lin.eta, c, h, p, &mut buffers.dx, &mut buffers.cov)
        {
            return small.is_some();
        }
        let ph_t = p * h.transpose();
        let Some(cholesky) = (h * &ph_t + c).cholesky() else {
            return false;
        };
        let k = cholesky.solve(&ph_t.transpose()).transpose();
        buffers.dx = -(&k * &lin.eta);
        let i_kh = DMatrix::identity(p.nrows(), p.nrows()) - &k * h;
        let cov = &i_kh * p * i_kh.transpose() + &k * c * k.transpose();
        buffers.cov = 0.5 * (&cov + cov.transpose());
        true
    }

    /// Grows the feature (the shared lifecycle rule) with block-diagonal priors for its new
    /// rows; after a growth by triangulation every earlier view, taken from the particle's
    /// own path, updates the new rows. Returns whether it grew.
    pub(super) fn grow(
        &mut self,
        observation: &Observation,
        settings: &LifecycleSettings,
        skips: &mut Skips,
    ) -> Result<bool> {
        let Some(grown) = grow(
            &mut self.track,
            &mut self.feature,
            observation.measurement.as_ref(),
            settings,
            skips,
        )?
        else {
            return Ok(false);
        };
        let (old_dim, added) = (grown.old_dim, grown.added);
        let new_dim = old_dim + added;
        let mut cov = DMatrix::zeros(new_dim, new_dim);
        if old_dim > 0 && self.cov.shape() == (old_dim, old_dim) {
            cov.view_mut((0, 0), (old_dim, old_dim))
                .copy_from(&self.cov);
        }
        cov.view_mut((old_dim, old_dim), (added, added))
            .copy_from(&grown.prior);
        self.cov = cov;
        if grown.triangulated {
            // The particle's path is known: each earlier view is a measurement from its pose.
            let views = std::mem::take(&mut self.track.views);
            if let Some((_, others)) = views.split_last() {
                for view in others {
                    self.update(
                        view.measurement.as_ref(),
                        &view.world_from_sensor,
                        &Pose3::identity(),
                        skips,
                    )?;
                }
            }
            self.track.views = views;
        }
        drop_views_when_grown(&mut self.track, self.feature.as_ref());
        Ok(true)
    }

    /// Applies the measurement's change outside the M-space (a wall's extent), with the map
    /// of the feature's rows that it implies ([`FeatureMap::set_coordinates_outside_mspace`]).
    pub(super) fn extend(
        &mut self,
        observation: &Observation,
        pose: &P,
        skips: &mut Skips,
    ) -> Result<()> {
        let Some(extension) = extension_of(
            self.feature.as_ref(),
            observation,
            &pose.world_from_sensor(&observation.robot_from_sensor),
            skips,
        ) else {
            return Ok(());
        };
        self.apply_extension(extension, skips)
    }

    /// Changes the feature's coordinates outside its M-space by `extension`, with the map
    /// of its rows that the change implies.
    fn apply_extension(&mut self, extension: Extension, skips: &mut Skips) -> Result<()> {
        let mut single = FeatureMap::new();
        let id = single.insert(slam_core::dyn_clone::clone_box(self.feature.as_ref()))?;
        let Ok(transform) =
            single.set_coordinates_outside_mspace(id, extension, OUTSIDE_MSPACE_TOLERANCE)
        else {
            skips.count("extension: refused (it would move the feature inside its M-space)");
            return Ok(());
        };
        if let Some(transform) = transform {
            let t = &transform.matrix;
            if t.shape() != self.cov.shape() {
                skips.count("extension: row map of the wrong size");
                return Ok(());
            }
            self.cov = t * &self.cov * t.transpose();
        }
        self.feature = single.remove(id)?;
        Ok(())
    }
}
