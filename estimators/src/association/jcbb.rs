//! Joint compatibility branch and bound (JCBB, Neira & Tardos, IEEE T-RA 17(6), 2001) over
//! the candidates of one step.

use std::collections::HashMap;

use slam_core::{Result, chi2_quantile};

use super::{AssociationSettings, Candidate, Gates, in_gate};

/// JCBB over the candidates of confirmed features; observations it leaves unpaired then go
/// to their nearest tentative candidate in the gate. Returns, per observation, the index of
/// the chosen candidate in its list.
pub(super) fn jcbb<T>(
    lists: &[Vec<Candidate<T>>],
    settings: &AssociationSettings,
    gates: &Gates,
    joint: impl Fn(&[&Candidate<T>]) -> Option<(f64, usize)>,
) -> Result<Vec<Option<usize>>> {
    // Individually compatible pairings with confirmed features, per observation.
    let mut levels: Vec<(usize, Vec<usize>)> = Vec::new();
    for (observation, list) in lists.iter().enumerate() {
        let mut compatible = Vec::new();
        for (k, c) in list.iter().enumerate() {
            if !c.tentative && in_gate(c, settings.gate_probability, gates)? {
                compatible.push(k);
            }
        }
        if !compatible.is_empty() {
            levels.push((observation, compatible));
        }
    }
    let mut search = Search {
        lists,
        levels: &levels,
        joint: &joint,
        probability: settings.gate_probability,
        gates: HashMap::new(),
        best: Vec::new(),
        best_distance: f64::INFINITY,
        nodes: 0,
        max_nodes: settings.jcbb_max_nodes,
    };
    search.recurse(0, &mut Vec::new(), 0.0)?;
    let mut chosen: Vec<Option<usize>> = vec![None; lists.len()];
    for &(observation, k) in &search.best {
        chosen[observation] = Some(k);
    }
    for (observation, list) in lists.iter().enumerate() {
        if chosen[observation].is_some() {
            continue;
        }
        for (k, c) in list.iter().enumerate() {
            if c.tentative && in_gate(c, settings.gate_probability, gates)? {
                chosen[observation] = Some(k);
                break;
            }
        }
    }
    Ok(chosen)
}

/// The state of one JCBB search.
struct Search<'a, 'j, T, J> {
    lists: &'a [Vec<Candidate<T>>],
    /// `(observation, indices of its compatible candidates)`, in search order.
    levels: &'j [(usize, Vec<usize>)],
    joint: &'j J,
    probability: f64,
    gates: HashMap<usize, f64>,
    /// Best hypothesis: `(observation, candidate index)` pairs.
    best: Vec<(usize, usize)>,
    best_distance: f64,
    nodes: usize,
    max_nodes: usize,
}

impl<'a, T, J> Search<'a, '_, T, J>
where
    J: Fn(&[&'a Candidate<T>]) -> Option<(f64, usize)>,
{
    fn gate(&mut self, dof: usize) -> Result<f64> {
        if let Some(&g) = self.gates.get(&dof) {
            return Ok(g);
        }
        let g = chi2_quantile(self.probability, dof)?;
        self.gates.insert(dof, g);
        Ok(g)
    }

    fn candidate(&self, observation: usize, k: usize) -> &'a Candidate<T> {
        &self.lists[observation][k]
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
        if level == self.levels.len() {
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
        let levels = self.levels;
        let (observation, compatible) = &levels[level];
        for &k in compatible {
            let feature = self.candidate(*observation, k).feature;
            if hypothesis
                .iter()
                .any(|&(o, j)| self.candidate(o, j).feature == feature)
            {
                continue;
            }
            hypothesis.push((*observation, k));
            let pairings: Vec<&'a Candidate<T>> = hypothesis
                .iter()
                .map(|&(o, j)| self.candidate(o, j))
                .collect();
            if let Some((joint_distance, dof)) = (self.joint)(&pairings)
                && joint_distance <= self.gate(dof)?
            {
                self.recurse(level + 1, hypothesis, joint_distance)?;
            }
            hypothesis.pop();
        }
        let remaining = self.levels.len() - level - 1;
        if hypothesis.len() + remaining >= self.best.len() {
            self.recurse(level + 1, hypothesis, distance)?;
        }
        Ok(())
    }
}
