//! The inference engine (section 3 of the source): Problem 4, maximize
//! `log p(x | measured) + h_T(x) + gamma |INMODEL|` subject to the priorlets' equalities (3)
//! and inequalities (4) for topology `T`, and the bounds (5), over `x = (rho, alpha)`.
//!
//! - Inner loop (Algorithm 2): penalty homotopy for the prior's constraints
//!   (`lambda f^2`, `lambda max(0, g)^2`, the smallest branch of a disjunction), log-barrier
//!   for the bounds, Newton steps with backtracking (from at most 99.5 % of the way to the
//!   nearest bound, the fraction-to-the-boundary rule). The barrier is primal-dual: the
//!   bounds' multipliers are estimated along with `x` (`BoundDuals`, restarted on the
//!   central path at each stage), and the Newton model's curvature of the barrier is theirs,
//!   so an iterate pressed against a bound is not slowed to a crawl. Gradients and Hessians
//!   are exact (second-order dual numbers through the priorlet's tape). A Newton step uses
//!   the exact Hessian when its banded sum (data, barrier and windows) is positive definite,
//!   which a banded Cholesky factor in `O(n)` finds out, as it is at nearly every step (the data
//!   terms' curvature outweighs the penalties' negative curvature). Otherwise the Hessian is
//!   convexified window by window (Algorithm 2, line 12): each priorlet window's Hessian
//!   (energies plus penalties) has its negative eigenvalues raised to a small positive value
//!   (eigen-decomposition by cyclic Jacobi, `symmetric_eigen`, started from the window's
//!   eigenvectors of the previous convexified step, `convexify_from`), so the banded sum is
//!   positive definite. The windows' energies and penalties are summed apart (`WindowSums`),
//!   so one evaluation serves every penalty weight: the line search's first trial point is
//!   evaluated with its derivatives, and once accepted (nearly always) it is where the next
//!   Newton step starts, in its stage or the next, without evaluating the windows again. The
//!   windows' terms are computed in parallel for problems of at least `PARALLEL_WINDOWS`
//!   windows (rayon, the whole inference on a worker of its pool) and added in window order,
//!   so the results do not depend on the number of threads.
//! - Outer loop (Algorithm 1): every reading in INMODEL and the strictest topology first;
//!   while infeasible, the link with the largest penalty is relaxed (same region -> different
//!   region -> different surface) and the readings of regions smaller than
//!   [`Params::min_region_points`] leave INMODEL (outliers). A last pass moves each region
//!   boundary by one reading while that lowers the fit cost (a small local search the source
//!   lists as future work).
//! - Independent parts: a link that no priorlet window crosses (a different-surface link when
//!   the prior's `different_surface` priorlet states nothing, as in every shipped prior)
//!   splits the problem into parts that share no term, so each part (a run of readings between
//!   such links) has its own inner optimization, and a part whose readings and links an
//!   earlier topology already had keeps that earlier result: relaxing one link solves only
//!   the part that holds it (`PartSolver`). The parts that the boundary refinement's coming
//!   moves need (and the first topology's parts) are solved ahead, as many at once as there
//!   are threads; the results are those of solving them one by one.

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use slam_sensors::LaserScan;

use crate::compile::{Atom, AtomKind, Prior, Priorlet};
use crate::dual::Sparse;
use crate::error::{PriorError, Result};
use crate::parser::Topology;
use crate::window::{SparseNodes, WindowPlan};

/// The readings of one scan given to the engine: bearings, measured ranges and their
/// standard deviations, in scan order.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanInput {
    /// Bearing of each reading in the sensor frame, rad (`phi_i`).
    pub phi: Vec<f64>,
    /// Measured range of each reading, m.
    pub rho: Vec<f64>,
    /// Standard deviation of each range, m.
    pub sigma: Vec<f64>,
    /// Beam index of each reading in the scan it came from.
    pub beam: Vec<usize>,
}

impl ScanInput {
    /// Readings with one standard deviation `sigma` for all.
    pub fn new(phi: Vec<f64>, rho: Vec<f64>, sigma: f64) -> Result<ScanInput> {
        let n = rho.len();
        let input = ScanInput {
            beam: (0..n).collect(),
            sigma: vec![sigma; n],
            phi,
            rho,
        };
        input.validate()?;
        Ok(input)
    }

    /// The valid readings of a laser scan, with range standard deviation `sigma`.
    pub fn from_scan(scan: &LaserScan, sigma: f64) -> Result<ScanInput> {
        let points = scan.points();
        let input = ScanInput {
            phi: points.iter().map(|p| p.bearing).collect(),
            rho: points.iter().map(|p| p.range).collect(),
            sigma: vec![sigma; points.len()],
            beam: points.iter().map(|p| p.index).collect(),
        };
        input.validate()?;
        Ok(input)
    }

    /// Number of readings.
    pub fn len(&self) -> usize {
        self.rho.len()
    }

    /// Whether there are no readings.
    pub fn is_empty(&self) -> bool {
        self.rho.is_empty()
    }

    fn validate(&self) -> Result<()> {
        let n = self.rho.len();
        if self.phi.len() != n || self.sigma.len() != n || self.beam.len() != n {
            return Err(PriorError::InvalidInput(format!(
                "{} bearings, {} ranges, {} deviations and {} beam indices",
                self.phi.len(),
                n,
                self.sigma.len(),
                self.beam.len()
            )));
        }
        for i in 0..n {
            if !(self.rho[i].is_finite() && self.rho[i] > 0.0 && self.phi[i].is_finite()) {
                return Err(PriorError::InvalidInput(format!(
                    "reading {i}: range {} at bearing {}",
                    self.rho[i], self.phi[i]
                )));
            }
            if !(self.sigma[i].is_finite() && self.sigma[i] > 0.0) {
                return Err(PriorError::InvalidInput(format!(
                    "reading {i}: standard deviation {}",
                    self.sigma[i]
                )));
            }
        }
        Ok(())
    }
}

/// Parameters of the inference engine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Params {
    /// Each range may move at most this many standard deviations from its reading (source
    /// section 3.2: 4).
    pub bound_sigmas: f64,
    /// Probability `beta` that a reading is described by the prior; the objective gains
    /// `gamma = ln(beta / (1 - beta))` per reading in INMODEL.
    pub inlier_probability: f64,
    /// Regions with fewer readings leave INMODEL (outliers). `None`: twice the order.
    pub min_region_points: Option<usize>,
    /// Neighbours on each side used to estimate the initial normals.
    pub normal_window: usize,
    /// Smallest half-width of the bounds of a normal, degrees.
    pub min_normal_bound_deg: f64,
    /// A topology is feasible when every constraint is violated by less than this.
    pub feasibility_tolerance: f64,
    /// First penalty weight `lambda`.
    pub penalty_start: f64,
    /// Factor of `lambda` between homotopy stages.
    pub penalty_factor: f64,
    /// Largest penalty weight; still infeasible there means the topology must be relaxed.
    pub penalty_max: f64,
    /// First weight `mu` of the log-barrier of the bounds.
    pub barrier_start: f64,
    /// Factor of `mu` between stages (below 1).
    pub barrier_factor: f64,
    /// Newton steps per homotopy stage, at most.
    pub max_newton_steps: usize,
    /// A stage whose largest violation is above this fraction of the previous stage's, twice
    /// in a row, ends the inner loop as infeasible (the violation of a feasible topology falls
    /// with `1 / lambda`). 1 disables the test.
    pub stall_ratio: f64,
    /// Homotopy stages run after the first feasible one, to tighten the constraints further
    /// (the violation falls by `penalty_factor` per stage) before the degrees of freedom are
    /// computed.
    pub polish_stages: usize,
    /// Geometric first guess of the topology (the source's Fig. 6a): two consecutive
    /// readings farther apart than a surface seen at this incidence angle (degrees from its
    /// normal) would put them, plus 8 sigma, start on different surfaces. 90 or more: off.
    pub max_incidence_deg: f64,
    /// Outer iterations (relaxations), at most. `None`: three per reading.
    pub max_outer_iterations: Option<usize>,
    /// Move region boundaries by one reading while that lowers the fit cost.
    pub refine_boundaries: bool,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            bound_sigmas: 4.0,
            inlier_probability: 0.9,
            min_region_points: None,
            normal_window: 3,
            min_normal_bound_deg: 5.0,
            feasibility_tolerance: 1e-5,
            penalty_start: 1.0,
            penalty_factor: 10.0,
            penalty_max: 1e12,
            barrier_start: 1.0,
            barrier_factor: 0.1,
            max_newton_steps: 30,
            stall_ratio: 0.5,
            polish_stages: 2,
            max_incidence_deg: 85.0,
            max_outer_iterations: None,
            refine_boundaries: true,
        }
    }
}

impl Params {
    /// Checks that the settings are in range (what [`infer`] checks first), so that a caller
    /// can reject bad settings once, before any scan.
    pub fn validate(&self) -> Result<()> {
        let ok = self.bound_sigmas > 0.0
            && self.inlier_probability > 0.0
            && self.inlier_probability < 1.0
            && self.feasibility_tolerance > 0.0
            && self.penalty_start > 0.0
            && self.penalty_factor > 1.0
            && self.penalty_max >= self.penalty_start
            && self.barrier_start > 0.0
            && self.barrier_factor > 0.0
            && self.barrier_factor < 1.0
            && self.min_normal_bound_deg >= 0.0
            && self.max_newton_steps > 0;
        if ok {
            Ok(())
        } else {
            Err(PriorError::InvalidInput(format!(
                "parameters out of range: {self:?}"
            )))
        }
    }
}

/// The relation between two consecutive readings of INMODEL.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Link {
    /// Index (into the scan input) of the first reading.
    pub from: usize,
    /// Index of the next reading in INMODEL.
    pub to: usize,
    /// Same region, different region or different surface.
    pub topology: Topology,
}

/// The result of [`infer`].
#[derive(Clone, Debug)]
pub struct Solution {
    /// Name of the prior used.
    pub prior: String,
    /// Bearings of the readings (copied from the input).
    pub phi: Vec<f64>,
    /// Measured ranges (copied from the input).
    pub measured: Vec<f64>,
    /// Range standard deviations (copied from the input).
    pub sigma: Vec<f64>,
    /// Corrected ranges (outliers keep their measured range).
    pub rho: Vec<f64>,
    /// Corrected surface normals, rad (NaN for outliers).
    pub alpha: Vec<f64>,
    /// Standard deviation of the initial normal estimates (the prior covariance of `alpha`).
    pub alpha_sigma: Vec<f64>,
    /// Whether each reading is described by the prior (INMODEL).
    pub in_model: Vec<bool>,
    /// Topology between consecutive readings of INMODEL.
    pub links: Vec<Link>,
    /// Whether the final topology is feasible.
    pub feasible: bool,
    /// Largest constraint violation at the solution.
    pub max_violation: f64,
    /// Outer iterations used: the topologies tried (relaxations and boundary moves).
    pub outer_iterations: usize,
    /// Inner optimizations run: the parts of those topologies solved (a part whose
    /// readings and links an earlier topology had is not solved again).
    pub inner_optimizations: usize,
    /// Fit cost: `sum (rho - measured)^2 / (2 sigma^2)` plus the energies.
    pub fit_cost: f64,
    /// The negative log-posterior of Problem 4 up to a constant: fit cost minus
    /// `gamma |INMODEL|`.
    pub objective: f64,
}

/// A straight region as a wall segment in the sensor frame, for a wall-based front-end.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RegionSegment {
    /// First and last reading of the region.
    pub readings: (usize, usize),
    /// The ends: the first and last corrected readings projected on the region's line, m.
    pub ends: [[f64; 2]; 2],
    /// Normal of the line (towards the sensor), rad.
    pub normal: f64,
    /// Distance of the line from the sensor, m.
    pub distance: f64,
    /// Number of readings.
    pub points: usize,
}

impl Solution {
    /// The regions whose corrected normals all agree within `tolerance` rad (every region
    /// under a polygonal prior) and that hold at least `min_points` readings, as segments.
    pub fn straight_regions(&self, min_points: usize, tolerance: f64) -> Vec<RegionSegment> {
        self.regions()
            .into_iter()
            .filter(|r| r.len() >= min_points.max(2))
            .filter_map(|region| {
                let first = self.alpha[region[0]];
                let straight = region.iter().all(|&i| {
                    let d = self.alpha[i] - first;
                    d.sin().atan2(d.cos()).abs() <= tolerance
                });
                if !straight {
                    return None;
                }
                let (mut sx, mut sy) = (0.0, 0.0);
                for &i in &region {
                    sx += self.alpha[i].cos();
                    sy += self.alpha[i].sin();
                }
                let normal = sy.atan2(sx);
                let n = [normal.cos(), normal.sin()];
                let points: Vec<[f64; 2]> = region
                    .iter()
                    .map(|&i| {
                        let (s, c) = self.phi[i].sin_cos();
                        [self.rho[i] * c, self.rho[i] * s]
                    })
                    .collect();
                let distance = -points
                    .iter()
                    .map(|p| n[0] * p[0] + n[1] * p[1])
                    .sum::<f64>()
                    / points.len() as f64;
                let project = |p: [f64; 2]| {
                    let off = n[0] * p[0] + n[1] * p[1] + distance;
                    [p[0] - off * n[0], p[1] - off * n[1]]
                };
                Some(RegionSegment {
                    readings: (region[0], region[region.len() - 1]),
                    ends: [project(points[0]), project(points[points.len() - 1])],
                    normal,
                    distance,
                    points: region.len(),
                })
            })
            .collect()
    }

    /// Indices of the readings in INMODEL.
    pub fn inliers(&self) -> Vec<usize> {
        (0..self.in_model.len())
            .filter(|&i| self.in_model[i])
            .collect()
    }

    /// Indices of the readings outside INMODEL.
    pub fn outliers(&self) -> Vec<usize> {
        (0..self.in_model.len())
            .filter(|&i| !self.in_model[i])
            .collect()
    }

    fn groups(&self, split: impl Fn(Topology) -> bool) -> Vec<Vec<usize>> {
        let inliers = self.inliers();
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut current = Vec::new();
        for (k, &i) in inliers.iter().enumerate() {
            current.push(i);
            let end = k + 1 == inliers.len() || self.links.get(k).is_none_or(|l| split(l.topology));
            if end {
                groups.push(std::mem::take(&mut current));
            }
        }
        groups
    }

    /// Regions: runs of INMODEL readings joined by same-region links.
    pub fn regions(&self) -> Vec<Vec<usize>> {
        self.groups(|t| t != Topology::SameRegion)
    }

    /// Surfaces: runs of INMODEL readings not separated by a different-surface link.
    pub fn surfaces(&self) -> Vec<Vec<usize>> {
        self.groups(|t| t == Topology::DifferentSurface)
    }

    /// The corrected readings as points in the sensor frame (NaN-free: INMODEL only).
    pub fn corrected_points(&self) -> Vec<(usize, [f64; 2])> {
        self.inliers()
            .into_iter()
            .map(|i| {
                let (s, c) = self.phi[i].sin_cos();
                (i, [self.rho[i] * c, self.rho[i] * s])
            })
            .collect()
    }
}

