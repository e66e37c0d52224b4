//! `slam eval GT.tum EST.tum`: absolute trajectory error (ATE) and relative pose error (RPE)
//! of an estimated trajectory against ground truth, computed as the common tools compute them
//! (`evo_ape tum GT EST -a`, `evo_rpe tum GT EST`, TUM RGB-D `associate.py` /
//! `evaluate_ate.py`): the computation is [`slam_runtime::eval::trajectory`]; this command
//! reads the files, prints the figures, writes them as JSON and draws both trajectories and
//! the error over time (`EST` with `.eval.png` for its extension, or `--plot FILE`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;
use slam_core::nalgebra::Vector3;
use slam_runtime::eval::trajectory::{
    AlignMode, Ate, ErrorStats, RpeDelta, RpeStats, associate, ate, rpe,
};
use slam_sensors::data::{StampedPose, read_tum, write_atomically};

use crate::error::{CliError, Result};
use crate::plot::TrajectoryComparison;

/// Arguments of `slam eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Ground-truth trajectory (TUM format).
    pub ground_truth: PathBuf,
    /// Estimated trajectory (TUM format).
    pub estimate: PathBuf,
    /// Largest time difference, s, between an estimate pose and the ground-truth pose it is
    /// matched to (as evo's --t_max_diff and associate.py's --max_difference).
    #[arg(long, default_value_t = 0.01)]
    pub max_dt: f64,
    /// Alignment of the estimate onto ground truth before the errors are computed.
    #[arg(long, value_enum, default_value_t = AlignArg::Se3)]
    pub align: AlignArg,
    /// RPE step between the two poses of a compared pair, in --delta-unit.
    #[arg(long, default_value_t = 1.0)]
    pub delta: f64,
    /// Unit of --delta: f (frames: associated poses) or s (seconds).
    #[arg(long, value_enum, default_value_t = DeltaUnit::Frames)]
    pub delta_unit: DeltaUnit,
    /// RPE over all pairs (i, i + delta) instead of consecutive, non-overlapping ones.
    #[arg(long)]
    pub all_pairs: bool,
    /// Also write all numbers to this JSON file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// The plot of both trajectories (the estimate aligned as --align says) and of the
    /// position error over time: .png or .svg [default: ESTIMATE with the extension
    /// .eval.png, beside it].
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Draw no plot.
    #[arg(long, conflicts_with = "plot")]
    pub no_plot: bool,
}

/// How the estimate is aligned onto ground truth before the errors are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AlignArg {
    /// No alignment: the estimate is compared as it is.
    None,
    /// Least-squares rigid transform (rotation + translation; Umeyama 1991 without scale).
    Se3,
    /// Least-squares similarity transform (rotation + translation + scale; Umeyama 1991).
    Sim3,
}

impl From<AlignArg> for AlignMode {
    fn from(arg: AlignArg) -> Self {
        match arg {
            AlignArg::None => AlignMode::None,
            AlignArg::Se3 => AlignMode::Se3,
            AlignArg::Sim3 => AlignMode::Sim3,
        }
    }
}

/// Unit of the RPE step on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeltaUnit {
    /// Frames: associated poses.
    #[value(name = "f", alias = "frames")]
    Frames,
    /// Seconds.
    #[value(name = "s", alias = "seconds")]
    Seconds,
}

/// Everything `slam eval` reports (the JSON file).
#[derive(Debug, Serialize)]
struct Report {
    ground_truth: String,
    estimate: String,
    ground_truth_poses: usize,
    estimate_poses: usize,
    association: AssociationReport,
    alignment: AlignmentReport,
    ate_m: ErrorStats,
    rpe: RpeReport,
}

#[derive(Debug, Serialize)]
struct AssociationReport {
    method: &'static str,
    max_dt_s: f64,
    pairs: usize,
}

#[derive(Debug, Serialize)]
struct AlignmentReport {
    mode: AlignMode,
    method: &'static str,
    /// Rows of the rotation matrix.
    rotation: [[f64; 3]; 3],
    /// The rotation as yaw (z), pitch (y), roll (x), degrees.
    yaw_deg: f64,
    pitch_deg: f64,
    roll_deg: f64,
    translation_m: [f64; 3],
    scale: f64,
}

#[derive(Debug, Serialize)]
struct RpeReport {
    definition: &'static str,
    delta: f64,
    delta_unit: &'static str,
    all_pairs: bool,
    translation_m: ErrorStats,
    rotation_deg: ErrorStats,
}

const ASSOCIATION_METHOD: &str = "nearest timestamp within max_dt_s, smallest |dt| first, \
                                  each pose used at most once (TUM associate.py)";
