//! The world description: walls (chains whose vertices are shared corners), poles, ceiling
//! lines, lamps, point landmarks, the robot's path, and the sensors with their noise. Read
//! from TOML or JSON; unknown keys are errors.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Vector2, Vector3};
use slam_core::{Pose2, Pose3};

use crate::camera::PinholeCamera;
use crate::data::rb2d::Rb2dParams;
use crate::error::{Result, SensorError};
use crate::events::KnownLandmark;
use crate::odometry::Integration;

/// A simulated world. See `sensors/src/sim/default_world.toml` for a documented example (it
/// lists every key), and `worlds/rb2d-circle.toml` for a landmark-only world driven by
/// constant controls.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct World {
    /// A short name.
    pub name: String,
    /// Wall chains: consecutive points are joined by walls and share their corner.
    #[serde(default)]
    pub walls: Vec<WallChain>,
    /// Vertical cylinders (pillars, tree trunks).
    #[serde(default)]
    pub poles: Vec<PoleSpec>,
    /// Horizontal lines on the ceiling (light strips, beams).
    #[serde(default)]
    pub ceiling_lines: Vec<CeilingLineSpec>,
    /// Round ceiling lamps.
    #[serde(default)]
    pub lamps: Vec<LampSpec>,
    /// Point landmarks (`[[landmarks]]`), seen only by the range-bearing sensor; their ids
    /// follow the poles' (see [`TrueMap::point_landmarks`]).
    #[serde(default)]
    pub landmarks: Vec<LandmarkSpec>,
    /// The robot's path and speed.
    pub robot: RobotSpec,
    /// Wheel odometry noise.
    #[serde(default)]
    pub odometry: OdometrySpec,
    /// The planar laser; absent means none.
    #[serde(default)]
    pub laser: Option<LaserSpec>,
    /// The ceiling camera; absent means none.
    #[serde(default)]
    pub camera: Option<CameraSpec>,
    /// The range-bearing landmark sensor (`[range_bearing]`); absent means none.
    #[serde(default)]
    pub range_bearing: Option<RangeBearingSpec>,
}

/// A chain of walls through `points`; closed chains also join the last point to the first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallChain {
    /// Corner points, m.
    pub points: Vec<[f64; 2]>,
    /// Whether the chain closes on itself.
    #[serde(default)]
    pub closed: bool,
}

/// A vertical cylinder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoleSpec {
    /// Centre x, m.
    pub x: f64,
    /// Centre y, m.
    pub y: f64,
    /// Radius, m.
    pub radius: f64,
}

/// A horizontal ceiling line.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CeilingLineSpec {
    /// One end `(x, y)`, m.
    pub from: [f64; 2],
    /// The other end `(x, y)`, m.
    pub to: [f64; 2],
    /// Height above the floor, m.
    pub height: f64,
}

/// A round ceiling lamp.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LampSpec {
    /// Centre x, m.
    pub x: f64,
    /// Centre y, m.
    pub y: f64,
    /// Height above the floor, m.
    pub height: f64,
    /// Radius of the bright disc, m.
    #[serde(default = "default_lamp_radius")]
    pub radius: f64,
}

fn default_lamp_radius() -> f64 {
    0.15
}

/// A point landmark (`[[landmarks]]`): seen by the range-bearing sensor only, invisible to the
/// laser and the camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LandmarkSpec {
    /// Position x, m.
    pub x: f64,
    /// Position y, m.
    pub y: f64,
}

/// The most laps a world may ask for (a resource limit).
pub const MAX_LAPS: usize = 10_000;