/// Everything an inner optimization needs, for the readings of INMODEL (compressed indices).
pub(crate) struct Problem<'a> {
    pub prior: &'a Prior,
    pub phi: Vec<f64>,
    pub rho: Vec<f64>,
    pub w_rho: Vec<f64>,
    pub alpha0: Vec<f64>,
    pub alpha_sigma: Vec<f64>,
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    /// `(first reading, topology)` of each window of `order` consecutive readings.
    pub windows: Vec<(usize, Topology)>,
    /// What the Newton steps need of the priorlets on these windows.
    plan: WindowPlan,
    /// Whether to evaluate the windows in parallel: when there are at least
    /// [`PARALLEL_WINDOWS`], unless the problem is one of several solved at once.
    parallel: bool,
}

/// The topology a window of consecutive links sees.
pub(crate) fn window_topology(links: &[Topology]) -> Topology {
    if links.contains(&Topology::DifferentSurface) {
        Topology::DifferentSurface
    } else if links.contains(&Topology::DifferentRegion) {
        Topology::DifferentRegion
    } else {
        Topology::SameRegion
    }
}

pub(crate) fn windows_of(order: usize, links: &[Topology], m: usize) -> Vec<(usize, Topology)> {
    if m < order {
        return Vec::new();
    }
    (0..=m - order)
        .map(|s| (s, window_topology(&links[s..s + order - 1])))
        .collect()
}

/// The Newton model at one point: the objective's value, gradient and banded Hessian.
struct Evaluation {
    value: f64,
    gradient: Vec<f64>,
    band: Band,
}

impl Evaluation {
    /// The objective's rate of change along `direction` (`gradient . direction`).
    fn slope(&self, direction: &[f64]) -> f64 {
        self.gradient
            .iter()
            .zip(direction)
            .map(|(g, d)| g * d)
            .sum()
    }
}

/// A symmetric banded matrix (lower band stored).
struct Band {
    n: usize,
    b: usize,
    data: Vec<f64>,
}

impl Band {
    fn new(n: usize, b: usize) -> Band {
        Band {
            n,
            b,
            data: vec![0.0; n * (b + 1)],
        }
    }
    fn at(&mut self, i: usize, j: usize) -> &mut f64 {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        &mut self.data[i * (self.b + 1) + (i - j)]
    }
    /// Solves `A d = rhs` by banded Cholesky with `shift` added to the diagonal.
    fn solve(&self, rhs: &[f64], shift: f64) -> Option<Vec<f64>> {
        let (n, b) = (self.n, self.b);
        let w = b + 1;
        // Row i of the factor L holds L[i][i - d] at l[i * w + d], as `data` does.
        let mut l = vec![0.0; n * w];
        for j in 0..n {
            let mut s = self.data[j * w] + shift;
            for k in j.saturating_sub(b)..j {
                s -= l[j * w + j - k] * l[j * w + j - k];
            }
            if s.is_nan() || s <= 0.0 || !s.is_finite() {
                return None;
            }
            let d = s.sqrt();
            // The factor's diagonal is kept as its reciprocal: products instead of divisions.
            let inverse = 1.0 / d;
            l[j * w] = inverse;
            for i in j + 1..(j + b + 1).min(n) {
                let mut s = self.data[i * w + i - j];
                for k in i.saturating_sub(b)..j {
                    s -= l[i * w + i - k] * l[j * w + j - k];
                }
                l[i * w + i - j] = s * inverse;
            }
        }
        let mut y = rhs.to_vec();
        for i in 0..n {
            let mut s = y[i];
            for k in i.saturating_sub(b)..i {
                s -= l[i * w + i - k] * y[k];
            }
            y[i] = s * l[i * w];
        }
        for i in (0..n).rev() {
            let mut s = y[i];
            for k in i + 1..(i + b + 1).min(n) {
                s -= l[k * w + k - i] * y[k];
            }
            y[i] = s * l[i * w];
        }
        y.iter().all(|v| v.is_finite()).then_some(y)
    }
}

/// The penalty of one constraint (smallest branch) and the index of that branch, given the
/// value of each tape node.
fn constraint_penalty(value: impl Fn(usize) -> f64, branches: &[Atom]) -> (f64, usize) {
    let mut best = (f64::INFINITY, 0);
    for (k, atom) in branches.iter().enumerate() {
        let v = atom.violation(value(atom.node));
        let p = v * v;
        if p < best.0 || !best.0.is_finite() {
            best = (p, k);
        }
    }
    best
}

impl Problem<'_> {
    fn dim(&self) -> usize {
        2 * self.rho.len()
    }

    fn local<'x>(&self, x: &'x [f64], start: usize) -> &'x [f64] {
        &x[2 * start..2 * (start + self.prior.order)]
    }

    fn local_phi(&self, start: usize) -> &[f64] {
        &self.phi[start..start + self.prior.order]
    }

    /// Window `w`'s energies and penalties (squared violations, without `lambda`) at `x`,
    /// each summed from zero in the priorlet's order, as [`split_window_terms`] sums them.
    fn window_value_terms(&self, x: &[f64], w: usize, buffer: &mut Vec<f64>) -> (f64, f64) {
        let (start, topology) = self.windows[w];
        let priorlet = self.prior.priorlet(topology);
        if priorlet.is_empty() {
            return (0.0, 0.0);
        }
        let (local, phi) = (self.local(x, start), self.local_phi(start));
        self.plan
            .values(self.prior, (w, topology), local, phi, buffer);
        let mut energy = 0.0;
        for &e in &priorlet.energies {
            energy += buffer[e];
        }
        let mut penalty = 0.0;
        for c in &priorlet.constraints {
            let p = constraint_penalty(|k| buffer[k], &c.branches).0;
            if p > 0.0 {
                penalty += p;
            } else if p.is_nan() {
                penalty = f64::NAN;
            }
        }
        (energy, penalty)
    }

    /// The data term plus the barrier at `x`; `None` outside the bounds.
    fn data_and_barrier_value(&self, x: &[f64], mu: f64) -> Option<f64> {
        let mut total = 0.0;
        for j in 0..self.rho.len() {
            let dr = x[2 * j] - self.rho[j];
            let da = (x[2 * j + 1] - self.alpha0[j]) / self.alpha_sigma[j];
            total += 0.5 * (self.w_rho[j] * dr * dr + da * da);
        }
        for i in 0..x.len() {
            let (a, b) = (x[i] - self.lo[i], self.hi[i] - x[i]);
            if !(a > 0.0 && b > 0.0) {
                return None;
            }
            total -= mu * (a.ln() + b.ln());
        }
        Some(total)
    }

    /// The objective at `x` given the windows' summed energies and penalties there: the data
    /// term and the barrier, plus `energy + lambda penalty`. `None` outside the bounds or
    /// when not finite. [`Problem::value`] and the Newton steps' evaluations
    /// ([`Problem::assemble`]) both compute it here, so their values compare exactly.
    fn objective(
        &self,
        x: &[f64],
        (energy, penalty): (f64, f64),
        lambda: f64,
        mu: f64,
    ) -> Option<f64> {
        let total = self.data_and_barrier_value(x, mu)? + energy + lambda * penalty;
        total.is_finite().then_some(total)
    }

    /// `terms` of each run of [`WINDOW_CHUNK`] windows (their indices), in window order: in
    /// parallel when the problem is ([`Problem::parallel`]), on the calling thread otherwise.
    /// One list per chunk (an indexed collect: no list grown and moved as it goes).
    fn per_chunk<T: Send>(
        &self,
        terms: impl Fn(std::ops::Range<usize>) -> Vec<T> + Sync,
    ) -> Vec<Vec<T>> {
        let n = self.windows.len();
        let chunk = |c: usize| c * WINDOW_CHUNK..((c + 1) * WINDOW_CHUNK).min(n);
        let chunks = n.div_ceil(WINDOW_CHUNK);
        if self.parallel {
            (0..chunks)
                .into_par_iter()
                .map(|c| terms(chunk(c)))
                .collect()
        } else {
            (0..chunks).map(|c| terms(chunk(c))).collect()
        }
    }

    /// The data term, energies, penalties and barrier at `x` (value only). `None` outside
    /// the bounds or when not finite. The windows' terms are added in window order, for any
    /// number of threads.
    fn value(&self, x: &[f64], lambda: f64, mu: f64) -> Option<f64> {
        let terms = self.per_chunk(|windows| {
            let mut buffer = Vec::new();
            windows
                .map(|w| self.window_value_terms(x, w, &mut buffer))
                .collect()
        });
        let (mut energy, mut penalty) = (0.0, 0.0);
        for (e, p) in terms.into_iter().flatten() {
            energy += e;
            penalty += p;
        }
        self.objective(x, (energy, penalty), lambda, mu)
    }

    /// Fit cost: data term of the ranges plus the energies.
    pub fn fit_cost(&self, x: &[f64]) -> f64 {
        let mut buffer = Vec::new();
        let mut total = 0.0;
        for j in 0..self.rho.len() {
            let dr = x[2 * j] - self.rho[j];
            total += 0.5 * self.w_rho[j] * dr * dr;
        }
        for &(start, topology) in &self.windows {
            let priorlet = self.prior.priorlet(topology);
            priorlet.eval(self.local(x, start), self.local_phi(start), &mut buffer);
            for &e in &priorlet.energies {
                total += buffer[e];
            }
        }
        total
    }

    /// The data term's weight of reading `j`'s normal: its initial value's inverse variance.
    fn normal_weight(&self, j: usize) -> f64 {
        1.0 / (self.alpha_sigma[j] * self.alpha_sigma[j])
    }

    /// The data term's and the barrier's curvature (`barrier_curvature`, per coordinate) on
    /// the diagonal of a band with the windows' width.
    fn data_band(&self, barrier_curvature: &[f64]) -> Band {
        let mut band = Band::new(self.dim(), 2 * self.prior.order - 1);
        for j in 0..self.rho.len() {
            *band.at(2 * j, 2 * j) += self.w_rho[j];
            *band.at(2 * j + 1, 2 * j + 1) += self.normal_weight(j);
        }
        for (i, &c) in barrier_curvature.iter().enumerate() {
            *band.at(i, i) += c;
        }
        band
    }

    /// Value, gradient and banded Hessian of the objective at `x`, from the windows' `sums`
    /// there (exact Hessians): the data term, the barrier with the Newton model's
    /// `barrier_curvature`, and the windows' energies plus `lambda` times their penalties.
    /// `known`: the value, when the caller has it ([`Problem::objective`] at `x` with these
    /// `sums`, `lambda` and `mu`, as the line search computes it for the point it accepts).
    fn assemble(
        &self,
        (x, sums, known): (&[f64], &WindowSums, Option<f64>),
        (lambda, mu): (f64, f64),
        barrier_curvature: &[f64],
    ) -> Result<Evaluation> {
        let value = known
            .or_else(|| self.objective(x, (sums.energy.value, sums.penalty.value), lambda, mu))
            .filter(|_| sums.energy.gradient.iter().all(|g| g.is_finite()))
            .filter(|_| sums.penalty.gradient.iter().all(|g| g.is_finite()))
            .ok_or_else(|| {
                PriorError::Numerical(
                    "objective or gradient not finite during the Newton steps".into(),
                )
            })?;
        let mut gradient = vec![0.0; self.dim()];
        for j in 0..self.rho.len() {
            gradient[2 * j] = self.w_rho[j] * (x[2 * j] - self.rho[j]);
            gradient[2 * j + 1] = self.normal_weight(j) * (x[2 * j + 1] - self.alpha0[j]);
        }
        for (i, g) in gradient.iter_mut().enumerate() {
            let (a, b) = (x[i] - self.lo[i], self.hi[i] - x[i]);
            *g += mu * (-1.0 / a + 1.0 / b)
                + sums.energy.gradient[i]
                + lambda * sums.penalty.gradient[i];
        }
        let mut band = self.data_band(barrier_curvature);
        for (entry, (e, p)) in band
            .data
            .iter_mut()
            .zip(sums.energy.band.data.iter().zip(&sums.penalty.band.data))
        {
            *entry += e + lambda * p;
        }
        Ok(Evaluation {
            value,
            gradient,
            band,
        })
    }

    /// Every window's terms at `x`, the energies and the penalties apart
    /// ([`split_window_terms`]). The windows are evaluated in parallel (rayon) in chunks of
    /// [`WINDOW_CHUNK`] and their terms added in window order, as a serial loop adds them:
    /// the sums are the same bit for bit for any number of threads.
    fn window_sums(&self, x: &[f64]) -> WindowSums {
        match self.prior.order {
            2 => self.window_sums_of::<4>(x),
            3 => self.window_sums_of::<6>(x),
            _ => self.window_sums_of::<8>(x),
        }
    }

    /// Window `w`'s priorlet and its tape nodes with their derivatives at `x`; `None` when
    /// the priorlet states nothing.
    fn window_derivatives<'n, const N: usize>(
        &self,
        x: &[f64],
        w: usize,
        nodes: &'n mut SparseNodes<N>,
    ) -> Option<(&Priorlet, &'n [Sparse<N>])> {
        let (start, topology) = self.windows[w];
        let priorlet = self.prior.priorlet(topology);
        if priorlet.is_empty() {
            return None;
        }
        let (local, phi) = (self.local(x, start), self.local_phi(start));
        let nodes = self
            .plan
            .derivatives(self.prior, (w, topology), local, phi, nodes);
        Some((priorlet, nodes))
    }

    /// The split terms of `windows` at `x`.
    fn chunk_terms<const N: usize>(
        &self,
        x: &[f64],
        windows: std::ops::Range<usize>,
    ) -> Vec<SplitTerms<N>> {
        let mut nodes = SparseNodes::<N>::new();
        let mut out = Vec::with_capacity(windows.len());
        for w in windows {
            if let Some((priorlet, buffer)) = self.window_derivatives(x, w, &mut nodes) {
                let (energy, penalty, violation) = split_window_terms(priorlet, buffer);
                out.push(SplitTerms {
                    window: w,
                    energy,
                    penalty,
                    violation,
                });
            }
        }
        out
    }

    fn window_sums_of<const N: usize>(&self, x: &[f64]) -> WindowSums {
        let k = 2 * self.prior.order;
        let terms = self.per_chunk(|windows| self.chunk_terms::<N>(x, windows));
        let (n, width) = (self.dim(), 2 * self.prior.order - 1);
        let sum = || WindowSum {
            value: 0.0,
            gradient: vec![0.0; n],
            band: Band::new(n, width),
        };
        let mut sums = WindowSums {
            energy: sum(),
            penalty: sum(),
            violations: vec![0.0; self.windows.len()],
        };
        for t in terms.iter().flatten() {
            let start = self.windows[t.window].0;
            sums.violations[t.window] = t.violation;
            for (total, term) in [
                (&mut sums.energy, &t.energy),
                (&mut sums.penalty, &t.penalty),
            ] {
                total.value += term.v;
                let hessian = symmetrized(&term.h, k);
                for i in 0..k {
                    total.gradient[2 * start + i] += term.g[i];
                    for j in 0..=i {
                        *total.band.at(2 * start + i, 2 * start + j) += hessian[i][j];
                    }
                }
            }
        }
        sums
    }

    /// The Newton model's banded Hessian at `x` with every window's Hessian (energies plus
    /// `lambda` times penalties) convexified ([`convexify_from`]), for the steps where the
    /// exact one is not positive definite: the data term's and the barrier's curvature
    /// (`barrier_curvature`) plus the windows'. `bases` holds each window's eigenvectors of the
    /// previous convexified evaluation (empty: none yet) and receives this one's.
    fn convexified_band(
        &self,
        x: &[f64],
        lambda: f64,
        barrier_curvature: &[f64],
        bases: &mut Vec<f64>,
    ) -> Band {
        let mut band = self.data_band(barrier_curvature);
        match self.prior.order {
            2 => self.add_convexified_windows::<4>(x, lambda, &mut band, bases),
            3 => self.add_convexified_windows::<6>(x, lambda, &mut band, bases),
            _ => self.add_convexified_windows::<8>(x, lambda, &mut band, bases),
        }
        band
    }

    /// Adds every window's convexified Hessian of its energies plus `lambda` times its
    /// penalties ([`convexify`]) to `band`. The windows are evaluated in parallel (rayon) in
    /// chunks of [`WINDOW_CHUNK`], each into its own terms, which are then added in window
    /// order, as a serial loop adds them: the sums are the same bit for bit for any number of
    /// threads.
    ///
    /// Each window's eigen-decomposition starts from its eigenvectors of the previous
    /// convexified evaluation, `N x N` numbers per window in `bases` (identity matrices when
    /// `bases` does not have that length), which receives the new ones.
    fn add_convexified_windows<const N: usize>(
        &self,
        x: &[f64],
        lambda: f64,
        band: &mut Band,
        bases: &mut Vec<f64>,
    ) {
        let k = 2 * self.prior.order;
        if bases.len() != self.windows.len() * N * N {
            bases.clear();
            for _ in &self.windows {
                for i in 0..N {
                    bases.extend((0..N).map(|j| if i == j { 1.0 } else { 0.0 }));
                }
            }
        }
        let terms: Vec<Vec<(usize, [[f64; N]; N])>> = self
            .windows
            .par_chunks(WINDOW_CHUNK)
            .zip(bases.par_chunks_mut(WINDOW_CHUNK * N * N))
            .enumerate()
            .map(|(c, (chunk, chunk_bases))| {
                let mut nodes = SparseNodes::<N>::new();
                let mut out = Vec::with_capacity(chunk.len());
                for (i, &(start, _)) in chunk.iter().enumerate() {
                    let w = c * WINDOW_CHUNK + i;
                    let Some((priorlet, buffer)) = self.window_derivatives(x, w, &mut nodes) else {
                        continue;
                    };
                    let total = window_terms(priorlet, buffer, lambda);
                    let stored = &mut chunk_bases[i * N * N..(i + 1) * N * N];
                    out.push((start, convexify_stored(&total.h, k, stored)));
                }
                out
            })
            .collect();
        for (start, hessian) in terms.iter().flatten() {
            for i in 0..k {
                for j in 0..=i {
                    *band.at(2 * start + i, 2 * start + j) += hessian[i][j];
                }
            }
        }
    }
}

