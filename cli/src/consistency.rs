//! `slam consistency`: the statistical consistency of the estimator over many seeded runs of
//! a simulated world, for the M-space walls and for the naive endpoint walls (the M-space
//! paper's Fig. 1 claim, measured).
//!
//! For `N` runs the average robot-pose NEES at a step is `1/N` times a chi-square variable
//! with `3N` degrees of freedom when the filter is consistent, so its two-sided 95% band is
//! `[chi2(0.025, 3N) / N, chi2(0.975, 3N) / N]` (Bar-Shalom, Li & Kirubarajan, ch. 5.4). The
//! report gives the fraction of steps whose average lies in the band.

use std::collections::BTreeMap;
use std::path::PathBuf;

use rayon::prelude::*;
use serde::Serialize;
use slam_core::chi2_quantile;

use slam_runtime::Config;
use slam_runtime::eval::{map_error_against_truth, pose_nees};

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

/// The outcome of one run.
struct RunOutcome {
    nees: Vec<(f64, f64)>,
    ate_rmse_m: Option<f64>,
    map_error_m: f64,
}

/// The study of one representation.
#[derive(Debug, Serialize)]
pub struct Study {
    /// Runs that finished.
    pub runs_ok: usize,
    /// Runs that stopped with an error, with the error.
    pub failures: Vec<(u64, String)>,
    /// Steps with a NEES in every finished run.
    pub steps: usize,
    /// Fraction of those steps whose average NEES lies in the 95% band.
    pub fraction_within_band: f64,
    /// Fraction of steps above the band (overconfident) and below it (pessimistic).
    pub fraction_above_band: f64,
    /// Fraction of steps below the band.
    pub fraction_below_band: f64,
    /// Mean over steps of the average NEES (3 when consistent).
    pub mean_nees: f64,
    /// Median over steps of the average NEES.
    pub median_nees: f64,
    /// Mean ATE over the runs (aligned, m).
    pub ate_rmse_mean_m: f64,
    /// Mean map error over the runs (m).
    pub map_error_mean_m: f64,
    /// Per run: `(seed, mean pose NEES, ATE m)`.
    pub per_run: Vec<(u64, f64, Option<f64>)>,
    /// `(time, average NEES)` per step.
    #[serde(skip)]
    pub series: Vec<(f64, f64)>,
}

/// The whole report.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Runs per representation.
    pub runs: usize,
    /// Seeds `first..first + runs`.
    pub first_seed: u64,
    /// The 95% band of the average NEES over `runs` runs.
    pub band_95: (f64, f64),
    /// Per representation.
    pub representations: BTreeMap<String, Study>,
    /// The command's configuration.
    pub config: Config,
}

/// One seeded run of `config` (whose data must be simulated).
fn one_run(config: &Config, seed: u64) -> Result<RunOutcome> {
    if !config.data.data_spec()?.is_simulated() {
        return Err(CliError::Usage(format!(
            "slam consistency needs simulated data (sim or world:FILE), not `{}`",
            config.data.spec
        )));
    }
    let mut config = config.clone();
    config.data.seed = seed;
    let output = slam_runtime::run(&config, &mut ())?;
    let trajectory = output.record.trajectory_errors()?;
    let map_error_m = output.truth_map.as_ref().map_or(0.0, |t| {
        map_error_against_truth(
            output.estimator.as_ref(),
            &t.shapes(),
            trajectory.as_ref().map(|t| &t.alignment),
        )
        .rms_m
    });
    Ok(RunOutcome {
        nees: pose_nees(&output.record.estimates, &output.record.true_poses()),
        ate_rmse_m: trajectory.map(|t| t.ate_rmse_m),
        map_error_m,
    })
}

/// Runs the study of one representation over `seeds`.
fn study(config: &Config, seeds: &[u64], band: (f64, f64), quiet: bool) -> Study {
    let bar = if quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(seeds.len() as u64)
    };
    let outcomes: Vec<(u64, Result<RunOutcome>)> = seeds
        .par_iter()
        .map(|&seed| {
            let outcome = one_run(config, seed);
            bar.inc(1);
            (seed, outcome)
        })
        .collect();
    bar.finish_and_clear();
    let mut failures = Vec::new();
    let mut ok = Vec::new();
    let mut per_run = Vec::new();
    for (seed, outcome) in outcomes {
        match outcome {
            Ok(o) => {
                let mean = o.nees.iter().map(|(_, n)| n).sum::<f64>() / o.nees.len().max(1) as f64;
                per_run.push((seed, mean, o.ate_rmse_m));
                ok.push(o);
            }
            Err(e) => failures.push((seed, e.to_string())),
        }
    }
    let mut by_time: BTreeMap<u64, (f64, Vec<f64>)> = BTreeMap::new();
    for outcome in &ok {
        for &(time, nees) in &outcome.nees {
            by_time
                .entry(time.to_bits())
                .or_insert((time, Vec::new()))
                .1
                .push(nees);
        }
    }
    let mut series: Vec<(f64, f64)> = by_time
        .values()
        .filter(|(_, values)| values.len() == ok.len() && !ok.is_empty())
        .map(|(time, values)| (*time, values.iter().sum::<f64>() / values.len() as f64))
        .collect();
    series.sort_by(|a, b| a.0.total_cmp(&b.0));
    let steps = series.len().max(1) as f64;
    let count =
        |f: &dyn Fn(f64) -> bool| series.iter().filter(|(_, n)| f(*n)).count() as f64 / steps;
    let mut sorted: Vec<f64> = series.iter().map(|(_, n)| *n).collect();
    sorted.sort_by(f64::total_cmp);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let ates: Vec<f64> = ok.iter().filter_map(|o| o.ate_rmse_m).collect();
    let maps: Vec<f64> = ok.iter().map(|o| o.map_error_m).collect();
    Study {
        runs_ok: ok.len(),
        failures,
        steps: series.len(),
        fraction_within_band: count(&|n| n >= band.0 && n <= band.1),
        fraction_above_band: count(&|n| n > band.1),
        fraction_below_band: count(&|n| n < band.0),
        mean_nees: mean(&sorted),
        median_nees: sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN),
        ate_rmse_mean_m: mean(&ates),
        map_error_mean_m: mean(&maps),
        per_run,
        series,
    }
}

/// Runs the study for every representation of `walls` and writes the report.
pub fn run_study(
    config: &Config,
    walls: &[String],
    runs: usize,
    first_seed: u64,
    quiet: bool,
) -> Result<Report> {
    if runs == 0 {
        return Err(CliError::Usage("--runs must be at least 1".into()));
    }
    let dof = 3 * runs;
    let band = (
        chi2_quantile(0.025, dof)? / runs as f64,
        chi2_quantile(0.975, dof)? / runs as f64,
    );
    let seeds: Vec<u64> = (first_seed..first_seed + runs as u64).collect();
    let mut representations = BTreeMap::new();
    for name in walls {
        let mut config = config.clone();
        config.set_frontend_key("wall_representation", toml::Value::String(name.clone()))?;
        representations.insert(name.clone(), study(&config, &seeds, band, quiet));
    }
    Ok(Report {
        runs,
        first_seed,
        band_95: band,
        representations,
        config: config.clone(),
    })
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
fn csv(report: &Report) -> String {
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

fn chart(report: &Report) -> LineChart {
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

    /// The default world driven along the corridor into the pillar room, without the camera.
    fn short_world() -> PathBuf {
        let mut world = slam_sensors::sim::World::default_world();
        world.camera = None;
        world.robot.waypoints.truncate(3);
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
            mspace.mean_nees < endpoints.mean_nees / 10.0,
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
