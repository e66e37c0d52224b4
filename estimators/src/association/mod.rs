//! Data association, shared by the EKF and by each FastSLAM particle: which feature an
//! observation without a landmark id is of.
//!
//! An estimator lists, per observation, its candidates: the features the observation can
//! be of (same type, near, plausible) with the squared Mahalanobis
//! distance of the innovation under its own covariance; the shared rule then chooses by the
//! configured [`Association`] rule:
//! - **nearest neighbour**: each observation to its nearest candidate inside the
//!   `gate_probability` gate (several observations may pair with one feature: two pieces of
//!   one wall);
//! - **JCBB** (joint compatibility branch and bound, Neira & Tardos, IEEE T-RA 17(6), 2001):
//!   the largest set of one-to-one pairings with confirmed features whose **joint**
//!   innovation passes the gate, the estimator giving the joint distance of a hypothesis
//!   (the EKF from its full covariance; a particle as the sum of independent distances).
//!
//! An observation left unpaired starts a new feature only when it lies outside the
//! `new_feature_probability` gate of every candidate; between the two gates it is ambiguous
//! and dropped.

mod jcbb;

use std::collections::HashMap;

use serde::{Deserialize, Serialize};
use slam_core::{
    CoordBlock, Coordinates, DynMeasurementModel, Feature, MapToSensor, Pose3, Result, Skips,
    chi2_quantile,
};

/// How observations without landmark ids are matched to features.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Association {
    /// Each observation to the feature with the smallest Mahalanobis distance inside the gate.
    #[default]
    NearestNeighbour,
    /// Joint compatibility branch and bound (Neira & Tardos 2001): the largest set of
    /// pairings whose joint innovation passes the gate.
    Jcbb,
}

/// The association settings an estimator's parameters carry (the same keys in
/// [`crate::EkfParams`] and [`crate::FastSlamParams`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AssociationSettings {
    /// The rule.
    pub rule: Association,
    /// Probability of the chi-square gate an innovation must pass to pair.
    pub gate_probability: f64,
    /// An unmatched observation starts a new feature only outside this gate of every
    /// candidate.
    pub new_feature_probability: f64,
    /// Candidates lie within this distance of the feature the observation would start, m.
    pub margin: f64,
    /// Node limit of the JCBB search.
    pub jcbb_max_nodes: usize,
    /// An unmatched observation does not start a feature where the feature it would start
    /// overlaps an existing one of its kind within this distance (m; 0: no such rule): it
    /// is that feature seen with more error than the gates expect, and a second feature
    /// there would double it.
    pub new_feature_clearance: f64,
}

impl AssociationSettings {
    /// Range checks, as `(holds, what must hold)`, for the estimator's `validate`.
    pub(crate) fn checks(&self) -> Vec<(bool, &'static str)> {
        let probability = |p: f64| p > 0.0 && p < 1.0;
        vec![
            (
                probability(self.gate_probability),
                "gate_probability in (0, 1)",
            ),
            (
                probability(self.new_feature_probability)
                    && self.new_feature_probability >= self.gate_probability,
                "new_feature_probability in [gate_probability, 1)",
            ),
            (
                self.margin.is_finite() && self.margin >= 0.0,
                "association_margin >= 0",
            ),
            (self.jcbb_max_nodes >= 1, "jcbb_max_nodes >= 1"),
            (
                self.new_feature_clearance.is_finite() && self.new_feature_clearance >= 0.0,
                "new_feature_clearance >= 0",
            ),
        ]
    }
}

/// Chi-square gates by probability and degrees of freedom: those of the settings'
/// probabilities for 1 to 8 degrees of freedom are computed once, any other on demand.
#[derive(Clone, Debug, Default)]
pub(crate) struct Gates {
    known: HashMap<(usize, u64), f64>,
}

impl Gates {
    /// The gates of `probabilities` for 1 to 8 degrees of freedom.
    pub(crate) fn new(probabilities: &[f64]) -> Result<Self> {
        let mut known = HashMap::new();
        for &p in probabilities {
            for dof in 1..=8 {
                known.insert((dof, p.to_bits()), chi2_quantile(p, dof)?);
            }
        }
        Ok(Gates { known })
    }

