//! The exact gradients and Hessians (second-order dual numbers through the compiled tape)
//! against central differences of the plain values.
#![allow(clippy::needless_range_loop)]

use proptest::prelude::*;
use slam_priors::compile::Priorlet;
use slam_priors::dual::Dual;
use slam_priors::{Library, Topology, parse_prior};

/// Every function of the language in one order-3 prior.
const EVERYTHING: &str = "name: Everything
order: 3
q = [rho_1, rho_2; alpha_1, rho_3]
v = [cos(phi_2); sin(phi_2)] * rho_2
priorlet same_region:
  tan(alpha_1 / 4) + atan(rho_2) * atan2(rho_3, rho_1 + 1) == sqrt(rho_1) * exp(alpha_2 / 5)
  log(rho_3) - abs(alpha_3 - 3) + rho_1 ^ alpha_2 <= rho_2 ^ 2.5 / rho_1
  dot(q * v, [1; -2]) + norm(transpose(v)) >= deg2rad(rad2deg(alpha_3)) || v' * v == 1
  model_likelihood (rho_1 == 0) || 1 == 1
";

fn check<const N: usize>(
    priorlet: &Priorlet,
    x: &[f64],
    phi: &[f64],
) -> std::result::Result<(), String> {
    let duals: Vec<Dual<N>> = x
        .iter()
        .enumerate()
        .map(|(i, &v)| Dual::variable(v, i))
        .collect();
    let mut exact = Vec::new();
    priorlet.eval(&duals, phi, &mut exact);
    let mut plain = Vec::new();
    let value_at = |y: &[f64], node: usize, plain: &mut Vec<f64>| {
        priorlet.eval(y, phi, plain);
        plain[node]
    };
    let mut nodes: Vec<usize> = priorlet.energies.clone();
    for c in &priorlet.constraints {
        nodes.extend(c.branches.iter().map(|a| a.node));
    }
    for node in nodes {
        let d = exact[node];
        if !d.v.is_finite() {
            continue;
        }
        for i in 0..N {
            let h = 1e-5 * (1.0 + x[i].abs());
            let mut up = x.to_vec();
            let mut down = x.to_vec();
            up[i] += h;
            down[i] -= h;
            let numeric =
                (value_at(&up, node, &mut plain) - value_at(&down, node, &mut plain)) / (2.0 * h);
            if (numeric - d.g[i]).abs() > 1e-5 * (1.0 + d.g[i].abs()) {
                return Err(format!(
                    "node {node} gradient {i}: exact {} numeric {numeric}",
                    d.g[i]
                ));
            }
            for j in 0..N {
                // Central second differences at steps h and h / 2, Richardson-extrapolated
                // (truncation error O(h^4)).
                let second = |step: f64, plain: &mut Vec<f64>| {
                    let hi = step * (1.0 + x[i].abs());
                    let hj = step * (1.0 + x[j].abs());
                    let mut at = |si: f64, sj: f64| {
                        let mut y = x.to_vec();
                        y[i] += si * hi;
                        y[j] += sj * hj;
                        value_at(&y, node, plain)
                    };
                    (at(1.0, 1.0) - at(1.0, -1.0) - at(-1.0, 1.0) + at(-1.0, -1.0))
                        / (4.0 * hi * hj)
                };
                let coarse = second(2e-3, &mut plain);
                let fine = second(1e-3, &mut plain);
                let numeric = (4.0 * fine - coarse) / 3.0;
                if (numeric - d.h[i][j]).abs() > 1e-4 * (1.0 + d.h[i][j].abs()) {
                    return Err(format!(
                        "node {node} Hessian ({i}, {j}): exact {} numeric {numeric}",
                        d.h[i][j]
                    ));
                }
            }
        }
    }
    Ok(())
}

fn window(order: usize, seed: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut x = Vec::new();
    let mut phi = Vec::new();
    for k in 0..order {
        x.push(1.0 + 2.0 * seed[3 * k]); // rho in [1, 3]
        x.push(-1.0 + 2.0 * seed[3 * k + 1]); // alpha in [-1, 1]
        phi.push(0.2 * k as f64 + 0.1 * seed[3 * k + 2]);
    }
    (x, phi)
}

#[test]
fn a_relation_is_not_an_energy() {
    // The energy line above is a disjunction: the checker refuses it (the property tests
    // below replace it with a real energy).
    let error = parse_prior(EVERYTHING, "e.prior").unwrap_err();
    assert!(error.to_string().contains("relation"), "{error}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, ..ProptestConfig::default() })]

    #[test]
    fn shipped_priors_have_exact_derivatives(seed in prop::collection::vec(0.0..1.0_f64, 12)) {
        let library = Library::shipped().unwrap();
        for name in library.names() {
            let prior = library.compile(&name).unwrap();
            let (x, phi) = window(prior.order, &seed);
            for t in Topology::ALL {
                let p = prior.priorlet(t);
                let result = match prior.order {
                    2 => check::<4>(p, &x, &phi),
                    _ => check::<6>(p, &x, &phi),
                };
                prop_assert!(result.is_ok(), "{name} {t:?}: {:?}", result);
            }
        }
    }

    #[test]
    fn every_function_has_exact_derivatives(seed in prop::collection::vec(0.0..1.0_f64, 12)) {
        let text = EVERYTHING.replace("  model_likelihood (rho_1 == 0) || 1 == 1\n", "  model_likelihood rho_1 ^ 3 / (alpha_2 + 3)\n");
        let prior = parse_prior(&text, "e.prior").unwrap();
        let (x, phi) = window(3, &seed);
        let result = check::<6>(prior.priorlet(Topology::SameRegion), &x, &phi);
        prop_assert!(result.is_ok(), "{:?}", result);
    }
}
