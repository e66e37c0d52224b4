//! `slam run [CONFIG.toml] [--data SPEC] [--out DIR] [--seed N] [--quiet]`: runs the
//! configured estimator on simulated or real data and writes the standard outputs.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use slam_runtime::eval::stamped;
use slam_runtime::g2o::{G2oObserver, g2o_text};
use slam_runtime::grid::GridObserver;
use slam_runtime::mcap_log::McapLog;
use slam_runtime::{Config, Observer, PostProcessOutput, RunMetrics, RunOutput, RunResults};
use slam_sensors::data::{write_atomically, write_tum};

use crate::error::{CliError, Result};
use crate::figures::{run_figure, stage_figure};
use crate::outputs::{
    create_dir, map_json, plain_map_json, write_estimates_csv, write_json, write_text,
    write_trajectory,
};
use crate::outset::OutputSet;
use crate::progress::Progress;

/// Arguments of `slam run`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Exit codes: 0 the run went through the data; 1 an error (nothing \
    written); 2 bad arguments; 3 the filter diverged (outputs written, \"status\": \
    \"diverged\" in metrics.json); 130 interrupted by Ctrl-C or SIGTERM (outputs of the steps \
    run written, \"status\": \"interrupted\"). The outputs replace --out as one set: killed at \
    any moment, --out holds the previous complete set or the new one."
)]
pub struct RunArgs {
    /// Configuration file (TOML). Every table and key is optional: `slam config print
    /// [CONFIG]` shows them all with the values a run uses; the README explains them.
    pub config: Option<PathBuf>,
    /// Data: sim (the built-in world), world:FILE, carmen:FILE, mcap:FILE (a ROS 2 bag),
    /// victoria-park:DIR, mrclam:DIR or mrclam:DIR:ROBOT, rb2d:FILE. Overrides the config's
    /// `[data] spec`.
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
    /// Write the occupancy grid, map.pgm + map.yaml (ROS map_server format); an error for
    /// data without laser scans. Same as the config's `[output] grid = true`, which skips
    /// such data with a note instead.
    #[arg(long)]
    pub grid: bool,
    /// Write the pose graph with landmarks and walls, graph.g2o (`[output] g2o = true`).
    #[arg(long)]
    pub g2o: bool,
    /// Write run.mcap, the run for Foxglove (`[output] mcap = true`).
    #[arg(long)]
    pub mcap: bool,
}

/// The configuration of `slam run` with its arguments applied.
pub fn config_of(args: &RunArgs) -> Result<Config> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    let mut config = with_overrides(config, args.data.as_deref(), args.seed);
    if let Some(out) = &args.out {
        config.output.dir = out.clone();
    }
    config.output.grid |= args.grid;
    config.output.g2o |= args.g2o;
    config.output.mcap |= args.mcap;
    Ok(config)
}

/// `config` with the data spec and the seed replaced where given (what `--data` and `--seed`
/// of `slam run` do).
pub fn with_overrides(mut config: Config, data: Option<&str>, seed: Option<u64>) -> Config {
    if let Some(data) = data {
        config.data.spec = data.to_string();
    }
    if let Some(seed) = seed {
        config.data.seed = seed;
    }
    config
}

/// The computation of `slam run` without its files ([`slam_runtime::compute_run`], with the
/// command's error type): runs `config`, with `observer` watching, until the end of the data
/// or until `stop` is set, and computes the run's metrics.
pub fn compute_run(
    config: &Config,
    observer: &mut dyn Observer,
    stop: &AtomicBool,
) -> Result<RunResults> {
    Ok(slam_runtime::compute_run(config, observer, stop)?)
}

/// How a run ended: the exit code of `slam run`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunStatus {
    /// The run went through the data (exit code 0).
    Complete,
    /// The filter diverged; the outputs are written (exit code [`EXIT_DIVERGED`]).
    Diverged,
    /// Ctrl-C (or SIGTERM) stopped the run; the outputs of the steps run are written,
    /// marked `"status": "interrupted"` (exit code [`EXIT_INTERRUPTED`]).
    Interrupted,
}

/// The exit code of a run whose filter diverged (its outputs are written).
pub const EXIT_DIVERGED: u8 = 3;

/// The exit code of an interrupted run (its outputs are written, marked as such).
pub const EXIT_INTERRUPTED: u8 = 130;

impl RunStatus {
    /// The process exit code.
    pub fn exit_code(self) -> u8 {
        match self {
            RunStatus::Complete => 0,
            RunStatus::Diverged => EXIT_DIVERGED,
            RunStatus::Interrupted => EXIT_INTERRUPTED,
        }
    }

