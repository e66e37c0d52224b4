//! The standard outputs of `slam run`: `trajectory.tum`, `map.json`, `metrics.json`,
//! `map.svg` and `map.png` (and `map_path.tum` for a particle filter), and the metrics they
//! hold.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;
use slam_core::nalgebra::{DMatrix, Matrix2, Vector2, Vector3};
use slam_core::{
    CoordBlock, Estimator, Feature, FeatureId, Pose2, RowOwner, chi2_quantile, downcast_feature,
};
use slam_examples::EndpointWall;
use slam_features::{HLine, Point, Pole, PpcaLine, Wall};
use slam_sensors::TruthKind;
use slam_sensors::data::{StampedPose, write_atomically, write_tum};
use slam_sensors::events::KnownLandmark;
use slam_sensors::sim::TrueMap;

use crate::error::{CliError, Result};
use crate::eval::{AlignMode, Alignment, ErrorStats, associate, ate, umeyama};
use crate::pipeline::RunResult;
use crate::plot::{Figure, palette};

/// The estimated trajectory as stamped 3-D poses (z = 0).
pub fn trajectory(result: &RunResult) -> Vec<StampedPose> {
    result
        .estimates
        .iter()
        .map(|r| StampedPose {
            time: r.time,
            pose: r.pose.to_pose3(0.0),
        })
        .collect()
}

/// Whether feature `id` has rows in the estimator's state (it is not tentative).
pub fn confirmed(estimator: &dyn Estimator<Pose2>, id: FeatureId) -> bool {
    estimator
        .map()
        .row_owners(id)
        .is_ok_and(|owners| !owners.is_empty())
}

/// The covariance of a feature's coordinates from its own rows, `B~ C_pp B~^T`, plus the
/// identity rows of its shared blocks (cross terms between them are left out).
fn coordinate_covariance(estimator: &dyn Estimator<Pose2>, id: FeatureId) -> Option<DMatrix<f64>> {
    let map = estimator.map();
    let feature = map.get(id).ok()?;
    let coordinates = feature.coordinates();
    let n = coordinates.dim();
    let mut c = DMatrix::zeros(n, n);
    if feature.mspace_dim() > 0 {
        let own = estimator.row_covariance(RowOwner::Feature(id))?;
        let dual = feature.dual().ok()?;
        c += &dual * own * dual.transpose();
    }
    for (k, link) in map.links(id).ok()?.iter().enumerate() {
        if let Some(shared) = link {
            let block = estimator.row_covariance(RowOwner::Shared(*shared))?;
            let offset = coordinates.offset(k);
            c.view_mut((offset, offset), block.shape())
                .copy_from(&block);
        }
    }
    Some(c)
}

/// One feature of `map.json`.
#[derive(Serialize)]
struct MapFeature {
    id: usize,
    #[serde(rename = "type")]
    kind: &'static str,
    mspace_dim: usize,
    subspaces: Vec<&'static str>,
    confirmed: bool,
    landmark_id: Option<u64>,
    coordinates: Vec<CoordBlock>,
    /// Shared block of each coordinate block, if any.
    shared_blocks: Vec<Option<usize>>,
    /// Covariance of the feature's own M-space rows.
    covariance: Option<Vec<Vec<f64>>>,
    /// The feature as serialized by its type (typetag), to read it back.
    feature: serde_json::Value,
}

#[derive(Serialize)]
struct MapShared {
    id: usize,
    value: CoordBlock,
    members: Vec<(usize, usize)>,
    covariance: Option<Vec<Vec<f64>>>,
}

#[derive(Serialize)]
struct MapFile {
    frame: &'static str,
    features: Vec<MapFeature>,
    shared_blocks: Vec<MapShared>,
}

fn rows(m: &DMatrix<f64>) -> Vec<Vec<f64>> {
    m.row_iter().map(|r| r.iter().copied().collect()).collect()
}

