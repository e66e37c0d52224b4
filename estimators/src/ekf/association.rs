//! The EKF's side of data association: the candidates of an observation, linearized against
//! the full state, and the joint distance of a JCBB hypothesis from the full covariance. The
//! rules are the shared ones ([`crate::association`]).

use slam_core::{FeatureId, Observation, Result, RobotPose};

use super::jacobians::stack;
use super::{Decision, Ekf, Pairing};
use crate::association::{
    Candidate, Choice, associate, candidate_features, crowded, sort_by_distance,
};

impl<P: RobotPose> Ekf<P> {
    /// The candidate features of an observation with their Mahalanobis distances, nearest
    /// first.
    fn candidates(&mut self, observation: &Observation) -> Vec<Candidate<Pairing>> {
        let world_from_sensor = self
            .frames
            .world_from_sensor(&self.pose, &observation.robot_from_sensor);
        let mut skips = std::mem::take(&mut self.skips);
        let nearby = candidate_features(
            self.map.iter(),
            observation.measurement.as_ref(),
            &world_from_sensor,
            self.params.association_margin,
            &mut skips,
        );
        let mut out = Vec::new();
        let mut lin = std::mem::take(&mut self.linearization);
        for (id, _, _) in nearby {
            let spare = self.spare_pairings.pop().unwrap_or_else(Pairing::empty);
            let Ok(mut pairing) = self.linearize_into(observation, id, &mut lin, spare) else {
                skips.count("association: linearization failed");
                continue;
            };
            let tentative = !self.is_confirmed(id);
            let Some(distance) = self.mahalanobis(&pairing, tentative) else {
                skips.count("association: singular innovation covariance");
                self.spare_pairings.push(pairing);
                continue;
            };
            if !tentative {
                pairing.nis = Some(distance);
            }
            if distance.is_finite() {
                out.push(Candidate {
                    feature: id.0,
                    distance,
                    dof: pairing.eta.len(),
                    tentative,
                    data: pairing,
                });
            } else {
                skips.count("association: non-finite Mahalanobis distance");
                self.spare_pairings.push(pairing);
            }
        }
        self.linearization = lin;
        self.skips = skips;
        sort_by_distance(&mut out);
        out
    }

    /// Decides, for every observation, whether it pairs, starts a feature or is dropped:
    /// known landmark ids directly, the others by the configured rule.
    pub(super) fn associate(&mut self, observations: &[Observation]) -> Result<Vec<Decision>> {
        let mut decisions: Vec<Option<Decision>> = (0..observations.len()).map(|_| None).collect();
        let mut open = Vec::new();
        for (index, observation) in observations.iter().enumerate() {
            match observation.landmark_id {
                Some(id) => {
                    decisions[index] = Some(match self.ids.get(&id) {
                        Some(&feature) => match self.linearize(observation, feature) {
                            Ok(pairing) => self.validated(pairing, feature)?,
                            Err(_) => {
                                self.skips.count("association: linearization failed");
                                Decision::Reject
                            }
                        },
                        None => Decision::New,
                    });
                }
                None => open.push(index),
            }
        }
        let lists: Vec<Vec<Candidate<Pairing>>> = open
            .iter()
            .map(|&index| self.candidates(&observations[index]))
            .collect();
        let settings = self.params.association_settings();
        let choices = associate(&lists, &settings, &self.gates, |hypothesis| {
            let pairings: Vec<&Pairing> = hypothesis.iter().map(|c| &c.data).collect();
            self.joint_distance(&pairings)
        })?;
        for ((index, list), choice) in open.into_iter().zip(lists).zip(choices) {
            let chosen = match choice {
                Choice::Pair(k) => Some(k),
                _ => None,
            };
            let mut paired = None;
            for (k, candidate) in list.into_iter().enumerate() {
                if Some(k) == chosen {
                    paired = Some(candidate.data);
                } else {
                    self.recycle(candidate.data);
                }
            }
            decisions[index] = Some(match choice {
                Choice::Pair(_) => paired.map_or(Decision::Reject, Decision::Pair),
                Choice::New if self.crowded(&observations[index]) => {
                    self.skips
                        .count("association: a new feature would double an existing one");
                    Decision::Reject
                }
                Choice::New => Decision::New,
                Choice::Ambiguous => Decision::Reject,
            });
        }
        Ok(decisions
            .into_iter()
            .map(|d| d.unwrap_or(Decision::Reject))
            .collect())
    }

    /// A known landmark's pairing if its innovation passes the validation gate
    /// (`known_id_gate_probability`), else a rejection.
    fn validated(&mut self, mut pairing: Pairing, feature: FeatureId) -> Result<Decision> {
        let probability = self.params.known_id_gate_probability;
        if probability >= 1.0 {
            return Ok(Decision::Pair(pairing));
        }
        let gate = self.gates.gate(probability, pairing.eta.len())?;
        let tentative = !self.is_confirmed(feature);
        let distance = self.mahalanobis(&pairing, tentative);
        if !tentative {
            pairing.nis = distance;
        }
        if distance.is_some_and(|d| d <= gate) {
            Ok(Decision::Pair(pairing))
        } else {
            self.skips
                .count("association: a known landmark outside its validation gate");
            self.recycle(pairing);
            Ok(Decision::Reject)
        }
    }

    /// Whether the feature `observation` would start overlaps an existing one within the
    /// clearance.
    fn crowded(&self, observation: &Observation) -> bool {
        let world_from_sensor = self
            .frames
            .world_from_sensor(&self.pose, &observation.robot_from_sensor);
        crowded(
            self.map.iter().map(|(_, f)| f),
            observation.measurement.as_ref(),
            &world_from_sensor,
            self.params.new_feature_clearance,
        )
    }

    /// Joint Mahalanobis distance and dimension of a set of pairings (for JCBB).
    fn joint_distance(&self, pairings: &[&Pairing]) -> Option<(f64, usize)> {
        let (indices, h, r, eta) = stack(pairings);
        let c = self.cov.gather(&indices, &indices);
        let s = &h * c * h.transpose() + r;
        let s_inv = s.try_inverse()?;
        Some(((eta.transpose() * s_inv * &eta)[(0, 0)], eta.len()))
    }
}