/// The robot and how it moves: either through `waypoints` (in order, `laps` times, steered by
/// a proportional controller at up to `speed` and `max_yaw_rate_deg`, a waypoint being
/// reached within `reach`), or with constant `controls` for a fixed number of steps (then
/// `laps`, `speed`, `max_yaw_rate_deg` and `reach` are not used).
///
/// Each step lasts `dt` and holds the speed and yaw rate constant; `integration` says how the
/// step moves the robot: `"arc"` (default) the exact constant-velocity arc, `"euler"`
/// straight ahead by `v dt`, then a turn by `omega dt` (the rb2d convention; under constant
/// controls the poses then lie exactly on a circle of radius `v dt / (2 sin(omega dt / 2))`).
/// The noisy odometry uses the same integration as the true motion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Start position `(x, y)`, m.
    pub start: [f64; 2],
    /// Start heading, degrees.
    #[serde(default)]
    pub start_heading_deg: f64,
    /// Waypoints `(x, y)`, m; leave empty when `controls` are given.
    #[serde(default)]
    pub waypoints: Vec<[f64; 2]>,
    /// Constant controls instead of waypoints.
    #[serde(default)]
    pub controls: Option<ConstantControls>,
    /// How a step's speed and yaw rate move the robot.
    #[serde(default)]
    pub integration: Integration,
    /// How many times the waypoint list is driven.
    #[serde(default = "one")]
    pub laps: usize,
    /// Cruise speed, m/s.
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// Largest yaw rate, degrees per second.
    #[serde(default = "default_yaw_rate")]
    pub max_yaw_rate_deg: f64,
    /// Time step, s.
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// A waypoint is reached within this distance, m.
    #[serde(default = "default_reach")]
    pub reach: f64,
}

/// Constant controls (`[robot] controls = { v = 1.0, omega_deg = 7.2, steps = 1000 }`): the
/// robot drives `steps` steps at speed `v` and yaw rate `omega_deg`, an exact circle (or a
/// straight line when the yaw rate is 0).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstantControls {
    /// Forward speed, m/s.
    pub v: f64,
    /// Yaw rate, degrees per second (positive turns left).
    pub omega_deg: f64,
    /// Number of steps (motions); the run has `steps + 1` poses.
    pub steps: usize,
}

fn one() -> usize {
    1
}
fn default_speed() -> f64 {
    0.5
}
fn default_yaw_rate() -> f64 {
    45.0
}
fn default_dt() -> f64 {
    0.1
}
fn default_reach() -> f64 {
    0.25
}

/// Noise of the wheel odometry: the measured speed and yaw rate of each step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OdometrySpec {
    /// Standard deviation of the forward speed, m/s.
    pub sigma_v: f64,
    /// Standard deviation of the yaw rate, degrees per second.
    pub sigma_omega_deg: f64,
}

impl Default for OdometrySpec {
    fn default() -> Self {
        OdometrySpec {
            sigma_v: 0.05,
            sigma_omega_deg: 2.0,
        }
    }
}

/// A planar laser, level unless pitched or rolled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaserSpec {
    /// Mount position on the robot `(x, y, z)`, m.
    pub position: [f64; 3],
    /// Mount yaw, degrees.
    pub yaw_deg: f64,
    /// Field of view, degrees, centred ahead.
    pub fov_deg: f64,
    /// Number of beams.
    pub beams: usize,
    /// Largest range, m; no return beyond.
    pub max_range: f64,
    /// Range noise standard deviation, m.
    pub sigma_range: f64,
    /// A scan every this many steps.
    pub every: usize,
    /// Mount pitch (about the laser's once-rotated y axis; positive tilts the forward beams
    /// down), degrees. A tilted scan plane meets the (vertical) walls and poles along
    /// slanted lines, and the floor (z = 0) where it dips below the laser's height.
    pub pitch_deg: f64,
    /// Mount roll (about the laser's twice-rotated x axis), degrees.
    pub roll_deg: f64,
}

impl Default for LaserSpec {
    /// A SICK LMS-200 limited to 8 m, as in the paper's experiments.
    fn default() -> Self {
        LaserSpec {
            position: [0.15, 0.0, 0.3],
            yaw_deg: 0.0,
            fov_deg: 180.0,
            beams: 361,
            max_range: 8.0,
            sigma_range: 0.02,
            every: 2,
            pitch_deg: 0.0,
            roll_deg: 0.0,
        }
    }
}

