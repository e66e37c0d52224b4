//! A front-end registered outside the framework (it passes on the observations the data give,
//! from one event in `every`, and counts them) runs from a TOML string by its registered name,
//! and the EKF maps the rb2d landmarks through it.

mod common;

use serde::{Deserialize, Serialize};
use slam_core::Observation;
use slam_runtime::frontend::{FrontendCounts, SensorInfo};
use slam_runtime::{Frontend, FrontendConfig, RuntimeError};
use slam_sensors::Event;

use common::{TempWorld, parse_error, run_toml, short_rb2d_circle};

const NAME: &str = "test-given-observations";

/// The settings: pass the observations of one `Observations` event in `every`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct GivenObservationsConfig {
    every: usize,
}

impl Default for GivenObservationsConfig {
    fn default() -> Self {
        GivenObservationsConfig { every: 1 }
    }
}

#[typetag::serde(name = "test-given-observations")]
impl FrontendConfig for GivenObservationsConfig {
    fn validate(&self) -> slam_runtime::Result<()> {
        if self.every == 0 {
            return Err(RuntimeError::setting(
                "frontend",
                "test-given-observations: every must be at least 1",
            ));
        }
        Ok(())
    }

    fn build(&self, _: &SensorInfo) -> slam_runtime::Result<Box<dyn Frontend>> {
        Ok(Box::new(GivenObservations {
            every: self.every,
            events: 0,
            passed: 0,
            held_back: 0,
        }))
    }
}

struct GivenObservations {
    every: usize,
    events: usize,
    passed: usize,
    held_back: usize,
}

impl Frontend for GivenObservations {
    fn observe(&mut self, event: &Event) -> slam_runtime::Result<Vec<Observation>> {
        let Event::Observations(given) = event else {
            return Ok(Vec::new());
        };
        self.events += 1;
        if !(self.events - 1).is_multiple_of(self.every) {
            self.held_back += given.len();
            return Ok(Vec::new());
        }
        self.passed += given.len();
        Ok(given.clone())
    }

    fn counts(&self) -> FrontendCounts {
        [
            ("events", self.events),
            ("passed", self.passed),
            ("held_back", self.held_back),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }
}

fn config_text(world: &TempWorld, frontend: &str) -> String {
    format!(
        "{}\n[estimator]\ntype = \"ekf\"\n[frontend]\ntype = \"{NAME}\"\n{frontend}\n",
        world.data_table(5)
    )
}

#[test]
fn its_counts_are_the_runs_front_end_counts() {
    let world = short_rb2d_circle(80);
    let batches = world.observation_batches(5);
    let total: usize = batches.iter().map(Vec::len).sum();
    let kept: usize = batches.iter().step_by(3).map(Vec::len).sum();
    let (config, output, metrics) = run_toml(&config_text(&world, "every = 3"));
    // The table's `type` chose it over the EKF's default front-end, with its settings.
    let table = toml::Value::try_from(&config.frontend).unwrap();
    assert_eq!(table["type"].as_str(), Some(NAME));
    assert_eq!(table["every"].as_integer(), Some(3));
    let expected = FrontendCounts::from([
        ("events".to_string(), batches.len()),
        ("held_back".to_string(), total - kept),
        ("passed".to_string(), kept),
    ]);
    assert_eq!(output.frontend, expected);
    assert_eq!(metrics.frontend, expected);
    // What it passed on is what the EKF was given.
    let u = metrics.updates;
    assert_eq!(u.associated + u.new_features + u.rejected, kept, "{u:?}");
    assert!(kept < total);
}

#[test]
fn the_ekf_maps_the_rb2d_landmarks_through_it() {
    let world = short_rb2d_circle(120);
    let batches = world.observation_batches(5);
    let sighted: std::collections::BTreeSet<u64> =
        batches.iter().flatten().map(|id| id.unwrap()).collect();
    let (_, output, metrics) = run_toml(&config_text(&world, ""));
    let total: usize = batches.iter().map(Vec::len).sum();
    assert_eq!(output.frontend["passed"], total);
    assert_eq!(output.frontend["held_back"], 0);
    let error = metrics
        .map_error
        .as_ref()
        .unwrap_or_else(|| panic!("no map error: {:?}", metrics.unavailable));
    // Known association: the EKF confirms nearly every landmark it saw, by its data id.
    assert!(
        error.count + 2 >= sighted.len(),
        "{} of {} landmarks mapped",
        error.count,
        sighted.len()
    );
    assert!(error.by_landmark.keys().all(|id| sighted.contains(id)));
    assert!(error.rms_m < 0.3, "{error:?}");
    let points = &metrics.features["point"];
    assert_eq!(points.get(&2), Some(&error.count), "{points:?}");
    assert!(
        metrics.ate_rmse_m.unwrap() < 0.3,
        "{:?}",
        metrics.ate_rmse_m
    );
}

#[test]
fn its_settings_are_checked_and_unknown_names_are_errors() {
    let world = short_rb2d_circle(5);
    let config = slam_runtime::Config::from_toml(&config_text(&world, "every = 0"), "inline")
        .expect("parses; checked when run");
    let error = slam_runtime::run(&config, &mut ())
        .err()
        .expect("the run fails");
    assert!(error.to_string().contains("every must be"), "{error}");
    let error = parse_error(&config_text(&world, "evry = 2"));
    assert!(error.contains("evry"), "{error}");
    let error = parse_error("[frontend]\ntype = \"no-such-frontend\"\n");
    assert!(error.contains("no-such-frontend"), "{error}");
}
