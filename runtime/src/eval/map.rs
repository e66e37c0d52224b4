//! Map error and map statistics from the feature trait alone ([`Feature::shape`]), so that
//! a user's feature type is scored like a built-in one.

use std::collections::BTreeMap;

use serde::Serialize;
use slam_core::nalgebra::{DMatrix, DVector, Matrix2, Vector2, Vector3};
use slam_core::{Estimator, Feature, FeatureId, FeatureMap, Pose2, RowOwner, Shape};
use slam_sensors::KnownLandmark;

use super::trajectory::{Alignment, umeyama};
use crate::error::Result;

/// Map errors, overall and by feature type.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MapError {
    /// Root mean square over every confirmed feature with a true counterpart, m.
    pub rms_m: f64,
    /// Median of the same errors, m (robust to a few gross ones).
    pub median_m: f64,
    /// Number of features compared.
    pub count: usize,
    /// Error of each landmark by its id, when landmarks are matched by id, m.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub by_landmark: BTreeMap<u64, f64>,
    /// The same by feature type: `(count, rms)`.
    pub by_type: BTreeMap<String, (usize, f64)>,
    /// How the features were compared with the truth.
    pub method: String,
}

/// Whether feature `id` has rows in the estimator's state (it is not tentative).
pub fn confirmed(estimator: &dyn Estimator<Pose2>, id: FeatureId) -> bool {
    estimator
        .map()
        .row_owners(id)
        .is_ok_and(|owners| !owners.is_empty())
}

/// Map error of the confirmed features against a true map given as shapes (a simulated
/// world's [`slam_sensors::sim::TrueMap::shapes`]): each feature's [`Feature::shape`], moved
/// by `alignment` when given, against the nearest true shape of its kind
/// ([`Shape::error_against`]).
pub fn map_error_against_truth(
    estimator: &dyn Estimator<Pose2>,
    truth: &[Shape],
    alignment: Option<&Alignment>,
) -> MapError {
    let place = |p: Vector3<f64>| alignment.map_or(p, |a| a.apply(&p));
    let mut errors: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for (id, feature) in estimator.map().iter() {
        if !confirmed(estimator, id) {
            continue;
        }
        let Some(shape) = feature.shape() else {
            continue;
        };
        if let Some(error) = shape.placed(place).error_against(truth) {
            errors
                .entry(feature.kind().to_string())
                .or_default()
                .push(error);
        }
    }
    let frame = if alignment.is_some() {
        "; the map is first moved by the trajectory's ATE alignment"
    } else {
        ""
    };
    summarize(
        errors,
        &format!(
            "walls and ceiling lines: RMS distance of their ends to the closest true line \
             within 15 degrees (ceiling lines: with the height error); poles and lamps: \
             distance to the nearest true one{frame}"
        ),
    )
}

/// Map error against known landmarks matched by landmark id (rb2d, MR.CLAM), each feature at
/// its shape's [`Shape::anchor`]. With `align`, the estimated positions are first aligned onto
/// the known ones by the least-squares rigid transform (the map frame of a run is its first
/// pose, not the survey frame).
pub fn map_error_against_landmarks(
    estimator: &dyn Estimator<Pose2>,
    landmarks: &[KnownLandmark],
    align: bool,
) -> Result<MapError> {
    let known: BTreeMap<u64, Vector2<f64>> = landmarks.iter().map(|l| (l.id, l.position)).collect();
    let mut pairs = Vec::new();
    for (id, feature) in estimator.map().iter() {
        if !confirmed(estimator, id) {
            continue;
        }
        let Some(landmark) = estimator.landmark_id(id) else {
            continue;
        };
        let (Some(truth), Some(shape)) = (known.get(&landmark), feature.shape()) else {
            continue;
        };
        pairs.push((feature.kind().to_string(), shape.anchor(), *truth, landmark));
    }
    let mut method = "known landmarks matched by id: distance of each estimate to its \
                      surveyed position"
        .to_string();
    if align && pairs.len() >= 3 {
        let from: Vec<_> = pairs
            .iter()
            .map(|(_, e, _, _)| Vector3::new(e.x, e.y, 0.0))
            .collect();
        let to: Vec<_> = pairs
            .iter()
            .map(|(_, _, t, _)| Vector3::new(t.x, t.y, 0.0))
            .collect();
        let alignment = umeyama(&from, &to, false)?;
        for ((_, estimate, _, _), p) in pairs.iter_mut().zip(&from) {
            *estimate = alignment.apply(p).xy();
        }
        method.push_str(", after the least-squares rigid alignment of the estimated landmarks");
    }
    let mut errors: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut by_landmark = BTreeMap::new();
    for (kind, estimate, truth, landmark) in pairs {
        let error = (estimate - truth).norm();
        errors.entry(kind).or_default().push(error);
        by_landmark.insert(landmark, error);
    }
    Ok(MapError {
        by_landmark,
        ..summarize(errors, &method)
    })
}

