use super::*;
use crate::sim::{World, simulate};
use proptest::prelude::*;

/// The range from `origin` along `heading` to the walls of the room `[0, 10] x [0, 6]` with
/// a pillar face at x = 6, y in [2, 4] (so that translation along every axis is observable).
fn ray(origin: Vector2<f64>, heading: f64) -> f64 {
    let u = Vector2::new(heading.cos(), heading.sin());
    let mut best = f64::INFINITY;
    let mut hit = |t: f64, ok: bool| {
        if ok && t > 1e-9 && t < best {
            best = t;
        }
    };
    for (x, lo, hi) in [(0.0, 0.0, 6.0), (10.0, 0.0, 6.0), (6.0, 2.0, 4.0)] {
        let t = (x - origin.x) / u.x;
        let y = origin.y + t * u.y;
        hit(t, (lo..=hi).contains(&y));
    }
    for y in [0.0, 6.0] {
        let t = (y - origin.y) / u.y;
        let x = origin.x + t * u.x;
        hit(t, (0.0..=10.0).contains(&x));
    }
    best
}

/// A 180-beam half-open sweep of the room from `pose`, in the sensor frame.
fn scan(pose: &Pose2) -> Vec<Vector2<f64>> {
    (0..180)
        .map(|i| {
            let bearing = (-90.0 + i as f64).to_radians();
            let range = ray(pose.translation(), pose.theta + bearing);
            Vector2::new(range * bearing.cos(), range * bearing.sin())
        })
        .collect()
}

fn wide_prior() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(
        0.2f64.powi(2),
        0.2f64.powi(2),
        0.1f64.powi(2),
    ))
}

#[test]
fn a_known_motion_is_recovered_from_a_perturbed_guess() {
    let before = Pose2::new(2.0, 3.0, 0.1);
    let after = Pose2::new(2.8, 3.3, 0.35);
    let truth = before.between(&after);
    let guess = Pose2::new(truth.x + 0.12, truth.y - 0.08, truth.theta + 0.06);
    let matched = match_scans(
        &scan(&before),
        &scan(&after),
        &guess,
        &wide_prior(),
        &LaserOdometryParams::default(),
    )
    .unwrap()
    .unwrap();
    let m = matched.reference_from_current;
    assert!(
        (m.translation() - truth.translation()).norm() < 5e-3,
        "{m:?} vs {truth:?}"
    );
    assert!((m.theta - truth.theta).abs() < 1e-3, "{m:?} vs {truth:?}");
    assert!(matched.matched > 150);
    // The points constrain the pose far more than the prior.
    assert!(matched.covariance[(2, 2)] < 0.01 * wide_prior()[(2, 2)]);
}

#[test]
fn too_few_points_refuse_the_match_and_bad_priors_are_errors() {
    let pose = Pose2::new(2.0, 3.0, 0.1);
    let params = LaserOdometryParams::default();
    let few = &scan(&pose)[..10];
    let refused = match_scans(few, few, &Pose2::identity(), &wide_prior(), &params).unwrap();
    assert!(refused.is_none());
    let singular = Matrix3::zeros();
    assert!(
        match_scans(
            &scan(&pose),
            &scan(&pose),
            &Pose2::identity(),
            &singular,
            &params
        )
        .is_err()
    );
    let nan = Pose2::new(f64::NAN, 0.0, 0.0);
    assert!(match_scans(&scan(&pose), &scan(&pose), &nan, &wide_prior(), &params).is_err());
    let bad = LaserOdometryParams {
        gate: -1.0,
        ..Default::default()
    };
    let message = match_scans(&scan(&pose), &scan(&pose), &pose, &wide_prior(), &bad)
        .unwrap_err()
        .to_string();
    assert!(message.contains("gate > 0"), "{message}");
}