const RPE_DEFINITION: &str = "E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j), Q ground truth, P aligned \
                              estimate; translation |t(E)|, rotation angle of E (evo_rpe)";

/// The human-readable summary of a report.
fn summary(report: &Report) -> String {
    let mut text = String::new();
    let a = &report.alignment;
    let r = &report.rpe;
    let stats = |s: &ErrorStats| {
        format!(
            "rmse {:.6}  mean {:.6}  median {:.6}  std {:.6}  min {:.6}  max {:.6}",
            s.rmse, s.mean, s.median, s.std, s.min, s.max
        )
    };
    // Writing to a String cannot fail.
    let _ = writeln!(
        text,
        "ground truth {} ({} poses), estimate {} ({} poses)",
        report.ground_truth, report.ground_truth_poses, report.estimate, report.estimate_poses
    );
    let _ = writeln!(
        text,
        "association: {} pairs (nearest timestamp, |dt| <= {} s, each pose used once)",
        report.association.pairs, report.association.max_dt_s
    );
    let _ = writeln!(text, "alignment: {}", a.mode.description());
    if a.mode != AlignMode::None {
        let _ = writeln!(
            text,
            "  yaw {:.6} deg, pitch {:.6} deg, roll {:.6} deg, translation ({:.6}, {:.6}, {:.6}) m, scale {:.9}",
            a.yaw_deg,
            a.pitch_deg,
            a.roll_deg,
            a.translation_m[0],
            a.translation_m[1],
            a.translation_m[2],
            a.scale
        );
    }
    let _ = writeln!(
        text,
        "ATE (translation, m, {} pairs): {}",
        report.ate_m.count,
        stats(&report.ate_m)
    );
    // A rigid alignment leaves the RPE unchanged; a scale does not.
    let scaled = if a.mode == AlignMode::Sim3 {
        format!(", estimate scaled by {:.9}", a.scale)
    } else {
        String::new()
    };
    let _ = writeln!(
        text,
        "RPE (delta {} {}, {} pairs, {} pairs{scaled}):",
        r.delta,
        r.delta_unit,
        if r.all_pairs { "all" } else { "consecutive" },
        r.translation_m.count
    );
    let _ = writeln!(text, "  translation (m):  {}", stats(&r.translation_m));
    let _ = writeln!(text, "  rotation (deg):   {}", stats(&r.rotation_deg));
    text
}

/// The time span of a trajectory, for messages.
fn time_span(poses: &[StampedPose]) -> (f64, f64) {
    poses
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.time), hi.max(p.time))
        })
}

/// Runs `slam eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    if !(args.max_dt.is_finite() && args.max_dt >= 0.0) {
        return Err(CliError::Usage(format!(
            "--max-dt must be a non-negative number of seconds, got {}",
            args.max_dt
        )));
    }
    let delta = match args.delta_unit {
        DeltaUnit::Frames => {
            if !(args.delta >= 1.0 && args.delta.fract() == 0.0 && args.delta < 1e15) {
                return Err(CliError::Usage(format!(
                    "--delta with --delta-unit f must be a whole number of frames >= 1, got {}",
                    args.delta
                )));
            }
            // A whole number below 1e15: exact as usize.
            RpeDelta::Frames(args.delta as usize)
        }
        DeltaUnit::Seconds => {
            if !(args.delta.is_finite() && args.delta > 0.0) {
                return Err(CliError::Usage(format!(
                    "--delta with --delta-unit s must be a positive time, got {}",
                    args.delta
                )));
            }
            RpeDelta::Seconds(args.delta)
        }
    };
    let gt = read_tum(&args.ground_truth)?;
    let est = read_tum(&args.estimate)?;
    for (poses, path, what) in [
        (&gt, &args.ground_truth, "ground-truth"),
        (&est, &args.estimate, "estimated"),
    ] {
        if poses.is_empty() {
            return Err(CliError::Usage(format!(
                "{}: the {what} trajectory holds no poses",
                path.display()
            )));
        }
    }
    let pairs = associate(&gt, &est, args.max_dt);
    if pairs.is_empty() {
        let (g0, g1) = time_span(&gt);
        let (e0, e1) = time_span(&est);
        return Err(CliError::Usage(format!(
            "no pose of {} (times {e0} to {e1} s) has a pose of {} (times {g0} to {g1} s) \
             within --max-dt {} s; check that both use the same clock",
            args.estimate.display(),
            args.ground_truth.display(),
            args.max_dt
        )));
    }
    let mode = AlignMode::from(args.align);
    let ate = ate(&gt, &est, &pairs, mode).map_err(|e| {
        CliError::Usage(format!(
            "{}: {e} (--align none reports the unaligned error)",
            args.estimate.display()
        ))
    })?;
    let rpe = rpe(&gt, &est, &pairs, &ate.alignment, delta, args.all_pairs)?;
    let stats = [&ate.errors, &rpe.translation_m, &rpe.rotation_deg];
    if !stats.iter().all(|s| s.is_finite()) {
        let largest = gt
            .iter()
            .chain(&est)
            .map(|p| p.pose.translation.amax())
            .fold(0.0, f64::max);
        return Err(CliError::Usage(format!(
            "{}: the errors against {} are not finite numbers (coordinates up to {largest:e} \
             m overflow): check the values and units of both files",
            args.estimate.display(),
            args.ground_truth.display()
        )));
    }
    let report = report(args, &gt, &est, pairs.len(), &ate, rpe);
    print!("{}", summary(&report));
    if let Some(path) = &args.json {
        write_json(path, &report)?;
    }
    if let Some(path) = plot_path(args) {
        comparison(args, &gt, &est, &pairs, &ate).save(&path)?;
        println!("plot: {}", path.display());
    }
    Ok(())
}

