//! Data association for observations without landmark ids: Mahalanobis-gated nearest
//! neighbour, and joint compatibility branch and bound (JCBB, Neira & Tardos, IEEE T-RA
//! 17(6), 2001).

use std::collections::{BTreeMap, HashMap};

use slam_core::{Result, chi2_quantile};

use super::Pairing;

/// One feature an observation might be of.
#[derive(Clone, Debug)]
pub(super) struct Candidate {
    /// The observation linearized against the feature.
    pub pairing: Pairing,
    /// Squared Mahalanobis distance of the innovation, `eta^T S^-1 eta`.
    pub distance: f64,
    /// Whether the feature is tentative (no state rows yet).
    pub tentative: bool,
}

/// The association of one observation: the index of the chosen candidate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Choice {
    /// Paired with candidate `k` of the observation's list.
    Pair(usize),
}

/// Whether a candidate passes the individual gate for its innovation dimension.
fn in_gate(candidate: &Candidate, gates: &BTreeMap<usize, f64>) -> bool {
    gates
        .get(&candidate.pairing.eta.len())
        .is_some_and(|&gate| candidate.distance <= gate)
}

/// Each observation to its nearest candidate (candidates are sorted by distance) that passes
/// the gate; several observations may pair with one feature (two pieces of one wall).
pub(super) fn nearest_neighbour(
    candidates: &BTreeMap<usize, Vec<Candidate>>,
    gates: &BTreeMap<usize, f64>,
) -> BTreeMap<usize, Choice> {
    candidates
        .iter()
        .filter_map(|(&observation, list)| {
            list.iter()
                .position(|c| in_gate(c, gates))
                .map(|k| (observation, Choice::Pair(k)))
        })
        .collect()
}

/// JCBB over the candidates with state rows; observations it leaves unpaired then go to the
/// nearest tentative candidate in the gate. `joint(pairings)` gives the joint squared
/// Mahalanobis distance and dimension of a hypothesis, `None` when its `S` is singular.
pub(super) fn jcbb<'a>(
    candidates: &'a BTreeMap<usize, Vec<Candidate>>,
    gates: &BTreeMap<usize, f64>,
    joint: impl Fn(&[&'a super::Pairing]) -> Option<(f64, usize)>,
    probability: f64,
    max_nodes: usize,
) -> Result<BTreeMap<usize, Choice>> {
    // Individually compatible pairings with confirmed features, per observation.
    let lists: Vec<(usize, Vec<usize>)> = candidates
        .iter()
        .map(|(&observation, list)| {
            let compatible = list
                .iter()
                .enumerate()
                .filter(|(_, c)| !c.tentative && in_gate(c, gates))
                .map(|(k, _)| k)
                .collect();
            (observation, compatible)
        })
        .filter(|(_, compatible): &(usize, Vec<usize>)| !compatible.is_empty())
        .collect();
    let mut search = Search {
        candidates,
        lists: &lists,
        joint: &joint,
        probability,
        gates: HashMap::new(),
        best: Vec::new(),
        best_distance: f64::INFINITY,
        nodes: 0,
        max_nodes,
    };
    search.recurse(0, &mut Vec::new(), 0.0)?;
    let mut chosen: BTreeMap<usize, Choice> = search
        .best
        .iter()
        .map(|&(observation, k)| (observation, Choice::Pair(k)))
        .collect();
    for (&observation, list) in candidates {
        if chosen.contains_key(&observation) {
            continue;
        }
        if let Some(k) = list.iter().position(|c| c.tentative && in_gate(c, gates)) {
            chosen.insert(observation, Choice::Pair(k));
        }
    }
    Ok(chosen)
}

/// The state of one JCBB search.
struct Search<'a, 'j, J> {
    candidates: &'a BTreeMap<usize, Vec<Candidate>>,
    /// `(observation, indices of its compatible candidates)`, in search order.
    lists: &'j [(usize, Vec<usize>)],
    joint: &'j J,
    probability: f64,
    gates: HashMap<usize, f64>,
    /// Best hypothesis: `(observation, candidate index)` pairs.
    best: Vec<(usize, usize)>,
    best_distance: f64,
    nodes: usize,
    max_nodes: usize,
}

impl<'a, J> Search<'a, '_, J>
where
    J: Fn(&[&'a Pairing]) -> Option<(f64, usize)>,
{
    fn gate(&mut self, dof: usize) -> Result<f64> {
        if let Some(&g) = self.gates.get(&dof) {
            return Ok(g);
        }
        let g = chi2_quantile(self.probability, dof)?;
        self.gates.insert(dof, g);
        Ok(g)
    }

    fn pairing(&self, observation: usize, k: usize) -> &'a Pairing {
        &self.candidates[&observation][k].pairing
    }

    /// Depth-first over observations `level..`: pair with each compatible candidate whose
    /// addition keeps the hypothesis jointly compatible, or leave the observation unpaired
    /// when the remaining levels could still beat the best hypothesis.
    fn recurse(
        &mut self,
        level: usize,
        hypothesis: &mut Vec<(usize, usize)>,
        distance: f64,
    ) -> Result<()> {
        self.nodes += 1;
        if level == self.lists.len() {
            let better = hypothesis.len() > self.best.len()
                || (hypothesis.len() == self.best.len() && distance < self.best_distance);
            if better {
                self.best = hypothesis.clone();
                self.best_distance = distance;
            }
            return Ok(());
        }
        if self.nodes > self.max_nodes {
            return Ok(());
        }
        let lists = self.lists;
        let (observation, compatible) = &lists[level];
        for &k in compatible {
            let feature = self.pairing(*observation, k).feature;
            if hypothesis
                .iter()
                .any(|&(o, j)| self.pairing(o, j).feature == feature)
            {
                continue;
            }
            hypothesis.push((*observation, k));
            let pairings: Vec<&'a Pairing> = hypothesis
                .iter()
                .map(|&(o, j)| self.pairing(o, j))
                .collect();
            if let Some((joint_distance, dof)) = (self.joint)(&pairings)
                && joint_distance <= self.gate(dof)?
            {
                self.recurse(level + 1, hypothesis, joint_distance)?;
            }
            hypothesis.pop();
        }
        let remaining = self.lists.len() - level - 1;
        if hypothesis.len() + remaining >= self.best.len() {
            self.recurse(level + 1, hypothesis, distance)?;
        }
        Ok(())
    }
}