fn summarize(errors: BTreeMap<String, Vec<f64>>, method: &str) -> MapError {
    let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let mut all: Vec<f64> = errors.values().flatten().copied().collect();
    all.sort_by(f64::total_cmp);
    let median = match all.len() {
        0 => 0.0,
        n if n % 2 == 1 => all[n / 2],
        n => 0.5 * (all[n / 2 - 1] + all[n / 2]),
    };
    MapError {
        rms_m: rms(&all),
        median_m: median,
        count: all.len(),
        by_landmark: BTreeMap::new(),
        by_type: errors
            .iter()
            .map(|(k, v)| (k.clone(), (v.len(), rms(v))))
            .collect(),
        method: method.to_string(),
    }
}

/// The coordinates a feature holds in shared blocks (each counts as M-space rows of the
/// feature: a wall with two shared corners has dimension 4).
pub fn shared_dims(map: &FeatureMap, id: FeatureId) -> usize {
    let Ok(feature) = map.get(id) else { return 0 };
    map.links(id).map_or(0, |links| {
        links
            .iter()
            .zip(feature.coordinates().blocks())
            .filter(|(link, _)| link.is_some())
            .map(|(_, block)| block.dim())
            .sum()
    })
}

/// Features by type and M-space dimension, shared blocks included (tentative ones under
/// dimension 0).
pub fn feature_counts(
    estimator: &dyn Estimator<Pose2>,
) -> BTreeMap<String, BTreeMap<usize, usize>> {
    let mut counts: BTreeMap<String, BTreeMap<usize, usize>> = BTreeMap::new();
    for (id, feature) in estimator.map().iter() {
        let dim = if confirmed(estimator, id) {
            feature.mspace_dim() + shared_dims(estimator.map(), id)
        } else {
            0
        };
        *counts
            .entry(feature.kind().to_string())
            .or_default()
            .entry(dim)
            .or_default() += 1;
    }
    counts
}

/// The covariance of a feature's coordinates from its own rows, `B~ C_pp B~^T`, plus the
/// identity rows of its shared blocks (cross terms between them are left out); `None` when
/// the estimator does not have it.
pub fn coordinate_covariance(
    estimator: &dyn Estimator<Pose2>,
    id: FeatureId,
) -> Option<DMatrix<f64>> {
    let map = estimator.map();
    let feature: &dyn Feature = map.get(id).ok()?;
    let coordinates = feature.coordinates();
    let n = coordinates.dim();
    let mut c = DMatrix::zeros(n, n);
    if feature.mspace_dim() > 0 {
        let own = estimator.row_covariance(RowOwner::Feature(id))?;
        let dual = feature.dual().ok()?;
        c += &dual * own * dual.transpose();
    }
    for (k, link) in map.links(id).ok()?.iter().enumerate() {
        if let Some(shared) = link {
            let block = estimator.row_covariance(RowOwner::Shared(*shared))?;
            let offset = coordinates.offset(k);
            c.view_mut((offset, offset), block.shape())
                .copy_from(&block);
        }
    }
    Some(c)
}

/// The covariance of a feature's anchor position ([`slam_core::Shape::anchor`]: a point's or
/// pole's position) in the world frame: the covariance of its own M-space rows carried through
/// the derivative of the anchor (central differences). `None` where the estimator keeps no
/// covariance, the feature has no shape, or some of its rows are shared with other features.
pub fn anchor_covariance(estimator: &dyn Estimator<Pose2>, id: FeatureId) -> Option<Matrix2<f64>> {
    let feature = estimator.map().get(id).ok()?;
    let covariance = estimator.row_covariance(RowOwner::Feature(id))?;
    let dim = feature.mspace_dim();
    if dim == 0 || covariance.shape() != (dim, dim) {
        return None;
    }
    let step = 1e-6;
    let anchor_after = |k: usize, sign: f64| {
        let mut moved = dyn_clone::clone_box(feature);
        let mut dx = DVector::zeros(dim);
        dx[k] = sign * step;
        moved.apply_perturbation(&dx).ok()?;
        moved.shape().map(|s| s.anchor())
    };
    let mut jacobian = DMatrix::zeros(2, dim);
    for k in 0..dim {
        let derivative = (anchor_after(k, 1.0)? - anchor_after(k, -1.0)?) / (2.0 * step);
        jacobian[(0, k)] = derivative.x;
        jacobian[(1, k)] = derivative.y;
    }
    let c = &jacobian * covariance * jacobian.transpose();
    let c = Matrix2::new(c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)]);
    c.iter().all(|v| v.is_finite()).then_some(c)
}
