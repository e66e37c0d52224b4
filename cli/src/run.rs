//! `slam run [CONFIG.toml] [--data SPEC] [--out DIR] [--seed N] [--quiet]`: runs the
//! configured estimator on simulated or real data and writes the standard outputs.

use std::path::{Path, PathBuf};

use serde::Serialize;
use slam_core::nalgebra::Vector3;

use crate::config::Config;
use crate::data::{DataSpec, Loaded};
use crate::error::{CliError, Result};
use crate::eval::{Alignment, ErrorStats, umeyama};
use crate::frontend::FrontendCounts;
use crate::outputs::{
    ChiSquareSummary, FigureContext, MapError, chi_square_summary, estimates_csv, feature_counts,
    map_error_against_landmarks, map_error_against_truth, map_figure, map_json, map_path,
    path_errors, pose_nees, trajectory_errors, write_text, write_trajectory,
};
use crate::pipeline::{self, RunResult, UpdateTotals, progress_bar};

/// Arguments of `slam run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Configuration file (TOML, see `slam run --help`); every setting has a default.
    pub config: Option<PathBuf>,
    /// Data: sim (the built-in world), world:FILE, carmen:FILE, victoria-park:DIR,
    /// mrclam:DIR or mrclam:DIR:ROBOT, rb2d:FILE. Overrides the config's `[data] spec`.
    #[arg(long)]
    pub data: Option<String>,
    /// Output folder. Overrides the config's `[output] dir` (default `slam-out`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Simulation seed. Overrides the config's `[data] seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// No progress bar and only the summary line.
    #[arg(long)]
    pub quiet: bool,
}

/// Everything in `metrics.json`.
#[derive(Serialize)]
struct Metrics {
    data: String,
    estimator: &'static str,
    seed: u64,
    /// Time steps with an estimate.
    steps: usize,
    events: usize,
    wall_time_s: f64,
    /// Mean wall time per time step, ms.
    time_per_step_ms: f64,
    ate_rmse_m: Option<f64>,
    ate_rmse_unaligned_m: Option<f64>,
    ate_against: Option<&'static str>,
    ate: Option<ErrorStats>,
    /// ATE (aligned RMSE) of the path the map belongs to, where it is not the estimates' (a
    /// particle filter: the path of the particle whose map is kept), m.
    map_path_ate_rmse_m: Option<f64>,
    /// Map error after the trajectory's ATE alignment (where the map is compared with a
    /// true map), m.
    map_error_m: Option<f64>,
    /// The same without alignment, m.
    map_error_unaligned_m: Option<f64>,
    map_error: Option<MapError>,
    /// Robot pose NEES (3 dof) at every step with a true pose.
    nees: Option<ChiSquareSummary>,
    /// NIS of every paired observation.
    nis: ChiSquareSummary,
    features: std::collections::BTreeMap<String, std::collections::BTreeMap<usize, usize>>,
    updates: UpdateTotals,
    frontend: FrontendCounts,
    config: Config,
}

/// Runs `slam run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if let Some(data) = &args.data {
        config.data.spec = data.clone();
    }
    if let Some(out) = &args.out {
        config.output.dir = out.clone();
    }
    if let Some(seed) = args.seed {
        config.data.seed = seed;
    }
    let summary = run_config(&config, args.quiet)?;
    println!("{summary}");
    Ok(())
}

