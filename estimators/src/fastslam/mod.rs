//! FastSLAM 1.0 (Montemerlo et al. 2002) over the M-space features: a Rao-Blackwellized
//! particle filter whose particles sample their poses from the motion model and keep their
//! own maps, where every feature carries a small EKF over its own M-space perturbation
//! `dx_p` (paper section V: the representation is orthogonal to the SLAM algorithm).
//!
//! Written against the slam-core traits only, with the EKF's lifecycle rules
//! (tentative features, growth of the M-space by revealed subspaces or triangulation,
//! extension outside the M-space, pruning) and association rules (known landmark ids, else
//! the Mahalanobis-gated nearest neighbour, **per particle**). Shared corners (section VI)
//! are not joined: each particle's features stay independent, as FastSLAM requires.
//!
//! - **Weights** (log space): each paired observation multiplies the particle's weight by
//!   `N(eta; 0, S)`, `S = H_f P_f H_f^T + C_eta` (`2 C_eta` against a tentative feature);
//!   an observation that starts a feature by the likelihood it would have on the
//!   new-feature gate, and an ambiguous (dropped) one by its best candidate's likelihood.
//! - **Resampling**: systematic (low-variance) when the effective sample size
//!   `1 / sum w_i^2` falls below `resample_threshold * N`.
//! - **Shared maps**: a particle's map is a persistent vector of features
//!   (`pvec::PVec`, a 16-ary trie of `Arc` nodes): resampling copies roots only (O(N)),
//!   and a particle copies a feature (and its O(log M) path) only when it changes it.
//! - **Proposal**: FastSLAM 1.0 (the motion model) by default; FastSLAM 2.0's improved
//!   proposal ([`Proposal::Improved`]) draws the pose conditioned on the step's observations.
//! - **Parallel and reproducible**: particles are processed with rayon; every particle draws
//!   from its own ChaCha stream derived from the seed, the step and its index, so the result
//!   does not depend on the number of threads.

pub(crate) mod pvec;

use std::collections::BTreeMap;
use std::sync::{Arc, OnceLock};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal, Uniform};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{
    DynMeasurementModel, Error, Estimator, Feature, FeatureId, FeatureMap, MapToSensor,
    MotionModel, Observation, Pose3, Result, RobotPose, RowOwner, UpdateReport, chi2_quantile,
    linearize,
};

use crate::ancestry::Ancestry;
use crate::lifecycle::{
    BoundingBox, growth_prior, placed_by_triangulation, ready_subspace, stack_priors,
};
use pvec::PVec;

/// Largest `|B (x_new - x_old)|` accepted for a change outside the M-space.
const OUTSIDE_MSPACE_TOLERANCE: f64 = 1e-6;

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
}

impl Default for FastSlamParams {
    fn default() -> Self {
        FastSlamParams {
            particles: 100,
            proposal: Proposal::Motion,
            seed: 1,
            resample_threshold: 0.5,
            gate_probability: 0.99,
            new_feature_probability: 0.9999,
            confirm_after: 3,
            tentative_lifetime: 15,
            new_row_variance: 1e4,
            max_views: 8,
            association_margin: 3.0,
        }
    }
}

impl FastSlamParams {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<()> {
        let probability = |p: f64| p > 0.0 && p < 1.0;
        let checks = [
            (self.particles >= 1, "particles >= 1"),
            (
                self.resample_threshold.is_finite()
                    && (0.0..=1.0).contains(&self.resample_threshold),
                "resample_threshold in [0, 1]",
            ),
            (
                probability(self.gate_probability),
                "gate_probability in (0, 1)",
            ),
            (
                probability(self.new_feature_probability)
                    && self.new_feature_probability >= self.gate_probability,
                "new_feature_probability in [gate_probability, 1)",
            ),
            (self.confirm_after >= 1, "confirm_after >= 1"),
            (self.tentative_lifetime >= 1, "tentative_lifetime >= 1"),
            (
                self.new_row_variance.is_finite() && self.new_row_variance > 0.0,
                "new_row_variance > 0",
            ),
            (self.max_views >= 2, "max_views >= 2"),
            (
                self.association_margin.is_finite() && self.association_margin >= 0.0,
                "association_margin >= 0",
            ),
        ];
        match checks.iter().find(|(ok, _)| !ok) {
            Some((_, what)) => Err(Error::InvalidArgument(format!(
                "FastSLAM parameters: {what}"
            ))),
            None => Ok(()),
        }
    }
}

/// An earlier measurement of a feature, kept for triangulation.
#[derive(Clone, Debug)]
struct View {
    world_from_sensor: Pose3,
    measurement: Arc<dyn DynMeasurementModel>,
}

/// One feature of one particle: the feature with the EKF over its own M-space rows, and the
/// lifecycle's bookkeeping.
#[derive(Clone, Debug)]
struct Landmark {
    feature: Box<dyn Feature>,
    /// Covariance of the own M-space perturbation (`mspace_dim` square).
    cov: DMatrix<f64>,
    sightings: usize,
    last_seen: usize,
    revealed: BTreeMap<&'static str, usize>,
    views: Vec<View>,
    landmark_id: Option<u64>,
}

