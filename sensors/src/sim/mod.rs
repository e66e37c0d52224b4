//! The simulator, the embedded default world: a robot follows waypoints (or constant
//! controls) through a world of walls, poles, ceiling lines, lamps and point landmarks, and
//! produces, seeded and reproducibly, noisy wheel odometry, laser scans by ray casting,
//! ceiling-camera images, range-bearing landmark observations, and its true poses.
//!
//! Each sensor draws its noise from its own random stream derived from the seed (odometry 1,
//! laser 2, camera 3, range-bearing 4), so adding or removing a sensor does not change the
//! others' outputs for the same seed.

pub mod raycast;
pub mod render;
mod world;

pub use world::{
    CameraSpec, CeilingLineSpec, ConstantControls, DEFAULT_WORLD_TOML, LampSpec, LandmarkSpec,
    LaserSpec, OdometrySpec, PoleSpec, RangeBearingSpec, RobotSpec, TrueMap, WallChain, World,
};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{Observation, Pose2, Pose3, RobotPose, wrap_angle};
use std::sync::Arc;

use std::collections::VecDeque;

use crate::error::{Result, SensorError};
use crate::events::{
    Clock, Dataset, DatasetInfo, Event, EventStream, KnownLandmark, Pump, Step, TimedEvent,
    TruthKind,
};
use crate::models::RangeBearing;
use crate::odometry::{Integration, Unicycle};
use crate::scan::LaserScan;
use render::{Ceiling, render_ceiling};

/// Most steps a simulation may take before giving up on reaching its waypoints.
pub const MAX_STEPS: usize = 200_000;

/// A simulated run: the event stream, the true trajectory and the true map.
#[derive(Debug)]
pub struct Simulation {
    /// Odometry, scans, images, range-bearing observations and ground truth, in time order.
    /// At each step `k` (time `k dt`): the motion that led to the step (from step 1), the true
    /// pose, then the scan, the image and the observations that the step has.
    pub dataset: Dataset,
    /// The true pose at every step (step k at time k dt).
    pub trajectory: Vec<Pose2>,
    /// The world's true map.
    pub truth: TrueMap,
}

/// One step of the driven path: the true speed and yaw rate that lead to the next pose.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Control {
    v: f64,
    omega: f64,
}

/// Simulates `world` with the random seed `seed`: the same world and seed give the same run.
/// This is [`simulate_stream`] collected.
///
/// [`Dataset::landmarks`] lists the point landmarks with their range-bearing ids (pole
/// centres first, then `[[landmarks]]`: [`TrueMap::point_landmarks`]).
///
/// ```
/// use slam_sensors::sim::{simulate, World};
/// let mut world = World::default_world();
/// world.robot.waypoints.truncate(1); // a short drive east along the corridor
/// let run = simulate(&world, 7).unwrap();
/// assert_eq!(run.trajectory.len(), run.dataset.counts().ground_truth);
/// ```
pub fn simulate(world: &World, seed: u64) -> Result<Simulation> {
    let SimulatedStream {
        events,
        truth,
        trajectory,
    } = simulate_stream(world, seed)?;
    Ok(Simulation {
        dataset: events.into_dataset()?,
        trajectory,
        truth,
    })
}

/// A simulated run whose events are generated one time step at a time, as they are read.
#[derive(Debug)]
pub struct SimulatedStream {
    /// The events of [`Simulation::dataset`], in the same order, generated lazily.
    pub events: EventStream,
    /// The world's true map.
    pub truth: TrueMap,
    /// The true pose at every step (step k at time k dt), computed up front.
    pub trajectory: Vec<Pose2>,
}