/// Runs a configuration and writes its outputs; returns a one-line summary.
pub fn run_config(config: &Config, quiet: bool) -> Result<String> {
    if let crate::config::EstimatorConfig::EmPolygon(polygon) = &config.estimator {
        return crate::polygon::run_config(config, polygon, quiet);
    }
    let spec: DataSpec = config.data.spec.parse()?;
    crate::frontend::Frontend::check(&config.frontend)?;
    let loaded = spec.load_with(config.data.seed, &config.data.reader_options())?;
    let (sigma_range, noise_factor) = sigma_range(config, &loaded)?;
    let Loaded {
        dataset,
        truth: truth_map,
        ..
    } = loaded;
    let dataset = match &config.data.odometry_from_poses {
        Some(noise) => crate::data::odometry_from_poses(dataset, noise, config.data.seed)?,
        None => dataset,
    };
    let dataset = match &config.data.laser_odometry {
        Some(params) => {
            let (dataset, report) = slam_sensors::laser_odometry::laser_odometry(dataset, params)?;
            if !quiet {
                eprintln!(
                    "laser odometry: {} scans matched, {} matches refused (odometry kept)",
                    report.matched, report.refused
                );
            }
            dataset
        }
        None => dataset,
    };
    let name = dataset.name.clone();
    let landmarks = dataset.landmarks.clone();
    let bar = progress_bar(dataset.events.len(), quiet);
    let result = pipeline::run(config, dataset, sigma_range, noise_factor, &bar)?;

    let estimator = result.estimator.as_ref();
    let trajectory = trajectory_errors(&result)?;
    let has_truth_poses = result
        .truth
        .iter()
        .any(|t| t.2 == slam_sensors::TruthKind::True);
    let alignment = trajectory.as_ref().map(|t| &t.alignment);
    let map_error_unaligned = truth_map
        .as_ref()
        .map(|truth| map_error_against_truth(estimator, truth, None).rms_m);
    // Features the data named (known landmark ids) are compared with the known landmarks;
    // otherwise a simulated world's map is compared with its true map.
    let named = estimator
        .map()
        .iter()
        .any(|(id, _)| estimator.landmark_id(id).is_some());
    let map_error = if named && !landmarks.is_empty() {
        Some(map_error_against_landmarks(
            estimator,
            &landmarks,
            !has_truth_poses,
        )?)
    } else {
        truth_map
            .as_ref()
            .map(|truth| map_error_against_truth(estimator, truth, alignment))
    }
    .filter(|m| m.count > 0);
    let nees_series = pose_nees(&result);
    let nees: Vec<(f64, usize)> = nees_series.into_iter().map(|(_, n)| (n, 3)).collect();
    let steps = result.estimates.len();
    let metrics = Metrics {
        data: name.clone(),
        estimator: config.estimator.name(),
        seed: config.data.seed,
        steps,
        events: result.events,
        wall_time_s: result.wall_time_s,
        time_per_step_ms: 1e3 * result.wall_time_s / steps.max(1) as f64,
        ate_rmse_m: trajectory.as_ref().map(|t| t.ate_rmse_m),
        ate_rmse_unaligned_m: trajectory.as_ref().map(|t| t.ate_rmse_unaligned_m),
        ate_against: trajectory.as_ref().map(|t| t.against),
        ate: trajectory.as_ref().map(|t| t.ate),
        map_path_ate_rmse_m: match map_path(&result) {
            Some(path) => path_errors(&result, &path)?.map(|t| t.ate_rmse_m),
            None => None,
        },
        map_error_m: map_error.as_ref().map(|m| m.rms_m),
        map_error_unaligned_m: map_error_unaligned,
        map_error,
        nees: if nees.is_empty() {
            None
        } else {
            Some(chi_square_summary(&nees)?)
        },
        nis: chi_square_summary(&result.nis)?,
        features: feature_counts(estimator),
        updates: result.updates,
        frontend: result.frontend,
        config: config.clone(),
    };

    let dir = &config.output.dir;
    std::fs::create_dir_all(dir).map_err(|e| CliError::Output {
        path: dir.display().to_string(),
        message: e.to_string(),
    })?;
    write_trajectory(dir, &result)?;
    write_text(dir, "map.json", &map_json(estimator)?)?;
    write_text(dir, "estimates.csv", &estimates_csv(&result))?;
    let json = serde_json::to_string_pretty(&metrics)
        .map_err(|e| CliError::Usage(format!("serializing metrics: {e}")))?;
    write_text(dir, "metrics.json", &json)?;
    if config.output.plots {
        draw(
            dir,
            &result,
            &name,
            truth_map.as_ref(),
            &landmarks,
            !has_truth_poses,
        )?;
    }
    let number = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
    Ok(format!(
        "{name}: {} steps in {:.1} s ({:.3} ms/step); ATE {} m ({}); map error {} m; pose NEES \
         mean {}; outputs in {}",
        steps,
        result.wall_time_s,
        metrics.time_per_step_ms,
        number(metrics.ate_rmse_m),
        metrics.ate_against.unwrap_or("no truth"),
        number(metrics.map_error_m),
        number(metrics.nees.as_ref().map(|n| n.mean_per_dof * 3.0)),
        dir.display()
    ))
}

/// The laser's range noise the front-end assumes, and the factor by which the covariances of
/// what it extracts are inflated: the config's `sigma_range` (factor 1), else a simulated
/// laser's noise with the configured `simulated_noise_factor`, else 3 cm (factor 1).
pub fn sigma_range(config: &Config, loaded: &Loaded) -> Result<(f64, f64)> {
    let (sigma, factor) = match (config.frontend.sigma_range, loaded.laser_sigma_range) {
        (Some(sigma), _) => (sigma, 1.0),
        (None, Some(sigma)) => (sigma, config.frontend.simulated_noise_factor),
        (None, None) => (0.03, 1.0),
    };
    if sigma.is_finite() && sigma > 0.0 && factor.is_finite() && factor > 0.0 {
        Ok((sigma, factor))
    } else {
        Err(CliError::Usage(format!(
            "[frontend] sigma_range and simulated_noise_factor must be positive, got {sigma} and \
             {factor}"
        )))
    }
}

