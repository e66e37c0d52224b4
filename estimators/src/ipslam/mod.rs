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
//!    map; unmatched old ones stay;
//! 5. (an addition, `merge_map_clusters`, on by default) each map cluster that step 3 or 4
//!    changed is merged with another map cluster near the scan that lies on the same line
//!    (principal directions within `map_merge_angle_deg`, the shorter one's centre within
//!    `max_normal_distance` of the longer one's line, the segments overlapping or within
//!    `max_normal_distance` of each other), the thinnest such union first, again and again
//!    while the union finds a partner. The union is exact from the two clusters' moments
//!    (count, centre, sample covariance: [`ppca::combine`]) and is refused when thick
//!    (non-principal deviation above `map_merge_max_sigma`, 3 cm by default; `None`:
//!    `new_cluster_max_sigma`). The paper merges map clusters
//!    with the scan's only (Table I, step 6c), so two clusters of one wall that grew apart
//!    (a corridor seen on the way out and again on the way back, before the first sighting's
//!    cluster reached the second's) stay two forever; its stated aim is a compact map of a few
//!    lines per wall, which this step keeps.
//! 6. (an addition, `prune_unconfirmed_after`, off by default) a map cluster near the scan that
//!    holds the points of a single scan (never matched or merged since) is removed once that
//!    many scans have been processed after it: clutter, people and glimpses through doors. The
//!    paper keeps every unmatched old cluster unchanged (Table I, step 6c-iv), so this is off
//!    unless asked for.
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
//! The scan's points arrive as observations, and the map's features are made, by the types
//! the caller names ([`LineMapTypes`]: this crate knows no feature or measurement type).

mod line_map;
mod matching;
pub mod ppca;

use std::sync::{Arc, OnceLock};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Vector2, Vector3};
use slam_core::{
    Estimator, Feature, FeatureMap, MotionModel, Observation, Pose3, Result, RobotPose, RowOwner,
    UpdateReport,
};

use crate::lifecycle::first_failure;
use crate::particles::{ParticleSet, stream};
use line_map::{LineMap, ScanOutcome, match_to_own_map, process};
pub use ppca::{Cluster, GMeansParams};

/// What IPSLAM needs of the types the caller uses for its line maps: the map feature of a
/// cluster (a PPCA line behind the slam-core traits) and the scan point an observation
/// carries (a laser return in the sensor frame). `Arc`-shared by the filter.
pub trait LineMapTypes: Send + Sync {
    /// The map feature of a cluster.
    fn cluster_feature(&self, cluster: &Cluster) -> Result<Box<dyn Feature>>;

    /// The return an observation carries, in its sensor's frame (x forward, y left, m), or
    /// `None` for an observation of something else.
    fn scan_point(&self, observation: &Observation) -> Option<Vector2<f64>>;
}

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
    /// After a scan, merge the map clusters it changed with other map clusters of the same
    /// line (step 5 of the module documentation; an addition: the paper merges map clusters
    /// with the scan's only, so two clusters of one wall that grew apart never fuse).
    pub merge_map_clusters: bool,
    /// ... whose principal directions are within this angle, degrees.
    pub map_merge_angle_deg: f64,
    /// ... and whose union has a non-principal deviation at most this, m (`None`:
    /// `new_cluster_max_sigma`). The default, 3 cm, kept the paths best on the Intel lab;
    /// 5 cm merged more but thickened the clusters and flattened the weights (BENCHMARKS.md).
    pub map_merge_max_sigma: Option<f64>,
    /// Remove a map cluster near the scan that holds a single scan's points once this many
    /// scans have been processed since (step 6 of the module documentation; an addition, not
    /// in the paper; 0: never, the paper).
    pub prune_unconfirmed_after: usize,
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
            merge_map_clusters: true,
            map_merge_angle_deg: 15.0,
            map_merge_max_sigma: Some(0.03),
            prune_unconfirmed_after: 0,
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
                self.particles <= crate::particles::MAX_PARTICLES,
                "particles <= 100000 (a resource limit: each particle keeps a map and a path)",
            ),
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
            (
                self.map_merge_max_sigma.is_none_or(positive),
                "map_merge_max_sigma > 0",
            ),
            (
                positive(self.map_merge_angle_deg) && self.map_merge_angle_deg <= 90.0,
                "map_merge_angle_deg in (0, 90]",
            ),
        ];
        first_failure("IPSLAM", &checks)
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