    /// The `probability` quantile of chi-square with `dof` degrees of freedom.
    pub(crate) fn gate(&self, probability: f64, dof: usize) -> Result<f64> {
        match self.known.get(&(dof, probability.to_bits())) {
            Some(&g) => Ok(g),
            None => chi2_quantile(probability, dof),
        }
    }
}

/// One feature an observation might be of.
#[derive(Clone, Debug)]
pub(crate) struct Candidate<T> {
    /// The feature (an id or slot of the estimator's map).
    pub feature: usize,
    /// Squared Mahalanobis distance of the innovation, `eta^T S^-1 eta`.
    pub distance: f64,
    /// Dimension of the innovation.
    pub dof: usize,
    /// Whether the feature is tentative (not yet in the estimate).
    pub tentative: bool,
    /// What the estimator keeps of the candidate (its linearization).
    pub data: T,
}

/// What [`associate`] decided for one observation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Choice {
    /// Paired with candidate `k` of the observation's list.
    Pair(usize),
    /// Far from every candidate: it starts a new feature.
    New,
    /// Near a candidate but paired with none: dropped.
    Ambiguous,
}

/// A horizontal axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BoundingBox {
    lo: [f64; 2],
    hi: [f64; 2],
}

impl Default for BoundingBox {
    fn default() -> Self {
        BoundingBox {
            lo: [f64::INFINITY; 2],
            hi: [f64::NEG_INFINITY; 2],
        }
    }
}

impl BoundingBox {
    /// The box of the x, y values of every point block (scalars ignored).
    pub(crate) fn of(coordinates: &Coordinates) -> Self {
        let mut bbox = BoundingBox::default();
        for block in coordinates.blocks() {
            let (x, y) = match block {
                CoordBlock::Point3(p) => (p.x, p.y),
                CoordBlock::Point2(p) => (p.x, p.y),
                CoordBlock::Scalar(_) => continue,
            };
            bbox.lo = [bbox.lo[0].min(x), bbox.lo[1].min(y)];
            bbox.hi = [bbox.hi[0].max(x), bbox.hi[1].max(y)];
        }
        bbox
    }

    /// Grows the box to hold `other` as well.
    pub(crate) fn include(&mut self, other: &BoundingBox) {
        for k in 0..2 {
            self.lo[k] = self.lo[k].min(other.lo[k]);
            self.hi[k] = self.hi[k].max(other.hi[k]);
        }
    }

    /// Whether the boxes come within `margin` of each other.
    pub(crate) fn near(&self, other: &BoundingBox, margin: f64) -> bool {
        (0..2).all(|k| self.lo[k] - margin <= other.hi[k] && other.lo[k] - margin <= self.hi[k])
    }
}

/// The features `measurement` (taken from `world_from_sensor`) can be of, with their
/// coordinates in the sensor frame: the features of its type whose bounding box lies within
/// `margin` of the feature the measurement would start (when it can start one) and that the
/// model finds plausible. A feature that cannot be brought into the sensor frame is counted in
/// `skips` and left out.
pub(crate) fn candidate_features<'a, K>(
    features: impl Iterator<Item = (K, &'a dyn Feature)>,
    measurement: &dyn DynMeasurementModel,
    world_from_sensor: &Pose3,
    margin: f64,
    skips: &mut Skips,
) -> Vec<(K, &'a dyn Feature, Coordinates)> {
    let placed = placed_box(measurement, world_from_sensor);
    let to_sensor = match MapToSensor::new(world_from_sensor) {
        Ok(t) => t,
        Err(_) => {
            if matches!(placed, Placed::Failed) {
                skips.count(NOT_PLACED);
            }
            skips.count("association: sensor pose has no map-to-sensor transform");
            return Vec::new();
        }
    };
    candidate_features_in(features, measurement, &placed, &to_sensor, margin, skips)
}

