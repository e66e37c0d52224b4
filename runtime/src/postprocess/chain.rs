//! A chain of planar poses smoothed against measurements of each pose and the odometry
//! between neighbours: `min sum_i rho(|x_i - z_i|^2_{Λ_i}) + sum_i |(x_{i-1} ⊖ x_i) - u_i|^2_{Ω_i}`,
//! with `rho` the Cauchy loss on the squared Mahalanobis distance of each pose measurement
//! (a measurement far from what its neighbours and the odometry say is down-weighted, not
//! followed). Gauss-Newton with re-weighting; the normal equations are block tridiagonal and
//! are solved by block elimination in `O(n)`.

use slam_core::nalgebra::{Matrix3, Vector3};
use slam_core::{Pose2, wrap_angle};

/// A measurement of one pose: the pose and its information (inverse covariance).
#[derive(Clone, Copy, Debug)]
pub(crate) struct PoseMeasurement {
    pub pose: Pose2,
    pub information: Matrix3<f64>,
}

/// The odometry from the pose before to this one: `x_{i-1} ⊖ x_i` and its information.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Odometry {
    pub increment: Pose2,
    pub information: Matrix3<f64>,
}

/// One node of the chain.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ChainNode {
    /// Where the solver starts.
    pub initial: Pose2,
    /// A measurement of the pose, if any.
    pub measurement: Option<PoseMeasurement>,
    /// The odometry from the node before (none for the first node or where the chain breaks).
    pub odometry: Option<Odometry>,
}

/// The smoothed poses and the final weight of each node's measurement (1 for a measurement
/// that agrees with the rest, towards 0 for one that does not; 0 without a measurement).
#[derive(Clone, Debug)]
pub(crate) struct SmoothedChain {
    pub poses: Vec<Pose2>,
    pub weights: Vec<f64>,
}

/// The information, per unit of each coordinate, of the weak prior at every node's initial
/// pose that keeps a stretch without measurements determined ((100 m)^2 and (100 rad)^2).
const WEAK_PRIOR: f64 = 1e-4;

/// Smooths the chain (see the module documentation); `cauchy_scale` is the Mahalanobis
/// distance at which a measurement's weight halves. `None` when the normal equations are
/// not positive definite or a step is not finite.
pub(crate) fn smooth_chain(
    nodes: &[ChainNode],
    cauchy_scale: f64,
    iterations: usize,
) -> Option<SmoothedChain> {
    let n = nodes.len();
    let mut poses: Vec<Pose2> = nodes.iter().map(|node| node.initial).collect();
    let mut weights = vec![0.0; n];
    for _ in 0..iterations {
        let mut diagonal = vec![Matrix3::identity() * WEAK_PRIOR; n];
        let mut off_diagonal = vec![Matrix3::zeros(); n]; // (i - 1, i), for i >= 1
        let mut gradient = vec![Vector3::zeros(); n];
        for (i, node) in nodes.iter().enumerate() {
            gradient[i] += difference(&poses[i], &node.initial) * WEAK_PRIOR;
            if let Some(measurement) = &node.measurement {
                let error = difference(&poses[i], &measurement.pose);
                let squared = error.dot(&(measurement.information * error));
                weights[i] = 1.0 / (1.0 + squared / (cauchy_scale * cauchy_scale));
                diagonal[i] += measurement.information * weights[i];
                gradient[i] += measurement.information * error * weights[i];
            }
            if let (Some(odometry), true) = (&node.odometry, i > 0) {
                let (relative, d_before, d_this) = poses[i - 1].between_with_jacobians(&poses[i]);
                let error = difference(&relative, &odometry.increment);
                let omega = odometry.information;
                diagonal[i - 1] += d_before.transpose() * omega * d_before;
                diagonal[i] += d_this.transpose() * omega * d_this;
                off_diagonal[i] += d_before.transpose() * omega * d_this;
                gradient[i - 1] += d_before.transpose() * omega * error;
                gradient[i] += d_this.transpose() * omega * error;
            }
        }
        let step = solve_block_tridiagonal(&diagonal, &off_diagonal, &gradient)?;
        let mut largest: f64 = 0.0;
        for (pose, delta) in poses.iter_mut().zip(&step) {
            *pose = Pose2::new(
                pose.x + delta.x,
                pose.y + delta.y,
                wrap_angle(pose.theta + delta.z),
            );
            largest = largest.max(delta.amax());
        }
        if !largest.is_finite() {
            return None;
        }
        if largest < 1e-7 {
            break;
        }
    }
    Some(SmoothedChain { poses, weights })
}

/// `a - b` in `(x, y, theta)`, the angle wrapped.
fn difference(a: &Pose2, b: &Pose2) -> Vector3<f64> {
    Vector3::new(a.x - b.x, a.y - b.y, wrap_angle(a.theta - b.theta))
}

