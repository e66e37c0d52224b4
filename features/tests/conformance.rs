//! Every feature type runs the slam-core conformance suite over random geometry, including
//! near-degenerate geometry, which must be an error and never a NaN.

use proptest::prelude::*;
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::testing::{ConformanceParams, check_coincidence, check_feature};
use slam_core::{Feature, test_feature_conformance};
use slam_features::{HLine, Point, Pole, PpcaLine, Wall};

test_feature_conformance!(
    wall_conforms,
    Wall::new(Vector2::new(1.0, 2.0), Vector2::new(4.0, -1.0)).unwrap()
);
test_feature_conformance!(
    ppca_line_conforms,
    PpcaLine::from_cluster(
        Vector2::new(1.0, 2.0),
        Vector2::new(0.6, 0.8),
        2.5,
        1e-4,
        90
    )
    .unwrap()
);
test_feature_conformance!(
    hline_conforms,
    HLine::new(Vector3::new(1.0, 2.0, 2.4), Vector3::new(-3.0, 0.5, 2.4)).unwrap()
);
test_feature_conformance!(
    pole_conforms,
    Pole::new(0.25, Vector2::new(-7.0, 3.0)).unwrap()
);
test_feature_conformance!(
    point_conforms,
    Point::new(Vector3::new(2.0, -1.0, 2.7)).unwrap()
);

/// Lengths closer than this to a minimum may be crossed by the suite's probes (steps of
/// `1e-6` scaled by coordinates up to 60).
const NEAR_DEGENERATE: f64 = 1e-4;

/// Lengths from well below the minimum up to 40 m, with extra weight near zero.
fn length() -> impl Strategy<Value = f64> {
    prop_oneof![0.0..2e-3, 2e-3..0.1, 0.1..40.0]
}

fn angle() -> impl Strategy<Value = f64> {
    -std::f64::consts::PI..std::f64::consts::PI
}

fn coordinate() -> impl Strategy<Value = f64> {
    -60.0..60.0
}

fn assert_conforms(feature: &dyn Feature) -> Result<(), TestCaseError> {
    let report = check_feature(feature, &ConformanceParams::default())
        .map_err(|failure| TestCaseError::fail(failure.to_string()))?;
    prop_assert!(!report.configurations.is_empty());
    Ok(())
}