/// Skip reason of an observation that places no feature (so no spatial filter for it).
const NOT_PLACED: &str = "association: no feature placed from the observation (no spatial filter)";

/// Where the feature an observation would start lies.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Placed {
    /// Within this box.
    At(BoundingBox),
    /// The observation starts no feature.
    Nowhere,
    /// The feature could not be placed.
    Failed,
}

/// Where the feature `measurement` would start from `world_from_sensor` lies.
pub(crate) fn placed_box(
    measurement: &dyn DynMeasurementModel,
    world_from_sensor: &Pose3,
) -> Placed {
    match measurement.initial_feature_dyn(world_from_sensor) {
        Ok(Some(feature)) => Placed::At(BoundingBox::of(feature.coordinates())),
        Ok(None) => Placed::Nowhere,
        Err(_) => Placed::Failed,
    }
}

/// [`candidate_features`] with the map-to-sensor transform and the [`placed_box`] of the
/// sensor pose made beforehand (a [`slam_core::SensorFrame`]'s, once per step).
pub(crate) fn candidate_features_in<'a, K>(
    features: impl Iterator<Item = (K, &'a dyn Feature)>,
    measurement: &dyn DynMeasurementModel,
    placed: &Placed,
    to_sensor: &MapToSensor,
    margin: f64,
    skips: &mut Skips,
) -> Vec<(K, &'a dyn Feature, Coordinates)> {
    // Room for every offered feature up to a few (the usual case), grown past that.
    let mut out = Vec::with_capacity(features.size_hint().1.unwrap_or(0).min(16));
    let near = Nearness {
        placed,
        to_sensor,
        margin,
    };
    visit_candidate_features(
        features,
        measurement,
        &near,
        skips,
        |key, feature, x_o, _| {
            out.push((key, feature, x_o));
        },
    );
    out
}

/// Where an observation's candidates are looked for: the [`placed_box`] of the feature it
/// would start, the map-to-sensor transform, and the margin around the box.
pub(crate) struct Nearness<'n> {
    pub placed: &'n Placed,
    pub to_sensor: &'n MapToSensor,
    pub margin: f64,
}

/// [`candidate_features_in`] without collecting: `visit` gets each candidate with its
/// coordinates in the sensor frame, and `skips` to count with.
pub(crate) fn visit_candidate_features<'a, K>(
    features: impl Iterator<Item = (K, &'a dyn Feature)>,
    measurement: &dyn DynMeasurementModel,
    nearness: &Nearness<'_>,
    skips: &mut Skips,
    mut visit: impl FnMut(K, &'a dyn Feature, Coordinates, &mut Skips),
) {
    let near = match nearness.placed {
        Placed::At(near) => Some(near),
        Placed::Nowhere => None,
        Placed::Failed => {
            skips.count(NOT_PLACED);
            None
        }
    };
    for (key, feature) in features {
        if !measurement.accepts(feature) {
            continue;
        }
        if let Some(near) = near
            && !BoundingBox::of(feature.coordinates()).near(near, nearness.margin)
        {
            continue;
        }
        let Ok(x_o) = nearness.to_sensor.transform(feature.coordinates()) else {
            skips.count("association: feature not transformable into the sensor frame");
            continue;
        };
        if measurement.plausible_dyn(feature, &x_o) {
            visit(key, feature, x_o, skips);
        }
    }
}

/// Largest angle between a new feature and an existing one for the clearance rule, rad.
const CLEARANCE_ANGLE: f64 = 0.2;

/// Whether the feature `measurement` would start (from `world_from_sensor`) overlaps one of
/// `features` within `clearance` ([`AssociationSettings::new_feature_clearance`],
/// [`slam_core::Shape::overlap_separation`]).
pub(crate) fn crowded<'a>(
    features: impl Iterator<Item = &'a dyn Feature>,
    measurement: &dyn DynMeasurementModel,
    world_from_sensor: &Pose3,
    clearance: f64,
) -> bool {
    if clearance <= 0.0 {
        return false;
    }
    let Some(shape) = measurement
        .initial_feature_dyn(world_from_sensor)
        .ok()
        .flatten()
        .and_then(|f| f.shape())
    else {
        return false;
    };
    features.filter(|f| measurement.accepts(*f)).any(|f| {
        f.shape().is_some_and(|other| {
            shape
                .overlap_separation(&other, CLEARANCE_ANGLE)
                .is_some_and(|d| d <= clearance)
        })
    })
}

