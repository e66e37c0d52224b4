//! A post-processing stage registered outside the framework (it tallies the scans and their
//! returns and reports the final pose) runs from `[[postprocess]]` tables of a TOML string,
//! and its figures and summary reach the run's output and metrics.

mod common;

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::Vector2;
use slam_core::{Estimator, FeatureMap, Pose2, UpdateReport};
use slam_runtime::postprocess::FinishedRun;
use slam_runtime::{
    Observer, PostProcess, PostProcessConfig, PostProcessOutput, RunOutput, RuntimeError,
};
use slam_sensors::{Event, TimedEvent};

use common::{TempWorld, parse_error, run_toml, short_office};

/// The settings: the stage's output name, and the range within which returns are counted, m
/// (0: all).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct ScanTallyConfig {
    name: String,
    max_range: f64,
}

impl Default for ScanTallyConfig {
    fn default() -> Self {
        ScanTallyConfig {
            name: "scan-tally".into(),
            max_range: 0.0,
        }
    }
}

#[typetag::serde(name = "test-scan-tally")]
impl PostProcessConfig for ScanTallyConfig {
    fn validate(&self) -> slam_runtime::Result<()> {
        if !(self.max_range.is_finite() && self.max_range >= 0.0) {
            return Err(RuntimeError::setting(
                "postprocess",
                format!(
                    "test-scan-tally max_range must be 0 or positive, got {}",
                    self.max_range
                ),
            ));
        }
        Ok(())
    }

    fn build(&self) -> slam_runtime::Result<Box<dyn PostProcess>> {
        Ok(Box::new(ScanTally {
            config: self.clone(),
            scans: 0,
            returns: 0,
            steps: 0,
            scan_positions: Vec::new(),
        }))
    }
}

struct ScanTally {
    config: ScanTallyConfig,
    scans: usize,
    returns: usize,
    steps: usize,
    /// Where the estimate was at each scan.
    scan_positions: Vec<Vector2<f64>>,
}

impl Observer for ScanTally {
    fn event(
        &mut self,
        event: &TimedEvent,
        _: Option<&UpdateReport>,
        estimator: &dyn Estimator<Pose2>,
    ) -> slam_runtime::Result<()> {
        if let Event::Scan { scan, .. } = &event.event {
            self.scans += 1;
            self.returns += count_returns(scan, self.config.max_range);
            self.scan_positions.push(estimator.pose().translation());
        }
        Ok(())
    }

    fn step_end(&mut self, _: f64, _: &dyn Estimator<Pose2>) -> slam_runtime::Result<()> {
        self.steps += 1;
        Ok(())
    }
}

impl PostProcess for ScanTally {
    fn finish(self: Box<Self>, run: &FinishedRun<'_>) -> slam_runtime::Result<PostProcessOutput> {
        let pose = run.estimator.pose();
        let summary = format!(
            "{}: {} scans, {} returns, {} steps; final pose ({:.3}, {:.3}, {:.3})",
            self.config.name, self.scans, self.returns, self.steps, pose.x, pose.y, pose.theta
        );
        Ok(PostProcessOutput {
            name: self.config.name.clone(),
            map: FeatureMap::new(),
            points: self.scan_positions,
            path: run.map_poses(),
            metrics: serde_json::json!({
                "scans": self.scans,
                "returns": self.returns,
                "steps": self.steps,
                "final_pose": [pose.x, pose.y, pose.theta],
            }),
            summary,
        })
    }
}

/// Valid returns of `scan` within `max_range` (0: all).
fn count_returns(scan: &slam_sensors::LaserScan, max_range: f64) -> usize {
    scan.points()
        .iter()
        .filter(|p| max_range <= 0.0 || p.range <= max_range)
        .count()
}

fn config_text(world: &TempWorld, stages: &str) -> String {
    format!(
        "{}\n[estimator]\ntype = \"dead-reckoning\"\n{stages}\n",
        world.data_table(4)
    )
}

fn stage<'a>(output: &'a RunOutput, name: &str) -> &'a PostProcessOutput {
    output
        .postprocess
        .iter()
        .find(|s| s.name == name)
        .unwrap_or_else(|| panic!("no stage {name}"))
}

#[test]
fn its_figures_and_summary_come_from_the_run() {
    let world = short_office(6.0);
    let (config, output, metrics) = run_toml(&config_text(
        &world,
        "[[postprocess]]\ntype = \"test-scan-tally\"\n\n\
         [[postprocess]]\ntype = \"test-scan-tally\"\nname = \"near-tally\"\nmax_range = 2.5\n",
    ));
    assert_eq!(config.postprocess.len(), 2);
    // The scans and returns of the simulation, counted here independently.
    let scans: Vec<_> = world
        .events(4)
        .into_iter()
        .filter_map(|e| match e {
            Event::Scan { scan, .. } => Some(scan),
            _ => None,
        })
        .collect();
    let returns: usize = scans.iter().map(|s| count_returns(s, 0.0)).sum();
    let near: usize = scans.iter().map(|s| count_returns(s, 2.5)).sum();
    assert!(scans.len() > 20 && 0 < near && near < returns);
    let pose = output.estimator.pose();
    assert_eq!(Some(pose), output.record.estimates.last().map(|r| r.pose));
    let steps = output.record.estimates.len();
    let names: Vec<&str> = output.postprocess.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["scan-tally", "near-tally"]);
    for (name, counted) in [("scan-tally", returns), ("near-tally", near)] {
        let s = stage(&output, name);
        let expected = serde_json::json!({
            "scans": scans.len(),
            "returns": counted,
            "steps": steps,
            "final_pose": [pose.x, pose.y, pose.theta],
        });
        assert_eq!(s.metrics, expected, "{name}");
        assert_eq!(metrics.postprocess[name], expected, "{name}");
        assert!(
            s.summary
                .starts_with(&format!("{name}: {} scans, {counted} returns", scans.len())),
            "{}",
            s.summary
        );
        assert_eq!(s.points.len(), scans.len());
        assert_eq!(s.path.len(), steps);
        assert!(s.map.is_empty());
    }
}

#[test]
fn its_settings_are_checked_and_unknown_stages_are_errors() {
    let world = short_office(3.0);
    let text = config_text(
        &world,
        "[[postprocess]]\ntype = \"test-scan-tally\"\nmax_range = -1.0\n",
    );
    let config = slam_runtime::Config::from_toml(&text, "inline").unwrap();
    let error = slam_runtime::run(&config, &mut ())
        .err()
        .expect("the run fails");
    assert!(error.to_string().contains("max_range"), "{error}");
    let error = parse_error("[[postprocess]]\ntype = \"test-scan-tally\"\ncolour = 2\n");
    assert!(error.contains("colour"), "{error}");
    let error = parse_error("[[postprocess]]\ntype = \"no-such-stage\"\n");
    assert!(error.contains("no-such-stage"), "{error}");
}