    fn of(output: &RunOutput) -> Self {
        if output.interrupted_at.is_some() {
            RunStatus::Interrupted
        } else if output.divergence.is_some() {
            RunStatus::Diverged
        } else {
            RunStatus::Complete
        }
    }
}

/// Runs `slam run`; returns the summary it prints.
pub fn run(args: &RunArgs) -> Result<String> {
    run_inner(
        &config_of(args)?,
        args.quiet,
        &AtomicBool::new(false),
        args.grid,
    )
    .map(|(summary, _)| summary)
}

/// Runs `slam run` until the end of the data or until `stop` is set; returns the summary and
/// how the run ended.
pub fn run_until(args: &RunArgs, stop: &AtomicBool) -> Result<(String, RunStatus)> {
    run_inner(&config_of(args)?, args.quiet, stop, args.grid)
}

/// Runs a configuration and writes its outputs; returns a summary (one line, and one per
/// post-processing stage).
pub fn run_config(config: &Config, quiet: bool) -> Result<String> {
    run_config_until(config, quiet, &AtomicBool::new(false)).map(|(summary, _)| summary)
}

/// [`run_config`], stopped at the next event once `stop` is set. The outputs are written
/// into a new set beside the output folder, which replaces the previous set only when
/// complete (`outset`); an output folder that cannot be written is an error before the run.
pub fn run_config_until(
    config: &Config,
    quiet: bool,
    stop: &AtomicBool,
) -> Result<(String, RunStatus)> {
    run_inner(config, quiet, stop, false)
}

/// [`run_config_until`]; `grid_required` (the `--grid` flag) makes data without laser scans
/// an error rather than a note.
fn run_inner(
    config: &Config,
    quiet: bool,
    stop: &AtomicBool,
    grid_required: bool,
) -> Result<(String, RunStatus)> {
    config.output.validate()?;
    if grid_required
        && let Some(kind) = ["rb2d:", "victoria-park:"]
            .iter()
            .find(|kind| config.data.spec.starts_with(**kind))
    {
        return Err(CliError::Usage(no_scans_error(kind.trim_end_matches(':'))));
    }
    let set = OutputSet::prepare(&config.output.dir)?;
    let mut progress = Progress::new(quiet);
    let mut streams = Streams::new(set.path(), config)?;
    let RunResults { output, metrics } = {
        let mut observers: Vec<&mut dyn Observer> = vec![&mut progress];
        streams.add_to(&mut observers);
        compute_run(config, &mut observers, stop)?
    };
    progress.finish();
    for warning in &output.input.warnings {
        eprintln!("slam: warning: {warning}");
    }
    if !quiet {
        for note in &output.input.notes {
            eprintln!("slam: note: {note}");
        }
    }
    write_outputs(set.path(), config, &output, &metrics)?;
    let notes = streams.finish(set.path(), &output, grid_required)?;
    set.commit()?;
    let dir = &config.output.dir;
    let mut summary = summary_line(&output, &metrics, dir);
    for note in notes {
        summary.push_str("; ");
        summary.push_str(&note);
    }
    for stage in &output.postprocess {
        summary.push('\n');
        summary.push_str(&stage.summary);
        summary.push_str(&format!("; outputs in {}", dir.join(&stage.name).display()));
    }
    if let Some(report) = &output.laser_odometry
        && !quiet
    {
        eprintln!("{report}");
    }
    Ok((summary, RunStatus::of(&output)))
}

/// The `--grid` error for data without laser scans.
fn no_scans_error(data: &str) -> String {
    format!(
        "--grid: {data} has no laser scans, so there is no occupancy grid to write (rb2d and \
         Victoria Park logs carry ready-made observations); drop --grid"
    )
}

/// The outputs written as the run goes: the occupancy grid, the g2o graph's odometry, the
/// MCAP log.
struct Streams {
    grid: Option<GridObserver>,
    g2o: Option<G2oObserver>,
    mcap: Option<McapLog>,
}

impl Streams {
    /// The observers `config` asks for; `run.mcap` is created in the set folder `dir`.
    fn new(dir: &Path, config: &Config) -> Result<Self> {
        let output = &config.output;
        Ok(Streams {
            grid: output
                .grid
                .then(|| GridObserver::new(output.grid_resolution, output.grid_max_range)),
            g2o: output.g2o.then(G2oObserver::default),
            mcap: match output.mcap {
                true => Some(McapLog::create(
                    &dir.join("run.mcap"),
                    output.mcap_map_interval_s,
                )?),
                false => None,
            },
        })
    }