proptest! {
    #[test]
    fn the_conjugation_jacobian_matches_central_differences(
        ox in -1.0..1.0f64, oy in -1.0..1.0f64, ot in -3.0..3.0f64,
        ix in -2.0..2.0f64, iy in -2.0..2.0f64, it in -3.0..3.0f64,
    ) {
        let outer = Pose2::new(ox, oy, ot);
        let inner = Pose2::new(ix, iy, it);
        let (_, analytic) = conjugate(&outer, &inner);
        let h = 1e-6;
        for k in 0..3 {
            let mut step = Vector3::zeros();
            step[k] = h;
            let (plus, _) = conjugate(&outer, &inner.plus_vector(&step));
            let (minus, _) = conjugate(&outer, &inner.plus_vector(&-step));
            let numeric = Vector3::new(
                (plus.x - minus.x) / (2.0 * h),
                (plus.y - minus.y) / (2.0 * h),
                wrap_angle(plus.theta - minus.theta) / (2.0 * h),
            );
            prop_assert!((analytic.column(k) - numeric).amax() < 1e-6);
        }
    }
}

#[test]
fn the_conjugation_maps_a_sensor_motion_to_the_robot_motion() {
    let robot_from_sensor = Pose2::new(0.3, -0.1, 0.2);
    let robot_motion = Pose2::new(0.5, 0.2, 0.3);
    let (sensor_motion, _) = conjugate(&robot_from_sensor.inverse(), &robot_motion);
    // The sensor's pose after the motion, both ways round.
    let a = robot_motion.compose(&robot_from_sensor);
    let b = robot_from_sensor.compose(&sensor_motion);
    assert!((a.to_vector() - b.to_vector()).amax() < 1e-12);
}

/// The pose at each ground-truth event, dead-reckoned through the motion events from the
/// first true pose; with the true poses.
fn dead_reckoning(dataset: &Dataset) -> Vec<(Pose2, Pose2)> {
    let mut pose: Option<Pose2> = None;
    let mut out = Vec::new();
    for timed in &dataset.events {
        match &timed.event {
            Event::Motion(motion) => {
                if let Some(p) = pose.as_mut() {
                    *p = motion.predict(p).unwrap().pose;
                }
            }
            Event::GroundTruth { pose: truth, .. } => {
                let estimate = *pose.get_or_insert(*truth);
                out.push((estimate, *truth));
            }
            _ => {}
        }
    }
    out
}

/// The built-in world without its camera (rendering is slow in debug builds), first
/// `waypoints` waypoints only.
fn laser_world(waypoints: usize) -> World {
    let mut world = World::default_world();
    world.camera = None;
    world.robot.waypoints.truncate(waypoints);
    world
}

#[test]
fn laser_odometry_drifts_less_than_wheel_odometry_on_the_simulated_world() {
    let run = simulate(&laser_world(3), 3).unwrap();
    let scans = run.dataset.counts().scans;
    let wheels = dead_reckoning(&run.dataset);
    let (laser, report) = laser_odometry(run.dataset, &LaserOdometryParams::default()).unwrap();
    assert!(
        report.matched as f64 > 0.95 * scans as f64,
        "{report:?} of {scans}"
    );
    let laser = dead_reckoning(&laser);
    assert_eq!(laser.len() + report.truth_between_scans, wheels.len());
    let rms = |poses: &[(Pose2, Pose2)]| {
        let sum: f64 = poses
            .iter()
            .map(|(e, t)| (e.translation() - t.translation()).norm_squared())
            .sum();
        (sum / poses.len() as f64).sqrt()
    };
    let (wheels, laser) = (rms(&wheels), rms(&laser));
    eprintln!("laser {laser:.3} m, wheels {wheels:.3} m");
    assert!(
        laser < 0.5 * wheels,
        "laser {laser:.3} m, wheels {wheels:.3} m"
    );
}

