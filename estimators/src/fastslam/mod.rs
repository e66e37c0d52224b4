//! FastSLAM 1.0 (Montemerlo et al. 2002) over the M-space features: a Rao-Blackwellized
//! particle filter whose particles sample their poses from the motion model and keep their
//! own maps, where every feature carries a small EKF over its own M-space perturbation
//! `dx_p` (paper section V: the representation is orthogonal to the SLAM algorithm).
//!
//! Written against the slam-core traits only, with the shared lifecycle
//! ([`crate::lifecycle`]: tentative features, growth of the M-space by revealed subspaces or
//! triangulation, extension outside the M-space, pruning) and the shared association
//! ([`crate::association`]: known landmark ids, else gated nearest neighbour or JCBB, **per
//! particle**). Shared corners (section VI) are not joined: each particle's features stay
//! independent, as FastSLAM requires. Duplicates in a particle's map (a wall mapped twice
//! after drift) are merged in the map the filter reports (`merge_duplicates`, on by
//! default), by the EKF's test on the pair's coincidence residual with the two features
//! independent given the particle's path; the particles' own maps are left as they are.
//!
//! - **Weights** (log space): each paired observation multiplies the particle's weight by
//!   `N(eta; 0, S)`, `S = H_f P_f H_f^T + C_eta` (`2 C_eta` against a tentative feature);
//!   an observation that starts a feature by the likelihood it would have on the
//!   new-feature gate, and an ambiguous (dropped) one by its best candidate's likelihood.
//! - **Resampling**: systematic (low-variance) when the effective sample size
//!   `1 / sum w_i^2` falls below `resample_threshold * N` (the shared particle machinery).
//! - **Shared maps**: a particle's map is a persistent vector of features (a 16-ary trie of
//!   `Arc` nodes): resampling copies roots only (O(N)), and a particle copies a feature (and
//!   its O(log M) path) only when it changes it.
//! - **Proposal**: FastSLAM 1.0 (the motion model) by default; FastSLAM 2.0's improved
//!   proposal ([`Proposal::Improved`]) draws the pose conditioned on the step's observations.
//! - **Parallel and reproducible**: particles are processed with rayon; every particle draws
//!   from its own ChaCha stream derived from the seed, the step and its index, so the result
//!   does not depend on the number of threads.

mod landmark;
mod proposal;
mod small;
mod step;

use std::sync::OnceLock;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use slam_core::nalgebra::DMatrix;
use slam_core::{
    Estimator, FeatureId, FeatureMap, MotionModel, Observation, Result, RobotPose, RowOwner, Skips,
    UpdateReport,
};

use crate::association::{Association, AssociationSettings, Gates};
use crate::lifecycle::{LifecycleSettings, first_failure};
use crate::particles::{ParticleSet, stream};
use landmark::{Landmark, LandmarkMap, MergeSettings};
use step::{ParticleStep, StepContext, Workspace};

/// How particles draw their poses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Proposal {
    /// FastSLAM 1.0: from the motion model alone.
    #[default]
    Motion,
    /// FastSLAM 2.0 (Montemerlo et al. 2003): from the motion model conditioned on the
    /// step's observations of confirmed features, `N(mu, Sigma)` with
    /// `Sigma^-1 = C_motion^-1 + sum H_r^T Q^-1 H_r` and `Q = H_f P_f H_f^T + C_eta`;
    /// the weight is the observations' likelihood under the predicted pose,
    /// `N(eta; 0, H_r C_motion H_r^T + Q)`.
    Improved,
}

