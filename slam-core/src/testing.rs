//! The conformance suite: the checks every feature type and measurement model must pass,
//! ours or a user's, each runnable in one line.
//!
//! - [`assert_feature_conforms`] (or the [`test_feature_conformance!`](crate::test_feature_conformance)
//!   macro): explores every reachable M-space configuration (every order of growth, every
//!   combination of shared blocks) and checks `B B~ = I` (eq. 12); that B and B~ vanish on
//!   shared blocks (section VI); that `apply_perturbation` changes `x_f` by `B~ dx_p` to first
//!   order (central differences); that the unobserved directions stay put (a configuration's
//!   perturbations leave the subspaces it lacks unchanged, measured by the B rows of the
//!   configurations that have them); that bad perturbations are errors that leave the feature unchanged; the Jacobians
//!   `J_of` and `J_os` of the transform (eqs. 7-9, 34) for the feature's coordinates, level and
//!   tilted, against central differences; and a serde round trip of `Box<dyn Feature>`.
//! - [`assert_measurement_conforms`]: every block of the linearized measurement (eq. 30):
//!   `J_eta_o`, `J_eta_v`, robot, sensor offset, own M-space and shared-block columns, against
//!   central differences of the whole chain; a feature initialized from a measurement explains it.

use std::collections::HashSet;
use std::fmt;

use nalgebra::{DMatrix, DVector, Vector3, Vector6};

use crate::coords::CoordBlock;
use crate::feature::Feature;
use crate::measurement::{
    DynMeasurementModel, LinearizedMeasurement, MeasurementModel, OwnLinearization, SensorFrame,
    chain_linearize_at, chain_linearize_own_at, innovation_at, linearize, linearize_at,
    linearize_at_into, linearize_own_at, linearize_own_at_into,
};
use crate::pose::{Pose2, Pose3, RobotPose};
use crate::transform::MapToSensor;

/// Central-difference Jacobian of `f` at `x`; the step for coordinate `i` is
/// `step * max(1, |x_i|)`.
///
/// ```
/// use slam_core::{testing::numeric_jacobian, nalgebra::DVector};
/// let j = numeric_jacobian(&DVector::from_vec(vec![2.0]), 1e-6, |x| DVector::from_vec(vec![x[0] * x[0]]));
/// assert!((j[(0, 0)] - 4.0).abs() < 1e-6);
/// ```
pub fn numeric_jacobian(
    x: &DVector<f64>,
    step: f64,
    mut f: impl FnMut(&DVector<f64>) -> DVector<f64>,
) -> DMatrix<f64> {
    let f0 = f(x);
    let mut jacobian = DMatrix::zeros(f0.len(), x.len());
    for i in 0..x.len() {
        let h = step * x[i].abs().max(1.0);
        let mut plus = x.clone();
        plus[i] += h;
        let mut minus = x.clone();
        minus[i] -= h;
        let column = (f(&plus) - f(&minus)) / (2.0 * h);
        jacobian.set_column(i, &column);
    }
    jacobian
}

/// Tolerances and probes of the conformance suite.
#[derive(Clone, Debug, PartialEq)]
pub struct ConformanceParams {
    /// Allowed `|B B~ - I|` entry, scaled by `1 + max|B| max|B~|`.
    pub identity_tolerance: f64,
    /// Allowed difference of analytic and numeric Jacobian entries, relative to
    /// `max(1, max|J|)`.
    pub jacobian_tolerance: f64,
    /// Central-difference step (scaled per coordinate, see [`numeric_jacobian`]).
    pub step: f64,
    /// Most M-space configurations explored per feature.
    pub max_configurations: usize,
    /// Sensor poses at which the transform Jacobians are checked (level and tilted).
    pub sensor_poses: Vec<Pose3>,
}

impl Default for ConformanceParams {
    fn default() -> Self {
        ConformanceParams {
            identity_tolerance: 1e-9,
            jacobian_tolerance: 1e-5,
            step: 1e-6,
            max_configurations: 64,
            sensor_poses: vec![
                Pose3::identity(),
                Pose3::new(Vector3::new(1.5, -2.0, 0.3), 0.9, 0.0, 0.0),
                Pose3::new(Vector3::new(-0.7, 0.4, 1.2), -2.4, 0.15, -0.1),
                Pose3::new(Vector3::new(0.3, 0.2, 0.5), 2.8, -0.6, 0.5),
            ],
        }
    }
}

