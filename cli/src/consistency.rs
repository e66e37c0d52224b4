//! `slam consistency`: the statistical consistency of the estimator over many seeded runs of
//! a simulated world, for the M-space walls and for the naive endpoint walls (the M-space
//! paper's Fig. 1 claim, measured). The study itself (the runs, the average NEES and its 95%
//! band) is [`slam_runtime::study`]; this command takes the arguments, shows the progress,
//! prints the summary and writes `consistency.json`, `consistency.csv` and `consistency.png`.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard, PoisonError};

use slam_runtime::Config;
use slam_runtime::study::{ConsistencyReport, StudyProgress, consistency_study};

use crate::error::{CliError, Result};
use crate::outputs::{create_dir, write_json, write_text};
use crate::plot::{LineChart, Series, palette};

/// Arguments of `slam consistency`.
#[derive(Debug, clap::Args)]
pub struct ConsistencyArgs {
    /// Configuration for every run (TOML); its data must be simulated (sim or world:FILE).
    pub config: Option<PathBuf>,
    /// Number of seeded runs per representation.
    #[arg(long, default_value_t = 50)]
    pub runs: usize,
    /// Seed of the first run (the others follow).
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Simulated data: sim or world:FILE (overrides the config).
    #[arg(long)]
    pub data: Option<String>,
    /// Wall representations to compare: registered names of the `features` front-end's
    /// `wall_representation` (`mspace`; `endpoints`, the naive walls of slam-examples).
    #[arg(long, value_delimiter = ',', default_value = "mspace,endpoints")]
    pub walls: Vec<String>,
    /// Output folder (consistency.json, consistency.csv, consistency.png).
    #[arg(long, default_value = "consistency")]
    pub out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// The progress bar of `slam consistency`: one bar per representation, hidden with
/// `--quiet`.
struct Bar {
    quiet: bool,
    bar: Mutex<indicatif::ProgressBar>,
}

impl Bar {
    fn new(quiet: bool) -> Self {
        Bar {
            quiet,
            bar: Mutex::new(indicatif::ProgressBar::hidden()),
        }
    }

