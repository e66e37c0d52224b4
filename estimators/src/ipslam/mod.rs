//! IPSLAM (Brunskill & Roy, "SLAM using Incremental Probabilistic PCA and Dimensionality
//! Reduction", ICRA 2005): particles carrying maps of 1-D PPCA line clusters (Table I).
//!
//! Per processed scan, the points are clustered once by G-means with 1-D PPCA
//! ([`ppca::gmeans`]; the clustering is invariant to the rigid transform that places the scan
//! in a particle's map frame, so it is shared by all particles), then for every particle:
//! 1. the clusters and points are placed by the particle's pose;
//! 2. the weight is multiplied by `prod_j max_c p(z_j | c)` under `N(mu, W W^T + s^2 I)`
//!    (eq. 18), in log space, each point's likelihood floored at the outlier threshold;
//! 3. new clusters correspond to old ones whose principal directions are within 60 degrees
//!    and whose centres are within the sum of the two principal variances (and, an addition,
//!    within `max_normal_distance` of the old cluster's line; and, another addition, also when
//!    their segments overlap or come within `max_normal_distance`: with the paper's rule
//!    alone short clusters of one wall never merge), matched greedily by centre distance;
//!    matched pairs merge by incremental PCA (eqs. 15-16) unless the merged cluster would be
//!    thick (non-principal deviation above `new_cluster_max_sigma`);
//! 4. unmatched new clusters with enough points and a small non-principal variance join the
//!    map; unmatched old ones stay.
//!
//! Then the particles are resampled (systematic) when the effective sample size is below the
//! threshold (the paper resamples at every step: threshold 1). The particles sample their
//! poses from the motion model as in [`crate::FastSlam`] (or, with
//! [`IpslamProposal::ScanMatch`], from the match of the scan to their own clusters), and share
//! their cluster maps after resampling (persistent vectors).
//!
//! Deviations from the paper, each a setting: weights use the map **before** the merge
//! (Table I scores the merged map, which has absorbed the points it scores); G-means tests the
//! residuals **across** the principal direction (the 1-D PPCA noise term, Gaussian for a wall),
//! since the projection along a wall is uniform and would split every wall into short pieces,
//! and also splits a cluster thicker than `new_cluster_max_sigma` (the residuals of a
//! scattered group can look normal: on the Intel log most scans kept groups 0.3-1 m thick);
//! scans are processed after `min_travel` / `min_turn_deg` of motion.
//!
//! The map's features are made by a factory the caller gives (a PPCA line feature type
//! lives outside this crate, which knows no feature type).

mod matching;
pub mod ppca;

use std::sync::{Arc, OnceLock};

use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Matrix3, Vector2, Vector3};
use slam_core::{
    Error, Estimator, Feature, FeatureMap, MotionModel, Observation, Pose3, Result, RobotPose,
    RowOwner, UpdateReport,
};

use crate::ancestry::Ancestry;
use crate::fastslam::pvec::PVec;
use crate::fastslam::{resample_indices, sample_motion, weighted_mean};
pub use ppca::{Cluster, GMeansParams};

/// Makes the map feature of a cluster (a PPCA line behind the slam-core traits).
pub type ClusterFeatureFactory = Arc<dyn Fn(&Cluster) -> Result<Box<dyn Feature>> + Send + Sync>;

/// How IPSLAM's particles draw their poses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IpslamProposal {
    /// From the motion model alone (the paper, eq. 17).
    #[default]
    Motion,
    /// Scan matching (an addition, in the manner of grid-based particle filters, Grisetti et
    /// al. 2007): each particle follows the motion model's mean; at a processed scan its pose
    /// moves to the nearest minimum of the robust point-to-line distances of the scan to its
    /// own clusters plus the motion model's Gaussian prior (accumulated since the last
    /// processed scan), and is drawn from the Gaussian of that minimum (inverse of the
    /// Gauss-Newton information). Where too few points match, it is drawn from the prior.
    /// The weight stays eq. 18 at the drawn pose.
    ScanMatch,
}