/// A failed conformance check: which check, in which configuration, and what was seen.
#[derive(Clone, Debug, PartialEq)]
pub struct ConformanceFailure {
    /// Name of the check.
    pub check: &'static str,
    /// The M-space configuration (active subspaces, shared blocks) or probe.
    pub configuration: String,
    /// What was wrong.
    pub detail: String,
}

impl fmt::Display for ConformanceFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "conformance check `{}` failed in configuration [{}]: {}",
            self.check, self.configuration, self.detail
        )
    }
}

impl std::error::Error for ConformanceFailure {}

/// What a passing run covered.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ConformanceReport {
    /// The configurations checked, described.
    pub configurations: Vec<String>,
    /// The largest own M-space dimension reached.
    pub max_dim: usize,
}

type Check<T> = std::result::Result<T, ConformanceFailure>;

fn fail<T>(check: &'static str, configuration: &str, detail: impl Into<String>) -> Check<T> {
    Err(ConformanceFailure {
        check,
        configuration: configuration.to_string(),
        detail: detail.into(),
    })
}

/// A linearization buffer as a filter leaves it: other shapes (larger and smaller than any
/// model's), NaN entries, a shared block.
fn stale_linearization() -> LinearizedMeasurement {
    let nan = |r, c| DMatrix::from_element(r, c, f64::NAN);
    LinearizedMeasurement {
        eta: DVector::from_element(7, f64::NAN),
        cov_eta: nan(1, 1),
        d_eta_d_robot: nan(9, 9),
        d_eta_d_sensor: nan(1, 2),
        d_eta_d_own: nan(8, 8),
        d_eta_d_shared: vec![(0, nan(2, 2))],
        d_eta_d_xf: nan(0, 3),
    }
}

fn describe(feature: &dyn Feature) -> String {
    let active: Vec<&str> = feature.active_subspaces().iter().map(|s| s.name).collect();
    let shared: Vec<usize> = (0..feature.coordinates().num_blocks())
        .filter(|&k| feature.is_shared(k))
        .collect();
    format!(
        "{} dim {} active {:?} shared blocks {:?}",
        feature.kind(),
        feature.mspace_dim(),
        active,
        shared
    )
}

fn configuration_key(feature: &dyn Feature) -> (Vec<&'static str>, Vec<bool>) {
    let mut active: Vec<&'static str> = feature.active_subspaces().iter().map(|s| s.name).collect();
    active.sort_unstable();
    let shared = (0..feature.coordinates().num_blocks())
        .map(|k| feature.is_shared(k))
        .collect();
    (active, shared)
}

fn compare_jacobians(
    check: &'static str,
    configuration: &str,
    analytic: &DMatrix<f64>,
    numeric: &DMatrix<f64>,
    tolerance: f64,
) -> Check<()> {
    if analytic.shape() != numeric.shape() {
        return fail(
            check,
            configuration,
            format!(
                "shape {:?}, numeric {:?}",
                analytic.shape(),
                numeric.shape()
            ),
        );
    }
    let scale = analytic.amax().max(1.0);
    let error = (analytic - numeric).amax();
    if error.is_nan() || error > tolerance * scale {
        return fail(
            check,
            configuration,
            format!(
                "max difference {error:e} (scale {scale:e})\nanalytic {analytic}numeric {numeric}"
            ),
        );
    }
    Ok(())
}

/// Runs the feature conformance suite; see the module documentation.
pub fn check_feature(
    feature: &dyn Feature,
    params: &ConformanceParams,
) -> Check<ConformanceReport> {
    let mut report = ConformanceReport::default();
    let mut seen = HashSet::new();
    let mut explored = Vec::new();
    let mut queue: Vec<Box<dyn Feature>> = vec![dyn_clone::clone_box(feature)];
    while let Some(current) = queue.pop() {
        if report.configurations.len() >= params.max_configurations {
            break;
        }
        if !seen.insert(configuration_key(&*current)) {
            continue;
        }
        let configuration = describe(&*current);
        let (b, b_dual) = check_configuration(&*current, &configuration, params)?;
        report.max_dim = report.max_dim.max(current.mspace_dim());
        report.configurations.push(configuration.clone());
        queue.extend(grown(&*current, &configuration)?);
        queue.extend(shared(&*current, &configuration)?);
        explored.push(Explored {
            key: configuration_key(&*current),
            active: current.active_subspaces(),
            b,
            b_dual,
            configuration,
        });
    }
    check_unobserved_directions(&explored, params)?;
    Ok(report)
}