/// Settings of [`FastSlam`]; `Default` gives the values used on the built-in world.
///
/// ```
/// use slam_estimators::FastSlamParams;
/// let params = FastSlamParams { particles: 30, ..Default::default() };
/// assert!(params.validate().is_ok());
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FastSlamParams {
    /// Number of particles.
    pub particles: usize,
    /// FastSLAM 1.0 (`"motion"`) or 2.0 (`"improved"`).
    pub proposal: Proposal,
    /// Seed of the particles' random streams.
    pub seed: u64,
    /// Resample when the effective sample size falls below this fraction of the particles.
    pub resample_threshold: f64,
    /// Association rule of each particle for observations without landmark ids.
    pub association: Association,
    /// Probability of the chi-square gate an innovation must pass to pair (as the EKF's).
    pub gate_probability: f64,
    /// An unmatched observation starts a new feature only outside this gate of every
    /// feature of the particle (as the EKF's).
    pub new_feature_probability: f64,
    /// Sightings of a subspace (including the first) before it is activated.
    pub confirm_after: usize,
    /// Update steps a tentative feature survives without a sighting.
    pub tentative_lifetime: usize,
    /// Prior variance of new M-space rows in directions the revealing observation does not
    /// determine.
    pub new_row_variance: f64,
    /// Views kept per growing feature for triangulation.
    pub max_views: usize,
    /// Candidate features of an observation are those whose bounding box lies within this
    /// distance of the feature the observation would start, m.
    pub association_margin: f64,
    /// Node limit of each particle's JCBB search (`association = "jcbb"`).
    pub jcbb_max_nodes: usize,
    /// An unmatched observation does not start a feature that would overlap an existing
    /// one of its kind within this distance, m (0: off): it would double that feature.
    pub new_feature_clearance: f64,
    /// Merge the duplicates of the map the filter reports (the best particle's, as
    /// [`Estimator::map`] gives it): each confirmed feature is tested against the confirmed
    /// features of its kind that overlap it within `merge_distance`, by the EKF's rule
    /// ([`crate::EkfParams::merge_duplicates`]) with the two features independent given the
    /// particle's path, and a pair that is one feature becomes one. The particles' own maps
    /// are left as they are: merging inside the filter cleaned the maps but made the paths
    /// worse on real logs (a merged wall moves between the two without the particle's pose
    /// following; BENCHMARKS.md). On by default; the path does not depend on it.
    pub merge_duplicates: bool,
    /// Probability of the chi-square gate on the pair's coincidence residual.
    pub merge_probability: f64,
    /// Features farther apart than this are not tested, m.
    pub merge_distance: f64,
    /// Model error allowed on top of the pair's covariance (standard deviation, in the
    /// residual's units: m for a wall's offset). A particle's features are known given its
    /// path, so their covariances leave out the path's error: a wall placed twice a few
    /// centimetres apart by a pose error fails the test without this. Default 0.05 m (on the
    /// built-in world 74 walls become 29 with it and 73 without).
    pub merge_tolerance: f64,
}

impl Default for FastSlamParams {
    fn default() -> Self {
        FastSlamParams {
            particles: 100,
            proposal: Proposal::Motion,
            seed: 1,
            resample_threshold: 0.5,
            association: Association::NearestNeighbour,
            gate_probability: 0.99,
            new_feature_probability: 0.9999,
            confirm_after: 3,
            tentative_lifetime: 15,
            new_row_variance: 1e4,
            max_views: 8,
            association_margin: 3.0,
            jcbb_max_nodes: 20_000,
            new_feature_clearance: 0.0,
            merge_duplicates: true,
            merge_probability: 0.99,
            merge_distance: 0.5,
            merge_tolerance: 0.05,
        }
    }
}

impl FastSlamParams {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<()> {
        let mut checks = vec![
            (self.particles >= 1, "particles >= 1"),
            (
                self.particles <= crate::particles::MAX_PARTICLES,
                "particles <= 100000 (a resource limit: each particle keeps a map and a path)",
            ),
            (
                self.resample_threshold.is_finite()
                    && (0.0..=1.0).contains(&self.resample_threshold),
                "resample_threshold in [0, 1]",
            ),
        ];
        checks.extend([
            (
                self.merge_probability > 0.0 && self.merge_probability < 1.0,
                "merge_probability in (0, 1)",
            ),
            (
                self.merge_distance.is_finite() && self.merge_distance >= 0.0,
                "merge_distance >= 0",
            ),
            (
                self.merge_tolerance.is_finite() && self.merge_tolerance >= 0.0,
                "merge_tolerance >= 0",
            ),
        ]);
        checks.extend(self.association_settings().checks());
        checks.extend(self.lifecycle_settings().checks());
        first_failure("FastSLAM", &checks)
    }

    /// The association settings.
    pub fn association_settings(&self) -> AssociationSettings {
        AssociationSettings {
            rule: self.association,
            gate_probability: self.gate_probability,
            new_feature_probability: self.new_feature_probability,
            margin: self.association_margin,
            jcbb_max_nodes: self.jcbb_max_nodes,
            new_feature_clearance: self.new_feature_clearance,
        }
    }

