//! `[estimator] type = "em-polygon"`: EM polygonal approximation of the registered laser
//! points ([`slam_estimators::em_polygon`], Latecki & Lakaemper 2006) as a post-processing
//! estimator.
//!
//! The scans are placed by the poses the data give (`poses = "given"`: the SLAM-corrected
//! poses of the Radish logs, or a simulation's true poses) or by the trajectory of an M-space
//! EKF run first (`poses = "ekf"`, its settings under `[estimator.ekf]`). Every valid return
//! becomes a point in the map frame; the fitted segments become `slam_features::Wall`s (M-space
//! dimension 4: line and both ends), the polyline joints shared corners (eq. 33).
//!
//! ```toml
//! [estimator]
//! type = "em-polygon"
//! poses = "given"        # or "ekf"
//! max_range = 0          # drop returns beyond this range, m (0: keep all)
//! [estimator.fit]        # slam_estimators::EmPolygonParams
//! sigma_min = 0.02
//! ```
//!
//! Outputs: `trajectory.tum` (the poses used), `map.json` (the walls and their shared
//! corners), `metrics.json` (segments, mean point-to-segment distance, compression ratio, the
//! statistics of every iteration), `map.svg` / `map.png` (points, walls, path) and
//! `map-walls.png` (walls and path alone).

use std::time::Instant;

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, Vector2, Vector3};
use slam_core::{CoordBlock, Estimator, FeatureMap, Observation, Pose2, Pose3, UpdateReport};
use slam_estimators::em_polygon::{IterationStats, PolygonMap};
use slam_estimators::{EkfParams, EmPolygonParams, fit_polygons};
use slam_features::Wall;
use slam_sensors::data::{StampedPose, write_tum};
use slam_sensors::{Event, LaserScan, TruthKind};

use crate::config::{Config, EstimatorConfig};
use crate::data::{DataSpec, Loaded};
use crate::error::{CliError, Result};
use crate::outputs::{map_json, write_text};
use crate::plot::{Figure, palette};

/// Where the poses that place the scans come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PoseSource {
    /// The poses the data give (true poses, else reference poses).
    #[default]
    Given,
    /// The trajectory of the M-space EKF, run first on the same data.
    Ekf,
}

/// The `[estimator]` table of `type = "em-polygon"`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmPolygonConfig {
    /// Where the scan poses come from.
    pub poses: PoseSource,
    /// Returns beyond this range are dropped, m (0: none is).
    pub max_range: f64,
    /// Settings of the fit.
    pub fit: EmPolygonParams,
    /// Settings of the EKF, for `poses = "ekf"`.
    pub ekf: EkfParams,
}

/// The fitted walls as an [`Estimator`], so that the standard map outputs apply: it holds a
/// map and the last pose, and estimates nothing.
struct PolygonEstimator {
    map: FeatureMap,
    pose: Pose2,
}

impl Estimator<Pose2> for PolygonEstimator {
    fn name(&self) -> &'static str {
        "em-polygon"
    }

    fn predict(&mut self, _: &dyn slam_core::MotionModel<Pose2>) -> slam_core::Result<()> {
        Err(slam_core::Error::InvalidArgument(
            "em-polygon is post-processing: it does not track poses".into(),
        ))
    }

    fn update(&mut self, _: &[Observation]) -> slam_core::Result<UpdateReport> {
        Err(slam_core::Error::InvalidArgument(
            "em-polygon is post-processing: it takes registered points".into(),
        ))
    }

    fn pose(&self) -> Pose2 {
        self.pose
    }

    fn pose_covariance(&self) -> DMatrix<f64> {
        DMatrix::zeros(3, 3)
    }

    fn map(&self) -> &FeatureMap {
        &self.map
    }

    fn row_covariance(&self, _: slam_core::RowOwner) -> Option<DMatrix<f64>> {
        None
    }
}

/// `metrics.json` of an em-polygon run.
#[derive(Serialize)]
struct Metrics {
    data: String,
    estimator: &'static str,
    poses: PoseSource,
    seed: u64,
    scans: usize,
    points: usize,
    segments: usize,
    polylines: usize,
    closed_polylines: usize,
    /// Polyline joints that became shared wall corners.
    shared_corners: usize,
    /// Mean distance of the points to their nearest segment, m.
    mean_point_to_segment_m: Option<f64>,
    /// Median of the same, m.
    median_point_to_segment_m: Option<f64>,
    /// Points per segment endpoint (points : 2 segments).
    compression_ratio: Option<f64>,
    iterations: usize,
    converged: bool,
    /// Seconds of the fit alone.
    fit_time_s: f64,
    /// Seconds of the whole run (EKF, registration, fit).
    wall_time_s: f64,
    /// ATE of the EKF trajectory (`poses = "ekf"` on data with truth), m.
    ate_rmse_m: Option<f64>,
    iteration_stats: Vec<IterationStats>,
    config: Config,
}