/// The step `d` of `H d = -g` for the symmetric block tridiagonal `H` with diagonal blocks
/// `diagonal[i]` and blocks `off_diagonal[i]` at `(i - 1, i)` (`off_diagonal[0]` unused).
fn solve_block_tridiagonal(
    diagonal: &[Matrix3<f64>],
    off_diagonal: &[Matrix3<f64>],
    gradient: &[Vector3<f64>],
) -> Option<Vec<Vector3<f64>>> {
    let n = diagonal.len();
    // Forward elimination: D'_i = D_i - O_i^T D'_{i-1}^{-1} O_i, r'_i likewise.
    let mut eliminated: Vec<Matrix3<f64>> = Vec::with_capacity(n);
    let mut rhs: Vec<Vector3<f64>> = Vec::with_capacity(n);
    for i in 0..n {
        let (block, right) = if i == 0 {
            (diagonal[0], -gradient[0])
        } else {
            let previous = eliminated[i - 1].cholesky()?;
            let coupling = off_diagonal[i];
            let solved = previous.solve(&coupling);
            (
                diagonal[i] - coupling.transpose() * solved,
                -gradient[i] - solved.transpose() * rhs[i - 1],
            )
        };
        eliminated.push(block);
        rhs.push(right);
    }
    // Back substitution.
    let mut step = vec![Vector3::zeros(); n];
    for i in (0..n).rev() {
        let mut right = rhs[i];
        if i + 1 < n {
            right -= off_diagonal[i + 1] * step[i + 1];
        }
        step[i] = eliminated[i].cholesky()?.solve(&right);
    }
    Some(step)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn information(sigma_xy: f64, sigma_theta: f64) -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::new(
            sigma_xy.powi(-2),
            sigma_xy.powi(-2),
            sigma_theta.powi(-2),
        ))
    }

    /// A path along x, 1 m a node, turning 0.1 rad a node.
    fn truth(n: usize) -> Vec<Pose2> {
        let mut pose = Pose2::identity();
        let step = Pose2::new(1.0, 0.0, 0.1);
        (0..n)
            .map(|_| {
                let here = pose;
                pose = pose.compose(&step);
                here
            })
            .collect()
    }

    #[test]
    fn the_block_solver_matches_a_dense_solve() {
        let n = 4;
        let mut dense = slam_core::nalgebra::DMatrix::<f64>::zeros(3 * n, 3 * n);
        let mut diagonal = Vec::new();
        let mut off = vec![Matrix3::zeros()];
        for i in 0..n {
            let d = Matrix3::new(5.0 + i as f64, 0.3, 0.1, 0.3, 4.0, -0.2, 0.1, -0.2, 3.0);
            dense.view_mut((3 * i, 3 * i), (3, 3)).copy_from(&d);
            diagonal.push(d);
            if i > 0 {
                let o = Matrix3::new(0.5, -0.1, 0.2, 0.3, 0.4, 0.0, -0.2, 0.1, 0.6) * 0.5;
                dense.view_mut((3 * (i - 1), 3 * i), (3, 3)).copy_from(&o);
                dense
                    .view_mut((3 * i, 3 * (i - 1)), (3, 3))
                    .copy_from(&o.transpose());
                off.push(o);
            }
        }
        let gradient: Vec<Vector3<f64>> = (0..n)
            .map(|i| Vector3::new(i as f64, 1.0 - i as f64, 0.5))
            .collect();
        let step = solve_block_tridiagonal(&diagonal, &off, &gradient).unwrap();
        let g = slam_core::nalgebra::DVector::from_iterator(
            3 * n,
            gradient.iter().flat_map(|v| v.iter().copied()),
        );
        let expected = dense.lu().solve(&(-g)).unwrap();
        for i in 0..n {
            for k in 0..3 {
                assert!((step[i][k] - expected[3 * i + k]).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_run_of_wrong_measurements_is_outvoted_by_the_odometry_and_the_rest() {
        let poses = truth(40);
        let odometry = information(0.02, 0.005);
        let measured = information(0.01, 0.002);
        let nodes: Vec<ChainNode> = (0..poses.len())
            .map(|i| {
                // Nodes 15-19 measured 1 m off along the path, consistently.
                let off = if (15..20).contains(&i) {
                    Pose2::new(1.0, 0.0, 0.0)
                } else {
                    Pose2::identity()
                };
                ChainNode {
                    initial: poses[i].compose(&Pose2::new(0.3, -0.2, 0.05)),
                    measurement: Some(PoseMeasurement {
                        pose: poses[i].compose(&off),
                        information: measured,
                    }),
                    odometry: (i > 0).then(|| Odometry {
                        increment: poses[i - 1].between(&poses[i]),
                        information: odometry,
                    }),
                }
            })
            .collect();
        let smoothed = smooth_chain(&nodes, 3.0, 50).unwrap();
        for (i, (found, true_pose)) in smoothed.poses.iter().zip(&poses).enumerate() {
            // The outvoted measurements keep a Cauchy weight of about 1e-3, which pulls the
            // nodes next to them by a centimetre (of the metre they are off).
            let error = true_pose.between(found);
            assert!(error.translation().norm() < 0.02, "node {i}: {error:?}");
        }
        assert!(smoothed.weights[17] < 0.01 && smoothed.weights[5] > 0.99);
        // Without the odometry each node follows its own measurement.
        let alone: Vec<ChainNode> = nodes
            .iter()
            .map(|node| ChainNode {
                odometry: None,
                ..*node
            })
            .collect();
        let followed = smooth_chain(&alone, 3.0, 50).unwrap();
        assert!(poses[17].between(&followed.poses[17]).translation().norm() > 0.99);
    }

    #[test]
    fn a_stretch_without_measurements_follows_the_odometry() {
        let poses = truth(12);
        let nodes: Vec<ChainNode> = (0..poses.len())
            .map(|i| ChainNode {
                initial: Pose2::identity(),
                measurement: (!(3..=9).contains(&i)).then(|| PoseMeasurement {
                    pose: poses[i],
                    information: information(0.01, 0.002),
                }),
                odometry: (i > 0).then(|| Odometry {
                    increment: poses[i - 1].between(&poses[i]),
                    information: information(0.02, 0.005),
                }),
            })
            .collect();
        let smoothed = smooth_chain(&nodes, 3.0, 50).unwrap();
        for (i, (found, true_pose)) in smoothed.poses.iter().zip(&poses).enumerate() {
            let error = true_pose.between(found).translation().norm();
            // Only the weak prior at the initial poses (identity, up to 11 m away) pulls.
            assert!(error < 1e-4, "node {i}: {error}");
        }
    }
}
