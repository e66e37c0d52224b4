//! The ceiling-image front-end on simulated images of the default world: lamps at their true
//! projections, lines along the true projected ceiling lines; the Hough line method on
//! synthetic images; the settings' `line_method` word.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{Pose2, RobotPose};
use slam_sensors::Event;
use slam_sensors::camera::{GrayImage, PinholeCamera};
use slam_sensors::extract::hough::HoughParams;
use slam_sensors::extract::image::{
    ImageExtractorParams, ImageLine, LineMethod, extract_image_features,
};
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
    let (mut hough_found, mut hough_good) = (0, 0);
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
        // Every extracted line lies on a true ceiling line's projection, by either method.
        let on_some_true_line = |line: &ImageLine| {
            run.truth.ceiling_lines.iter().any(|(a, b)| {
                let (Some(pa), Some(pb)) = (project(a), project(b)) else {
                    return false;
                };
                let d = (pb - pa).normalize();
                let n = Vector2::new(-d.y, d.x);
                line.ends.iter().all(|q| n.dot(&(q - pa)).abs() < 1.5)
            })
        };
        for line in &features.lines {
            lines_found += 1;
            lines_good += usize::from(on_some_true_line(line));
        }
        let by_hough = extract_image_features(image, camera, &hough());
        for line in &by_hough.lines {
            hough_found += 1;
            hough_good += usize::from(on_some_true_line(line));
        }
        assert_eq!(by_hough.lamps, features.lamps);
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
    assert!(hough_found >= 100, "only {hough_found} Hough lines");
    assert!(
        hough_good as f64 >= 0.97 * hough_found as f64,
        "{hough_good} of {hough_found} Hough lines on a true line"
    );
    println!(
        "{lamps_found} of {lamps_visible} lamps found; {lines_good} of {lines_found} lines on true \
         lines; Hough: {hough_good} of {hough_found}"
    );
}

// The Hough line method (`line_method = "hough"`) on synthetic images.

fn hough() -> ImageExtractorParams {
    ImageExtractorParams {
        line_method: LineMethod::Hough,
        ..ImageExtractorParams::default()
    }
}

/// A dark 320 x 240 image with Gaussian intensity noise (deviation 4, as the simulator's).
fn dark_image(rng: &mut ChaCha8Rng) -> GrayImage {
    let mut image = GrayImage::new(320, 240);
    for v in image.data.iter_mut() {
        let noise: f64 = (0..4).map(|_| rng.random::<f64>() - 0.5).sum::<f64>() * 7.0;
        *v = (40.0 + noise).round().clamp(0.0, 255.0) as u8;
    }
    image
}

/// Paints the pixels whose centres lie within `width / 2` of the segment `a`-`b`.
fn paint_strip(image: &mut GrayImage, a: Vector2<f64>, b: Vector2<f64>, width: f64) {
    let e = b - a;
    for y in 0..image.height as i64 {
        for x in 0..image.width as i64 {
            let p = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
            let t = ((p - a).dot(&e) / e.norm_squared()).clamp(0.0, 1.0);
            if (p - (a + e * t)).norm() <= 0.5 * width {
                image.set(x, y, 220);
            }
        }
    }
}

/// The angle (degrees, modulo 180) between a found line and the segment `a`-`b`, and the
/// largest distance of its ends from the segment's line, px.
fn line_error(line: &ImageLine, a: Vector2<f64>, b: Vector2<f64>) -> (f64, f64) {
    let (d, e) = (
        (b - a).normalize(),
        (line.ends[1] - line.ends[0]).normalize(),
    );
    let angle = d.dot(&e).abs().min(1.0).acos().to_degrees();
    let n = Vector2::new(-d.y, d.x);
    let offset = line
        .ends
        .iter()
        .map(|q| n.dot(&(q - a)).abs())
        .fold(0.0, f64::max);
    (angle, offset)
}

#[test]
fn hough_finds_a_straight_strip_with_its_angle_and_offset() {
    let camera = PinholeCamera::default();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (a, b) in [
        (Vector2::new(40.3, 60.7), Vector2::new(270.2, 170.1)),
        (Vector2::new(100.0, 20.0), Vector2::new(104.0, 220.0)),
        (Vector2::new(20.0, 120.5), Vector2::new(300.0, 120.5)),
    ] {
        let mut image = dark_image(&mut rng);
        paint_strip(&mut image, a, b, 6.5);
        let features = extract_image_features(&image, &camera, &hough());
        assert_eq!(features.lines.len(), 1, "{a} {b}: {:?}", features.lines);
        assert!(features.lamps.is_empty());
        let line = &features.lines[0];
        let (angle, offset) = line_error(line, a, b);
        assert!(angle < 0.3 && offset < 0.5, "{angle} deg, {offset} px");
        // Ends at the strip's extent: the segment's ends plus up to half its width.
        let length = (line.ends[1] - line.ends[0]).norm();
        assert!(
            (length - (b - a).norm()).abs() < 7.0,
            "{length} vs {}",
            (b - a).norm()
        );
        assert!(!line.clipped);
        assert!(line.cov[(0, 0)] > 0.0 && line.cov.determinant() > 0.0);
    }
}

