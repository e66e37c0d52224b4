//! The M-space EKF (paper section V): the filter holds the robot pose and the M-space
//! perturbations of every feature with their covariance; features keep their own
//! coordinates and are moved by `x_f += B~ dx_p` after each update (eq. 24).
//!
//! Written against the slam-core traits only: it never knows a concrete feature type.
//!
//! One update step ([`Ekf::update`]):
//! 1. **Association**: each observation is linearized against candidate features
//!    ([`FeatureMap::linearize`], eq. 30). Known landmark ids pair directly; otherwise
//!    Mahalanobis-gated nearest neighbour, or joint compatibility (JCBB) when configured.
//! 2. **Lifecycle**: an unmatched observation far from every feature starts a tentative
//!    feature (M-space dimension 0). A subspace that re-observations reveal
//!    `confirm_after` times is activated ([`slam_core::Feature::activate`]); features that one
//!    measurement cannot place (bearing-only lamps, ceiling-line position) grow when their
//!    stored views triangulate them. New rows enter with a prior and are then updated by the
//!    observation that revealed them.
//! 3. **Update**: all pairings of the step in one batch (eqs. 28-32), then `x_f += B~ dx_p`
//!    for every feature and shared block, and the extent of features along directions outside
//!    their M-space grows to cover what was measured ([`slam_core::MeasurementModel::extend`]).
//! 4. **Corners**: two features whose shareable blocks (wall ends) are fully estimated and
//!    statistically the same point are constrained together and then share the block
//!    (section VI, eq. 33): the covariance is re-parameterized onto the shared rows.
//! 5. **Duplicates**: a confirmed feature seen this step that is, by its joint covariance with
//!    another of its kind, the same physical feature ([`slam_core::Feature::coincidence`]) is
//!    constrained to it and removed, the kept one grown over its extent (see `merge.rs`).
//!    An unmatched observation that would start a feature on top of an existing one (within
//!    `new_feature_clearance`) is refused instead.

mod association;
mod corners;
mod covariance;
mod frames;
mod jacobians;
mod merge;
mod update;
mod views;

use std::collections::{BTreeMap, HashMap};

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Dim, Matrix, RawStorage, SMatrix};
use slam_core::{
    Error, Estimator, FeatureId, FeatureMap, LinearizedMeasurement, MotionModel, Observation,
    Result, RobotPose, RowOwner, Skips, UpdateReport, assign_matrix, assign_vector, reshape_zeroed,
};

use crate::association::{Association, AssociationSettings, Gates};
use crate::lifecycle::{LifecycleSettings, Track, first_failure};
use covariance::StateCovariance;
use frames::StepFrames;
use jacobians::pose_generators;