/// Where the plot goes: `--plot`, else the estimate's path with the extension `.eval.png`;
/// `None` with `--no-plot`.
fn plot_path(args: &EvalArgs) -> Option<PathBuf> {
    if args.no_plot {
        return None;
    }
    Some(
        args.plot
            .clone()
            .unwrap_or_else(|| args.estimate.with_extension("eval.png")),
    )
}

/// The figure of both trajectories (the estimate aligned) and the error of each pair over
/// time.
fn comparison(
    args: &EvalArgs,
    gt: &[StampedPose],
    est: &[StampedPose],
    pairs: &[(usize, usize)],
    ate: &Ate,
) -> TrajectoryComparison {
    let name = |p: &Path| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    let errors = pairs
        .iter()
        .map(|&(g, e)| {
            let aligned = ate.alignment.apply(&est[e].pose.translation);
            (est[e].time, (gt[g].pose.translation - aligned).norm())
        })
        .collect();
    TrajectoryComparison {
        title: format!(
            "{} against {}",
            name(&args.estimate),
            name(&args.ground_truth)
        ),
        ground_truth: gt.iter().map(|p| p.pose.translation.xy()).collect(),
        estimate: est
            .iter()
            .map(|p| ate.alignment.apply(&p.pose.translation).xy())
            .collect(),
        errors,
        labels: [
            format!("ground truth ({} poses)", gt.len()),
            format!(
                "estimate ({} poses, aligned: --align {})",
                est.len(),
                match args.align {
                    AlignArg::None => "none",
                    AlignArg::Se3 => "se3",
                    AlignArg::Sim3 => "sim3",
                }
            ),
            format!(
                "position error of the {} matched poses (ATE rmse {:.3} m)",
                pairs.len(),
                ate.errors.rmse
            ),
        ],
    }
}

fn report(
    args: &EvalArgs,
    gt: &[StampedPose],
    est: &[StampedPose],
    pairs: usize,
    ate: &Ate,
    rpe: RpeStats,
) -> Report {
    let r = &ate.alignment.rotation;
    let t = &ate.alignment.translation;
    let angles = slam_core::Pose3::from_rotation(Vector3::zeros(), r);
    Report {
        ground_truth: args.ground_truth.display().to_string(),
        estimate: args.estimate.display().to_string(),
        ground_truth_poses: gt.len(),
        estimate_poses: est.len(),
        association: AssociationReport {
            method: ASSOCIATION_METHOD,
            max_dt_s: args.max_dt,
            pairs,
        },
        alignment: AlignmentReport {
            mode: AlignMode::from(args.align),
            method: AlignMode::from(args.align).description(),
            rotation: [0, 1, 2].map(|i| [r[(i, 0)], r[(i, 1)], r[(i, 2)]]),
            yaw_deg: angles.yaw.to_degrees(),
            pitch_deg: angles.pitch.to_degrees(),
            roll_deg: angles.roll.to_degrees(),
            translation_m: [t.x, t.y, t.z],
            scale: ate.alignment.scale,
        },
        ate_m: ate.errors,
        rpe: RpeReport {
            definition: RPE_DEFINITION,
            delta: args.delta,
            delta_unit: match args.delta_unit {
                DeltaUnit::Frames => "frames",
                DeltaUnit::Seconds => "s",
            },
            all_pairs: args.all_pairs,
            translation_m: rpe.translation_m,
            rotation_deg: rpe.rotation_deg,
        },
    }
}

