//! Particle machinery shared by [`crate::FastSlam`] and [`crate::Ipslam`]: particles with
//! log weights, maps and paths; seeded per-particle random streams; sampling from the motion
//! model; weighted mean; systematic resampling when the effective sample size is low.
//!
//! Every particle draws from its own ChaCha stream derived from the seed, the draw number and
//! its index ([`stream`]), so results do not depend on the number of threads.

mod ancestry;
pub(crate) mod pvec;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal, Uniform};
use rayon::prelude::*;
use slam_core::nalgebra::allocator::Allocator;
use slam_core::nalgebra::{DMatrix, DVector, DefaultAllocator, Dim, OMatrix, OVector};
use slam_core::{Error, MotionModel, Result, RobotPose, assign_vector};

pub(crate) use ancestry::Ancestry;

/// The most particles a filter may have (a resource limit, checked before anything is
/// allocated).
pub const MAX_PARTICLES: usize = 100_000;

/// One particle: a pose hypothesis, its weight, the map conditioned on its path, and the path.
#[derive(Clone, Debug)]
pub(crate) struct Particle<P, M> {
    pub pose: P,
    pub log_weight: f64,
    pub map: M,
    /// Its pose at every step so far (shared with its ancestors').
    pub path: Ancestry<P>,
}

/// The particles of a filter with their shared bookkeeping.
#[derive(Debug)]
pub(crate) struct ParticleSet<P, M> {
    pub particles: Vec<Particle<P, M>>,
    seed: u64,
    /// Random draws so far (predictions, updates and resamplings), to derive fresh streams.
    draws: u64,
    /// Index of the particle with the largest weight after the last weighting.
    pub best: usize,
    /// The weighted mean pose and its covariance.
    pub mean: (P, DMatrix<f64>),
    /// Resamplings so far.
    pub resamplings: usize,
}

impl<P: RobotPose, M: Clone + Default + Send> ParticleSet<P, M> {
    /// `count` particles at `pose` spread by `pose_covariance` (`P::DIM` square; zero for a
    /// known start), with empty maps.
    pub(crate) fn new(
        pose: P,
        pose_covariance: &DMatrix<f64>,
        count: usize,
        seed: u64,
    ) -> Result<Self> {
        if pose_covariance.shape() != (P::DIM, P::DIM) {
            return Err(Error::DimensionMismatch {
                what: "initial pose covariance".into(),
                expected: P::DIM,
                got: pose_covariance.nrows(),
            });
        }
        slam_core::ensure_finite(pose_covariance.as_slice(), "initial pose covariance")?;
        if count > MAX_PARTICLES {
            return Err(Error::InvalidArgument(format!(
                "{count} particles is above the limit of {MAX_PARTICLES}"
            )));
        }
        let root = matrix_sqrt(pose_covariance);
        let mut particles = Vec::with_capacity(count);
        for index in 0..count {
            let mut rng = stream(seed, 0, index as u64);
            let z = DVector::from_fn(P::DIM, |_, _| StandardNormal.sample(&mut rng));
            let offset = &root * z;
            particles.push(Particle {
                pose: pose.oplus(offset.as_slice())?,
                log_weight: 0.0,
                map: M::default(),
                path: Ancestry::default(),
            });
        }
        let mut set = ParticleSet {
            particles,
            seed,
            draws: 1,
            best: 0,
            mean: (pose, DMatrix::zeros(P::DIM, P::DIM)),
            resamplings: 0,
        };
        set.update_mean();
        Ok(set)
    }

    /// The seed of the particles' streams.
    pub(crate) fn seed(&self) -> u64 {
        self.seed
    }

    /// A fresh draw number for [`stream`].
    pub(crate) fn next_draw(&mut self) -> u64 {
        let draw = self.draws;
        self.draws += 1;
        draw
    }

    /// The particles' log weights.
    pub(crate) fn log_weights(&self) -> Vec<f64> {
        self.particles.iter().map(|p| p.log_weight).collect()
    }

    /// Recomputes the weighted mean pose and covariance.
    pub(crate) fn update_mean(&mut self) {
        let poses: Vec<P> = self.particles.iter().map(|p| p.pose).collect();
        self.mean = weighted_mean(&poses, &self.log_weights(), self.best);
    }

    /// Every particle draws its increment from `N(x_d, C_d)` and moves by it (the motion
    /// model as the proposal).
    pub(crate) fn sample_motion(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        let draw = self.next_draw();
        let poses: Vec<P> = self.particles.iter().map(|p| p.pose).collect();
        let poses = sample_motion(&poses, motion, self.seed, draw)?;
        for (particle, pose) in self.particles.iter_mut().zip(poses) {
            particle.pose = pose;
        }
        self.update_mean();
        Ok(())
    }

    /// Multiplies each particle's weight by its likelihood (`log_likelihoods` in particle
    /// order), keeps the log weights near zero and finds the best particle.
    pub(crate) fn weigh(&mut self, log_likelihoods: impl IntoIterator<Item = f64>) {
        for (particle, l) in self.particles.iter_mut().zip(log_likelihoods) {
            particle.log_weight += l;
        }
        self.best = normalize_log_weights(
            self.particles
                .iter_mut()
                .map(|p| &mut p.log_weight)
                .collect(),
        );
    }