#[test]
fn truth_between_scans_is_left_out_and_truth_at_a_scan_follows_its_increment() {
    let run = simulate(&laser_world(2), 3).unwrap();
    let counts = run.dataset.counts();
    // The built-in world scans at every other step.
    assert!(counts.scans < counts.ground_truth, "{counts:?}");
    let (laser, report) = laser_odometry(run.dataset, &LaserOdometryParams::default()).unwrap();
    let times_of = |kind: fn(&Event) -> bool| -> Vec<f64> {
        let events = laser.events.iter().filter(|e| kind(&e.event));
        events.map(|e| e.time).collect()
    };
    let kept = times_of(|e| matches!(e, Event::GroundTruth { .. }));
    assert_eq!(kept.len() + report.truth_between_scans, counts.ground_truth);
    assert!(report.truth_between_scans > 0, "{report:?}");
    let scan_times = times_of(|e| matches!(e, Event::Scan { .. }));
    // The first truth comes before any motion and those after the last scan follow the
    // wheel odometry, which then goes out as it is; every other one is at a scan.
    let last_scan = scan_times.last().copied().unwrap_or(f64::INFINITY);
    for time in kept[1..].iter().filter(|&&t| t <= last_scan) {
        assert!(scan_times.contains(time), "truth at {time} between scans");
    }
    // Dead reckoning on the matches moves between any two compared poses where the robot
    // moved: no compared estimate is left behind, still at the scan before.
    let poses = dead_reckoning(&laser);
    for pair in poses.windows(2) {
        let ((estimate_before, truth_before), (estimate, truth)) = (pair[0], pair[1]);
        if truth_before.between(&truth).translation().norm() > 1e-3 {
            assert_ne!(estimate_before, estimate, "stale estimate at {truth:?}");
        }
    }
}

/// RMS translation error of dead-reckoned poses against the truth, m.
fn rms_error(poses: &[(Pose2, Pose2)]) -> f64 {
    let sum: f64 = poses
        .iter()
        .map(|(e, t)| (e.translation() - t.translation()).norm_squared())
        .sum();
    (sum / poses.len() as f64).sqrt()
}

/// Matching each scan to a local map of recent key scans drifts less than matching it to
/// the last key scan alone (whose errors add up scan by scan). Seen on seeds 1-7 with six
/// waypoints: 0.09-0.16 m against 0.10-0.24 m, lower every time.
#[test]
fn the_local_map_drifts_less_than_scan_to_scan_matching() {
    let drift = |local_map_scans: usize| {
        let run = simulate(&laser_world(4), 5).unwrap();
        let params = LaserOdometryParams {
            local_map_scans,
            ..LaserOdometryParams::default()
        };
        let (laser, _) = laser_odometry(run.dataset, &params).unwrap();
        rms_error(&dead_reckoning(&laser))
    };
    let (scan_to_scan, local_map) = (drift(1), drift(50));
    eprintln!("scan to scan {scan_to_scan:.3} m, local map {local_map:.3} m");
    assert!(
        local_map < scan_to_scan,
        "scan to scan {scan_to_scan:.3} m, local map {local_map:.3} m"
    );
}

#[test]
fn a_tilted_laser_is_an_error() {
    let mut run = simulate(&laser_world(1), 3).unwrap();
    for timed in &mut run.dataset.events {
        if let Event::Scan {
            robot_from_sensor, ..
        } = &mut timed.event
        {
            robot_from_sensor.pitch = 0.3;
        }
    }
    let message = laser_odometry(run.dataset, &LaserOdometryParams::default())
        .unwrap_err()
        .to_string();
    assert!(message.contains("level laser"), "{message}");
}

/// A 180-beam sweep along the hall `y in [-5, 5]`, 12 m long, from `pose` (sensor frame);
/// beams that leave it at its ends are dropped.
fn corridor_scan(pose: &Pose2) -> Vec<Vector2<f64>> {
    (0..180)
        .filter_map(|i| {
            let bearing = (-90.0 + i as f64).to_radians();
            let heading = pose.theta + bearing;
            let u = Vector2::new(heading.cos(), heading.sin());
            let wall = if u.y > 0.0 { 5.0 } else { -5.0 };
            let range = (wall - pose.y) / u.y;
            let x = pose.x + range * u.x;
            (range.is_finite() && range > 0.0 && (0.0..=12.0).contains(&x))
                .then(|| Vector2::new(range * bearing.cos(), range * bearing.sin()))
        })
        .collect()
}