    fn add_to<'a>(&'a mut self, observers: &mut Vec<&'a mut dyn Observer>) {
        if let Some(grid) = &mut self.grid {
            observers.push(grid);
        }
        if let Some(g2o) = &mut self.g2o {
            observers.push(g2o);
        }
        if let Some(mcap) = &mut self.mcap {
            observers.push(mcap);
        }
    }

    /// Writes the files into `dir`; returns the notes for the summary.
    fn finish(self, dir: &Path, output: &RunOutput, grid_required: bool) -> Result<Vec<String>> {
        let mut notes = Vec::new();
        if let Some(observer) = self.grid {
            let grid = &observer.grid;
            if grid.scans() == 0 {
                if grid_required {
                    return Err(CliError::Usage(no_scans_error(&output.name)));
                }
                notes.push("no occupancy grid (the data have no laser scans)".to_string());
            } else {
                write_atomically(&dir.join("map.pgm"), &grid.pgm())?;
                write_text(dir, "map.yaml", &grid.yaml("map.pgm"))?;
            }
        }
        if let Some(observer) = self.g2o {
            write_text(dir, "graph.g2o", &g2o_text(output, &observer))?;
        }
        if let Some(log) = self.mcap {
            log.finish(output.estimator.as_ref())?;
        }
        Ok(notes)
    }
}

/// Every output of a run into `dir`.
fn write_outputs(
    dir: &Path,
    config: &Config,
    output: &RunOutput,
    metrics: &RunMetrics,
) -> Result<()> {
    write_trajectory(dir, output)?;
    write_text(dir, "map.json", &map_json(output.estimator.as_ref())?)?;
    write_estimates_csv(dir, output)?;
    write_json(dir, "metrics.json", metrics)?;
    if config.output.plots {
        let figure = run_figure(output);
        figure.save(&dir.join("map.svg"))?;
        figure.save(&dir.join("map.png"))?;
    }
    for stage in &output.postprocess {
        write_stage(dir, stage, &output.name, config.output.plots)?;
    }
    Ok(())
}

/// The outputs of a post-processing stage, in a folder of its name: `map.json`,
/// `metrics.json`, `trajectory.tum` (the poses it used) and its figures (`map.svg`,
/// `map.png` with the points it used, `map-walls.png` without).
fn write_stage(dir: &Path, stage: &PostProcessOutput, data: &str, plots: bool) -> Result<()> {
    let folder = dir.join(&stage.name);
    create_dir(&folder)?;
    write_text(&folder, "map.json", &plain_map_json(&stage.map)?)?;
    if !stage.path.is_empty() {
        write_tum(
            &folder.join("trajectory.tum"),
            &stamped(stage.path.iter().copied()),
        )?;
    }
    write_json(&folder, "metrics.json", &stage.metrics)?;
    if plots {
        let with_points = stage_figure(stage, data, true);
        with_points.save(&folder.join("map.svg"))?;
        with_points.save(&folder.join("map.png"))?;
        stage_figure(stage, data, false).save(&folder.join("map-walls.png"))?;
    }
    Ok(())
}

/// The map quality clause of the summary (runs with scans and walls), else empty.
fn map_quality_clause(metrics: &RunMetrics) -> String {
    let Some(quality) = &metrics.map_quality else {
        return String::new();
    };
    let median = quality
        .median_point_to_wall_m
        .map_or("n/a".to_string(), |m| format!("{:.1} cm", 100.0 * m));
    format!(
        "; {} walls, {:.0} m, {:.1}% doubled ({:.1}% same side); scan points to walls {median} \
         (median)",
        quality.walls,
        quality.wall_length_m,
        100.0 * quality.doubled_fraction,
        100.0 * quality.doubled_same_side_fraction
    )
}

/// The loop consistency clause of the summary (runs with scans that come back to a place),
/// else empty.
fn revisit_clause(metrics: &RunMetrics) -> String {
    let Some(figures) = &metrics.revisit_consistency else {
        return String::new();
    };
    let Some(estimate) = &figures.estimate else {
        return String::new();
    };
    let reference = figures.reference.map_or(String::new(), |r| {
        format!(", {:.1} cm by the reference poses", 100.0 * r.median_m)
    });
    format!(
        "; passes over the same place {:.1} cm apart (median{reference})",
        100.0 * estimate.median_m
    )
}