/// The leading `k x k` block of `(h + h^T) / 2`.
fn symmetrized<const N: usize>(h: &[[f64; N]; N], k: usize) -> [[f64; N]; N] {
    let mut m = [[0.0; N]; N];
    for i in 0..k {
        for j in 0..k {
            m[i][j] = 0.5 * (h[i][j] + h[j][i]);
        }
    }
    m
}

/// [`convexify_from`] with the engine's floor, the basis read from and written back to
/// `stored` (`N x N` numbers, row by row).
fn convexify_stored<const N: usize>(
    h: &[[f64; N]; N],
    k: usize,
    stored: &mut [f64],
) -> [[f64; N]; N] {
    let mut basis = [[0.0; N]; N];
    for (r, row) in basis.iter_mut().enumerate() {
        row.copy_from_slice(&stored[r * N..(r + 1) * N]);
    }
    let hessian = convexify_from::<N>(h, k, |largest| 1e-9 * largest.max(1.0), &mut basis);
    for (r, row) in basis.iter().enumerate() {
        stored[r * N..(r + 1) * N].copy_from_slice(row);
    }
    hessian
}

/// Problems with at least this many windows evaluate their windows in parallel
/// ([`Problem::window_sums`], [`Problem::value`]); smaller ones on the calling thread, where
/// waking a second thread costs about what it saves.
const PARALLEL_WINDOWS: usize = 64;

/// Windows per parallel task in [`Problem::add_windows`] (a window costs about a
/// microsecond, mostly its eigen-decomposition).
const WINDOW_CHUNK: usize = 16;

/// What one window adds to the objective, over its `2 order` inputs: its energies, its
/// penalties (without `lambda`) and its largest constraint violation.
struct SplitTerms<const N: usize> {
    window: usize,
    energy: Sparse<N>,
    penalty: Sparse<N>,
    violation: f64,
}

/// The windows' energies or their penalties (squared violations, without `lambda`) summed
/// at one point: value, gradient and banded Hessian (each window's symmetrized).
struct WindowSum {
    value: f64,
    gradient: Vec<f64>,
    band: Band,
}

/// Every window's terms at one point, the energies and the penalties apart, so that one
/// evaluation serves any penalty weight (`energy + lambda penalty`): the line search's
/// accepted trial point is where the next Newton step starts, in its homotopy stage or the
/// next, without evaluating the windows again.
struct WindowSums {
    energy: WindowSum,
    penalty: WindowSum,
    /// Each window's largest constraint violation (0 for a window with no constraint).
    violations: Vec<f64>,
}

/// A window's energies, its penalties (each constraint's smallest branch squared, without
/// `lambda`; NaN when a constraint's value is) and its largest violation, from the window's
/// tape `nodes`. Values are those of [`Problem::window_value_terms`] bit for bit.
fn split_window_terms<const N: usize>(
    priorlet: &Priorlet,
    nodes: &[Sparse<N>],
) -> (Sparse<N>, Sparse<N>, f64) {
    let inputs = |mask: u8| crate::dual::bits::<N>(mask);
    let mut energy = Sparse::<N>::constant(0.0);
    for &e in &priorlet.energies {
        let (index, count) = inputs(energy.mask | nodes[e].mask);
        energy.add_assign(&nodes[e], &index[..count]);
    }
    let mut penalty = Sparse::<N>::constant(0.0);
    let mut largest = 0.0_f64;
    for c in &priorlet.constraints {
        let (p, branch) = constraint_penalty(|k| nodes[k].v, &c.branches);
        largest = largest.max(p.sqrt());
        if p > 0.0 {
            // The smallest branch is violated: its value `f` is nonzero (an equality) or
            // positive (an inequality), and the penalty is `f^2`.
            let f = &nodes[c.branches[branch].node];
            let (index, count) = inputs(f.mask);
            let mut square = Sparse::constant(0.0);
            square.set_mul(f, f, &index[..count]);
            let (index, count) = inputs(penalty.mask | f.mask);
            penalty.add_assign(&square, &index[..count]);
        } else if p.is_nan() {
            penalty.v = f64::NAN;
        }
    }
    (energy, penalty, largest)
}

/// Value, gradient and Hessian of a window's energies plus `lambda` times its penalties, from
/// the window's tape `nodes`.
fn window_terms<const N: usize>(
    priorlet: &Priorlet,
    nodes: &[Sparse<N>],
    lambda: f64,
) -> Sparse<N> {
    let mut total = Sparse::<N>::constant(0.0);
    let inputs = |mask: u8| crate::dual::bits::<N>(mask);
    for &e in &priorlet.energies {
        let (index, count) = inputs(total.mask | nodes[e].mask);
        total.add_assign(&nodes[e], &index[..count]);
    }
    for c in &priorlet.constraints {
        let (penalty, branch) = constraint_penalty(|k| nodes[k].v, &c.branches);
        if penalty > 0.0 {
            let atom = c.branches[branch];
            let f = &nodes[atom.node];
            let active = match atom.kind {
                AtomKind::Equal => true,
                AtomKind::AtMost => f.v > 0.0,
            };
            if active {
                // total + (lambda * f) * f, as duals compute it (lambda * f is a product by
                // a constant: each of its entries is lambda times f's).
                let (index, count) = inputs(f.mask);
                let mut scaled = Sparse::constant(0.0);
                scaled.set_scaled(lambda, f, &index[..count]);
                let mut square = Sparse::constant(0.0);
                square.set_mul(&scaled, f, &index[..count]);
                let (index, count) = inputs(total.mask | f.mask);
                total.add_assign(&square, &index[..count]);
            }
        }
    }
    total
}

/// Eigen-decomposition of the leading `k x k` block of a symmetric matrix `a` by the cyclic
/// Jacobi method: `(eigenvalues, eigenvectors as columns)`, in no particular order; entries
/// past `k` are zero. Only the lower triangle of the block is read. Each rotation zeroes one
/// off-diagonal entry (the stable formulas of Rutishauser); the sweeps stop when every
/// off-diagonal entry is negligible against the diagonal entries it couples or its square
/// against the block's squared Frobenius norm (a few sweeps: the convergence is quadratic).
/// A block with an entry that is not finite is returned as it is, with the identity as
/// eigenvectors (no panic, no endless loop; there are at most [`JACOBI_MAX_SWEEPS`] sweeps).
///
/// For the engine's 4 x 4 windows (priors of order 2) this executes about 2,800 instructions
/// against about 4,150 for nalgebra's `SymmetricEigen` (Householder tridiagonalization and
/// implicit QR, which the tests use as the reference), and takes less time still: the
/// rotations are paired so that their square roots and divisions overlap.
pub(crate) fn symmetric_eigen<const N: usize>(
    a: &[[f64; N]; N],
    k: usize,
) -> ([f64; N], [[f64; N]; N]) {
    let k = k.min(N);
    let mut m = [[0.0; N]; N];
    for i in 0..k {
        for j in 0..=i {
            m[i][j] = a[i][j];
            m[j][i] = a[i][j];
        }
    }
    let mut vectors = [[0.0; N]; N];
    // The whole array (the engine's case) with loops of constant length.
    if k == N {
        jacobi(&mut m, &mut vectors, N);
    } else {
        jacobi(&mut m, &mut vectors, k);
    }
    let mut values = [0.0; N];
    for (e, value) in values.iter_mut().enumerate().take(k) {
        *value = m[e][e];
    }
    (values, vectors)
}

/// Upper bound on the Jacobi sweeps of [`symmetric_eigen`] (a 4 x 4 block takes 3 to 5).
const JACOBI_MAX_SWEEPS: usize = 30;

/// Cyclic Jacobi on the leading `k x k` block of the symmetric `m` (both triangles stored):
/// `m` becomes diagonal (the eigenvalues) and `v` the eigenvectors as columns.
#[inline(always)]
fn jacobi<const N: usize>(m: &mut [[f64; N]; N], v: &mut [[f64; N]; N], k: usize) {
    for (i, row) in v.iter_mut().enumerate().take(k) {
        row[i] = 1.0;
    }
    // Sums of squares of the entries divided by the largest (no overflow, no underflow).
    let mut largest = 0.0_f64;
    for row in m.iter().take(k) {
        for x in row.iter().take(k) {
            largest = largest.max(x.abs());
        }
    }
    // A zero block or an infinite entry: nothing to do.
    if !(largest > 0.0 && largest.is_finite()) {
        return;
    }
    let inverse = 1.0 / largest;
    let mut norm2 = 0.0;
    for row in m.iter().take(k) {
        for x in row.iter().take(k) {
            norm2 += (x * inverse) * (x * inverse);
        }
    }
    // A NaN (which `f64::max` skips): nothing to do.
    if !norm2.is_finite() {
        return;
    }
    // Off-diagonal squares below this are zero against the block's norm (half an ulp).
    let negligible2 = norm2 * (0.25 * f64::EPSILON * f64::EPSILON);
    for _ in 0..JACOBI_MAX_SWEEPS {
        let mut off2 = 0.0;
        for p in 0..k {
            for q in p + 1..k {
                off2 += (m[p][q] * inverse) * (m[p][q] * inverse);
            }
        }
        if off2 <= negligible2 {
            return;
        }
        if k == 4 {
            // The engine's windows (priors of order 2): the six rotations with constant
            // indices, so the loops unroll and the bounds checks go.
            // Disjoint pairs one after the other: their two rotations are independent, so
            // the processor overlaps their divisions and square roots.
            rotate(m, v, 0, 1, 4, inverse);
            rotate(m, v, 2, 3, 4, inverse);
            rotate(m, v, 0, 2, 4, inverse);
            rotate(m, v, 1, 3, 4, inverse);
            rotate(m, v, 0, 3, 4, inverse);
            rotate(m, v, 1, 2, 4, inverse);
        } else {
            for p in 0..k {
                for q in p + 1..k {
                    rotate(m, v, p, q, k, inverse);
                }
            }
        }
    }
}

/// One Jacobi rotation of [`jacobi`]: zeroes `m[p][q]` (`p < q < k`) unless it is already
/// negligible against both `m[p][p]` and `m[q][q]` (then it is set to zero). `inverse` is one
/// over the block's largest entry (the tangent of the angle is computed from the entries
/// scaled by it, which cannot overflow).
#[inline(always)]
fn rotate<const N: usize>(
    m: &mut [[f64; N]; N],
    v: &mut [[f64; N]; N],
    p: usize,
    q: usize,
    k: usize,
    inverse: f64,
) {
    let g = m[p][q];
    let (app, aqq) = (m[p][p], m[q][q]);
    if g == 0.0
        || (app.abs() + 1e2 * g.abs() == app.abs() && aqq.abs() + 1e2 * g.abs() == aqq.abs())
    {
        m[p][q] = 0.0;
        m[q][p] = 0.0;
        return;
    }
    // The tangent of the smaller rotation angle, t = sign(h) 2 g / (|h| + sqrt(h^2 + 4 g^2))
    // with h = aqq - app (Rutishauser's t = sign(theta) / (|theta| + sqrt(theta^2 + 1)),
    // theta = h / 2 g, with one division less on the critical path).
    let (gs, hs) = (g * inverse, (aqq - app) * inverse);
    let mut t = 2.0 * gs * hs.signum() / (hs.abs() + (hs * hs + 4.0 * gs * gs).sqrt());
    if !t.is_finite() {
        // Scaled entries so small that their squares underflow.
        let theta = 0.5 * (aqq - app) / g;
        t = theta.signum() / (theta.abs() + (1.0 + theta * theta).sqrt());
    }
    let root = (1.0 + t * t).sqrt();
    let (s, tau) = (t / root, t / (1.0 + root));
    m[p][p] = app - t * g;
    m[q][q] = aqq + t * g;
    m[p][q] = 0.0;
    m[q][p] = 0.0;
    for r in 0..k {
        if r != p && r != q {
            let (arp, arq) = (m[r][p], m[r][q]);
            let new_p = arp - s * (arq + tau * arp);
            let new_q = arq + s * (arp - tau * arq);
            m[r][p] = new_p;
            m[p][r] = new_p;
            m[r][q] = new_q;
            m[q][r] = new_q;
        }
    }
    for row in v.iter_mut().take(k) {
        let (vp, vq) = (row[p], row[q]);
        row[p] = vp - s * (vq + tau * vp);
        row[q] = vq + s * (vp - tau * vq);
    }
}