/// Poses with their times.
type TimedPoses = Vec<(f64, Pose2)>;

/// A scan with its time and mount.
struct TimedScan {
    time: f64,
    scan: LaserScan,
    robot_from_sensor: Pose3,
}

/// The pose at `time`: the last pose at or before it.
fn pose_at(poses: &[(f64, Pose2)], time: f64) -> Option<Pose2> {
    let k = poses.partition_point(|(t, _)| *t <= time);
    k.checked_sub(1).map(|k| poses[k].1)
}

/// The valid returns of the scans placed by `poses`, in the map frame.
fn register(scans: &[TimedScan], poses: &[(f64, Pose2)], max_range: f64) -> Vec<Vector2<f64>> {
    let mut points = Vec::new();
    for s in scans {
        let Some(pose) = pose_at(poses, s.time) else {
            continue;
        };
        let world_from_sensor = pose.to_pose3(0.0).compose(&s.robot_from_sensor);
        for p in s.scan.points() {
            if max_range > 0.0 && p.range > max_range {
                continue;
            }
            let q =
                world_from_sensor.transform_point(&Vector3::new(p.position.x, p.position.y, 0.0));
            points.push(q.xy());
        }
    }
    points
}

/// The fitted segments as walls (line and both ends estimated), with the polyline joints as
/// shared corners. Returns the map and the number of shared corners.
fn walls(fit: &PolygonMap) -> Result<(FeatureMap, usize)> {
    let mut map = FeatureMap::new();
    let mut ids = Vec::new();
    for (k, s) in fit.segments.iter().enumerate() {
        let wall = Wall::new(s.start, s.end)
            .and_then(|w| w.with_subspaces(&["line", "start", "end"]))
            .map_err(|e| CliError::Usage(format!("segment {k} cannot be a wall: {e}")))?;
        ids.push(map.insert(Box::new(wall))?);
    }
    let mut shared = 0;
    for polyline in &fit.polylines {
        let n = polyline.segments.len();
        let joints = if polyline.closed {
            n
        } else {
            n.saturating_sub(1)
        };
        for j in 0..joints {
            let (a, a_reversed) = polyline.segments[j];
            let (b, b_reversed) = polyline.segments[(j + 1) % n];
            // Leaving `a` through its end (start when walked reversed), entering `b` at its start.
            let a_end = usize::from(!a_reversed);
            let b_end = usize::from(b_reversed);
            let vertex = polyline.vertices[(j + 1) % polyline.vertices.len()];
            map.share(
                &[(ids[a], a_end), (ids[b], b_end)],
                CoordBlock::Point2(vertex),
            )?;
            shared += 1;
        }
    }
    Ok((map, shared))
}

