//! The priorlets of one inner optimization evaluated window by window, with the work that
//! does not change between Newton steps done once.
//!
//! For each priorlet the engine notes which nodes of its tape a constraint or an energy needs
//! (the others are never evaluated) and which window inputs each node depends on. Nodes that
//! depend on no input (constants and functions of the bearings, such as `cos(phi_1)`) are
//! evaluated once per window when the problem is built. Derivatives are carried by
//! [`Sparse`] duals, which compute only the gradient and Hessian entries of the inputs a node
//! depends on.
//!
//! Every value, gradient and Hessian entry is computed by the same operations, in the same
//! order, as [`Priorlet::eval`] on `f64` or on [`crate::dual::Dual`]: the results are the
//! same bit for bit, up to the sign of zeros ([`Sparse`];
//! `tests::planned_evaluation_is_bitwise_the_plain_one`), and so are the engine's solutions.

use crate::compile::{Op, Prior, Priorlet};
use crate::dual::{Dual, Scalar, Sparse, Unary, atan2_at, bits};
use crate::parser::Topology;

/// What the engine needs to know about one priorlet's tape.
#[derive(Clone, Debug)]
struct TapePlan {
    /// The needed nodes (those a constraint or an energy reads) that depend on no input.
    constants: Vec<usize>,
    /// The needed nodes that depend on inputs, in tape order.
    steps: Vec<Step>,
}

/// A needed node that depends on inputs.
#[derive(Clone, Copy, Debug)]
struct Step {
    /// Its index in the tape.
    node: usize,
    /// Its operation.
    op: Op,
    /// The inputs it depends on (the bits of its mask), the first `count` of `index`.
    index: [usize; 8],
    count: usize,
}

impl TapePlan {
    fn new(priorlet: &Priorlet) -> TapePlan {
        let tape = &priorlet.tape;
        // Inputs of each node: bit `2 k` for `rho_{k+1}`, `2 k + 1` for `alpha_{k+1}`.
        let mut masks = vec![0_u8; tape.len()];
        for (k, op) in tape.iter().enumerate() {
            masks[k] = match *op {
                Op::Rho(i) => input_bit(2 * i),
                Op::Alpha(i) => input_bit(2 * i + 1),
                _ => op
                    .arguments()
                    .into_iter()
                    .flatten()
                    .fold(0, |mask, a| mask | masks[a]),
            };
        }
        // Whether a constraint or an energy needs the node.
        let mut live = vec![false; tape.len()];
        let atoms = priorlet.constraints.iter().flat_map(|c| &c.branches);
        for node in atoms
            .map(|a| a.node)
            .chain(priorlet.energies.iter().copied())
        {
            live[node] = true;
        }
        for k in (0..tape.len()).rev() {
            if live[k] {
                for a in tape[k].arguments().into_iter().flatten() {
                    live[a] = true;
                }
            }
        }
        let needed = || (0..tape.len()).filter(|&k| live[k]);
        let constants = needed().filter(|&k| masks[k] == 0).collect();
        let steps = needed()
            .filter(|&k| masks[k] != 0)
            .map(|k| {
                let (index, count) = bits::<8>(masks[k]);
                Step {
                    node: k,
                    op: tape[k],
                    index,
                    count,
                }
            })
            .collect();
        TapePlan { constants, steps }
    }
}

/// The mask bit of window input `i` (inputs past the eighth are not tracked: a window has at
/// most `2 MAX_ORDER = 8`).
fn input_bit(i: usize) -> u8 {
    if i < 8 { 1 << i } else { 0 }
}

/// The plans of a prior's three priorlets and the constant nodes of every window.
pub(crate) struct WindowPlan {
    plans: [TapePlan; 3],
    /// Length of the longest tape: window `w`'s constants start at `w * stride`.
    stride: usize,
    /// Constant nodes as plain numbers compute them (NaN for the other nodes).
    plain: Vec<f64>,
    /// Constant nodes as duals compute them (they divide by multiplying by the reciprocal).
    dual: Vec<f64>,
}