/// Simulates `world` with the random seed `seed` step by step: the drive (the true
/// trajectory) is computed up front, the odometry, scans, images and observations of each step
/// when the stream reaches it, with the same random draws as [`simulate`], so the events are
/// the same, bit for bit. An invalid world or a drive that does not reach its waypoints is an
/// error of this call.
///
/// ```
/// use slam_sensors::sim::{simulate_stream, World};
/// use slam_sensors::Event;
/// let mut world = World::default_world();
/// world.robot.waypoints.truncate(1);
/// let run = simulate_stream(&world, 7).unwrap();
/// let steps = run.trajectory.len();
/// let truths = run.events
///     .filter(|e| matches!(e.as_ref().unwrap().event, Event::GroundTruth { .. }))
///     .count();
/// assert_eq!(truths, steps);
/// ```
pub fn simulate_stream(world: &World, seed: u64) -> Result<SimulatedStream> {
    world.validate()?;
    let (trajectory, controls) = drive(world)?;
    let truth = world.true_map();
    let ceiling = Ceiling {
        lines: truth.ceiling_lines.clone(),
        lamps: world
            .lamps
            .iter()
            .map(|l| (Vector3::new(l.x, l.y, l.height), l.radius))
            .collect(),
    };
    let landmarks = truth.point_landmarks();
    let info = DatasetInfo {
        name: format!("simulated {}", world.name),
        clock: Clock::Seconds,
        landmarks: landmarks.clone(),
        gps_antenna: slam_core::nalgebra::Vector2::zeros(),
    };
    let steps = Steps {
        world: world.clone(),
        truth: truth.clone(),
        ceiling,
        landmarks,
        trajectory: trajectory.clone(),
        controls,
        k: 0,
        odometry_rng: stream(seed, 1),
        laser_rng: stream(seed, 2),
        camera_rng: stream(seed, 3),
        range_bearing_rng: stream(seed, 4),
    };
    Ok(SimulatedStream {
        events: EventStream::new(info, Pump::new(steps)),
        truth,
        trajectory,
    })
}

/// The state of a [`simulate_stream`] run: what the steps need, and the next step.
struct Steps {
    world: World,
    truth: TrueMap,
    ceiling: Ceiling,
    landmarks: Vec<KnownLandmark>,
    trajectory: Vec<Pose2>,
    controls: Vec<Control>,
    /// The next step.
    k: usize,
    odometry_rng: ChaCha8Rng,
    laser_rng: ChaCha8Rng,
    camera_rng: ChaCha8Rng,
    range_bearing_rng: ChaCha8Rng,
}

impl Step for Steps {
    /// The events of step `k`: the motion that led to it (from step 1), the true pose, then
    /// the scan, the image and the observations that the step has.
    fn step(&mut self, out: &mut VecDeque<TimedEvent>) -> Result<bool> {
        let k = self.k;
        let Some(pose) = self.trajectory.get(k) else {
            return Ok(false);
        };
        self.k += 1;
        let world = &self.world;
        let time = k as f64 * world.robot.dt;
        let mut push = |event| out.push_back(TimedEvent { time, event });
        if k > 0 {
            let motion = noisy_odometry(&self.controls[k - 1], world, &mut self.odometry_rng)?;
            push(Event::Motion(Box::new(motion)));
        }
        push(Event::GroundTruth {
            pose: *pose,
            kind: TruthKind::True,
        });
        if let Some(laser) = world.laser.as_ref().filter(|l| k.is_multiple_of(l.every)) {
            let scan = cast_scan(pose, laser, &self.truth, &mut self.laser_rng)?;
            push(Event::Scan {
                scan,
                robot_from_sensor: laser.robot_from_sensor(),
            });
        }
        if let Some(camera) = world.camera.as_ref().filter(|c| k.is_multiple_of(c.every)) {
            let world_from_camera = pose.world_from_sensor(&camera.robot_from_sensor());
            let image = render_ceiling(
                &world_from_camera,
                camera,
                &self.ceiling,
                &mut self.camera_rng,
            );
            push(Event::Image {
                image,
                camera: camera.intrinsics,
                robot_from_sensor: camera.robot_from_sensor(),
            });
        }
        if let Some(sensor) = world
            .range_bearing
            .as_ref()
            .filter(|s| k.is_multiple_of(s.every))
        {
            let observations =
                observe_landmarks(pose, sensor, &self.landmarks, &mut self.range_bearing_rng)?;
            if !observations.is_empty() {
                push(Event::Observations(observations));
            }
        }
        Ok(true)
    }
}