/// Settings of the [`Ekf`]; `Default` gives the values used on the built-in world.
///
/// ```
/// use slam_estimators::{Association, EkfParams};
/// let params = EkfParams { association: Association::Jcbb, ..Default::default() };
/// assert_eq!(params.confirm_after, 3);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EkfParams {
    /// Association rule for observations without landmark ids.
    pub association: Association,
    /// Probability of the chi-square gate an innovation must pass to pair.
    pub gate_probability: f64,
    /// An unmatched observation starts a new feature only if it lies outside this gate of
    /// every feature; between the two gates it is dropped as ambiguous.
    pub new_feature_probability: f64,
    /// Sightings of a subspace (including the first) before it is activated.
    pub confirm_after: usize,
    /// Update steps a tentative feature survives without a sighting.
    pub tentative_lifetime: usize,
    /// Prior variance of new M-space rows in directions the observation that reveals them
    /// does not determine (uninformative: large against the rows' scale of metres).
    pub new_row_variance: f64,
    /// Whether features join at shared blocks (wall corners, section VI).
    pub join_corners: bool,
    /// Largest distance between two blocks that may become one shared block, m.
    pub corner_distance: f64,
    /// Views kept per growing feature for triangulation.
    pub max_views: usize,
    /// Candidate features for an observation are those whose bounding box lies within this
    /// distance of the feature the observation would start, m.
    pub association_margin: f64,
    /// Node limit of the JCBB search (the best hypothesis so far is used when reached).
    pub jcbb_max_nodes: usize,
    /// An unmatched observation does not start a feature that would overlap an existing
    /// one of its kind within this distance, m (0: off): it would double that feature.
    pub new_feature_clearance: f64,
    /// Whether confirmed features that are one physical feature (a wall mapped twice) are
    /// merged: tested with their joint covariance, constrained together, one removed.
    pub merge_duplicates: bool,
    /// Probability of the chi-square gate two features' difference must pass to be merged.
    pub merge_probability: f64,
    /// Features are tested for merging when their shapes overlap within this distance, m.
    pub merge_distance: f64,
    /// Deviation two duplicates may have beyond their covariance, in the units of the
    /// coincidence residual (m for walls, poles and points): a real wall is not a line, and
    /// a wall updated a hundred times has a covariance far below its model error. Added to
    /// the merge test's covariance and to the merge constraint's noise. Default 0.
    pub merge_tolerance: f64,
    /// Observability-constrained updates (Huang, Mourikis & Roumeliotis, "Observability-based
    /// rules for designing consistent EKF SLAM estimators", IJRR 2010): each row of a
    /// measurement Jacobian is projected, over the state rows it depends on, so that it
    /// cannot observe a world translation or rotation, and the pose transition is the
    /// closest one that carries those directions from one predicted pose to the next.
    /// Without it the EKF gains spurious information about the absolute heading and becomes
    /// overconfident.
    pub observability_constraint: bool,
    /// A confirmed feature seen again before the robot has moved `reupdate_distance` (m) or
    /// turned `reupdate_angle` (rad) since its last update is not updated with (the
    /// observation still counts as a sighting and extends the feature): views from nearly
    /// the same place share their systematic error (clutter, the segment fit), and updating
    /// with each of them makes the feature and the pose overconfident. 0 and 0 (the
    /// defaults) update with every observation. `configs/carmen-walls.toml` uses 0.3 m and
    /// 0.1 rad: on freiburg-079 (4791 scans 0.1 m apart) the EKF no longer turns the robot
    /// by 5 degrees towards a wall built from one far viewpoint (BENCHMARKS.md, "Real
    /// buildings").
    pub reupdate_distance: f64,
    /// See `reupdate_distance`, rad.
    pub reupdate_angle: f64,
    /// Probability of the chi-square validation gate an observation with a known landmark
    /// id must pass to update (1: every one updates). The id says which landmark was seen,
    /// not that the first-order model holds: a landmark a few centimetres from the sensor,
    /// with 10 cm of range noise, moved a whole update's pose by 27 cm on a simulated log
    /// and left the filter overconfident for good (BENCHMARKS.md, "500 landmarks"). The
    /// default 0.999 rejects one valid observation in a thousand.
    pub known_id_gate_probability: f64,
}

impl Default for EkfParams {
    fn default() -> Self {
        EkfParams {
            association: Association::NearestNeighbour,
            gate_probability: 0.99,
            new_feature_probability: 0.9999,
            confirm_after: 3,
            tentative_lifetime: 15,
            new_row_variance: 1e4,
            join_corners: true,
            corner_distance: 0.3,
            max_views: 8,
            association_margin: 3.0,
            jcbb_max_nodes: 20_000,
            new_feature_clearance: 0.0,
            merge_duplicates: true,
            merge_probability: 0.99,
            merge_distance: 0.5,
            merge_tolerance: 0.0,
            observability_constraint: true,
            reupdate_distance: 0.0,
            reupdate_angle: 0.0,
            known_id_gate_probability: 0.999,
        }
    }
}