impl WindowPlan {
    /// Plans `prior` on `windows` (`(first reading, topology)`) of the bearings `phi`.
    pub fn new(prior: &Prior, windows: &[(usize, Topology)], phi: &[f64]) -> WindowPlan {
        let plans = prior.priorlets.each_ref().map(TapePlan::new);
        let stride = prior.priorlets.iter().map(|p| p.tape.len()).max();
        let stride = stride.unwrap_or(0);
        let mut plain = vec![f64::NAN; windows.len() * stride];
        let mut dual = vec![f64::NAN; windows.len() * stride];
        let mut plain_nodes: Vec<f64> = Vec::new();
        let mut dual_nodes: Vec<Dual<0>> = Vec::new();
        for (w, &(start, topology)) in windows.iter().enumerate() {
            let priorlet = prior.priorlet(topology);
            let plan = &plans[topology.index()];
            let phi = &phi[start..start + prior.order];
            let slots = w * stride..w * stride + priorlet.tape.len();
            constants(
                priorlet,
                plan,
                phi,
                &mut plain_nodes,
                &mut plain[slots.clone()],
            );
            constants(priorlet, plan, phi, &mut dual_nodes, &mut dual[slots]);
        }
        WindowPlan {
            plans,
            stride,
            plain,
            dual,
        }
    }

    /// The needed nodes of window `w` (of `topology`) at the plain inputs `x`, into `out`
    /// (other nodes hold stale values).
    pub fn values(
        &self,
        prior: &Prior,
        (w, topology): (usize, Topology),
        x: &[f64],
        phi: &[f64],
        out: &mut Vec<f64>,
    ) {
        let priorlet = prior.priorlet(topology);
        let plan = &self.plans[topology.index()];
        let constants = &self.plain[w * self.stride..];
        if out.len() < priorlet.tape.len() {
            out.resize(priorlet.tape.len(), f64::NAN);
        }
        for &k in &plan.constants {
            out[k] = constants[k];
        }
        for step in &plan.steps {
            let value = step.op.apply(x, phi, out);
            out[step.node] = value;
        }
    }

    /// The needed nodes of window `w` (of `topology`) with their derivatives with respect to
    /// the window's inputs `x`, in `nodes` (other nodes hold stale values).
    pub fn derivatives<'n, const N: usize>(
        &self,
        prior: &Prior,
        (w, topology): (usize, Topology),
        x: &[f64],
        phi: &[f64],
        nodes: &'n mut SparseNodes<N>,
    ) -> &'n [Sparse<N>] {
        let priorlet = prior.priorlet(topology);
        let plan = &self.plans[topology.index()];
        let constants = &self.dual[w * self.stride..];
        let buffer = &mut nodes.0[topology.index()];
        if buffer.len() < priorlet.tape.len() {
            buffer.resize(priorlet.tape.len(), Sparse::constant(0.0));
        }
        for &k in &plan.constants {
            buffer[k].v = constants[k];
        }
        // The sine and cosine of the last argument a `sin` or `cos` node took: a priorlet
        // usually takes both of one angle (a normal's `[cos(alpha); sin(alpha)]`).
        let mut trig = SinCos::default();
        for step in &plan.steps {
            let (earlier, rest) = buffer.split_at_mut(step.node);
            // Inputs are below 2 order <= N (the checker bounds the indices of rho and alpha).
            let index = &step.index[..step.count];
            let index = &index[..index.partition_point(|&i| i < N)];
            match step.op {
                Op::Sin(a) | Op::Cos(a) => {
                    let (sin, cos) = trig.at(earlier[a].v);
                    let derivatives = match step.op {
                        Op::Sin(_) => (sin, cos, -sin),
                        _ => (cos, -sin, -cos),
                    };
                    rest[0].set_chain(&earlier[a], derivatives, index);
                }
                _ => set_node(&step.op, (x, phi), earlier, index, &mut rest[0]),
            }
        }
        buffer
    }
}

/// The sine and cosine of the last angle asked for, kept for the next request of the same
/// angle (the same bits as `f64::sin` and `f64::cos`: [`Unary::at`] computes them so).
#[derive(Default)]
struct SinCos {
    last: Option<(u64, f64, f64)>,
}

impl SinCos {
    /// `(sin(v), cos(v))`.
    fn at(&mut self, v: f64) -> (f64, f64) {
        match self.last {
            Some((bits, sin, cos)) if bits == v.to_bits() => (sin, cos),
            _ => {
                let (sin, cos) = (v.sin(), v.cos());
                self.last = Some((v.to_bits(), sin, cos));
                (sin, cos)
            }
        }
    }
}

/// Tape nodes with derivatives, one buffer per topology case. Node `k` of a priorlet always
/// depends on the same inputs, so the entries of its slot outside them stay zero, as
/// [`Sparse`]'s `set_*` operations require.
pub(crate) struct SparseNodes<const N: usize>([Vec<Sparse<N>>; 3]);

impl<const N: usize> SparseNodes<N> {
    /// Empty buffers.
    pub fn new() -> Self {
        SparseNodes([Vec::new(), Vec::new(), Vec::new()])
    }
}

