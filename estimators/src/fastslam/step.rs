//! One particle's update step: association against its own map, then, observation by
//! observation, pairing (weight, EKF update, lifecycle) or a new feature, then pruning.

use std::rc::Rc;
use std::sync::Arc;

use rand_chacha::ChaCha8Rng;
use slam_core::nalgebra::{DMatrix, DVector};
use slam_core::{
    DynMeasurementModel, Feature, MapToSensor, Observation, OwnLinearization, Result, RobotPose,
    SensorFrame, UpdateReport,
};

use super::landmark::{Landmark, LandmarkMap, UpdateBuffers};
use super::{FastSlamParams, Proposal};
use crate::association::{
    BoundingBox, Candidate, Choice, Gates, Nearness, Placed, associate, crowded, placed_box,
    sort_by_distance, visit_candidate_features,
};
use crate::lifecycle::{Sighting, Track};
use crate::particles::{Particle, log_normal};

/// What a particle decided for one observation.
#[derive(Debug)]
pub(super) enum Decision {
    /// Paired with the feature in this slot.
    Pair(usize),
    /// Starts a new feature.
    New,
    /// Dropped, with the log-likelihood of its best candidate (if any).
    Reject(Option<f64>),
}

/// A candidate's linearization and likelihood (`(ln N, eta^T S^-1 eta, dof)`), kept from the
/// association for its pairing.
#[derive(Debug)]
struct Scored {
    lin: OwnLinearization,
    likelihood: (f64, f64, usize),
}

/// The association's linearization of the pair it chose for an observation.
#[derive(Debug)]
struct Chosen {
    slot: usize,
    scored: Scored,
}

/// Gates and the step's shared data, the same for every particle.
pub(super) struct StepContext<'a> {
    pub params: &'a FastSlamParams,
    pub step: usize,
    pub gates: &'a Gates,
    /// The measurements that triangulate, shared as views.
    pub shared: Vec<Option<Arc<dyn DynMeasurementModel>>>,
}

impl<'a> StepContext<'a> {
    pub(super) fn new(
        params: &'a FastSlamParams,
        step: usize,
        gates: &'a Gates,
        observations: &[Observation],
    ) -> Self {
        StepContext {
            params,
            step,
            gates,
            shared: shared_views(observations),
        }
    }

    /// `(pairing gate, new-feature gate)` for an innovation of dimension `dof`.
    pub(super) fn gates(&self, dof: usize) -> Result<(f64, f64)> {
        Ok((
            self.gates.gate(self.params.gate_probability, dof)?,
            self.gates.gate(self.params.new_feature_probability, dof)?,
        ))
    }
}

/// The shared measurement of each observation that triangulates, kept as a view by every
/// particle that sees it.
fn shared_views(
    observations: &[Observation],
) -> Vec<Option<Arc<dyn slam_core::DynMeasurementModel>>> {
    observations
        .iter()
        .map(|o| {
            o.measurement
                .triangulates_dyn()
                .then(|| Arc::clone(&o.measurement))
        })
        .collect()
}

/// Storage one worker reuses from particle to particle: linearizations no longer needed
/// (a candidate not chosen, a pairing done), so that the next are written without
/// allocating.
#[derive(Default)]
pub(super) struct Workspace {
    spare_linearizations: Vec<OwnLinearization>,
    /// Emptied candidate lists.
    spare_lists: Vec<Vec<Candidate<Scored>>>,
    /// A landmark update's state change and covariance.
    update: UpdateBuffers,
}

impl Workspace {
    /// An empty candidate list: a spare one, or a new one.
    fn candidate_list(&mut self) -> Vec<Candidate<Scored>> {
        self.spare_lists.pop().unwrap_or_default()
    }

    /// Keeps the linearizations of `list` and the list itself for later use.
    fn recycle_list(&mut self, mut list: Vec<Candidate<Scored>>) {
        for candidate in list.drain(..) {
            self.recycle(candidate.data.lin);
        }
        self.spare_lists.push(list);
    }

    /// A linearization buffer: a spare one, or a new one.
    fn linearization(&mut self) -> OwnLinearization {
        self.spare_linearizations.pop().unwrap_or_default()
    }

    /// Keeps `lin`'s storage for a later linearization.
    fn recycle(&mut self, lin: OwnLinearization) {
        self.spare_linearizations.push(lin);
    }
}