/// The symmetric `k x k` matrix `h` with its negative eigenvalues raised to `floor_of(largest)`
/// (Algorithm 2, line 12: "convexify"): `h + sum (floor - lambda_e) v_e v_e^T` over the
/// eigenpairs `(lambda_e, v_e)` below the floor, where `largest` is the largest eigenvalue
/// magnitude. `h` is symmetrized first; a matrix with an entry that is not finite gives zero.
pub(crate) fn convexify<const N: usize>(
    h: &[[f64; N]; N],
    k: usize,
    floor_of: impl Fn(f64) -> f64,
) -> [[f64; N]; N] {
    let mut basis = [[0.0; N]; N];
    for (i, row) in basis.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    convexify_from(h, k, floor_of, &mut basis)
}

/// [`convexify`] with the eigen-decomposition started from `basis`, whose columns are the
/// eigenvectors of a nearby matrix (the same window at the previous Newton step): the
/// Jacobi sweeps run on `B^T h B` (`B`: the columns of `basis` made orthonormal by
/// Gram-Schmidt), which is nearly diagonal, and take about half as many sweeps as from the
/// identity. `basis` receives the new eigenvectors (it is left as it is when `h` has an entry
/// that is not finite). From the identity this is [`convexify`] bit for bit.
pub(crate) fn convexify_from<const N: usize>(
    h: &[[f64; N]; N],
    k: usize,
    floor_of: impl Fn(f64) -> f64,
    basis: &mut [[f64; N]; N],
) -> [[f64; N]; N] {
    // The whole array (the engine's case) with loops of constant length.
    if k >= N {
        convexify_block(h, N, floor_of, basis)
    } else {
        convexify_block(h, k, floor_of, basis)
    }
}

/// [`convexify_from`] on the leading `k x k` block (`k <= N`).
#[inline(always)]
fn convexify_block<const N: usize>(
    h: &[[f64; N]; N],
    k: usize,
    floor_of: impl Fn(f64) -> f64,
    basis: &mut [[f64; N]; N],
) -> [[f64; N]; N] {
    let mut m = [[0.0; N]; N];
    for i in 0..k {
        for j in 0..k {
            m[i][j] = 0.5 * (h[i][j] + h[j][i]);
        }
    }
    if !m.iter().flatten().all(|v| v.is_finite()) {
        return [[0.0; N]; N];
    }
    if !orthonormalize(basis, k) {
        // A degenerate basis (never from the engine): start from the identity.
        *basis = [[0.0; N]; N];
        for (i, row) in basis.iter_mut().enumerate().take(k) {
            row[i] = 1.0;
        }
    }
    // t = B^T m B (lower triangle; `symmetric_eigen` reads only that).
    let mut mb = [[0.0; N]; N];
    for i in 0..k {
        for j in 0..k {
            let mut s = 0.0;
            for r in 0..k {
                s += m[i][r] * basis[r][j];
            }
            mb[i][j] = s;
        }
    }
    let mut t = [[0.0; N]; N];
    for i in 0..k {
        for j in 0..=i {
            let mut s = 0.0;
            for r in 0..k {
                s += basis[r][i] * mb[r][j];
            }
            t[i][j] = s;
        }
    }
    let (values, rotation) = symmetric_eigen(&t, k);
    // The eigenvectors of m: B times those of t.
    let mut vectors = [[0.0; N]; N];
    for i in 0..k {
        for j in 0..k {
            let mut s = 0.0;
            for r in 0..k {
                s += basis[i][r] * rotation[r][j];
            }
            vectors[i][j] = s;
        }
    }
    *basis = vectors;
    let largest = values[..k].iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let floor = floor_of(largest);
    for e in 0..k {
        let raise = floor - values[e];
        if raise > 0.0 {
            for i in 0..k {
                let w = raise * vectors[i][e];
                for j in 0..=i {
                    m[i][j] += w * vectors[j][e];
                }
            }
            for i in 0..k {
                for j in 0..i {
                    m[j][i] = m[i][j];
                }
            }
        }
    }
    m
}

/// Makes the first `k` columns of `basis` orthonormal (modified Gram-Schmidt, in column
/// order); the identity stays the identity bit for bit. `false` when a column has no
/// length left (or is not finite).
#[inline(always)]
fn orthonormalize<const N: usize>(basis: &mut [[f64; N]; N], k: usize) -> bool {
    for j in 0..k {
        for p in 0..j {
            let mut dot = 0.0;
            for row in basis.iter().take(k) {
                dot += row[p] * row[j];
            }
            if dot != 0.0 {
                for row in basis.iter_mut().take(k) {
                    row[j] -= dot * row[p];
                }
            }
        }
        let mut norm2 = 0.0;
        for row in basis.iter().take(k) {
            norm2 += row[j] * row[j];
        }
        if !(norm2 > 1e-3 && norm2.is_finite()) {
            return false;
        }
        if norm2 != 1.0 {
            let inverse = 1.0 / norm2.sqrt();
            for row in basis.iter_mut().take(k) {
                row[j] *= inverse;
            }
        }
    }
    true
}

/// What an inner optimization returns.
pub(crate) struct Inner {
    pub x: Vec<f64>,
    pub feasible: bool,
    pub max_violation: f64,
    /// Penalty attributed to each link (sum of squared violations of the windows across it).
    pub link_penalties: Vec<f64>,
}

/// Algorithm 2: the continuous optimization of `x` for a fixed INMODEL and topology.
pub(crate) fn inner_optimization(problem: &Problem, params: &Params) -> Result<Inner> {
    let mut x: Vec<f64> = (0..problem.rho.len())
        .flat_map(|j| [problem.rho[j], problem.alpha0[j]])
        .collect();
    let mut lambda = params.penalty_start;
    let mut mu = params.barrier_start;
    let mut history = Vec::new();
    let mut polish = 0;
    let mut bases = Vec::new();
    let mut duals = BoundDuals::new(&x, (&problem.lo, &problem.hi), mu);
    let mut sums = problem.window_sums(&x);
    loop {
        newton(
            problem,
            (&mut x, &mut sums),
            (lambda, mu),
            params,
            (&mut bases, &mut duals),
        )?;
        let violations = &sums.violations;
        let max_violation = violations.iter().fold(0.0, |a: f64, &v| a.max(v));
        let feasible = max_violation < params.feasibility_tolerance;
        // A feasible topology's violation falls about as fast as lambda grows; one that
        // stalls over two stages (past the first three) will not become feasible.
        history.push(max_violation);
        let h = history.len();
        let stalled = h >= 5
            && history[h - 1] > params.stall_ratio * history[h - 2]
            && history[h - 2] > params.stall_ratio * history[h - 3];
        if feasible {
            polish += 1;
        }
        let polished = feasible && polish > params.polish_stages;
        if polished || (!feasible && stalled) || lambda >= params.penalty_max {
            let m = problem.rho.len();
            let mut link_penalties = vec![0.0; m.saturating_sub(1)];
            for (&(start, _), v) in problem.windows.iter().zip(violations) {
                for link in start..start + problem.prior.order - 1 {
                    link_penalties[link] += v * v;
                }
            }
            return Ok(Inner {
                x,
                feasible,
                max_violation,
                link_penalties,
            });
        }
        lambda *= params.penalty_factor;
        mu *= params.barrier_factor;
        duals = BoundDuals::new(&x, (&problem.lo, &problem.hi), mu);
    }
}

/// The Newton model at `x` (where the windows' terms are `sums`) and its step: with the
/// exact Hessian when the banded sum is positive definite (its Cholesky factor exists), as
/// it is at nearly every step; otherwise with each window's Hessian convexified
/// ([`Problem::convexified_band`]) and, should even that fail to factor, a growing multiple
/// of the identity added.
fn newton_direction(
    problem: &Problem,
    point: (&[f64], &WindowSums, Option<f64>),
    (lambda, mu): (f64, f64),
    barrier_curvature: &[f64],
    bases: &mut Vec<f64>,
) -> Result<(Evaluation, Vec<f64>)> {
    let x = point.0;
    let mut eval = problem.assemble(point, (lambda, mu), barrier_curvature)?;
    let rhs: Vec<f64> = eval.gradient.iter().map(|g| -g).collect();
    if let Some(direction) = eval.band.solve(&rhs, 0.0) {
        return Ok((eval, direction));
    }
    eval.band = problem.convexified_band(x, lambda, barrier_curvature, bases);
    let mut shift = 0.0;
    loop {
        if let Some(direction) = eval.band.solve(&rhs, shift) {
            return Ok((eval, direction));
        }
        shift = if shift == 0.0 { 1e-8 } else { shift * 100.0 };
        if shift > 1e12 {
            return Err(PriorError::Numerical("Hessian cannot be factored".into()));
        }
    }
}

/// The Newton steps of one homotopy stage from `x`, where the windows' terms are `sums`;
/// both are moved to the stage's last point. Returns the number of steps.
fn newton(
    problem: &Problem,
    (x, sums): (&mut Vec<f64>, &mut WindowSums),
    (lambda, mu): (f64, f64),
    params: &Params,
    (bases, duals): (&mut Vec<f64>, &mut BoundDuals),
) -> Result<usize> {
    let bounds = (problem.lo.as_slice(), problem.hi.as_slice());
    // The objective at `x`, once the line search has computed it.
    let mut known = None;
    for step_count in 0..params.max_newton_steps {
        let curvature = duals.curvature(x, bounds);
        let (eval, direction) =
            newton_direction(problem, (x, sums, known), (lambda, mu), &curvature, bases)?;
        let slope = eval.slope(&direction);
        if -slope < 1e-12 * (1.0 + eval.value.abs()) {
            return Ok(step_count);
        }
        // At most a fraction of the way to the nearest bound (the barrier's domain).
        let mut step = step_to_boundary(x, &direction, (&problem.lo, &problem.hi));
        let mut accepted = false;
        let mut trial = x.clone();
        // The first trial point is evaluated with the windows' derivatives, since it is
        // nearly always accepted and then is where the next step starts; a shorter one by
        // its value alone.
        let (mut first, mut at_first) = (true, None);
        while step > 1e-14 {
            for i in 0..x.len() {
                trial[i] = x[i] + step * direction[i];
            }
            let value = if first {
                first = false;
                let at_trial = problem.window_sums(&trial);
                let terms = (at_trial.energy.value, at_trial.penalty.value);
                at_first = Some(at_trial);
                problem.objective(&trial, terms, lambda, mu)
            } else {
                problem.value(&trial, lambda, mu)
            };
            if let Some(v) = value
                && v <= eval.value + 1e-4 * step * slope
            {
                accepted = true;
                known = Some(v);
                break;
            }
            // Rejected: the first trial's terms are of no further use.
            at_first = None;
            step *= 0.5;
        }
        if !accepted {
            return Ok(step_count);
        }
        duals.update(x, &direction, mu, bounds);
        std::mem::swap(x, &mut trial);
        duals.safeguard(x, mu, bounds);
        *sums = match at_first {
            Some(at_trial) => at_trial,
            None => problem.window_sums(x),
        };
        // A full step from a point this close to the minimum lands where the next evaluation
        // would find the stopping test above met (Newton converges quadratically there): the
        // stage ends at once, without that evaluation.
        if step == 1.0 && -slope < FINAL_STEP_DECREMENT * (1.0 + eval.value.abs()) {
            return Ok(step_count + 1);
        }
    }
    Ok(params.max_newton_steps)
}

/// The multipliers of the bounds (primal-dual interior point, as IPOPT's): `z_lo (x - lo) =
/// mu` and `z_hi (hi - x) = mu` at a stage's solution; each stage starts from these values at
/// its first point (the central path). The Newton model's curvature of the barrier is
/// `z_lo / (x - lo) + z_hi / (hi - x)` instead of the primal barrier's `mu / (x - lo)^2 +
/// mu / (hi - x)^2`: near a bound the latter changes so fast that Newton steps crawl towards it.
struct BoundDuals {
    lower: Vec<f64>,
    upper: Vec<f64>,
}

/// How far [`BoundDuals`] may stray from `mu / slack` (IPOPT's kappa_Sigma).
const DUAL_SAFEGUARD: f64 = 1e10;

impl BoundDuals {
    /// The multipliers on the central path at `x` for the barrier weight `mu`.
    fn new(x: &[f64], (lo, hi): (&[f64], &[f64]), mu: f64) -> BoundDuals {
        BoundDuals {
            lower: (0..x.len()).map(|i| mu / (x[i] - lo[i])).collect(),
            upper: (0..x.len()).map(|i| mu / (hi[i] - x[i])).collect(),
        }
    }

    /// The barrier's curvature in the Newton model at `x`, per coordinate.
    fn curvature(&self, x: &[f64], (lo, hi): (&[f64], &[f64])) -> Vec<f64> {
        (0..x.len())
            .map(|i| self.lower[i] / (x[i] - lo[i]) + self.upper[i] / (hi[i] - x[i]))
            .collect()
    }

    /// The Newton step of the multipliers for the primal step `direction` from `x`, taken at
    /// most [`FRACTION_TO_BOUNDARY`] of the way to zero, then kept within a factor
    /// [`DUAL_SAFEGUARD`] of `mu / slack` at the new point `x + step direction`.
    fn update(&mut self, x: &[f64], direction: &[f64], mu: f64, (lo, hi): (&[f64], &[f64])) {
        let n = x.len();
        let mut change = vec![0.0; 2 * n];
        let mut step = 1.0_f64;
        for i in 0..n {
            let (a, b) = (x[i] - lo[i], hi[i] - x[i]);
            change[i] = mu / a - self.lower[i] - self.lower[i] / a * direction[i];
            change[n + i] = mu / b - self.upper[i] + self.upper[i] / b * direction[i];
            for (z, dz) in [(self.lower[i], change[i]), (self.upper[i], change[n + i])] {
                if dz < 0.0 {
                    step = step.min(FRACTION_TO_BOUNDARY * z / -dz);
                }
            }
        }
        for i in 0..n {
            self.lower[i] += step * change[i];
            self.upper[i] += step * change[n + i];
        }
    }

    /// Keeps each multiplier within a factor [`DUAL_SAFEGUARD`] of `mu / slack` at `x`.
    fn safeguard(&mut self, x: &[f64], mu: f64, (lo, hi): (&[f64], &[f64])) {
        for i in 0..x.len() {
            let (a, b) = (x[i] - lo[i], hi[i] - x[i]);
            self.lower[i] = safeguarded(self.lower[i], mu, a);
            self.upper[i] = safeguarded(self.upper[i], mu, b);
        }
    }
}