/// One particle: a pose hypothesis and the map conditioned on its path.
#[derive(Clone, Debug)]
struct Particle<P> {
    pose: P,
    log_weight: f64,
    map: PVec<Landmark>,
    /// Known landmark ids to slots (copied on write: only when a new id appears).
    ids: Arc<BTreeMap<u64, usize>>,
    /// Slots of tentative features (few), for pruning.
    tentative: Vec<usize>,
    /// FastSLAM 2.0: the pose covariance accumulated by predictions since the pose was last
    /// drawn (the pose is their mean meanwhile).
    pending: Option<DMatrix<f64>>,
    /// Its pose at every step so far (shared with its ancestors').
    path: Ancestry<P>,
}

/// What a particle decided for one observation.
#[derive(Debug)]
enum Decision {
    /// Paired with the feature in this slot.
    Pair(usize),
    /// Starts a new feature.
    New,
    /// Dropped, with the log-likelihood of its best candidate (if any).
    Reject(Option<f64>),
}

/// Gates and the step's shared data, the same for every particle.
struct StepContext<'a> {
    params: &'a FastSlamParams,
    step: usize,
    /// `(pairing gate, new-feature gate)` by innovation dimension.
    gates: &'a BTreeMap<usize, (f64, f64)>,
    /// The measurements that triangulate, shared as views.
    shared: Vec<Option<Arc<dyn DynMeasurementModel>>>,
}

impl StepContext<'_> {
    fn gates(&self, dof: usize) -> Result<(f64, f64)> {
        match self.gates.get(&dof) {
            Some(&g) => Ok(g),
            None => Ok((
                chi2_quantile(self.params.gate_probability, dof)?,
                chi2_quantile(self.params.new_feature_probability, dof)?,
            )),
        }
    }
}

/// The best particle's map as a [`FeatureMap`], built on demand.
#[derive(Debug)]
struct Snapshot {
    map: FeatureMap,
    /// The particle slot of each feature id of `map`.
    slots: Vec<usize>,
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
    particles: Vec<Particle<P>>,
    gates: BTreeMap<usize, (f64, f64)>,
    /// Update steps so far.
    step: usize,
    /// Random draws so far (predictions and resamplings), to derive fresh streams.
    draws: u64,
    /// Index of the particle with the largest weight after the last update.
    best: usize,
    /// The weighted mean pose and its covariance.
    mean: (P, DMatrix<f64>),
    resamplings: usize,
    snapshot: OnceLock<Snapshot>,
}

/// A fresh random stream for `(seed, draw, index)`: independent of the thread that uses it.
pub(crate) fn stream(seed: u64, draw: u64, index: u64) -> ChaCha8Rng {
    let mut z = seed ^ draw.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    let mut rng = ChaCha8Rng::seed_from_u64(z ^ (z >> 31));
    rng.set_stream(index);
    rng
}

/// `ln N(eta; 0, s)`, `None` when `s` is not positive definite.
fn log_normal(eta: &DVector<f64>, s: &DMatrix<f64>) -> Option<(f64, f64)> {
    let cholesky = s.clone().cholesky()?;
    let solved = cholesky.solve(eta);
    let d2 = eta.dot(&solved);
    let log_det: f64 = 2.0
        * cholesky
            .l_dirty()
            .diagonal()
            .iter()
            .map(|v| v.ln())
            .sum::<f64>();
    let m = eta.len() as f64;
    let value = -0.5 * (d2 + log_det + m * (2.0 * std::f64::consts::PI).ln());
    value.is_finite().then_some((value, d2))
}

/// Systematic (low-variance) resampling: `n` indices drawn with probabilities `weights`
/// (normalized, summing to 1) from one uniform offset `u` in `[0, 1/n)`.
pub(crate) fn systematic_resample(weights: &[f64], u: f64) -> Vec<usize> {
    let n = weights.len();
    let mut out = Vec::with_capacity(n);
    let mut cumulative = weights.first().copied().unwrap_or(0.0);
    let mut i = 0;
    for k in 0..n {
        let target = u + k as f64 / n as f64;
        while target > cumulative && i + 1 < n {
            i += 1;
            cumulative += weights[i];
        }
        out.push(i);
    }
    out
}

/// Normalized weights from log weights (max subtracted first).
pub(crate) fn normalized(log_weights: &[f64]) -> Vec<f64> {
    let max = log_weights
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let raw: Vec<f64> = log_weights.iter().map(|l| (l - max).exp()).collect();
    let total: f64 = raw.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        let n = log_weights.len().max(1) as f64;
        return vec![1.0 / n; log_weights.len()];
    }
    raw.into_iter().map(|w| w / total).collect()
}

/// Weighted mean of particle poses (angles averaged as wrapped differences from the particle
/// `best`) and their weighted covariance.
pub(crate) fn weighted_mean<P: RobotPose>(
    poses: &[P],
    log_weights: &[f64],
    best: usize,
) -> (P, DMatrix<f64>) {
    let weights = normalized(log_weights);
    let reference = poses[best.min(poses.len() - 1)];
    let differences: Vec<DVector<f64>> = poses
        .iter()
        .map(|p| DVector::from_vec(pose_difference(p, &reference)))
        .collect();
    let mut mean = DVector::zeros(P::DIM);
    for (d, w) in differences.iter().zip(&weights) {
        mean += d * *w;
    }
    let mut cov = DMatrix::zeros(P::DIM, P::DIM);
    for (d, w) in differences.iter().zip(&weights) {
        let e = d - &mean;
        cov += &e * e.transpose() * *w;
    }
    let mut parameters = reference.parameters();
    for (p, d) in parameters.iter_mut().zip(mean.iter()) {
        *p += d;
    }
    let pose = P::from_parameters(&parameters).unwrap_or(reference);
    (pose, cov)
}