fn summary_line(output: &RunOutput, metrics: &RunMetrics, dir: &Path) -> String {
    let number = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
    let nees = match &metrics.nees {
        Some(nees) if metrics.nees_covariance == "gaussian" => nees.describe(),
        Some(nees) => format!("{} (of the {})", nees.describe(), metrics.nees_covariance),
        None => match &metrics.nees_reference {
            Some(nees) => format!("{} against the reference poses", nees.describe()),
            None => "n/a".into(),
        },
    };
    let mut line = format!(
        "{}: {} steps in {:.1} s ({:.3} ms/step); ATE {} m ({}); map error {} m; pose NEES per \
         dof {nees}",
        output.name,
        metrics.steps,
        metrics.wall_time_s,
        metrics.time_per_step_ms,
        number(metrics.ate_rmse_m),
        metrics.ate_against.unwrap_or("no truth"),
        number(metrics.map_error_m),
    );
    line.push_str(&map_quality_clause(metrics));
    line.push_str(&revisit_clause(metrics));
    let skipped: usize = output.input.skipped_readings.values().sum();
    if skipped > 0 {
        let reasons: Vec<String> = output
            .input
            .skipped_readings
            .iter()
            .map(|(reason, n)| format!("{n} {reason}"))
            .collect();
        line.push_str(&format!("; readings skipped: {}", reasons.join(", ")));
    }
    if let Some(divergence) = &output.divergence {
        line.push_str(&format!(
            "; DIVERGED at time {}: {}",
            divergence.time, divergence.reason
        ));
    }
    if let Some(time) = output.interrupted_at {
        line.push_str(&format!("; INTERRUPTED after time {time}"));
    }
    line.push_str(&format!("; outputs in {}", dir.display()));
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::Pose2;
    use slam_core::nalgebra::Vector2;

    /// A JSON output file of a run.
    fn read_json(path: &Path) -> serde_json::Value {
        let text =
            std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        serde_json::from_str(&text).unwrap()
    }

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
        let metrics = read_json(&dir.path().join("out/metrics.json"));
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
    fn the_standard_outputs_hold_the_walls_the_graph_and_the_replay() {
        let dir = temp_dir("standard");
        let world_path = short_world(dir.path());
        let mut config = Config::default();
        config.data.spec = format!("world:{}", world_path.display());
        config.output.dir = dir.path().join("out");
        config.output.plots = false;
        config.output.grid = true;
        config.output.g2o = true;
        config.output.mcap = true;
        run_config(&config, true).unwrap();
        let out = dir.path().join("out");
        // The grid: a map_saver image and its yaml (interop/test_outputs.py reads them).
        let yaml = std::fs::read_to_string(out.join("map.yaml")).unwrap();
        assert!(
            yaml.contains("image: map.pgm") && yaml.contains("mode: trinary"),
            "{yaml}"
        );
        assert!(
            std::fs::read(out.join("map.pgm"))
                .unwrap()
                .starts_with(b"P5\n")
        );
        // The graph: one vertex per step, one edge fewer, the walls as pairs of vertices.
        let metrics = read_json(&out.join("metrics.json"));
        let steps = metrics["steps"].as_u64().unwrap() as usize;
        let graph = std::fs::read_to_string(out.join("graph.g2o")).unwrap();
        let count = |tag: &str| graph.lines().filter(|l| l.starts_with(tag)).count();
        assert_eq!(count("VERTEX_SE2 "), steps);
        assert_eq!(count("EDGE_SE2 "), steps - 1);
        let walls = count("# WALL ");
        assert!(walls >= 5, "{walls} walls");
        assert_eq!(count("VERTEX_XY "), 2 * walls + count("EDGE_SE2_XY "));
        // The replay log ends with the MCAP magic.
        let mcap = std::fs::read(out.join("run.mcap")).unwrap();
        assert!(mcap.ends_with(b"\x89MCAP0\r\n"));
    }

    #[test]
    fn a_grid_without_scans_is_a_note_from_the_config_and_an_error_from_the_flag() {
        let dir = temp_dir("no-grid");
        let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        let mut config = Config::default();
        config.data.spec = format!("world:{}", world.display());
        config.data.max_events = 100;
        config.output.dir = dir.path().join("out");
        config.output.plots = false;
        config.output.grid = true;
        let summary = run_config(&config, true).unwrap();
        assert!(summary.contains("no occupancy grid"), "{summary}");
        assert!(!dir.path().join("out/map.pgm").exists());
        let error = run_inner(&config, true, &AtomicBool::new(false), true)
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("--grid") && error.contains("no laser scans"),
            "{error}"
        );
        // Nothing was replaced: the former set is still there.
        assert!(dir.path().join("out/metrics.json").exists());
        config.data.spec = "rb2d:/no/such.rb2d".into();
        let error = run_inner(&config, true, &AtomicBool::new(false), true)
            .unwrap_err()
            .to_string();
        assert!(error.contains("--grid: rb2d has no laser scans"), "{error}");
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
                let summary = run_config(&config, true).unwrap();
                let metrics = read_json(&out.join("metrics.json"));
                assert_eq!(metrics["estimator"], estimator);
                // The NEES of the weighted particle cloud, said so, with the band of its mean.
                assert_eq!(metrics["nees_covariance"], "particle cloud");
                assert!(
                    summary.contains("pose NEES per dof")
                        && summary.contains("95% band")
                        && summary.contains("of the particle cloud"),
                    "{summary}"
                );
                if estimator == "ipslam" {
                    assert!(metrics["nis"].is_null());
                    let reason = metrics["unavailable"]["nis"].as_str().unwrap();
                    assert!(reason.contains("no innovation"), "{reason}");
                }
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
    fn resource_limits_are_errors_naming_the_key_and_the_limit_before_any_work() {
        let dir = temp_dir("limits");
        let out = dir.path().join("out");
        let text = format!(
            "[estimator]\ntype = \"fastslam\"\nparticles = 100000000000\n[output]\ndir = \"{}\"\n",
            out.display()
        );
        let error = run_config(&Config::from_toml(&text, "t").unwrap(), true)
            .unwrap_err()
            .chain();
        assert!(error.contains("particles <= 100000"), "{error}");
        let mut world = slam_sensors::sim::World::default_world();
        if let Some(laser) = world.laser.as_mut() {
            laser.beams = 100_000_000;
        }
        let mut camera = world.clone();
        camera.laser = None;
        if let Some(c) = camera.camera.as_mut() {
            c.intrinsics.width = 100_000;
            c.intrinsics.height = 100_000;
        }
        for (name, world, expected) in [
            (
                "beams",
                world,
                "[laser] beams = 100000000 is above the limit of 100000",
            ),
            (
                "camera",
                camera,
                "100000 x 100000 = 10000000000 pixels is above the limit",
            ),
        ] {
            let path = dir.path().join(format!("{name}.toml"));
            std::fs::write(&path, toml::to_string(&world).unwrap()).unwrap();
            let mut config = Config::default();
            config.data.spec = format!("world:{}", path.display());
            config.output.dir = out.clone();
            let error = run_config(&config, true).unwrap_err().chain();
            assert!(error.contains(expected), "{error}");
        }
        assert!(!out.exists(), "a refused run wrote its outputs");
    }

    #[test]
    fn an_unwritable_out_is_an_error_before_the_data_is_read() {
        // --out under a file cannot be created; the data do not exist either. The error is
        // the output folder's: it is checked before the data are opened and the run starts.
        let dir = temp_dir("unwritable");
        let file = dir.path().join("a-file");
        std::fs::write(&file, "").unwrap();
        let mut config = Config::default();
        config.data.spec = "rb2d:/no/such/file.rb2d".into();
        config.output.dir = file.join("out");
        let error = run_config(&config, true).unwrap_err().chain();
        assert!(
            error.contains("a-file") && !error.contains("/no/such/file.rb2d"),
            "{error}"
        );
    }

    #[test]
    fn a_run_along_a_straight_line_keeps_its_outputs_with_the_ate_null_and_its_reason() {
        // The robot drives straight: its true poses lie on one line, so no SE(3) alignment
        // is determined. The run is kept; the ATE is null with the reason, and no hint names
        // an option that `slam run` does not have.
        let dir = temp_dir("straight");
        let text = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml"),
        )
        .unwrap()
        .replace(
            "controls = { v = 1.0, omega_deg = 7.2, steps = 1000 }",
            "controls = { v = 1.0, omega_deg = 0.0, steps = 60 }",
        );
        assert!(text.contains("omega_deg = 0.0, steps = 60"));
        let world = dir.path().join("straight.toml");
        std::fs::write(&world, text).unwrap();
        let mut config = Config::default();
        config.data.spec = format!("world:{}", world.display());
        config.output.dir = dir.path().join("out");
        config.output.plots = false;
        let (summary, status) = run_config_until(&config, true, &AtomicBool::new(false)).unwrap();
        assert_eq!(status, RunStatus::Complete);
        assert!(summary.contains("ATE n/a m"), "{summary}");
        assert!(!summary.contains("--align"), "{summary}");
        let metrics = read_json(&dir.path().join("out/metrics.json"));
        assert!(metrics["ate_rmse_m"].is_null());
        let reason = metrics["unavailable"]["ate"].as_str().unwrap();
        assert!(
            reason.contains("one line") && !reason.contains("--align"),
            "{reason}"
        );
        assert_eq!(metrics["steps"], 61);
        assert!(dir.path().join("out/trajectory.tum").is_file());
        assert!(dir.path().join("out/map.json").is_file());
    }

    #[test]
    fn a_warning_about_the_data_reaches_the_metrics() {
        // A CARMEN log whose scans have every reading at the maximum range: the reader warns
        // (the maximum range or the unit is likely wrong) and the run keeps the warning.
        let dir = temp_dir("warning");
        let mut world = slam_sensors::sim::World::default_world();
        world.camera = None;
        world.robot.waypoints.truncate(3);
        let run = slam_sensors::sim::simulate(&world, 1).unwrap();
        let text =
            slam_sensors::data::carmen::carmen_text(&run.dataset, &Pose2::identity(), "t").unwrap();
        let mut blind = String::new();
        for line in text.lines() {
            let mut fields: Vec<String> = line.split_whitespace().map(String::from).collect();
            if fields.first().map(String::as_str) == Some("ROBOTLASER1") {
                let n: usize = fields[8].parse().unwrap();
                let max_range = fields[5].clone();
                for field in &mut fields[9..9 + n] {
                    *field = max_range.clone();
                }
            }
            blind.push_str(&fields.join(" "));
            blind.push('\n');
        }
        let log = dir.path().join("blind.log");
        std::fs::write(&log, blind).unwrap();
        let mut config = Config::default();
        config.data.spec = format!("carmen:{}", log.display());
        config.output.dir = dir.path().join("out");
        config.output.plots = false;
        run_config(&config, true).unwrap();
        let metrics = read_json(&dir.path().join("out/metrics.json"));
        let warnings = metrics["input"]["warnings"].as_array().unwrap();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        let warning = warnings[0].as_str().unwrap();
        assert!(
            warning.contains("blind.log") && warning.contains("maximum_range"),
            "{warning}"
        );
    }

    #[test]
    fn input_glitches_are_counted_in_the_metrics_and_the_summary() {
        let dir = temp_dir("glitch");
        let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        let world = slam_sensors::sim::World::from_file(&world).unwrap();
        let run = slam_sensors::sim::simulate(&world, 1).unwrap();
        let text =
            slam_sensors::data::rb2d::rb2d_text(&run.dataset, &world.rb2d_params(), "t").unwrap();
        // One slightly negative range, as other tools write them.
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        let k = lines.iter().position(|l| l.starts_with("OBS 5 ")).unwrap();
        let mut fields: Vec<String> = lines[k].split(' ').map(String::from).collect();
        fields[3] = "-0.01".into();
        lines[k] = fields.join(" ");
        let log = dir.path().join("glitch.rb2d");
        std::fs::write(&log, lines.join("\n")).unwrap();
        let mut config = Config::default();
        config.data.spec = format!("rb2d:{}", log.display());
        config.output.dir = dir.path().join("out");
        config.output.plots = false;
        let summary = run_config(&config, true).unwrap();
        assert!(
            summary.contains("readings skipped: 1 rb2d OBS: range not positive"),
            "{summary}"
        );
        let metrics = read_json(&dir.path().join("out/metrics.json"));
        assert_eq!(
            metrics["input"]["skipped_readings"]["rb2d OBS: range not positive"],
            1
        );
        assert_eq!(metrics["status"], "complete");
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
            data: slam_runtime::data::DataConfig {
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
        let metrics = read_json(&dir.path().join("out/metrics.json"));
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
            let metrics = read_json(&dir.path().join("out/metrics.json"));
            let ate = metrics["ate_rmse_m"].as_f64().unwrap();
            let points = metrics["features"]["point"]["2"].as_u64().unwrap_or(0);
            assert!(ate < 0.05, "{association}: ATE {ate}");
            assert!(
                (45..=56).contains(&points),
                "{association}: {points} landmarks"
            );
        }
    }

    /// An EM-polygon stage on given poses (after dead reckoning, which uses none of them).
    fn polygon_config(spec: &str, out: &Path) -> Config {
        let text = format!(
            "[data]\nspec = \"{spec}\"\n[estimator]\ntype = \"dead-reckoning\"\n\
             [[postprocess]]\ntype = \"em-polygon\"\nposes = \"given\"\n\
             [output]\ndir = \"{}\"\n",
            out.display()
        );
        Config::from_toml(&text, "test").unwrap()
    }

    /// A CARMEN log of a robot in a 6 m x 4 m room, scanning from a few places.
    fn room_log(dir: &std::path::Path) -> std::path::PathBuf {
        room_log_with_odometry(dir, None)
    }

    /// [`room_log`], with `ODOM` lines before the scans when `odometry_frame` is given: the
    /// odometry's poses are that frame composed with the scans' (reference) poses.
    fn room_log_with_odometry(
        dir: &std::path::Path,
        odometry_frame: Option<Pose2>,
    ) -> std::path::PathBuf {
        use std::fmt::Write as _;
        let walls = [
            (Vector2::new(0.0, 0.0), Vector2::new(6.0, 0.0)),
            (Vector2::new(6.0, 0.0), Vector2::new(6.0, 4.0)),
            (Vector2::new(6.0, 4.0), Vector2::new(0.0, 4.0)),
            (Vector2::new(0.0, 4.0), Vector2::new(0.0, 0.0)),
        ];
        let mut text = String::new();
        for (k, x) in [1.5, 2.5, 3.5, 4.5].iter().enumerate() {
            let pose = Pose2::new(*x, 2.0, 1.6 * k as f64);
            let mut ranges = Vec::new();
            for b in 0..361 {
                let bearing = pose.theta - std::f64::consts::FRAC_PI_2
                    + b as f64 * std::f64::consts::PI / 360.0;
                let d = Vector2::new(bearing.cos(), bearing.sin());
                let range = walls
                    .iter()
                    .filter_map(|(a, e)| {
                        let m = slam_core::nalgebra::Matrix2::from_columns(&[d, a - e]);
                        let t = m.try_inverse()? * (a - pose.translation());
                        (t.x > 0.0 && (0.0..=1.0).contains(&t.y)).then_some(t.x)
                    })
                    .fold(f64::INFINITY, f64::min);
                ranges.push(format!("{range:.4}"));
            }
            let odometry = odometry_frame.map_or(pose, |frame| frame.compose(&pose));
            // Twice before the first scan: a motion (of zero) comes before the first
            // reference pose, so the run starts at the origin, not on the reference.
            let repeats = match odometry_frame {
                None => 0,
                Some(_) if k == 0 => 2,
                Some(_) => 1,
            };
            for r in 0..repeats {
                let _ = writeln!(
                    text,
                    "ODOM {} {} {} 0 0 0 {k}.{r} host {k}.{r}",
                    odometry.x, odometry.y, odometry.theta
                );
            }
            let _ = writeln!(
                text,
                "FLASER 361 {} {x} 2.0 {t} {} {} {} {k}.5 host {k}.5",
                ranges.join(" "),
                odometry.x,
                odometry.y,
                odometry.theta,
                t = pose.theta
            );
        }
        let path = dir.join("room.log");
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn a_carmen_room_with_given_poses_becomes_four_walls_with_shared_corners() {
        let dir = temp_dir("room");
        let log = room_log(dir.path());
        let out = dir.path().join("out");
        let config = polygon_config(&format!("carmen:{}", log.display()), &out);
        let summary = run_config(&config, true).unwrap();
        assert!(summary.contains("4 segments"), "{summary}");
        let stage = out.join("em-polygon");
        let metrics: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(stage.join("metrics.json")).unwrap())
                .unwrap();
        assert_eq!(metrics["segments"], 4);
        assert_eq!(metrics["closed_polylines"], 1);
        assert_eq!(metrics["shared_corners"], 4);
        assert!(metrics["mean_point_to_segment_m"].as_f64().unwrap() < 0.01);
        let ratio = metrics["compression_ratio"].as_f64().unwrap();
        assert_eq!(ratio, metrics["points"].as_f64().unwrap() / 8.0);
        // The run's metrics hold the stage's.
        let run: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap())
                .unwrap();
        assert_eq!(run["postprocess"]["em-polygon"]["segments"], 4);
        let map: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(stage.join("map.json")).unwrap())
                .unwrap();
        let features = map["features"].as_array().unwrap();
        assert_eq!(features.len(), 4);
        assert!(features.iter().all(|f| f["type"] == "wall"));
        assert_eq!(map["shared_blocks"].as_array().unwrap().len(), 4);
        for file in ["map.svg", "map.png", "map-walls.png"] {
            assert!(stage.join(file).exists(), "{file} missing");
        }
    }

    /// A log whose reference poses lie in another frame than its odometry (a Radish
    /// corrected log's, say) gets the NEES against them from the path's start: exact
    /// increments score (nearly) 0, where comparing the frames as they are would not.
    #[test]
    fn reference_poses_in_another_frame_give_the_nees_from_the_start() {
        let dir = temp_dir("reference-nees");
        let log = room_log_with_odometry(dir.path(), Some(Pose2::new(-3.0, 8.0, 2.2)));
        let out = dir.path().join("out");
        let text = format!(
            "[data]\nspec = \"carmen:{}\"\n[estimator]\ntype = \"dead-reckoning\"\n\
             [output]\ndir = \"{}\"\nplots = false\n",
            log.display(),
            out.display()
        );
        let config = Config::from_toml(&text, "test").unwrap();
        let summary = run_config(&config, true).unwrap();
        let metrics: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap())
                .unwrap();
        assert!(
            metrics["nees"].is_null(),
            "no true poses: {}",
            metrics["nees"]
        );
        let nees = &metrics["nees_reference"];
        assert!(nees["count"].as_u64().unwrap() >= 3, "{nees}");
        assert!(nees["mean_per_dof"].as_f64().unwrap() < 1e-12, "{nees}");
        assert!(
            summary.contains("pose NEES per dof 0") && summary.contains("against the reference"),
            "{summary}"
        );
    }

    #[test]
    fn a_relocalize_stage_writes_a_path_that_fits_the_walls_at_least_as_well() {
        let dir = temp_dir("relocalize");
        let world = short_world(dir.path());
        let text = format!(
            "[data]\nspec = \"world:{}\"\n[[postprocess]]\ntype = \"relocalize\"\n\
             [output]\ndir = \"{}\"\nplots = false\n",
            world.display(),
            dir.path().join("out").display()
        );
        let config = Config::from_toml(&text, "test").unwrap();
        let summary = run_config(&config, true).unwrap();
        assert!(summary.contains("relocalize:"), "{summary}");
        let stage = dir.path().join("out/relocalize");
        let lines = |path: &Path| std::fs::read_to_string(path).unwrap().lines().count();
        assert_eq!(
            lines(&stage.join("trajectory.tum")),
            lines(&dir.path().join("out/trajectory.tum"))
        );
        let metrics = read_json(&stage.join("metrics.json"));
        let number = |key: &str| metrics[key].as_f64().unwrap();
        assert!(number("relocalized") >= 0.9 * number("scans"), "{metrics}");
        let (before, after) = (
            number("median_point_to_wall_before_m"),
            number("median_point_to_wall_after_m"),
        );
        assert!(after <= before, "median {before} -> {after}");
        let (before, after) = (number("ate_rmse_before_m"), number("ate_rmse_after_m"));
        assert!(after <= 1.2 * before, "ATE {before} -> {after}");
        // The passes over the same places, by the filter's, the relocalized and the true poses.
        let run = read_json(&dir.path().join("out/metrics.json"));
        let passes = &run["revisit_consistency"];
        let median = |figure: &serde_json::Value| figure["median_m"].as_f64().unwrap();
        // The true poses leave only the range noise (1 cm); the filter's stay within 2 cm.
        assert!(median(&passes["reference"]) < 0.01, "{passes}");
        assert!(median(&passes["estimate"]) < 0.02, "{passes}");
        assert_eq!(metrics["revisits_before"], passes["estimate"]);
        assert!(median(&metrics["revisits_after"]) < 0.02, "{metrics}");
    }

    /// The Intel lab with its SLAM-corrected poses (about 160,000 points): run with
    /// `cargo test --release -p slam-cli intel -- --ignored` (BENCHMARKS.md has the figures).
    #[test]
    #[ignore]
    fn the_intel_lab_becomes_a_polygonal_map() {
        let log = Path::new(option_env!("SLAM_DATA").unwrap_or("the real datasets are absent"))
            .join("radish-carmen-corrected/intel-corrected.log.gz");
        assert!(log.exists(), "{} is absent (DATASETS.md)", log.display());
        let dir = temp_dir("intel");
        let out = dir.path().join("out");
        run_config(
            &polygon_config(&format!("carmen:{}", log.display()), &out),
            true,
        )
        .unwrap();
        let metrics = read_json(&out.join("em-polygon/metrics.json"));
        let points = metrics["points"].as_u64().unwrap();
        let mean = metrics["mean_point_to_segment_m"].as_f64().unwrap();
        let ratio = metrics["compression_ratio"].as_f64().unwrap();
        assert!((150_000..170_000).contains(&points), "{points} points");
        assert!(mean < 0.05, "mean point-to-segment distance {mean}");
        assert!(ratio > 50.0, "compression {ratio}");
    }

    #[test]
    fn polygon_stages_without_scans_or_with_bad_keys_are_clear_errors() {
        let dir = temp_dir("errors");
        let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        let config = polygon_config(
            &format!("world:{}", world.display()),
            &dir.path().join("out"),
        );
        let error = run_config(&config, true).unwrap_err().chain();
        assert!(error.contains("no laser scans"), "{error}");
        let error = Config::from_toml(
            "[[postprocess]]\ntype = \"em-polygon\"\nposes = \"gps\"\n",
            "t",
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("gps"), "{error}");
        let error = Config::from_toml(
            "[[postprocess]]\ntype = \"em-polygon\"\n[postprocess.fit]\nsigma = 1\n",
            "t",
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("sigma"), "{error}");
    }
}
