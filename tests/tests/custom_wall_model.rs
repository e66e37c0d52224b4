//! A wall representation registered outside the framework (M-space walls whose segment
//! covariance is inflated by a factor from its settings) is selected by name and by a table
//! with its settings from a TOML string, and the EKF maps walls with it.

mod common;

use std::collections::BTreeMap;
use std::sync::Mutex;

use serde::{Deserialize, Serialize};
use slam_core::{DynMeasurementModel, Error, Pose2};
use slam_runtime::frontend::WallModel;
use slam_runtime::{RunMetrics, RunOutput};
use slam_sensors::extract::ExtractedSegment;

use common::{TempWorld, run_toml, short_office};

const NAME: &str = "test-inflated-mspace";

/// Segments turned into observations, by the bits of the factor they were inflated with
/// (each test uses a factor of its own, so that tests running at once do not mix).
static CALLS: Mutex<BTreeMap<u64, usize>> = Mutex::new(BTreeMap::new());

fn calls(factor: f64) -> usize {
    CALLS
        .lock()
        .unwrap()
        .get(&factor.to_bits())
        .copied()
        .unwrap_or(0)
}

/// M-space walls whose line covariance and end deviations are multiplied by `factor`
/// (deviations; the covariance by its square).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct InflatedMspaceWalls {
    factor: f64,
}

impl Default for InflatedMspaceWalls {
    fn default() -> Self {
        InflatedMspaceWalls { factor: 1.0 }
    }
}

#[typetag::serde(name = "test-inflated-mspace")]
impl WallModel for InflatedMspaceWalls {
    fn observation(
        &self,
        segment: &ExtractedSegment,
        sigma_range: f64,
    ) -> slam_core::Result<Box<dyn DynMeasurementModel>> {
        let f = self.factor;
        if !(f.is_finite() && f > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "{NAME}: factor must be positive, got {f}"
            )));
        }
        *CALLS.lock().unwrap().entry(f.to_bits()).or_default() += 1;
        let mut segment = segment.clone();
        segment.cov *= f * f;
        segment.end_spacing = segment.end_spacing.map(|s| s * f);
        Ok(Box::new(segment.to_observation(sigma_range * f)?))
    }
}

fn run_walls(world: &TempWorld, frontend: &str) -> (RunOutput, RunMetrics) {
    let text = format!(
        "{}\n[estimator]\ntype = \"ekf\"\n[frontend]\ntype = \"features\"\n{frontend}\n",
        world.data_table(2)
    );
    let (_, output, metrics) = run_toml(&text);
    (output, metrics)
}

/// Confirmed walls (M-space dimension above 0) of a run.
fn mapped_walls(metrics: &RunMetrics) -> usize {
    metrics.features.get("wall").map_or(0, |by_dim| {
        by_dim
            .iter()
            .filter(|&(&dim, _)| dim > 0)
            .map(|(_, n)| n)
            .sum()
    })
}

fn poses(output: &RunOutput) -> Vec<Pose2> {
    output.record.estimates.iter().map(|r| r.pose).collect()
}

#[test]
fn by_name_it_maps_the_walls_as_mspace_does() {
    let world = short_office(8.0);
    let (output, metrics) = run_walls(&world, &format!("wall_representation = \"{NAME}\""));
    // Every extracted segment went through it, with the default factor 1.
    let walls = output.frontend["walls"];
    assert!(walls > 20, "{:?}", output.frontend);
    assert_eq!(calls(1.0), walls + output.frontend["dropped"]);
    assert!(mapped_walls(&metrics) >= 3, "{:?}", metrics.features);
    let error = metrics.map_error.as_ref().expect("a map error");
    let (n, rms) = error.by_type["wall"];
    assert!(n >= 3 && rms < 0.1, "{error:?}");
    // Factor 1 is the built-in representation, bit for bit.
    let (mspace, mspace_metrics) = run_walls(&world, "wall_representation = \"mspace\"");
    assert_eq!(output.frontend, mspace.frontend);
    assert_eq!(metrics.features, mspace_metrics.features);
    assert_eq!(poses(&output), poses(&mspace));
}

#[test]
fn a_table_passes_its_settings() {
    let world = short_office(8.0);
    let factor = 2.0;
    let (output, metrics) = run_walls(
        &world,
        &format!("[frontend.wall_representation]\ntype = \"{NAME}\"\nfactor = {factor:?}\n"),
    );
    let walls = output.frontend["walls"];
    assert!(walls > 20, "{:?}", output.frontend);
    assert_eq!(calls(factor), walls + output.frontend["dropped"]);
    assert!(mapped_walls(&metrics) >= 3, "{:?}", metrics.features);
    let (n, rms) = metrics.map_error.as_ref().expect("a map error").by_type["wall"];
    assert!(n >= 3 && rms < 0.1, "{n} walls, {rms} m");
    // Doubled deviations: the wall innovations are small for their covariance. The run's
    // NIS (walls and poles) falls well below the uninflated run's.
    let (_, plain) = run_walls(&world, "wall_representation = \"mspace\"");
    let (inflated, plain) = (
        metrics.nis.expect("NIS of the inflated walls"),
        plain.nis.expect("NIS of the plain walls"),
    );
    assert!(inflated.count > 0 && plain.count > 0);
    assert!(
        inflated.mean_per_dof < 0.6 * plain.mean_per_dof,
        "NIS per dof {} inflated, {} plain",
        inflated.mean_per_dof,
        plain.mean_per_dof
    );
}

#[test]
fn a_factor_it_refuses_maps_no_wall() {
    // The representation has no `validate` of its own: a bad factor shows up as segments the
    // front-end drops (or, were it checked up front, as an error naming the factor).
    let world = short_office(4.0);
    let text = format!(
        "{}\n[estimator]\ntype = \"ekf\"\n[frontend]\nwall_representation = \
         {{ type = \"{NAME}\", factor = -1.0 }}\n",
        world.data_table(2)
    );
    let config = slam_runtime::Config::from_toml(&text, "inline").unwrap();
    match slam_runtime::run(&config, &mut ()) {
        Ok(output) => {
            assert_eq!(output.frontend["walls"], 0, "{:?}", output.frontend);
            assert!(output.frontend["dropped"] > 0, "{:?}", output.frontend);
            assert!(
                !output
                    .estimator
                    .map()
                    .iter()
                    .any(|(_, f)| f.kind() == "wall")
            );
        }
        Err(error) => assert!(error.to_string().contains("factor"), "{error}"),
    }
    let error = common::parse_error(&format!(
        "[frontend.wall_representation]\ntype = \"{NAME}\"\nfactr = 2.0\n"
    ));
    assert!(error.contains("factr"), "{error}");
}