impl EkfParams {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<()> {
        let mut checks = self.association_settings().checks();
        checks.extend(self.lifecycle_settings().checks());
        checks.push((
            self.corner_distance.is_finite() && self.corner_distance >= 0.0,
            "corner_distance >= 0",
        ));
        checks.push((
            self.merge_probability > 0.0 && self.merge_probability < 1.0,
            "merge_probability in (0, 1)",
        ));
        checks.push((
            self.merge_distance.is_finite() && self.merge_distance >= 0.0,
            "merge_distance >= 0",
        ));
        checks.push((
            self.merge_tolerance.is_finite() && self.merge_tolerance >= 0.0,
            "merge_tolerance >= 0",
        ));
        checks.push((
            self.reupdate_distance.is_finite() && self.reupdate_distance >= 0.0,
            "reupdate_distance >= 0",
        ));
        checks.push((
            self.reupdate_angle.is_finite() && self.reupdate_angle >= 0.0,
            "reupdate_angle >= 0",
        ));
        checks.push((
            self.known_id_gate_probability > 0.0 && self.known_id_gate_probability <= 1.0,
            "known_id_gate_probability in (0, 1]",
        ));
        first_failure("EKF", &checks)
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

/// `eta^T S^-1 eta` for the inverse `s_inv` of an innovation covariance.
fn quadratic_form<D: Dim, S: RawStorage<f64, D, D>>(
    s_inv: &Matrix<f64, D, D, S>,
    eta: &DVector<f64>,
) -> f64 {
    (0..eta.len())
        .map(|i| eta[i] * (0..eta.len()).map(|j| s_inv[(i, j)] * eta[j]).sum::<f64>())
        .sum()
}

/// One observation linearized against one feature: a block row of `J_eta,state` (eq. 30)
/// restricted to the state rows it touches.
#[derive(Clone, Debug)]
struct Pairing {
    /// The feature.
    feature: FeatureId,
    /// State rows touched: the pose rows, then the feature's own and shared rows.
    indices: Vec<usize>,
    /// `J_eta,state` on those rows (`m x indices.len()`).
    h: DMatrix<f64>,
    /// The innovation `eta`.
    eta: DVector<f64>,
    /// `C_eta`.
    cov_eta: DMatrix<f64>,
    /// `eta^T S^-1 eta` against the feature as confirmed, when association computed it
    /// (the NIS the update reports).
    nis: Option<f64>,
}

/// The M-space EKF over robot poses of type `P`.
///
/// ```
/// use slam_core::{Estimator, Pose2, nalgebra::DMatrix};
/// use slam_estimators::{Ekf, EkfParams};
/// let ekf = Ekf::new(Pose2::identity(), DMatrix::zeros(3, 3), EkfParams::default()).unwrap();
/// assert_eq!(ekf.name(), "ekf");
/// assert_eq!(ekf.state_dim(), 3);
/// ```
#[derive(Debug)]
pub struct Ekf<P: RobotPose> {
    params: EkfParams,
    pose: P,
    cov: StateCovariance,
    map: FeatureMap,
    /// State row indices of every row owner, in the owner's own row order.
    rows: BTreeMap<RowOwner, Vec<usize>>,
    tracks: BTreeMap<FeatureId, Track<P>>,
    ids: HashMap<u64, FeatureId>,
    gates: Gates,
    step: usize,
    corners_joined: usize,
    features_merged: usize,
    /// Earlier views of features that grew by triangulation in this step, to update with.
    view_batch: Vec<Pairing>,
    /// What the current step left out, by reason.
    skips: Skips,
    /// The sensor frames of the current step's mounts at the current pose.
    frames: StepFrames<P>,
    /// The linearization buffer every pairing is written through (its storage kept).
    linearization: LinearizedMeasurement,
    /// Pairings of past steps, their storage reused by the next linearizations.
    spare_pairings: Vec<Pairing>,
    /// Scratch space for the unobservable directions of a pairing's rows.
    scratch: Vec<f64>,
}

/// What the filter decided for one observation.
#[derive(Debug)]
enum Decision {
    /// Paired with a feature (the linearization at the pre-update state).
    Pair(Pairing),
    /// Starts a new feature.
    New,
    /// Dropped (ambiguous, or it could not be linearized or placed).
    Reject,
}

impl Pairing {
    /// A pairing with no storage yet (the buffers [`Ekf::linearize`] fills).
    fn empty() -> Self {
        Pairing {
            feature: FeatureId(0),
            indices: Vec::new(),
            h: DMatrix::zeros(0, 0),
            eta: DVector::zeros(0),
            cov_eta: DMatrix::zeros(0, 0),
            nis: None,
        }
    }
}

impl<P: RobotPose> Ekf<P> {
    /// A filter at `pose` with pose covariance `pose_covariance` (`P::DIM` square) and no
    /// features.
    pub fn new(pose: P, pose_covariance: DMatrix<f64>, params: EkfParams) -> Result<Self> {
        params.validate()?;
        if pose_covariance.shape() != (P::DIM, P::DIM) {
            return Err(Error::DimensionMismatch {
                what: "initial pose covariance".into(),
                expected: P::DIM,
                got: pose_covariance.nrows(),
            });
        }
        slam_core::ensure_finite(pose_covariance.as_slice(), "initial pose covariance")?;
        let cov = StateCovariance::dense(&pose_covariance, &pose_generators(&pose));
        let mut probabilities = vec![
            params.gate_probability,
            params.new_feature_probability,
            params.merge_probability,
        ];
        if params.known_id_gate_probability < 1.0 {
            probabilities.push(params.known_id_gate_probability);
        }
        let gates = Gates::new(&probabilities)?;
        Ok(Ekf {
            params,
            pose,
            cov,
            map: FeatureMap::new(),
            rows: BTreeMap::new(),
            tracks: BTreeMap::new(),
            ids: HashMap::new(),
            gates,
            step: 0,
            corners_joined: 0,
            features_merged: 0,
            view_batch: Vec::new(),
            skips: Skips::default(),
            frames: StepFrames::default(),
            linearization: LinearizedMeasurement::default(),
            spare_pairings: Vec::new(),
            scratch: Vec::new(),
        })
    }

