//! `slam bench`: runs the configured estimator several times without writing outputs and
//! prints what a run costs: time per step (stepping only, and the process's CPU time), the
//! peak resident memory and the state size (pose rows plus the map's M-space rows).
//!
//! Absolute times on a shared machine drift; compare two programs or two commits only in one
//! command, interleaved (BENCHMARKS.md, `scripts/ab-*.sh`).

use std::path::PathBuf;

use clap::Args;
use slam_runtime::bench::{self, BenchReport, ProcessMeter};

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

/// Runs `slam bench` and returns what it prints.
pub fn run_bench(args: &BenchArgs) -> Result<String> {
    let report = measure(args)?;
    if args.json {
        return Ok(serde_json::to_string_pretty(&report).unwrap_or_default());
    }
    Ok(table(&report))
}

/// Runs the configured estimator `args.runs` times and measures each run
/// ([`slam_runtime::bench::measure`], with the process read from `/proc/self`).
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
    Ok(bench::measure(&config, args.runs, &ProcSelf)?)
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

/// The process as Linux reports it in `/proc/self`.
struct ProcSelf;

impl ProcessMeter for ProcSelf {
    fn cpu_seconds(&self) -> Option<f64> {
        process_cpu_seconds()
    }

    fn peak_resident_mb(&self) -> Option<f64> {
        peak_resident_mb()
    }
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
    use slam_runtime::bench::BenchRun;

    #[test]
    fn the_table_names_the_estimator_the_data_and_the_time_per_step() {
        let run = BenchRun {
            steps: 100,
            stepping_s: 0.05,
            per_step_ms: 0.5,
            cpu_s: None,
            state_rows_end: 43,
            state_rows_max: 43,
            features_end: 20,
        };
        let report = BenchReport {
            estimator: "ekf".into(),
            data: "world:circle.toml".into(),
            runs: vec![run.clone(), run],
            median_per_step_ms: 0.5,
            peak_resident_mb: Some(12.5),
        };
        let text = table(&report);
        assert!(
            text.contains("ekf on world:circle.toml, 2 run(s)"),
            "{text}"
        );
        assert!(text.contains("median 0.5000 ms per step"), "{text}");
        assert!(text.contains("peak resident memory 12.5 MB"), "{text}");
        assert_eq!(text.lines().count(), 5, "{text}");
    }
}