/// Runs `[estimator] type = "em-polygon"` and writes its outputs; returns a one-line summary.
pub fn run_config(config: &Config, polygon: &EmPolygonConfig, quiet: bool) -> Result<String> {
    if !(polygon.max_range.is_finite() && polygon.max_range >= 0.0) {
        return Err(CliError::Usage(format!(
            "[estimator] max_range must be 0 or positive, got {}",
            polygon.max_range
        )));
    }
    polygon.fit.validate()?;
    let clock = Instant::now();
    let spec: DataSpec = config.data.spec.parse()?;
    let loaded = spec.load_with(config.data.seed, &config.data.reader_options())?;
    let name = loaded.dataset.name.clone();
    let scans: Vec<TimedScan> = loaded
        .dataset
        .events
        .iter()
        .take(match config.data.max_events {
            0 => usize::MAX,
            n => n,
        })
        .filter_map(|e| match &e.event {
            Event::Scan {
                scan,
                robot_from_sensor,
            } => Some(TimedScan {
                time: e.time,
                scan: scan.clone(),
                robot_from_sensor: *robot_from_sensor,
            }),
            _ => None,
        })
        .collect();
    if scans.is_empty() {
        return Err(CliError::Usage(format!(
            "{name}: no laser scans, nothing for em-polygon to approximate"
        )));
    }
    let (poses, ate_rmse_m) = match polygon.poses {
        PoseSource::Given => (given_poses(&loaded)?, None),
        PoseSource::Ekf => ekf_poses(config, polygon, loaded, quiet)?,
    };
    let points = register(&scans, &poses, polygon.max_range);
    let fit_clock = Instant::now();
    let fit = fit_polygons(&points, &polygon.fit)?;
    let fit_time_s = fit_clock.elapsed().as_secs_f64();
    let (map, shared_corners) = walls(&fit)?;
    let estimator = PolygonEstimator {
        map,
        pose: poses.last().map_or(Pose2::identity(), |p| p.1),
    };
    let metrics = Metrics {
        data: name.clone(),
        estimator: config.estimator.name(),
        poses: polygon.poses,
        seed: config.data.seed,
        scans: scans.len(),
        points: points.len(),
        segments: fit.segments.len(),
        polylines: fit.polylines.len(),
        closed_polylines: fit.polylines.iter().filter(|p| p.closed).count(),
        shared_corners,
        mean_point_to_segment_m: fit.mean_distance,
        median_point_to_segment_m: fit.median_distance,
        compression_ratio: fit.compression_ratio,
        iterations: fit.iterations.len(),
        converged: fit.converged,
        fit_time_s,
        wall_time_s: clock.elapsed().as_secs_f64(),
        ate_rmse_m,
        iteration_stats: fit.iterations.clone(),
        config: config.clone(),
    };

    let dir = &config.output.dir;
    std::fs::create_dir_all(dir).map_err(|e| CliError::Output {
        path: dir.display().to_string(),
        message: e.to_string(),
    })?;
    let trajectory: Vec<StampedPose> = poses
        .iter()
        .map(|(time, pose)| StampedPose {
            time: *time,
            pose: pose.to_pose3(0.0),
        })
        .collect();
    write_tum(&dir.join("trajectory.tum"), &trajectory)?;
    write_text(dir, "map.json", &map_json(&estimator)?)?;
    let json = serde_json::to_string_pretty(&metrics)
        .map_err(|e| CliError::Usage(format!("serializing metrics: {e}")))?;
    write_text(dir, "metrics.json", &json)?;
    if config.output.plots {
        let with_points = figure(&name, Some(&points), &fit, &poses);
        with_points.save(&dir.join("map.svg"))?;
        with_points.save(&dir.join("map.png"))?;
        figure(&name, None, &fit, &poses).save(&dir.join("map-walls.png"))?;
    }
    let number =
        |v: Option<f64>, digits: usize| v.map_or("n/a".into(), |v| format!("{v:.digits$}"));
    Ok(format!(
        "{name}: {} points of {} scans -> {} segments in {} polylines after {} iterations \
         ({:.1} s); mean point-to-segment distance {} m; compression {}:1; outputs in {}",
        points.len(),
        scans.len(),
        fit.segments.len(),
        fit.polylines.len(),
        fit.iterations.len(),
        fit_time_s,
        number(fit.mean_distance, 3),
        number(fit.compression_ratio, 0),
        dir.display()
    ))
}

/// The poses the data give: true poses when there are some, else reference poses.
fn given_poses(loaded: &Loaded) -> Result<Vec<(f64, Pose2)>> {
    let of_kind = |kind: TruthKind| -> Vec<(f64, Pose2)> {
        loaded
            .dataset
            .events
            .iter()
            .filter_map(|e| match &e.event {
                Event::GroundTruth { pose, kind: k } if *k == kind => Some((e.time, *pose)),
                _ => None,
            })
            .collect()
    };
    let poses = match of_kind(TruthKind::True) {
        poses if !poses.is_empty() => poses,
        _ => of_kind(TruthKind::Reference),
    };
    if poses.is_empty() {
        return Err(CliError::Usage(format!(
            "{}: the data give no poses; use poses = \"ekf\" to place the scans by the EKF",
            loaded.dataset.name
        )));
    }
    Ok(poses)
}

/// The trajectory of the EKF run on the data, and its ATE where the data have truth.
fn ekf_poses(
    config: &Config,
    polygon: &EmPolygonConfig,
    loaded: Loaded,
    quiet: bool,
) -> Result<(TimedPoses, Option<f64>)> {
    let mut ekf_config = config.clone();
    ekf_config.estimator = EstimatorConfig::Ekf(polygon.ekf.clone());
    let (sigma_range, noise_factor) = crate::run::sigma_range(&ekf_config, &loaded)?;
    let bar = crate::pipeline::progress_bar(loaded.dataset.events.len(), quiet);
    let result =
        crate::pipeline::run(&ekf_config, loaded.dataset, sigma_range, noise_factor, &bar)?;
    let ate = crate::outputs::trajectory_errors(&result)?.map(|t| t.ate_rmse_m);
    Ok((
        result.estimates.iter().map(|r| (r.time, r.pose)).collect(),
        ate,
    ))
}

