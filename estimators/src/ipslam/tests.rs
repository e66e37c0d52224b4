//! IPSLAM in a simulated rectangular room.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam_core::nalgebra::{DMatrix, Vector2};
use slam_core::{Estimator, MotionModel, Pose2, Pose3};
use slam_sensors::models::LinePoint;
use slam_sensors::odometry::{Integration, Unicycle};

use super::*;

/// Range from `origin` along `angle` to the walls of the room `[0, 10] x [0, 6]`.
pub(crate) fn ray(origin: Vector2<f64>, angle: f64) -> f64 {
    let d = Vector2::new(angle.cos(), angle.sin());
    let mut best = f64::INFINITY;
    for (axis, value) in [(0, 0.0), (0, 10.0), (1, 0.0), (1, 6.0)] {
        if d[axis].abs() > 1e-12 {
            let t = (value - origin[axis]) / d[axis];
            if t > 0.0 {
                best = best.min(t);
            }
        }
    }
    best
}

/// Scan points as [`LinePoint`] observations; no map features (the tests look at the
/// clusters).
struct PointsOnly;

impl LineMapTypes for PointsOnly {
    fn cluster_feature(&self, _: &Cluster) -> slam_core::Result<Box<dyn Feature>> {
        Err(slam_core::Error::InvalidArgument(
            "no features in this test".into(),
        ))
    }

    fn scan_point(&self, observation: &Observation) -> Option<Vector2<f64>> {
        LinePoint::point_of(observation)
    }
}

/// The observations of one scan's points.
pub(crate) fn point_observations(points: &[Vector2<f64>], mount: &Pose3) -> Vec<Observation> {
    points
        .iter()
        .map(|p| Observation {
            robot_from_sensor: *mount,
            measurement: Arc::new(LinePoint::new(*p, 0.01).unwrap()),
            landmark_id: None,
        })
        .collect()
}

/// Scans, then drives a robot 30 steps through the room `[0, 10] x [0, 6]` with odometry scaled by
/// `odometry_scale` and turning `odometry_turn_bias` rad/s too much (plus small noise), scanning
/// every step; returns the largest position error and the filter.
fn drive_through_the_room(
    params: IpslamParams,
    odometry_scale: f64,
    odometry_turn_bias: f64,
) -> (f64, Ipslam<Pose2>) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let range_noise = Normal::new(0.0, 0.01).unwrap();
    let start = Pose2::new(2.0, 3.0, 0.0);
    let mut filter =
        Ipslam::new(start, DMatrix::zeros(3, 3), params, Arc::new(PointsOnly)).unwrap();
    let mut truth = start;
    let mut worst: f64 = 0.0;
    for step in 0..=30 {
        if step > 0 {
            let omega = if step <= 15 { 0.0 } else { 0.3 };
            let exact = Unicycle::new(0.5, omega, 0.5, 0.05, 0.03, Integration::Arc).unwrap();
            truth = exact.apply_control(&truth, &exact.control()).unwrap();
            let measured = Unicycle::new(
                0.5 * odometry_scale + 0.02 * Normal::new(0.0, 1.0).unwrap().sample(&mut rng),
                omega + odometry_turn_bias + 0.01 * Normal::new(0.0, 1.0).unwrap().sample(&mut rng),
                0.5,
                0.05,
                0.03,
                Integration::Arc,
            )
            .unwrap();
            filter.predict(&measured).unwrap();
        }
        let points: Vec<Vector2<f64>> = (0..181)
            .map(|k| {
                let bearing = (k as f64 - 90.0).to_radians();
                let range =
                    ray(truth.translation(), truth.theta + bearing) + range_noise.sample(&mut rng);
                Vector2::new(range * bearing.cos(), range * bearing.sin())
            })
            .collect();
        filter
            .update(&point_observations(&points, &Pose3::identity()))
            .unwrap();
        worst = worst.max((filter.pose().translation() - truth.translation()).norm());
    }
    assert_eq!(filter.scans_processed(), 31);
    (worst, filter)
}

/// Every cluster lies on a wall of the room and is thin.
fn assert_clusters_on_the_walls(clusters: &[Cluster]) {
    for c in clusters {
        let to_wall = [c.mean.x, 10.0 - c.mean.x, c.mean.y, 6.0 - c.mean.y]
            .into_iter()
            .fold(f64::INFINITY, |a, b| a.min(b.abs()));
        assert!(to_wall < 0.25, "{c:?} is {to_wall} m from every wall");
        assert!(c.sigma2.sqrt() < 0.05, "{c:?}");
    }
}

fn every_scan() -> IpslamParams {
    IpslamParams {
        particles: 20,
        min_travel: 0.0,
        min_turn_deg: 0.0,
        ..Default::default()
    }
}

#[test]
fn the_room_becomes_a_few_long_clusters_and_the_pose_stays_close() {
    let (worst, filter) = drive_through_the_room(every_scan(), 1.0, 0.0);
    assert!(worst < 0.25, "largest position error {worst}");
    let clusters = filter.clusters();
    // A cluster per wall: the map's clusters of one wall fuse (9 clusters without that).
    assert!(
        (4..=5).contains(&clusters.len()),
        "{} clusters for 4 walls",
        clusters.len()
    );
    assert_clusters_on_the_walls(&clusters);
    let unfused = IpslamParams {
        merge_map_clusters: false,
        ..every_scan()
    };
    let (_, unfused) = drive_through_the_room(unfused, 1.0, 0.0);
    assert!(unfused.clusters().len() > 5);
    // The map holds no feature: the factory refused them all.
    assert!(filter.map().is_empty());
}

#[test]
fn scan_matching_corrects_biased_odometry() {
    // Odometry 10 % long and turning 0.1 rad/s too much: 0.75 m and 1.5 rad of error over
    // the drive if nothing corrects it.
    let scan_match = IpslamParams {
        proposal: IpslamProposal::ScanMatch,
        ..every_scan()
    };
    let (worst, filter) = drive_through_the_room(scan_match, 1.1, 0.1);
    assert!(worst < 0.1, "largest position error {worst}");
    assert_clusters_on_the_walls(&filter.clusters());
    // The same odometry with the motion proposal and the same particles ends far off.
    let (worst_motion, _) = drive_through_the_room(every_scan(), 1.1, 0.1);
    assert!(worst_motion > 3.0 * worst, "{worst_motion} against {worst}");
}

#[test]
fn observations_are_not_used_and_bad_parameters_are_errors() {
    let bad = IpslamParams {
        match_angle_deg: 120.0,
        ..Default::default()
    };
    assert!(
        Ipslam::new(
            Pose2::identity(),
            DMatrix::zeros(3, 3),
            bad,
            Arc::new(PointsOnly)
        )
        .is_err()
    );
    // Observations that are not scan points are rejected and change nothing.
    let mut filter = Ipslam::new(
        Pose2::identity(),
        DMatrix::zeros(3, 3),
        IpslamParams::default(),
        Arc::new(PointsOnly),
    )
    .unwrap();
    let other = Observation {
        robot_from_sensor: Pose3::identity(),
        measurement: Arc::new(
            slam_sensors::models::RangeBearing::new(2.0, 0.1, 0.1, 0.01).unwrap(),
        ),
        landmark_id: None,
    };
    let report = filter.update(&[other]).unwrap();
    assert_eq!((report.rejected, filter.scans_processed()), (1, 0));
}