/// `map.json`: every feature (tentative ones flagged) with coordinates, M-space dimension
/// and covariance, and the shared blocks.
pub fn map_json(estimator: &dyn Estimator<Pose2>) -> Result<String> {
    let map = estimator.map();
    let mut features = Vec::new();
    for (id, feature) in map.iter() {
        let value = serde_json::to_value(feature as &dyn Feature)
            .map_err(|e| CliError::Usage(format!("serializing feature {}: {e}", id.0)))?;
        features.push(MapFeature {
            id: id.0,
            kind: feature.kind(),
            mspace_dim: feature.mspace_dim(),
            subspaces: feature.active_subspaces().iter().map(|s| s.name).collect(),
            confirmed: confirmed(estimator, id),
            landmark_id: estimator.landmark_id(id),
            coordinates: feature.coordinates().blocks().to_vec(),
            shared_blocks: map.links(id)?.iter().map(|l| l.map(|s| s.0)).collect(),
            covariance: estimator
                .row_covariance(RowOwner::Feature(id))
                .map(|c| rows(&c)),
            feature: value,
        });
    }
    let shared_blocks = map
        .shared_blocks()
        .map(|(id, block)| MapShared {
            id: id.0,
            value: block.value,
            members: block.members.iter().map(|(f, k)| (f.0, *k)).collect(),
            covariance: estimator
                .row_covariance(RowOwner::Shared(id))
                .map(|c| rows(&c)),
        })
        .collect();
    serde_json::to_string_pretty(&MapFile {
        frame: "map (world) frame, metres",
        features,
        shared_blocks,
    })
    .map_err(|e| CliError::Usage(format!("serializing the map: {e}")))
}

/// Summary of a chi-square statistic over a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ChiSquareSummary {
    /// Number of values.
    pub count: usize,
    /// Mean of the values divided by their degrees of freedom (1 when consistent).
    pub mean_per_dof: f64,
    /// Fraction of values inside their two-sided 95% chi-square interval.
    pub within_95: f64,
}

/// Summarizes `(value, dof)` pairs.
pub fn chi_square_summary(values: &[(f64, usize)]) -> Result<ChiSquareSummary> {
    if values.is_empty() {
        return Ok(ChiSquareSummary::default());
    }
    let mut bands: BTreeMap<usize, (f64, f64)> = BTreeMap::new();
    let mut inside = 0;
    let mut sum = 0.0;
    for &(value, dof) in values {
        if dof == 0 {
            continue;
        }
        let band = match bands.get(&dof) {
            Some(b) => *b,
            None => {
                let b = (chi2_quantile(0.025, dof)?, chi2_quantile(0.975, dof)?);
                bands.insert(dof, b);
                b
            }
        };
        inside += usize::from(value >= band.0 && value <= band.1);
        sum += value / dof as f64;
    }
    Ok(ChiSquareSummary {
        count: values.len(),
        mean_per_dof: sum / values.len() as f64,
        within_95: inside as f64 / values.len() as f64,
    })
}

/// The independent true poses of a run, by the bits of their time.
fn true_poses(result: &RunResult) -> BTreeMap<u64, Pose2> {
    result
        .truth
        .iter()
        .filter(|(_, _, kind)| *kind == TruthKind::True)
        .map(|(t, p, _)| (t.to_bits(), *p))
        .collect()
}

/// The robot-pose NEES at every estimate that has a true pose at the same time.
pub fn pose_nees(result: &RunResult) -> Vec<(f64, f64)> {
    let truth = true_poses(result);
    result
        .estimates
        .iter()
        .filter_map(|r| {
            let truth = truth.get(&r.time.to_bits())?;
            let e = slam_core::RobotPose::ominus(truth, &r.pose);
            let e = Vector3::new(e[0], e[1], e[2]);
            // A pose known exactly (the start) has no NEES.
            let cholesky = r.covariance.cholesky()?;
            if cholesky.l().diagonal().min() < 1e-9 {
                return None;
            }
            Some((r.time, (e.transpose() * cholesky.inverse() * e)[(0, 0)]))
        })
        .collect()
}

/// Per-type map errors.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MapError {
    /// Root mean square over every confirmed feature with a true counterpart, m.
    pub rms_m: f64,
    /// Median of the same errors, m (robust to a few gross ones).
    pub median_m: f64,
    /// Number of features compared.
    pub count: usize,
    /// Error of each landmark by its id, when landmarks are matched by id, m.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub by_landmark: BTreeMap<u64, f64>,
    /// The same by feature type: `(count, rms)`.
    pub by_type: BTreeMap<String, (usize, f64)>,
    /// How the features were compared with the truth.
    pub method: String,
}

/// Distance from `p` to the segment `a b`.
fn segment_distance(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let e = b - a;
    let t = ((p - a).dot(&e) / e.norm_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + e * t)).norm()
}