/// Settings of [`Ipslam`]; `Default` gives the paper's values where it states them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpslamParams {
    /// Number of particles (the paper: 201).
    pub particles: usize,
    /// Seed of the particles' random streams.
    pub seed: u64,
    /// Resample when the effective sample size is below this fraction (1: every step).
    pub resample_threshold: f64,
    /// G-means: `A*^2` above which a cluster is split (the paper: 1.035).
    pub critical_value: f64,
    /// G-means: smallest cluster, points.
    pub min_points: usize,
    /// Outlier threshold: likelihood under the best cluster (the paper: 0.01).
    pub outlier_likelihood: f64,
    /// Largest number of clusters per scan.
    pub max_clusters_per_scan: usize,
    /// Largest angle between principal directions of corresponding clusters, degrees (60).
    pub match_angle_deg: f64,
    /// Largest distance of a new cluster's centre from an old cluster's line for them to
    /// correspond, m (an addition: parallel walls never merge).
    pub max_normal_distance: f64,
    /// A new cluster joins the map with at least this many points.
    pub new_cluster_min_points: usize,
    /// ... and a non-principal standard deviation at most this, m.
    pub new_cluster_max_sigma: f64,
    /// Points farther than this from the sensor are not used, m.
    pub max_range: f64,
    /// A scan is processed once the robot has moved this far since the last one, m.
    pub min_travel: f64,
    /// ... or turned this much, degrees.
    pub min_turn_deg: f64,
    /// The log-likelihood of a scan is multiplied by this (1: the paper's eq. 18). Scan points
    /// are not independent given the map; values below 1 temper the weights, as in grid-based
    /// particle filters, so that resampling keeps more of the particles.
    pub likelihood_scale: f64,
    /// The motion model (`"motion"`, the paper) or scan matching (`"scan-match"`).
    pub proposal: IpslamProposal,
    /// Scan matching: a point matches a cluster within this distance of its line, m.
    pub match_gate: f64,
    /// Scan matching: deviation of a point from its cluster's line, m.
    pub match_point_sigma: f64,
}

impl Default for IpslamParams {
    fn default() -> Self {
        IpslamParams {
            particles: 201,
            seed: 1,
            resample_threshold: 1.0,
            critical_value: 1.035,
            min_points: 8,
            outlier_likelihood: 0.01,
            max_clusters_per_scan: 60,
            match_angle_deg: 60.0,
            max_normal_distance: 0.3,
            new_cluster_min_points: 10,
            new_cluster_max_sigma: 0.05,
            max_range: 20.0,
            min_travel: 0.3,
            min_turn_deg: 10.0,
            likelihood_scale: 1.0,
            proposal: IpslamProposal::Motion,
            match_gate: 0.3,
            match_point_sigma: 0.05,
        }
    }
}

