//! Degrees of freedom and posterior covariance (section 4 of the source).
//!
//! At a feasible solution `x` (INMODEL readings only, `x = (rho_1, alpha_1, rho_2, ...)`):
//!
//! - `Free = ker grad_x f_T(x)` (eq. 6): the variations the prior's equalities allow;
//! - `Extr = span grad_q r` (eq. 8): how the readings and normals change when the sensor
//!   pose `q = (t_x, t_y, theta)` moves (each reading's surface is taken locally as its
//!   osculating circle: the solution's point, normal and curvature between neighbours);
//! - `Intr = Free - Extr` (eq. 9): the shape's own degrees of freedom. `Extr` is projected
//!   onto `Free` first (Proposition 2 says it lies there for a pose-independent prior), and
//!   `Intr` is the orthogonal complement of that projection within `Free`;
//! - posterior covariance (section 4.3): `Sigma_x = P (Sigma_x0^-1 + H_h)^-1 P` with `P` the
//!   orthogonal projector onto `Free`, `Sigma_x0` the prior covariance of `x` (range
//!   variances and the initial normals' variances) and `H_h` the energies' Hessian
//!   (convexified); reported as its eigen-variations.

use slam_core::nalgebra::{DMatrix, DVector};

use crate::compile::{AtomKind, Prior};
use crate::dual::Dual;
use crate::engine::{Solution, convexify, windows_of};
use crate::error::{PriorError, Result};
use crate::parser::Topology;

/// The degrees of freedom of a solution and its posterior covariance. Vectors are in the
/// coordinates `(rho, alpha)` of the INMODEL readings, interleaved: entry `2 j` is the range
/// and `2 j + 1` the normal of reading `members[j]`.
#[derive(Clone, Debug)]
pub struct Dof {
    /// The INMODEL readings, in scan order.
    pub members: Vec<usize>,
    /// Number of equality constraints used.
    pub constraints: usize,
    /// Orthonormal basis of `Free` (columns).
    pub free: DMatrix<f64>,
    /// Orthonormal basis of the extrinsic degrees of freedom (columns, within `Free`).
    pub extrinsic: DMatrix<f64>,
    /// Orthonormal basis of the intrinsic degrees of freedom (columns, within `Free`).
    pub intrinsic: DMatrix<f64>,
    /// Posterior covariance in `Free` coordinates: `free^T Sigma_x free`.
    pub core: DMatrix<f64>,
    /// Eigen-variations of the posterior covariance: standard deviation and unit direction,
    /// largest first.
    pub variations: Vec<(f64, DVector<f64>)>,
}

impl Dof {
    /// Dimension of `Free`.
    pub fn free_dim(&self) -> usize {
        self.free.ncols()
    }
    /// Dimension of `Extr`.
    pub fn extrinsic_dim(&self) -> usize {
        self.extrinsic.ncols()
    }
    /// Dimension of `Intr`.
    pub fn intrinsic_dim(&self) -> usize {
        self.intrinsic.ncols()
    }
    /// The posterior covariance of `x` (`2 m x 2 m`).
    pub fn covariance(&self) -> DMatrix<f64> {
        &self.free * &self.core * self.free.transpose()
    }
    /// Posterior standard deviation of each INMODEL range, in `members` order.
    pub fn range_std(&self) -> Vec<f64> {
        let cov = self.covariance();
        (0..self.members.len())
            .map(|j| cov[(2 * j, 2 * j)].max(0.0).sqrt())
            .collect()
    }
}

/// Relative tolerance on the singular values of the (row-normalized) constraint Jacobian
/// below which a direction counts as free.
pub const RANK_TOLERANCE: f64 = 1e-6;

/// Relative tolerance on the singular values of the sensor-pose derivative projected onto
/// `Free` below which a direction does not count as extrinsic (the solution is feasible only
/// to the engine's tolerance, so the projection is not exact).
pub const EXTRINSIC_TOLERANCE: f64 = 1e-3;