/// Every pose moved by its own draw of the increment from `N(x_d, C_d)` (the motion model as
/// the proposal), in parallel; the draw of pose `i` comes from `stream(seed, draw, i)`.
pub(crate) fn sample_motion<P: RobotPose>(
    poses: &[P],
    motion: &dyn MotionModel<P>,
    seed: u64,
    draw: u64,
) -> Result<Vec<P>> {
    let Some(first) = poses.first() else {
        return Ok(Vec::new());
    };
    let prediction = motion.predict(first)?;
    slam_core::ensure_finite(prediction.cov_control.as_slice(), "motion noise")?;
    let control = motion.control();
    let root = matrix_sqrt(&prediction.cov_control);
    if root.nrows() != control.len() {
        return Err(Error::DimensionMismatch {
            what: "motion noise".into(),
            expected: control.len(),
            got: root.nrows(),
        });
    }
    poses
        .par_iter()
        .enumerate()
        .map(|(index, pose)| {
            let mut rng = stream(seed, draw, index as u64);
            let z = DVector::from_fn(control.len(), |_, _| StandardNormal.sample(&mut rng));
            let sampled = &control + &root * z;
            motion.apply_control(pose, &sampled)
        })
        .collect()
}

/// Systematic resampling of `log_weights` when the effective sample size is below
/// `threshold * n`: the chosen parent of each new particle, or `None` (no resampling).
pub(crate) fn resample_indices(
    log_weights: &[f64],
    threshold: f64,
    seed: u64,
    draw: u64,
) -> Option<Vec<usize>> {
    let n = log_weights.len();
    let weights = normalized(log_weights);
    let ess = 1.0 / weights.iter().map(|w| w * w).sum::<f64>();
    if ess >= threshold * n as f64 {
        return None;
    }
    let mut rng = stream(seed, draw, u64::MAX);
    let u: f64 = Uniform::new(0.0, 1.0 / n as f64)
        .map(|d| d.sample(&mut rng))
        .unwrap_or(0.0);
    Some(systematic_resample(&weights, u))
}

/// `a - b` in pose parameters with angle differences wrapped.
fn pose_difference<P: RobotPose>(a: &P, b: &P) -> Vec<f64> {
    crate::ekf::pose_error(a, b)
}

impl<P: RobotPose> FastSlam<P> {
    /// A filter whose particles start at `pose`, spread by `pose_covariance` (`P::DIM`
    /// square; zero for a known start), with no features.
    pub fn new(pose: P, pose_covariance: DMatrix<f64>, params: FastSlamParams) -> Result<Self> {
        params.validate()?;
        if pose_covariance.shape() != (P::DIM, P::DIM) {
            return Err(Error::DimensionMismatch {
                what: "initial pose covariance".into(),
                expected: P::DIM,
                got: pose_covariance.nrows(),
            });
        }
        slam_core::ensure_finite(pose_covariance.as_slice(), "initial pose covariance")?;
        let root = matrix_sqrt(&pose_covariance);
        let mut particles = Vec::with_capacity(params.particles);
        for index in 0..params.particles {
            let mut rng = stream(params.seed, 0, index as u64);
            let z = DVector::from_fn(P::DIM, |_, _| StandardNormal.sample(&mut rng));
            let offset = &root * z;
            let mut parameters = pose.parameters();
            for (p, d) in parameters.iter_mut().zip(offset.iter()) {
                *p += d;
            }
            particles.push(Particle {
                pose: P::from_parameters(&parameters)?,
                log_weight: 0.0,
                map: PVec::default(),
                ids: Arc::new(BTreeMap::new()),
                tentative: Vec::new(),
                pending: None,
                path: Ancestry::default(),
            });
        }
        let mut gates = BTreeMap::new();
        for dof in 1..=8 {
            gates.insert(
                dof,
                (
                    chi2_quantile(params.gate_probability, dof)?,
                    chi2_quantile(params.new_feature_probability, dof)?,
                ),
            );
        }
        let mut filter = FastSlam {
            params,
            particles,
            gates,
            step: 0,
            draws: 1,
            best: 0,
            mean: (pose, DMatrix::zeros(P::DIM, P::DIM)),
            resamplings: 0,
            snapshot: OnceLock::new(),
        };
        filter.mean = filter.weighted_mean();
        Ok(filter)
    }

    /// The settings.
    pub fn params(&self) -> &FastSlamParams {
        &self.params
    }

    /// Number of particles.
    pub fn particle_count(&self) -> usize {
        self.particles.len()
    }

    /// Resamplings so far.
    pub fn resamplings(&self) -> usize {
        self.resamplings
    }

    /// Every particle's pose and normalized weight.
    pub fn particle_poses(&self) -> Vec<(P, f64)> {
        let weights = normalized(&self.log_weights());
        self.particles
            .iter()
            .zip(weights)
            .map(|(p, w)| (p.pose, w))
            .collect()
    }

