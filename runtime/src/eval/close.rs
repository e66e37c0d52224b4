//! Landmarks mapped twice: pairs of confirmed point-like features (poles, points) that are
//! statistically the same, by the Mahalanobis distance of their difference.
//!
//! The difference `r` is the features' coincidence residual
//! ([`slam_core::Feature::coincidence`], the centres' difference for poles and points) and its
//! covariance is `J_a C_aa J_a^T + J_b C_bb J_b^T - J_a C_ab J_b^T - J_b C_ba J_a^T` with
//! `J = d_r/d_coordinates B~`: the joint covariance, which a SLAM map's strongly correlated
//! features need (their marginal covariances hold the uncertainty of the whole map's place
//! and make distinct neighbours look alike). An estimator without cross-covariances (a
//! particle filter: features independent given the path) gives `C_ab = 0`.

use serde::Serialize;
use slam_core::nalgebra::DMatrix;
use slam_core::{Estimator, Feature, FeatureId, Pose2, RowOwner};

/// The feature kinds compared.
const POINT_LIKE: [&str; 2] = ["pole", "point"];

/// Pairs of confirmed poles or points within a Mahalanobis distance of each other.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CloseLandmarks {
    /// The distance, in standard deviations.
    pub distance: f64,
    /// Confirmed poles and points compared.
    pub features: usize,
    /// Pairs within `distance`.
    pub pairs: usize,
    /// `"joint"` (cross-covariances used) or `"marginal"` (the estimator has none).
    pub covariance: &'static str,
}

/// One feature's part of the test: its rows' covariance through `B~`.
struct Entry<'a> {
    id: FeatureId,
    feature: &'a dyn Feature,
    dual: DMatrix<f64>,
    cov: DMatrix<f64>,
}

/// The pairs of confirmed poles and points (of one kind) whose difference lies within
/// `distance` standard deviations; `None` when the map has fewer than two.
pub fn close_landmarks(estimator: &dyn Estimator<Pose2>, distance: f64) -> Option<CloseLandmarks> {
    let map = estimator.map();
    let entries: Vec<Entry> = map
        .iter()
        .filter(|(id, f)| {
            POINT_LIKE.contains(&f.kind())
                && map.links(*id).is_ok_and(|l| l.iter().all(Option::is_none))
        })
        .filter_map(|(id, feature)| {
            let cov = estimator.row_covariance(RowOwner::Feature(id))?;
            Some(Entry {
                id,
                feature,
                dual: feature.dual().ok()?,
                cov,
            })
        })
        .collect();
    if entries.len() < 2 {
        return None;
    }
    let limit = distance * distance;
    let mut pairs = 0;
    let joint = estimator
        .cross_covariance(
            RowOwner::Feature(entries[0].id),
            RowOwner::Feature(entries[1].id),
        )
        .is_some();
    for (i, a) in entries.iter().enumerate() {
        for b in &entries[i + 1..] {
            if a.feature.kind() != b.feature.kind() {
                continue;
            }
            let Ok(Some(c)) = a.feature.coincidence(b.feature) else {
                continue;
            };
            let ja = &c.d_self * &a.dual;
            let jb = &c.d_other * &b.dual;
            let marginal = &ja * &a.cov * ja.transpose() + &jb * &b.cov * jb.transpose();
            // The joint covariance is at most twice the marginal sum: a pair outside the
            // distance under that bound is outside it under the joint covariance too.
            let d2_bound = (&marginal * 2.0)
                .try_inverse()
                .map(|inv| (c.residual.transpose() * inv * &c.residual)[(0, 0)]);
            if d2_bound.is_some_and(|d2| d2 > limit) {
                continue;
            }
            let cab = joint
                .then(|| {
                    estimator.cross_covariance(RowOwner::Feature(a.id), RowOwner::Feature(b.id))
                })
                .flatten();
            let s = match cab {
                Some(cab) => {
                    let cross = &ja * cab * jb.transpose();
                    &marginal + &cross + cross.transpose()
                }
                None => marginal,
            };
            let d2 = s
                .try_inverse()
                .map(|inv| (c.residual.transpose() * inv * &c.residual)[(0, 0)]);
            if d2.is_some_and(|d2| d2 <= limit) {
                pairs += 1;
            }
        }
    }
    Some(CloseLandmarks {
        distance,
        features: entries.len(),
        pairs,
        covariance: if joint { "joint" } else { "marginal" },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::nalgebra::DMatrix;
    use slam_core::{Observation, Pose3};
    use slam_estimators::{Ekf, EkfParams};
    use slam_sensors::models::PoleObservation;
    use std::sync::Arc;

    /// Trees at 10 m and the given bearings, seen in one step from a robot whose pose has
    /// variance `pose_variance`; both confirmed at once, no merging.
    fn map_of(bearings: [f64; 2], pose_variance: f64) -> Ekf<Pose2> {
        let params = EkfParams {
            confirm_after: 1,
            merge_duplicates: false,
            ..EkfParams::default()
        };
        let cov = DMatrix::identity(3, 3) * pose_variance;
        let mut ekf = Ekf::new(Pose2::identity(), cov, params).unwrap();
        let observations: Vec<Observation> = bearings
            .iter()
            .map(|&b| Observation {
                robot_from_sensor: Pose3::identity(),
                measurement: Arc::new(
                    PoleObservation::new(10.0, b, 0.2, [0.05, 0.005, 0.05]).unwrap(),
                ),
                landmark_id: None,
            })
            .collect();
        ekf.update(&observations).unwrap();
        ekf
    }

    /// Two trees 2 m apart, placed from one uncertain pose: each is uncertain by the pose's
    /// metre, but their difference is known to centimetres. The joint test keeps them apart;
    /// with the cross-covariance left out (what a marginal test does) they would be one.
    #[test]
    fn trees_placed_from_one_uncertain_pose_are_apart_by_their_joint_covariance() {
        let ekf = map_of([0.0, 0.2], 1.0);
        let close = close_landmarks(&ekf, 3.0).unwrap();
        assert_eq!(
            close,
            CloseLandmarks {
                distance: 3.0,
                features: 2,
                pairs: 0,
                covariance: "joint"
            }
        );
        let marginal: Vec<DMatrix<f64>> = ekf
            .map()
            .iter()
            .map(|(id, _)| ekf.row_covariance(RowOwner::Feature(id)).unwrap())
            .collect();
        let centres: Vec<_> = ekf.map().iter().map(|(_, f)| f.shape().unwrap()).collect();
        let (slam_core::Shape::Pole { centre: a, .. }, slam_core::Shape::Pole { centre: b, .. }) =
            (&centres[0], &centres[1])
        else {
            panic!("not poles");
        };
        let sum = (marginal[0].clone() + &marginal[1])
            .view((1, 1), (2, 2))
            .into_owned();
        let d = a - b;
        let d2_marginal = (d.transpose() * sum.try_inverse().unwrap() * d)[(0, 0)];
        assert!(d2_marginal < 9.0, "{d2_marginal}");
    }

    /// The same two trees 5 cm apart are one tree mapped twice.
    #[test]
    fn trees_within_their_noise_of_each_other_are_a_pair() {
        let ekf = map_of([0.0, 0.005], 1e-6);
        assert_eq!(close_landmarks(&ekf, 3.0).unwrap().pairs, 1);
    }
}