    /// The pose transition `Phi*` closest to `J_rr` (Frobenius norm) that carries the
    /// unobservable directions of the pose rows, `N_k` (kept from the last prediction), onto
    /// those at the predicted pose, `N_k+1`: `Phi* = J + (N_k+1 - J N_k)(N_k^T N_k)^-1 N_k^T`
    /// (the OC-EKF of Huang, Mourikis & Roumeliotis 2010). Propagating `N` by `J_rr` alone
    /// would leave its rotation direction at a pose that the updates never moved (the
    /// dead-reckoned one), so that `H N = 0` would be imposed about the wrong point; for a
    /// planar pose `Phi*` differs from `J_rr` only in using the whole displacement since the
    /// last prediction, the last update's correction included.
    fn constrained_transition(&self, d_pose_d_pose: &DMatrix<f64>, predicted: &P) -> DMatrix<f64> {
        let n_now = self.cov.generators(&Self::pose_indices());
        let n_next = pose_generators(predicted);
        match (n_now.transpose() * &n_now).try_inverse() {
            Some(gram_inverse) => {
                d_pose_d_pose + (n_next - d_pose_d_pose * &n_now) * gram_inverse * n_now.transpose()
            }
            None => d_pose_d_pose.clone(),
        }
    }

    /// The settings.
    pub fn params(&self) -> &EkfParams {
        &self.params
    }

    /// Number of state rows: the pose plus every M-space row.
    pub fn state_dim(&self) -> usize {
        self.cov.dim()
    }

    /// Corners joined so far.
    pub fn corners_joined(&self) -> usize {
        self.corners_joined
    }

    /// Features merged into others so far.
    pub fn features_merged(&self) -> usize {
        self.features_merged
    }

    /// Whether feature `id` has rows in the state (it is no longer tentative).
    pub fn is_confirmed(&self, id: FeatureId) -> bool {
        self.rows.contains_key(&RowOwner::Feature(id))
            || self
                .map
                .links(id)
                .is_ok_and(|links| links.iter().any(Option::is_some))
    }