/// How to bring the estimate into the frame the figure's references use: onto the GPS fixes
/// (nearest estimate within 0.5 s) when there are some, onto known landmarks when the run has
/// no true poses, else none.
fn estimate_alignment(
    result: &RunResult,
    landmarks: &[slam_sensors::events::KnownLandmark],
    align_landmarks: bool,
) -> Option<Alignment> {
    let as3 = |p: slam_core::nalgebra::Vector2<f64>| Vector3::new(p.x, p.y, 0.0);
    if result.gps.len() >= 3 {
        let mut from = Vec::new();
        let mut to = Vec::new();
        for (time, fix) in &result.gps {
            let nearest = result
                .estimates
                .partition_point(|r| r.time < *time)
                .min(result.estimates.len().saturating_sub(1));
            let record = result.estimates.get(nearest)?;
            if (record.time - time).abs() <= 0.5 {
                from.push(as3(record.pose.translation()));
                to.push(as3(*fix));
            }
        }
        return umeyama(&from, &to, false).ok();
    }
    if align_landmarks && !landmarks.is_empty() {
        let estimator = result.estimator.as_ref();
        let known: std::collections::BTreeMap<u64, _> =
            landmarks.iter().map(|l| (l.id, l.position)).collect();
        let (mut from, mut to) = (Vec::new(), Vec::new());
        for (id, feature) in estimator.map().iter() {
            let Some(truth) = estimator.landmark_id(id).and_then(|l| known.get(&l)) else {
                continue;
            };
            if let Some(slam_core::CoordBlock::Point3(p)) = feature.coordinates().blocks().first() {
                from.push(as3(p.xy()));
                to.push(as3(*truth));
            }
        }
        return umeyama(&from, &to, false).ok();
    }
    None
}