    /// The effective sample size `1 / sum w_i^2` of the current weights.
    pub fn effective_sample_size(&self) -> f64 {
        let w = normalized(&self.log_weights());
        1.0 / w.iter().map(|w| w * w).sum::<f64>()
    }

    fn log_weights(&self) -> Vec<f64> {
        self.particles.iter().map(|p| p.log_weight).collect()
    }

    /// Weighted mean of the particle poses and their weighted covariance.
    fn weighted_mean(&self) -> (P, DMatrix<f64>) {
        let poses: Vec<P> = self.particles.iter().map(|p| p.pose).collect();
        weighted_mean(&poses, &self.log_weights(), self.best)
    }

    /// Resamples (systematic) when the effective sample size is below the threshold.
    fn maybe_resample(&mut self) {
        let Some(chosen) = resample_indices(
            &self.log_weights(),
            self.params.resample_threshold,
            self.params.seed,
            self.draws,
        ) else {
            return;
        };
        self.draws += 1;
        let best = self.best;
        // Copies share the parent's map: O(1) per particle.
        let resampled: Vec<Particle<P>> = chosen
            .iter()
            .map(|&i| Particle {
                log_weight: 0.0,
                ..self.particles[i].clone()
            })
            .collect();
        self.best = chosen.iter().position(|&i| i == best).unwrap_or(0);
        self.particles = resampled;
        self.resamplings += 1;
    }

    fn best_particle(&self) -> &Particle<P> {
        &self.particles[self.best.min(self.particles.len() - 1)]
    }

    fn snapshot(&self) -> &Snapshot {
        self.snapshot.get_or_init(|| {
            let mut map = FeatureMap::new();
            let mut slots = Vec::new();
            for (slot, landmark) in self.best_particle().map.iter() {
                if map
                    .insert(slam_core::dyn_clone::clone_box(landmark.feature.as_ref()))
                    .is_ok()
                {
                    slots.push(slot);
                }
            }
            Snapshot { map, slots }
        })
    }

    fn landmark_of(&self, id: FeatureId) -> Option<&Landmark> {
        let slot = *self.snapshot().slots.get(id.0)?;
        self.best_particle().map.get(slot)
    }
}

/// `A` with `A A^T = m` for a symmetric positive semi-definite `m` (negative eigenvalues
/// clipped).
pub(crate) fn matrix_sqrt(m: &DMatrix<f64>) -> DMatrix<f64> {
    let symmetric = 0.5 * (m + m.transpose());
    let eigen = symmetric.symmetric_eigen();
    let roots = eigen.eigenvalues.map(|v| v.max(0.0).sqrt());
    &eigen.eigenvectors * DMatrix::from_diagonal(&roots)
}

/// One observation in FastSLAM 2.0's proposal: its index, `H_r`, `eta` and `Q`.
type ProposalRow = (usize, DMatrix<f64>, DVector<f64>, DMatrix<f64>);

/// The per-particle work of one update step.
struct ParticleUpdate<'a, 'c, P: RobotPose> {
    context: &'c StepContext<'a>,
    particle: &'c mut Particle<P>,
    report: UpdateReport,
    log_likelihood: f64,
    /// Observations whose likelihood the proposal already counted.
    weighted: Vec<bool>,
    /// The particle's random stream for this step (FastSLAM 2.0).
    rng: ChaCha8Rng,
}

impl<P: RobotPose> ParticleUpdate<'_, '_, P> {
    /// FastSLAM 2.0: draws the pose from the motion prior conditioned on the observations of
    /// confirmed features paired in `decisions`, and counts their joint likelihood under the
    /// predicted pose. Without such observations the pose is drawn from the prior alone.
    fn propose(&mut self, observations: &[Observation], decisions: &[Decision]) -> Result<()> {
        let Some(prior) = self.particle.pending.take() else {
            return Ok(());
        };
        let d = P::DIM;
        let pose = self.particle.pose;
        // (observation, H_r, eta, Q) of each pairing with a confirmed feature.
        let mut rows: Vec<ProposalRow> = Vec::new();
        for (index, decision) in decisions.iter().enumerate() {
            let Decision::Pair(slot) = decision else {
                continue;
            };
            let Some(landmark) = self.particle.map.get(*slot) else {
                continue;
            };
            let n = landmark.feature.mspace_dim();
            if n == 0 || landmark.cov.shape() != (n, n) {
                continue;
            }
            let observation = &observations[index];
            let Ok(lin) = linearize(
                observation.measurement.as_ref(),
                landmark.feature.as_ref(),
                &pose,
                &observation.robot_from_sensor,
            ) else {
                continue;
            };
            let q = &lin.d_eta_d_own * &landmark.cov * lin.d_eta_d_own.transpose() + &lin.cov_eta;
            rows.push((index, lin.d_eta_d_robot, lin.eta, q));
        }
        let root;
        let mut mean = DVector::zeros(d);
        if rows.is_empty() {
            root = matrix_sqrt(&prior);
        } else {
            // Information form; the prior's information is regularized for a still robot.
            let regularized = &prior + DMatrix::identity(d, d) * 1e-12;
            let Some(mut information) = regularized.try_inverse() else {
                return Ok(());
            };
            let mut gradient = DVector::zeros(d);
            let m: usize = rows.iter().map(|r| r.2.len()).sum();
            let mut h = DMatrix::zeros(m, d);
            let mut eta = DVector::zeros(m);
            let mut q_all = DMatrix::zeros(m, m);
            let mut at = 0;
            for (_, h_r, e, q) in &rows {
                let Some(q_inv) = q.clone().try_inverse() else {
                    return Ok(());
                };
                information += h_r.transpose() * &q_inv * h_r;
                gradient += h_r.transpose() * &q_inv * e;
                let k = e.len();
                h.view_mut((at, 0), (k, d)).copy_from(h_r);
                eta.rows_mut(at, k).copy_from(e);
                q_all.view_mut((at, at), (k, k)).copy_from(q);
                at += k;
            }
            let Some(sigma) = information.try_inverse() else {
                return Ok(());
            };
            mean = -(&sigma * gradient);
            root = matrix_sqrt(&sigma);
            let s = &h * &prior * h.transpose() + q_all;
            if let Some((log_likelihood, _)) = log_normal(&eta, &s) {
                self.log_likelihood += log_likelihood;
                for (index, ..) in &rows {
                    self.weighted[*index] = true;
                }
            }
        }
        let z = DVector::from_fn(d, |_, _| StandardNormal.sample(&mut self.rng));
        let delta = mean + root * z;
        let mut parameters = pose.parameters();
        for (p, x) in parameters.iter_mut().zip(delta.iter()) {
            *p += x;
        }
        if let Ok(drawn) = P::from_parameters(&parameters) {
            self.particle.pose = drawn;
        }
        Ok(())
    }