    /// The whole state covariance (pose rows first); for tests and small maps.
    pub fn covariance(&self) -> DMatrix<f64> {
        self.cov.to_dense()
    }

    /// The state rows of a row owner.
    pub fn rows_of(&self, owner: RowOwner) -> Option<&[usize]> {
        self.rows.get(&owner).map(Vec::as_slice)
    }

    fn pose_indices() -> Vec<usize> {
        (0..P::DIM).collect()
    }

    /// Linearizes `observation` against feature `id` at the current state (eq. 30), through
    /// the kept linearization buffer into a spare pairing (no allocation once the buffers
    /// have their shapes).
    fn linearize(&mut self, observation: &Observation, id: FeatureId) -> Result<Pairing> {
        let mut lin = std::mem::take(&mut self.linearization);
        let spare = self.spare_pairings.pop().unwrap_or_else(Pairing::empty);
        let pairing = self.linearize_into(observation, id, &mut lin, spare);
        self.linearization = lin;
        pairing
    }

    /// [`Ekf::linearize`] through `lin` into `pairing`'s storage.
    fn linearize_into(
        &self,
        observation: &Observation,
        id: FeatureId,
        lin: &mut LinearizedMeasurement,
        mut pairing: Pairing,
    ) -> Result<Pairing> {
        let frame = self
            .frames
            .frame(&self.pose, &observation.robot_from_sensor)?;
        let measurement = observation.measurement.as_ref();
        slam_core::linearize_at_into(measurement, self.map.get(id)?, &frame, lin)?;
        let shared_width: usize = lin.d_eta_d_shared.iter().map(|(_, d)| d.ncols()).sum();
        let width = P::DIM + lin.d_eta_d_own.ncols() + shared_width;
        let m = lin.eta.len();
        pairing.feature = id;
        pairing.nis = None;
        pairing.indices.clear();
        pairing.indices.extend(0..P::DIM);
        reshape_zeroed(&mut pairing.h, m, width);
        pairing
            .h
            .columns_mut(0, P::DIM)
            .copy_from(&lin.d_eta_d_robot);
        self.map.visit_columns(id, lin, |owner, d| {
            let rows = self.rows.get(&owner).ok_or_else(|| {
                Error::Invariant(format!("row owner {owner:?} has no state rows"))
            })?;
            if rows.len() != d.ncols() {
                return Err(Error::DimensionMismatch {
                    what: format!("state rows of {owner:?}"),
                    expected: rows.len(),
                    got: d.ncols(),
                });
            }
            pairing
                .h
                .columns_mut(pairing.indices.len(), d.ncols())
                .copy_from(d);
            pairing.indices.extend_from_slice(rows);
            Ok(())
        })?;
        assign_vector(&mut pairing.eta, lin.eta.as_slice());
        assign_matrix(&mut pairing.cov_eta, &lin.cov_eta);
        Ok(pairing)
    }

    /// Keeps a pairing no longer needed, for its storage.
    fn recycle(&mut self, pairing: Pairing) {
        self.spare_pairings.push(pairing);
    }

    /// `eta^T S^-1 eta` with `S` of [`Ekf::innovation_covariance`]; `None` when `S` is
    /// singular. On the stack for up to 4 measurement rows and 16 state rows, with the
    /// dynamic path's bits (nalgebra inverts up to 4 x 4 in closed form for any storage).
    fn mahalanobis(&self, pairing: &Pairing, tentative: bool) -> Option<f64> {
        match pairing.eta.len() {
            1 => self.mahalanobis_fixed::<1>(pairing, tentative),
            2 => self.mahalanobis_fixed::<2>(pairing, tentative),
            3 => self.mahalanobis_fixed::<3>(pairing, tentative),
            4 => self.mahalanobis_fixed::<4>(pairing, tentative),
            _ => self.mahalanobis_dynamic(pairing, tentative),
        }
    }