/// `z` within a factor [`DUAL_SAFEGUARD`] of `mu / slack` (`max` then `min`, which never
/// panic, where `f64::clamp` would on limits out of order).
fn safeguarded(z: f64, mu: f64, slack: f64) -> f64 {
    z.max(mu / (DUAL_SAFEGUARD * slack))
        .min(DUAL_SAFEGUARD * mu / slack)
}

/// The longest step along `direction`, at most 1, that goes at most [`FRACTION_TO_BOUNDARY`]
/// of the way from `x` to the bounds `lo` and `hi` (the fraction-to-the-boundary rule of
/// interior-point methods): the line search starts inside the barrier's domain instead of
/// halving its way back into it.
fn step_to_boundary(x: &[f64], direction: &[f64], (lo, hi): (&[f64], &[f64])) -> f64 {
    let mut step = 1.0_f64;
    for i in 0..x.len() {
        let room = if direction[i] < 0.0 {
            (x[i] - lo[i]) / -direction[i]
        } else if direction[i] > 0.0 {
            (hi[i] - x[i]) / direction[i]
        } else {
            continue;
        };
        step = step.min(FRACTION_TO_BOUNDARY * room);
    }
    step
}

/// How far towards the nearest bound a Newton step may go ([`step_to_boundary`]).
const FRACTION_TO_BOUNDARY: f64 = 0.995;

/// A Newton step taken in full whose decrement (`-gradient . direction`) is below this
/// fraction of `1 + |value|` ends the homotopy stage without a further evaluation: that
/// evaluation would only confirm convergence (decrement below `1e-12` of it), since the
/// decrement falls roughly with its square from one step to the next. It saves one of the
/// 2 to 4 evaluations of a converging stage. (At `1e-11` the engine's solutions on the
/// benchmarked scans are the same bit for bit as without it, but for one circle whose fit
/// cost came out lower; at `1e-9` one Intel scan's fit cost came out higher by `4e-8`.)
const FINAL_STEP_DECREMENT: f64 = 1e-11;

/// Initial normals (facing the sensor, by a total-least-squares line through the neighbours of
/// the same region), their standard deviations and the bounds of `x` (section 3.2).
fn build_problem<'a>(
    prior: &'a Prior,
    input: &ScanInput,
    members: &[usize],
    links: &[Topology],
    params: &Params,
) -> Problem<'a> {
    let m = members.len();
    let points: Vec<[f64; 2]> = members
        .iter()
        .map(|&i| {
            let (s, c) = input.phi[i].sin_cos();
            [input.rho[i] * c, input.rho[i] * s]
        })
        .collect();
    let mut alpha0 = vec![0.0; m];
    let mut alpha_sigma = vec![0.0; m];
    let mut half_width = vec![0.0; m];
    let min_bound = params.min_normal_bound_deg.to_radians();
    let cap = 0.49 * std::f64::consts::PI;
    let w = params.normal_window.max(1);
    for j in 0..m {
        // The reach of the region around j, within the window.
        let mut reach_left = j;
        while reach_left > 0 && j - reach_left < w && links[reach_left - 1] == Topology::SameRegion
        {
            reach_left -= 1;
        }
        let mut reach_right = j;
        while reach_right + 1 < m
            && reach_right - j < w
            && links[reach_right] == Topology::SameRegion
        {
            reach_right += 1;
        }
        let p = points[j];
        let sigma = input.sigma[members[j]];
        if reach_left == reach_right {
            alpha0[j] = (-p[1]).atan2(-p[0]);
            alpha_sigma[j] = std::f64::consts::FRAC_PI_4;
            half_width[j] = cap;
            continue;
        }
        // Candidate windows: left, right and centred; the one with the smallest residual
        // variance wins (robust to an outlier or a corner on one side).
        let half = w / 2;
        let candidates = [
            (reach_left, j),
            (j, reach_right),
            (
                j.saturating_sub(half).max(reach_left),
                (j + w - half).min(reach_right),
            ),
        ];
        let mut best: Option<(f64, f64, f64, f64)> = None; // (score, theta, spread, extent)
        for (first, last) in candidates {
            if last <= first {
                continue;
            }
            let count = (last - first + 1) as f64;
            let (mut cx, mut cy) = (0.0, 0.0);
            for q in &points[first..=last] {
                cx += q[0] / count;
                cy += q[1] / count;
            }
            let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
            for q in &points[first..=last] {
                let (dx, dy) = (q[0] - cx, q[1] - cy);
                sxx += dx * dx;
                sxy += dx * dy;
                syy += dy * dy;
            }
            let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
            let trace = sxx + syy;
            let det = sxx * syy - sxy * sxy;
            let smallest = 0.5 * (trace - (trace * trace - 4.0 * det).max(0.0).sqrt());
            // Residual variance; windows of two points (no residual) rank as one noise level.
            let score = if count > 2.0 {
                smallest.max(0.0) / (count - 2.0)
            } else {
                sigma * sigma
            };
            let (a, b) = (points[first], points[last]);
            let extent = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
            if best.is_none_or(|(s, ..)| score < s * 0.999) {
                best = Some((score, theta, trace.max(1e-12), extent));
            }
        }
        let Some((_, theta, spread, extent)) = best else {
            continue;
        };
        let mut normal = [-theta.sin(), theta.cos()];
        if normal[0] * p[0] + normal[1] * p[1] > 0.0 {
            normal = [-normal[0], -normal[1]];
        }
        alpha0[j] = normal[1].atan2(normal[0]);
        alpha_sigma[j] = (sigma / spread.sqrt()).max(1e-3);
        let curvature = prior.max_curvature.map_or(f64::INFINITY, |k| k * extent);
        half_width[j] = (params.bound_sigmas * alpha_sigma[j] + curvature)
            .max(min_bound)
            .min(cap);
    }
    for j in 1..m {
        let delta = alpha0[j] - alpha0[j - 1];
        alpha0[j] -= (delta / std::f64::consts::TAU).round() * std::f64::consts::TAU;
    }
    let mut lo = Vec::with_capacity(2 * m);
    let mut hi = Vec::with_capacity(2 * m);
    for j in 0..m {
        let i = members[j];
        let r = params.bound_sigmas * input.sigma[i];
        lo.push((input.rho[i] - r).max(0.5 * input.rho[i]));
        hi.push(input.rho[i] + r);
        lo.push(alpha0[j] - half_width[j]);
        hi.push(alpha0[j] + half_width[j]);
    }
    let phi: Vec<f64> = members.iter().map(|&i| input.phi[i]).collect();
    let windows = windows_of(prior.order, links, m);
    Problem {
        prior,
        rho: members.iter().map(|&i| input.rho[i]).collect(),
        w_rho: members
            .iter()
            .map(|&i| 1.0 / (input.sigma[i] * input.sigma[i]))
            .collect(),
        alpha0,
        alpha_sigma,
        lo,
        hi,
        plan: WindowPlan::new(prior, &windows, &phi),
        parallel: windows.len() >= PARALLEL_WINDOWS,
        windows,
        phi,
    }
}

/// The inner optimization of a topology, solved part by part: the runs of readings between
/// links that no priorlet window crosses share no term of the objective, so each run is a
/// problem of its own, and a run whose readings and links were solved before (by an earlier
/// topology of the outer loop) is not solved again.
///
/// Each part's normals are unwrapped from its own first reading; the parts' results are
/// shifted by whole turns to continue the unwrapping of the whole scan (the priorlets see
/// only differences and trigonometric functions of the normals within a part's windows).
///
/// A part's result depends only on its readings and links, so parts that a coming topology
/// will need can be solved ahead, several at once ([`PartSolver::prefetch`]): the results,
/// and the count of inner optimizations reported, are those of solving them one by one.
struct PartSolver<'a> {
    prior: &'a Prior,
    input: &'a ScanInput,
    params: &'a Params,
    /// Results by part: its readings and its links.
    solved: HashMap<PartKey, SolvedPart>,
    /// Parts used so far by [`PartSolver::solve`] (inner optimizations of the topologies
    /// tried; a part solved ahead and never used is not counted).
    inner_optimizations: usize,
}

/// A part: its readings and its links.
type PartKey = (Vec<usize>, Vec<Topology>);

/// A part's inner optimization, with its first and last initial normal (for the unwrapping
/// across parts).
struct SolvedPart {
    inner: Inner,
    first_normal: f64,
    last_normal: f64,
    /// Whether [`PartSolver::solve`] has used it.
    used: bool,
}

impl<'a> PartSolver<'a> {
    fn new(prior: &'a Prior, input: &'a ScanInput, params: &'a Params) -> Self {
        PartSolver {
            prior,
            input,
            params,
            solved: HashMap::new(),
            inner_optimizations: 0,
        }
    }

    /// The inner optimization of one part (not yet used); its windows evaluated in parallel
    /// when it is large enough and `alone` (not one of several parts solved at once).
    fn solve_part(
        (prior, input, params): (&Prior, &ScanInput, &Params),
        (readings, links): &PartKey,
        alone: bool,
    ) -> Result<SolvedPart> {
        let mut problem = build_problem(prior, input, readings, links, params);
        problem.parallel &= alone;
        Ok(SolvedPart {
            inner: inner_optimization(&problem, params)?,
            first_normal: problem.alpha0.first().copied().unwrap_or(0.0),
            last_normal: problem.alpha0.last().copied().unwrap_or(0.0),
            used: false,
        })
    }

    /// Solves the first parts of `topologies` (INMODEL readings and links, in order) that are
    /// not solved yet, as many as there are threads, in parallel, for [`PartSolver::solve`] to
    /// find. A part whose inner optimization fails is left out: `solve` meets the same error
    /// when it needs that part.
    fn prefetch(&mut self, topologies: &[(Vec<usize>, Vec<Topology>)]) {
        let threads = rayon::current_num_threads();
        let mut missing: Vec<PartKey> = Vec::new();
        for (members, links) in topologies {
            if missing.len() >= threads {
                break;
            }
            let mut start = 0;
            for end in part_ends(self.prior, links, members.len()) {
                let key = (members[start..end].to_vec(), links[start..end - 1].to_vec());
                if !self.solved.contains_key(&key) && !missing.contains(&key) {
                    missing.push(key);
                }
                start = end;
            }
        }
        if missing.len() < 2 {
            return;
        }
        let context = (self.prior, self.input, self.params);
        let solved: Vec<(PartKey, Result<SolvedPart>)> = missing
            .into_par_iter()
            .map(|key| {
                let part = Self::solve_part(context, &key, false);
                (key, part)
            })
            .collect();
        for (key, part) in solved {
            if let Ok(part) = part {
                self.solved.insert(key, part);
            }
        }
    }

    /// The inner optimization of INMODEL `members` with `links`, as one [`Inner`] over all
    /// of them.
    fn solve(&mut self, members: &[usize], links: &[Topology]) -> Result<Inner> {
        let m = members.len();
        let mut whole = Inner {
            x: Vec::with_capacity(2 * m),
            feasible: true,
            max_violation: 0.0,
            link_penalties: vec![0.0; m.saturating_sub(1)],
        };
        let mut previous_last_normal: Option<f64> = None;
        let mut start = 0;
        let context = (self.prior, self.input, self.params);
        for end in part_ends(self.prior, links, m) {
            let key = (members[start..end].to_vec(), links[start..end - 1].to_vec());
            let part = match self.solved.entry(key) {
                Entry::Occupied(solved) => solved.into_mut(),
                Entry::Vacant(part) => {
                    let solved = Self::solve_part(context, part.key(), true)?;
                    part.insert(solved)
                }
            };
            if !part.used {
                part.used = true;
                self.inner_optimizations += 1;
            }
            let SolvedPart {
                inner,
                first_normal,
                last_normal,
                ..
            } = &*part;
            // build_problem's unwrapping, continued from the previous part.
            let shift = previous_last_normal.map_or(0.0, |previous| {
                -((first_normal - previous) / std::f64::consts::TAU).round() * std::f64::consts::TAU
            });
            previous_last_normal = Some(last_normal + shift);
            for pair in inner.x.chunks_exact(2) {
                whole.x.push(pair[0]);
                whole.x.push(pair[1] + shift);
            }
            whole.feasible &= inner.feasible;
            whole.max_violation = whole.max_violation.max(inner.max_violation);
            whole.link_penalties[start..end - 1].copy_from_slice(&inner.link_penalties);
            start = end;
        }
        Ok(whole)
    }
}

/// The next weaker topology of a link: same region, then different region, then different
/// surface.
fn relaxed(link: Topology) -> Topology {
    match link {
        Topology::SameRegion => Topology::DifferentRegion,
        _ => Topology::DifferentSurface,
    }
}

/// The topology with region boundary `k` (a link that is not same-region) moved by one
/// reading in `direction` (-1 or 1): link `j = k + direction` takes `k`'s topology and `k`
/// becomes same-region. `(j, topology)`; `None` when `j` is past the ends or a boundary too.
fn moved_boundary(
    links: &[Topology],
    k: usize,
    direction: isize,
) -> Option<(usize, Vec<Topology>)> {
    let j = usize::try_from(k as isize + direction).ok()?;
    if links.get(j) != Some(&Topology::SameRegion) {
        return None;
    }
    let mut trial = links.to_vec();
    trial[j] = trial[k];
    trial[k] = Topology::SameRegion;
    Some((j, trial))
}

/// The ends (exclusive) of the runs of the `m` readings between links that no priorlet
/// window crosses: link `k` (between readings `k` and `k + 1`) splits when it is not
/// same-region (the initial normals look across same-region links) and every window of
/// `order` readings that holds both of its readings has a priorlet that states nothing.
fn part_ends(prior: &Prior, links: &[Topology], m: usize) -> Vec<usize> {
    let order = prior.order;
    let splits = |k: usize| {
        if links[k] == Topology::SameRegion {
            return false;
        }
        if m < order {
            return true;
        }
        let first_window = (k + 2).saturating_sub(order);
        (first_window..=k.min(m - order)).all(|s| {
            prior
                .priorlet(window_topology(&links[s..s + order - 1]))
                .is_empty()
        })
    };
    let mut ends: Vec<usize> = (0..m.saturating_sub(1))
        .filter(|&k| splits(k))
        .map(|k| k + 1)
        .collect();
    if m > 0 {
        ends.push(m);
    }
    ends
}