/// Computes the degrees of freedom and posterior covariance of a feasible solution.
pub fn analyze(prior: &Prior, solution: &Solution) -> Result<Dof> {
    if !solution.feasible {
        return Err(PriorError::InvalidInput(
            "degrees of freedom need a feasible solution".into(),
        ));
    }
    let members = solution.inliers();
    let m = members.len();
    let n = 2 * m;
    let links: Vec<Topology> = solution.links.iter().map(|l| l.topology).collect();
    let x: Vec<f64> = members
        .iter()
        .flat_map(|&i| [solution.rho[i], solution.alpha[i]])
        .collect();
    let phi: Vec<f64> = members.iter().map(|&i| solution.phi[i]).collect();
    let windows = windows_of(prior.order, &links, m);
    let (rows, energy) = match prior.order {
        2 => jacobian::<4>(prior, &windows, &x, &phi),
        3 => jacobian::<6>(prior, &windows, &x, &phi),
        _ => jacobian::<8>(prior, &windows, &x, &phi),
    };
    // Free = ker J: eigenvectors of J^T J with (relatively) zero eigenvalues.
    let mut jtj = DMatrix::<f64>::zeros(n, n);
    for (start, row) in &rows {
        for (a, &ra) in row.iter().enumerate() {
            for (b, &rb) in row.iter().enumerate() {
                jtj[(start + a, start + b)] += ra * rb;
            }
        }
    }
    let free = if rows.is_empty() {
        DMatrix::identity(n, n)
    } else {
        let eigen = jtj.symmetric_eigen();
        let largest = eigen.eigenvalues.iter().fold(0.0_f64, |a, &v| a.max(v));
        let threshold = (RANK_TOLERANCE * RANK_TOLERANCE) * largest;
        let columns: Vec<DVector<f64>> = (0..n)
            .filter(|&k| eigen.eigenvalues[k] <= threshold)
            .map(|k| eigen.eigenvectors.column(k).into_owned())
            .collect();
        matrix_of(n, &columns)
    };
    let d = free.ncols();
    // Extr: derivative of the readings with respect to the sensor pose.
    let e = extrinsic_directions(&members, &links, &x, &phi);
    let q = free.transpose() * &e; // d x 3
    let e_norm = e.norm().max(1e-300);
    let qqt = &q * q.transpose();
    let (extrinsic, intrinsic) = if d == 0 {
        (DMatrix::zeros(n, 0), DMatrix::zeros(n, 0))
    } else {
        let eigen = qqt.symmetric_eigen();
        let threshold = (EXTRINSIC_TOLERANCE * e_norm).powi(2);
        let mut ext = Vec::new();
        let mut int = Vec::new();
        for k in 0..d {
            let column = &free * eigen.eigenvectors.column(k);
            if eigen.eigenvalues[k] > threshold {
                ext.push(column);
            } else {
                int.push(column);
            }
        }
        (matrix_of(n, &ext), matrix_of(n, &int))
    };
    // Posterior covariance in Free coordinates.
    let mut information = energy;
    for (j, &i) in members.iter().enumerate() {
        information[(2 * j, 2 * j)] += 1.0 / (solution.sigma[i] * solution.sigma[i]);
        let sa = solution.alpha_sigma[i];
        information[(2 * j + 1, 2 * j + 1)] += 1.0 / (sa * sa);
    }
    let cholesky = information
        .cholesky()
        .ok_or_else(|| PriorError::Numerical("posterior information not positive".into()))?;
    let core = if d == 0 {
        DMatrix::zeros(0, 0)
    } else {
        let solved = cholesky.solve(&free);
        let c = free.transpose() * solved;
        0.5 * (&c + c.transpose())
    };
    let mut variations: Vec<(f64, DVector<f64>)> = if d == 0 {
        Vec::new()
    } else {
        let eigen = core.clone().symmetric_eigen();
        (0..d)
            .map(|k| {
                (
                    eigen.eigenvalues[k].max(0.0).sqrt(),
                    &free * eigen.eigenvectors.column(k),
                )
            })
            .collect()
    };
    variations.sort_by(|a, b| b.0.total_cmp(&a.0));
    Ok(Dof {
        members,
        constraints: rows.len(),
        free,
        extrinsic,
        intrinsic,
        core,
        variations,
    })
}

