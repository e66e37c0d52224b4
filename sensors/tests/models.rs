//! Every measurement model against central differences of the whole chain (eq. 30), over
//! random geometry, at every M-space configuration it can meet; plus triangulation.

use std::f64::consts::PI;

use proptest::prelude::*;
use slam_core::nalgebra::{Matrix2, Vector2, Vector3};
use slam_core::testing::{ConformanceParams, check_measurement};
use slam_core::{Feature, FeatureMap, MapToSensor, MeasurementModel, Pose2, Pose3, RobotPose};
use slam_features::{HLine, Point, Pole, Wall};
use slam_sensors::camera::PinholeCamera;
use slam_sensors::models::{
    ImageLineObservation, ImagePointObservation, PoleObservation, RangeBearing, WallObservation,
};

fn check<M: MeasurementModel>(
    model: &M,
    feature: &M::Feature,
    robot: &Pose2,
    mount: &Pose3,
) -> Result<(), TestCaseError> {
    check_measurement(model, feature, robot, mount, &ConformanceParams::default())
        .map_err(|f| TestCaseError::fail(f.to_string()))
}

fn robot() -> impl Strategy<Value = Pose2> {
    (-3.0..3.0f64, -3.0..3.0f64, -PI..PI).prop_map(|(x, y, t)| Pose2::new(x, y, t))
}

/// A laser mount: forward offset, small tilt.
fn laser_mount() -> impl Strategy<Value = Pose3> {
    (
        0.0..0.5f64,
        -0.1..0.1f64,
        -0.2..0.2f64,
        -0.1..0.1f64,
        -0.1..0.1f64,
    )
        .prop_map(|(x, y, yaw, pitch, roll)| Pose3::new(Vector3::new(x, y, 0.3), yaw, pitch, roll))
}

/// A camera looking up, possibly slightly tilted.
fn camera_mount() -> impl Strategy<Value = Pose3> {
    (-0.2..0.2f64, -PI..PI, -0.05..0.05f64, -0.05..0.05f64)
        .prop_map(|(x, yaw, pitch, roll)| Pose3::new(Vector3::new(x, 0.0, 0.5), yaw, pitch, roll))
}

/// The feature seen from the sensor, for building a measurement near the truth.
fn in_sensor(feature: &dyn Feature, robot: &Pose2, mount: &Pose3) -> slam_core::Coordinates {
    let sensor = robot.world_from_sensor(mount);
    MapToSensor::new(&sensor)
        .unwrap()
        .transform(feature.coordinates())
        .unwrap()
}