/// Removes the readings of regions smaller than `min_points`; a link bridging removed
/// readings becomes same-region (the strictest), or different-surface when its two readings
/// are too far apart to be on one surface ([`GapTest`]). Returns whether anything was
/// removed.
fn remove_lonely_points(
    members: &mut Vec<usize>,
    links: &mut Vec<Topology>,
    min_points: usize,
    input: &ScanInput,
    gap: &GapTest,
) -> bool {
    let m = members.len();
    let mut keep = vec![true; m];
    let mut start = 0;
    for j in 0..m {
        if j + 1 == m || links[j] != Topology::SameRegion {
            if j + 1 - start < min_points {
                keep[start..=j].iter_mut().for_each(|k| *k = false);
            }
            start = j + 1;
        }
    }
    if keep.iter().all(|&k| k) {
        return false;
    }
    let mut new_members = Vec::new();
    let mut new_links = Vec::new();
    let mut previous: Option<usize> = None;
    for j in 0..m {
        if !keep[j] {
            continue;
        }
        if let Some(p) = previous {
            new_links.push(if p + 1 == j {
                links[p]
            } else if gap.between(input, members[p], members[j]) {
                Topology::DifferentSurface
            } else {
                Topology::SameRegion
            });
        }
        new_members.push(members[j]);
        previous = Some(j);
    }
    *members = new_members;
    *links = new_links;
    true
}

/// The geometric part of the first topology guess (the source's Fig. 6a): two readings
/// farther apart than a surface seen at [`Params::max_incidence_deg`] would put them (plus
/// 8 sigma) cannot be on one surface. Beams with no return between them count as at most
/// one more beam spacing (a surface there would have answered them).
pub(crate) struct GapTest {
    stretch: Option<f64>,
    spacing: f64,
}

impl GapTest {
    fn new(input: &ScanInput, params: &Params) -> GapTest {
        let mut steps: Vec<f64> = input.phi.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
        steps.sort_by(f64::total_cmp);
        GapTest {
            stretch: (params.max_incidence_deg < 90.0)
                .then(|| 1.0 / params.max_incidence_deg.to_radians().cos()),
            spacing: steps.get(steps.len() / 2).copied().unwrap_or(0.0),
        }
    }

    fn between(&self, input: &ScanInput, a: usize, b: usize) -> bool {
        let Some(stretch) = self.stretch else {
            return false;
        };
        let point = |i: usize| {
            let (s, c) = input.phi[i].sin_cos();
            [input.rho[i] * c, input.rho[i] * s]
        };
        let (p, q) = (point(a), point(b));
        let distance = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
        let beams = (b.abs_diff(a) as f64 * self.spacing).max(self.spacing);
        let angle = (input.phi[b] - input.phi[a])
            .abs()
            .min(beams + self.spacing);
        let expected = input.rho[a].min(input.rho[b]) * angle * stretch;
        distance > expected + 8.0 * input.sigma[a].max(input.sigma[b])
    }
}

/// Runs the inference (Algorithm 1 around Algorithm 2) of `prior` on one scan.
///
/// It runs on a worker thread of rayon's pool (the calling thread waits), so that the
/// parallel evaluation of each Newton step's windows is not handed into the pool from
/// outside at every step.
pub fn infer(prior: &Prior, input: &ScanInput, params: &Params) -> Result<Solution> {
    rayon::scope(|_| infer_on_worker(prior, input, params))
}