    /// [`Ekf::mahalanobis`] through dynamic matrices.
    fn mahalanobis_dynamic(&self, pairing: &Pairing, tentative: bool) -> Option<f64> {
        self.innovation_covariance(pairing, tentative)
            .try_inverse()
            .map(|s_inv| quadratic_form(&s_inv, &pairing.eta))
    }

    /// [`Ekf::mahalanobis`] for `M` measurement rows on the stack, the arithmetic of
    /// [`Ekf::innovation_covariance`] and [`quadratic_form`].
    fn mahalanobis_fixed<const M: usize>(&self, pairing: &Pairing, tentative: bool) -> Option<f64> {
        const CAPACITY: usize = 64;
        let k = pairing.h.ncols();
        if pairing.h.nrows() != M || M * k > CAPACITY {
            return self.mahalanobis_dynamic(pairing, tentative);
        }
        let mut hc = [0.0; CAPACITY];
        self.add_hc(pairing, &mut hc);
        let s =
            SMatrix::<f64, M, M>::from_fn(|i, j| innovation_entry(pairing, &hc, tentative, i, j));
        Some(quadratic_form(&s.try_inverse()?, &pairing.eta))
    }

    /// `S = H C H^T + C_eta` of a pairing; for a tentative feature (no rows) the feature's own
    /// uncertainty is approximated by one more `C_eta` (it was placed by one measurement).
    fn innovation_covariance(&self, pairing: &Pairing, tentative: bool) -> DMatrix<f64> {
        let (m, k) = pairing.h.shape();
        let mut hc = vec![0.0; m * k];
        self.add_hc(pairing, &mut hc);
        DMatrix::from_fn(m, m, |i, j| innovation_entry(pairing, &hc, tentative, i, j))
    }

    /// `hc += H C` on the pairing's rows (`m x k`, column-major), C read in place.
    fn add_hc(&self, pairing: &Pairing, hc: &mut [f64]) {
        let (m, k) = pairing.h.shape();
        let indices = &pairing.indices;
        for b in 0..k {
            for a in 0..k {
                let c = self.cov.get(indices[a], indices[b]);
                for i in 0..m {
                    hc[i + m * b] += pairing.h[(i, a)] * c;
                }
            }
        }
    }
}

/// Entry `(i, j)` of a pairing's `S` (see [`Ekf::innovation_covariance`]) from its `H C`.
fn innovation_entry(pairing: &Pairing, hc: &[f64], tentative: bool, i: usize, j: usize) -> f64 {
    let (m, k) = pairing.h.shape();
    let s = (0..k)
        .map(|b| hc[i + m * b] * pairing.h[(j, b)])
        .sum::<f64>()
        + pairing.cov_eta[(i, j)];
    if tentative {
        s + pairing.cov_eta[(i, j)]
    } else {
        s
    }
}

impl<P: RobotPose> Estimator<P> for Ekf<P> {
    fn name(&self) -> &'static str {
        "ekf"
    }

    /// Eqs. 25-27: the pose moves by the dead-reckoning increment; `C_rr` and `C_rp` follow.
    fn predict(&mut self, motion: &dyn MotionModel<P>) -> Result<()> {
        let prediction = motion.predict(&self.pose)?;
        let added = &prediction.d_pose_d_control
            * &prediction.cov_control
            * prediction.d_pose_d_control.transpose();
        slam_core::ensure_finite(added.as_slice(), "motion noise")?;
        slam_core::ensure_finite(prediction.d_pose_d_pose.as_slice(), "J_rr")?;
        let transition = if self.params.observability_constraint {
            self.constrained_transition(&prediction.d_pose_d_pose, &prediction.pose)
        } else {
            prediction.d_pose_d_pose.clone()
        };
        self.cov.predict(&transition, &added);
        self.pose = prediction.pose;
        Ok(())
    }

    fn update(&mut self, observations: &[Observation]) -> Result<UpdateReport> {
        self.step += 1;
        self.skips = Skips::default();
        self.cov.flush();
        self.frames.prepare(&self.pose, observations);
        let decisions = self.associate(observations)?;
        let mut report = self.apply_decisions(observations, decisions)?;
        report.skipped = std::mem::take(&mut self.skips);
        Ok(report)
    }