    /// Decides every observation against the particle's map before changing it.
    fn associate(&self, observations: &[Observation]) -> Result<Vec<Decision>> {
        observations
            .iter()
            .map(|o| match o.landmark_id {
                Some(id) => Ok(match self.particle.ids.get(&id) {
                    Some(&slot) => Decision::Pair(slot),
                    None => Decision::New,
                }),
                None => self.nearest(o),
            })
            .collect()
    }

    /// The Mahalanobis-gated nearest neighbour of an observation without an id (the EKF's
    /// rule), per particle.
    fn nearest(&self, observation: &Observation) -> Result<Decision> {
        let measurement = observation.measurement.as_ref();
        let pose = self.particle.pose;
        let world_from_sensor = pose.world_from_sensor(&observation.robot_from_sensor);
        let near = measurement
            .initial_feature_dyn(&world_from_sensor)
            .ok()
            .flatten()
            .map(|f| BoundingBox::of(f.coordinates()));
        let to_sensor = MapToSensor::new(&world_from_sensor)?;
        let mut best: Option<(f64, usize, f64)> = None;
        let mut far_from_all = true;
        let mut best_likelihood: Option<f64> = None;
        for (slot, landmark) in self.particle.map.iter() {
            let feature = landmark.feature.as_ref();
            if !measurement.accepts(feature) {
                continue;
            }
            if let Some(near) = &near
                && !BoundingBox::of(feature.coordinates())
                    .near(near, self.context.params.association_margin)
            {
                continue;
            }
            let Ok(x_o) = to_sensor.transform(feature.coordinates()) else {
                continue;
            };
            if !measurement.plausible_dyn(feature, &x_o) {
                continue;
            }
            let Some((log_likelihood, d2, dof)) = likelihood(landmark, observation, &pose) else {
                continue;
            };
            let (gate, new_gate) = self.context.gates(dof)?;
            if d2 <= new_gate {
                far_from_all = false;
            }
            if best_likelihood.is_none_or(|b| log_likelihood > b) {
                best_likelihood = Some(log_likelihood);
            }
            if d2 <= gate && best.is_none_or(|(b, _, _)| d2 < b) {
                best = Some((d2, slot, log_likelihood));
            }
        }
        Ok(match best {
            Some((_, slot, _)) => Decision::Pair(slot),
            None if far_from_all => Decision::New,
            None => Decision::Reject(best_likelihood),
        })
    }

    fn run(&mut self, observations: &[Observation]) -> Result<()> {
        let decisions = self.associate(observations)?;
        if self.context.params.proposal == Proposal::Improved {
            self.propose(observations, &decisions)?;
        }
        for (index, decision) in decisions.into_iter().enumerate() {
            let observation = &observations[index];
            match decision {
                Decision::Pair(slot) => self.pair(slot, index, observation)?,
                Decision::New => self.start(index, observation)?,
                Decision::Reject(best) => {
                    self.report.rejected += 1;
                    if let Some(l) = best {
                        self.log_likelihood += l;
                    }
                }
            }
        }
        self.prune();
        Ok(())
    }

    /// Pairs an observation with the feature in `slot`: weight, EKF update, sighting,
    /// growth, extension.
    fn pair(&mut self, slot: usize, index: usize, observation: &Observation) -> Result<()> {
        let pose = self.particle.pose;
        let Some(landmark) = self.particle.map.get(slot) else {
            self.report.rejected += 1;
            return Ok(());
        };
        let Some((log_likelihood, d2, dof)) = likelihood(landmark, observation, &pose) else {
            self.report.rejected += 1;
            return Ok(());
        };
        let confirmed = landmark.feature.mspace_dim() > 0;
        if !self.weighted.get(index).copied().unwrap_or(false) {
            self.log_likelihood += log_likelihood;
        }
        self.report.associated += 1;
        if confirmed {
            self.report.nis.push((d2, dof));
        }
        let context = self.context;
        let Some(landmark) = self.particle.map.get_mut(slot) else {
            return Ok(());
        };
        // As in the EKF: sighting and growth first, then one update on the (new) rows.
        note_sighting(landmark, context, index, observation, &pose)?;
        let grown = grow(landmark, context, observation)?;
        if confirmed || grown {
            ekf_update(landmark, observation, &pose)?;
        }
        extend(landmark, observation, &pose)?;
        Ok(())
    }