/// A scan's points in the sensor frame and the sensor's mount.
type ScanPoints = (Vec<Vector2<f64>>, Pose3);

/// IPSLAM over robot poses of type `P` (see the module documentation).
pub struct Ipslam<P: RobotPose> {
    params: IpslamParams,
    set: ParticleSet<P, LineMap>,
    types: Arc<dyn LineMapTypes>,
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
            .field("particles", &self.set.particles.len())
            .field("scans_processed", &self.scans_processed)
            .finish_non_exhaustive()
    }
}

impl<P: RobotPose> Ipslam<P> {
    /// A filter whose particles start at `pose`, spread by `pose_covariance` (`P::DIM`
    /// square; zero for a known start), with empty maps; `types` reads the scan points and
    /// makes the map features.
    pub fn new(
        pose: P,
        pose_covariance: DMatrix<f64>,
        params: IpslamParams,
        types: Arc<dyn LineMapTypes>,
    ) -> Result<Self> {
        params.validate()?;
        let set = ParticleSet::new(pose, &pose_covariance, params.particles, params.seed)?;
        Ok(Ipslam {
            params,
            set,
            types,
            last_processed: None,
            motion_covariance: DMatrix::zeros(P::DIM, P::DIM),
            scans_processed: 0,
            snapshot: OnceLock::new(),
        })
    }

    /// Scans processed so far.
    pub fn scans_processed(&self) -> usize {
        self.scans_processed
    }

    /// The clusters of the particle with the largest weight.
    pub fn clusters(&self) -> Vec<Cluster> {
        self.set
            .best_particle()
            .map
            .iter()
            .map(|(_, c)| c.cluster)
            .collect()
    }

    /// The information of the `scan-match` prior on the sensor's `(x, y, heading)`: the
    /// accumulated motion covariance's position and heading variances (the sensor's lever arm
    /// neglected), floored at 1 cm and 0.2 degrees.
    fn matching_prior(&self) -> Vector3<f64> {
        let c = &self.motion_covariance;
        let heading = P::HEADING;
        let position = (0.5 * (c[(0, 0)] + c[(1, 1)])).max(1e-4);
        let heading = c[(heading, heading)].max(0.2f64.to_radians().powi(2));
        Vector3::new(1.0 / position, 1.0 / position, 1.0 / heading)
    }

    /// Whether the robot moved enough since the last processed scan.
    fn moved_enough(&self) -> bool {
        let Some(last) = &self.last_processed else {
            return true;
        };
        let (translation, rotation) = self.set.mean.0.distance_and_angle(last);
        translation >= self.params.min_travel || rotation >= self.params.min_turn_deg.to_radians()
    }

    /// The scan's points among the observations, those within range, with their sensor
    /// mount (`None` when no observation is a scan point), and how many observations were
    /// something else.
    fn scan_points(&self, observations: &[Observation]) -> (Option<ScanPoints>, usize) {
        let mut scan: Option<ScanPoints> = None;
        let mut others = 0;
        for observation in observations {
            match self.types.scan_point(observation) {
                Some(p) => {
                    let (points, _) = scan.get_or_insert_with(|| {
                        (
                            Vec::with_capacity(observations.len()),
                            observation.robot_from_sensor,
                        )
                    });
                    if p.iter().all(|v| v.is_finite()) && p.norm() <= self.params.max_range {
                        points.push(p);
                    }
                }
                None => others += 1,
            }
        }
        (scan, others)
    }