fn write_json(path: &Path, report: &Report) -> Result<()> {
    let mut text = serde_json::to_string_pretty(report).map_err(|e| {
        CliError::Runtime(slam_runtime::RuntimeError::Invariant(format!(
            "serializing the report: {e}"
        )))
    })?;
    text.push('\n');
    write_atomically(path, text.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::Pose3;
    use slam_core::nalgebra::{Matrix3, Rotation3};
    use slam_runtime::eval::Alignment;

    fn stamped(time: f64, pose: Pose3) -> StampedPose {
        StampedPose { time, pose }
    }

    /// A non-planar trajectory: a helix with a varying attitude, 0.1 s apart.
    fn helix(n: usize) -> Vec<StampedPose> {
        (0..n)
            .map(|k| {
                let s = k as f64 * 0.1;
                let position = Vector3::new(3.0 * s.cos(), 2.0 * s.sin(), 0.3 * s);
                stamped(s, Pose3::new(position, s, 0.1 * s.sin(), 0.05 * s.cos()))
            })
            .collect()
    }

    /// `p -> scale * rotation * p + translation` applied to every pose.
    fn transformed(
        poses: &[StampedPose],
        scale: f64,
        rotation: &Matrix3<f64>,
        translation: &Vector3<f64>,
    ) -> Vec<StampedPose> {
        poses
            .iter()
            .map(|p| {
                let t = scale * (rotation * p.pose.translation) + translation;
                stamped(
                    p.time,
                    Pose3::from_rotation(t, &(rotation * p.pose.rotation())),
                )
            })
            .collect()
    }

    fn one_to_one(n: usize) -> Vec<(usize, usize)> {
        (0..n).map(|k| (k, k)).collect()
    }

    fn known_rotation() -> Matrix3<f64> {
        Rotation3::from_euler_angles(0.2, -0.3, 1.1).into_inner()
    }

    fn test_dir(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix(&format!("slam-eval-{name}-"))
            .tempdir()
            .unwrap()
    }

    fn args(gt: &Path, est: &Path) -> EvalArgs {
        EvalArgs {
            ground_truth: gt.to_path_buf(),
            estimate: est.to_path_buf(),
            max_dt: 0.01,
            align: AlignArg::Se3,
            delta: 1.0,
            delta_unit: DeltaUnit::Frames,
            all_pairs: false,
            json: None,
            plot: None,
            no_plot: false,
        }
    }

    #[test]
    fn run_prints_and_writes_json() {
        let dir = test_dir("run");
        let gt = helix(50);
        let mut est = transformed(&gt, 1.0, &known_rotation(), &Vector3::new(1.0, 2.0, 3.0));
        for p in &mut est {
            p.time += 0.003;
        }
        let (gt_path, est_path) = (dir.path().join("gt.tum"), dir.path().join("est.tum"));
        slam_sensors::data::write_tum(&gt_path, &gt).unwrap();
        slam_sensors::data::write_tum(&est_path, &est[..45]).unwrap();
        let json = dir.path().join("eval.json");
        let mut a = args(&gt_path, &est_path);
        a.json = Some(json.clone());
        run(&a).unwrap();
        let value: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(value["association"]["pairs"], 45);
        assert_eq!(value["alignment"]["mode"], "se3");
        assert_eq!(value["ate_m"]["count"], 45);
        assert!(value["ate_m"]["rmse"].as_f64().unwrap() < 1e-5);
        assert_eq!(value["rpe"]["translation_m"]["count"], 44);
        assert!(value["rpe"]["rotation_deg"]["max"].as_f64().unwrap() < 1e-4);
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        // The ground truth, the estimate, the JSON and the plot beside the estimate.
        assert_eq!(names.len(), 4, "{names:?}");
        assert!(dir.path().join("est.eval.png").is_file(), "{names:?}");
        // The summary names the alignment.
        let report = report(
            &a,
            &gt,
            &est,
            45,
            &ate(&gt, &est, &one_to_one(45), AlignMode::Se3).unwrap(),
            rpe(
                &gt,
                &est,
                &one_to_one(45),
                &Alignment::identity(),
                RpeDelta::Frames(1),
                false,
            )
            .unwrap(),
        );
        let text = summary(&report);
        assert!(
            text.contains("Umeyama") && text.contains("no scale") && text.contains("ATE"),
            "{text}"
        );
    }

    #[test]
    fn run_draws_both_trajectories_and_the_error() {
        let dir = test_dir("plot");
        let gt = helix(60);
        let mut est = transformed(&gt, 1.0, &known_rotation(), &Vector3::new(1.0, 2.0, 0.0));
        for (k, p) in est.iter_mut().enumerate() {
            p.pose.translation.x += 0.05 * (k as f64 * 0.3).sin();
        }
        let (gt_path, est_path) = (dir.path().join("gt.tum"), dir.path().join("est.tum"));
        slam_sensors::data::write_tum(&gt_path, &gt).unwrap();
        slam_sensors::data::write_tum(&est_path, &est).unwrap();
        let mut a = args(&gt_path, &est_path);
        run(&a).unwrap();
        let png = std::fs::read(dir.path().join("est.eval.png")).unwrap();
        assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"));
        // The PNG's width (big-endian at byte 16) is the figure's.
        assert_eq!(
            u32::from_be_bytes([png[16], png[17], png[18], png[19]]),
            1200
        );
        a.plot = Some(dir.path().join("chosen.svg"));
        run(&a).unwrap();
        let svg = std::fs::read_to_string(dir.path().join("chosen.svg")).unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("position error"),
            "{svg:.200}"
        );
        std::fs::remove_file(dir.path().join("est.eval.png")).unwrap();
        a.plot = None;
        a.no_plot = true;
        run(&a).unwrap();
        assert!(!dir.path().join("est.eval.png").exists());
        // An unknown image format is an error naming the file.
        a.no_plot = false;
        a.plot = Some(dir.path().join("plot.gif"));
        let e = run(&a).unwrap_err().to_string();
        assert!(
            e.contains("plot.gif") && e.contains("unknown image format"),
            "{e}"
        );
    }

    #[test]
    fn run_errors_are_clear() {
        let dir = test_dir("errors");
        let (gt_path, est_path, empty) = (
            dir.path().join("gt.tum"),
            dir.path().join("est.tum"),
            dir.path().join("empty.tum"),
        );
        slam_sensors::data::write_tum(&gt_path, &helix(20)).unwrap();
        let late: Vec<_> = helix(20)
            .into_iter()
            .map(|p| stamped(p.time + 100.0, p.pose))
            .collect();
        slam_sensors::data::write_tum(&est_path, &late).unwrap();
        slam_sensors::data::write_tum(&empty, &[]).unwrap();
        let error = run(&args(&gt_path, &empty)).unwrap_err().to_string();
        assert!(
            error.contains("empty.tum") && error.contains("no poses"),
            "{error}"
        );
        let error = run(&args(&empty, &gt_path)).unwrap_err().to_string();
        assert!(
            error.contains("empty.tum") && error.contains("ground-truth"),
            "{error}"
        );
        let error = run(&args(&gt_path, &est_path)).unwrap_err().to_string();
        assert!(
            error.contains("gt.tum") && error.contains("est.tum") && error.contains("--max-dt"),
            "{error}"
        );
        let missing = run(&args(&dir.path().join("missing.tum"), &est_path))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("missing.tum"), "{missing}");
        let mut bad = args(&gt_path, &gt_path);
        bad.delta = 1.5;
        assert!(matches!(run(&bad), Err(CliError::Usage(_))));
        bad.delta_unit = DeltaUnit::Seconds;
        bad.max_dt = -0.1;
        assert!(matches!(run(&bad), Err(CliError::Usage(_))));
        bad.max_dt = 0.01;
        bad.json = Some(dir.path().join("no-such-folder").join("eval.json"));
        assert!(run(&bad).is_err());
    }

    #[test]
    fn coordinates_that_overflow_are_an_error_not_inf_or_nan() {
        let dir = test_dir("overflow");
        let (gt_path, est_path) = (dir.path().join("gt.tum"), dir.path().join("big.tum"));
        let gt = helix(20);
        let big: Vec<_> = gt
            .iter()
            .map(|p| {
                stamped(
                    p.time,
                    Pose3::new(p.pose.translation * 1e300, 0.0, 0.0, 0.0),
                )
            })
            .collect();
        slam_sensors::data::write_tum(&gt_path, &gt).unwrap();
        slam_sensors::data::write_tum(&est_path, &big).unwrap();
        let mut none = args(&gt_path, &est_path);
        none.align = AlignArg::None;
        let error = run(&none).unwrap_err().to_string();
        assert!(
            error.contains("big.tum") && error.contains("not finite") && error.contains("e300"),
            "{error}"
        );
        let error = run(&args(&gt_path, &est_path)).unwrap_err().to_string();
        assert!(
            error.contains("overflow") && !error.contains("coordinates too large"),
            "{error}"
        );
    }
}