    /// Starts a feature from an observation.
    fn start(&mut self, index: usize, observation: &Observation) -> Result<()> {
        let pose = self.particle.pose;
        let world_from_sensor = pose.world_from_sensor(&observation.robot_from_sensor);
        let Ok(Some(feature)) = observation
            .measurement
            .initial_feature_dyn(&world_from_sensor)
        else {
            self.report.rejected += 1;
            return Ok(());
        };
        let mut landmark = Landmark {
            feature,
            cov: DMatrix::zeros(0, 0),
            sightings: 0,
            last_seen: self.context.step,
            revealed: BTreeMap::new(),
            views: Vec::new(),
            landmark_id: observation.landmark_id,
        };
        // The likelihood this observation would have on the new-feature gate of a feature
        // placed by it (`S = 2 C_eta`): what starting a feature is worth against pairing.
        if let Ok(lin) = linearize(
            observation.measurement.as_ref(),
            landmark.feature.as_ref(),
            &pose,
            &observation.robot_from_sensor,
        ) {
            let dof = lin.eta.len();
            let s = &lin.cov_eta * 2.0;
            if let Some((at_zero, _)) = log_normal(&DVector::zeros(dof), &s) {
                let (_, new_gate) = self.context.gates(dof)?;
                self.log_likelihood += at_zero - 0.5 * new_gate;
            }
        }
        note_sighting(&mut landmark, self.context, index, observation, &pose)?;
        if grow(&mut landmark, self.context, observation)? {
            ekf_update(&mut landmark, observation, &pose)?;
        }
        let tentative = landmark.feature.mspace_dim() == 0;
        let id = landmark.landmark_id;
        let slot = self.particle.map.push(landmark);
        if tentative {
            self.particle.tentative.push(slot);
        }
        if let Some(id) = id {
            Arc::make_mut(&mut self.particle.ids).insert(id, slot);
        }
        self.report.new_features += 1;
        Ok(())
    }

    /// Drops tentative features not seen for `tentative_lifetime` steps.
    fn prune(&mut self) {
        let step = self.context.step;
        let lifetime = self.context.params.tentative_lifetime;
        let particle = &mut *self.particle;
        let mut keep = Vec::with_capacity(particle.tentative.len());
        for &slot in &particle.tentative {
            let Some(landmark) = particle.map.get(slot) else {
                continue;
            };
            if landmark.feature.mspace_dim() > 0 {
                continue;
            }
            if step.saturating_sub(landmark.last_seen) > lifetime {
                if let Some(id) = landmark.landmark_id {
                    Arc::make_mut(&mut particle.ids).remove(&id);
                }
                particle.map.set(slot, None);
            } else {
                keep.push(slot);
            }
        }
        particle.tentative = keep;
    }
}

/// `(ln N(eta; 0, S), eta^T S^-1 eta, dim eta)` of an observation of `landmark` from `pose`;
/// `S = H P H^T + C_eta`, or `2 C_eta` for a tentative feature.
fn likelihood<P: RobotPose>(
    landmark: &Landmark,
    observation: &Observation,
    pose: &P,
) -> Option<(f64, f64, usize)> {
    let lin = linearize(
        observation.measurement.as_ref(),
        landmark.feature.as_ref(),
        pose,
        &observation.robot_from_sensor,
    )
    .ok()?;
    let s = if landmark.feature.mspace_dim() == 0 {
        &lin.cov_eta * 2.0
    } else {
        &lin.d_eta_d_own * &landmark.cov * lin.d_eta_d_own.transpose() + &lin.cov_eta
    };
    let (l, d2) = log_normal(&lin.eta, &s)?;
    Some((l, d2, lin.eta.len()))
}

/// The feature's EKF update by one measurement from a known sensor pose (FastSLAM 1.0):
/// `K = P H^T S^-1`, `dx_p = -K eta`, `x_f += B~ dx_p` (eq. 24), Joseph-form covariance.
/// A step the feature refuses (it would turn a line around) is not applied.
fn ekf_update<P: RobotPose>(
    landmark: &mut Landmark,
    observation: &Observation,
    pose: &P,
) -> Result<()> {
    update_from(
        landmark,
        observation.measurement.as_ref(),
        pose,
        &observation.robot_from_sensor,
    )
}