impl LaserSpec {
    /// The laser's pose on the robot.
    pub fn robot_from_sensor(&self) -> Pose3 {
        let [x, y, z] = self.position;
        Pose3::new(
            Vector3::new(x, y, z),
            self.yaw_deg.to_radians(),
            self.pitch_deg.to_radians(),
            self.roll_deg.to_radians(),
        )
    }

    /// Whether the scan plane is horizontal (no pitch, no roll).
    pub fn is_level(&self) -> bool {
        self.pitch_deg == 0.0 && self.roll_deg == 0.0
    }
}

/// A camera looking straight up at the ceiling.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraSpec {
    /// Intrinsics.
    pub intrinsics: PinholeCamera,
    /// Mount position on the robot `(x, y, z)`, m.
    pub position: [f64; 3],
    /// Mount yaw (image u axis relative to the robot's forward axis), degrees.
    pub yaw_deg: f64,
    /// An image every this many steps.
    pub every: usize,
    /// Mount pitch (about the camera's once-rotated y axis; 0: looking straight up), degrees.
    pub pitch_deg: f64,
    /// Mount roll (about the camera's twice-rotated x axis), degrees.
    pub roll_deg: f64,
    /// Width of a ceiling line's bright strip, m.
    pub strip_width: f64,
    /// Standard deviation of the intensity noise, grey levels.
    pub intensity_noise: f64,
}

impl Default for CameraSpec {
    fn default() -> Self {
        CameraSpec {
            intrinsics: PinholeCamera::default(),
            position: [0.0, 0.0, 0.5],
            yaw_deg: 0.0,
            every: 2,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            strip_width: 0.05,
            intensity_noise: 4.0,
        }
    }
}

impl CameraSpec {
    /// The camera's pose on the robot (optical axis up when pitch and roll are 0).
    pub fn robot_from_sensor(&self) -> Pose3 {
        let [x, y, z] = self.position;
        Pose3::new(
            Vector3::new(x, y, z),
            self.yaw_deg.to_radians(),
            self.pitch_deg.to_radians(),
            self.roll_deg.to_radians(),
        )
    }
}

/// The range-bearing landmark sensor (`[range_bearing]`): the classic landmark-SLAM sensor.
///
/// It sits at the robot origin, facing forward (`robot_from_sensor` is the identity), and
/// measures the range and the bearing (in the robot frame) of every point landmark (pole
/// centres and `[[landmarks]]`) whose true range is at most `max_range` and whose true
/// bearing is within `fov_deg / 2` of straight ahead. Walls and poles do **not** occlude it:
/// every landmark in range and in the field of view is seen, with its true id. Range and
/// bearing get independent Gaussian noise; a measurement whose noisy range is not positive is
/// dropped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeBearingSpec {
    /// Largest true range observed, m.
    pub max_range: f64,
    /// Range noise standard deviation, m.
    pub sigma_range: f64,
    /// Bearing noise standard deviation, degrees.
    pub sigma_bearing_deg: f64,
    /// Observations every this many steps (step 0 included).
    pub every: usize,
    /// Field of view, degrees, centred ahead (default 360: all around).
    #[serde(default = "full_circle")]
    pub fov_deg: f64,
}

fn full_circle() -> f64 {
    360.0
}

/// The world's true map, for evaluation and plots; serialized (as `truth_map.json` by
/// `slam simulate`) with 2-D points as `[x, y]`, 3-D points as `[x, y, z]`, walls and ceiling
/// lines as `[a, b]`, poles as `[centre, radius]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrueMap {
    /// Wall segments `(a, b)`.
    pub walls: Vec<(Vector2<f64>, Vector2<f64>)>,
    /// Shared corners: wall chain vertices where two walls meet.
    pub corners: Vec<Vector2<f64>>,
    /// Poles `(centre, radius)`.
    pub poles: Vec<(Vector2<f64>, f64)>,
    /// Ceiling lines `(a, b)` with their height as z.
    pub ceiling_lines: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// Lamp centres.
    pub lamps: Vec<Vector3<f64>>,
    /// Point landmarks (`[[landmarks]]`), in order; landmark `j` has range-bearing id
    /// `poles.len() + j`.
    #[serde(default)]
    pub landmarks: Vec<Vector2<f64>>,
}