/// The per-particle work of one update step.
pub(super) struct ParticleStep<'a, 'c, P: RobotPose> {
    pub context: &'c StepContext<'a>,
    pub particle: &'c mut Particle<P, LandmarkMap<P>>,
    pub report: UpdateReport,
    pub log_likelihood: f64,
    /// Observations whose likelihood the proposal already counted.
    pub weighted: Vec<bool>,
    /// The particle's random stream for this step (FastSLAM 2.0).
    pub rng: ChaCha8Rng,
    /// Each observation's sensor frame at `frames_pose`, made for the association (shared by
    /// the observations of one mounting).
    frames: Vec<Option<Rc<SensorFrame>>>,
    /// The particle's pose when the frames were made.
    frames_pose: Option<P>,
    /// Each observation's chosen pair with its linearization at `frames_pose`.
    chosen: Vec<Option<Chosen>>,
    /// Slots the step's pairings changed (their association linearizations are stale).
    touched: Vec<usize>,
    /// The worker's reusable storage.
    workspace: Workspace,
}

impl<'a, 'c, P: RobotPose> ParticleStep<'a, 'c, P> {
    pub(super) fn new(
        context: &'c StepContext<'a>,
        particle: &'c mut Particle<P, LandmarkMap<P>>,
        rng: ChaCha8Rng,
        workspace: Workspace,
    ) -> Self {
        ParticleStep {
            context,
            particle,
            report: UpdateReport::default(),
            log_likelihood: 0.0,
            weighted: Vec::new(),
            rng,
            frames: Vec::new(),
            frames_pose: None,
            chosen: Vec::new(),
            touched: Vec::new(),
            workspace,
        }
    }

    /// The sensor frame of observation `index` at the particle's pose: the association's
    /// (taken: each observation is paired once) while the pose has not moved since, else a
    /// new one.
    fn frame(&mut self, index: usize, observation: &Observation) -> Option<Rc<SensorFrame>> {
        let made = self.frames.get_mut(index).and_then(Option::take);
        match made {
            Some(frame) if self.frames_pose == Some(self.particle.pose) => Some(frame),
            _ => SensorFrame::new(&self.particle.pose, &observation.robot_from_sensor)
                .ok()
                .map(Rc::new),
        }
    }

    /// The step's log-likelihood and report, and the workspace for the next particle.
    pub(super) fn finish(self) -> (f64, UpdateReport, Workspace) {
        (self.log_likelihood, self.report, self.workspace)
    }