    /// The lifecycle settings.
    pub fn lifecycle_settings(&self) -> LifecycleSettings {
        LifecycleSettings {
            confirm_after: self.confirm_after,
            tentative_lifetime: self.tentative_lifetime,
            new_row_variance: self.new_row_variance,
            max_views: self.max_views,
        }
    }
}

/// The best particle's map as a [`FeatureMap`], built on demand.
#[derive(Debug)]
struct Snapshot<P> {
    map: FeatureMap,
    /// The particle slot of each feature id of `map`.
    slots: Vec<usize>,
    /// The best particle's map with its duplicates merged (`merge_duplicates`); `None`:
    /// the particle's own.
    merged: Option<LandmarkMap<P>>,
    /// What the merge left out (pairs it could not test), reported with the next step.
    skipped: Skips,
}

/// FastSLAM 1.0 over robot poses of type `P` (see the module documentation).
///
/// ```
/// use slam_core::{Estimator, Pose2, nalgebra::DMatrix};
/// use slam_estimators::{FastSlam, FastSlamParams};
/// let filter = FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), FastSlamParams::default()).unwrap();
/// assert_eq!(filter.name(), "fastslam");
/// assert_eq!(filter.particle_count(), 100);
/// ```
#[derive(Debug)]
pub struct FastSlam<P: RobotPose> {
    params: FastSlamParams,
    set: ParticleSet<P, LandmarkMap<P>>,
    gates: Gates,
    /// Update steps so far.
    step: usize,
    snapshot: OnceLock<Snapshot<P>>,
}

impl<P: RobotPose> FastSlam<P> {
    /// A filter whose particles start at `pose`, spread by `pose_covariance` (`P::DIM`
    /// square; zero for a known start), with no features.
    pub fn new(pose: P, pose_covariance: DMatrix<f64>, params: FastSlamParams) -> Result<Self> {
        params.validate()?;
        let set = ParticleSet::new(pose, &pose_covariance, params.particles, params.seed)?;
        let gates = Gates::new(&[
            params.gate_probability,
            params.new_feature_probability,
            params.merge_probability,
        ])?;
        Ok(FastSlam {
            params,
            set,
            gates,
            step: 0,
            snapshot: OnceLock::new(),
        })
    }

    /// The settings.
    pub fn params(&self) -> &FastSlamParams {
        &self.params
    }

    /// Number of particles.
    pub fn particle_count(&self) -> usize {
        self.set.particles.len()
    }

    /// Resamplings so far.
    pub fn resamplings(&self) -> usize {
        self.set.resamplings
    }

    /// Every particle's pose and normalized weight.
    pub fn particle_poses(&self) -> Vec<(P, f64)> {
        self.set.poses_and_weights()
    }

    /// The effective sample size `1 / sum w_i^2` of the current weights.
    pub fn effective_sample_size(&self) -> f64 {
        self.set.effective_sample_size()
    }

    fn snapshot(&self) -> &Snapshot<P> {
        self.snapshot.get_or_init(|| {
            let mut skipped = Skips::default();
            let merged = self.params.merge_duplicates.then(|| {
                let mut merged = self.set.best_particle().map.clone();
                let gates = &self.gates;
                let probability = self.params.merge_probability;
                let settings = MergeSettings {
                    distance: self.params.merge_distance,
                    tolerance: self.params.merge_tolerance,
                    gate: &|dof| gates.gate(probability, dof),
                };
                merged.merge_duplicates(&settings, &mut skipped);
                merged
            });
            let landmarks = match &merged {
                Some(merged) => &merged.landmarks,
                None => &self.set.best_particle().map.landmarks,
            };
            let mut map = FeatureMap::new();
            let mut slots = Vec::new();
            for (slot, landmark) in landmarks.iter() {
                if map
                    .insert(slam_core::dyn_clone::clone_box(landmark.feature.as_ref()))
                    .is_ok()
                {
                    slots.push(slot);
                }
            }
            Snapshot {
                map,
                slots,
                merged,
                skipped,
            }
        })
    }

