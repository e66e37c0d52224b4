//! The feature lifecycle, shared by the EKF and by each FastSLAM particle (paper section IV:
//! the M-space of a feature grows as more of it is observed):
//!
//! 1. **Tentative**: an observation far from every feature starts one at M-space dimension 0
//!    ([`slam_core::MeasurementModel::initial_feature`]); it has no rows in the estimate.
//! 2. **Growth**: every sighting counts the subspaces it reveals
//!    ([`slam_core::MeasurementModel::revealed_subspaces`]); a subspace revealed
//!    `confirm_after` times (once for a known landmark) is activated and its rows enter with
//!    their prior ([`slam_core::Feature::growth_prior`], else `new_row_variance`). A feature
//!    that one measurement cannot place grows when its stored views triangulate it
//!    (the `triangulation` module).
//! 3. **Extension**: directions outside the M-space (a wall's extent) follow the
//!    measurements ([`slam_core::MeasurementModel::extend`]).
//! 4. **Removal**: a tentative feature not seen for `tentative_lifetime` steps is removed.
//! 5. **Shared corners** (the `corners` module): blocks of two features that are the same point become
//!    one shared block (section VI); the covariance part is the EKF's.
//!
//! What differs between estimators (how a covariance grows, how an update is applied) stays
//! in the estimator; the rules and the bookkeeping live here.

pub(crate) mod corners;
mod triangulation;

use std::collections::BTreeMap;
use std::sync::Arc;

use slam_core::nalgebra::DMatrix;
use slam_core::{
    DynMeasurementModel, Error, Extension, Feature, FeatureId, FeatureMap, Growth, MapToSensor,
    Observation, Pose3, Result, RobotPose, Skips, Subspace,
};

pub(crate) use triangulation::placed_by_triangulation;

/// The lifecycle settings an estimator's parameters carry (the same keys in
/// [`crate::EkfParams`] and [`crate::FastSlamParams`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LifecycleSettings {
    /// Sightings of a subspace (including the first) before it is activated.
    pub confirm_after: usize,
    /// Update steps a tentative feature survives without a sighting.
    pub tentative_lifetime: usize,
    /// Prior variance of new M-space rows in directions the revealing observation does not
    /// determine.
    pub new_row_variance: f64,
    /// Views kept per growing feature for triangulation.
    pub max_views: usize,
}

impl LifecycleSettings {
    /// Range checks, as `(holds, what must hold)`, for the estimator's `validate`.
    pub(crate) fn checks(&self) -> Vec<(bool, &'static str)> {
        vec![
            (self.confirm_after >= 1, "confirm_after >= 1"),
            (self.tentative_lifetime >= 1, "tentative_lifetime >= 1"),
            (
                self.new_row_variance.is_finite() && self.new_row_variance > 0.0,
                "new_row_variance > 0",
            ),
            (self.max_views >= 2, "max_views >= 2"),
        ]
    }
}