/// Conformance of a feature `margin` above its degenerate limit: within [`NEAR_DEGENERATE`]
/// the suite's probes may cross the limit, which must be refused as degenerate (never a NaN).
fn assert_conforms_near(feature: &dyn Feature, margin: f64) -> Result<(), TestCaseError> {
    if margin >= NEAR_DEGENERATE {
        return assert_conforms(feature);
    }
    if let Err(failure) = check_feature(feature, &ConformanceParams::default()) {
        prop_assert!(failure.detail.contains("degenerate"), "{failure}");
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn walls_conform_or_refuse(x in coordinate(), y in coordinate(), l in length(), a in angle()) {
        let start = Vector2::new(x, y);
        let end = start + l * Vector2::new(a.cos(), a.sin());
        match Wall::new(start, end) {
            Ok(wall) => {
                let length = (end - start).norm();
                prop_assert!(length >= Wall::MIN_LENGTH);
                assert_conforms_near(&wall, length - Wall::MIN_LENGTH)?;
            }
            Err(e) => {
                prop_assert!((end - start).norm() < Wall::MIN_LENGTH, "refused a {l} m wall: {e}");
            }
        }
    }

    #[test]
    fn hlines_conform_or_refuse(
        x in coordinate(), y in coordinate(), z in -5.0..10.0f64, l in length(), a in angle(),
    ) {
        let start = Vector3::new(x, y, z);
        let end = start + l * Vector3::new(a.cos(), a.sin(), 0.0);
        match HLine::new(start, end) {
            Ok(line) => assert_conforms_near(&line, (end - start).norm() - HLine::MIN_LENGTH)?,
            Err(e) => prop_assert!((end - start).norm() < HLine::MIN_LENGTH, "refused: {e}"),
        }
    }

    #[test]
    fn poles_conform_or_refuse(x in coordinate(), y in coordinate(), r in prop_oneof![-1.0..1e-3, 1e-3..3.0]) {
        match Pole::new(r, Vector2::new(x, y)) {
            Ok(pole) => assert_conforms_near(&pole, r - Pole::MIN_RADIUS)?,
            Err(e) => prop_assert!(r < Pole::MIN_RADIUS, "refused r = {r}: {e}"),
        }
    }

    #[test]
    fn points_conform(x in coordinate(), y in coordinate(), z in -10.0..10.0f64) {
        assert_conforms(&Point::new(Vector3::new(x, y, z)).unwrap())?;
    }

    #[test]
    fn non_finite_geometry_is_an_error(bad in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(f64::NEG_INFINITY)]) {
        prop_assert!(Wall::new(Vector2::new(bad, 0.0), Vector2::new(1.0, 0.0)).is_err());
        prop_assert!(HLine::new(Vector3::new(0.0, 0.0, bad), Vector3::new(1.0, 0.0, 2.0)).is_err());
        prop_assert!(Pole::new(bad, Vector2::new(1.0, 0.0)).is_err());
        prop_assert!(Point::new(Vector3::new(0.0, bad, 0.0)).is_err());
    }

    #[test]
    fn wall_coincidence_jacobians(
        x in coordinate(), y in coordinate(), l in 0.2..20.0f64, a in angle(),
        dx in -1.0..1.0f64, dy in -1.0..1.0f64, m in 0.2..20.0f64, turn in -0.5..0.5f64,
    ) {
        let start = Vector2::new(x, y);
        let wall = Wall::new(start, start + l * Vector2::new(a.cos(), a.sin())).unwrap();
        let other_start = start + Vector2::new(dx, dy);
        let direction = Vector2::new((a + turn).cos(), (a + turn).sin());
        let other = Wall::new(other_start, other_start + m * direction).unwrap();
        let checked = check_coincidence(&wall, &other, &ConformanceParams::default())
            .map_err(|failure| TestCaseError::fail(failure.to_string()))?;
        prop_assert!(checked, "walls facing the same way must be comparable");
        let reversed = Wall::new(other.end(), other.start()).unwrap();
        prop_assert!(wall.coincidence(&reversed).unwrap().is_none(), "the other side of a wall");
    }

    #[test]
    fn pole_and_point_coincidence_jacobians(
        x in coordinate(), y in coordinate(), z in -5.0..5.0f64, r in 0.05..1.0f64,
        dx in -1.0..1.0f64, dy in -1.0..1.0f64,
    ) {
        let params = ConformanceParams::default();
        let pole = Pole::new(r, Vector2::new(x, y)).unwrap();
        let near = Pole::new(r * 1.5, Vector2::new(x + dx, y + dy)).unwrap();
        prop_assert_eq!(check_coincidence(&pole, &near, &params), Ok(true));
        let point = Point::new(Vector3::new(x, y, z)).unwrap();
        let other = Point::new(Vector3::new(x + dx, y + dy, z + dx)).unwrap();
        prop_assert_eq!(check_coincidence(&point, &other, &params), Ok(true));
        prop_assert_eq!(check_coincidence(&pole, &point, &params), Ok(false));
    }
}

/// A pole just above the minimum radius, where the suite's probes cross it (the case
/// proptest drew in CI on 28 Nov 2026): refused as degenerate, never a NaN.
#[test]
fn a_pole_at_the_minimum_radius_is_refused_as_degenerate_by_the_probes() {
    let pole = Pole::new(Pole::MIN_RADIUS + 1e-9, Vector2::new(-50.0, 40.0)).unwrap();
    assert_conforms_near(&pole, 1e-9).unwrap();
    let refused = check_feature(&pole, &ConformanceParams::default());
    assert!(
        refused.is_err_and(|failure| failure.detail.contains("degenerate")),
        "the probes should cross the minimum radius"
    );
}