    fn landmark_of(&self, id: FeatureId) -> Option<&Landmark<P>> {
        let snapshot = self.snapshot();
        let slot = *snapshot.slots.get(id.0)?;
        match &snapshot.merged {
            Some(merged) => merged.landmarks.get(slot),
            None => self.set.best_particle().map.landmarks.get(slot),
        }
    }

    /// FastSLAM 2.0's prediction: each particle's mean moves, and the covariance waits for
    /// the next observations (eq. 26).
    fn predict_pending(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        let predicted: Vec<Result<(P, DMatrix<f64>)>> = self
            .set
            .particles
            .par_iter()
            .map(|particle| {
                let prediction = motion.predict(&particle.pose)?;
                let prior = particle
                    .map
                    .pending
                    .clone()
                    .unwrap_or_else(|| DMatrix::zeros(P::DIM, P::DIM));
                Ok((prediction.pose, prediction.propagate_covariance(&prior)?))
            })
            .collect();
        for (particle, result) in self.set.particles.iter_mut().zip(predicted) {
            let (pose, cov) = result?;
            slam_core::ensure_finite(cov.as_slice(), "motion noise")?;
            particle.pose = pose;
            particle.map.pending = Some(cov);
        }
        self.set.update_mean();
        Ok(())
    }
}

impl<P: RobotPose> Estimator<P> for FastSlam<P> {
    fn name(&self) -> &'static str {
        "fastslam"
    }

    /// Every particle draws its increment from `N(x_d, C_d)` and moves by it (FastSLAM 1.0's
    /// proposal: the motion model); FastSLAM 2.0 draws at the next update instead.
    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        match self.params.proposal {
            Proposal::Improved => self.predict_pending(motion),
            Proposal::Motion => self.set.sample_motion(motion),
        }
    }

    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        self.step += 1;
        let context = StepContext::new(&self.params, self.step, &self.gates, observations);
        let (seed, draw) = (self.set.seed(), self.set.next_draw());
        let results: Vec<Result<(f64, UpdateReport)>> = self
            .set
            .particles
            .par_iter_mut()
            .enumerate()
            .map_init(Workspace::default, |workspace, (index, particle)| {
                let rng = stream(seed, draw, index as u64);
                let mut work =
                    ParticleStep::new(&context, particle, rng, std::mem::take(workspace));
                work.run(observations)?;
                let (log_likelihood, report, kept) = work.finish();
                *workspace = kept;
                Ok((log_likelihood, report))
            })
            .collect();
        let mut reports = Vec::with_capacity(results.len());
        let mut likelihoods = Vec::with_capacity(results.len());
        for result in results {
            let (log_likelihood, report) = result?;
            likelihoods.push(log_likelihood);
            reports.push(report);
        }
        self.set.weigh(likelihoods);
        let mut report = reports.swap_remove(self.set.best);
        self.set.update_mean();
        self.set.resample(self.params.resample_threshold);
        if let Some(snapshot) = self.snapshot.take() {
            report.skipped.merge(&snapshot.skipped);
        }
        Ok(report)
    }

    /// The weighted mean of the particle poses.
    fn pose(&self) -> P {
        self.set.mean.0
    }

    /// The weighted covariance of the particle poses.
    fn pose_covariance(&self) -> DMatrix<f64> {
        self.set.mean.1.clone()
    }

    fn covariance_source(&self) -> &'static str {
        "particle cloud"
    }

    /// The map of the particle with the largest weight.
    fn map(&self) -> &FeatureMap {
        &self.snapshot().map
    }

    fn row_covariance(&self, owner: RowOwner) -> Option<DMatrix<f64>> {
        match owner {
            RowOwner::Feature(id) => self
                .landmark_of(id)
                .filter(|l| l.feature.mspace_dim() > 0)
                .map(|l| l.cov.clone()),
            RowOwner::Shared(_) => None,
        }
    }

    fn landmark_id(&self, id: FeatureId) -> Option<u64> {
        self.landmark_of(id).and_then(|l| l.track.landmark_id)
    }

    fn end_step(&mut self) {
        self.set.end_step();
    }

    /// The path of the particle with the largest weight (whose map [`map`](Estimator::map)
    /// returns).
    fn map_path(&self) -> Option<Vec<P>> {
        Some(self.set.best_particle().path.to_vec())
    }
}

#[cfg(test)]
mod tests;