fn matrix_of(n: usize, columns: &[DVector<f64>]) -> DMatrix<f64> {
    if columns.is_empty() {
        DMatrix::zeros(n, 0)
    } else {
        DMatrix::from_columns(columns)
    }
}

/// Normalized gradients of the active equalities (`(first variable, row)`) and the dense
/// convexified Hessian of the energies.
fn jacobian<const N: usize>(
    prior: &Prior,
    windows: &[(usize, Topology)],
    x: &[f64],
    phi: &[f64],
) -> (Vec<(usize, Vec<f64>)>, DMatrix<f64>) {
    let k = 2 * prior.order;
    let mut rows = Vec::new();
    let mut energy = DMatrix::zeros(x.len(), x.len());
    let mut buffer: Vec<Dual<N>> = Vec::new();
    for &(start, topology) in windows {
        let priorlet = prior.priorlet(topology);
        if priorlet.is_empty() {
            continue;
        }
        let local: Vec<Dual<N>> = (0..k)
            .map(|i| Dual::variable(x[2 * start + i], i))
            .collect();
        priorlet.eval(&local, &phi[start..start + prior.order], &mut buffer);
        for c in &priorlet.constraints {
            let best = c
                .branches
                .iter()
                .min_by(|a, b| {
                    a.violation(buffer[a.node].v)
                        .total_cmp(&b.violation(buffer[b.node].v))
                })
                .copied();
            let Some(atom) = best else { continue };
            if atom.kind != AtomKind::Equal {
                continue;
            }
            let g = &buffer[atom.node].g[..k];
            let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm > 0.0 && norm.is_finite() {
                rows.push((2 * start, g.iter().map(|v| v / norm).collect()));
            }
        }
        if !priorlet.energies.is_empty() {
            let mut h = [[0.0; N]; N];
            for &e in &priorlet.energies {
                for a in 0..k {
                    for b in 0..k {
                        h[a][b] += buffer[e].h[a][b];
                    }
                }
            }
            let h = convexify::<N>(&h, k, |_| 0.0);
            for a in 0..k {
                for b in 0..k {
                    energy[(2 * start + a, 2 * start + b)] += h[a][b];
                }
            }
        }
    }
    (rows, energy)
}