fn wall_in_front(robot: &Pose2, distance: f64, length: f64, skew: f64) -> Wall {
    // A wall across the robot's heading at `distance`, rotated by `skew`.
    let heading = Vector2::new(robot.theta.cos(), robot.theta.sin());
    let centre = robot.translation() + heading * distance;
    let along = Vector2::new(-(robot.theta + skew).sin(), (robot.theta + skew).cos());
    Wall::seen_from(
        centre - along * length / 2.0,
        centre + along * length / 2.0,
        robot.translation(),
    )
    .unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn wall_observation_jacobians(
        robot in robot(), mount in laser_mount(), distance in 1.5..8.0f64, length in 0.5..6.0f64,
        skew in -0.8..0.8f64, noise in -0.05..0.05f64, real_a in any::<bool>(), real_b in any::<bool>(),
        config in 0usize..6,
    ) {
        let mut wall = wall_in_front(&robot, distance, length, skew);
        match config {
            0 => {}
            1 => { wall.activate("line").unwrap(); }
            2 => { wall = wall.with_subspaces(&["line", "start"]).unwrap(); }
            3 => { wall = wall.with_subspaces(&["line", "end", "start"]).unwrap(); }
            4 => { wall = wall.with_subspaces(&["line", "start"]).unwrap(); wall.share_block(1).unwrap(); }
            _ => { wall = wall.with_subspaces(&["line"]).unwrap(); wall.share_block(0).unwrap(); wall.share_block(1).unwrap(); }
        }
        let seen = in_sensor(&wall, &robot, &mount);
        let ends: Vec<Vector2<f64>> = seen.blocks().iter().map(|b| Vector2::from_column_slice(b.as_slice())).collect();
        let shift = Vector2::new(noise, -noise);
        let z = WallObservation::from_segment(
            ends[1] + shift, ends[0] + shift, Matrix2::new(1e-4, 0.0, 0.0, 4e-4), [real_a, real_b], [0.05, 0.07],
        ).unwrap();
        check(&z, &wall, &robot, &mount)?;
    }

    #[test]
    fn pole_observation_jacobians(robot in robot(), mount in laser_mount(), r in 0.05..0.6f64, range in 1.0..20.0f64, bearing in -1.5..1.5f64) {
        let heading = robot.theta + bearing;
        let centre = robot.translation() + range * Vector2::new(heading.cos(), heading.sin());
        let pole = Pole::full(r, centre).unwrap();
        let z = PoleObservation::new(range + 0.03, bearing - 0.01, r + 0.01, [0.05, 0.01, 0.02]).unwrap();
        check(&z, &pole, &robot, &mount)?;
        check(&z, &Pole::new(r, centre).unwrap(), &robot, &mount)?;
    }

    #[test]
    fn range_bearing_jacobians(robot in robot(), mount in laser_mount(), range in 0.5..20.0f64, bearing in -3.0..3.0f64, z in -1.0..2.0f64) {
        let heading = robot.theta + bearing;
        let p = robot.translation() + range * Vector2::new(heading.cos(), heading.sin());
        let obs = RangeBearing::new(range * 1.01, bearing + 0.01, 0.1, 0.02).unwrap();
        check(&obs, &Point::planar(Vector3::new(p.x, p.y, z)).unwrap(), &robot, &mount)?;
        check(&obs, &Point::full(Vector3::new(p.x, p.y, z)).unwrap(), &robot, &mount)?;
    }

    #[test]
    fn image_point_jacobians(robot in robot(), mount in camera_mount(), dx in -1.5..1.5f64, dy in -1.5..1.5f64, h in 1.0..3.0f64) {
        let lamp = Point::full(Vector3::new(robot.x + dx, robot.y + dy, 0.5 + h)).unwrap();
        let obs = ImagePointObservation::new(Vector2::new(150.0, 110.0), 1.0, PinholeCamera::default(), 2.0).unwrap();
        check(&obs, &lamp, &robot, &mount)?;
    }

    #[test]
    fn image_line_jacobians(
        robot in robot(), mount in camera_mount(), offset in -1.0..1.0f64, angle in -PI..PI,
        length in 0.5..3.0f64, h in 1.0..3.0f64, config in 0usize..3,
    ) {
        let centre = robot.translation() + Vector2::new(offset, 0.3);
        let along = Vector2::new(angle.cos(), angle.sin()) * length / 2.0;
        let (a, b) = (centre - along, centre + along);
        let mut line = HLine::new(Vector3::new(a.x, a.y, 0.5 + h), Vector3::new(b.x, b.y, 0.5 + h)).unwrap();
        for name in ["direction", "position"].iter().take(config) {
            line.activate(name).unwrap();
        }
        let camera = PinholeCamera::default();
        let seen = in_sensor(&line, &robot, &mount);
        let ends: Vec<Vector2<f64>> = seen
            .blocks()
            .iter()
            .map(|b| { let p = b.as_slice(); Vector2::new(p[0] / p[2] + 0.01, p[1] / p[2] - 0.005) })
            .collect();
        prop_assume!((ends[1] - ends[0]).norm() > 0.05);
        let obs = ImageLineObservation::from_ends([ends[1], ends[0]], Matrix2::new(1e-4, 0.0, 0.0, 1e-5), camera, 2.0).unwrap();
        check(&obs, &line, &robot, &mount)?;
    }
}

#[test]
fn lamps_triangulate_from_two_views_with_parallax() {
    let camera = PinholeCamera::default();
    let lamp = Vector3::new(3.0, 1.0, 2.6);
    let mount = Pose3::new(Vector3::new(0.0, 0.0, 0.5), 0.0, 0.0, 0.0);
    let observe = |robot: Pose2| {
        let sensor = robot.world_from_sensor(&mount);
        let (pixel, _) = camera
            .project(&sensor.inverse_transform_point(&lamp))
            .unwrap();
        (
            sensor,
            ImagePointObservation::new(pixel, 1.0, camera, 2.0).unwrap(),
        )
    };
    let (s1, z1) = observe(Pose2::new(2.0, 1.0, 0.0));
    let (s2, z2) = observe(Pose2::new(2.02, 1.0, 0.0));
    assert!(
        ImagePointObservation::triangulate(&[(s1, &z1), (s2, &z2)])
            .unwrap()
            .is_none(),
        "2 cm baseline"
    );
    let (s3, z3) = observe(Pose2::new(3.8, 1.2, 0.3));
    let t = ImagePointObservation::triangulate(&[(s1, &z1), (s3, &z3)])
        .unwrap()
        .unwrap();
    assert!((t.feature.position() - lamp).norm() < 1e-9);
    assert_eq!(t.reveals, vec!["horizontal", "height"]);
    // Through the object-safe interface, as an estimator calls it.
    let dyn_z1: &dyn slam_core::DynMeasurementModel = &z1;
    let boxed = dyn_z1
        .triangulate_dyn(&s1, &[(s3, &z3 as &dyn slam_core::DynMeasurementModel)])
        .unwrap()
        .unwrap();
    assert_eq!(boxed.feature.kind(), "point");
}