impl IpslamParams {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<()> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let checks = [
            (self.particles >= 1, "particles >= 1"),
            (
                self.resample_threshold.is_finite()
                    && (0.0..=1.0).contains(&self.resample_threshold),
                "resample_threshold in [0, 1]",
            ),
            (positive(self.critical_value), "critical_value > 0"),
            (self.min_points >= 3, "min_points >= 3"),
            (
                self.outlier_likelihood.is_finite() && self.outlier_likelihood >= 0.0,
                "outlier_likelihood >= 0",
            ),
            (
                self.max_clusters_per_scan >= 1,
                "max_clusters_per_scan >= 1",
            ),
            (
                positive(self.match_angle_deg) && self.match_angle_deg <= 90.0,
                "match_angle_deg in (0, 90]",
            ),
            (
                positive(self.max_normal_distance),
                "max_normal_distance > 0",
            ),
            (
                self.new_cluster_min_points >= 3,
                "new_cluster_min_points >= 3",
            ),
            (
                positive(self.new_cluster_max_sigma),
                "new_cluster_max_sigma > 0",
            ),
            (positive(self.max_range), "max_range > 0"),
            (
                self.min_travel.is_finite() && self.min_travel >= 0.0,
                "min_travel >= 0",
            ),
            (
                self.min_turn_deg.is_finite() && self.min_turn_deg >= 0.0,
                "min_turn_deg >= 0",
            ),
            (positive(self.likelihood_scale), "likelihood_scale > 0"),
            (positive(self.match_gate), "match_gate > 0"),
            (positive(self.match_point_sigma), "match_point_sigma > 0"),
        ];
        match checks.iter().find(|(ok, _)| !ok) {
            Some((_, what)) => Err(Error::InvalidArgument(format!("IPSLAM parameters: {what}"))),
            None => Ok(()),
        }
    }

    fn matching(&self) -> matching::MatchSettings {
        matching::MatchSettings {
            gate: self.match_gate,
            end_margin: self.match_gate,
            point_sigma: self.match_point_sigma,
            iterations: 10,
            min_matched: self.new_cluster_min_points.max(20),
        }
    }

    fn gmeans(&self) -> GMeansParams {
        GMeansParams {
            critical_value: self.critical_value,
            min_points: self.min_points,
            outlier_likelihood: self.outlier_likelihood,
            max_clusters: self.max_clusters_per_scan,
            max_sigma: self.new_cluster_max_sigma,
        }
    }
}

#[derive(Clone, Debug)]
struct Particle<P> {
    pose: P,
    log_weight: f64,
    map: PVec<Cluster>,
    /// Its pose at every step so far (shared with its ancestors').
    path: Ancestry<P>,
}

/// IPSLAM over robot poses of type `P` (see the module documentation).
pub struct Ipslam<P: RobotPose> {
    params: IpslamParams,
    particles: Vec<Particle<P>>,
    factory: ClusterFeatureFactory,
    draws: u64,
    best: usize,
    mean: (P, DMatrix<f64>),
    /// The mean pose at the last processed scan.
    last_processed: Option<P>,
    /// The `scan-match` proposal: the motion model's covariance accumulated since the last
    /// processed scan (eq. 26 without the prior term), at the mean pose.
    motion_covariance: DMatrix<f64>,
    scans_processed: usize,
    snapshot: OnceLock<FeatureMap>,
}

impl<P: RobotPose> std::fmt::Debug for Ipslam<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ipslam")
            .field("params", &self.params)
            .field("particles", &self.particles.len())
            .field("scans_processed", &self.scans_processed)
            .finish_non_exhaustive()
    }
}

use matching::planar;

impl<P: RobotPose> Ipslam<P> {
    /// A filter whose particles all start at `pose` (the pose covariance spreads them as in
    /// [`crate::FastSlam::new`]), with empty maps; `factory` makes the map features.
    pub fn new(
        pose: P,
        pose_covariance: DMatrix<f64>,
        params: IpslamParams,
        factory: ClusterFeatureFactory,
    ) -> Result<Self> {
        params.validate()?;
        // The initial spread: FastSLAM's construction, reused.
        let seeded = crate::FastSlam::new(
            pose,
            pose_covariance,
            crate::FastSlamParams {
                particles: params.particles,
                seed: params.seed,
                ..Default::default()
            },
        )?;
        let particles = seeded
            .particle_poses()
            .into_iter()
            .map(|(pose, _)| Particle {
                pose,
                log_weight: 0.0,
                map: PVec::default(),
                path: Ancestry::default(),
            })
            .collect();
        let mut filter = Ipslam {
            params,
            particles,
            factory,
            draws: 1,
            best: 0,
            mean: (pose, DMatrix::zeros(P::DIM, P::DIM)),
            last_processed: None,
            motion_covariance: DMatrix::zeros(P::DIM, P::DIM),
            scans_processed: 0,
            snapshot: OnceLock::new(),
        };
        filter.mean = filter.weighted_mean();
        Ok(filter)
    }

    /// Scans processed so far.
    pub fn scans_processed(&self) -> usize {
        self.scans_processed
    }