impl TrueMap {
    /// The map as shapes a map error compares estimated features with
    /// ([`slam_core::Shape::error_against`]): walls, poles, ceiling lines and lamps (the point
    /// landmarks are scored by their ids instead).
    pub fn shapes(&self) -> Vec<slam_core::Shape> {
        use slam_core::Shape;
        let walls = self.walls.iter().map(|(start, end)| Shape::Wall {
            start: *start,
            end: *end,
        });
        let poles = self.poles.iter().map(|(centre, radius)| Shape::Pole {
            centre: *centre,
            radius: *radius,
        });
        let lines = self.ceiling_lines.iter().map(|(start, end)| Shape::Line {
            start: *start,
            end: *end,
        });
        let lamps = self.lamps.iter().map(|position| Shape::Point {
            position: *position,
        });
        walls.chain(poles).chain(lines).chain(lamps).collect()
    }

    /// The point landmarks a range-bearing sensor observes, with their ids: the pole centres
    /// first (ids `0..poles.len()`), then the `[[landmarks]]` points.
    pub fn point_landmarks(&self) -> Vec<KnownLandmark> {
        let poles = self.poles.iter().map(|(c, _)| *c);
        poles
            .chain(self.landmarks.iter().copied())
            .enumerate()
            .map(|(id, position)| KnownLandmark {
                id: id as u64,
                position,
            })
            .collect()
    }
}

/// The built-in default world: a 40 m x 15 m office floor (documented in the file itself).
pub const DEFAULT_WORLD_TOML: &str = include_str!("default_world.toml");

impl World {
    /// The built-in office floor.
    ///
    /// ```
    /// let world = slam_sensors::sim::World::default_world();
    /// assert_eq!(world.name, "office");
    /// ```
    pub fn default_world() -> World {
        // The embedded file is checked by a unit test; a parse failure here is a build bug.
        World::from_toml(DEFAULT_WORLD_TOML, "default_world.toml")
            .unwrap_or_else(|e| panic!("the embedded default world is invalid: {e}"))
    }