/// Distance from `p` to the infinite line through `a` and `b`.
fn line_distance(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let t = (b - a).normalize();
    let d = p - a;
    (d - t * t.dot(&d)).norm()
}

/// The error of an estimated segment against the closest true segment of similar direction
/// (within 15 degrees): RMS of the distances of its two ends to the true line.
fn segment_error(
    a: Vector2<f64>,
    b: Vector2<f64>,
    truths: &[(Vector2<f64>, Vector2<f64>)],
) -> Option<f64> {
    let mid = (a + b) / 2.0;
    let direction = (b - a).normalize();
    truths
        .iter()
        .filter(|(p, q)| (q - p).normalize().dot(&direction).abs() > 15f64.to_radians().cos())
        .min_by(|x, y| {
            segment_distance(&mid, &x.0, &x.1).total_cmp(&segment_distance(&mid, &y.0, &y.1))
        })
        .map(|(p, q)| {
            let (da, db) = (line_distance(&a, p, q), line_distance(&b, p, q));
            ((da * da + db * db) / 2.0).sqrt()
        })
}

/// Map error of the confirmed features against a simulated world's true map: walls and
/// ceiling lines by the distance of their ends to the closest true line of similar
/// direction (plus the height error of ceiling lines), poles and lamps by the distance to the
/// nearest true one.
pub fn map_error_against_truth(
    estimator: &dyn Estimator<Pose2>,
    truth: &TrueMap,
    alignment: Option<&Alignment>,
) -> MapError {
    let place3 = |p: Vector3<f64>| alignment.map_or(p, |a| a.apply(&p));
    let place = |p: Vector2<f64>| place3(Vector3::new(p.x, p.y, 0.0)).xy();
    let mut errors: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let true_lines: Vec<_> = truth
        .ceiling_lines
        .iter()
        .map(|(a, b)| (a.xy(), b.xy()))
        .collect();
    for (id, feature) in estimator.map().iter() {
        if !confirmed(estimator, id) {
            continue;
        }
        let error = if let Some(wall) = downcast_feature::<Wall>(feature) {
            segment_error(place(wall.start()), place(wall.end()), &truth.walls)
        } else if let Some(wall) = downcast_feature::<EndpointWall>(feature) {
            segment_error(place(wall.start()), place(wall.end()), &truth.walls)
        } else if let Some(line) = downcast_feature::<PpcaLine>(feature) {
            segment_error(place(line.start()), place(line.end()), &truth.walls)
        } else if let Some(pole) = downcast_feature::<Pole>(feature) {
            truth
                .poles
                .iter()
                .map(|(c, _)| (c - place(pole.centre())).norm())
                .min_by(f64::total_cmp)
        } else if let Some(line) = downcast_feature::<HLine>(feature) {
            if line.mspace_dim() < 3 {
                continue;
            }
            let horizontal = segment_error(line.start().xy(), line.end().xy(), &true_lines);
            let height = truth
                .ceiling_lines
                .iter()
                .map(|(a, _)| a.z)
                .min_by(|x, y| {
                    (x - line.height())
                        .abs()
                        .total_cmp(&(y - line.height()).abs())
                })
                .map(|z| z - line.height());
            horizontal.zip(height).map(|(h, z)| (h * h + z * z).sqrt())
        } else if let Some(point) = downcast_feature::<Point>(feature) {
            if point.mspace_dim() < 3 {
                continue;
            }
            truth
                .lamps
                .iter()
                .map(|l| (l - place3(point.position())).norm())
                .min_by(f64::total_cmp)
        } else {
            None
        };
        if let Some(error) = error {
            errors
                .entry(feature.kind().to_string())
                .or_default()
                .push(error);
        }
    }
    let frame = if alignment.is_some() {
        "; the map is first moved by the trajectory's ATE alignment"
    } else {
        ""
    };
    summarize(
        errors,
        &format!(
            "walls and ceiling lines: RMS distance of their ends to the closest true line \
             within 15 degrees (ceiling lines: with the height error); poles and lamps: \
             distance to the nearest true one{frame}"
        ),
    )
}