/// The registered points (grey, when given), the walls as polylines (blue) and the path.
fn figure(
    name: &str,
    points: Option<&[Vector2<f64>]>,
    fit: &PolygonMap,
    poses: &[(f64, Pose2)],
) -> Figure {
    let mut figure = Figure::new(
        format!(
            "{name}: em-polygon, {} segments over {} points",
            fit.segments.len(),
            fit.points
        ),
        1600,
    );
    if let Some(points) = points {
        figure.dots(points.to_vec(), palette::TRUTH, 1);
        figure.legend(
            format!("{} registered points", points.len()),
            palette::TRUTH,
        );
    }
    figure.polyline(
        poses.iter().map(|p| p.1.translation()).collect(),
        palette::PATH,
        1,
    );
    figure.legend("path", palette::PATH);
    for polyline in &fit.polylines {
        let mut vertices = polyline.vertices.clone();
        if polyline.closed
            && let Some(first) = vertices.first().copied()
        {
            vertices.push(first);
        }
        figure.polyline(vertices, palette::WALL, 3);
    }
    figure.legend(
        format!(
            "{} walls in {} polylines",
            fit.segments.len(),
            fit.polylines.len()
        ),
        palette::WALL,
    );
    figure
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh folder for one test's files, removed when dropped.
    fn temp_dir(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix(&format!("slam-cli-polygon-{name}-"))
            .tempdir()
            .unwrap()
    }

    /// A CARMEN log of a robot in a 6 m x 4 m room, scanning from a few places.
    fn room_log(dir: &std::path::Path) -> std::path::PathBuf {
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
            let _ = writeln!(
                text,
                "FLASER 361 {} {x} 2.0 {t} {x} 2.0 {t} {k}.0 host {k}.0",
                ranges.join(" "),
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
        let text = format!(
            "[data]\nspec = \"carmen:{}\"\n[estimator]\ntype = \"em-polygon\"\n[output]\ndir = \"{}\"\n",
            log.display(),
            dir.path().join("out").display()
        );
        let config = Config::from_toml(&text, "test").unwrap();
        let summary = crate::run::run_config(&config, true).unwrap();
        assert!(summary.contains("4 segments"), "{summary}");
        let metrics: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("out/metrics.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(metrics["segments"], 4);
        assert_eq!(metrics["closed_polylines"], 1);
        assert_eq!(metrics["shared_corners"], 4);
        assert!(metrics["mean_point_to_segment_m"].as_f64().unwrap() < 0.01);
        let ratio = metrics["compression_ratio"].as_f64().unwrap();
        assert_eq!(ratio, metrics["points"].as_f64().unwrap() / 8.0);
        let map: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("out/map.json")).unwrap(),
        )
        .unwrap();
        let features = map["features"].as_array().unwrap();
        assert_eq!(features.len(), 4);
        assert!(features.iter().all(|f| f["type"] == "wall"));
        assert_eq!(map["shared_blocks"].as_array().unwrap().len(), 4);
        for file in ["trajectory.tum", "map.svg", "map.png", "map-walls.png"] {
            assert!(dir.path().join("out").join(file).exists(), "{file} missing");
        }
    }

    /// The Intel lab with its SLAM-corrected poses (about 160,000 points): run with
    /// `cargo test --release -p slam-cli intel -- --ignored` (BENCHMARKS.md has the figures).
    #[test]
    #[ignore]
    fn the_intel_lab_becomes_a_polygonal_map() {
        let log = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/datasets/radish-carmen-corrected/intel-corrected.log.gz");
        if !log.exists() {
            eprintln!("skipped: {} is absent", log.display());
            return;
        }
        let dir = temp_dir("intel");
        let text = format!(
            "[data]\nspec = \"carmen:{}\"\n[estimator]\ntype = \"em-polygon\"\n[output]\ndir = \"{}\"\n",
            log.display(),
            dir.path().join("out").display()
        );
        let config = Config::from_toml(&text, "test").unwrap();
        crate::run::run_config(&config, true).unwrap();
        let metrics: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("out/metrics.json")).unwrap(),
        )
        .unwrap();
        let points = metrics["points"].as_u64().unwrap();
        let mean = metrics["mean_point_to_segment_m"].as_f64().unwrap();
        let ratio = metrics["compression_ratio"].as_f64().unwrap();
        assert!((150_000..170_000).contains(&points), "{points} points");
        assert!(mean < 0.05, "mean point-to-segment distance {mean}");
        assert!(ratio > 50.0, "compression {ratio}");
    }

    #[test]
    fn data_without_scans_or_poses_are_clear_errors() {
        let dir = temp_dir("errors");
        let world =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        let text = format!(
            "[data]\nspec = \"world:{}\"\n[estimator]\ntype = \"em-polygon\"\n[output]\ndir = \"{}\"\n",
            world.display(),
            dir.path().join("out").display()
        );
        let config = Config::from_toml(&text, "test").unwrap();
        let error = crate::run::run_config(&config, true)
            .unwrap_err()
            .to_string();
        assert!(error.contains("no laser scans"), "{error}");
        let error = Config::from_toml("[estimator]\ntype = \"em-polygon\"\nposes = \"gps\"\n", "t")
            .unwrap_err()
            .to_string();
        assert!(error.contains("gps"), "{error}");
        let error = Config::from_toml(
            "[estimator]\ntype = \"em-polygon\"\n[estimator.fit]\nsigma = 1\n",
            "t",
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("sigma"), "{error}");
    }
}