/// An independent random stream per purpose, so that e.g. adding a camera does not change
/// the laser noise.
fn stream(seed: u64, purpose: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(purpose);
    rng
}

/// Drives the robot: constant controls when the world gives them, otherwise through the
/// waypoints: turn towards the next one (proportional yaw rate, limited), slow down while the
/// heading error is large. Steps integrate as the world says (exact arcs by default).
fn drive(world: &World) -> Result<(Vec<Pose2>, Vec<Control>)> {
    let robot = &world.robot;
    let max_yaw_rate = robot.max_yaw_rate_deg.to_radians();
    let mut pose = world.start_pose();
    let mut poses = vec![pose];
    let mut controls = Vec::new();
    if let Some(constant) = &robot.controls {
        let control = Control {
            v: constant.v,
            omega: constant.omega_deg.to_radians(),
        };
        for _ in 0..constant.steps {
            pose = advance(&pose, &control, robot.dt, robot.integration);
            poses.push(pose);
            controls.push(control);
        }
        return Ok((poses, controls));
    }
    let targets = (0..robot.laps).flat_map(|_| robot.waypoints.iter());
    for target in targets {
        let target = Vector2::new(target[0], target[1]);
        loop {
            let to_target = target - pose.translation();
            if to_target.norm() < robot.reach {
                break;
            }
            if poses.len() > MAX_STEPS {
                return Err(SensorError::World(format!(
                    "{}: the robot did not reach waypoint ({}, {}) within {MAX_STEPS} steps",
                    world.name, target.x, target.y
                )));
            }
            let error = wrap_angle(to_target.y.atan2(to_target.x) - pose.theta);
            let omega = (2.0 * error).clamp(-max_yaw_rate, max_yaw_rate);
            let v = robot.speed
                * error.cos().max(0.0).powi(4)
                * (to_target.norm() / 0.5).clamp(0.2, 1.0);
            let control = Control { v, omega };
            pose = advance(&pose, &control, robot.dt, robot.integration);
            poses.push(pose);
            controls.push(control);
        }
    }
    Ok((poses, controls))
}

fn advance(pose: &Pose2, control: &Control, dt: f64, integration: Integration) -> Pose2 {
    // Noise-free: the unicycle's step (the exact arc by default).
    match Unicycle::new(control.v, control.omega, dt, 0.0, 0.0, integration) {
        Ok(step) => slam_core::MotionModel::apply_control(&step, pose, &step_control(&step))
            .unwrap_or(*pose),
        Err(_) => *pose,
    }
}

fn step_control(step: &Unicycle) -> slam_core::nalgebra::DVector<f64> {
    slam_core::MotionModel::<Pose2>::control(step)
}

/// The odometry of one step: the true speed and yaw rate plus noise, with the noise model the
/// filter should assume.
fn noisy_odometry(control: &Control, world: &World, rng: &mut ChaCha8Rng) -> Result<Unicycle> {
    let sigma_v = world.odometry.sigma_v;
    let sigma_omega = world.odometry.sigma_omega_deg.to_radians();
    let v = control.v + gaussian(rng, sigma_v);
    let omega = control.omega + gaussian(rng, sigma_omega);
    Unicycle::new(
        v,
        omega,
        world.robot.dt,
        sigma_v,
        sigma_omega,
        world.robot.integration,
    )
}