#[test]
fn ceiling_lines_triangulate_only_across_the_line() {
    let camera = PinholeCamera::default();
    let (a, b) = (Vector3::new(1.0, 2.0, 2.8), Vector3::new(5.0, 2.0, 2.8));
    let mount = Pose3::new(Vector3::new(0.0, 0.0, 0.4), 0.0, 0.0, 0.0);
    let observe = |robot: Pose2| {
        let sensor = robot.world_from_sensor(&mount);
        let to_image = |p: &Vector3<f64>| {
            let q = sensor.inverse_transform_point(p);
            Vector2::new(q.x / q.z, q.y / q.z)
        };
        let obs = ImageLineObservation::from_ends(
            [to_image(&a), to_image(&b)],
            Matrix2::identity() * 1e-6,
            camera,
            2.0,
        )
        .unwrap();
        (sensor, obs)
    };
    // Moving along the line gives no parallax about it.
    let (s1, z1) = observe(Pose2::new(2.0, 1.5, 0.1));
    let (s2, z2) = observe(Pose2::new(4.0, 1.5, 0.1));
    assert!(
        ImageLineObservation::triangulate(&[(s1, &z1), (s2, &z2)])
            .unwrap()
            .is_none()
    );
    // Moving across it does.
    let (s3, z3) = observe(Pose2::new(3.0, 3.2, -0.2));
    let t = ImageLineObservation::triangulate(&[(s1, &z1), (s3, &z3)])
        .unwrap()
        .unwrap();
    let line = t.feature;
    assert!(
        (line.height() - 2.8).abs() < 1e-6,
        "height {}",
        line.height()
    );
    let on_line = |p: Vector3<f64>| (p.y - 2.0).abs() < 1e-6;
    assert!(on_line(line.start()) && on_line(line.end()), "{line:?}");
    assert_eq!(t.reveals, vec!["direction", "position"]);
    // A one-view line placed at the assumed depth projects onto the measured line.
    let initial = z1.initial_feature(&s1).unwrap().unwrap();
    let dyn_z1: &dyn slam_core::DynMeasurementModel = &z1;
    let eta = slam_core::innovation_at(dyn_z1, &initial, &Pose2::new(2.0, 1.5, 0.1), &mount)
        .unwrap()
        .eta;
    assert!(eta.norm() < 1e-9);
}

#[test]
fn wall_endpoints_reveal_subspaces_and_feed_a_cornered_map() {
    let robot = Pose2::new(0.0, 0.0, 0.0);
    let mount = Pose3::identity();
    let wall = Wall::seen_from(
        Vector2::new(3.0, -1.0),
        Vector2::new(3.0, 2.0),
        Vector2::zeros(),
    )
    .unwrap()
    .with_subspaces(&["line"])
    .unwrap();
    // Seen from the origin the wall runs from (3, 2) down to (3, -1)? Its free side faces us.
    assert!(wall.normal().x < 0.0);
    let z = WallObservation::from_segment(
        Vector2::new(3.0, -1.0),
        Vector2::new(3.0, 2.0),
        Matrix2::new(1e-4, 0.0, 0.0, 1e-4),
        [true, false],
        [0.03, 0.03],
    )
    .unwrap();
    let seen = in_sensor(&wall, &robot, &mount);
    let revealed = z.revealed_subspaces(&wall, &seen);
    // The real measured end (3, -1) is the wall's end point.
    let end_is_real = (wall.end() - Vector2::new(3.0, -1.0)).norm() < 1e-9;
    assert_eq!(revealed, vec![if end_is_real { "end" } else { "start" }]);
    let mut map = FeatureMap::new();
    let id = map.insert(Box::new(wall)).unwrap();
    let lin = map.linearize(id, &z, &robot, &mount).unwrap();
    assert_eq!(
        lin.measurement.eta.len(),
        2,
        "endpoint rows wait for the subspace"
    );
    map.activate(id, revealed[0]).unwrap();
    let lin = map.linearize(id, &z, &robot, &mount).unwrap();
    assert_eq!(lin.measurement.eta.len(), 3);
    assert!(lin.measurement.eta.norm() < 1e-12);
}