fn infer_on_worker(prior: &Prior, input: &ScanInput, params: &Params) -> Result<Solution> {
    params.validate()?;
    input.validate()?;
    let n = input.len();
    if n < prior.order {
        return Err(PriorError::InvalidInput(format!(
            "{n} readings, fewer than the order {} of the prior",
            prior.order
        )));
    }
    let min_points = params.min_region_points.unwrap_or(2 * prior.order).max(1);
    let max_outer = params.max_outer_iterations.unwrap_or(3 * n + 10);
    let mut members: Vec<usize> = (0..n).collect();
    let gap = GapTest::new(input, params);
    let mut links: Vec<Topology> = (0..n - 1)
        .map(|k| {
            if gap.between(input, k, k + 1) {
                Topology::DifferentSurface
            } else {
                Topology::SameRegion
            }
        })
        .collect();
    // Readings isolated by the geometric guess are outliers from the start.
    remove_lonely_points(&mut members, &mut links, min_points, input, &gap);
    if members.len() < prior.order {
        return Err(PriorError::InvalidInput(
            "no run of readings close enough together to be one surface".into(),
        ));
    }
    let mut outer = 0;
    let mut result;
    let mut parts = PartSolver::new(prior, input, params);
    // The first topology's parts at once; later ones change one part at a time.
    parts.prefetch(&[(members.clone(), links.clone())]);
    loop {
        outer += 1;
        result = parts.solve(&members, &links)?;
        if result.feasible || outer >= max_outer || members.len() < prior.order {
            break;
        }
        let candidate = result
            .link_penalties
            .iter()
            .enumerate()
            .filter(|&(k, &p)| links[k] != Topology::DifferentSurface && p > 0.0)
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(k, _)| k);
        let Some(k) = candidate else { break };
        links[k] = relaxed(links[k]);
        remove_lonely_points(&mut members, &mut links, min_points, input, &gap);
        if members.len() < prior.order {
            return Err(PriorError::InvalidInput(
                "every reading was removed from INMODEL: the prior does not describe this scan"
                    .into(),
            ));
        }
    }
    let mut problem = build_problem(prior, input, &members, &links, params);
    if result.feasible && params.refine_boundaries {
        let mut best_cost = problem.fit_cost(&result.x);
        let boundaries: Vec<usize> = (0..links.len())
            .filter(|&k| links[k] != Topology::SameRegion)
            .collect();
        let moves: Vec<(usize, isize)> = boundaries
            .iter()
            .flat_map(|&k0| [(k0, -1), (k0, 1)])
            .collect();
        // A move that would leave a region too small is not tried.
        let keeps_every_reading = |trial: &[Topology]| {
            let (mut trial_members, mut trial_links) = (members.clone(), trial.to_vec());
            !remove_lonely_points(
                &mut trial_members,
                &mut trial_links,
                min_points,
                input,
                &gap,
            )
        };
        for (next, &(k0, direction)) in moves.iter().enumerate() {
            let mut k = k0;
            for _ in 0..3 {
                // This move and the first move of every later boundary and direction from
                // the current topology, solved ahead in parallel.
                let coming =
                    std::iter::once((k, direction)).chain(moves[next + 1..].iter().copied());
                let coming: Vec<(Vec<usize>, Vec<Topology>)> = coming
                    .filter_map(|(k, direction)| moved_boundary(&links, k, direction))
                    .filter(|(_, trial)| keeps_every_reading(trial))
                    .map(|(_, trial)| (members.clone(), trial))
                    .collect();
                parts.prefetch(&coming);
                let Some((j, trial)) = moved_boundary(&links, k, direction) else {
                    break;
                };
                if !keeps_every_reading(&trial) {
                    break;
                }
                let trial_problem = build_problem(prior, input, &members, &trial, params);
                outer += 1;
                let trial_result = parts.solve(&members, &trial)?;
                let cost = trial_problem.fit_cost(&trial_result.x);
                if trial_result.feasible && cost < best_cost - 1e-9 {
                    best_cost = cost;
                    links = trial;
                    result = trial_result;
                    problem = trial_problem;
                    k = j;
                } else {
                    break;
                }
            }
        }
    }
    let fit_cost = problem.fit_cost(&result.x);
    let gamma = (params.inlier_probability / (1.0 - params.inlier_probability)).ln();
    let mut rho = input.rho.clone();
    let mut alpha = vec![f64::NAN; n];
    let mut alpha_sigma = vec![f64::NAN; n];
    let mut in_model = vec![false; n];
    for (j, &i) in members.iter().enumerate() {
        rho[i] = result.x[2 * j];
        alpha[i] = result.x[2 * j + 1];
        alpha_sigma[i] = problem.alpha_sigma[j];
        in_model[i] = true;
    }
    Ok(Solution {
        prior: prior.name.clone(),
        phi: input.phi.clone(),
        measured: input.rho.clone(),
        sigma: input.sigma.clone(),
        rho,
        alpha,
        alpha_sigma,
        in_model,
        links: members
            .windows(2)
            .zip(&links)
            .map(|(w, &topology)| Link {
                from: w[0],
                to: w[1],
                topology,
            })
            .collect(),
        feasible: result.feasible,
        max_violation: result.max_violation,
        outer_iterations: outer,
        inner_optimizations: parts.inner_optimizations,
        fit_cost,
        objective: fit_cost - gamma * members.len() as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use slam_core::nalgebra::{DMatrix, SymmetricEigen};

    /// A random orthogonal `k x k` matrix (a product of `k` Householder reflections) in the
    /// leading block of an `N x N` array.
    fn orthogonal<const N: usize>(k: usize, rng: &mut ChaCha8Rng) -> [[f64; N]; N] {
        let mut q = [[0.0; N]; N];
        for i in 0..k {
            q[i][i] = 1.0;
        }
        for _ in 0..k {
            let v: Vec<f64> = (0..k).map(|_| rng.random_range(-1.0..1.0)).collect();
            let norm2: f64 = v.iter().map(|x| x * x).sum();
            // q = (I - 2 v v^T / |v|^2) q
            for c in 0..k {
                let dot: f64 = (0..k).map(|r| v[r] * q[r][c]).sum();
                for r in 0..k {
                    q[r][c] -= 2.0 * v[r] * dot / norm2;
                }
            }
        }
        q
    }

    /// `Q diag(values) Q^T` in the leading `k x k` block.
    fn compose<const N: usize>(q: &[[f64; N]; N], values: &[f64]) -> [[f64; N]; N] {
        let mut a = [[0.0; N]; N];
        for (e, &value) in values.iter().enumerate() {
            for i in 0..values.len() {
                for j in 0..values.len() {
                    a[i][j] += value * q[i][e] * q[j][e];
                }
            }
        }
        a
    }

    /// The decomposition reproduces `a`, its eigenvectors are orthonormal and the entries
    /// past `k` are zero; returns the eigenvalues, sorted.
    fn check_decomposition<const N: usize>(a: &[[f64; N]; N], k: usize) -> Vec<f64> {
        let (values, vectors) = symmetric_eigen(a, k);
        let scale = a.iter().flatten().fold(1.0_f64, |m, v| m.max(v.abs()));
        for i in 0..N {
            for j in 0..N {
                let recomposed: f64 = (0..k)
                    .map(|e| values[e] * vectors[i][e] * vectors[j][e])
                    .sum();
                let expected = if i < k && j < k { a[i][j] } else { 0.0 };
                assert!(
                    (recomposed - expected).abs() < 1e-12 * scale,
                    "k {k} ({i}, {j}): {recomposed} vs {expected}"
                );
                let dot: f64 = (0..N).map(|r| vectors[r][i] * vectors[r][j]).sum();
                let identity = if i == j && i < k { 1.0 } else { 0.0 };
                assert!(
                    (dot - identity).abs() < 1e-12,
                    "k {k}: V^T V ({i}, {j}) = {dot}"
                );
            }
        }
        assert!(values[k..].iter().all(|&v| v == 0.0));
        let mut sorted = values[..k].to_vec();
        sorted.sort_by(f64::total_cmp);
        sorted
    }

    /// A scan of `beams` bearings spread evenly over `bearings`, each reading the range to
    /// the wall that `wall_of(i)` gives as (its normal towards the sensor, its distance),
    /// plus a few millimetres of deterministic noise when `noisy`.
    fn scan_of_walls(
        beams: usize,
        bearings: (f64, f64),
        wall_of: impl Fn(usize) -> (f64, f64),
        noisy: bool,
    ) -> ScanInput {
        let phi: Vec<f64> = (0..beams)
            .map(|i| bearings.0 + (bearings.1 - bearings.0) * i as f64 / (beams - 1) as f64)
            .collect();
        let rho = phi
            .iter()
            .enumerate()
            .map(|(i, &angle)| {
                let (normal, distance) = wall_of(i);
                let noise = if noisy {
                    0.004 * ((i * 7919 % 13) as f64 / 13.0 - 0.5)
                } else {
                    0.0
                };
                -distance / (angle - normal).cos() + noise
            })
            .collect();
        ScanInput::new(phi, rho, 0.01).expect("valid scan")
    }

    /// A wall 3 m ahead with a gap (beams 40-59) through which a wall 6 m ahead is seen: three
    /// surfaces.
    fn two_surface_input() -> ScanInput {
        let depth = |i: usize| if (40..60).contains(&i) { 6.0 } else { 3.0 };
        scan_of_walls(90, (-1.2, 1.2), |i| (std::f64::consts::PI, depth(i)), true)
    }

    #[test]
    fn links_that_no_window_crosses_split_the_problem() {
        use Topology::{DifferentRegion as R, DifferentSurface as S, SameRegion as Q};
        let library = crate::Library::shipped().expect("shipped priors");
        let rectangular = library.compile("Rectangular prior").expect("prior");
        let polygonal = library.compile("Polygonal prior").expect("prior");
        let circular = library.compile("Circular prior").expect("prior");
        let links = [Q, Q, S, Q, R, Q, Q];
        // The rectangular prior ties the normals across a region change: only the surface
        // change splits.
        assert_eq!(part_ends(&rectangular, &links, 8), vec![3, 8]);
        // The polygonal prior states nothing across a region change either.
        assert_eq!(part_ends(&polygonal, &links, 8), vec![3, 5, 8]);
        // Order 3: a window of three readings holds two links; a different-surface link
        // still states nothing, and the windows around it only hold it.
        assert_eq!(circular.order, 3);
        assert_eq!(part_ends(&circular, &links, 8), vec![3, 5, 8]);
        // A prior with a different-surface priorlet (and none across a region change) ties
        // the readings across the surface change, not across the region change.
        let mut custom = crate::Library::shipped().expect("shipped priors");
        let name = custom
            .add(
                "name: Tied\norder: 2\npriorlet same_region:\n  alpha_1 == alpha_2\n\
                 priorlet different_surface:\n  model_likelihood (alpha_2 - alpha_1)^2\n",
                "test",
            )
            .expect("valid prior");
        let tied = custom.compile(&name).expect("prior");
        assert_eq!(part_ends(&tied, &links, 8), vec![5, 8]);
        assert!(part_ends(&rectangular, &[], 0).is_empty());
        assert_eq!(part_ends(&rectangular, &[], 1), vec![1]);
    }

    /// Part by part, the inner optimization reaches the optimum of the whole problem (within
    /// the feasibility tolerance), with the normals in the whole problem's unwrapping, and a
    /// part solved before is not solved again.
    #[test]
    fn solving_part_by_part_matches_the_whole_problem() {
        let library = crate::Library::shipped().expect("shipped priors");
        let prior = library.compile("Rectangular prior").expect("prior");
        let input = two_surface_input();
        let params = Params::default();
        let members: Vec<usize> = (0..input.len()).collect();
        let mut links = vec![Topology::SameRegion; input.len() - 1];
        links[39] = Topology::DifferentSurface;
        links[59] = Topology::DifferentSurface;
        let whole_problem = build_problem(&prior, &input, &members, &links, &params);
        let whole = inner_optimization(&whole_problem, &params).expect("inner optimization");
        let mut parts = PartSolver::new(&prior, &input, &params);
        let by_parts = parts.solve(&members, &links).expect("parts");
        assert_eq!(parts.inner_optimizations, 3);
        assert!(whole.feasible && by_parts.feasible);
        assert_eq!(by_parts.x.len(), whole.x.len());
        for (j, (a, b)) in by_parts.x.iter().zip(&whole.x).enumerate() {
            assert!((a - b).abs() < 1e-5, "x[{j}]: {a} by parts, {b} whole");
        }
        // The same topology again: nothing solved.
        parts.solve(&members, &links).expect("parts");
        assert_eq!(parts.inner_optimizations, 3);
        // A link relaxed in the middle part: only that part is solved again.
        links[50] = Topology::DifferentRegion;
        parts.solve(&members, &links).expect("parts");
        assert_eq!(parts.inner_optimizations, 4);
    }

    /// The normals of the parts continue the whole scan's unwrapping, even where the scan's
    /// normals pass through +-pi.
    #[test]
    fn the_parts_normals_are_unwrapped_as_the_whole_scans() {
        let library = crate::Library::shipped().expect("shipped priors");
        let prior = library.compile("Polygonal prior").expect("prior");
        // Two walls ahead, their normals (towards the sensor) on either side of +-pi: the
        // first at pi - 0.05, 2 m away; after a gap the second at -pi + 0.05, 4 m away. The
        // second part's first normal is unwrapped to pi + 0.05 in the whole scan.
        let beams = 60;
        let wall_of = |i: usize| {
            if i < 30 {
                (std::f64::consts::PI - 0.05, 2.0)
            } else {
                (-std::f64::consts::PI + 0.05, 4.0)
            }
        };
        let input = scan_of_walls(beams, (-0.6, 0.6), wall_of, false);
        let params = Params::default();
        let members: Vec<usize> = (0..beams).collect();
        let mut links = vec![Topology::SameRegion; beams - 1];
        links[29] = Topology::DifferentSurface;
        let whole_problem = build_problem(&prior, &input, &members, &links, &params);
        let whole = inner_optimization(&whole_problem, &params).expect("inner optimization");
        let by_parts = PartSolver::new(&prior, &input, &params)
            .solve(&members, &links)
            .expect("parts");
        for j in 0..beams {
            let (a, b) = (by_parts.x[2 * j + 1], whole.x[2 * j + 1]);
            assert!((a - b).abs() < 1e-5, "normal {j}: {a} by parts, {b} whole");
        }
    }

    /// The windows are evaluated in parallel and their terms added in window order: the
    /// solution is the same bit for bit on one thread and on two.
    #[test]
    fn results_do_not_depend_on_the_number_of_threads() {
        use crate::scene::{ScanSpec, Scene};
        let spec = ScanSpec {
            world_from_sensor: [1.7, 2.2, 0.3],
            angle_min: -std::f64::consts::PI,
            angle_increment: std::f64::consts::TAU / 120.0,
            beams: 120,
            sigma: 0.01,
            outliers: 2,
            max_range: 30.0,
        };
        let scan = Scene::rectangle(4.0, 4.0)
            .simulate_seeded(&spec, 3)
            .expect("valid scene");
        let input = ScanInput::from_scan(&scan.scan, 0.01).expect("valid scan");
        let library = crate::Library::shipped().expect("shipped priors");
        let prior = library.compile("Rectangular prior").expect("prior");
        let solve = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            pool.install(|| infer(&prior, &input, &Params::default()))
                .expect("inference")
        };
        let (one, two) = (solve(1), solve(2));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(one.feasible && one.outer_iterations > 1);
        assert_eq!(one.inner_optimizations, two.inner_optimizations);
        assert_eq!(bits(&one.rho), bits(&two.rho));
        assert_eq!(bits(&one.alpha), bits(&two.alpha));
        assert_eq!(one.in_model, two.in_model);
        assert_eq!(one.links, two.links);
        assert_eq!(one.outer_iterations, two.outer_iterations);
        assert_eq!(
            [one.max_violation, one.fit_cost, one.objective].map(f64::to_bits),
            [two.max_violation, two.fit_cost, two.objective].map(f64::to_bits)
        );
    }

    /// Parts solved ahead, two at once, are those `solve` finds: its result is the same bit
    /// for bit as without them, and it counts only the parts it uses.
    #[test]
    fn parts_solved_ahead_are_the_parts_solved_one_by_one() {
        let (input, prior) = corner_gap_and_wall();
        let params = Params::default();
        let (members, links) = whole_scan(
            &input,
            &[
                (59, Topology::DifferentRegion),
                (100, Topology::DifferentSurface),
            ],
        );
        assert_eq!(
            part_ends(&prior, &links, members.len()).len(),
            2,
            "two parts"
        );
        // Another topology, whose first part is new.
        let mut other = links.clone();
        other[59] = Topology::DifferentSurface;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("thread pool");
        let mut ahead = PartSolver::new(&prior, &input, &params);
        pool.install(|| {
            ahead.prefetch(&[
                (members.clone(), links.clone()),
                (members.clone(), other.clone()),
            ])
        });
        assert_eq!(ahead.solved.len(), 2, "as many parts as threads");
        assert_eq!(ahead.inner_optimizations, 0, "none used yet");
        let mut one_by_one = PartSolver::new(&prior, &input, &params);
        // `links` then `other`: each the same bits as solved one by one.
        for (topology, counted) in [(&links, 2), (&other, 4)] {
            let got = pool
                .install(|| ahead.solve(&members, topology))
                .expect("solved");
            let expected = one_by_one.solve(&members, topology).expect("solved");
            let bits = |inner: &Inner| inner.x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&expected));
            assert_eq!(got.link_penalties, expected.link_penalties);
            assert_eq!(ahead.inner_optimizations, counted);
            assert_eq!(one_by_one.inner_optimizations, counted);
            if counted == 2 {
                assert_eq!(ahead.solved.len(), 2, "found, not solved again");
            }
        }
    }

    /// 150 readings of a room corner, a gap and a wall, with a little noise, and the
    /// rectangular prior.
    fn corner_gap_and_wall() -> (ScanInput, Prior) {
        let phi: Vec<f64> = (0..150).map(|k| -1.5 + 0.02 * k as f64).collect();
        let rho: Vec<f64> = phi
            .iter()
            .enumerate()
            .map(|(k, &b)| {
                let wall = if k < 60 {
                    2.0 / b.cos()
                } else {
                    3.0 / b.sin().abs().max(0.3)
                };
                wall + 0.003 * ((k * 7919) % 13) as f64 / 13.0
            })
            .collect();
        let input = ScanInput::new(phi, rho, 0.01).expect("valid scan");
        let library = crate::Library::shipped().expect("shipped priors");
        let prior = library.compile("Rectangular prior").expect("prior");
        (input, prior)
    }

    /// Every reading of `input` as a member, and links of the same region but for
    /// `changes` (`(link, topology)`).
    fn whole_scan(input: &ScanInput, changes: &[(usize, Topology)]) -> (Vec<usize>, Vec<Topology>) {
        let members: Vec<usize> = (0..input.len()).collect();
        let mut links = vec![Topology::SameRegion; input.len() - 1];
        for &(link, topology) in changes {
            links[link] = topology;
        }
        (members, links)
    }

    /// A point near the problem's start: every range 1 mm long, every normal 0.01 rad less.
    fn near_start(problem: &Problem) -> Vec<f64> {
        (0..problem.rho.len())
            .flat_map(|j| [problem.rho[j] + 1e-3, problem.alpha0[j] - 1e-2])
            .collect()
    }

    /// A large problem's value (its windows in parallel) is the serial sum bit for bit.
    #[test]
    fn parallel_values_are_the_serial_sum() {
        let (input, prior) = corner_gap_and_wall();
        let (members, links) = whole_scan(&input, &[(59, Topology::DifferentRegion)]);
        let problem = build_problem(&prior, &input, &members, &links, &Params::default());
        assert!(problem.windows.len() >= PARALLEL_WINDOWS);
        let x = near_start(&problem);
        let (lambda, mu) = (1e3, 1e-2);
        let mut buffer = Vec::new();
        // The windows one by one, then the data term and the barrier.
        let (mut energy, mut penalty) = (0.0, 0.0);
        for w in 0..problem.windows.len() {
            let (e, p) = problem.window_value_terms(&x, w, &mut buffer);
            energy += e;
            penalty += p;
        }
        assert!(penalty > 0.0, "a point off the constraints");
        let serial = problem
            .objective(&x, (energy, penalty), lambda, mu)
            .expect("inside the bounds");
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            let value = pool.install(|| problem.value(&x, lambda, mu));
            assert_eq!(value.map(f64::to_bits), Some(serial.to_bits()), "{threads}");
        }
    }

    /// The line search starts at most 99.5 % of the way to the nearest bound, and at the
    /// full step when no bound is that near.
    #[test]
    fn steps_stop_short_of_the_bounds() {
        let (lo, hi) = (vec![0.0, -1.0, 2.0], vec![1.0, 1.0, 3.0]);
        let x = vec![0.5, 0.0, 2.9];
        // Within reach: a full step.
        assert_eq!(step_to_boundary(&x, &[0.1, -0.5, 0.0], (&lo, &hi)), 1.0);
        // The third coordinate would cross its upper bound (0.1 away) at a step of 0.5.
        let step = step_to_boundary(&x, &[0.1, -0.5, 0.2], (&lo, &hi));
        assert!((step - 0.995 * 0.5).abs() < 1e-15, "{step}");
        // The first would cross its lower bound (0.5 away) at a step of 0.25.
        let direction = [-2.0, 0.0, 0.2];
        let step = step_to_boundary(&x, &direction, (&lo, &hi));
        assert!((step - 0.995 * 0.25).abs() < 1e-15, "{step}");
        for i in 0..3 {
            let moved = x[i] + step * direction[i];
            assert!(moved > lo[i] && moved < hi[i], "coordinate {i}: {moved}");
        }
    }

    /// The bounds' multipliers start on the central path, where the barrier's curvature is
    /// the primal barrier's, and step back to it.
    #[test]
    fn bound_multipliers_follow_the_central_path() {
        let (lo, hi) = (vec![0.0, -1.0], vec![1.0, 1.0]);
        let bounds = (lo.as_slice(), hi.as_slice());
        let (x, mu) = (vec![0.2, 0.5], 1e-3);
        let mut duals = BoundDuals::new(&x, bounds, mu);
        let curvature = duals.curvature(&x, bounds);
        let primal = [
            mu / (0.2 * 0.2) + mu / (0.8 * 0.8),
            mu / (1.5 * 1.5) + mu / (0.5 * 0.5),
        ];
        for i in 0..2 {
            assert!((curvature[i] - primal[i]).abs() < 1e-12 * primal[i], "{i}");
        }
        // Twice the central multipliers: one step without a primal move halves them back.
        for z in duals.lower.iter_mut().chain(duals.upper.iter_mut()) {
            *z *= 2.0;
        }
        duals.update(&x, &[0.0, 0.0], mu, bounds);
        let central = BoundDuals::new(&x, bounds, mu);
        for i in 0..2 {
            assert!((duals.lower[i] - central.lower[i]).abs() < 1e-12 * central.lower[i]);
            assert!((duals.upper[i] - central.upper[i]).abs() < 1e-12 * central.upper[i]);
        }
        // A move towards the lower bound raises its multiplier and lowers the upper one's.
        duals.update(&x, &[-0.1, 0.0], mu, bounds);
        assert!(duals.lower[0] > central.lower[0] && duals.upper[0] < central.upper[0]);
        // Far off the central path, they are brought back within the safeguard's factor.
        duals.lower[1] = 1e30;
        duals.safeguard(&x, mu, bounds);
        assert!(duals.lower[1] <= DUAL_SAFEGUARD * mu / 1.5 * (1.0 + 1e-12));
    }

    /// A Newton step uses the exact Hessian where the banded sum factors, and the
    /// convexified one where it does not; both steps go downhill.
    #[test]
    fn newton_steps_use_the_exact_hessian_where_it_factors() {
        let (input, prior) = corner_gap_and_wall();
        // The corner forced into one region: an infeasible topology.
        let (members, links) = whole_scan(&input, &[]);
        let problem = build_problem(&prior, &input, &members, &links, &Params::default());
        let start: Vec<f64> = (0..problem.rho.len())
            .flat_map(|j| [problem.rho[j], problem.alpha0[j]])
            .collect();
        let sums = problem.window_sums(&start);
        let mut factored = [0, 0];
        for (lambda, mu) in [(1.0, 1e-2), (1e8, 1e-9)] {
            let mut bases = Vec::new();
            let bounds = (problem.lo.as_slice(), problem.hi.as_slice());
            let curvature = BoundDuals::new(&start, bounds, mu).curvature(&start, bounds);
            let (eval, direction) = newton_direction(
                &problem,
                (&start, &sums, None),
                (lambda, mu),
                &curvature,
                &mut bases,
            )
            .expect("a step");
            let exact = problem
                .assemble((&start, &sums, None), (lambda, mu), &curvature)
                .expect("finite");
            let convexified = problem.convexified_band(&start, lambda, &curvature, &mut Vec::new());
            let rhs: Vec<f64> = exact.gradient.iter().map(|g| -g).collect();
            let used = match exact.band.solve(&rhs, 0.0) {
                Some(_) => {
                    factored[0] += 1;
                    &exact.band
                }
                None => {
                    factored[1] += 1;
                    &convexified
                }
            };
            assert_eq!(eval.band.data, used.data, "lambda {lambda}");
            assert_eq!(eval.gradient, exact.gradient, "lambda {lambda}");
            assert_eq!(Some(direction.clone()), used.solve(&rhs, 0.0));
            let slope = eval.slope(&direction);
            assert!(slope < 0.0, "lambda {lambda}: slope {slope}");
        }
        assert_eq!(factored, [1, 1], "one exact and one convexified step");
    }

    /// The Newton model's gradient and Hessian are the objective's (`Problem::value`), by
    /// central differences, with the primal barrier's curvature (the bound multipliers on
    /// the central path), for a penalty weight whose constraints are violated.
    #[test]
    fn newton_model_is_the_derivative_of_the_value() {
        let (input, prior) = corner_gap_and_wall();
        let (members, links) = whole_scan(&input, &[(59, Topology::DifferentRegion)]);
        let problem = build_problem(&prior, &input, &members, &links, &Params::default());
        let x = near_start(&problem);
        let (lambda, mu) = (10.0, 1e-2);
        let bounds = (problem.lo.as_slice(), problem.hi.as_slice());
        let curvature = |x: &[f64]| BoundDuals::new(x, bounds, mu).curvature(x, bounds);
        let model = |x: &[f64]| {
            let sums = problem.window_sums(x);
            problem
                .assemble((x, &sums, None), (lambda, mu), &curvature(x))
                .expect("finite")
        };
        let at_x = model(&x);
        let value = |x: &[f64]| problem.value(x, lambda, mu).expect("inside");
        assert_eq!(at_x.value.to_bits(), value(&x).to_bits());
        let h = 1e-6;
        let moved = |i: usize, d: f64| {
            let mut y = x.clone();
            y[i] += d;
            y
        };
        // Coordinates around the corner (readings 57-62) and at the scan's start.
        for i in (114..126).chain(0..4) {
            let numeric = (value(&moved(i, h)) - value(&moved(i, -h))) / (2.0 * h);
            let analytic = at_x.gradient[i];
            assert!(
                (numeric - analytic).abs() <= 1e-5 * (1.0 + analytic.abs()),
                "gradient {i}: {numeric} against {analytic}"
            );
            let (plus, minus) = (model(&moved(i, h)), model(&moved(i, -h)));
            for j in i.saturating_sub(3)..=i {
                let numeric = (plus.gradient[j] - minus.gradient[j]) / (2.0 * h);
                let mut band = Band::new(at_x.band.n, at_x.band.b);
                band.data.clone_from(&at_x.band.data);
                let analytic = *band.at(i, j);
                assert!(
                    (numeric - analytic).abs() <= 1e-4 * (1.0 + analytic.abs()),
                    "Hessian ({i}, {j}): {numeric} against {analytic}"
                );
            }
        }
    }

    /// One evaluation's window sums (energies and penalties apart, with each window's
    /// largest violation) and the convexified band are those of a serial loop over the
    /// windows, bit for bit, on one thread and on two; the sums' values and violations are
    /// those of the plain evaluation.
    #[test]
    fn window_terms_are_added_in_window_order() {
        let (input, prior) = corner_gap_and_wall();
        let (members, links) = whole_scan(
            &input,
            &[
                (59, Topology::DifferentRegion),
                (100, Topology::DifferentSurface),
            ],
        );
        let problem = build_problem(&prior, &input, &members, &links, &Params::default());
        let x = near_start(&problem);
        let lambda = 1e3;
        // The serial loop.
        let (n, width) = (problem.dim(), 2 * prior.order - 1);
        let sum = || WindowSum {
            value: 0.0,
            gradient: vec![0.0; n],
            band: Band::new(n, width),
        };
        let (mut energy, mut penalty) = (sum(), sum());
        let mut violations = vec![0.0; problem.windows.len()];
        let zero_curvature = vec![0.0; n];
        let mut convexified = problem.data_band(&zero_curvature);
        let mut nodes = SparseNodes::<4>::new();
        let mut plain = Vec::new();
        for (w, &(start, topology)) in problem.windows.iter().enumerate() {
            let priorlet = prior.priorlet(topology);
            if priorlet.is_empty() {
                continue;
            }
            let (local, phi) = (problem.local(&x, start), problem.local_phi(start));
            let buffer = problem
                .plan
                .derivatives(&prior, (w, topology), local, phi, &mut nodes);
            let (e, p, violation) = split_window_terms(priorlet, buffer);
            let (plain_e, plain_p) = problem.window_value_terms(&x, w, &mut plain);
            assert_eq!(
                (e.v.to_bits(), p.v.to_bits()),
                (plain_e.to_bits(), plain_p.to_bits())
            );
            violations[w] = violation;
            for (total, term) in [(&mut energy, &e), (&mut penalty, &p)] {
                total.value += term.v;
                let h = symmetrized(&term.h, 4);
                for i in 0..4 {
                    total.gradient[2 * start + i] += term.g[i];
                    for j in 0..=i {
                        *total.band.at(2 * start + i, 2 * start + j) += h[i][j];
                    }
                }
            }
            let total = window_terms(priorlet, buffer, lambda);
            let h = convexify::<4>(&total.h, 4, |largest| 1e-9 * largest.max(1.0));
            for i in 0..4 {
                for j in 0..=i {
                    *convexified.at(2 * start + i, 2 * start + j) += h[i][j];
                }
            }
        }
        assert!(
            violations.iter().any(|&v| v > 0.0),
            "a point off the constraints"
        );
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let same = |a: &WindowSum, b: &WindowSum, what: &str| {
            assert_eq!(a.value.to_bits(), b.value.to_bits(), "{what}");
            assert_eq!(bits(&a.gradient), bits(&b.gradient), "{what}");
            assert_eq!(bits(&a.band.data), bits(&b.band.data), "{what}");
        };
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            let sums = pool.install(|| problem.window_sums(&x));
            same(&sums.energy, &energy, "energy");
            same(&sums.penalty, &penalty, "penalty");
            assert_eq!(
                bits(&sums.violations),
                bits(&violations),
                "{threads} threads"
            );
            let band = pool
                .install(|| problem.convexified_band(&x, lambda, &zero_curvature, &mut Vec::new()));
            assert_eq!(
                bits(&band.data),
                bits(&convexified.data),
                "{threads} threads"
            );
        }
    }

    /// A symmetric `k x k` matrix (in the leading block of an 8 x 8 array) with entries
    /// uniform in [-10, 10).
    fn random_symmetric(rng: &mut ChaCha8Rng, k: usize) -> [[f64; 8]; 8] {
        let mut a = [[0.0; 8]; 8];
        for i in 0..k {
            for j in 0..=i {
                let v = rng.random_range(-10.0..10.0);
                a[i][j] = v;
                a[j][i] = v;
            }
        }
        a
    }

    #[test]
    fn eigen_decomposition_of_random_symmetric_matrices() {
        let mut rng = ChaCha8Rng::seed_from_u64(20);
        for _ in 0..50 {
            // Every fixed window size, a leading block, and the general path (k = 5).
            for k in [2, 4, 6, 8, 3, 5] {
                let a = random_symmetric(&mut rng, k);
                let values = check_decomposition(&a, k);
                let trace: f64 = (0..k).map(|i| a[i][i]).sum();
                assert!((values.iter().sum::<f64>() - trace).abs() < 1e-10);
            }
        }
    }

    #[test]
    fn eigen_decomposition_of_known_matrices() {
        // The second-difference matrix tridiag(-1, 2, -1) of size 4: eigenvalues
        // 2 - 2 cos(j pi / 5), j = 1..4.
        let mut a = [[0.0; 4]; 4];
        for i in 0..4 {
            a[i][i] = 2.0;
            if i + 1 < 4 {
                a[i][i + 1] = -1.0;
                a[i + 1][i] = -1.0;
            }
        }
        let values = check_decomposition(&a, 4);
        for (j, v) in values.iter().enumerate() {
            let expected = 2.0 - 2.0 * ((j + 1) as f64 * std::f64::consts::PI / 5.0).cos();
            assert!((v - expected).abs() < 1e-14, "{values:?}");
        }
        // Repeated eigenvalues (a triple one and a negative one) in a random basis, and a
        // multiple of the identity, in the leading block of a larger array.
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        let q = orthogonal::<6>(4, &mut rng);
        let a = compose(&q, &[2.0, -1.0, 2.0, 2.0]);
        let values = check_decomposition(&a, 4);
        for (v, expected) in values.iter().zip([-1.0, 2.0, 2.0, 2.0]) {
            assert!((v - expected).abs() < 1e-13, "{values:?}");
        }
        let mut three = [[0.0; 6]; 6];
        for (i, row) in three.iter_mut().enumerate() {
            row[i] = 3.0;
        }
        assert_eq!(check_decomposition(&three, 6), vec![3.0; 6]);
        // An empty block.
        assert_eq!(symmetric_eigen(&three, 0), ([0.0; 6], [[0.0; 6]; 6]));
    }

    /// nalgebra's `SymmetricEigen` of the leading `k x k` block: the eigenvalues, sorted,
    /// and the convexification as the engine computed it before the Jacobi routine
    /// (`sum max(lambda_e, floor) v_e v_e^T`).
    fn reference<const N: usize>(
        a: &[[f64; N]; N],
        k: usize,
        floor_of: impl Fn(f64) -> f64,
    ) -> (Vec<f64>, [[f64; N]; N]) {
        let m = DMatrix::from_fn(k, k, |i, j| 0.5 * (a[i][j] + a[j][i]));
        let eigen = SymmetricEigen::new(m);
        let mut values: Vec<f64> = eigen.eigenvalues.iter().copied().collect();
        let largest = values.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
        let floor = floor_of(largest);
        let mut out = [[0.0; N]; N];
        for (e, value) in values.iter().enumerate() {
            for i in 0..k {
                for j in 0..k {
                    out[i][j] +=
                        value.max(floor) * eigen.eigenvectors[(i, e)] * eigen.eigenvectors[(j, e)];
                }
            }
        }
        values.sort_by(f64::total_cmp);
        (values, out)
    }

    /// The Jacobi decomposition and the convexification agree with nalgebra's
    /// `SymmetricEigen` on random symmetric matrices, on near-degenerate ones (clustered,
    /// repeated and tiny eigenvalues, in a random basis), on sums of a few outer products
    /// (the rank-deficient Hessians of the penalties) and across scales.
    #[test]
    fn jacobi_agrees_with_nalgebra() {
        let mut rng = ChaCha8Rng::seed_from_u64(24);
        let floor_of = |largest: f64| 1e-9 * largest.max(1.0);
        let mut cases: Vec<([[f64; 8]; 8], usize)> = Vec::new();
        for _ in 0..200 {
            for k in [2, 3, 4, 5, 6, 8] {
                cases.push((random_symmetric(&mut rng, k), k));
            }
        }
        let clusters: [&[f64]; 8] = [
            &[1.0, 1.0 + 1e-12, 1.0 - 1e-10, -3.0],
            &[0.0, 0.0, 1e-14, 5.0],
            &[0.0, -1e-15, 1e-15, 1e12],
            &[2.0, 2.0, 2.0, 2.0 + 1e-13],
            &[-1e-9, 1e-9, 1.0, 1.0],
            &[1e-300, 0.0, 0.0, 0.0],
            &[0.0, 0.0, 0.0, 0.0],
            &[3.0, -3.0, 3.0, -3.0],
        ];
        for _ in 0..50 {
            for values in clusters {
                let q = orthogonal::<8>(4, &mut rng);
                cases.push((compose(&q, values), 4));
            }
            // lambda g g^T + mu h h^T (+ a small energy term): rank 2 or 3.
            for lambda in [1.0, 1e6, 1e12] {
                let g: Vec<f64> = (0..4).map(|_| rng.random_range(-3.0..3.0)).collect();
                let h: Vec<f64> = (0..4).map(|_| rng.random_range(-3.0..3.0)).collect();
                let e: Vec<f64> = (0..4).map(|_| rng.random_range(-1.0..1.0)).collect();
                let mut a = [[0.0; 8]; 8];
                for i in 0..4 {
                    for j in 0..4 {
                        a[i][j] = lambda * (g[i] * g[j] + 0.3 * h[i] * h[j]) + e[i] * e[j];
                    }
                }
                cases.push((a, 4));
            }
        }
        for (a, k) in &cases {
            let (a, k) = (*a, *k);
            let values = check_decomposition(&a, k);
            let (expected, convexified) = reference(&a, k, floor_of);
            let scale = expected.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            for (v, e) in values.iter().zip(&expected) {
                assert!(
                    (v - e).abs() <= 1e-13 * scale,
                    "k {k}: {values:?} vs {expected:?}"
                );
            }
            let c = convexify::<8>(&a, k, floor_of);
            for i in 0..8 {
                for j in 0..8 {
                    assert!(
                        (c[i][j] - convexified[i][j]).abs() <= 1e-13 * scale.max(1.0),
                        "k {k} ({i}, {j}): {} vs {}",
                        c[i][j],
                        convexified[i][j]
                    );
                    assert_eq!(c[i][j], c[j][i]);
                }
            }
            // Warm starts: from a random orthogonal basis, from one a little off orthogonal
            // and from the eigenvectors of a warm start (the engine's case, step after step).
            let mut skewed = orthogonal::<8>(k, &mut rng);
            for row in skewed.iter_mut().take(k) {
                for x in row.iter_mut().take(k) {
                    *x *= 1.0 + 1e-3 * rng.random_range(-1.0..1.0);
                }
            }
            let mut found = orthogonal::<8>(k, &mut rng);
            convexify_from::<8>(&a, k, floor_of, &mut found);
            for mut basis in [orthogonal::<8>(k, &mut rng), skewed, found] {
                let c = convexify_from::<8>(&a, k, floor_of, &mut basis);
                for i in 0..8 {
                    for j in 0..8 {
                        assert!(
                            (c[i][j] - convexified[i][j]).abs() <= 1e-12 * scale.max(1.0),
                            "warm, k {k} ({i}, {j}): {} vs {}",
                            c[i][j],
                            convexified[i][j]
                        );
                        assert_eq!(c[i][j], c[j][i]);
                        // The new basis: orthonormal eigenvectors (B^T a B diagonal).
                        let dot: f64 = (0..8).map(|r| basis[r][i] * basis[r][j]).sum();
                        let identity = if i == j && i < k { 1.0 } else { 0.0 };
                        assert!((dot - identity).abs() < 1e-12, "warm, k {k}: B^T B {dot}");
                        if i != j {
                            let off: f64 = (0..8)
                                .flat_map(|r| (0..8).map(move |q| (r, q)))
                                .map(|(r, q)| basis[r][i] * a[r][q] * basis[q][j])
                                .sum();
                            assert!(off.abs() <= 1e-12 * scale.max(1.0), "warm, k {k}: {off}");
                        }
                    }
                }
            }
        }
        // Entries that are not finite: no panic, no endless loop.
        let mut a = [[1.0; 4]; 4];
        a[1][2] = f64::NAN;
        a[2][1] = f64::NAN;
        assert_eq!(symmetric_eigen(&a, 4).0, [1.0; 4]);
        a[1][2] = f64::INFINITY;
        a[2][1] = f64::INFINITY;
        assert_eq!(symmetric_eigen(&a, 4).0, [1.0; 4]);
    }

    #[test]
    fn convexify_raises_negative_eigenvalues_and_keeps_the_rest() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let q = orthogonal::<4>(4, &mut rng);
        let floor_of = |largest: f64| 1e-9 * largest.max(1.0);
        // A negative and a zero eigenvalue become the floor; the eigenvectors stay.
        let a = compose(&q, &[5.0, 1.0, -2.0, 0.0]);
        let c = convexify::<4>(&a, 4, floor_of);
        let expected = compose(&q, &[5.0, 1.0, 5e-9, 5e-9]);
        for i in 0..4 {
            for j in 0..4 {
                assert!((c[i][j] - expected[i][j]).abs() < 1e-13, "({i}, {j})");
            }
        }
        let mut values = symmetric_eigen(&c, 4).0.to_vec();
        values.sort_by(f64::total_cmp);
        assert!(
            values[0] > 0.0 && (values[0] - 5e-9).abs() < 1e-13,
            "{values:?}"
        );
        // A positive definite matrix comes back as it was (symmetrized).
        let mut b = compose(&q, &[5.0, 1.0, 2.0, 0.5]);
        b[0][1] += 1e-3;
        let c = convexify::<4>(&b, 4, floor_of);
        for i in 0..4 {
            for j in 0..4 {
                assert_eq!(c[i][j], 0.5 * (b[i][j] + b[j][i]));
            }
        }
        // A matrix with a NaN or an infinity contributes nothing.
        b[2][3] = f64::NAN;
        assert_eq!(convexify::<4>(&b, 4, floor_of), [[0.0; 4]; 4]);
        b[2][3] = f64::INFINITY;
        assert_eq!(convexify::<4>(&b, 4, floor_of), [[0.0; 4]; 4]);
    }
}