fn update_from<P: RobotPose>(
    landmark: &mut Landmark,
    measurement: &dyn DynMeasurementModel,
    pose: &P,
    robot_from_sensor: &Pose3,
) -> Result<()> {
    let n = landmark.feature.mspace_dim();
    if n == 0 || landmark.cov.shape() != (n, n) {
        return Ok(());
    }
    let Ok(lin) = linearize(
        measurement,
        landmark.feature.as_ref(),
        pose,
        robot_from_sensor,
    ) else {
        return Ok(());
    };
    let h = &lin.d_eta_d_own;
    let ph_t = &landmark.cov * h.transpose();
    let s = h * &ph_t + &lin.cov_eta;
    let Some(cholesky) = s.cholesky() else {
        return Ok(());
    };
    let k = cholesky.solve(&ph_t.transpose()).transpose();
    let dx = -(&k * &lin.eta);
    if !dx.iter().all(|v| v.is_finite()) {
        return Ok(());
    }
    let mut candidate = slam_core::dyn_clone::clone_box(landmark.feature.as_ref());
    if candidate.apply_perturbation(&dx).is_err() {
        return Ok(());
    }
    let i_kh = DMatrix::identity(n, n) - &k * h;
    let cov = &i_kh * &landmark.cov * i_kh.transpose() + &k * &lin.cov_eta * k.transpose();
    landmark.cov = 0.5 * (&cov + cov.transpose());
    landmark.feature = candidate;
    Ok(())
}

/// Counts a sighting (the subspaces it reveals) and keeps a view while the feature can
/// still grow by triangulation.
fn note_sighting<P: RobotPose>(
    landmark: &mut Landmark,
    context: &StepContext<'_>,
    index: usize,
    observation: &Observation,
    pose: &P,
) -> Result<()> {
    let world_from_sensor = pose.world_from_sensor(&observation.robot_from_sensor);
    let x_o = MapToSensor::new(&world_from_sensor)?.transform(landmark.feature.coordinates())?;
    let revealed = observation
        .measurement
        .revealed_subspaces_dyn(landmark.feature.as_ref(), &x_o)
        .unwrap_or_default();
    landmark.sightings += 1;
    landmark.last_seen = context.step;
    for name in revealed {
        *landmark.revealed.entry(name).or_default() += 1;
    }
    let shared = context.shared.get(index).cloned().flatten();
    match shared {
        Some(measurement) if !landmark.feature.growth_options().is_empty() => {
            if landmark.views.len() >= context.params.max_views {
                // Keep the first view (the widest baseline so far) and the most recent ones.
                landmark.views.remove(1);
            }
            landmark.views.push(View {
                world_from_sensor,
                measurement,
            });
        }
        _ => landmark.views.clear(),
    }
    Ok(())
}

/// Grows the feature by every subspace revealed often enough (the EKF's rule), or by
/// triangulation from its views, which then update the new rows. Returns whether it grew.
fn grow(
    landmark: &mut Landmark,
    context: &StepContext<'_>,
    observation: &Observation,
) -> Result<bool> {
    let threshold = if landmark.landmark_id.is_some() {
        1
    } else {
        context.params.confirm_after
    };
    let variance = context.params.new_row_variance;
    let old_dim = landmark.feature.mspace_dim();
    let mut priors = Vec::new();
    loop {
        let options = landmark.feature.growth_options();
        let Some(subspace) = ready_subspace(&options, &landmark.revealed, threshold) else {
            break;
        };
        landmark.revealed.remove(subspace.name);
        let growth = landmark.feature.activate(subspace.name)?;
        priors.push(growth_prior(landmark.feature.as_ref(), &growth, variance));
    }
    let mut triangulated = false;
    if landmark.feature.mspace_dim() == old_dim
        && observation.measurement.triangulates_dyn()
        && let Some((current, others)) = landmark.views.split_last()
    {
        let other_views: Vec<_> = others
            .iter()
            .map(|v| (v.world_from_sensor, v.measurement.as_ref()))
            .collect();
        if let Some(grown) = placed_by_triangulation(
            landmark.feature.as_ref(),
            observation.measurement.as_ref(),
            &current.world_from_sensor,
            &other_views,
        )? {
            let added = grown.mspace_dim() - old_dim;
            landmark.feature = grown;
            priors.push(DMatrix::identity(added, added) * variance);
            triangulated = true;
        }
    }
    let new_dim = landmark.feature.mspace_dim();
    if new_dim == old_dim {
        return Ok(false);
    }
    let added = new_dim - old_dim;
    let block = stack_priors(&priors, added)?;
    let mut cov = DMatrix::zeros(new_dim, new_dim);
    if old_dim > 0 && landmark.cov.shape() == (old_dim, old_dim) {
        cov.view_mut((0, 0), (old_dim, old_dim))
            .copy_from(&landmark.cov);
    }
    cov.view_mut((old_dim, old_dim), (added, added))
        .copy_from(&block);
    landmark.cov = cov;
    if triangulated {
        // The particle's path is known: each earlier view is a measurement from its pose.
        let views = std::mem::take(&mut landmark.views);
        if let Some((_, others)) = views.split_last() {
            for view in others {
                update_from(
                    landmark,
                    view.measurement.as_ref(),
                    &view.world_from_sensor,
                    &Pose3::identity(),
                )?;
            }
        }
        landmark.views = views;
    }
    if landmark.feature.growth_options().is_empty() {
        landmark.views.clear();
    }
    Ok(true)
}