    pub(super) fn run(&mut self, observations: &[Observation]) -> Result<()> {
        self.weighted = vec![false; observations.len()];
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

    /// Decides every observation against the particle's map before changing it: known
    /// landmark ids directly, the others by the shared association rule.
    fn associate(&mut self, observations: &[Observation]) -> Result<Vec<Decision>> {
        let mut decisions: Vec<Option<Decision>> = Vec::with_capacity(observations.len());
        self.chosen = (0..observations.len()).map(|_| None).collect();
        // Sized once for the step: each observation pairs, opens or reports at most once.
        self.touched = Vec::with_capacity(observations.len());
        self.report.nis.reserve(observations.len());
        let mut open = Vec::with_capacity(observations.len());
        let mut lists = Vec::with_capacity(observations.len());
        let particle: &Particle<P, LandmarkMap<P>> = self.particle;
        self.frames = frames_of(&particle.pose, observations);
        self.frames_pose = Some(particle.pose);
        let frames = &self.frames;
        let (nearby, placed) = near_any(particle, self.context, observations, frames);
        for (index, observation) in observations.iter().enumerate() {
            match observation.landmark_id {
                Some(id) => decisions.push(Some(match particle.map.ids.get(&id) {
                    Some(&slot) => Decision::Pair(slot),
                    None => Decision::New,
                })),
                None => {
                    decisions.push(None);
                    open.push(index);
                    lists.push(candidates(
                        particle,
                        self.context,
                        &mut self.report,
                        &mut self.workspace,
                        observation,
                        frames[index].as_deref(),
                        &placed[index],
                        &nearby,
                    ));
                }
            }
        }
        let settings = self.context.params.association_settings();
        // Given the particle's pose its features are independent: the joint distance of a
        // hypothesis is the sum of its pairings' distances.
        let choices = associate(&lists, &settings, self.context.gates, |pairings| {
            Some((
                pairings.iter().map(|c| c.distance).sum(),
                pairings.iter().map(|c| c.dof).sum(),
            ))
        })?;
        for ((index, mut list), choice) in open.into_iter().zip(lists).zip(choices) {
            let decision = match choice {
                Choice::Pair(k) => {
                    let candidate = list.swap_remove(k);
                    self.chosen[index] = Some(Chosen {
                        slot: candidate.feature,
                        scored: candidate.data,
                    });
                    Decision::Pair(candidate.feature)
                }
                Choice::New if self.crowded(&observations[index]) => {
                    self.report
                        .skipped
                        .count("association: a new feature would double an existing one");
                    Decision::Reject(None)
                }
                Choice::New => Decision::New,
                Choice::Ambiguous => Decision::Reject(
                    list.iter()
                        .map(|c| c.data.likelihood.0)
                        .fold(None, |best: Option<f64>, l| {
                            Some(best.map_or(l, |b| b.max(l)))
                        }),
                ),
            };
            decisions[index] = Some(decision);
            self.workspace.recycle_list(list);
        }
        Ok(decisions
            .into_iter()
            .map(|d| d.unwrap_or(Decision::Reject(None)))
            .collect())
    }

    /// Whether the feature `observation` would start overlaps one of the particle's features
    /// within the clearance.
    fn crowded(&self, observation: &Observation) -> bool {
        let world_from_sensor = self
            .particle
            .pose
            .world_from_sensor(&observation.robot_from_sensor);
        crowded(
            self.particle
                .map
                .landmarks
                .iter()
                .map(|(_, l)| l.feature.as_ref()),
            observation.measurement.as_ref(),
            &world_from_sensor,
            self.context.params.new_feature_clearance,
        )
    }

    /// Pairs an observation with the feature in `slot`: weight, sighting, growth, EKF update,
    /// extension.
    fn pair(&mut self, slot: usize, index: usize, observation: &Observation) -> Result<()> {
        let pose = self.particle.pose;
        let chosen = self.chosen_scored(slot, index);
        let frame = self.frame(index, observation);
        self.touched.push(slot);
        let Some(landmark) = self.particle.map.landmarks.get(slot) else {
            self.report.rejected += 1;
            return Ok(());
        };
        let (lin, likelihood) = match chosen {
            Some(Scored { lin, likelihood }) => (Some(lin), Some(likelihood)),
            None => {
                let spare = self.workspace.linearization();
                let lin = frame
                    .as_ref()
                    .and_then(|frame| landmark.linearize(observation, frame, spare));
                let likelihood = lin.as_ref().and_then(|lin| landmark.likelihood(lin));
                (lin, likelihood)
            }
        };
        let (Some(lin), Some((log_likelihood, d2, dof))) = (lin, likelihood) else {
            self.report.rejected += 1;
            self.report
                .skipped
                .count("pairing: likelihood not computable");
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
        let skips = &mut self.report.skipped;
        let Some(landmark) = self.particle.map.landmarks.get_mut(slot) else {
            return Ok(());
        };
        // As in the EKF: sighting and growth first, then one update on the (new) rows.
        let to_sensor = frame.as_ref().map(|f| &f.to_sensor);
        sight(
            landmark,
            context,
            index,
            observation,
            &pose,
            to_sensor,
            skips,
        )?;
        let grown = landmark.grow(observation, &context.params.lifecycle_settings(), skips)?;
        if grown {
            // New rows: linearized again at the grown feature.
            landmark.update(
                observation.measurement.as_ref(),
                &pose,
                &observation.robot_from_sensor,
                skips,
            )?;
        } else if confirmed {
            // A sighting does not change the feature: the pairing's linearization holds.
            landmark.update_linearized_with(&lin, skips, &mut self.workspace.update);
        }
        let extended = landmark.extend(observation, &pose, skips);
        self.workspace.recycle(lin);
        extended
    }

    /// The association's linearization and likelihood of observation `index` with the
    /// feature in `slot` (taken), while they are what the pairing would compute again: the
    /// particle has not moved since and no pairing of this step changed the feature.
    fn chosen_scored(&mut self, slot: usize, index: usize) -> Option<Scored> {
        let chosen = self.chosen.get_mut(index).and_then(Option::take)?;
        let fresh = chosen.slot == slot
            && self.frames_pose == Some(self.particle.pose)
            && !self.touched.contains(&slot);
        fresh.then_some(chosen.scored)
    }

    /// Starts a feature from an observation.
    fn start(&mut self, index: usize, observation: &Observation) -> Result<()> {
        let pose = self.particle.pose;
        let world_from_sensor = pose.world_from_sensor(&observation.robot_from_sensor);
        let feature = match observation
            .measurement
            .initial_feature_dyn(&world_from_sensor)
        {
            Ok(Some(feature)) => feature,
            Ok(None) => {
                self.report.rejected += 1;
                return Ok(());
            }
            Err(_) => {
                self.report.rejected += 1;
                self.report
                    .skipped
                    .count("new feature: not placeable from the observation");
                return Ok(());
            }
        };
        let mut landmark = Landmark {
            feature,
            cov: DMatrix::zeros(0, 0),
            track: Track::started(observation.landmark_id, self.context.step),
        };
        self.count_new_feature_likelihood(&landmark, observation, &pose)?;
        let context = self.context;
        let skips = &mut self.report.skipped;
        sight(
            &mut landmark,
            context,
            index,
            observation,
            &pose,
            None,
            skips,
        )?;
        if landmark.grow(observation, &context.params.lifecycle_settings(), skips)? {
            landmark.update(
                observation.measurement.as_ref(),
                &pose,
                &observation.robot_from_sensor,
                skips,
            )?;
        }
        let tentative = landmark.feature.mspace_dim() == 0;
        let id = landmark.track.landmark_id;
        let map = &mut self.particle.map;
        let slot = map.landmarks.push(landmark);
        if tentative {
            map.tentative.push(slot);
        }
        if let Some(id) = id {
            Arc::make_mut(&mut map.ids).insert(id, slot);
        }
        self.report.new_features += 1;
        Ok(())
    }

    /// The likelihood this observation would have on the new-feature gate of a feature
    /// placed by it (`S = 2 C_eta`): what starting a feature is worth against pairing.
    fn count_new_feature_likelihood(
        &mut self,
        landmark: &Landmark<P>,
        observation: &Observation,
        pose: &P,
    ) -> Result<()> {
        let Ok(lin) = slam_core::linearize(
            observation.measurement.as_ref(),
            landmark.feature.as_ref(),
            pose,
            &observation.robot_from_sensor,
        ) else {
            self.report
                .skipped
                .count("new feature: likelihood not computable");
            return Ok(());
        };
        let dof = lin.eta.len();
        let s = &lin.cov_eta * 2.0;
        if let Some((at_zero, _)) = log_normal(&DVector::zeros(dof), &s) {
            let (_, new_gate) = self.context.gates(dof)?;
            self.log_likelihood += at_zero - 0.5 * new_gate;
        }
        Ok(())
    }

    /// Drops tentative features not seen for `tentative_lifetime` steps.
    fn prune(&mut self) {
        let step = self.context.step;
        let lifetime = self.context.params.tentative_lifetime;
        let map = &mut self.particle.map;
        let mut keep = Vec::with_capacity(map.tentative.len());
        for &slot in &map.tentative {
            let Some(landmark) = map.landmarks.get(slot) else {
                continue;
            };
            if landmark.feature.mspace_dim() > 0 {
                continue;
            }
            if landmark.track.expired(step, lifetime) {
                if let Some(id) = landmark.track.landmark_id {
                    Arc::make_mut(&mut map.ids).remove(&id);
                }
                map.landmarks.set(slot, None);
            } else {
                keep.push(slot);
            }
        }
        map.tentative = keep;
    }
}

/// The sensor frame of each observation from `world_from_robot`, made once per sensor: a
/// run of observations from the same mounting shares one.
fn frames_of<P: RobotPose>(
    world_from_robot: &P,
    observations: &[Observation],
) -> Vec<Option<Rc<SensorFrame>>> {
    let mut frames: Vec<Option<Rc<SensorFrame>>> = Vec::with_capacity(observations.len());
    for (index, observation) in observations.iter().enumerate() {
        let same_sensor =
            index > 0 && observations[index - 1].robot_from_sensor == observation.robot_from_sensor;
        let frame = match frames.last() {
            Some(previous) if same_sensor => previous.clone(),
            _ => SensorFrame::new(world_from_robot, &observation.robot_from_sensor)
                .ok()
                .map(Rc::new),
        };
        frames.push(frame);
    }
    frames
}

/// A feature of a particle's map with its slot and bounding box.
type Nearby<'f> = (usize, &'f dyn Feature, BoundingBox);

/// The particle's features, in slot order, whose bounding box lies within the association
/// margin of the box of every feature the step's observations without an id would start: one
/// search of the map's boxes per step instead of a pass over the map per observation. All of
/// them when one of those observations places no feature (no spatial filter for it). Also
/// each observation's [`placed_box`] (`Nowhere` for those with an id), for the candidates.
fn near_any<'f, P: RobotPose>(
    particle: &'f Particle<P, LandmarkMap<P>>,
    context: &StepContext<'_>,
    observations: &[Observation],
    frames: &[Option<Rc<SensorFrame>>],
) -> (Vec<Nearby<'f>>, Vec<Placed>) {
    let placed: Vec<Placed> = observations
        .iter()
        .zip(frames)
        .map(|(observation, frame)| match frame {
            Some(frame) if observation.landmark_id.is_none() => {
                placed_box(observation.measurement.as_ref(), frame.world_from_sensor())
            }
            _ => Placed::Nowhere,
        })
        .collect();
    let mut reach = BoundingBox::default();
    let mut filtered = true;
    for ((observation, frame), placed) in observations.iter().zip(frames).zip(&placed) {
        if observation.landmark_id.is_some() {
            continue;
        }
        match (frame, placed) {
            (Some(_), Placed::At(near)) => reach.include(near),
            _ => filtered = false,
        }
    }
    let landmarks = &particle.map.landmarks;
    let margin = context.params.association_margin;
    // A subtree's box is near the reach whenever one of its features' boxes is.
    let nearby = landmarks
        .iter_where(|bbox| !filtered || bbox.near(&reach, margin))
        .into_iter()
        .map(|(slot, l, bbox)| (slot, l.feature.as_ref(), *bbox))
        .collect();
    (nearby, placed)
}