/// Map error against known landmarks matched by landmark id (rb2d, MR.CLAM). With `align`,
/// the estimated positions are first aligned onto the known ones by the least-squares rigid
/// transform (the map frame of a run is its first pose, not the survey frame).
pub fn map_error_against_landmarks(
    estimator: &dyn Estimator<Pose2>,
    landmarks: &[KnownLandmark],
    align: bool,
) -> Result<MapError> {
    let known: BTreeMap<u64, Vector2<f64>> = landmarks.iter().map(|l| (l.id, l.position)).collect();
    let mut pairs = Vec::new();
    for (id, feature) in estimator.map().iter() {
        if !confirmed(estimator, id) {
            continue;
        }
        let Some(truth) = estimator.landmark_id(id).and_then(|l| known.get(&l)) else {
            continue;
        };
        let estimate = match feature.coordinates().blocks().first() {
            Some(CoordBlock::Point3(p)) => p.xy(),
            Some(CoordBlock::Point2(p)) => *p,
            _ => match feature.coordinates().blocks().get(1) {
                Some(CoordBlock::Point2(p)) => *p,
                _ => continue,
            },
        };
        pairs.push((
            feature.kind().to_string(),
            estimate,
            *truth,
            estimator.landmark_id(id).unwrap_or_default(),
        ));
    }
    let mut method = "known landmarks matched by id: distance of each estimate to its \
                      surveyed position"
        .to_string();
    if align && pairs.len() >= 3 {
        let from: Vec<_> = pairs
            .iter()
            .map(|(_, e, _, _)| Vector3::new(e.x, e.y, 0.0))
            .collect();
        let to: Vec<_> = pairs
            .iter()
            .map(|(_, _, t, _)| Vector3::new(t.x, t.y, 0.0))
            .collect();
        let alignment = umeyama(&from, &to, false)?;
        for ((_, estimate, _, _), p) in pairs.iter_mut().zip(&from) {
            *estimate = alignment.apply(p).xy();
        }
        method.push_str(", after the least-squares rigid alignment of the estimated landmarks");
    }
    let mut errors: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut by_landmark = BTreeMap::new();
    for (kind, estimate, truth, landmark) in pairs {
        let error = (estimate - truth).norm();
        errors.entry(kind).or_default().push(error);
        by_landmark.insert(landmark, error);
    }
    Ok(MapError {
        by_landmark,
        ..summarize(errors, &method)
    })
}

fn summarize(errors: BTreeMap<String, Vec<f64>>, method: &str) -> MapError {
    let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let mut all: Vec<f64> = errors.values().flatten().copied().collect();
    all.sort_by(f64::total_cmp);
    let median = match all.len() {
        0 => 0.0,
        n if n % 2 == 1 => all[n / 2],
        n => 0.5 * (all[n / 2 - 1] + all[n / 2]),
    };
    MapError {
        rms_m: rms(&all),
        median_m: median,
        count: all.len(),
        by_landmark: BTreeMap::new(),
        by_type: errors
            .iter()
            .map(|(k, v)| (k.clone(), (v.len(), rms(v))))
            .collect(),
        method: method.to_string(),
    }
}

/// The coordinates a feature holds in shared blocks (each counts as M-space rows of the
/// feature: a wall with two shared corners has dimension 4).
fn shared_dims(map: &slam_core::FeatureMap, id: FeatureId) -> usize {
    let Ok(feature) = map.get(id) else { return 0 };
    map.links(id).map_or(0, |links| {
        links
            .iter()
            .zip(feature.coordinates().blocks())
            .filter(|(link, _)| link.is_some())
            .map(|(_, block)| block.dim())
            .sum()
    })
}

/// Features by type and M-space dimension, shared blocks included (tentative ones under
/// dimension 0).
pub fn feature_counts(
    estimator: &dyn Estimator<Pose2>,
) -> BTreeMap<String, BTreeMap<usize, usize>> {
    let mut counts: BTreeMap<String, BTreeMap<usize, usize>> = BTreeMap::new();
    for (id, feature) in estimator.map().iter() {
        let dim = if confirmed(estimator, id) {
            feature.mspace_dim() + shared_dims(estimator.map(), id)
        } else {
            0
        };
        *counts
            .entry(feature.kind().to_string())
            .or_default()
            .entry(dim)
            .or_default() += 1;
    }
    counts
}

/// The trajectory errors of a run against its ground truth (or reference) poses.
#[derive(Clone, Debug, Serialize)]
pub struct TrajectoryErrors {
    /// ATE after the least-squares rigid alignment (Umeyama, no scale; `evo_ape -a`), m.
    pub ate_rmse_m: f64,
    /// ATE without alignment, m.
    pub ate_rmse_unaligned_m: f64,
    /// Full statistics of the aligned ATE.
    pub ate: ErrorStats,
    /// Whether the poses compared against are independent truth or another system's output.
    pub against: &'static str,
    /// The alignment of the estimate onto the references.
    #[serde(skip)]
    pub alignment: Alignment,
}