/// Far points of a wall seen at a slant lie farther apart than the gate: with a reach that
/// grows with the range they keep their normals (and stay in the reference), and those
/// normals are the wall's.
#[test]
fn far_points_keep_their_normals_with_a_range_scaled_reach() {
    let points = corridor_scan(&Pose2::new(1.0, 0.0, 0.0));
    let fixed = LaserOdometryParams::default();
    let scaled = LaserOdometryParams {
        normal_reach_per_metre: 0.1,
        ..LaserOdometryParams::default()
    };
    let far = |reference: &[(Vector2<f64>, Vector2<f64>)]| {
        reference.iter().filter(|(p, _)| p.norm() > 8.0).count()
    };
    let with_gate = with_normals(&points, &fixed);
    let with_reach = with_normals(&points, &scaled);
    let far_points = points.iter().filter(|p| p.norm() > 8.0).count();
    assert!(far_points > 10, "{far_points}");
    assert!(2 * far(&with_gate) < far_points, "{with_gate:?}");
    // Points within two beams of the view's far end have too few neighbours.
    assert!(
        far(&with_reach) + 4 >= far_points,
        "{} of {far_points}",
        far(&with_reach)
    );
    for (p, n) in &with_reach {
        assert!(n.y.abs() > 0.999, "normal {n:?} at {p:?}");
    }
}

/// A guess turned 35 degrees from the truth finds no match from the guess alone (too few
/// points pair up at the gate); with starting headings 4 degrees apart on each side the match
/// finds the truth.
#[test]
fn extra_starting_headings_recover_a_large_heading_error() {
    let before = Pose2::new(2.0, 3.0, 0.1);
    let after = Pose2::new(2.6, 3.2, 0.5);
    let truth = before.between(&after);
    let guess = Pose2::new(truth.x, truth.y, truth.theta + 35f64.to_radians());
    let prior = Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.6f64.powi(2)));
    let run = |heading_starts: usize| {
        let params = LaserOdometryParams {
            heading_starts,
            heading_start_step_deg: 4.0,
            ..LaserOdometryParams::default()
        };
        match_scans(&scan(&before), &scan(&after), &guess, &prior, &params)
            .unwrap()
            .map(|m| m.reference_from_current)
    };
    let error = |m: Pose2| wrap_angle(m.theta - truth.theta).abs().to_degrees();
    let single = run(0);
    assert!(
        single.is_none_or(|m| error(m) > 1.0),
        "{single:?} vs {truth:?}"
    );
    let several = run(10).unwrap();
    assert!(error(several) < 0.1, "{several:?} vs {truth:?}");
    assert!((several.translation() - truth.translation()).norm() < 5e-3);
}

/// A match that pairs fewer than half of the scan's points retries from starting headings
/// beyond `heading_starts`. With the odometry's heading 40 degrees off and starts reaching 4
/// degrees, the first match lands 45 degrees off with 34 of 180 points paired (or, on the
/// other side, is refused), and the retry (starts out to 40 degrees) finds the truth; a
/// well-paired match does not retry.
#[test]
fn a_poor_match_retries_from_wider_starting_headings() {
    let before = Pose2::new(2.0, 3.0, 0.1);
    let after = Pose2::new(2.6, 3.2, 0.5);
    let truth = before.between(&after);
    let prior = Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.6f64.powi(2)));
    let run = |offset_deg: f64, retry_heading_starts: usize| {
        let params = LaserOdometryParams {
            heading_starts: 2,
            retry_heading_starts,
            ..LaserOdometryParams::default()
        };
        let guess = Pose2::new(truth.x, truth.y, truth.theta + offset_deg.to_radians());
        match_scans(&scan(&before), &scan(&after), &guess, &prior, &params).unwrap()
    };
    let error = |m: &ScanMatch| {
        wrap_angle(m.reference_from_current.theta - truth.theta)
            .abs()
            .to_degrees()
    };
    let poor = run(-40.0, 0).unwrap();
    assert!(error(&poor) > 10.0, "{poor:?} vs {truth:?}");
    assert!(2 * poor.matched < 180 && !poor.retried, "{poor:?}");
    assert_eq!(run(40.0, 0), None);
    for offset_deg in [-40.0, 40.0] {
        let retried = run(offset_deg, 20).unwrap();
        assert!(retried.retried);
        assert!(error(&retried) < 0.1, "{retried:?} vs {truth:?}");
        assert!(2 * retried.matched >= 180, "{retried:?}");
    }
    // Near the truth the first match pairs most points: no retry, the same match.
    let near = run(3.0, 20).unwrap();
    assert!(!near.retried);
    assert_eq!(Some(near), run(3.0, 0));
}