/// The particle's features an observation without an id can be of, with their
/// likelihoods, nearest first. `nearby` is the particle's features that may be near one of
/// the step's observations ([`near_any`]); the sensor's frame at the
/// particle's pose is made once for all of them.
#[allow(clippy::too_many_arguments)] // the particle, the step, the observation's three parts
fn candidates<'f, P: RobotPose>(
    particle: &'f Particle<P, LandmarkMap<P>>,
    context: &StepContext<'_>,
    report: &mut UpdateReport,
    workspace: &mut Workspace,
    observation: &Observation,
    frame: Option<&SensorFrame>,
    placed: &Placed,
    nearby: &[Nearby<'f>],
) -> Vec<Candidate<Scored>> {
    let Some(frame) = frame else {
        report
            .skipped
            .count("association: sensor pose has no map-to-sensor transform");
        return Vec::new();
    };
    let landmarks = &particle.map.landmarks;
    let margin = context.params.association_margin;
    // The boxes kept from the map's search first (`visit_candidate_features` applies the same
    // test again to the few that pass).
    let near_placed = nearby.iter().filter(|(_, _, bbox)| match placed {
        Placed::At(near) => bbox.near(near, margin),
        _ => true,
    });
    let nearness = Nearness {
        placed,
        to_sensor: &frame.to_sensor,
        margin,
    };
    let mut list = workspace.candidate_list();
    visit_candidate_features(
        near_placed.map(|&(slot, feature, _)| (slot, feature)),
        observation.measurement.as_ref(),
        &nearness,
        &mut report.skipped,
        |slot, feature, _, skips| {
            let Some(landmark) = landmarks.get(slot) else {
                return;
            };
            let scored = landmark
                .linearize(observation, frame, workspace.linearization())
                .and_then(|lin| match landmark.likelihood(&lin) {
                    Some(likelihood) => Some(Scored { lin, likelihood }),
                    None => {
                        workspace.recycle(lin);
                        None
                    }
                });
            let Some(scored) = scored else {
                skips.count("association: candidate likelihood not computable");
                return;
            };
            let (_, d2, dof) = scored.likelihood;
            list.push(Candidate {
                feature: slot,
                distance: d2,
                dof,
                tentative: feature.mspace_dim() == 0,
                data: scored,
            });
        },
    );
    sort_by_distance(&mut list);
    list
}

/// Counts a sighting of `landmark` on its track (the shared lifecycle), keeping the step's
/// shared measurement as a view.
fn sight<P: RobotPose>(
    landmark: &mut Landmark<P>,
    context: &StepContext<'_>,
    index: usize,
    observation: &Observation,
    pose: &P,
    to_sensor: Option<&MapToSensor>,
    skips: &mut slam_core::Skips,
) -> Result<()> {
    let sighting = Sighting {
        observation,
        world_from_robot: pose,
        step: context.step,
        view_measurement: context.shared.get(index).cloned().flatten(),
        pose_covariance: None,
        to_sensor,
    };
    landmark.track.sight(
        landmark.feature.as_ref(),
        sighting,
        context.params.max_views,
        skips,
    )
}