/// The path the map belongs to as stamped 3-D poses (z = 0), where it is not the estimates'.
pub fn map_path(result: &RunResult) -> Option<Vec<StampedPose>> {
    result.map_path.as_ref().map(|path| {
        path.iter()
            .map(|(time, pose)| StampedPose {
                time: *time,
                pose: pose.to_pose3(0.0),
            })
            .collect()
    })
}

/// ATE of the estimates against the truth poses (`True` preferred, else `Reference`).
pub fn trajectory_errors(result: &RunResult) -> Result<Option<TrajectoryErrors>> {
    path_errors(result, &trajectory(result))
}

/// ATE of `est` against the truth poses of `result` (`True` preferred, else `Reference`,
/// else GPS fixes).
pub fn path_errors(result: &RunResult, est: &[StampedPose]) -> Result<Option<TrajectoryErrors>> {
    let stamped = |kind: TruthKind| -> Vec<StampedPose> {
        result
            .truth
            .iter()
            .filter(|(_, _, k)| *k == kind)
            .map(|(t, p, _)| StampedPose {
                time: *t,
                pose: p.to_pose3(0.0),
            })
            .collect()
    };
    let gps: Vec<StampedPose> = result
        .gps
        .iter()
        .map(|(t, p)| StampedPose {
            time: *t,
            pose: slam_core::Pose3::new(Vector3::new(p.x, p.y, 0.0), 0.0, 0.0, 0.0),
        })
        .collect();
    // Estimates are at the data's own times; GPS fixes come at theirs: pair them within
    // half a second.
    let (gt, against, max_dt) = match stamped(TruthKind::True) {
        gt if !gt.is_empty() => (gt, "ground truth", 1e-6),
        _ => match stamped(TruthKind::Reference) {
            reference if !reference.is_empty() => (reference, "reference poses of the data", 1e-6),
            _ => (gps, "GPS fixes (positions only)", 0.5),
        },
    };
    if gt.len() < 3 {
        return Ok(None);
    }
    let pairs = associate(&gt, est, max_dt);
    if pairs.len() < 3 {
        return Ok(None);
    }
    let aligned = ate(&gt, est, &pairs, AlignMode::Se3)?;
    let unaligned = ate(&gt, est, &pairs, AlignMode::None)?;
    Ok(Some(TrajectoryErrors {
        ate_rmse_m: aligned.errors.rmse,
        ate_rmse_unaligned_m: unaligned.errors.rmse,
        ate: aligned.errors,
        against,
        alignment: aligned.alignment,
    }))
}

/// `estimates.csv`: every estimated pose with its covariance, and the true pose and the
/// NEES where the data have true poses.
pub fn estimates_csv(result: &RunResult) -> String {
    use std::fmt::Write as _;
    let truth = true_poses(result);
    let nees: BTreeMap<u64, f64> = pose_nees(result)
        .into_iter()
        .map(|(t, n)| (t.to_bits(), n))
        .collect();
    let mut text = String::from(
        "time,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta,\
         true_x,true_y,true_theta,nees\n",
    );
    for r in &result.estimates {
        let c = &r.covariance;
        let _ = write!(
            text,
            "{},{},{},{},{:e},{:e},{:e},{:e},{:e},{:e}",
            r.time,
            r.pose.x,
            r.pose.y,
            r.pose.theta,
            c[(0, 0)],
            c[(0, 1)],
            c[(0, 2)],
            c[(1, 1)],
            c[(1, 2)],
            c[(2, 2)]
        );
        match truth.get(&r.time.to_bits()) {
            Some(t) => {
                let n = nees
                    .get(&r.time.to_bits())
                    .map_or(String::new(), |n| n.to_string());
                let _ = writeln!(text, ",{},{},{},{n}", t.x, t.y, t.theta);
            }
            None => text.push_str(",,,,\n"),
        }
    }
    text
}