/// The range-bearing observations from `pose` of the `landmarks` in range and in the field of
/// view (no occlusion), with noise; one noise pair is drawn per visible landmark, in id order.
fn observe_landmarks(
    pose: &Pose2,
    sensor: &RangeBearingSpec,
    landmarks: &[KnownLandmark],
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Observation>> {
    let sigma_bearing = sensor.sigma_bearing_deg.to_radians();
    let half_fov = 0.5 * sensor.fov_deg.to_radians();
    let mut observations = Vec::new();
    for landmark in landmarks {
        let local = pose.inverse_transform_point(&landmark.position);
        let range = local.norm();
        let bearing = local.y.atan2(local.x);
        if range > sensor.max_range || range < 1e-9 || bearing.abs() > half_fov {
            continue;
        }
        let noisy_range = range + gaussian(rng, sensor.sigma_range);
        let noisy_bearing = bearing + gaussian(rng, sigma_bearing);
        if noisy_range <= 0.0 {
            continue;
        }
        let measurement = RangeBearing::new(
            noisy_range,
            noisy_bearing,
            sensor.sigma_range,
            sigma_bearing,
        )?;
        observations.push(Observation {
            robot_from_sensor: Pose3::identity(),
            measurement: Arc::new(measurement),
            landmark_id: Some(landmark.id),
        });
    }
    Ok(observations)
}

fn gaussian(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    Normal::new(0.0, sigma).map_or(0.0, |n| n.sample(rng))
}

/// A laser scan from `pose` by ray casting, with range noise; no return beyond the
/// maximum range (reported as the maximum range). A tilted laser's beams are cast in 3-D
/// against the walls and poles (vertical, unbounded in height) and the floor.
fn cast_scan(
    pose: &Pose2,
    laser: &LaserSpec,
    truth: &TrueMap,
    rng: &mut ChaCha8Rng,
) -> Result<LaserScan> {
    if !laser.is_level() {
        return cast_tilted_scan(pose, laser, truth, rng);
    }
    let sensor = pose.compose(&Pose2::new(
        laser.position[0],
        laser.position[1],
        laser.yaw_deg.to_radians(),
    ));
    let fov = laser.fov_deg.to_radians();
    let increment = fov / (laser.beams - 1) as f64;
    let angle_min = -fov / 2.0;
    let origin = sensor.translation();
    let ranges = (0..laser.beams)
        .map(|i| {
            let bearing = sensor.theta + angle_min + increment * i as f64;
            let direction = Vector2::new(bearing.cos(), bearing.sin());
            let range = raycast::cast(&origin, &direction, &truth.walls, &truth.poles);
            noisy_range(range, laser, rng)
        })
        .collect();
    LaserScan::with_increment(angle_min, increment, ranges, 0.0, laser.max_range)
}

/// The noisy reading of a beam whose true range is `range` (`None`: no return).
fn noisy_range(range: Option<f64>, laser: &LaserSpec, rng: &mut ChaCha8Rng) -> f64 {
    match range {
        Some(t) if t < laser.max_range => {
            let noisy = t + gaussian(rng, laser.sigma_range);
            if noisy >= laser.max_range {
                laser.max_range
            } else {
                noisy.max(1e-3)
            }
        }
        _ => laser.max_range,
    }
}

/// [`cast_scan`] for a pitched or rolled laser: each beam's direction in the world is
/// `R (cos b, sin b, 0)`; its horizontal part is cast in the plane (walls and poles are
/// vertical), the range is the horizontal distance over the horizontal part's length, and a
/// beam going down stops at the floor if it reaches it first.
fn cast_tilted_scan(
    pose: &Pose2,
    laser: &LaserSpec,
    truth: &TrueMap,
    rng: &mut ChaCha8Rng,
) -> Result<LaserScan> {
    let world_from_sensor = pose.to_pose3(0.0).compose(&laser.robot_from_sensor());
    let rotation = world_from_sensor.rotation();
    let origin3 = world_from_sensor.translation;
    let origin = Vector2::new(origin3.x, origin3.y);
    let fov = laser.fov_deg.to_radians();
    let increment = fov / (laser.beams - 1) as f64;
    let angle_min = -fov / 2.0;
    let ranges = (0..laser.beams)
        .map(|i| {
            let bearing = angle_min + increment * i as f64;
            let direction = rotation * Vector3::new(bearing.cos(), bearing.sin(), 0.0);
            let horizontal = Vector2::new(direction.x, direction.y);
            let length = horizontal.norm();
            let to_wall = (length > 1e-9)
                .then(|| raycast::cast(&origin, &(horizontal / length), &truth.walls, &truth.poles))
                .flatten()
                .map(|t| t / length);
            let to_floor = (direction.z < -1e-12).then(|| origin3.z / -direction.z);
            let range = match (to_wall, to_floor) {
                (Some(w), Some(f)) => Some(w.min(f)),
                (w, f) => w.or(f),
            };
            noisy_range(range, laser, rng)
        })
        .collect();
    LaserScan::with_increment(angle_min, increment, ranges, 0.0, laser.max_range)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_world_parses_and_is_an_office_floor() {
        let world = World::from_toml(DEFAULT_WORLD_TOML, "default").unwrap();
        let map = world.true_map();
        let (mut lo, mut hi) = (
            Vector2::repeat(f64::INFINITY),
            Vector2::repeat(f64::NEG_INFINITY),
        );
        for (a, b) in &map.walls {
            lo = lo.inf(a).inf(b);
            hi = hi.sup(a).sup(b);
        }
        assert_eq!((hi - lo), Vector2::new(40.0, 15.0));
        assert!(
            map.walls.len() >= 20 && map.corners.len() >= 8,
            "{} walls, {} corners",
            map.walls.len(),
            map.corners.len()
        );
        assert!(map.poles.len() >= 3 && map.ceiling_lines.len() >= 5 && map.lamps.len() >= 10);
    }

    /// A tilted laser's beams meet a vertical wall farther than level ones (by 1 / cos of
    /// their elevation) and the floor where they dip; roll lifts the left (+y) side. A level
    /// laser keeps the planar cast.
    #[test]
    fn a_tilted_laser_meets_walls_along_slanted_lines_and_the_floor() {
        let truth = TrueMap {
            walls: vec![(Vector2::new(3.0, -50.0), Vector2::new(3.0, 50.0))],
            corners: Vec::new(),
            poles: Vec::new(),
            ceiling_lines: Vec::new(),
            lamps: Vec::new(),
            landmarks: Vec::new(),
        };
        let laser = |pitch_deg: f64, roll_deg: f64| LaserSpec {
            position: [0.0, 0.0, 0.3],
            fov_deg: 180.0,
            beams: 3,
            max_range: 20.0,
            sigma_range: 0.0,
            pitch_deg,
            roll_deg,
            ..LaserSpec::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let pose = Pose2::identity();
        // Beams at -90, 0 and +90 degrees.
        let level = cast_scan(&pose, &laser(0.0, 0.0), &truth, &mut rng).unwrap();
        assert!((level.ranges[1] - 3.0).abs() < 1e-9);
        assert_eq!(level.ranges[0], 20.0);
        let pitched_up = cast_scan(&pose, &laser(-5.0, 0.0), &truth, &mut rng).unwrap();
        let expected = 3.0 / 5f64.to_radians().cos();
        assert!(
            (pitched_up.ranges[1] - expected).abs() < 1e-9,
            "{:?}",
            pitched_up.ranges
        );
        let pitched_down = cast_scan(&pose, &laser(10.0, 0.0), &truth, &mut rng).unwrap();
        let floor = 0.3 / 10f64.to_radians().sin();
        assert!(
            (pitched_down.ranges[1] - floor).abs() < 1e-9,
            "{:?}",
            pitched_down.ranges
        );
        let rolled = cast_scan(&pose, &laser(0.0, 10.0), &truth, &mut rng).unwrap();
        assert!(
            (rolled.ranges[0] - floor).abs() < 1e-9,
            "{:?}",
            rolled.ranges
        );
        assert_eq!(rolled.ranges[2], 20.0);
        assert!((rolled.ranges[1] - 3.0).abs() < 1e-9);
    }

    #[test]
    fn unknown_keys_and_bad_values_are_errors() {
        let with_typo =
            DEFAULT_WORLD_TOML.replace("name = \"office\"", "name = \"office\"\ncolour = 3");
        let e = World::from_toml(&with_typo, "typo.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("typo.toml") && e.contains("colour"), "{e}");
        let negative = DEFAULT_WORLD_TOML.replace("radius = 0.25", "radius = -0.25");
        assert!(World::from_toml(&negative, "neg.toml").is_err());
    }

    #[test]
    fn the_default_drive_stays_clear_of_walls_and_pillars_and_closes_its_loop() {
        let world = World::default_world();
        let (poses, _) = drive(&world).unwrap();
        let map = world.true_map();
        let clearance = poses
            .iter()
            .map(|p| {
                let q = p.translation();
                let walls = map.walls.iter().map(|(a, b)| {
                    let e = b - a;
                    let t = ((q - a).dot(&e) / e.norm_squared()).clamp(0.0, 1.0);
                    (q - (a + e * t)).norm()
                });
                let poles = map.poles.iter().map(|(c, r)| (q - c).norm() - r);
                walls.chain(poles).fold(f64::INFINITY, f64::min)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            clearance > 0.3,
            "the robot comes within {clearance} m of an obstacle"
        );
        // It passes its start again (the corridor loop) after having gone far away.
        let start = poses[0].translation();
        let far = poses
            .iter()
            .position(|p| (p.translation() - start).norm() > 20.0)
            .unwrap();
        assert!(
            poses[far..]
                .iter()
                .any(|p| (p.translation() - start).norm() < 1.0)
        );
    }

    #[test]
    fn same_seed_same_run_different_seed_different_noise() {
        let mut world = World::default_world();
        world.robot.waypoints.truncate(1);
        let scans = |seed| {
            simulate(&world, seed)
                .unwrap()
                .dataset
                .events
                .into_iter()
                .filter_map(|e| match e.event {
                    Event::Scan { scan, .. } => Some(scan.ranges),
                    _ => None,
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(scans(3), scans(3));
        assert_ne!(scans(3), scans(4));
    }

    /// A short, camera-less run of the default world (the camera is the slow part).
    fn short_world() -> World {
        let mut world = World::default_world();
        world.robot.waypoints.truncate(1);
        world.camera = None;
        world
    }

    #[test]
    fn the_range_bearing_sensor_does_not_change_the_other_sensors() {
        let mut world = World::default_world();
        world.robot.waypoints.truncate(3); // into the pillar room: the poles are seen
        assert!(world.range_bearing.is_some());
        let without = {
            let mut w = world.clone();
            w.range_bearing = None;
            simulate(&w, 5).unwrap()
        };
        let with = simulate(&world, 5).unwrap();
        let others = |run: &Simulation| {
            run.dataset
                .events
                .iter()
                .filter_map(|e| match &e.event {
                    Event::Observations(_) => None,
                    Event::Motion(m) => Some(format!("{} {:?}", e.time, m.control())),
                    other => Some(format!("{} {other:?}", e.time)),
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(others(&with), others(&without));
        assert_eq!(without.dataset.counts().observations, 0);
        assert!(with.dataset.counts().observations > 0);
    }

    #[test]
    fn range_bearing_observations_match_the_truth_and_ignore_walls() {
        let mut world = short_world();
        world.laser = None;
        world.landmarks = vec![
            LandmarkSpec { x: 5.0, y: 7.5 },  // ahead in the corridor
            LandmarkSpec { x: 1.5, y: 3.0 },  // behind a wall, 4.5 m to the right
            LandmarkSpec { x: -3.0, y: 7.5 }, // behind the start, 4.5 m
            LandmarkSpec { x: 1.5, y: 20.0 }, // beyond the range
        ];
        world.range_bearing = Some(RangeBearingSpec {
            max_range: 8.0,
            sigma_range: 1e-9,
            sigma_bearing_deg: 1e-9,
            every: 3,
            fov_deg: 200.0,
        });
        let run = simulate(&world, 2).unwrap();
        let poles = world.poles.len() as u64;
        assert_eq!(run.dataset.landmarks.len(), world.poles.len() + 4);
        assert_eq!(run.dataset.landmarks[4].id, poles);
        let mut first = true;
        for e in &run.dataset.events {
            let Event::Observations(observations) = &e.event else {
                continue;
            };
            let k = (e.time / world.robot.dt).round() as usize;
            assert_eq!(k % 3, 0);
            let pose = run.trajectory[k];
            for o in observations {
                let id = o.landmark_id.unwrap();
                let rb = o
                    .measurement
                    .as_any()
                    .downcast_ref::<RangeBearing>()
                    .unwrap();
                let local =
                    pose.inverse_transform_point(&run.dataset.landmarks[id as usize].position);
                assert!((rb.range - local.norm()).abs() < 1e-6);
                assert!(wrap_angle(rb.bearing - local.y.atan2(local.x)).abs() < 1e-6);
                assert!(local.norm() <= 8.0 && local.y.atan2(local.x).abs() <= 100f64.to_radians());
            }
            if first {
                // At the start: the landmark ahead and the one behind the wall, not the one
                // behind the robot (field of view) nor the far one.
                let ids: Vec<_> = observations.iter().map(|o| o.landmark_id).collect();
                assert_eq!(ids, vec![Some(poles), Some(poles + 1)]);
                first = false;
            }
        }
        assert!(!first);
    }

    #[test]
    fn constant_controls_drive_an_exact_circle() {
        let mut world = short_world();
        world.robot.waypoints.clear();
        world.robot.start = [0.0, 0.0];
        world.robot.controls = Some(ConstantControls {
            v: 1.0,
            omega_deg: 9.0,
            steps: 400,
        });
        for integration in [Integration::Arc, Integration::Euler] {
            world.robot.integration = integration;
            let (poses, controls) = drive(&world).unwrap();
            assert_eq!((poses.len(), controls.len()), (401, 400));
            let phi = 0.9f64.to_radians();
            let (radius, centre) = match integration {
                Integration::Arc => (
                    1.0 / 9f64.to_radians(),
                    Vector2::new(0.0, 1.0 / 9f64.to_radians()),
                ),
                Integration::Euler => {
                    let rho = 0.1 / (2.0 * (phi / 2.0).sin());
                    (rho, Vector2::new(0.05, rho * (phi / 2.0).cos()))
                }
            };
            for p in &poses {
                assert!(((p.translation() - centre).norm() - radius).abs() < 1e-9);
            }
            // 400 steps of 0.9 degrees: one lap, back at the start.
            assert!(poses[400].translation().norm() < 1e-9);
        }
    }

    #[test]
    fn robot_modes_and_range_bearing_keys_are_checked() {
        let base = "name = \"w\"\n[robot]\nstart = [0.0, 0.0]\n";
        let circle = format!("{base}controls = {{ v = 1.0, omega_deg = 5.0, steps = 10 }}\n");
        assert!(World::from_toml(&circle, "c.toml").is_ok());
        let both = format!("{circle}waypoints = [[1.0, 0.0]]\n");
        let e = World::from_toml(&both, "both.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("either waypoints or constant controls"), "{e}");
        let neither = World::from_toml(base, "none.toml").unwrap_err().to_string();
        assert!(neither.contains("at least one waypoint"), "{neither}");
        let typo = format!("{base}controls = {{ v = 1.0, omega = 5.0, steps = 10 }}\n");
        let e = World::from_toml(&typo, "typo.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("typo.toml") && e.contains("omega"), "{e}");
        let sensor = "[range_bearing]\nmax_range = 5.0\nsigma_range = 0.1\nsigma_bearing_deg = 1.0\nevery = 1\n";
        let with_sensor = format!("{circle}{sensor}");
        let world = World::from_toml(&with_sensor, "rb.toml").unwrap();
        assert_eq!(world.range_bearing.as_ref().map(|s| s.fov_deg), Some(360.0));
        let unknown = format!("{with_sensor}sigma_range_deg = 2.0\n");
        let e = World::from_toml(&unknown, "rb.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("rb.toml") && e.contains("sigma_range_deg"),
            "{e}"
        );
        let missing = with_sensor.replace("every = 1\n", "");
        let e = World::from_toml(&missing, "rb.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("every"), "{e}");
        let zero = with_sensor.replace("sigma_range = 0.1", "sigma_range = 0.0");
        assert!(World::from_toml(&zero, "rb.toml").is_err());
        let landmark = format!("{circle}[[landmarks]]\nx = 1.0\ny = 2.0\nz = 3.0\n");
        let e = World::from_toml(&landmark, "lm.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 8") && e.contains("unknown field `z`"),
            "{e}"
        );
    }
}