/// The `2 m x 3` derivative of `x` with respect to the sensor pose `(t_x, t_y, theta)`.
fn extrinsic_directions(
    members: &[usize],
    links: &[Topology],
    x: &[f64],
    phi: &[f64],
) -> DMatrix<f64> {
    let m = members.len();
    let mut e = DMatrix::zeros(2 * m, 3);
    let point = |j: usize| {
        let (s, c) = phi[j].sin_cos();
        [x[2 * j] * c, x[2 * j] * s]
    };
    for j in 0..m {
        let rho = x[2 * j];
        let alpha = x[2 * j + 1];
        let u = [phi[j].cos(), phi[j].sin()];
        let u_perp = [-u[1], u[0]];
        let normal = [alpha.cos(), alpha.sin()];
        let nu = normal[0] * u[0] + normal[1] * u[1];
        if nu.abs() < 1e-6 {
            continue; // grazing beam: the range is not differentiable
        }
        let d_rho_d_t = [-normal[0] / nu, -normal[1] / nu];
        let d_rho_d_theta = -rho * (normal[0] * u_perp[0] + normal[1] * u_perp[1]) / nu;
        // Curvature and tangent from the neighbours of the same region.
        let previous = (j > 0 && links[j - 1] == Topology::SameRegion).then(|| j - 1);
        let next = (j + 1 < m && links[j] == Topology::SameRegion).then_some(j + 1);
        let (a, b) = match (previous, next) {
            (Some(p), Some(q)) => (p, q),
            (Some(p), None) => (p, j),
            (None, Some(q)) => (j, q),
            (None, None) => (j, j),
        };
        // Tangent: perpendicular to the normal, pointing along the scan; curvature from the
        // normals of two neighbours on the circle through them (exact for a circle:
        // kappa = 2 sin(delta alpha / 2) / chord).
        let (pa, pb) = (point(a), point(b));
        let chord = [pb[0] - pa[0], pb[1] - pa[1]];
        let length = (chord[0] * chord[0] + chord[1] * chord[1]).sqrt();
        let (tangent, curvature) = if a == b || length < 1e-12 {
            ([0.0, 0.0], 0.0)
        } else {
            let mut t = [-normal[1], normal[0]];
            if t[0] * chord[0] + t[1] * chord[1] < 0.0 {
                t = [-t[0], -t[1]];
            }
            let turn = x[2 * b + 1] - x[2 * a + 1];
            let turn = turn.sin().atan2(turn.cos());
            (t, 2.0 * (0.5 * turn).sin() / length)
        };
        // dp/dt = I + u d_rho_d_t^T; dp/dtheta = u d_rho_d_theta + rho u_perp.
        let dp_dt = [
            [1.0 + u[0] * d_rho_d_t[0], u[0] * d_rho_d_t[1]],
            [u[1] * d_rho_d_t[0], 1.0 + u[1] * d_rho_d_t[1]],
        ];
        let dp_dtheta = [
            u[0] * d_rho_d_theta + rho * u_perp[0],
            u[1] * d_rho_d_theta + rho * u_perp[1],
        ];
        e[(2 * j, 0)] = d_rho_d_t[0];
        e[(2 * j, 1)] = d_rho_d_t[1];
        e[(2 * j, 2)] = d_rho_d_theta;
        for c in 0..2 {
            e[(2 * j + 1, c)] = curvature * (tangent[0] * dp_dt[0][c] + tangent[1] * dp_dt[1][c]);
        }
        e[(2 * j + 1, 2)] =
            curvature * (tangent[0] * dp_dtheta[0] + tangent[1] * dp_dtheta[1]) - 1.0;
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Scene, Shape};

    /// The derivative of the readings and normals with respect to the sensor pose against
    /// central differences of ray casting, on a circle seen from inside.
    #[test]
    fn extrinsic_directions_match_ray_casting() {
        let scene = Scene {
            shapes: vec![Shape::Circle {
                centre: [0.0, 0.0],
                radius: 3.0,
            }],
        };
        let pose = [0.7, -0.4, 0.2];
        let phi: Vec<f64> = (0..40).map(|k| -1.0 + 0.05 * k as f64).collect();
        let read = |pose: [f64; 3]| -> Vec<f64> {
            phi.iter()
                .flat_map(|&b| {
                    let (t, n, _) = scene.cast([pose[0], pose[1]], pose[2] + b).unwrap();
                    [t, n[1].atan2(n[0]) - pose[2]]
                })
                .collect()
        };
        let x = read(pose);
        let members: Vec<usize> = (0..phi.len()).collect();
        let links = vec![Topology::SameRegion; phi.len() - 1];
        let e = extrinsic_directions(&members, &links, &x, &phi);
        for c in 0..3 {
            let h = 1e-6;
            // A step along the sensor frame's axis c (or of its heading).
            let (s, co) = pose[2].sin_cos();
            let step = match c {
                0 => [co * h, s * h, 0.0],
                1 => [-s * h, co * h, 0.0],
                _ => [0.0, 0.0, h],
            };
            let up = [pose[0] + step[0], pose[1] + step[1], pose[2] + step[2]];
            let down = [pose[0] - step[0], pose[1] - step[1], pose[2] - step[2]];
            let (xu, xd) = (read(up), read(down));
            for r in 0..x.len() {
                let mut d = xu[r] - xd[r];
                d = d.sin().atan2(d.cos());
                let numeric = d / (2.0 * h);
                assert!(
                    (numeric - e[(r, c)]).abs() < 1e-5 * (1.0 + numeric.abs()),
                    "row {r} column {c}: analytic {} numeric {numeric}",
                    e[(r, c)]
                );
            }
        }
    }
}