/// Sets `out` to the value and derivatives of `op` on the inputs `x` (with bearings `phi`),
/// given the earlier `nodes`: the operations of [`Op::apply`] on [`crate::dual::Dual`].
fn set_node<const N: usize>(
    op: &Op,
    (x, phi): (&[f64], &[f64]),
    nodes: &[Sparse<N>],
    index: &[usize],
    out: &mut Sparse<N>,
) {
    let input = |i: usize| x.get(i).copied().unwrap_or(f64::NAN);
    let chain = |out: &mut Sparse<N>, a: usize, function: Unary| {
        out.set_chain(&nodes[a], function.at(nodes[a].v), index);
    };
    match *op {
        Op::Const(c) => out.v = c,
        Op::Phi(k) => out.v = phi.get(k).copied().unwrap_or(f64::NAN),
        Op::Rho(k) => out.set_variable(input(2 * k), 2 * k),
        Op::Alpha(k) => out.set_variable(input(2 * k + 1), 2 * k + 1),
        Op::Add(a, b) => out.set_add(&nodes[a], &nodes[b], index),
        Op::Sub(a, b) => out.set_sub(&nodes[a], &nodes[b], index),
        Op::Mul(a, b) => out.set_mul(&nodes[a], &nodes[b], index),
        Op::Div(a, b) => out.set_div(&nodes[a], &nodes[b], index),
        Op::Neg(a) => out.set_neg(&nodes[a], index),
        Op::PowC(a, c) => chain(out, a, Unary::PowC(c)),
        Op::Sin(a) => chain(out, a, Unary::Sin),
        Op::Cos(a) => chain(out, a, Unary::Cos),
        Op::Tan(a) => chain(out, a, Unary::Tan),
        Op::Atan(a) => chain(out, a, Unary::Atan),
        Op::Sqrt(a) => chain(out, a, Unary::Sqrt),
        Op::Exp(a) => chain(out, a, Unary::Exp),
        Op::Ln(a) => chain(out, a, Unary::Ln),
        Op::Abs(a) => chain(out, a, Unary::Abs),
        Op::Atan2(a, b) => {
            let derivatives = atan2_at(nodes[a].v, nodes[b].v);
            out.set_chain2(&nodes[a], &nodes[b], derivatives, index);
        }
    }
}