/// A 180-beam sweep from `pose` of a regular polygonal room with `sides` sides around the
/// origin (corners `radius` away), in the sensor frame: seen from the centre, every turn by
/// a multiple of `360 / sides` degrees gives the same scan.
fn polygon_scan(sides: usize, radius: f64, pose: &Pose2) -> Vec<Vector2<f64>> {
    let corner = |i: usize| {
        let a = std::f64::consts::TAU * i as f64 / sides as f64;
        Vector2::new(radius * a.cos(), radius * a.sin())
    };
    (0..180)
        .map(|i| {
            let bearing = (-90.0 + i as f64).to_radians();
            let u = Vector2::new((pose.theta + bearing).cos(), (pose.theta + bearing).sin());
            let origin = pose.translation();
            let range = (0..sides)
                .filter_map(|k| {
                    let (a, b) = (corner(k), corner(k + 1));
                    let edge = b - a;
                    let denominator = u.x * edge.y - u.y * edge.x;
                    let rel = a - origin;
                    let t = (rel.x * edge.y - rel.y * edge.x) / denominator;
                    let s = (rel.x * u.y - rel.y * u.x) / denominator;
                    (t > 0.0 && (0.0..=1.0).contains(&s)).then_some(t)
                })
                .fold(f64::INFINITY, f64::min);
            Vector2::new(range * bearing.cos(), range * bearing.sin())
        })
        .collect()
}

/// In a room of 36 equal sides seen from its centre a turn of 10 degrees gives nearly the
/// same scan (the 7 beams at the ends of the turned sweep find no partner: the objective is
/// 3.2 higher there). With the starts reaching 12 degrees on each side and a gap of 5 the
/// match is ambiguous: its heading variance grows by (10 degrees)^2 for each side, once
/// although two starts end in each of those minima. Off (`ambiguity_gap` 0), or in the
/// rectangular room, whose minima differ, the covariance is the points' alone.
#[test]
fn a_second_minimum_as_low_widens_the_covariance() {
    let pose = Pose2::new(0.0, 0.0, 0.3);
    let prior = Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.6f64.powi(2)));
    let params = |ambiguity_gap: f64| LaserOdometryParams {
        heading_starts: 6,
        ambiguity_gap,
        ..LaserOdometryParams::default()
    };
    let scan_36 = polygon_scan(36, 5.0, &pose);
    let guess = Pose2::identity();
    let run = |gap: f64| {
        match_scans(&scan_36, &scan_36, &guess, &prior, &params(gap))
            .unwrap()
            .unwrap()
    };
    let sure = run(0.0);
    let ambiguous = run(5.0);
    assert!(!sure.ambiguous && ambiguous.ambiguous);
    assert_eq!(
        sure.reference_from_current,
        ambiguous.reference_from_current
    );
    assert!(sure.reference_from_current.theta.abs() < 1e-3, "{sure:?}");
    let ten_degrees = 10f64.to_radians().powi(2);
    // A near-round room holds the heading loosely: 2.7 degrees.
    assert!(sure.covariance[(2, 2)] < 0.1 * ten_degrees, "{sure:?}");
    let widened = ambiguous.covariance[(2, 2)] - sure.covariance[(2, 2)];
    assert!(
        (widened / (2.0 * ten_degrees) - 1.0).abs() < 0.02,
        "{ambiguous:?}"
    );
    // The rectangular room with a pillar face: one minimum, nothing widened.
    let before = Pose2::new(2.0, 3.0, 0.1);
    let after = Pose2::new(2.6, 3.2, 0.5);
    let truth = before.between(&after);
    let room = |gap: f64| {
        match_scans(&scan(&before), &scan(&after), &truth, &prior, &params(gap))
            .unwrap()
            .unwrap()
    };
    let (plain, checked) = (room(0.0), room(5.0));
    assert!(!checked.ambiguous);
    assert_eq!(plain, checked);
}

