//! `slam bench`: runs the configured estimator several times without writing outputs and
//! prints what a run costs: time per step (stepping only, and the process's CPU time), the
//! peak resident memory and the state size (pose rows plus the map's M-space rows).
//!
//! Absolute times on a shared machine drift; compare two programs or two commits only in one
//! command, interleaved (BENCHMARKS.md, `scripts/ab-*.sh`).

use std::path::PathBuf;

use clap::Args;
use serde::Serialize;
use slam_core::{Estimator, Pose2};
use slam_runtime::{Observer, run};

use crate::error::Result;
use crate::run::{RunArgs, config_of};

/// Arguments of `slam bench`.
#[derive(Args, Debug, Clone)]
pub struct BenchArgs {
    /// Configuration file (TOML), as for `slam run`.
    pub config: Option<PathBuf>,
    /// Data spec, as for `slam run --data`.
    #[arg(long)]
    pub data: Option<String>,
    /// Simulation (and odometry noise) seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// How many times to run (the summary gives the median).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Print the measurements as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
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

/// Runs `slam bench` and returns what it prints.
pub fn run_bench(args: &BenchArgs) -> Result<String> {
    let report = measure(args)?;
    if args.json {
        return Ok(serde_json::to_string_pretty(&report).unwrap_or_default());
    }
    Ok(table(&report))
}

/// Runs the configured estimator `args.runs` times and measures each run.
pub fn measure(args: &BenchArgs) -> Result<BenchReport> {
    let run_args = RunArgs {
        config: args.config.clone(),
        data: args.data.clone(),
        out: None,
        seed: args.seed,
        quiet: true,
        grid: false,
        g2o: false,
        mcap: false,
    };
    let config = config_of(&run_args)?;
    let mut runs = Vec::with_capacity(args.runs);
    let mut estimator = String::new();
    for _ in 0..args.runs.max(1) {
        let cpu_before = process_cpu_seconds();
        let mut observer = StateSize::default();
        let output = run(&config, &mut observer)?;
        let cpu_after = process_cpu_seconds();
        estimator = output.estimator.name().to_string();
        let steps = observer.steps;
        runs.push(BenchRun {
            steps,
            stepping_s: output.wall_time_s,
            per_step_ms: 1e3 * output.wall_time_s / steps.max(1) as f64,
            cpu_s: cpu_before.zip(cpu_after).map(|(a, b)| b - a),
            state_rows_end: state_rows(output.estimator.as_ref()),
            state_rows_max: observer.max_rows,
            features_end: output.estimator.map().len(),
        });
    }
    let mut per_step: Vec<f64> = runs.iter().map(|r| r.per_step_ms).collect();
    per_step.sort_by(f64::total_cmp);
    Ok(BenchReport {
        estimator,
        data: config.data.spec.clone(),
        median_per_step_ms: per_step[per_step.len() / 2],
        runs,
        peak_resident_mb: peak_resident_mb(),
    })
}

/// The report as a table.
fn table(report: &BenchReport) -> String {
    let mut text = format!(
        "slam bench: {} on {}, {} run(s)\n run   steps   stepping s   ms/step    CPU s   state rows (end / max)   features\n",
        report.estimator,
        report.data,
        report.runs.len()
    );
    for (k, r) in report.runs.iter().enumerate() {
        let cpu = r.cpu_s.map_or("-".to_string(), |c| format!("{c:.3}"));
        text += &format!(
            "{:>4} {:>7} {:>12.3} {:>9.4} {:>8} {:>12} / {:<9} {:>8}\n",
            k + 1,
            r.steps,
            r.stepping_s,
            r.per_step_ms,
            cpu,
            r.state_rows_end,
            r.state_rows_max,
            r.features_end
        );
    }
    let memory = report
        .peak_resident_mb
        .map_or("unavailable".to_string(), |m| format!("{m:.1} MB"));
    text += &format!(
        "median {:.4} ms per step (stepping only); peak resident memory {memory}",
        report.median_per_step_ms
    );
    text
}

/// Counts steps and the largest state.
#[derive(Default)]
struct StateSize {
    steps: usize,
    max_rows: usize,
}

impl Observer for StateSize {
    fn step_end(
        &mut self,
        _time: f64,
        estimator: &dyn Estimator<Pose2>,
    ) -> slam_runtime::Result<()> {
        self.steps += 1;
        self.max_rows = self.max_rows.max(state_rows(estimator));
        Ok(())
    }
}

/// Pose rows plus the map's M-space rows (each feature's own rows and each shared block once).
fn state_rows(estimator: &dyn Estimator<Pose2>) -> usize {
    let map = estimator.map();
    let own: usize = map.iter().map(|(_, feature)| feature.mspace_dim()).sum();
    let shared: usize = map
        .shared_blocks()
        .map(|(_, block)| block.value.dim())
        .sum();
    3 + own + shared
}

/// CPU seconds (user and system) of this process so far, from `/proc/self/stat` (Linux).
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let after = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = after.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    // Clock ticks are 100 per second on every Linux configuration Rust targets.
    Some((utime + stime) / 100.0)
}

/// Peak resident set size of this process, MB, from `/proc/self/status` (Linux).
fn peak_resident_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bench_of_the_circle_world_counts_its_steps_and_state() {
        let world = concat!(env!("CARGO_MANIFEST_DIR"), "/../worlds/rb2d-circle.toml");
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("bench.toml");
        // The first 300 events: about 100 steps (motion, observations, true pose).
        std::fs::write(&config, "[data]\nmax_events = 300\n").unwrap();
        let args = BenchArgs {
            config: Some(config),
            data: Some(format!("world:{world}")),
            seed: Some(1),
            runs: 2,
            json: false,
        };
        let report = measure(&args).unwrap();
        assert_eq!(report.runs.len(), 2);
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
        }
        let text = table(&report);
        assert!(text.contains("ekf on world:"), "{text}");
        assert!(text.contains("ms per step"), "{text}");
    }
}