/// The constant nodes of `priorlet` on a window with bearings `phi`, computed as `S`
/// computes them, into `slots` (one per node; the others are left NaN).
fn constants<S: Scalar>(
    priorlet: &Priorlet,
    plan: &TapePlan,
    phi: &[f64],
    nodes: &mut Vec<S>,
    slots: &mut [f64],
) {
    nodes.clear();
    nodes.resize(priorlet.tape.len(), S::constant(f64::NAN));
    for &k in &plan.constants {
        let value = priorlet.tape[k].apply(&[], phi, nodes);
        slots[k] = value.value();
        nodes[k] = value;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compile::{Library, parse_prior};

    /// Every function of the language, with divisions of bearings and of inputs.
    const EVERYTHING: &str = "name: Everything
order: 3
q = [rho_1, rho_2; alpha_1, rho_3]
v = [cos(phi_2); sin(phi_2)] * rho_2
w = 1 / sin(phi_1 + 0.3) + phi_3 / 7
unused = rho_3 * alpha_3 / 3
priorlet same_region:
  tan(alpha_1 / 4) + atan(rho_2) * atan2(rho_3, rho_1 + 1) == sqrt(rho_1) * exp(alpha_2 / 5) * w
  log(rho_3) - abs(alpha_3 - 3) + rho_1 ^ alpha_2 <= rho_2 ^ 2.5 / rho_1
  dot(q * v, [1; -2]) + norm(transpose(v)) >= deg2rad(rad2deg(alpha_3)) || v' * v == 1
  model_likelihood rho_1 ^ 3 / (alpha_2 + 3) - w
";

    /// The needed nodes of `priorlet` through the plan, against [`Priorlet::eval`]: the same
    /// bits for values, and for every gradient and Hessian entry of the inputs a node
    /// depends on (the others are zero).
    fn check<const N: usize>(prior: &Prior, topology: Topology, x: &[f64], phi: &[f64]) {
        let priorlet = prior.priorlet(topology);
        let windows = [(0, topology)];
        let plan = WindowPlan::new(prior, &windows, phi);
        let mut plain = Vec::new();
        priorlet.eval(x, phi, &mut plain);
        let mut planned = Vec::new();
        plan.values(prior, (0, topology), x, phi, &mut planned);
        let duals: Vec<Dual<N>> = (0..x.len()).map(|i| Dual::variable(x[i], i)).collect();
        let mut dense = Vec::new();
        priorlet.eval(&duals, phi, &mut dense);
        let mut nodes = SparseNodes::<N>::new();
        // The slots of an evaluation elsewhere are reused.
        let elsewhere: Vec<f64> = x.iter().map(|v| v + 0.1).collect();
        plan.derivatives(prior, (0, topology), &elsewhere, phi, &mut nodes);
        let sparse = plan.derivatives(prior, (0, topology), x, phi, &mut nodes);
        let tape_plan = &plan.plans[topology.index()];
        let needed = tape_plan.constants.iter().copied();
        for k in needed.chain(tape_plan.steps.iter().map(|s| s.node)) {
            assert_eq!(planned[k].to_bits(), plain[k].to_bits(), "node {k} value");
            let (d, s) = (&dense[k], &sparse[k]);
            assert_eq!(s.v.to_bits(), d.v.to_bits(), "node {k} dual value");
            let inside = |i: usize| s.mask & (1 << i) != 0;
            for i in 0..N {
                same_entry(s.g[i], d.g[i], inside(i), || {
                    format!("node {k} gradient {i}")
                });
                for j in 0..N {
                    let both = inside(i) && inside(j);
                    same_entry(s.h[i][j], d.h[i][j], both, || {
                        format!("node {k} ({i}, {j})")
                    });
                }
            }
        }
    }

    /// An entry inside the mask has the dense dual's bits (a zero may differ in sign: a term
    /// outside an operand's mask is `+0` here); outside, both are zero.
    fn same_entry(sparse: f64, dense: f64, inside: bool, what: impl Fn() -> String) {
        let zeros = sparse == 0.0 && dense == 0.0;
        if inside {
            assert!(
                sparse.to_bits() == dense.to_bits() || zeros,
                "{}: {sparse} {dense}",
                what()
            );
        } else {
            assert!(zeros, "{}: {sparse} {dense}", what());
        }
    }

    #[test]
    fn planned_evaluation_is_bitwise_the_plain_one() {
        let everything = parse_prior(EVERYTHING, "e.prior").unwrap();
        let library = Library::shipped().unwrap();
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut random = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..50 {
            let x: Vec<f64> = (0..6)
                .map(|i| {
                    if i % 2 == 0 {
                        1.0 + 2.0 * random()
                    } else {
                        2.0 * random() - 1.0
                    }
                })
                .collect();
            let phi: Vec<f64> = (0..3).map(|k| 0.2 * k as f64 + 0.1 * random()).collect();
            check::<6>(&everything, Topology::SameRegion, &x, &phi);
            for name in library.names() {
                let prior = library.compile(&name).unwrap();
                let k = 2 * prior.order;
                for topology in Topology::ALL {
                    match prior.order {
                        2 => check::<4>(&prior, topology, &x[..k], &phi[..prior.order]),
                        _ => check::<6>(&prior, topology, &x[..k], &phi[..prior.order]),
                    }
                }
            }
        }
    }

    /// Dead nodes are not evaluated, constant nodes are taken from the window's plan.
    #[test]
    fn plans_skip_dead_nodes_and_find_constants() {
        let library = Library::shipped().unwrap();
        let prior = library.compile("Rectangular prior").unwrap();
        // The different-region priorlet states only the normals' disjunction: the points,
        // defined for the same-region lines, are dead there.
        let priorlet = prior.priorlet(Topology::DifferentRegion);
        let plan = TapePlan::new(priorlet);
        let needed =
            |k: usize| plan.constants.contains(&k) || plan.steps.iter().any(|s| s.node == k);
        for (k, op) in priorlet.tape.iter().enumerate() {
            match op {
                Op::Rho(_) | Op::Phi(_) => assert!(!needed(k), "node {k}: {op:?}"),
                Op::Alpha(i) => {
                    let step = plan.steps.iter().find(|s| s.node == k).unwrap();
                    assert_eq!(step.index[..step.count], [2 * i + 1]);
                }
                _ => {}
            }
        }
        let plan = TapePlan::new(prior.priorlet(Topology::SameRegion));
        let tape = &prior.priorlet(Topology::SameRegion).tape;
        let cos_phi = tape
            .iter()
            .position(|op| matches!(op, Op::Cos(a) if matches!(tape[*a], Op::Phi(_))));
        assert!(plan.constants.contains(&cos_phi.unwrap()));
        assert!(plan.steps.iter().all(|s| s.count > 0));
    }
}