#[test]
fn hough_rejects_pure_noise_and_lamps() {
    let camera = PinholeCamera::default();
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    for _ in 0..5 {
        // Strong intensity noise with bright speckles and small bright clumps.
        let mut image = dark_image(&mut rng);
        for v in image.data.iter_mut() {
            if rng.random::<f64>() < 0.03 {
                *v = 200;
            }
        }
        for _ in 0..40 {
            let (x, y) = (rng.random_range(0..318), rng.random_range(0..238));
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                image.set(x + dx, y + dy, 230);
            }
        }
        // Two lamps, one cut by the border.
        for (centre, radius) in [
            (Vector2::new(160.0, 120.0), 20.0),
            (Vector2::new(5.0, 60.0), 20.0),
        ] {
            for y in 0..240 {
                for x in 0..320 {
                    let p = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
                    if (p - centre).norm() <= radius {
                        image.set(x, y, 255);
                    }
                }
            }
        }
        let features = extract_image_features(&image, &camera, &hough());
        assert!(features.lines.is_empty(), "{:?}", features.lines);
        // The lamp inside the image is a lamp still (clumps of speckles may be small lamps).
        assert!(
            features
                .lamps
                .iter()
                .any(|l| (l.centre - Vector2::new(160.0, 120.0)).norm() < 1.0)
        );
    }
}

#[test]
fn hough_separates_two_crossing_strips() {
    let camera = PinholeCamera::default();
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let strips = [
        (Vector2::new(30.0, 40.0), Vector2::new(290.0, 190.0)),
        (Vector2::new(120.0, 225.0), Vector2::new(210.0, 15.0)),
    ];
    let mut image = dark_image(&mut rng);
    for (a, b) in strips {
        paint_strip(&mut image, a, b, 6.5);
    }
    let features = extract_image_features(&image, &camera, &hough());
    assert_eq!(features.lines.len(), 2, "{:?}", features.lines);
    for (a, b) in strips {
        let line = features
            .lines
            .iter()
            .find(|l| line_error(l, a, b).0 < 5.0)
            .unwrap_or_else(|| panic!("no line along {a} {b}: {:?}", features.lines));
        let (angle, offset) = line_error(line, a, b);
        assert!(angle < 0.5 && offset < 1.0, "{angle} deg, {offset} px");
        // One line across the crossing, not two pieces.
        let length = (line.ends[1] - line.ends[0]).norm();
        assert!(length > (b - a).norm() - 2.0, "{length}");
    }
    // The component method sees one cross-shaped component: not a line.
    let components = extract_image_features(&image, &camera, &ImageExtractorParams::default());
    println!(
        "crossing strips: hough {} lines, components {} lines and {} lamps",
        features.lines.len(),
        components.lines.len(),
        components.lamps.len()
    );
}

#[test]
fn the_line_method_is_a_word_of_the_settings() {
    let parse = |text: &str| toml::from_str::<ImageExtractorParams>(text);
    assert_eq!(parse("").unwrap(), ImageExtractorParams::default());
    assert_eq!(
        ImageExtractorParams::default().line_method,
        LineMethod::Components
    );
    let params = parse("line_method = \"hough\"\n[hough]\nmin_votes = 30\n").unwrap();
    assert_eq!(params.line_method, LineMethod::Hough);
    assert_eq!(
        params.hough,
        HoughParams {
            min_votes: 30,
            ..HoughParams::default()
        }
    );
    assert_eq!(
        parse("line_method = \"components\"").unwrap().line_method,
        LineMethod::Components
    );
    let e = parse("line_method = \"houghs\"").unwrap_err().to_string();
    assert!(e.contains("houghs") && e.contains("hough"), "{e}");
    let e = parse("line_method = \"Hough\"").unwrap_err().to_string();
    assert!(e.contains("Hough"), "{e}");
    let e = parse("[hough]\nmin_vote = 3\n").unwrap_err().to_string();
    assert!(e.contains("min_vote"), "{e}");
}