    /// Steps 1-4 of the module documentation for every particle (after the `scan-match`
    /// proposal, when configured), in parallel.
    fn process_scan(
        &mut self,
        robot_from_sensor: &Pose3,
        points: &[Vector2<f64>],
    ) -> Vec<ScanOutcome> {
        let scan_clusters = ppca::gmeans(points, &self.params.gmeans());
        let params = &self.params;
        let prior = self.matching_prior();
        let scan_match = params.proposal == IpslamProposal::ScanMatch;
        let seed = self.set.seed();
        let draw = if scan_match { self.set.next_draw() } else { 0 };
        let scans_processed = self.scans_processed;
        self.set
            .particles
            .par_iter_mut()
            .enumerate()
            .map(|(index, particle)| {
                if scan_match {
                    let mut rng = stream(seed, draw, index as u64);
                    match_to_own_map(
                        particle,
                        params,
                        robot_from_sensor,
                        points,
                        &prior,
                        &mut rng,
                    );
                }
                process(
                    particle,
                    params,
                    robot_from_sensor,
                    &scan_clusters,
                    points,
                    scans_processed,
                )
            })
            .collect()
    }
}

impl<P: RobotPose> Estimator<P> for Ipslam<P> {
    fn name(&self) -> &'static str {
        "ipslam"
    }

    /// Every particle draws its increment from the motion model (eq. 17); with the
    /// `scan-match` proposal it takes the mean increment and the covariance accumulates.
    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        if self.params.proposal != IpslamProposal::ScanMatch {
            return self.set.sample_motion(motion);
        }
        let prediction = motion.predict(&self.set.mean.0)?;
        slam_core::ensure_finite(prediction.cov_control.as_slice(), "motion noise")?;
        self.motion_covariance = prediction.propagate_covariance(&self.motion_covariance)?;
        let control = motion.control();
        let poses = self
            .set
            .particles
            .iter()
            .map(|particle| motion.apply_control(&particle.pose, &control))
            .collect::<Result<Vec<P>>>()?;
        for (particle, pose) in self.set.particles.iter_mut().zip(poses) {
            particle.pose = pose;
        }
        // The draw the motion proposal would have used, so that both proposals number their
        // streams alike.
        self.set.next_draw();
        self.set.update_mean();
        Ok(())
    }

    /// Processes the scan points among `observations` (one scan) once the robot has moved
    /// enough; other observations are rejected.
    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        let (scan, others) = self.scan_points(observations);
        let rejected_only = UpdateReport {
            rejected: others,
            ..Default::default()
        };
        let Some((points, robot_from_sensor)) = scan else {
            return Ok(rejected_only);
        };
        if !self.moved_enough() {
            return Ok(rejected_only);
        }
        let outcomes = self.process_scan(&robot_from_sensor, &points);
        self.motion_covariance.fill(0.0);
        let scale = self.params.likelihood_scale;
        self.set
            .weigh(outcomes.iter().map(|o| scale * o.log_likelihood));
        let best = &outcomes[self.set.best];
        let report = UpdateReport {
            associated: best.merged,
            new_features: best.added,
            rejected: others,
            ..Default::default()
        };
        self.set.update_mean();
        self.set.resample(self.params.resample_threshold);
        self.last_processed = Some(self.set.mean.0);
        self.scans_processed += 1;
        self.snapshot = OnceLock::new();
        Ok(report)
    }

    fn pose(&self) -> P {
        self.set.mean.0
    }

    fn pose_covariance(&self) -> DMatrix<f64> {
        self.set.mean.1.clone()
    }

    fn covariance_source(&self) -> &'static str {
        "particle cloud"
    }

    /// The clusters of the particle with the largest weight, as the caller's features.
    fn map(&self) -> &FeatureMap {
        self.snapshot.get_or_init(|| {
            let mut map = FeatureMap::new();
            for (_, cluster) in self.set.best_particle().map.iter() {
                if let Ok(feature) = self.types.cluster_feature(&cluster.cluster) {
                    // A new feature is unshared: insertion succeeds.
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
        self.set.end_step();
    }

    /// The path of the particle with the largest weight (whose clusters
    /// [`map`](Estimator::map) returns).
    fn map_path(&self) -> Option<Vec<P>> {
        Some(self.set.best_particle().path.to_vec())
    }
}

#[cfg(test)]
mod tests;