    /// Resamples (systematic) when the effective sample size is below `threshold` times the
    /// particle count; resampled particles share their parents' maps and paths.
    pub(crate) fn resample(&mut self, threshold: f64) -> bool {
        let Some(chosen) = resample_indices(&self.log_weights(), threshold, self.seed, self.draws)
        else {
            return false;
        };
        self.draws += 1;
        let best = self.best;
        let resampled = chosen
            .iter()
            .map(|&i| Particle {
                log_weight: 0.0,
                ..self.particles[i].clone()
            })
            .collect();
        // What only the old generation held (maps, paths) is freed on every thread.
        std::mem::replace(&mut self.particles, resampled)
            .into_par_iter()
            .for_each(drop);
        self.best = chosen.iter().position(|&i| i == best).unwrap_or(0);
        self.resamplings += 1;
        true
    }

    /// The particle with the largest weight.
    pub(crate) fn best_particle(&self) -> &Particle<P, M> {
        &self.particles[self.best.min(self.particles.len() - 1)]
    }

    /// Appends each particle's pose to its path (once per recorded step).
    pub(crate) fn end_step(&mut self) {
        self.particles
            .par_iter_mut()
            .for_each(|particle| particle.path.push(particle.pose));
    }

    /// Every particle's pose and normalized weight.
    pub(crate) fn poses_and_weights(&self) -> Vec<(P, f64)> {
        let weights = normalized(&self.log_weights());
        self.particles
            .iter()
            .zip(weights)
            .map(|(p, w)| (p.pose, w))
            .collect()
    }

    /// The effective sample size `1 / sum w_i^2` of the current weights.
    pub(crate) fn effective_sample_size(&self) -> f64 {
        let w = normalized(&self.log_weights());
        1.0 / w.iter().map(|w| w * w).sum::<f64>()
    }
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

/// `ln N(eta; 0, s)` and `eta^T s^-1 eta`, `None` when `s` is not positive definite; for
/// dynamic and stack matrices alike.
pub(crate) fn log_normal<D: Dim>(
    eta: &OVector<f64, D>,
    s: &OMatrix<f64, D, D>,
) -> Option<(f64, f64)>
where
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
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

/// Weighted mean of particle poses (angles averaged as wrapped differences from the particle
/// `best`) and their weighted covariance.
pub(crate) fn weighted_mean<P: RobotPose>(
    poses: &[P],
    log_weights: &[f64],
    best: usize,
) -> (P, DMatrix<f64>) {
    let weights = normalized(log_weights);
    let reference = poses[best.min(poses.len() - 1)];
    let dim = P::DIM;
    // The differences from the reference, one row of `dim` each, in one buffer.
    let mut differences = Vec::with_capacity(poses.len() * dim);
    for p in poses {
        p.ominus_into(&reference, &mut differences);
    }
    let mut mean = vec![0.0; dim];
    for (d, w) in differences.chunks_exact(dim).zip(&weights) {
        for (m, d) in mean.iter_mut().zip(d) {
            *m += d * w;
        }
    }
    let mut cov = DMatrix::zeros(dim, dim);
    let mut e = vec![0.0; dim];
    for (d, w) in differences.chunks_exact(dim).zip(&weights) {
        for ((e, d), m) in e.iter_mut().zip(d).zip(&mean) {
            *e = d - m;
        }
        for j in 0..dim {
            for i in 0..dim {
                cov[(i, j)] += e[i] * e[j] * w;
            }
        }
    }
    let pose = reference.oplus(&mean).unwrap_or(reference);
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
    // Collected by index first (one buffer; a parallel collect into `Result<Vec>` builds a
    // list of pieces), the first error in particle order then reported.
    let sampled: Vec<Result<P>> = poses
        .par_iter()
        .enumerate()
        .map_init(
            || DVector::zeros(0),
            |sampled, (index, pose)| {
                let mut rng = stream(seed, draw, index as u64);
                draw_control(&control, &root, &mut rng, sampled);
                motion.apply_control(pose, sampled)
            },
        )
        .collect();
    sampled.into_iter().collect()
}

/// `control + root z` for `z` drawn from `N(0, I)` by `rng`, written into `sampled` (its
/// storage reused: a worker keeps one for all its particles): the products summed column
/// by column, as nalgebra's matrix-vector product does, so the numbers are those of
/// `&control + &root * z`.
fn draw_control(
    control: &DVector<f64>,
    root: &DMatrix<f64>,
    rng: &mut ChaCha8Rng,
    sampled: &mut DVector<f64>,
) {
    const STACK: usize = 8;
    let n = control.len();
    if n > STACK || root.shape() != (n, n) {
        let z = DVector::from_fn(n, |_, _| StandardNormal.sample(&mut *rng));
        *sampled = control + root * z;
        return;
    }
    let mut z = [0.0f64; STACK];
    for value in z.iter_mut().take(n) {
        *value = StandardNormal.sample(&mut *rng);
    }
    assign_vector(sampled, control.as_slice());
    for (i, value) in sampled.iter_mut().enumerate() {
        let mut product = root[(i, 0)] * z[0];
        for (j, z_j) in z.iter().enumerate().take(n).skip(1) {
            product += root[(i, j)] * z_j;
        }
        *value += product;
    }
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

/// `A` with `A A^T = m` for a symmetric positive semi-definite `m` (negative eigenvalues
/// clipped).
pub(crate) fn matrix_sqrt(m: &DMatrix<f64>) -> DMatrix<f64> {
    let symmetric = 0.5 * (m + m.transpose());
    let eigen = symmetric.symmetric_eigen();
    let roots = eigen.eigenvalues.map(|v| v.max(0.0).sqrt());
    &eigen.eigenvectors * DMatrix::from_diagonal(&roots)
}