/// The first failing check as an error naming the estimator (`what`).
pub(crate) fn first_failure(what: &str, checks: &[(bool, &'static str)]) -> Result<()> {
    match checks.iter().find(|(ok, _)| !ok) {
        Some((_, rule)) => Err(Error::InvalidArgument(format!("{what} parameters: {rule}"))),
        None => Ok(()),
    }
}

/// One earlier measurement of a feature, kept for triangulation.
#[derive(Clone, Debug)]
pub(crate) struct View<P> {
    pub world_from_sensor: Pose3,
    pub world_from_robot: P,
    pub robot_from_sensor: Pose3,
    /// The pose covariance when the view was taken (an EKF relates the view to the current
    /// pose with it).
    pub pose_covariance: Option<DMatrix<f64>>,
    pub measurement: Arc<dyn DynMeasurementModel>,
}

/// What an estimator remembers about a feature besides its estimate.
#[derive(Clone, Debug)]
pub(crate) struct Track<P> {
    /// Sightings so far, including the first.
    pub sightings: usize,
    /// The update step of the last sighting.
    pub last_seen: usize,
    /// How often each not-yet-active subspace was revealed.
    pub revealed: BTreeMap<&'static str, usize>,
    /// Views for triangulation (while the feature can still grow).
    pub views: Vec<View<P>>,
    /// The data's landmark id, when known.
    pub landmark_id: Option<u64>,
    /// The robot pose of the last update with this feature (the EKF's `reupdate_distance`).
    pub last_update: Option<P>,
}

impl<P> Default for Track<P> {
    fn default() -> Self {
        Track {
            sightings: 0,
            last_seen: 0,
            revealed: BTreeMap::new(),
            views: Vec::new(),
            landmark_id: None,
            last_update: None,
        }
    }
}

/// One sighting of a feature, as [`Track::sight`] records it.
pub(crate) struct Sighting<'a, P> {
    pub observation: &'a Observation,
    pub world_from_robot: &'a P,
    pub step: usize,
    /// The measurement to keep as a view (shared by the particles that see it), when it can
    /// triangulate.
    pub view_measurement: Option<Arc<dyn DynMeasurementModel>>,
    /// The pose covariance to keep with the view.
    pub pose_covariance: Option<DMatrix<f64>>,
    /// The map-to-sensor transform of this sighting's sensor at `world_from_robot`, when the
    /// estimator made it beforehand (once per step); made here otherwise.
    pub to_sensor: Option<&'a MapToSensor>,
}

impl<P: RobotPose> Track<P> {
    /// A track for a feature started by an observation with this landmark id.
    pub(crate) fn started(landmark_id: Option<u64>, step: usize) -> Self {
        Track {
            last_seen: step,
            landmark_id,
            ..Track::default()
        }
    }

    /// Sightings of a subspace needed to activate it: once for a known landmark.
    pub(crate) fn growth_threshold(&self, confirm_after: usize) -> usize {
        if self.landmark_id.is_some() {
            1
        } else {
            confirm_after
        }
    }

    /// Whether a tentative feature has gone unseen for longer than `lifetime` steps.
    pub(crate) fn expired(&self, step: usize, lifetime: usize) -> bool {
        step.saturating_sub(self.last_seen) > lifetime
    }

    /// Counts a sighting of `feature`: the subspaces it reveals, and a view kept while the
    /// feature can still grow by triangulation (the first view, the widest baseline so far,
    /// and the most recent ones).
    pub(crate) fn sight(
        &mut self,
        feature: &dyn Feature,
        sighting: Sighting<'_, P>,
        max_views: usize,
        skips: &mut Skips,
    ) -> Result<()> {
        let observation = sighting.observation;
        let (world_from_sensor, x_o) = match sighting.to_sensor {
            Some(to_sensor) => (
                *to_sensor.world_from_sensor(),
                to_sensor.transform(feature.coordinates())?,
            ),
            None => {
                let world_from_sensor = sighting
                    .world_from_robot
                    .world_from_sensor(&observation.robot_from_sensor);
                let x_o = MapToSensor::new(&world_from_sensor)?.transform(feature.coordinates())?;
                (world_from_sensor, x_o)
            }
        };
        let revealed = match observation
            .measurement
            .revealed_subspaces_dyn(feature, &x_o)
        {
            Ok(revealed) => revealed,
            Err(_) => {
                skips.count("lifecycle: revealed subspaces not computable");
                Vec::new()
            }
        };
        self.sightings += 1;
        self.last_seen = sighting.step;
        for name in revealed {
            *self.revealed.entry(name).or_default() += 1;
        }
        match sighting.view_measurement {
            Some(measurement) if !feature.growth_options().is_empty() => {
                if self.views.len() >= max_views {
                    self.views.remove(1);
                }
                self.views.push(View {
                    world_from_sensor,
                    world_from_robot: *sighting.world_from_robot,
                    robot_from_sensor: observation.robot_from_sensor,
                    pose_covariance: sighting.pose_covariance,
                    measurement,
                });
            }
            _ => self.views.clear(),
        }
        Ok(())
    }

    /// The feature placed by triangulating `measurement` (the last view) with the earlier
    /// views, when they reveal subspaces it does not have.
    fn triangulated(
        &self,
        feature: &dyn Feature,
        measurement: &dyn DynMeasurementModel,
        skips: &mut Skips,
    ) -> Result<Option<Box<dyn Feature>>> {
        let Some((current, others)) = self.views.split_last() else {
            return Ok(None);
        };
        let other_views: Vec<_> = others
            .iter()
            .map(|v| (v.world_from_sensor, v.measurement.as_ref()))
            .collect();
        placed_by_triangulation(
            feature,
            measurement,
            &current.world_from_sensor,
            &other_views,
            skips,
        )
    }
}

/// Where a feature that grows lives: an estimator's map entry or a particle's own feature.
pub(crate) trait GrowthTarget {
    /// The feature.
    fn feature(&self) -> Result<&dyn Feature>;
    /// Activates a subspace ([`Feature::activate`]).
    fn activate(&mut self, subspace: &str) -> Result<Growth>;
    /// Replaces the feature by its grown version (same block layout).
    fn replace(&mut self, feature: Box<dyn Feature>) -> Result<()>;
}

/// A feature of a [`FeatureMap`] as a [`GrowthTarget`].
pub(crate) struct MapEntry<'a> {
    pub map: &'a mut FeatureMap,
    pub id: FeatureId,
}

impl GrowthTarget for MapEntry<'_> {
    fn feature(&self) -> Result<&dyn Feature> {
        self.map.get(self.id)
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        self.map.activate(self.id, subspace)
    }

    fn replace(&mut self, feature: Box<dyn Feature>) -> Result<()> {
        self.map.replace(self.id, feature)
    }
}

impl GrowthTarget for Box<dyn Feature> {
    fn feature(&self) -> Result<&dyn Feature> {
        Ok(self.as_ref())
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        self.as_mut().activate(subspace)
    }

    fn replace(&mut self, feature: Box<dyn Feature>) -> Result<()> {
        *self = feature;
        Ok(())
    }
}