/// Applies the measurement's change outside the M-space (a wall's extent), with the map of
/// the feature's rows that it implies ([`FeatureMap::set_coordinates_outside_mspace`]).
fn extend<P: RobotPose>(
    landmark: &mut Landmark,
    observation: &Observation,
    pose: &P,
) -> Result<()> {
    let world_from_sensor = pose.world_from_sensor(&observation.robot_from_sensor);
    let Ok(Some(extension)) = observation
        .measurement
        .extend_dyn(landmark.feature.as_ref(), &world_from_sensor)
    else {
        return Ok(());
    };
    let mut single = FeatureMap::new();
    let id = single.insert(slam_core::dyn_clone::clone_box(landmark.feature.as_ref()))?;
    // A change the check refuses (it would move the feature inside its M-space) is not
    // applied.
    let Ok(transform) =
        single.set_coordinates_outside_mspace(id, extension, OUTSIDE_MSPACE_TOLERANCE)
    else {
        return Ok(());
    };
    if let Some(transform) = transform {
        let t = &transform.matrix;
        if t.shape() != landmark.cov.shape() {
            return Ok(());
        }
        landmark.cov = t * &landmark.cov * t.transpose();
    }
    landmark.feature = single.remove(id)?;
    Ok(())
}

impl<P: RobotPose> Estimator<P> for FastSlam<P> {
    fn name(&self) -> &'static str {
        "fastslam"
    }

    /// Every particle draws its increment from `N(x_d, C_d)` and moves by it (FastSLAM 1.0's
    /// proposal: the motion model).
    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        if self.params.proposal == Proposal::Improved {
            // The mean moves; the covariance waits for the next observations (eqs. 26).
            let predicted: Vec<Result<(P, DMatrix<f64>)>> = self
                .particles
                .par_iter()
                .map(|particle| {
                    let prediction = motion.predict(&particle.pose)?;
                    let prior = particle
                        .pending
                        .clone()
                        .unwrap_or_else(|| DMatrix::zeros(P::DIM, P::DIM));
                    Ok((prediction.pose, prediction.propagate_covariance(&prior)?))
                })
                .collect();
            for (particle, result) in self.particles.iter_mut().zip(predicted) {
                let (pose, cov) = result?;
                slam_core::ensure_finite(cov.as_slice(), "motion noise")?;
                particle.pose = pose;
                particle.pending = Some(cov);
            }
            self.mean = self.weighted_mean();
            return Ok(());
        }
        let (seed, draw) = (self.params.seed, self.draws);
        self.draws += 1;
        let poses: Vec<P> = self.particles.iter().map(|p| p.pose).collect();
        let poses = sample_motion(&poses, motion, seed, draw)?;
        for (particle, pose) in self.particles.iter_mut().zip(poses) {
            particle.pose = pose;
        }
        self.mean = self.weighted_mean();
        Ok(())
    }

    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        self.step += 1;
        let context = StepContext {
            params: &self.params,
            step: self.step,
            gates: &self.gates,
            shared: observations
                .iter()
                .map(|o| {
                    o.measurement
                        .triangulates_dyn()
                        .then(|| Arc::from(o.measurement.clone_box()))
                })
                .collect(),
        };
        let (seed, draw) = (self.params.seed, self.draws);
        self.draws += 1;
        let results: Vec<Result<(f64, UpdateReport)>> = self
            .particles
            .par_iter_mut()
            .enumerate()
            .map(|(index, particle)| {
                let mut work = ParticleUpdate {
                    context: &context,
                    particle,
                    report: UpdateReport::default(),
                    log_likelihood: 0.0,
                    weighted: vec![false; observations.len()],
                    rng: stream(seed, draw, index as u64),
                };
                work.run(observations)?;
                Ok((work.log_likelihood, work.report))
            })
            .collect();
        let mut reports = Vec::with_capacity(results.len());
        for (particle, result) in self.particles.iter_mut().zip(results) {
            let (log_likelihood, report) = result?;
            particle.log_weight += log_likelihood;
            reports.push(report);
        }
        // Keep the log weights near zero (they only matter relative to each other).
        self.best = crate::fastslam::normalize_log_weights(
            self.particles
                .iter_mut()
                .map(|p| &mut p.log_weight)
                .collect(),
        );
        let report = reports.swap_remove(self.best);
        self.mean = self.weighted_mean();
        self.maybe_resample();
        self.snapshot = OnceLock::new();
        Ok(report)
    }

    /// The weighted mean of the particle poses.
    fn pose(&self) -> P {
        self.mean.0
    }

    /// The weighted covariance of the particle poses.
    fn pose_covariance(&self) -> DMatrix<f64> {
        self.mean.1.clone()
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
        self.landmark_of(id).and_then(|l| l.landmark_id)
    }

    fn end_step(&mut self) {
        for particle in &mut self.particles {
            particle.path.push(particle.pose);
        }
    }

    /// The path of the particle with the largest weight (whose map [`map`](Estimator::map)
    /// returns).
    fn map_path(&self) -> Option<Vec<P>> {
        Some(self.best_particle().path.to_vec())
    }
}

#[cfg(test)]
mod tests;

/// Shifts log weights so that the largest is zero (they only matter relative to each other)
/// and returns the index of the largest (the first one on ties).
pub(crate) fn normalize_log_weights(mut log_weights: Vec<&mut f64>) -> usize {
    let max = log_weights
        .iter()
        .map(|w| **w)
        .fold(f64::NEG_INFINITY, f64::max);
    if max.is_finite() {
        for w in &mut log_weights {
            **w -= max;
        }
    }
    log_weights
        .iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |(bi, bw), (i, w)| {
            if **w > bw { (i, **w) } else { (bi, bw) }
        })
        .0
}
