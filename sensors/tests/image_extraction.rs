//! The ceiling-image front-end on simulated images of the default world: lamps at their true
//! projections, lines along the true projected ceiling lines.

use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{Pose2, RobotPose};
use slam_sensors::Event;
use slam_sensors::extract::image::{ImageExtractorParams, extract_image_features};
use slam_sensors::sim::{World, simulate};

#[test]
fn lamps_and_lines_are_found_where_the_camera_sees_them() {
    let mut world = World::default_world();
    world.laser = None;
    world.robot.waypoints.truncate(9); // the corridor and the pillar room
    let run = simulate(&world, 2).unwrap();
    let params = ImageExtractorParams::default();
    let mut pose = Pose2::identity();
    let (mut lamps_found, mut lamps_visible, mut lines_found, mut lines_good) = (0, 0, 0, 0);
    let mut images = 0;
    for e in &run.dataset.events {
        let (image, camera, mount) = match &e.event {
            Event::GroundTruth { pose: p, .. } => {
                pose = *p;
                continue;
            }
            Event::Image {
                image,
                camera,
                robot_from_sensor,
            } => (image, camera, robot_from_sensor),
            _ => continue,
        };
        images += 1;
        if images % 3 != 0 {
            continue;
        }
        let world_from_camera = pose.world_from_sensor(mount);
        let project = |p: &Vector3<f64>| {
            camera
                .project(&world_from_camera.inverse_transform_point(p))
                .ok()
                .map(|(px, _)| px)
        };
        let features = extract_image_features(image, camera, &params);
        // Lamps fully inside the image are found, within 1.5 px.
        for lamp in &run.truth.lamps {
            let Some(px) = project(lamp) else { continue };
            let margin = 30.0;
            let inside = px.x > margin
                && px.y > margin
                && px.x < camera.width as f64 - margin
                && px.y < camera.height as f64 - margin;
            if !inside {
                continue;
            }
            lamps_visible += 1;
            if features.lamps.iter().any(|b| (b.centre - px).norm() < 1.5) {
                lamps_found += 1;
            }
        }
        // Every extracted line lies on a true ceiling line's projection.
        for line in &features.lines {
            lines_found += 1;
            let on_some_true_line = run.truth.ceiling_lines.iter().any(|(a, b)| {
                let (Some(pa), Some(pb)) = (project(a), project(b)) else {
                    return false;
                };
                let d = (pb - pa).normalize();
                let n = Vector2::new(-d.y, d.x);
                line.ends.iter().all(|q| n.dot(&(q - pa)).abs() < 1.5)
            });
            lines_good += usize::from(on_some_true_line);
        }
    }
    assert!(lamps_visible >= 50, "only {lamps_visible} lamp sightings");
    assert!(
        lamps_found as f64 >= 0.97 * lamps_visible as f64,
        "{lamps_found} of {lamps_visible} lamps found"
    );
    assert!(lines_found >= 100, "only {lines_found} lines");
    assert!(
        lines_good as f64 >= 0.97 * lines_found as f64,
        "{lines_good} of {lines_found} lines on a true line"
    );
    println!(
        "{lamps_found} of {lamps_visible} lamps found; {lines_good} of {lines_found} lines on true lines"
    );
}