/// Whether a candidate passes the individual gate for its innovation dimension.
fn in_gate<T>(candidate: &Candidate<T>, gate_probability: f64, gates: &Gates) -> Result<bool> {
    Ok(candidate.distance <= gates.gate(gate_probability, candidate.dof)?)
}

/// Chooses for every observation (one candidate list each, sorted by distance, nearest
/// first) by `settings.rule`; `joint(hypothesis)` gives the joint squared Mahalanobis
/// distance and dimension of a set of pairings for JCBB (`None` when it is not defined).
pub(crate) fn associate<T>(
    lists: &[Vec<Candidate<T>>],
    settings: &AssociationSettings,
    gates: &Gates,
    joint: impl Fn(&[&Candidate<T>]) -> Option<(f64, usize)>,
) -> Result<Vec<Choice>> {
    let paired: Vec<Option<usize>> = match settings.rule {
        Association::NearestNeighbour => nearest_neighbour(lists, settings, gates)?,
        Association::Jcbb => jcbb::jcbb(lists, settings, gates, joint)?,
    };
    lists
        .iter()
        .zip(paired)
        .map(|(list, pair)| match pair {
            Some(k) => Ok(Choice::Pair(k)),
            None => {
                let mut far_from_all = true;
                for c in list {
                    if c.distance <= gates.gate(settings.new_feature_probability, c.dof)? {
                        far_from_all = false;
                    }
                }
                Ok(if far_from_all {
                    Choice::New
                } else {
                    Choice::Ambiguous
                })
            }
        })
        .collect()
}

/// Each observation to its nearest candidate that passes the gate.
fn nearest_neighbour<T>(
    lists: &[Vec<Candidate<T>>],
    settings: &AssociationSettings,
    gates: &Gates,
) -> Result<Vec<Option<usize>>> {
    let mut chosen = Vec::with_capacity(lists.len());
    for list in lists {
        let mut pick = None;
        for (k, c) in list.iter().enumerate() {
            if in_gate(c, settings.gate_probability, gates)? {
                pick = Some(k);
                break;
            }
        }
        chosen.push(pick);
    }
    Ok(chosen)
}

