//! What a run costs, measured (`slam bench`): the configured run repeated without outputs,
//! with the time per step (stepping only, and the process's CPU time), the peak resident
//! memory and the state size (pose rows plus the map's M-space rows).
//!
//! What the system reports of the process (CPU time, peak memory) comes from a
//! [`ProcessMeter`] the caller gives; the `slam` command reads Linux's `/proc/self`.
//! Absolute times on a shared machine drift; compare two programs or two commits only in one
//! command, interleaved (BENCHMARKS.md, `scripts/ab-*.sh`).

use serde::Serialize;
use slam_core::{Estimator, Pose2};

use crate::config::Config;
use crate::error::Result;
use crate::session::Observer;

/// What the system reports of the running process, where it does.
pub trait ProcessMeter {
    /// CPU seconds (user and system, all threads) of the process so far.
    fn cpu_seconds(&self) -> Option<f64>;
    /// Peak resident memory of the process so far, MB.
    fn peak_resident_mb(&self) -> Option<f64>;
}

/// A system that reports nothing.
impl ProcessMeter for () {
    fn cpu_seconds(&self) -> Option<f64> {
        None
    }

    fn peak_resident_mb(&self) -> Option<f64> {
        None
    }
}

/// What one run cost.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRun {
    /// Time steps.
    pub steps: usize,
    /// Seconds spent stepping (front-end and estimator; reading the data not included).
    pub stepping_s: f64,
    /// Milliseconds per step, stepping only.
    pub per_step_ms: f64,
    /// CPU seconds of the process during the run (all threads, data reading included), when
    /// the system reports it.
    pub cpu_s: Option<f64>,
    /// State rows at the end: 3 pose rows and the map's M-space rows.
    pub state_rows_end: usize,
    /// Largest state during the run.
    pub state_rows_max: usize,
    /// Map features at the end.
    pub features_end: usize,
}

/// The measurements of `slam bench`.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    /// The estimator's name.
    pub estimator: String,
    /// The data spec.
    pub data: String,
    /// Each run.
    pub runs: Vec<BenchRun>,
    /// Median of the runs' milliseconds per step.
    pub median_per_step_ms: f64,
    /// Peak resident memory of the process, MB (all runs), when the system reports it.
    pub peak_resident_mb: Option<f64>,
}

/// Runs `config` `runs` times (at least once), without outputs, and measures each run;
/// `meter` reads the process's CPU time around each run and its peak memory at the end.
pub fn measure(config: &Config, runs: usize, meter: &dyn ProcessMeter) -> Result<BenchReport> {
    let mut measured = Vec::with_capacity(runs);
    let mut estimator = String::new();
    for _ in 0..runs.max(1) {
        let cpu_before = meter.cpu_seconds();
        let mut observer = StateSize::default();
        let output = crate::run::run(config, &mut observer)?;
        let cpu_after = meter.cpu_seconds();
        estimator = output.estimator.name().to_string();
        let steps = observer.steps;
        measured.push(BenchRun {
            steps,
            stepping_s: output.wall_time_s,
            per_step_ms: 1e3 * output.wall_time_s / steps.max(1) as f64,
            cpu_s: cpu_before.zip(cpu_after).map(|(a, b)| b - a),
            state_rows_end: state_rows(output.estimator.as_ref()),
            state_rows_max: observer.max_rows,
            features_end: output.estimator.map().len(),
        });
    }
    let mut per_step: Vec<f64> = measured.iter().map(|r| r.per_step_ms).collect();
    per_step.sort_by(f64::total_cmp);
    Ok(BenchReport {
        estimator,
        data: config.data.spec.clone(),
        median_per_step_ms: per_step[per_step.len() / 2],
        runs: measured,
        peak_resident_mb: meter.peak_resident_mb(),
    })
}

/// The [`Observer`] that counts the time steps of a run and its largest state.
#[derive(Clone, Debug, Default)]
pub struct StateSize {
    /// Time steps ended.
    pub steps: usize,
    /// Largest [`state_rows`] at a step's end.
    pub max_rows: usize,
}

impl Observer for StateSize {
    fn step_end(&mut self, _time: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        self.steps += 1;
        self.max_rows = self.max_rows.max(state_rows(estimator));
        Ok(())
    }
}

/// The state size of an estimator: 3 pose rows plus the map's M-space rows (each feature's own
/// rows and each shared block once).
pub fn state_rows(estimator: &dyn Estimator<Pose2>) -> usize {
    let map = estimator.map();
    let own: usize = map.iter().map(|(_, feature)| feature.mspace_dim()).sum();
    let shared: usize = map
        .shared_blocks()
        .map(|(_, block)| block.value.dim())
        .sum();
    3 + own + shared
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bench_of_the_circle_world_counts_its_steps_and_state() {
        let world = concat!(env!("CARGO_MANIFEST_DIR"), "/../worlds/rb2d-circle.toml");
        // The first 300 events: about 100 steps (motion, observations, true pose).
        let text = format!("[data]\nspec = \"world:{world}\"\nseed = 1\nmax_events = 300\n");
        let config = Config::from_toml(&text, "bench").unwrap();
        let report = measure(&config, 2, &()).unwrap();
        assert_eq!(report.runs.len(), 2);
        assert_eq!(report.estimator, "ekf");
        for run in &report.runs {
            // Point landmarks of 2 rows each; a tenth of the circle sees many of the 50.
            assert!((90..=150).contains(&run.steps), "{} steps", run.steps);
            assert_eq!(run.state_rows_end, 3 + 2 * run.features_end);
            assert!(
                (10..=50).contains(&run.features_end),
                "{}",
                run.features_end
            );
            assert!(run.state_rows_max >= run.state_rows_end);
            assert!(run.per_step_ms > 0.0);
            assert_eq!(run.cpu_s, None);
        }
    }
}