/// Writes the estimated trajectory in TUM format (`trajectory.tum`), and the map's path where
/// it differs (`map_path.tum`).
pub fn write_trajectory(dir: &Path, result: &RunResult) -> Result<()> {
    write_tum(&dir.join("trajectory.tum"), &trajectory(result))?;
    if let Some(path) = map_path(result) {
        write_tum(&dir.join("map_path.tum"), &path)?;
    }
    Ok(())
}

/// Writes `text` to `dir/name` completely or not at all.
pub fn write_text(dir: &Path, name: &str, text: &str) -> Result<()> {
    write_atomically(&dir.join(name), text.as_bytes())?;
    Ok(())
}

/// The 95% ellipse of a 2-D covariance around `centre`, as a closed polyline.
fn ellipse(centre: Vector2<f64>, covariance: &Matrix2<f64>) -> Option<Vec<Vector2<f64>>> {
    let eigen = covariance.symmetric_eigen();
    if eigen.eigenvalues.iter().any(|v| !v.is_finite() || *v < 0.0) {
        return None;
    }
    let scale = chi2_quantile(0.95, 2).ok()?.sqrt();
    let axes = eigen.eigenvectors * Matrix2::from_diagonal(&eigen.eigenvalues.map(f64::sqrt));
    Some(
        (0..=48)
            .map(|k| {
                let t = k as f64 / 48.0 * std::f64::consts::TAU;
                centre + axes * Vector2::new(t.cos(), t.sin()) * scale
            })
            .collect(),
    )
}

/// The covariance of block `k` (a point) of a feature, from [`coordinate_covariance`].
fn point_covariance(c: &DMatrix<f64>, offset: usize) -> Matrix2<f64> {
    Matrix2::new(
        c[(offset, offset)],
        c[(offset, offset + 1)],
        c[(offset + 1, offset)],
        c[(offset + 1, offset + 1)],
    )
}

/// What the map figure shows besides the estimate.
pub struct FigureContext<'a> {
    /// Title.
    pub title: String,
    /// The simulated world's true map.
    pub truth_map: Option<&'a TrueMap>,
    /// Known landmark positions.
    pub landmarks: &'a [KnownLandmark],
    /// How to bring the estimate into the frame of the truth / GPS (identity when they
    /// share a frame).
    pub estimate_to_truth: Option<crate::eval::Alignment>,
}

/// Draws the map, the trajectory, the truth, GPS fixes and 95% covariance ellipses.
pub fn map_figure(result: &RunResult, context: &FigureContext) -> Figure {
    let mut figure = Figure::new(context.title.clone(), 1600);
    let place = |p: Vector2<f64>| -> Vector2<f64> {
        match &context.estimate_to_truth {
            Some(a) => a.apply(&Vector3::new(p.x, p.y, 0.0)).xy(),
            None => p,
        }
    };
    if let Some(truth) = context.truth_map {
        for (a, b) in &truth.walls {
            figure.segment(*a, *b, palette::TRUTH, 3);
        }
        for (c, r) in &truth.poles {
            figure.circle(*c, *r, palette::TRUTH, false);
        }
        for (a, b) in &truth.ceiling_lines {
            figure.segment(a.xy(), b.xy(), palette::TRUTH_CEILING, 1);
        }
        figure.dots(
            truth.lamps.iter().map(|l| l.xy()).collect(),
            palette::TRUTH,
            4,
        );
        figure.legend("true map", palette::TRUTH);
    }
    if !context.landmarks.is_empty() {
        for l in context.landmarks {
            figure.marker(l.position, palette::TRUTH, 9, false);
        }
        figure.legend("known landmarks", palette::TRUTH);
    }
    let truth_path: Vec<_> = result
        .truth
        .iter()
        .map(|(_, p, _)| p.translation())
        .collect();
    if !truth_path.is_empty() {
        let kind = if result.truth.iter().any(|t| t.2 == TruthKind::True) {
            "true path"
        } else {
            "reference path"
        };
        figure.polyline(truth_path, palette::TRUE_PATH, 1);
        figure.legend(kind, palette::TRUE_PATH);
    }
    if !result.gps.is_empty() {
        figure.dots(
            result.gps.iter().map(|(_, g)| *g).collect(),
            palette::GPS,
            2,
        );
        figure.legend(format!("{} GPS fixes", result.gps.len()), palette::GPS);
    }
    // A particle filter's map belongs to one particle's path, drawn instead of the mean.
    let (path, label): (Vec<_>, _) = match &result.map_path {
        Some(path) => (
            path.iter().map(|(_, p)| place(p.translation())).collect(),
            "path of the map's particle",
        ),
        None => (
            result
                .estimates
                .iter()
                .map(|r| place(r.pose.translation()))
                .collect(),
            "estimated path",
        ),
    };
    figure.polyline(path, palette::PATH, 2);
    figure.legend(label, palette::PATH);
    draw_features(&mut figure, result, &place);
    figure
}