/// Sorts candidates by distance, nearest first (stable: equal distances keep their order).
pub(crate) fn sort_by_distance<T>(list: &mut [Candidate<T>]) {
    list.sort_by(|a, b| a.distance.total_cmp(&b.distance));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidate(feature: usize, distance: f64, tentative: bool) -> Candidate<()> {
        Candidate {
            feature,
            distance,
            dof: 2,
            tentative,
            data: (),
        }
    }

    fn settings(rule: Association) -> AssociationSettings {
        AssociationSettings {
            rule,
            gate_probability: 0.99,
            new_feature_probability: 0.9999,
            margin: 3.0,
            jcbb_max_nodes: 1000,
            new_feature_clearance: 0.0,
        }
    }

    fn gates() -> Gates {
        Gates::new(&[0.99, 0.9999]).unwrap()
    }

    /// Independent innovations: the joint distance is the sum.
    fn sum(pairings: &[&Candidate<()>]) -> Option<(f64, usize)> {
        Some((
            pairings.iter().map(|c| c.distance).sum(),
            pairings.iter().map(|c| c.dof).sum(),
        ))
    }

    #[test]
    fn nearest_neighbour_pairs_in_the_gate_and_splits_the_rest_by_the_new_feature_gate() {
        // chi2(2): 0.99 gate 9.21, 0.9999 gate 18.42.
        let lists = vec![
            vec![candidate(0, 1.0, false), candidate(1, 4.0, false)],
            vec![candidate(0, 12.0, false)],
            vec![candidate(1, 30.0, false)],
            vec![],
        ];
        let choices = associate(
            &lists,
            &settings(Association::NearestNeighbour),
            &gates(),
            sum,
        )
        .unwrap();
        assert_eq!(
            choices,
            vec![Choice::Pair(0), Choice::Ambiguous, Choice::New, Choice::New]
        );
    }

    #[test]
    fn jcbb_pairs_one_to_one_and_respects_the_joint_gate() {
        // Both observations are nearest to feature 0; JCBB gives each its own feature.
        let lists = vec![
            vec![candidate(0, 0.5, false), candidate(1, 1.0, false)],
            vec![candidate(0, 0.4, false), candidate(1, 2.0, false)],
        ];
        let nn = associate(
            &lists,
            &settings(Association::NearestNeighbour),
            &gates(),
            sum,
        )
        .unwrap();
        assert_eq!(nn, vec![Choice::Pair(0), Choice::Pair(0)]);
        let jcbb = associate(&lists, &settings(Association::Jcbb), &gates(), sum).unwrap();
        let features: Vec<usize> = jcbb
            .iter()
            .zip(&lists)
            .map(|(c, list)| match c {
                Choice::Pair(k) => list[*k].feature,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(features.len(), 2);
        assert_ne!(features[0], features[1]);
        // Individually compatible pairings whose sum fails the joint gate (chi2(4) 0.99:
        // 13.28) leave one observation unpaired.
        let lists = vec![
            vec![candidate(0, 8.0, false)],
            vec![candidate(1, 8.0, false)],
        ];
        let jcbb = associate(&lists, &settings(Association::Jcbb), &gates(), sum).unwrap();
        assert_eq!(
            jcbb.iter().filter(|c| matches!(c, Choice::Pair(_))).count(),
            1,
            "{jcbb:?}"
        );
    }

    #[test]
    fn jcbb_leaves_tentative_features_to_the_nearest_neighbour() {
        let lists = vec![vec![candidate(3, 1.0, true)]];
        let jcbb = associate(&lists, &settings(Association::Jcbb), &gates(), sum).unwrap();
        assert_eq!(jcbb, vec![Choice::Pair(0)]);
    }

    /// A new wall is refused where it would lie on an existing one (within the clearance,
    /// overlapping, parallel), and allowed beside it, beyond it or with the rule off.
    #[test]
    fn a_new_wall_on_top_of_an_existing_one_is_crowded() {
        use slam_core::Pose3;
        use slam_core::nalgebra::{Matrix2, Vector2};
        use slam_features::Wall;
        use slam_sensors::models::WallObservation;
        let existing = Wall::seen_from(
            Vector2::new(0.0, 2.0),
            Vector2::new(4.0, 2.0),
            Vector2::zeros(),
        )
        .unwrap();
        let sighting = |a: (f64, f64), b: (f64, f64)| {
            WallObservation::from_segment(
                Vector2::new(a.0, a.1),
                Vector2::new(b.0, b.1),
                Matrix2::new(1e-4, 0.0, 0.0, 4e-4),
                [false, false],
                [0.05, 0.05],
            )
            .unwrap()
        };
        let crowded_at = |m: &WallObservation, clearance: f64| {
            let features: [&dyn Feature; 1] = [&existing];
            crowded(features.into_iter(), m, &Pose3::identity(), clearance)
        };
        let on_top = sighting((1.0, 2.1), (3.0, 2.1));
        assert!(crowded_at(&on_top, 0.15));
        assert!(!crowded_at(&on_top, 0.05), "farther than the clearance");
        assert!(!crowded_at(&on_top, 0.0), "the rule is off");
        assert!(
            !crowded_at(&sighting((1.0, 2.5), (3.0, 2.5)), 0.15),
            "beside it"
        );
        assert!(
            !crowded_at(&sighting((4.5, 2.0), (6.0, 2.0)), 0.15),
            "beyond its end"
        );
        assert!(
            !crowded_at(&sighting((2.0, 0.5), (2.0, 1.9)), 0.15),
            "across it"
        );
    }
}