/// One explored configuration, kept for the pairwise check.
struct Explored {
    key: (Vec<&'static str>, Vec<bool>),
    active: Vec<crate::feature::Subspace>,
    b: DMatrix<f64>,
    b_dual: DMatrix<f64>,
    configuration: String,
}

/// The unobserved directions stay put: perturbing a configuration's M-space leaves every
/// subspace it lacks unchanged, as measured by the rows of B of any larger configuration
/// (same sharing) that has them: `B_larger[missing rows] B~_smaller = 0`.
fn check_unobserved_directions(explored: &[Explored], params: &ConformanceParams) -> Check<()> {
    for small in explored {
        for large in explored {
            let same_sharing = small.key.1 == large.key.1;
            let contains = small.key.0.iter().all(|n| large.key.0.contains(n));
            if !same_sharing || !contains || small.key.0.len() == large.key.0.len() {
                continue;
            }
            let mut row = 0;
            for subspace in &large.active {
                if !small.key.0.contains(&subspace.name) {
                    let rows = large.b.rows(row, subspace.rows) * &small.b_dual;
                    let scale = 1.0 + large.b.amax() * small.b_dual.amax();
                    if rows.amax() > params.identity_tolerance * scale {
                        return fail(
                            "unobserved directions",
                            &small.configuration,
                            format!(
                                "its perturbations move `{}` of [{}] by up to {:e} per unit",
                                subspace.name,
                                large.configuration,
                                rows.amax()
                            ),
                        );
                    }
                }
                row += subspace.rows;
            }
        }
    }
    Ok(())
}

/// Checks [`Feature::coincidence`] of `feature` against `other`: the Jacobians `d_self` and
/// `d_other` against central differences of the residual in each feature's coordinates, and
/// the residual zero when `other` is `feature` itself. `Ok(false)` when the type gives no
/// coincidence for this pair, `Ok(true)` when it was checked.
///
/// ```
/// use slam_core::testing::{check_coincidence, ConformanceParams};
/// use slam_core::Feature;
/// // A type without `coincidence` is never merged: nothing to check.
/// fn merged_kind(a: &dyn Feature, b: &dyn Feature) -> bool {
///     check_coincidence(a, b, &ConformanceParams::default()) == Ok(true)
/// }
/// # let _ = merged_kind;
/// ```
pub fn check_coincidence(
    feature: &dyn Feature,
    other: &dyn Feature,
    params: &ConformanceParams,
) -> Check<bool> {
    let configuration = describe(feature);
    let evaluate = |a: &dyn Feature, b: &dyn Feature| match a.coincidence(b) {
        Ok(found) => Ok(found),
        Err(e) => fail("coincidence", &configuration, format!("refused: {e}")),
    };
    let Some(at) = evaluate(feature, other)? else {
        return Ok(false);
    };
    let moved = |base: &dyn Feature, x: &DVector<f64>| -> Option<Box<dyn Feature>> {
        let mut copy = dyn_clone::clone_box(base);
        let coordinates = base.coordinates().with_vector(x).ok()?;
        copy.set_coordinates(coordinates).ok()?;
        Some(copy)
    };
    let residual_or_nan = |found: Option<Box<dyn Feature>>, swap: bool| -> DVector<f64> {
        let residual = found.and_then(|f| {
            let result = if swap {
                feature.coincidence(&*f)
            } else {
                f.coincidence(other)
            };
            result.ok().flatten().map(|c| c.residual)
        });
        residual.unwrap_or_else(|| DVector::from_element(at.residual.len(), f64::NAN))
    };
    let x_self = feature.coordinates().to_vector();
    let numeric_self = numeric_jacobian(&x_self, params.step, |x| {
        residual_or_nan(moved(feature, x), false)
    });
    compare_jacobians(
        "coincidence d_self",
        &configuration,
        &at.d_self,
        &numeric_self,
        params.jacobian_tolerance,
    )?;
    let x_other = other.coordinates().to_vector();
    let numeric_other = numeric_jacobian(&x_other, params.step, |x| {
        residual_or_nan(moved(other, x), true)
    });
    compare_jacobians(
        "coincidence d_other",
        &configuration,
        &at.d_other,
        &numeric_other,
        params.jacobian_tolerance,
    )?;
    if let Some(itself) = evaluate(feature, feature)? {
        let scale = 1.0 + feature.coordinates().to_vector().amax();
        if itself.residual.amax() > params.identity_tolerance * scale {
            return fail(
                "coincidence",
                &configuration,
                format!("a feature is not itself: residual {}", itself.residual),
            );
        }
    }
    Ok(true)
}

/// Panics with a readable message unless `feature` passes [`check_feature`] with default
/// parameters. Use it in a test: `assert_feature_conforms(&Wall::new(...)?)`.
pub fn assert_feature_conforms(feature: &dyn Feature) {
    if let Err(failure) = check_feature(feature, &ConformanceParams::default()) {
        panic!("{failure}");
    }
}

/// Defines a `#[test]` running the feature conformance suite on the feature that `$make`
/// evaluates to.
///
/// ```ignore
/// slam_core::test_feature_conformance!(wall_conforms, Wall::new(a, b).unwrap());
/// ```
#[macro_export]
macro_rules! test_feature_conformance {
    ($name:ident, $make:expr) => {
        #[test]
        fn $name() {
            let feature = $make;
            $crate::testing::assert_feature_conforms(&feature);
        }
    };
}

/// Every growth option activated on a copy, with the reported rows checked.
fn grown(feature: &dyn Feature, configuration: &str) -> Check<Vec<Box<dyn Feature>>> {
    let mut rejected = dyn_clone::clone_box(feature);
    if rejected.activate("no-such-subspace").is_ok() {
        return fail(
            "growth",
            configuration,
            "an unknown subspace name was accepted",
        );
    }
    if describe(&*rejected) != configuration {
        return fail(
            "growth",
            configuration,
            "a refused growth changed the feature",
        );
    }
    let mut out = Vec::new();
    for option in feature.growth_options() {
        let mut next = dyn_clone::clone_box(feature);
        let before = next.mspace_dim();
        let growth = match next.activate(option.name) {
            Ok(growth) => growth,
            Err(e) => {
                return fail(
                    "growth",
                    configuration,
                    format!("offered subspace `{}` refused: {e}", option.name),
                );
            }
        };
        if growth.rows != (before..before + option.rows) || next.mspace_dim() != growth.rows.end {
            return fail(
                "growth",
                configuration,
                format!(
                    "`{}` reported rows {:?}, dim went {before} -> {}",
                    option.name,
                    growth.rows,
                    next.mspace_dim()
                ),
            );
        }
        let active_rows: usize = next.active_subspaces().iter().map(|s| s.rows).sum();
        if next.mspace_dim() != active_rows {
            return fail(
                "growth",
                configuration,
                format!(
                    "dim {} after `{}` but the active subspaces have {active_rows} rows",
                    next.mspace_dim(),
                    option.name
                ),
            );
        }
        if growth.why().is_empty() {
            return fail(
                "growth",
                configuration,
                format!("`{}` says no why", option.name),
            );
        }
        out.push(next);
    }
    Ok(out)
}

/// Every shareable, unshared block shared on a copy (when the feature accepts it now).
fn shared(feature: &dyn Feature, configuration: &str) -> Check<Vec<Box<dyn Feature>>> {
    let mut out = Vec::new();
    for block in feature.shareable_blocks() {
        if feature.is_shared(block) {
            continue;
        }
        let mut next = dyn_clone::clone_box(feature);
        if next.share_block(block).is_ok() {
            if !next.is_shared(block) {
                return fail(
                    "sharing",
                    configuration,
                    format!("share_block({block}) succeeded but is_shared({block}) is false"),
                );
            }
            out.push(next);
        } else if describe(&*next) != configuration {
            return fail(
                "sharing",
                configuration,
                "a refused share changed the feature",
            );
        }
    }
    Ok(out)
}

fn check_configuration(
    feature: &dyn Feature,
    configuration: &str,
    params: &ConformanceParams,
) -> Check<(DMatrix<f64>, DMatrix<f64>)> {
    let (b, b_dual) = check_projection(feature, configuration, params)?;
    check_shared_blocks(feature, configuration, &b, &b_dual)?;
    check_perturbation(feature, configuration, &b_dual, params)?;
    check_transform(feature, configuration, params)?;
    check_serde(feature, configuration, &b)?;
    Ok((b, b_dual))
}

/// Shapes and `B B~ = I` (eq. 12).
fn check_projection(
    feature: &dyn Feature,
    configuration: &str,
    params: &ConformanceParams,
) -> Check<(DMatrix<f64>, DMatrix<f64>)> {
    let dim = feature.mspace_dim();
    let dim_f = feature.coordinates().dim();
    let rows: usize = feature.active_subspaces().iter().map(|s| s.rows).sum();
    if rows != dim {
        return fail(
            "dimension",
            configuration,
            format!("subspace rows {rows} != mspace_dim {dim}"),
        );
    }
    let b = match feature.projection() {
        Ok(b) => b,
        Err(e) => return fail("projection", configuration, format!("B failed: {e}")),
    };
    let b_dual = match feature.dual() {
        Ok(b) => b,
        Err(e) => return fail("projection", configuration, format!("B~ failed: {e}")),
    };
    if b.shape() != (dim, dim_f) || b_dual.shape() != (dim_f, dim) {
        return fail(
            "projection",
            configuration,
            format!(
                "B is {:?}, B~ is {:?}, expected ({dim}, {dim_f}) and ({dim_f}, {dim})",
                b.shape(),
                b_dual.shape()
            ),
        );
    }
    if !b.iter().chain(b_dual.iter()).all(|v| v.is_finite()) {
        return fail("projection", configuration, "B or B~ is not finite");
    }
    let error = (&b * &b_dual - DMatrix::identity(dim, dim)).amax();
    let scale = 1.0 + b.amax() * b_dual.amax();
    if error > params.identity_tolerance * scale {
        return fail(
            "B B~ = I",
            configuration,
            format!("max |B B~ - I| = {error:e}"),
        );
    }
    Ok((b, b_dual))
}

/// Own B and B~ vanish on shared blocks (section VI).
fn check_shared_blocks(
    feature: &dyn Feature,
    configuration: &str,
    b: &DMatrix<f64>,
    b_dual: &DMatrix<f64>,
) -> Check<()> {
    let coordinates = feature.coordinates();
    for k in (0..coordinates.num_blocks()).filter(|&k| feature.is_shared(k)) {
        let (offset, width) = (coordinates.offset(k), coordinates.blocks()[k].dim());
        if b.columns(offset, width).amax() > 0.0 || b_dual.rows(offset, width).amax() > 0.0 {
            return fail(
                "shared block",
                configuration,
                format!("own B or B~ is not zero on shared block {k}"),
            );
        }
    }
    Ok(())
}

/// `apply_perturbation` moves `x_f` by `B~ dx_p` to first order and only inside the M-space.
fn check_perturbation(
    feature: &dyn Feature,
    configuration: &str,
    b_dual: &DMatrix<f64>,
    params: &ConformanceParams,
) -> Check<()> {
    let dim = feature.mspace_dim();
    let x0 = feature.coordinates().to_vector();
    let apply = |dp: &DVector<f64>| -> Check<DVector<f64>> {
        let mut moved = dyn_clone::clone_box(feature);
        match moved.apply_perturbation(dp) {
            Ok(()) => Ok(moved.coordinates().to_vector()),
            Err(e) => fail(
                "perturbation",
                configuration,
                format!("small perturbation refused: {e}"),
            ),
        }
    };
    // Bad perturbations are errors and leave the feature unchanged.
    for bad in [
        DVector::from_element(dim + 1, 0.0),
        DVector::from_element(dim.max(1), f64::NAN),
    ] {
        if bad.len() == dim + 1 || dim > 0 {
            let mut moved = dyn_clone::clone_box(feature);
            if moved.apply_perturbation(&bad).is_ok() || moved.coordinates().to_vector() != x0 {
                return fail(
                    "perturbation",
                    configuration,
                    "a malformed perturbation was accepted or changed x_f",
                );
            }
        }
    }
    if dim == 0 {
        return match apply(&DVector::zeros(0)) {
            Ok(x) if x == x0 => Ok(()),
            Ok(_) => fail(
                "perturbation",
                configuration,
                "an empty perturbation moved x_f",
            ),
            Err(e) => Err(e),
        };
    }
    let mut first_error = None;
    let numeric = numeric_jacobian(&DVector::zeros(dim), params.step, |dp| match apply(dp) {
        Ok(x) => x,
        Err(e) => {
            first_error.get_or_insert(e);
            DVector::zeros(x0.len())
        }
    });
    if let Some(e) = first_error {
        return Err(e);
    }
    compare_jacobians(
        "d x_f / d dx_p = B~",
        configuration,
        b_dual,
        &numeric,
        params.jacobian_tolerance,
    )?;
    Ok(())
}

/// `J_of` and `J_os` of eqs. 7-9 and 34 for this feature's coordinates at several sensor poses.
fn check_transform(
    feature: &dyn Feature,
    configuration: &str,
    params: &ConformanceParams,
) -> Check<()> {
    let x_m = feature.coordinates();
    for pose in &params.sensor_poses {
        let probe = format!(
            "{configuration}; sensor at {:?}",
            pose.to_vector().as_slice()
        );
        let to_sensor = match MapToSensor::new(pose) {
            Ok(t) => t,
            Err(e) => return fail("transform", &probe, e.to_string()),
        };
        let seen = match to_sensor.transform_with_jacobians(x_m) {
            Ok(seen) => seen,
            Err(e) => return fail("transform", &probe, e.to_string()),
        };
        let numeric_f = numeric_jacobian(&x_m.to_vector(), params.step, |v| {
            x_m.with_vector(v)
                .and_then(|x| to_sensor.transform(&x))
                .map(|x| x.to_vector())
                .unwrap_or_else(|_| DVector::from_element(v.len(), f64::NAN))
        });
        compare_jacobians(
            "J_of",
            &probe,
            &seen.d_xo_d_xm,
            &numeric_f,
            params.jacobian_tolerance,
        )?;
        let pose_vector = DVector::from_column_slice(pose.to_vector().as_slice());
        let numeric_s = numeric_jacobian(&pose_vector, params.step, |v| {
            MapToSensor::new(&Pose3::from_vector(&Vector6::from_column_slice(
                v.as_slice(),
            )))
            .and_then(|t| t.transform(x_m))
            .map(|x| x.to_vector())
            .unwrap_or_else(|_| DVector::from_element(x_m.dim(), f64::NAN))
        });
        compare_jacobians(
            "J_os",
            &probe,
            &seen.d_xo_d_sensor,
            &numeric_s,
            params.jacobian_tolerance * 10.0,
        )?;
    }
    Ok(())
}

/// `Box<dyn Feature>` survives a JSON round trip.
fn check_serde(feature: &dyn Feature, configuration: &str, b: &DMatrix<f64>) -> Check<()> {
    let boxed = dyn_clone::clone_box(feature);
    let json = match serde_json::to_string(&boxed) {
        Ok(json) => json,
        Err(e) => return fail("serde", configuration, format!("serialize: {e}")),
    };
    let back: Box<dyn Feature> = match serde_json::from_str(&json) {
        Ok(back) => back,
        Err(e) => return fail("serde", configuration, format!("deserialize {json}: {e}")),
    };
    let same = describe(&*back) == configuration
        && back.coordinates() == feature.coordinates()
        && back
            .projection()
            .is_ok_and(|b2| (b2 - b).amax() <= 1e-12 * b.amax().max(1.0));
    if !same {
        return fail(
            "serde",
            configuration,
            format!("round trip changed the feature: {json}"),
        );
    }
    Ok(())
}

/// Runs the measurement conformance suite for `model` observing `feature` from a sensor at
/// `robot_from_sensor` on a robot at `world_from_robot`.
pub fn check_measurement<M: MeasurementModel>(
    model: &M,
    feature: &M::Feature,
    world_from_robot: &Pose2,
    robot_from_sensor: &Pose3,
    params: &ConformanceParams,
) -> Check<()> {
    let configuration = format!("{} seen from robot {world_from_robot:?}", describe(feature));
    let cfg = configuration.as_str();
    let dyn_model: &dyn DynMeasurementModel = model;
    let lin = linearize(dyn_model, feature, world_from_robot, robot_from_sensor)
        .or_else(|e| fail("linearize", cfg, e.to_string()))?;
    // A model that writes its own linearization must give the generic chain's numbers.
    let frame = SensorFrame::new(world_from_robot, robot_from_sensor)
        .or_else(|e| fail("sensor frame", cfg, e.to_string()))?;
    let chain = chain_linearize_at(dyn_model, feature, &frame)
        .or_else(|e| fail("chain_linearize_at", cfg, e.to_string()))?;
    if lin != chain {
        return fail(
            "linearize_at",
            cfg,
            format!("the model's own differs from the generic chain: {lin:?} against {chain:?}"),
        );
    }
    // Written into a buffer that held other shapes and numbers, the same.
    let mut reused = stale_linearization();
    linearize_at_into(dyn_model, feature, &frame, &mut reused)
        .or_else(|e| fail("linearize_at_into", cfg, e.to_string()))?;
    if reused != chain {
        return fail(
            "linearize_at_into",
            cfg,
            format!(
                "into a used buffer it differs from the generic chain: {reused:?} against {chain:?}"
            ),
        );
    }
    let m = lin.eta.len();
    let nan = || DVector::from_element(m, f64::NAN);
    let sensor = world_from_robot.world_from_sensor(robot_from_sensor);
    let x_o = MapToSensor::new(&sensor)
        .and_then(|t| t.transform(feature.coordinates()))
        .or_else(|e| fail("transform", cfg, e.to_string()))?;
    let innovation = model
        .innovation(feature, &x_o)
        .or_else(|e| fail("innovation", cfg, e.to_string()))?;
    let tol = params.jacobian_tolerance;

    // C_eta symmetric and positive semi-definite.
    let cov = &lin.cov_eta;
    if (cov - cov.transpose()).amax() > 1e-12 * cov.amax().max(1.0)
        || cov
            .clone()
            .symmetric_eigenvalues()
            .iter()
            .any(|&l| l < -1e-12 * cov.amax().max(1.0))
    {
        return fail(
            "C_eta",
            cfg,
            format!("not symmetric positive semi-definite: {cov}"),
        );
    }

    // J_eta_o against x_o.
    let numeric = numeric_jacobian(&x_o.to_vector(), params.step, |v| {
        x_o.with_vector(v)
            .and_then(|x| model.innovation(feature, &x))
            .map(|i| i.eta)
            .unwrap_or_else(|_| nan())
    });
    compare_jacobians("J_eta_o", cfg, &innovation.d_eta_d_xo, &numeric, tol)?;

    // J_eta_v against v.
    let numeric = numeric_jacobian(&model.measurement(), params.step, |v| {
        model
            .with_measurement(v)
            .and_then(|changed| changed.innovation(feature, &x_o))
            .map(|i| i.eta)
            .unwrap_or_else(|_| nan())
    });
    compare_jacobians("J_eta_v", cfg, &innovation.d_eta_d_v, &numeric, tol)?;

    // Robot pose and sensor offset columns: the whole chain of eq. 21.
    let robot = DVector::from_vec(world_from_robot.parameters());
    let numeric = numeric_jacobian(&robot, params.step, |v| {
        Pose2::from_parameters(v.as_slice())
            .and_then(|r| innovation_at(dyn_model, feature, &r, robot_from_sensor))
            .map(|i| i.eta)
            .unwrap_or_else(|_| nan())
    });
    compare_jacobians(
        "J_eta_o J_os J_sr",
        cfg,
        &lin.d_eta_d_robot,
        &numeric,
        tol * 10.0,
    )?;
    let offset = DVector::from_column_slice(robot_from_sensor.to_vector().as_slice());
    let numeric = numeric_jacobian(&offset, params.step, |v| {
        let offset = Pose3::from_vector(&Vector6::from_column_slice(v.as_slice()));
        innovation_at(dyn_model, feature, world_from_robot, &offset)
            .map(|i| i.eta)
            .unwrap_or_else(|_| nan())
    });
    compare_jacobians(
        "J_eta_o J_os J_ss",
        cfg,
        &lin.d_eta_d_sensor_offset(
            &SensorFrame::new(world_from_robot, robot_from_sensor)
                .or_else(|e| fail("sensor frame", cfg, e.to_string()))?,
        ),
        &numeric,
        tol * 10.0,
    )?;

    // The same linearization with the robot as a 3-D pose (the general composition and
    // frame, no planar path): eta, the feature's columns and the robot's x, y, yaw columns.
    let frame_3d = SensorFrame::new(&world_from_robot.to_pose3(0.0), robot_from_sensor)
        .or_else(|e| fail("3-D sensor frame", cfg, e.to_string()))?;
    let lin_3d = linearize_at(dyn_model, feature, &frame_3d)
        .or_else(|e| fail("linearize_at (3-D robot)", cfg, e.to_string()))?;
    // The reduced linearization of a filter over the feature alone: the same numbers.
    let own = linearize_own_at(dyn_model, feature, &frame_3d.to_sensor)
        .or_else(|e| fail("linearize_own_at", cfg, e.to_string()))?;
    let own_chain = chain_linearize_own_at(dyn_model, feature, &frame_3d.to_sensor)
        .or_else(|e| fail("chain_linearize_own_at", cfg, e.to_string()))?;
    if own != own_chain {
        return fail(
            "linearize_own_at",
            cfg,
            format!(
                "the model's own differs from the generic chain: {own:?} against {own_chain:?}"
            ),
        );
    }
    // Written into a buffer that held other shapes and numbers, the same.
    let mut reused = OwnLinearization {
        eta: DVector::from_element(7, f64::NAN),
        cov_eta: DMatrix::from_element(1, 1, f64::NAN),
        d_eta_d_own: DMatrix::from_element(8, 8, f64::NAN),
    };
    linearize_own_at_into(dyn_model, feature, &frame_3d.to_sensor, &mut reused)
        .or_else(|e| fail("linearize_own_at_into", cfg, e.to_string()))?;
    if reused != own_chain {
        return fail(
            "linearize_own_at_into",
            cfg,
            format!(
                "into a used buffer it differs from the generic chain: {reused:?} against {own_chain:?}"
            ),
        );
    }
    if own.eta != lin_3d.eta
        || own.cov_eta != lin_3d.cov_eta
        || own.d_eta_d_own != lin_3d.d_eta_d_own
    {
        return fail(
            "linearize_own_at",
            cfg,
            format!("differs from linearize_at: {own:?} against {lin_3d:?}"),
        );
    }
    let robot_3d = lin_3d.d_eta_d_robot.select_columns(&[0, 1, 3]);
    for (what, planar, general) in [
        (
            "eta",
            &DMatrix::from_column_slice(m, 1, lin.eta.as_slice()),
            &DMatrix::from_column_slice(m, 1, lin_3d.eta.as_slice()),
        ),
        ("J_eta_o J_os J_sr", &lin.d_eta_d_robot, &robot_3d),
        ("J_eta_o J_of B~", &lin.d_eta_d_own, &lin_3d.d_eta_d_own),
        ("C_eta", &lin.cov_eta, &lin_3d.cov_eta),
    ] {
        if (planar - general).amax() > 1e-9 * general.amax().max(1.0) {
            return fail(
                "planar against 3-D robot pose",
                cfg,
                format!("{what}: {planar} against {general}"),
            );
        }
    }

    // Own M-space columns, J_eta_o J_of B~ (eq. 30).
    let numeric = numeric_jacobian(&DVector::zeros(feature.mspace_dim()), params.step, |dp| {
        let mut moved = dyn_clone::clone(feature);
        moved
            .apply_perturbation(dp)
            .and_then(|()| innovation_at(dyn_model, &moved, world_from_robot, robot_from_sensor))
            .map(|i| i.eta)
            .unwrap_or_else(|_| nan())
    });
    compare_jacobians(
        "J_eta_o J_of B~",
        cfg,
        &lin.d_eta_d_own,
        &numeric,
        tol * 10.0,
    )?;

    // Shared-block columns: identity rows on the block's coordinates (section VI).
    for (block, analytic) in &lin.d_eta_d_shared {
        let value = feature.coordinates().blocks()[*block];
        let numeric = numeric_jacobian(
            &DVector::from_column_slice(value.as_slice()),
            params.step,
            |v| {
                let mut moved = dyn_clone::clone(feature);
                CoordBlock::from_slice(value.kind(), v.as_slice())
                    .and_then(|b| moved.set_block(*block, b))
                    .and_then(|()| {
                        innovation_at(dyn_model, &moved, world_from_robot, robot_from_sensor)
                    })
                    .map(|i| i.eta)
                    .unwrap_or_else(|_| nan())
            },
        );
        compare_jacobians("shared block columns", cfg, analytic, &numeric, tol * 10.0)?;
    }

    // A feature made from this measurement alone explains it.
    if let Some(initial) = model
        .initial_feature(&sensor)
        .or_else(|e| fail("initial feature", cfg, e.to_string()))?
    {
        let eta = innovation_at(dyn_model, &initial, world_from_robot, robot_from_sensor)
            .or_else(|e| fail("initial feature", cfg, e.to_string()))?
            .eta;
        if eta.amax() > 1e-6 {
            return fail(
                "initial feature",
                cfg,
                format!("eta = {eta} for the feature initialized from v"),
            );
        }
    }
    Ok(())
}

/// Panics with a readable message unless [`check_measurement`] passes with default parameters.
pub fn assert_measurement_conforms<M: MeasurementModel>(
    model: &M,
    feature: &M::Feature,
    world_from_robot: &Pose2,
    robot_from_sensor: &Pose3,
) {
    if let Err(failure) = check_measurement(
        model,
        feature,
        world_from_robot,
        robot_from_sensor,
        &ConformanceParams::default(),
    ) {
        panic!("{failure}");
    }
}