    fn bar(&self) -> MutexGuard<'_, indicatif::ProgressBar> {
        // A bar is only drawn: one left by a panicking thread is still fine to use.
        self.bar.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl StudyProgress for Bar {
    fn start(&self, _name: &str, runs: usize) {
        *self.bar() = if self.quiet {
            indicatif::ProgressBar::hidden()
        } else {
            indicatif::ProgressBar::new(runs as u64)
        };
    }

    fn run_done(&self) {
        self.bar().inc(1);
    }

    fn finish(&self) {
        self.bar().finish_and_clear();
    }
}

/// Runs the study for every representation of `walls` ([`consistency_study`]), with a
/// progress bar unless `quiet`.
pub fn run_study(
    config: &Config,
    walls: &[String],
    runs: usize,
    first_seed: u64,
    quiet: bool,
) -> Result<ConsistencyReport> {
    if runs == 0 {
        return Err(CliError::Usage("--runs must be at least 1".into()));
    }
    Ok(consistency_study(
        config,
        walls,
        runs,
        first_seed,
        &Bar::new(quiet),
    )?)
}

/// Runs `slam consistency`.
pub fn run(args: &ConsistencyArgs) -> Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if let Some(data) = &args.data {
        config.data.spec = data.clone();
    }
    config.output.plots = false;
    let report = run_study(&config, &args.walls, args.runs, args.first_seed, args.quiet)?;
    for (name, study) in &report.representations {
        if study.runs_ok == 0 {
            let reason = study
                .failures
                .first()
                .map_or("no run".to_string(), |(seed, e)| {
                    format!("seed {seed}: {e}")
                });
            return Err(CliError::Usage(format!(
                "every {name} run failed; the first: {reason}"
            )));
        }
        for (seed, error) in &study.failures {
            eprintln!("slam consistency: {name} run with seed {seed} failed: {error}");
        }
    }
    let dir = &args.out;
    create_dir(dir)?;
    write_json(dir, "consistency.json", &report)?;
    write_text(dir, "consistency.csv", &csv(&report))?;
    chart(&report).save(&dir.join("consistency.png"))?;
    for (name, study) in &report.representations {
        println!(
            "{name}: average pose NEES of {} runs inside the 95% band [{:.2}, {:.2}] at {:.1}% of {} steps \
             ({:.1}% above, {:.1}% below); mean {:.2}, median {:.2}; ATE {:.3} m, map error {:.3} m; {} failed runs",
            study.runs_ok,
            report.band_95.0,
            report.band_95.1,
            100.0 * study.fraction_within_band,
            study.steps,
            100.0 * study.fraction_above_band,
            100.0 * study.fraction_below_band,
            study.mean_nees,
            study.median_nees,
            study.ate_rmse_mean_m,
            study.map_error_mean_m,
            study.failures.len()
        );
    }
    println!("report in {}", dir.display());
    Ok(())
}

/// `time,<representation>...` rows of the average NEES.
fn csv(report: &ConsistencyReport) -> String {
    let names: Vec<&String> = report.representations.keys().collect();
    let mut rows: BTreeMap<u64, (f64, Vec<String>)> = BTreeMap::new();
    for (k, study) in report.representations.values().enumerate() {
        for &(time, nees) in &study.series {
            let row = rows
                .entry(time.to_bits())
                .or_insert_with(|| (time, vec![String::new(); names.len()]));
            row.1[k] = nees.to_string();
        }
    }
    let mut text = format!(
        "time,{}\n",
        names
            .iter()
            .map(|n| n.as_str())
            .collect::<Vec<_>>()
            .join(",")
    );
    let mut sorted: Vec<_> = rows.into_values().collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (time, values) in sorted {
        text.push_str(&format!("{time},{}\n", values.join(",")));
    }
    text
}

fn chart(report: &ConsistencyReport) -> LineChart {
    let colours = [
        palette::WALL,
        palette::PATH,
        palette::POLE,
        palette::CEILING,
    ];
    LineChart {
        title: format!(
            "average robot-pose NEES over {} runs (95% band shaded)",
            report.runs
        ),
        x_label: "time [s]".into(),
        y_label: "average NEES (3 dof)".into(),
        series: report
            .representations
            .iter()
            .zip(colours.iter().cycle())
            .map(|((name, study), colour)| Series {
                label: format!(
                    "{name}: {:.0}% of steps in band",
                    100.0 * study.fraction_within_band
                ),
                colour: *colour,
                points: study.series.clone(),
            })
            .collect(),
        band: Some(report.band_95),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default world driven along the corridor and around the pillar room, without the
    /// camera.
    fn short_world() -> PathBuf {
        let mut world = slam_sensors::sim::World::default_world();
        world.camera = None;
        world.robot.waypoints.truncate(9);
        let path = std::env::temp_dir().join(format!(
            "slam-cli-consistency-{}-world.toml",
            std::process::id()
        ));
        std::fs::write(&path, toml::to_string(&world).unwrap()).unwrap();
        path
    }

    #[test]
    fn mspace_walls_are_more_consistent_than_endpoint_walls() {
        let world = short_world();
        let mut config = Config::default();
        config.data.spec = format!("world:{}", world.display());
        let walls = ["mspace".to_string(), "endpoints".to_string()];
        let report = run_study(&config, &walls, 3, 1, true).unwrap();
        let mspace = &report.representations["mspace"];
        let endpoints = &report.representations["endpoints"];
        assert_eq!((mspace.runs_ok, endpoints.runs_ok), (3, 3));
        assert!(mspace.steps > 500, "{} steps", mspace.steps);
        // The paper's Fig. 1 claim: the naive representation is overconfident and less
        // accurate on the same runs.
        assert!(
            endpoints.fraction_above_band > 0.4 && mspace.fraction_above_band < 0.1,
            "steps above the band: {} against {}",
            mspace.fraction_above_band,
            endpoints.fraction_above_band
        );
        assert!(
            4.0 * mspace.mean_nees < endpoints.mean_nees,
            "mean NEES {} against {}",
            mspace.mean_nees,
            endpoints.mean_nees
        );
        assert!(
            mspace.ate_rmse_mean_m < endpoints.ate_rmse_mean_m,
            "ATE {} against {}",
            mspace.ate_rmse_mean_m,
            endpoints.ate_rmse_mean_m
        );
        assert!(mspace.fraction_within_band > 0.5, "{mspace:?}");
        std::fs::remove_file(&world).unwrap();
    }
}