    /// A world from TOML text; `origin` names the source in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<World> {
        let world: World =
            toml::from_str(text).map_err(|e| SensorError::World(format!("{origin}: {e}")))?;
        world.validate()?;
        Ok(world)
    }

    /// A world from JSON text; `origin` names the source in errors.
    pub fn from_json(text: &str, origin: &str) -> Result<World> {
        let world: World =
            serde_json::from_str(text).map_err(|e| SensorError::World(format!("{origin}: {e}")))?;
        world.validate()?;
        Ok(world)
    }

    /// A world from a `.toml` or `.json` file.
    pub fn from_file(path: &std::path::Path) -> Result<World> {
        let text = std::fs::read_to_string(path).map_err(|e| SensorError::io(path, e))?;
        let origin = path.display().to_string();
        match path.extension().and_then(|e| e.to_str()) {
            Some("json") => World::from_json(&text, &origin),
            _ => World::from_toml(&text, &origin),
        }
    }

    /// The resource limits, checked before anything is allocated: an error names the key
    /// and the limit.
    fn check_limits(&self) -> Result<()> {
        let over = |key: &str, value: usize, limit: usize, why: &str| {
            Err(SensorError::World(format!(
                "{}: {key} = {value} is above the limit of {limit} ({why})",
                self.name
            )))
        };
        if let Some(c) = &self.robot.controls
            && c.steps > super::MAX_STEPS
        {
            return over(
                "[robot] controls.steps",
                c.steps,
                super::MAX_STEPS,
                "a pose per step is kept",
            );
        }
        if self.robot.laps > MAX_LAPS {
            return over(
                "[robot] laps",
                self.robot.laps,
                MAX_LAPS,
                "each lap drives every waypoint",
            );
        }
        if let Some(l) = &self.laser
            && l.beams > crate::scan::MAX_BEAMS
        {
            return over(
                "[laser] beams",
                l.beams,
                crate::scan::MAX_BEAMS,
                "a reading per beam and scan",
            );
        }
        Ok(())
    }

    /// The robot's start pose.
    pub fn start_pose(&self) -> Pose2 {
        Pose2::new(
            self.robot.start[0],
            self.robot.start[1],
            self.robot.start_heading_deg.to_radians(),
        )
    }

    /// The true map.
    pub fn true_map(&self) -> TrueMap {
        let v = |p: &[f64; 2]| Vector2::new(p[0], p[1]);
        let mut map = TrueMap::default();
        for chain in &self.walls {
            let n = chain.points.len();
            let edges = if chain.closed { n } else { n - 1 };
            for k in 0..edges {
                map.walls
                    .push((v(&chain.points[k]), v(&chain.points[(k + 1) % n])));
            }
            let inner = if chain.closed { 0..n } else { 1..n - 1 };
            map.corners.extend(inner.map(|k| v(&chain.points[k])));
        }
        map.poles = self
            .poles
            .iter()
            .map(|p| (Vector2::new(p.x, p.y), p.radius))
            .collect();
        map.ceiling_lines = self
            .ceiling_lines
            .iter()
            .map(|l| {
                (
                    Vector3::new(l.from[0], l.from[1], l.height),
                    Vector3::new(l.to[0], l.to[1], l.height),
                )
            })
            .collect();
        map.lamps = self
            .lamps
            .iter()
            .map(|l| Vector3::new(l.x, l.y, l.height))
            .collect();
        map.landmarks = self
            .landmarks
            .iter()
            .map(|l| Vector2::new(l.x, l.y))
            .collect();
        map
    }

    /// The `PARAM` values of this world's rb2d log: the step, the odometry noise (yaw rate in
    /// rad/s) and, with a range-bearing sensor, its noise (bearing in rad) and range.
    pub fn rb2d_params(&self) -> Rb2dParams {
        let sensor = self.range_bearing.as_ref();
        Rb2dParams {
            dt: self.robot.dt,
            sigma_v: self.odometry.sigma_v,
            sigma_w: self.odometry.sigma_omega_deg.to_radians(),
            sigma_r: sensor.map(|s| s.sigma_range),
            sigma_b: sensor.map(|s| s.sigma_bearing_deg.to_radians()),
            max_range: sensor.map(|s| s.max_range),
        }
    }

    /// Checks every number and the consistency of the description.
    pub fn validate(&self) -> Result<()> {
        self.check_limits()?;
        let bad = |what: String| Err(SensorError::World(format!("{}: {what}", self.name)));
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        for (i, chain) in self.walls.iter().enumerate() {
            if chain.points.len() < 2 || !chain.points.iter().all(|p| finite(p)) {
                return bad(format!("wall chain {i} needs at least two finite points"));
            }
            let n = chain.points.len();
            let edges = if chain.closed { n } else { n - 1 };
            for k in 0..edges {
                let (a, b) = (chain.points[k], chain.points[(k + 1) % n]);
                if ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt() < 0.05 {
                    return bad(format!(
                        "wall chain {i} has a wall shorter than 5 cm at point {k}"
                    ));
                }
            }
        }
        for (i, p) in self.poles.iter().enumerate() {
            if !finite(&[p.x, p.y, p.radius]) || p.radius <= 0.0 {
                return bad(format!(
                    "pole {i} needs a finite centre and a positive radius"
                ));
            }
        }
        let camera_height = self.camera.as_ref().map_or(0.0, |c| c.position[2]);
        for (i, l) in self.ceiling_lines.iter().enumerate() {
            let length = ((l.from[0] - l.to[0]).powi(2) + (l.from[1] - l.to[1]).powi(2)).sqrt();
            if !finite(&[l.from[0], l.from[1], l.to[0], l.to[1], l.height])
                || length < 0.1
                || l.height <= camera_height + 0.2
            {
                return bad(format!(
                    "ceiling line {i} needs finite ends at least 10 cm apart, at least 20 cm above the camera"
                ));
            }
        }
        for (i, l) in self.lamps.iter().enumerate() {
            if !finite(&[l.x, l.y, l.height, l.radius])
                || l.radius <= 0.0
                || l.height <= camera_height + 0.2
            {
                return bad(format!(
                    "lamp {i} needs a positive radius, at least 20 cm above the camera"
                ));
            }
        }
        for (i, l) in self.landmarks.iter().enumerate() {
            if !finite(&[l.x, l.y]) {
                return bad(format!("landmark {i} needs a finite position"));
            }
        }
        let r = &self.robot;
        if !r.waypoints.iter().all(|p| finite(p)) || !finite(&r.start) {
            return bad("the robot needs a finite start and finite waypoints".into());
        }
        match (&r.controls, r.waypoints.is_empty()) {
            (None, true) => {
                return bad("the robot needs at least one waypoint, or constant controls".into());
            }
            (Some(_), false) => {
                return bad(
                    "the robot takes either waypoints or constant controls, not both".into(),
                );
            }
            (Some(c), true) => {
                if !finite(&[c.v, c.omega_deg]) || c.steps == 0 || c.steps > super::MAX_STEPS {
                    return bad(format!(
                        "robot controls need a finite v and omega_deg and 1 to {} steps",
                        super::MAX_STEPS
                    ));
                }
            }
            (None, false) => {}
        }
        let positive = [r.speed, r.max_yaw_rate_deg, r.dt, r.reach];
        if !finite(&positive)
            || positive.iter().any(|&v| v <= 0.0)
            || r.laps == 0
            || !r.start_heading_deg.is_finite()
        {
            return bad("robot speed, yaw rate, dt, reach and laps must be positive".into());
        }
        let o = &self.odometry;
        if !finite(&[o.sigma_v, o.sigma_omega_deg]) || o.sigma_v < 0.0 || o.sigma_omega_deg < 0.0 {
            return bad("odometry noise must be finite and non-negative".into());
        }
        if let Some(l) = &self.laser {
            let ok = finite(&l.position)
                && finite(&[l.yaw_deg, l.fov_deg, l.max_range, l.sigma_range])
                && l.pitch_deg.abs() <= 30.0
                && l.roll_deg.abs() <= 30.0
                && l.beams >= 2
                && l.fov_deg > 0.0
                && l.fov_deg <= 360.0
                && l.max_range > 0.0
                && l.sigma_range >= 0.0
                && l.every > 0;
            if !ok {
                return bad("laser: at least 2 beams, a field of view in (0, 360], positive max range, every > 0, pitch and roll within 30 degrees".into());
            }
        }
        if let Some(c) = &self.camera {
            c.intrinsics.validate()?;
            let ok = finite(&c.position)
                && finite(&[c.yaw_deg, c.strip_width, c.intensity_noise])
                && c.pitch_deg.abs() <= 45.0
                && c.roll_deg.abs() <= 45.0
                && c.strip_width > 0.0
                && c.intensity_noise >= 0.0
                && c.every > 0;
            if !ok {
                return bad("camera: finite mount, pitch and roll within 45 degrees, positive strip width, every > 0".into());
            }
        }
        if let Some(s) = &self.range_bearing {
            let values = [s.max_range, s.sigma_range, s.sigma_bearing_deg, s.fov_deg];
            let ok = finite(&values)
                && s.max_range > 0.0
                && s.sigma_range > 0.0
                && s.sigma_bearing_deg > 0.0
                && s.fov_deg > 0.0
                && s.fov_deg <= 360.0
                && s.every > 0;
            if !ok {
                return bad("range_bearing: positive max_range, sigma_range and sigma_bearing_deg, a field of view in (0, 360], every > 0".into());
            }
        }
        Ok(())
    }
}