fn draw_features(
    figure: &mut Figure,
    result: &RunResult,
    place: &dyn Fn(Vector2<f64>) -> Vector2<f64>,
) {
    let estimator = result.estimator.as_ref();
    let map = estimator.map();
    let mut legend: BTreeMap<&'static str, (usize, crate::plot::Colour)> = BTreeMap::new();
    let mut count = |name: &'static str, colour| legend.entry(name).or_insert((0, colour)).0 += 1;
    for (id, feature) in map.iter() {
        if !confirmed(estimator, id) {
            continue;
        }
        let covariance = coordinate_covariance(estimator, id);
        let ellipse_at = |figure: &mut Figure, offset: usize, centre: Vector2<f64>, colour| {
            if let Some(points) = covariance
                .as_ref()
                .and_then(|c| ellipse(centre, &point_covariance(c, offset)))
            {
                figure.polyline(points.into_iter().map(place).collect(), colour, 1);
            }
        };
        if let Some(wall) = downcast_feature::<Wall>(feature) {
            let (colour, name) = if wall.mspace_dim() + shared_dims(map, id) >= 3 {
                (palette::WALL, "walls with an estimated end or corner")
            } else {
                (palette::WALL_LINE_ONLY, "walls, line only (dim 2)")
            };
            figure.segment(place(wall.start()), place(wall.end()), colour, 4);
            count(name, colour);
            for (k, end) in [wall.start(), wall.end()].into_iter().enumerate() {
                let estimated = wall.is_shared(k)
                    || wall
                        .active_subspaces()
                        .iter()
                        .any(|s| s.name == if k == 0 { "start" } else { "end" });
                if estimated {
                    figure.marker(place(end), palette::CORNER, 8, wall.is_shared(k));
                    ellipse_at(figure, 2 * k, end, palette::CORNER);
                }
            }
        } else if let Some(wall) = downcast_feature::<EndpointWall>(feature) {
            figure.segment(place(wall.start()), place(wall.end()), palette::WALL, 4);
            count("endpoint walls", palette::WALL);
            ellipse_at(figure, 0, wall.start(), palette::CORNER);
            ellipse_at(figure, 2, wall.end(), palette::CORNER);
        } else if let Some(line) = downcast_feature::<PpcaLine>(feature) {
            figure.segment(place(line.start()), place(line.end()), palette::WALL, 3);
            count("PPCA lines (IPSLAM clusters)", palette::WALL);
        } else if let Some(line) = downcast_feature::<HLine>(feature) {
            let (colour, width, name) = if line.mspace_dim() >= 3 {
                (palette::CEILING, 3, "ceiling lines (dim 3)")
            } else {
                (
                    palette::CEILING_DIRECTION,
                    1,
                    "ceiling lines, direction only",
                )
            };
            figure.segment(
                place(line.start().xy()),
                place(line.end().xy()),
                colour,
                width,
            );
            count(name, colour);
        } else if let Some(pole) = downcast_feature::<Pole>(feature) {
            figure.circle(place(pole.centre()), pole.radius(), palette::POLE, true);
            ellipse_at(figure, 1, pole.centre(), palette::POLE);
            count("poles", palette::POLE);
        } else if let Some(point) = downcast_feature::<Point>(feature) {
            let colour = if point.mspace_dim() >= 3 {
                palette::CEILING
            } else {
                palette::POINT
            };
            figure.marker(place(point.position().xy()), colour, 7, true);
            ellipse_at(figure, 0, point.position().xy(), colour);
            count("points and lamps", colour);
        } else {
            for block in feature.coordinates().blocks() {
                let p = match block {
                    CoordBlock::Point3(p) => p.xy(),
                    CoordBlock::Point2(p) => *p,
                    CoordBlock::Scalar(_) => continue,
                };
                figure.marker(place(p), palette::POINT, 7, false);
            }
            count("other features", palette::POINT);
        }
    }
    for (name, (n, colour)) in legend {
        figure.legend(format!("{n} {name}"), colour);
    }
}
