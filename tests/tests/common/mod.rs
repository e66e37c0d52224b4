//! Short simulated worlds and TOML runs shared by the extension-point tests (each test file
//! uses part of it).
#![allow(dead_code)]

use std::path::PathBuf;

use slam_runtime::{Config, RunMetrics, RunOutput};
use slam_sensors::Event;
use slam_sensors::sim::{World, simulate_stream};

/// A world written to a temporary file, as `[data] spec = "world:FILE"` reads it.
pub struct TempWorld {
    /// The world as written.
    pub world: World,
    /// The file's folder (removed when this is dropped).
    _dir: tempfile::TempDir,
    path: PathBuf,
}

impl TempWorld {
    /// Writes `world` to a fresh temporary folder.
    pub fn new(world: World) -> Self {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let path = dir.path().join("world.toml");
        let text = toml::to_string(&world).expect("the world serializes");
        std::fs::write(&path, text).expect("the world file is written");
        TempWorld {
            world,
            _dir: dir,
            path,
        }
    }

    /// The `[data]` table reading this world with `seed`, as TOML.
    pub fn data_table(&self, seed: u64) -> String {
        let spec = toml::Value::String(format!("world:{}", self.path.display()));
        format!("[data]\nspec = {spec}\nseed = {seed}\n")
    }

    /// The events of this world's simulation with `seed` (what the run reads).
    pub fn events(&self, seed: u64) -> Vec<Event> {
        simulate_stream(&self.world, seed)
            .expect("the world simulates")
            .events
            .map(|e| e.expect("a simulated event").event)
            .collect()
    }

    /// The range-bearing observations of each `Observations` event, in order.
    pub fn observation_batches(&self, seed: u64) -> Vec<Vec<Option<u64>>> {
        self.events(seed)
            .into_iter()
            .filter_map(|e| match e {
                Event::Observations(o) => Some(o.iter().map(|o| o.landmark_id).collect()),
                _ => None,
            })
            .collect()
    }
}

/// The built-in office floor without its camera, driving from its start (1.5, 7.5) east along
/// the corridor to `x_end` only.
pub fn short_office(x_end: f64) -> TempWorld {
    let mut world = World::default_world();
    world.camera = None;
    world.robot.waypoints = vec![[x_end, 7.5]];
    TempWorld::new(world)
}

/// `worlds/rb2d-circle.toml` (50 range-bearing landmarks with ids, no laser) cut to `steps`
/// steps of 0.1 m.
pub fn short_rb2d_circle(steps: usize) -> TempWorld {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
    let mut world = World::from_file(&file).expect("rb2d-circle.toml reads");
    world
        .robot
        .controls
        .as_mut()
        .expect("rb2d-circle is driven by constant controls")
        .steps = steps;
    TempWorld::new(world)
}

/// Parses `text` as a whole config (origin "inline"), runs it and computes its metrics.
pub fn run_toml(text: &str) -> (Config, RunOutput, RunMetrics) {
    let config = Config::from_toml(text, "inline").unwrap_or_else(|e| panic!("{e}\n{text}"));
    let output = slam_runtime::run(&config, &mut ()).unwrap_or_else(|e| panic!("{e}\n{text}"));
    let metrics = RunMetrics::compute(&output, &config).expect("metrics");
    (config, output, metrics)
}

/// The error of parsing `text` (it must not parse), as a string.
pub fn parse_error(text: &str) -> String {
    match Config::from_toml(text, "inline") {
        Ok(config) => panic!("parsed, but should not have: {config:?}"),
        Err(e) => e.to_string(),
    }
}
