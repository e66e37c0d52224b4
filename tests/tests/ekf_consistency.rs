//! Statistical consistency of the EKF on small simulated problems with known truth: the
//! normalized estimation error squared (NEES) of the map and the pose, averaged over many
//! seeded runs, stays near its degrees of freedom.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam_core::nalgebra::{DMatrix, Vector2, Vector3};
use slam_core::{
    Estimator, MotionModel, Observation, Pose2, Pose3, RobotPose, RowOwner, downcast_feature,
};
use slam_estimators::{Ekf, EkfParams};
use slam_features::Point;
use slam_sensors::camera::PinholeCamera;
use slam_sensors::models::ImagePointObservation;
use slam_sensors::odometry::{Integration, Unicycle};
use std::sync::Arc;

/// One run: a robot drives straight under one lamp with a ceiling camera; returns the lamp's
/// and the final pose's NEES (3 dof each), if the lamp was placed.
fn lamp_run(seed: u64) -> Option<(f64, f64)> {
    let camera = PinholeCamera::default();
    let mount = Pose3::new(Vector3::new(0.0, 0.0, 0.5), 0.0, 0.0, 0.0);
    let lamp = Vector3::new(3.0, 7.6, 2.6);
    let (sigma_v, sigma_w, sigma_px, dt) = (0.05, 2f64.to_radians(), 0.7, 0.1);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = |sigma: f64, rng: &mut ChaCha8Rng| Normal::new(0.0, sigma).unwrap().sample(rng);
    let mut truth = Pose2::new(1.5, 7.5, 0.0);
    let mut ekf = Ekf::new(truth, DMatrix::zeros(3, 3), EkfParams::default()).unwrap();
    for k in 1..60 {
        let (v, w) = (0.5, 0.0);
        let step = Unicycle::new(v, w, dt, sigma_v, sigma_w, Integration::Arc).unwrap();
        truth = step.apply_control(&truth, &step.control()).unwrap();
        let measured = Unicycle::new(
            v + noise(sigma_v, &mut rng),
            w + noise(sigma_w, &mut rng),
            dt,
            sigma_v,
            sigma_w,
            Integration::Arc,
        )
        .unwrap();
        ekf.predict(&measured).unwrap();
        if k % 2 == 0 {
            let camera_pose = truth.world_from_sensor(&mount);
            let Ok((pixel, _)) = camera.project(&camera_pose.inverse_transform_point(&lamp)) else {
                continue;
            };
            let pixel = pixel + Vector2::new(noise(sigma_px, &mut rng), noise(sigma_px, &mut rng));
            if pixel.x < 0.0 || pixel.y < 0.0 || pixel.x > 320.0 || pixel.y > 240.0 {
                continue;
            }
            let measurement = ImagePointObservation::new(pixel, sigma_px, camera, 2.3).unwrap();
            ekf.update(&[Observation {
                robot_from_sensor: mount,
                measurement: Arc::new(measurement),
                landmark_id: None,
            }])
            .unwrap();
        }
    }
    let (id, feature) = ekf.map().iter().next()?;
    let point = downcast_feature::<Point>(feature)?;
    let c = ekf.row_covariance(RowOwner::Feature(id))?;
    if c.nrows() != 3 {
        return None;
    }
    let e = point.position() - lamp;
    let lamp_nees = (e.transpose() * c.try_inverse()? * e)[(0, 0)];
    let pe = slam_core::RobotPose::ominus(&truth, &ekf.pose());
    let pe = Vector3::new(pe[0], pe[1], pe[2]);
    let pose_nees = (pe.transpose() * ekf.pose_covariance().try_inverse()? * pe)[(0, 0)];
    Some((lamp_nees, pose_nees))
}

#[test]
fn a_triangulated_lamp_is_consistent() {
    let runs: Vec<_> = (0..200).filter_map(lamp_run).collect();
    assert!(runs.len() > 150, "only {} runs placed the lamp", runs.len());
    let mean = |f: fn(&(f64, f64)) -> f64| runs.iter().map(f).sum::<f64>() / runs.len() as f64;
    let (lamp, pose) = (mean(|r| r.0), mean(|r| r.1));
    println!(
        "lamp NEES {lamp:.2}, pose NEES {pose:.2} over {} runs",
        runs.len()
    );
    assert!(
        lamp < 4.5 && pose < 4.5,
        "lamp NEES {lamp}, pose NEES {pose}"
    );
}