    /// The clusters of the particle with the largest weight.
    pub fn clusters(&self) -> Vec<Cluster> {
        self.particles[self.best]
            .map
            .iter()
            .map(|(_, c)| *c)
            .collect()
    }

    /// The information of the `scan-match` prior on the sensor's `(x, y, heading)`: the
    /// accumulated motion covariance's position and heading variances (the sensor's lever arm
    /// neglected), floored at 1 cm and 0.2 degrees.
    fn matching_prior(&self) -> Vector3<f64> {
        let c = &self.motion_covariance;
        let heading = if P::DIM == 3 { 2 } else { 3 };
        let position = (0.5 * (c[(0, 0)] + c[(1, 1)])).max(1e-4);
        let heading = c[(heading, heading)].max(0.2f64.to_radians().powi(2));
        Vector3::new(1.0 / position, 1.0 / position, 1.0 / heading)
    }

    fn weighted_mean(&self) -> (P, DMatrix<f64>) {
        let poses: Vec<P> = self.particles.iter().map(|p| p.pose).collect();
        let weights: Vec<f64> = self.particles.iter().map(|p| p.log_weight).collect();
        weighted_mean(&poses, &weights, self.best)
    }

    /// Whether the robot moved enough since the last processed scan.
    fn moved_enough(&self) -> bool {
        let Some(last) = &self.last_processed else {
            return true;
        };
        let d = crate::ekf::pose_error(&self.mean.0, last);
        let (translation, rotation) = if P::DIM == 3 {
            ((d[0] * d[0] + d[1] * d[1]).sqrt(), d[2].abs())
        } else {
            (
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(),
                d[3..].iter().fold(0.0f64, |a, b| a.max(b.abs())),
            )
        };
        translation >= self.params.min_travel || rotation >= self.params.min_turn_deg.to_radians()
    }
}

/// What one particle did with one scan.
#[derive(Default)]
struct ParticleStep {
    log_likelihood: f64,
    merged: usize,
    added: usize,
}

/// The `scan-match` proposal for one particle: the match of the scan to its own clusters
/// under the prior `N(pose, diag(1 / prior_information))`, then a draw from the Gaussian of
/// the match (from the prior where too few points match).
fn match_to_own_map<P: RobotPose>(
    particle: &mut Particle<P>,
    params: &IpslamParams,
    robot_from_sensor: &Pose3,
    points: &[Vector2<f64>],
    prior_information: &Vector3<f64>,
    rng: &mut impl rand::Rng,
) {
    let start = planar(&particle.pose.world_from_sensor(robot_from_sensor));
    let settings = params.matching();
    let clusters = matching::reachable(
        particle.map.iter().map(|(_, k)| k),
        &start.1,
        params.max_range + settings.gate + settings.end_margin,
    );
    let (centre, information) =
        match matching::refine(&clusters, points, start, prior_information, &settings) {
            Some(m) => ((m.heading, m.translation), m.information),
            None => (start, Matrix3::from_diagonal(prior_information)),
        };
    // x = L^-T z has the covariance (L L^T)^-1.
    let Some(cholesky) = information.cholesky() else {
        return;
    };
    let z = Vector3::from_fn(|_, _| -> f64 { StandardNormal.sample(rng) });
    let Some(offset) = cholesky.l().transpose().solve_upper_triangular(&z) else {
        return;
    };
    let heading = centre.0 + offset.z;
    let translation = centre.1 + offset.xy();
    if let Some(moved) =
        matching::move_sensor_to(&particle.pose, robot_from_sensor, heading, &translation)
    {
        particle.pose = moved;
    }
}