/// With the normal check on, the known motion is still recovered, and points pair only with
/// reference points on surfaces facing their own way: a scan matched to itself turned by 90
/// degrees (every wall then faces across its partner) pairs fewer points than without it.
#[test]
fn the_normal_check_keeps_the_match_and_refuses_crossed_surfaces() {
    let before = Pose2::new(2.0, 3.0, 0.1);
    let after = Pose2::new(2.8, 3.3, 0.35);
    let truth = before.between(&after);
    let guess = Pose2::new(truth.x + 0.12, truth.y - 0.08, truth.theta + 0.06);
    let checked = LaserOdometryParams {
        max_normal_angle_deg: 30.0,
        ..LaserOdometryParams::default()
    };
    let m = match_scans(
        &scan(&before),
        &scan(&after),
        &guess,
        &wide_prior(),
        &checked,
    )
    .unwrap()
    .unwrap()
    .reference_from_current;
    assert!(
        (m.translation() - truth.translation()).norm() < 5e-3,
        "{m:?}"
    );
    assert!((m.theta - truth.theta).abs() < 1e-3, "{m:?}");
    let points = scan(&before);
    let reference = with_normals(&points, &checked);
    let turned = Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    let pairs = |params: &LaserOdometryParams| {
        let problem = MatchProblem {
            current: &points,
            current_normals: normals(&points, params.gate, params.normal_reach_per_metre),
            min_normal_cosine: params.max_normal_angle_deg.to_radians().cos(),
            guess: &turned,
            prior_information: Matrix3::identity(),
            params,
            grid: &Grid::new(reference.clone(), GRID_CELL),
        };
        problem.minimise(turned, 2, 3).map_or(0, |m| m.matched)
    };
    let unchecked = LaserOdometryParams {
        min_matched: 3,
        ..LaserOdometryParams::default()
    };
    let checked = LaserOdometryParams {
        min_matched: 3,
        ..checked
    };
    assert!(
        pairs(&checked) < pairs(&unchecked) / 2,
        "{} {}",
        pairs(&checked),
        pairs(&unchecked)
    );
}

/// Starting headings beyond three standard deviations of the guess's heading are not tried:
/// with a sure heading the match is the single-start one, bit for bit.
#[test]
fn a_sure_heading_needs_no_extra_starts() {
    let before = Pose2::new(2.0, 3.0, 0.1);
    let after = Pose2::new(2.3, 3.1, 0.12);
    let guess = before.between(&after);
    let prior = Matrix3::from_diagonal(&Vector3::new(0.01, 0.01, 0.005f64.powi(2)));
    let run = |heading_starts: usize| {
        let params = LaserOdometryParams {
            heading_starts,
            ..LaserOdometryParams::default()
        };
        match_scans(&scan(&before), &scan(&after), &guess, &prior, &params)
            .unwrap()
            .unwrap()
            .reference_from_current
    };
    assert_eq!(run(5).to_vector(), run(0).to_vector());
}

/// `interval_noise` replaces the compound's covariance by the model's over the whole
/// interval: many short motions no longer make a narrow prior.
#[test]
fn interval_noise_applies_the_model_to_the_whole_interval() {
    let noise = OdometryNoise::default();
    let step = Pose2::new(0.1, 0.0, 0.05);
    let motions: Vec<TimedEvent> = (0..15)
        .map(|k| TimedEvent {
            time: k as f64,
            event: Event::Motion(Box::new(
                PoseIncrement::between(&Pose2::identity(), &step, &noise).unwrap(),
            )),
        })
        .collect();
    let compound_only = LaserOdometryParams::default();
    let (total, narrow) = interval_odometry(&motions, &compound_only).unwrap();
    let per_interval = LaserOdometryParams {
        interval_noise: Some(noise.clone()),
        ..LaserOdometryParams::default()
    };
    let (same_total, wide) = interval_odometry(&motions, &per_interval).unwrap();
    assert!((total.to_vector() - same_total.to_vector()).amax() < 1e-15);
    let model = noise.covariance(&total);
    assert!((wide[(2, 2)] - model[(2, 2)]).abs() < 1e-9);
    // Fifteen motions in quadrature: about a fifteenth of the variance.
    assert!(narrow[(2, 2)] < 0.2 * wide[(2, 2)], "{narrow} {wide}");
}