fn draw(
    dir: &Path,
    result: &RunResult,
    name: &str,
    truth_map: Option<&slam_sensors::sim::TrueMap>,
    landmarks: &[slam_sensors::events::KnownLandmark],
    align_landmarks: bool,
) -> Result<()> {
    let estimate_to_truth = estimate_alignment(result, landmarks, align_landmarks);
    let aligned = if estimate_to_truth.is_some() {
        " (estimate aligned onto the references)"
    } else {
        ""
    };
    let context = FigureContext {
        title: format!("{name}: {} map and path{aligned}", result.estimator.name()),
        truth_map,
        landmarks,
        estimate_to_truth,
    };
    let figure = map_figure(result, &context);
    figure.save(&dir.join("map.svg"))?;
    figure.save(&dir.join("map.png"))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default world driven only along the corridor and into the pillar room, without
    /// the camera (quick in a debug build).
    fn short_world(dir: &Path) -> PathBuf {
        let mut world = slam_sensors::sim::World::default_world();
        world.camera = None;
        world.robot.waypoints.truncate(3);
        let path = dir.join("short-world.toml");
        std::fs::write(&path, toml::to_string(&world).unwrap()).unwrap();
        path
    }

    /// A fresh folder for one test's files, removed when dropped.
    fn temp_dir(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix(&format!("slam-cli-run-{name}-"))
            .tempdir()
            .unwrap()
    }

    #[test]
    fn a_simulated_run_writes_every_output_and_maps_the_walls() {
        let dir = temp_dir("outputs");
        let world = short_world(dir.path());
        let mut config = Config::default();
        config.data.spec = format!("world:{}", world.display());
        config.output.dir = dir.path().join("out");
        let summary = run_config(&config, true).unwrap();
        assert!(summary.contains("ATE"), "{summary}");
        for file in [
            "trajectory.tum",
            "map.json",
            "metrics.json",
            "estimates.csv",
            "map.svg",
            "map.png",
        ] {
            assert!(dir.path().join("out").join(file).exists(), "{file} missing");
        }
        let metrics: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("out/metrics.json")).unwrap(),
        )
        .unwrap();
        let ate = metrics["ate_rmse_m"].as_f64().unwrap();
        let map_error = metrics["map_error_m"].as_f64().unwrap();
        assert!(ate < 0.1, "ATE {ate}");
        assert!(map_error < 0.15, "map error {map_error}");
        let walls = &metrics["features"]["wall"];
        let estimated_ends: u64 = ["3", "4"].iter().filter_map(|d| walls[d].as_u64()).sum();
        assert!(estimated_ends >= 5, "walls by dimension: {walls}");
        // The trajectory reads back as TUM, one pose per step.
        let trajectory =
            slam_sensors::data::read_tum(&dir.path().join("out/trajectory.tum")).unwrap();
        assert_eq!(trajectory.len() as u64, metrics["steps"].as_u64().unwrap());
        // An EKF's map belongs to its estimates: no separate map path.
        assert!(metrics["map_path_ate_rmse_m"].is_null());
        assert!(!dir.path().join("out/map_path.tum").exists());
    }

    #[test]
    fn particle_filters_run_from_the_same_config_with_one_word_changed() {
        let dir = temp_dir("particles");
        let world = short_world(dir.path());
        for (estimator, extra) in [("fastslam", "particles = 6"), ("ipslam", "particles = 6")] {
            let mut trajectories = Vec::new();
            for run in 0..2 {
                let out = dir.path().join(format!("{estimator}-{run}"));
                let text = format!(
                    "[data]\nspec = \"world:{}\"\n[estimator]\ntype = \"{estimator}\"\n{extra}\n\
                     [output]\nplots = false\ndir = \"{}\"\n",
                    world.display(),
                    out.display()
                );
                let config = Config::from_toml(&text, "test").unwrap();
                run_config(&config, true).unwrap();
                let metrics: serde_json::Value = serde_json::from_str(
                    &std::fs::read_to_string(out.join("metrics.json")).unwrap(),
                )
                .unwrap();
                assert_eq!(metrics["estimator"], estimator);
                let ate = metrics["ate_rmse_m"].as_f64().unwrap();
                assert!(ate < 1.0, "{estimator}: ATE {ate}");
                assert!(
                    metrics["map_error_m"].as_f64().is_some(),
                    "{estimator}: no map error"
                );
                // The path of the map's particle, one pose per step.
                let map_path = slam_sensors::data::read_tum(&out.join("map_path.tum")).unwrap();
                assert_eq!(map_path.len() as u64, metrics["steps"].as_u64().unwrap());
                let map_path_ate = metrics["map_path_ate_rmse_m"].as_f64().unwrap();
                assert!(
                    map_path_ate < 1.0,
                    "{estimator}: map path ATE {map_path_ate}"
                );
                trajectories.push(std::fs::read_to_string(out.join("trajectory.tum")).unwrap());
            }
            assert_eq!(
                trajectories[0], trajectories[1],
                "{estimator}: same seed, same run"
            );
        }
    }

    #[test]
    fn bad_configs_are_clear_errors() {
        let dir = temp_dir("bad");
        let path = dir.path().join("bad.toml");
        std::fs::write(
            &path,
            "[estimator]\ntype = \"ekf\"\ngate_probabilty = 0.9\n",
        )
        .unwrap();
        let error = Config::from_file(&path).unwrap_err().to_string();
        assert!(error.contains("gate_probabilty"), "{error}");
        let config = Config {
            data: crate::config::DataConfig {
                spec: "rb2d:/no/such/file.rb2d".into(),
                ..Default::default()
            },
            ..Default::default()
        };
        let error = run_config(&config, true).unwrap_err().to_string();
        assert!(error.contains("/no/such/file.rb2d"), "{error}");
    }

    #[test]
    fn the_rb2d_benchmark_is_as_accurate_as_kf_slam() {
        // The classic range-bearing log (1000 steps, 50 landmarks): MRPT's kf-slam reaches an
        // ATE of 3.4 cm on such a log.
        let dir = temp_dir("rb2d");
        let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        let mut config = Config::default();
        config.data.spec = format!("world:{}", world.display());
        config.output.dir = dir.path().join("out");
        config.output.plots = false;
        run_config(&config, true).unwrap();
        let metrics: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("out/metrics.json")).unwrap(),
        )
        .unwrap();
        let ate = metrics["ate_rmse_m"].as_f64().unwrap();
        let nees = metrics["nees"]["mean_per_dof"].as_f64().unwrap();
        assert!(ate < 0.034, "ATE {ate}");
        assert!(nees < 1.5, "pose NEES per dof {nees}");
    }

    #[test]
    fn both_association_rules_map_unlabelled_landmarks() {
        // The rb2d circle log without its landmark ids: 50 landmarks must come out as about 50
        // features, with the trajectory as accurate as with known ids.
        let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        for association in ["nearest-neighbour", "jcbb"] {
            let dir = temp_dir(association);
            let text = format!(
                "[data]\nspec = \"world:{}\"\n[estimator]\ntype = \"ekf\"\nassociation = \"{association}\"\n\
                 confirm_after = 2\n[frontend]\nignore_landmark_ids = true\n[output]\nplots = false\ndir = \"{}\"\n",
                world.display(),
                dir.path().join("out").display()
            );
            let config = Config::from_toml(&text, "test").unwrap();
            run_config(&config, true).unwrap();
            let metrics: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(dir.path().join("out/metrics.json")).unwrap(),
            )
            .unwrap();
            let ate = metrics["ate_rmse_m"].as_f64().unwrap();
            let points = metrics["features"]["point"]["2"].as_u64().unwrap_or(0);
            assert!(ate < 0.05, "{association}: ATE {ate}");
            assert!(
                (45..=56).contains(&points),
                "{association}: {points} landmarks"
            );
        }
    }
}