/// How a feature grew in one step.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Grown {
    /// M-space dimension before.
    pub old_dim: usize,
    /// Rows added.
    pub added: usize,
    /// Prior covariance of the added rows (`added` square).
    pub prior: DMatrix<f64>,
    /// Whether the growth came from triangulating the views (which then measure the new
    /// rows).
    pub triangulated: bool,
}

/// Grows the feature by every subspace revealed often enough or, failing that, by
/// triangulation from its views (when `measurement` triangulates); `None` when it did not
/// grow. Views are dropped once the feature cannot grow any more.
pub(crate) fn grow<P: RobotPose>(
    track: &mut Track<P>,
    target: &mut dyn GrowthTarget,
    measurement: &dyn DynMeasurementModel,
    settings: &LifecycleSettings,
    skips: &mut Skips,
) -> Result<Option<Grown>> {
    let threshold = track.growth_threshold(settings.confirm_after);
    let old_dim = target.feature()?.mspace_dim();
    let mut priors = Vec::new();
    // No subspace is ready unless one was revealed often enough (or no sighting is needed):
    // the usual case, decided without listing the feature's options.
    if threshold == 0 || track.revealed.values().any(|&count| count >= threshold) {
        loop {
            let options = target.feature()?.growth_options();
            let Some(subspace) = ready_subspace(&options, &track.revealed, threshold) else {
                break;
            };
            track.revealed.remove(subspace.name);
            let growth = target.activate(subspace.name)?;
            priors.push(growth_prior(
                target.feature()?,
                &growth,
                settings.new_row_variance,
            ));
        }
    }
    let mut triangulated = false;
    if target.feature()?.mspace_dim() == old_dim
        && measurement.triangulates_dyn()
        && let Some(grown) = track.triangulated(target.feature()?, measurement, skips)?
    {
        let added = grown.mspace_dim() - old_dim;
        target.replace(grown)?;
        priors.push(DMatrix::identity(added, added) * settings.new_row_variance);
        triangulated = true;
    }
    let new_dim = target.feature()?.mspace_dim();
    if new_dim == old_dim {
        return Ok(None);
    }
    let added = new_dim - old_dim;
    Ok(Some(Grown {
        old_dim,
        added,
        prior: stack_priors(&priors, added)?,
        triangulated,
    }))
}

/// Drops the views of a feature that cannot grow any more.
pub(crate) fn drop_views_when_grown<P>(track: &mut Track<P>, feature: &dyn Feature) {
    if feature.growth_options().is_empty() {
        track.views.clear();
    }
}

/// The first growth option revealed at least `threshold` times (the confirmation rule).
fn ready_subspace(
    options: &[Subspace],
    revealed: &BTreeMap<&'static str, usize>,
    threshold: usize,
) -> Option<Subspace> {
    options
        .iter()
        .find(|s| revealed.get(s.name).copied().unwrap_or(0) >= threshold)
        .copied()
}

/// The prior covariance of the rows `growth` added: the feature's own
/// ([`Feature::growth_prior`]) when valid, else `default_variance` times the identity.
fn growth_prior(feature: &dyn Feature, growth: &Growth, default_variance: f64) -> DMatrix<f64> {
    let n = growth.rows.len();
    feature
        .growth_prior(growth)
        .filter(|p| p.shape() == (n, n) && p.iter().all(|v| v.is_finite()))
        .unwrap_or_else(|| DMatrix::identity(n, n) * default_variance)
}

/// Block-diagonal stack of priors that must fill exactly `added` rows.
fn stack_priors(priors: &[DMatrix<f64>], added: usize) -> Result<DMatrix<f64>> {
    let mut block = DMatrix::zeros(added, added);
    let mut at = 0;
    for prior in priors {
        let n = prior.nrows();
        if at + n > added {
            return Err(Error::DimensionMismatch {
                what: "growth priors".into(),
                expected: added,
                got: at + n,
            });
        }
        block.view_mut((at, at), (n, n)).copy_from(prior);
        at += n;
    }
    Ok(block)
}

/// The change of `feature` outside its M-space that `observation` (taken by a sensor at
/// `world_from_sensor`) asks for, if any (a wall's extent growing to cover what was measured).
pub(crate) fn extension_of(
    feature: &dyn Feature,
    observation: &Observation,
    world_from_sensor: &Pose3,
    skips: &mut Skips,
) -> Option<Extension> {
    match observation
        .measurement
        .extend_dyn(feature, world_from_sensor)
    {
        Ok(extension) => extension,
        Err(_) => {
            skips.count("extension: not computable");
            None
        }
    }
}

/// Largest `|B (x_new - x_old)|` accepted for a change outside the M-space.
pub(crate) const OUTSIDE_MSPACE_TOLERANCE: f64 = 1e-6;

/// Largest angle between two segments tested as duplicates, rad (the EKF's and FastSLAM's
/// duplicate merging).
pub(crate) const MERGE_ANGLE: f64 = 0.25;

/// Variance of the constraint that makes two duplicates one (as for corners: tight, not
/// perfect), in the coincidence residual's units squared.
pub(crate) const MERGE_CONSTRAINT_VARIANCE: f64 = 1e-4;