/// Steps 1-4 of the module documentation for one particle.
fn process<P: RobotPose>(
    particle: &mut Particle<P>,
    params: &IpslamParams,
    robot_from_sensor: &Pose3,
    scan_clusters: &[(Cluster, Vec<Vector2<f64>>)],
    points: &[Vector2<f64>],
) -> ParticleStep {
    let (heading, translation) = planar(&particle.pose.world_from_sensor(robot_from_sensor));
    let (s, c) = heading.sin_cos();
    let place = |p: &Vector2<f64>| Vector2::new(c * p.x - s * p.y, s * p.x + c * p.y) + translation;
    let mut step = ParticleStep::default();
    // Old clusters that the scan can reach.
    let nearby: Vec<(usize, Cluster)> = particle
        .map
        .iter()
        .filter(|(_, k)| {
            (k.mean - translation).norm() <= params.max_range + 3.0 * k.principal_variance.sqrt()
        })
        .map(|(slot, k)| (slot, *k))
        .collect();
    // Eq. 18 against the map before this scan; each point floored at the outlier threshold.
    let floor = params.outlier_likelihood.max(1e-300).ln();
    for p in points {
        let z = place(p);
        let best = nearby
            .iter()
            .map(|(_, k)| k.log_likelihood(&z))
            .fold(f64::NEG_INFINITY, f64::max);
        step.log_likelihood += best.max(floor);
    }
    // Correspondence (section III-D), greedy by centre distance.
    let placed: Vec<(Cluster, Vec<Vector2<f64>>)> = scan_clusters
        .iter()
        .map(|(k, members)| {
            (
                k.transformed(heading, &translation),
                members.iter().map(place).collect(),
            )
        })
        .collect();
    let cos_limit = params.match_angle_deg.to_radians().cos();
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (j, (new, _)) in placed.iter().enumerate() {
        for (i, (_, old)) in nearby.iter().enumerate() {
            if old.direction.dot(&new.direction).abs() < cos_limit {
                continue;
            }
            let offset = new.mean - old.mean;
            let distance = offset.norm();
            let normal = Vector2::new(-old.direction.y, old.direction.x);
            // The paper's rule (centres within the sum of the principal variances), or,
            // an addition, segments that overlap or touch (half-lengths sqrt(3 lambda)).
            let extents = (3.0 * old.principal_variance).sqrt()
                + (3.0 * new.principal_variance).sqrt()
                + params.max_normal_distance;
            let reach = (old.principal_variance + new.principal_variance).max(extents);
            if distance <= reach && offset.dot(&normal).abs() <= params.max_normal_distance {
                pairs.push((distance, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut old_used = vec![false; nearby.len()];
    let mut new_used = vec![false; placed.len()];
    for (_, i, j) in pairs {
        if old_used[i] || new_used[j] {
            continue;
        }
        let (slot, old) = nearby[i];
        let (new, members) = &placed[j];
        let merged = ppca::merge(&old, new, members);
        // A merge that makes a thick cluster (two walls at a corner) is refused.
        if merged.sigma2.sqrt() > params.new_cluster_max_sigma {
            continue;
        }
        old_used[i] = true;
        new_used[j] = true;
        particle.map.set(slot, Some(merged));
        step.merged += 1;
    }
    for (j, (new, _)) in placed.into_iter().enumerate() {
        if !new_used[j]
            && new.count >= params.new_cluster_min_points
            && new.sigma2.sqrt() <= params.new_cluster_max_sigma
        {
            particle.map.push(new);
            step.added += 1;
        }
    }
    step
}

impl<P: RobotPose> Estimator<P> for Ipslam<P> {
    fn name(&self) -> &'static str {
        "ipslam"
    }

    /// Every particle draws its increment from the motion model (eq. 17); with the
    /// `scan-match` proposal it takes the mean increment and the covariance accumulates.
    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        let poses: Vec<P> = self.particles.iter().map(|p| p.pose).collect();
        let poses = if self.params.proposal == IpslamProposal::ScanMatch {
            let prediction = motion.predict(&self.mean.0)?;
            slam_core::ensure_finite(prediction.cov_control.as_slice(), "motion noise")?;
            self.motion_covariance = prediction.propagate_covariance(&self.motion_covariance)?;
            let control = motion.control();
            poses
                .iter()
                .map(|pose| motion.apply_control(pose, &control))
                .collect::<Result<Vec<P>>>()?
        } else {
            sample_motion(&poses, motion, self.params.seed, self.draws)?
        };
        self.draws += 1;
        for (particle, pose) in self.particles.iter_mut().zip(poses) {
            particle.pose = pose;
        }
        self.mean = self.weighted_mean();
        Ok(())
    }

    /// IPSLAM builds its map from scan points; extracted observations are not used.
    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        Ok(UpdateReport {
            rejected: observations.len(),
            ..Default::default()
        })
    }

    fn uses_scan_points(&self) -> bool {
        true
    }

    fn update_points(
        &mut self,
        robot_from_sensor: &Pose3,
        points: &[Vector2<f64>],
    ) -> Result<UpdateReport> {
        if !self.moved_enough() {
            return Ok(UpdateReport::default());
        }
        let points: Vec<Vector2<f64>> = points
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()) && p.norm() <= self.params.max_range)
            .copied()
            .collect();
        let scan_clusters = ppca::gmeans(&points, &self.params.gmeans());
        let params = &self.params;
        let prior = self.matching_prior();
        let draw = self.draws;
        if params.proposal == IpslamProposal::ScanMatch {
            self.draws += 1;
        }
        let steps: Vec<ParticleStep> = self
            .particles
            .par_iter_mut()
            .enumerate()
            .map(|(index, particle)| {
                if params.proposal == IpslamProposal::ScanMatch {
                    let mut rng = crate::fastslam::stream(params.seed, draw, index as u64);
                    match_to_own_map(
                        particle,
                        params,
                        robot_from_sensor,
                        &points,
                        &prior,
                        &mut rng,
                    );
                }
                process(particle, params, robot_from_sensor, &scan_clusters, &points)
            })
            .collect();
        self.motion_covariance.fill(0.0);
        for (particle, step) in self.particles.iter_mut().zip(&steps) {
            particle.log_weight += self.params.likelihood_scale * step.log_likelihood;
        }
        self.best = crate::fastslam::normalize_log_weights(
            self.particles
                .iter_mut()
                .map(|p| &mut p.log_weight)
                .collect(),
        );
        let report = UpdateReport {
            associated: steps[self.best].merged,
            new_features: steps[self.best].added,
            rejected: 0,
            nis: Vec::new(),
        };
        self.mean = self.weighted_mean();
        let weights: Vec<f64> = self.particles.iter().map(|p| p.log_weight).collect();
        if let Some(chosen) = resample_indices(
            &weights,
            self.params.resample_threshold,
            self.params.seed,
            self.draws,
        ) {
            self.draws += 1;
            let best = self.best;
            self.particles = chosen
                .iter()
                .map(|&i| Particle {
                    log_weight: 0.0,
                    ..self.particles[i].clone()
                })
                .collect();
            self.best = chosen.iter().position(|&i| i == best).unwrap_or(0);
        }
        self.last_processed = Some(self.mean.0);
        self.scans_processed += 1;
        self.snapshot = OnceLock::new();
        Ok(report)
    }

    fn pose(&self) -> P {
        self.mean.0
    }

    fn pose_covariance(&self) -> DMatrix<f64> {
        self.mean.1.clone()
    }

    /// The clusters of the particle with the largest weight, as features of the factory.
    fn map(&self) -> &FeatureMap {
        self.snapshot.get_or_init(|| {
            let mut map = FeatureMap::new();
            for (_, cluster) in self.particles[self.best].map.iter() {
                if let Ok(feature) = (self.factory)(cluster) {
                    // A factory's feature is unshared: insertion succeeds.
                    let _ = map.insert(feature);
                }
            }
            map
        })
    }

    fn row_covariance(&self, owner: RowOwner) -> Option<DMatrix<f64>> {
        let _ = owner;
        None
    }

    fn end_step(&mut self) {
        for particle in &mut self.particles {
            particle.path.push(particle.pose);
        }
    }

    /// The path of the particle with the largest weight (whose clusters
    /// [`map`](Estimator::map) returns).
    fn map_path(&self) -> Option<Vec<P>> {
        Some(self.particles[self.best].path.to_vec())
    }
}

#[cfg(test)]
mod tests;
