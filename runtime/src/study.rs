//! The consistency study of `slam consistency`: the statistical consistency of the estimator
//! over many seeded runs of a simulated world, one study per wall representation (the M-space
//! paper's Fig. 1 claim, measured: M-space walls against naive endpoint walls).
//!
//! For `N` runs the average robot-pose NEES at a step is `1/N` times a chi-square variable
//! with `3N` degrees of freedom when the filter is consistent, so its two-sided 95% band is
//! `[chi2(0.025, 3N) / N, chi2(0.975, 3N) / N]` (Bar-Shalom, Li & Kirubarajan, ch. 5.4)
//! ([`nees_band_95`]). The report gives the fraction of steps whose average lies in the band.
//!
//! The runs of one representation run in parallel (rayon); each is seeded, so the report
//! does not depend on the number of threads.

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;
use slam_core::chi2_quantile;

use crate::config::Config;
use crate::error::{Result, RuntimeError};
use crate::eval::{map_error_against_truth, pose_nees};

/// What a study reports as it goes (a program's progress bar). Every method does nothing by
/// default; `()` reports nothing.
pub trait StudyProgress: Sync {
    /// The `runs` runs of the wall representation `name` start.
    fn start(&self, _name: &str, _runs: usize) {}
    /// One run ended, finished or failed (called from the thread that ran it).
    fn run_done(&self) {}
    /// Every run of the representation started last ended.
    fn finish(&self) {}
}

impl StudyProgress for () {}

/// The outcome of one run.
struct RunOutcome {
    nees: Vec<(f64, f64)>,
    ate_rmse_m: Option<f64>,
    map_error_m: f64,
}

/// The study of one wall representation.
#[derive(Debug, Serialize)]
pub struct ConsistencyStudy {
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

/// The whole report of a study (`consistency.json`).
#[derive(Debug, Serialize)]
pub struct ConsistencyReport {
    /// Runs per representation.
    pub runs: usize,
    /// Seeds `first..first + runs`.
    pub first_seed: u64,
    /// The 95% band of the average NEES over `runs` runs.
    pub band_95: (f64, f64),
    /// Per representation.
    pub representations: BTreeMap<String, ConsistencyStudy>,
    /// The study's configuration.
    pub config: Config,
}

/// The two-sided 95% band of the average robot-pose NEES (3 dof) over `runs` consistent
/// runs: `[chi2(0.025, 3N) / N, chi2(0.975, 3N) / N]`.
pub fn nees_band_95(runs: usize) -> Result<(f64, f64)> {
    if runs == 0 {
        return Err(RuntimeError::Eval(
            "the NEES band of zero runs is not defined".into(),
        ));
    }
    let dof = 3 * runs;
    Ok((
        chi2_quantile(0.025, dof)? / runs as f64,
        chi2_quantile(0.975, dof)? / runs as f64,
    ))
}

/// One seeded run of `config` (whose data must be simulated).
fn one_run(config: &Config, seed: u64) -> Result<RunOutcome> {
    if !config.data.data_spec()?.is_simulated() {
        return Err(RuntimeError::Data(format!(
            "slam consistency needs simulated data (sim or world:FILE), not `{}`",
            config.data.spec
        )));
    }
    let mut config = config.clone();
    config.data.seed = seed;
    let output = crate::run::run(&config, &mut ())?;
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
fn study(
    config: &Config,
    name: &str,
    seeds: &[u64],
    band: (f64, f64),
    progress: &dyn StudyProgress,
) -> ConsistencyStudy {
    progress.start(name, seeds.len());
    let outcomes: Vec<(u64, Result<RunOutcome>)> = seeds
        .par_iter()
        .map(|&seed| {
            let outcome = one_run(config, seed);
            progress.run_done();
            (seed, outcome)
        })
        .collect();
    progress.finish();
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
    ConsistencyStudy {
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

/// The consistency study of `config` (whose data must be simulated: `sim` or `world:FILE`)
/// for every wall representation of `walls` (registered names of the `features` front-end's
/// `wall_representation`), `runs` runs each with the seeds `first_seed..first_seed + runs`.
/// A run that fails is listed in its study's `failures`; `progress` hears of each run.
pub fn consistency_study(
    config: &Config,
    walls: &[String],
    runs: usize,
    first_seed: u64,
    progress: &dyn StudyProgress,
) -> Result<ConsistencyReport> {
    let band = nees_band_95(runs)?;
    let seeds: Vec<u64> = (first_seed..first_seed + runs as u64).collect();
    let mut representations = BTreeMap::new();
    for name in walls {
        let mut config = config.clone();
        config.set_frontend_key("wall_representation", toml::Value::String(name.clone()))?;
        representations.insert(name.clone(), study(&config, name, &seeds, band, progress));
    }
    Ok(ConsistencyReport {
        runs,
        first_seed,
        band_95: band,
        representations,
        config: config.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_band_of_the_average_nees_narrows_around_3_with_more_runs() {
        let (lo1, hi1) = nees_band_95(1).unwrap();
        let (lo50, hi50) = nees_band_95(50).unwrap();
        // chi2(0.025, 3) = 0.2158, chi2(0.975, 3) = 9.3484.
        assert!(
            (lo1 - 0.2158).abs() < 1e-3 && (hi1 - 9.3484).abs() < 1e-3,
            "{lo1} {hi1}"
        );
        assert!(lo1 < lo50 && lo50 < 3.0 && 3.0 < hi50 && hi50 < hi1);
        assert!(nees_band_95(0).is_err());
    }

    #[test]
    fn runs_on_data_that_are_not_simulated_are_listed_as_failures() {
        let mut config = Config::default();
        config.data.spec = "rb2d:/no/such/file.rb2d".into();
        let walls = ["mspace".to_string()];
        let report = consistency_study(&config, &walls, 2, 7, &()).unwrap();
        let study = &report.representations["mspace"];
        assert_eq!(study.runs_ok, 0);
        assert_eq!(study.steps, 0);
        let seeds: Vec<u64> = study.failures.iter().map(|(seed, _)| *seed).collect();
        assert_eq!(seeds, [7, 8]);
        assert!(
            study.failures[0].1.contains("needs simulated data"),
            "{study:?}"
        );
    }
}