proptest! {
    /// The ring search finds the point a full search finds: the nearest within the reach
    /// whose normal passes the check.
    #[test]
    fn the_grid_finds_the_nearest_point_a_full_search_finds(
        coordinates in proptest::collection::vec((-3.0f64..3.0, -3.0f64..3.0, -1.0f64..1.0), 1..200),
        query in (-3.5f64..3.5, -3.5f64..3.5),
        reach in 0.01f64..1.5,
    ) {
        let points: Vec<(Vector2<f64>, Vector2<f64>)> = coordinates
            .iter()
            .map(|&(x, y, a)| (Vector2::new(x, y), Vector2::new(a.cos(), a.sin())))
            .collect();
        let z = Vector2::new(query.0, query.1);
        let accept = |n: &Vector2<f64>| n.x > -0.5;
        let full = points
            .iter()
            .filter(|(p, n)| (p - z).norm() <= reach && accept(n))
            .map(|(p, _)| (p - z).norm())
            .fold(None, |best: Option<f64>, d| Some(best.map_or(d, |b| b.min(d))));
        let grid = Grid::new(points.clone(), GRID_CELL);
        let found = grid.nearest(&z, reach, accept).map(|(p, _)| (p - z).norm());
        prop_assert_eq!(found, full);
    }
}

/// Points spread wider than the densest layout allows get coarser cells, and the search
/// still finds the nearest point.
#[test]
fn a_wide_grid_coarsens_its_cells_and_still_finds_the_nearest_point() {
    let normal = Vector2::new(1.0, 0.0);
    let points = vec![
        (Vector2::new(0.0, 0.0), normal),
        (Vector2::new(0.03, 0.04), normal),
        (Vector2::new(5.0e5, -5.0e5), normal),
    ];
    let grid = Grid::new(points, GRID_CELL);
    assert!(grid.cell > GRID_CELL, "{}", grid.cell);
    assert!((grid.width * grid.height) as usize <= MAX_GRID_CELLS);
    let z = Vector2::new(0.05, 0.05);
    let (nearest, _) = grid.nearest(&z, 0.3, |_| true).unwrap();
    assert_eq!(*nearest, Vector2::new(0.03, 0.04));
    assert!(
        grid.nearest(&Vector2::new(3.0, 3.0), 0.3, |_| true)
            .is_none()
    );
}

/// Points as far apart as floating point allows are gridded without overflow.
#[test]
fn points_at_the_ends_of_the_number_range_are_gridded() {
    let normal = Vector2::new(0.0, 1.0);
    let points = vec![
        (Vector2::new(-1e300, 1e300), normal),
        (Vector2::new(1e300, -1e300), normal),
        (Vector2::new(1.0, 2.0), normal),
    ];
    let grid = Grid::new(points, GRID_CELL);
    let (nearest, _) = grid
        .nearest(&Vector2::new(1.0, 2.1), 0.3, |_| true)
        .unwrap();
    assert_eq!(*nearest, Vector2::new(1.0, 2.0));
}

/// The chain's gridded local map is kept between matches and rebuilt when a key scan joins.
#[test]
fn the_local_map_follows_the_key_scans() {
    let params = LaserOdometryParams {
        local_map_scans: 2,
        ..LaserOdometryParams::default()
    };
    let first = scan(&Pose2::new(2.0, 3.0, 0.1));
    let second = scan(&Pose2::new(2.5, 3.0, 0.1));
    let count = |points: &[Vector2<f64>]| with_normals(points, &params).len();
    let mut chain = Chain::new(Pose2::identity(), &first, &params);
    assert_eq!(chain.local_map().points.len(), count(&first));
    chain.add_key_scan(Pose2::new(0.5, 0.0, 0.0), &second, &params);
    assert_eq!(
        chain.local_map().points.len(),
        count(&first) + count(&second)
    );
    chain.add_key_scan(Pose2::new(1.0, 0.0, 0.0), &first, &params);
    assert_eq!(
        chain.local_map().points.len(),
        count(&second) + count(&first)
    );
}

#[test]
fn a_bad_interval_noise_is_an_error_naming_it() {
    for noise in [
        OdometryNoise {
            rotation_per_radian: -0.1,
            ..OdometryNoise::default()
        },
        OdometryNoise {
            floor_rotation: 0.0,
            ..OdometryNoise::default()
        },
        OdometryNoise {
            translation_per_metre: f64::NAN,
            ..OdometryNoise::default()
        },
    ] {
        let params = LaserOdometryParams {
            interval_noise: Some(noise),
            ..LaserOdometryParams::default()
        };
        let error = params.validate().unwrap_err().to_string();
        assert!(error.contains("interval_noise"), "{error}");
    }
}