    fn pose(&self) -> P {
        self.pose
    }

    fn pose_covariance(&self) -> DMatrix<f64> {
        let pose = Self::pose_indices();
        self.cov.gather(&pose, &pose)
    }

    fn map(&self) -> &FeatureMap {
        &self.map
    }

    fn row_covariance(&self, owner: RowOwner) -> Option<DMatrix<f64>> {
        self.rows
            .get(&owner)
            .map(|rows| self.cov.gather(rows, rows))
    }

    fn cross_covariance(&self, a: RowOwner, b: RowOwner) -> Option<DMatrix<f64>> {
        Some(self.cov.gather(self.rows.get(&a)?, self.rows.get(&b)?))
    }

    fn landmark_id(&self, id: FeatureId) -> Option<u64> {
        self.tracks.get(&id).and_then(|t| t.landmark_id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::{MotionPrediction, Pose2};

    /// A body-frame increment `(dx, dy, dtheta)` with a small diagonal noise.
    #[derive(Debug)]
    struct BodyIncrement([f64; 3]);

    impl MotionModel<Pose2> for BodyIncrement {
        fn control(&self) -> DVector<f64> {
            DVector::from_column_slice(&self.0)
        }

        fn apply_control(&self, pose: &Pose2, control: &DVector<f64>) -> Result<Pose2> {
            let (s, c) = pose.theta.sin_cos();
            Ok(Pose2::new(
                pose.x + c * control[0] - s * control[1],
                pose.y + s * control[0] + c * control[1],
                pose.theta + control[2],
            ))
        }

        fn predict(&self, pose: &Pose2) -> Result<MotionPrediction<Pose2>> {
            let [dx, dy, _] = self.0;
            let (s, c) = pose.theta.sin_cos();
            Ok(MotionPrediction {
                pose: self.apply_control(pose, &self.control())?,
                d_pose_d_pose: DMatrix::from_row_slice(
                    3,
                    3,
                    &[
                        1.0,
                        0.0,
                        -s * dx - c * dy,
                        0.0,
                        1.0,
                        c * dx - s * dy,
                        0.0,
                        0.0,
                        1.0,
                    ],
                ),
                d_pose_d_control: DMatrix::from_row_slice(
                    3,
                    3,
                    &[c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0],
                ),
                cov_control: DMatrix::identity(3, 3) * 1e-4,
            })
        }
    }

    /// After an update moved the pose, the next prediction puts the unobservable directions of
    /// the pose rows at the predicted pose (OC-EKF), not at the dead-reckoned one.
    #[test]
    fn pose_generators_follow_the_estimate_through_corrections() {
        let start = Pose2::new(1.0, 2.0, 0.3);
        let motion = BodyIncrement([0.5, 0.0, 0.1]);
        for constrained in [true, false] {
            let params = EkfParams {
                observability_constraint: constrained,
                ..EkfParams::default()
            };
            let mut ekf = Ekf::new(start, DMatrix::identity(3, 3) * 1e-4, params).unwrap();
            // What an update's correction does to the estimate (the generators stay).
            ekf.apply_state_change(&DVector::from_column_slice(&[0.4, -0.7, 0.05]))
                .unwrap();
            ekf.predict(&motion).unwrap();
            let at_estimate = pose_generators(&ekf.pose);
            let dead_reckoned = motion.apply_control(&start, &motion.control()).unwrap();
            let expected = if constrained {
                at_estimate.clone()
            } else {
                // J_rr evaluated at the corrected heading, applied to the old directions.
                let old = pose_generators(&start);
                let j = motion.predict(&Pose2::new(1.4, 1.3, 0.35)).unwrap();
                j.d_pose_d_pose * old
            };
            let carried = ekf.cov.generators(&[0, 1, 2]);
            assert!(
                (&carried - &expected).amax() < 1e-12,
                "constrained {constrained}: {carried} against {expected}"
            );
            if !constrained {
                assert!((&carried - &at_estimate).amax() > 0.1, "{dead_reckoned:?}");
            }
        }
    }

    /// The loops of `innovation_covariance` and `quadratic_form` give the dense products.
    #[test]
    fn innovation_covariance_matches_the_dense_products() {
        let c = DMatrix::from_row_slice(3, 3, &[2.0, 0.3, -0.1, 0.3, 1.5, 0.2, -0.1, 0.2, 0.7]);
        let ekf = Ekf::new(Pose2::new(1.0, 2.0, 0.3), c.clone(), EkfParams::default()).unwrap();
        let pairing = Pairing {
            feature: FeatureId(0),
            indices: vec![2, 0],
            h: DMatrix::from_row_slice(2, 2, &[0.5, -1.0, 2.0, 0.25]),
            eta: DVector::from_column_slice(&[0.1, -0.2]),
            cov_eta: DMatrix::from_row_slice(2, 2, &[0.01, 0.0, 0.0, 0.04]),
            nis: None,
        };
        let c_rows = DMatrix::from_fn(2, 2, |a, b| c[(pairing.indices[a], pairing.indices[b])]);
        let dense = &pairing.h * c_rows * pairing.h.transpose() + &pairing.cov_eta;
        assert!((ekf.innovation_covariance(&pairing, false) - &dense).amax() < 1e-12);
        let tentative = &dense + &pairing.cov_eta;
        assert!((ekf.innovation_covariance(&pairing, true) - tentative).amax() < 1e-12);
        let s_inv = dense.try_inverse().unwrap();
        let nis = (pairing.eta.transpose() * &s_inv * &pairing.eta)[(0, 0)];
        assert!((quadratic_form(&s_inv, &pairing.eta) - nis).abs() < 1e-12);
    }

    /// The Mahalanobis distance on the stack (up to 4 rows) has the dynamic path's bits, and
    /// more rows take the dynamic path.
    #[test]
    fn the_stack_mahalanobis_distance_equals_the_dynamic_one_bit_for_bit() {
        let c = DMatrix::from_row_slice(3, 3, &[2.0, 0.3, -0.1, 0.3, 1.5, 0.2, -0.1, 0.2, 0.7]);
        let ekf = Ekf::new(Pose2::new(1.0, 2.0, 0.3), c, EkfParams::default()).unwrap();
        for m in 1..=6 {
            let pairing =
                Pairing {
                    feature: FeatureId(0),
                    indices: vec![2, 0, 1],
                    h: DMatrix::from_fn(m, 3, |i, j| ((i * 3 + j) as f64 * 0.77).sin()),
                    eta: DVector::from_fn(m, |i, _| 0.1 * (i as f64 + 1.0).cos()),
                    cov_eta: DMatrix::from_fn(m, m, |i, j| {
                        if i == j { 0.01 * (i + 1) as f64 } else { 0.0 }
                    }),
                    nis: None,
                };
            for tentative in [false, true] {
                let stack = ekf.mahalanobis(&pairing, tentative).unwrap();
                let dynamic = ekf.mahalanobis_dynamic(&pairing, tentative).unwrap();
                assert_eq!(
                    stack.to_bits(),
                    dynamic.to_bits(),
                    "{m} rows: {stack} {dynamic}"
                );
            }
        }
    }

    /// Without a correction the constrained transition is `J_rr` itself.
    #[test]
    fn without_a_correction_the_transition_is_unchanged() {
        let pose = Pose2::new(-3.0, 4.0, 2.0);
        let ekf = Ekf::new(pose, DMatrix::identity(3, 3), EkfParams::default()).unwrap();
        let prediction = BodyIncrement([0.3, 0.1, -0.2]).predict(&pose).unwrap();
        let transition = ekf.constrained_transition(&prediction.d_pose_d_pose, &prediction.pose);
        assert!((transition - prediction.d_pose_d_pose).amax() < 1e-12);
    }
}
