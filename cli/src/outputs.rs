//! The files `slam run` writes: `trajectory.tum` (and `map_path.tum` for a particle filter),
//! `map.json`, `estimates.csv`, `metrics.json`, and a folder per post-processing stage.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;
use slam_core::nalgebra::DMatrix;
use slam_core::{CoordBlock, Estimator, Feature, FeatureMap, Pose2, RowOwner};
use slam_runtime::RunOutput;
use slam_runtime::eval::{confirmed, pose_nees, stamped};
use slam_sensors::data::{write_atomically, write_atomically_with, write_tum};

use crate::error::{CliError, Result};

/// Creates `dir` (and its parents).
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| CliError::Output {
        path: dir.to_path_buf(),
        source,
    })
}

/// Writes `text` to `dir/name` completely or not at all.
pub fn write_text(dir: &Path, name: &str, text: &str) -> Result<()> {
    write_atomically(&dir.join(name), text.as_bytes())?;
    Ok(())
}

/// `value` as pretty JSON written to `dir/name`.
pub fn write_json(dir: &Path, name: &str, value: &impl Serialize) -> Result<()> {
    let mut json = serde_json::to_string_pretty(value).map_err(|e| {
        CliError::Runtime(slam_runtime::RuntimeError::Invariant(format!(
            "serializing {name}: {e}"
        )))
    })?;
    json.push('\n');
    write_text(dir, name, &json)
}

/// Writes the estimated trajectory in TUM format (`trajectory.tum`), and the map's path where
/// it differs (`map_path.tum`).
pub fn write_trajectory(dir: &Path, output: &RunOutput) -> Result<()> {
    let estimates = stamped(output.record.estimates.iter().map(|r| (r.time, r.pose)));
    write_tum(&dir.join("trajectory.tum"), &estimates)?;
    if let Some(path) = &output.map_path {
        write_tum(&dir.join("map_path.tum"), &stamped(path.iter().copied()))?;
    }
    Ok(())
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

/// What `map.json` says of a map beyond the features themselves.
struct MapContext<'a> {
    confirmed: &'a dyn Fn(slam_core::FeatureId) -> bool,
    landmark_id: &'a dyn Fn(slam_core::FeatureId) -> Option<u64>,
    covariance: &'a dyn Fn(RowOwner) -> Option<DMatrix<f64>>,
}

/// `map.json` of an estimator: every feature (tentative ones flagged) with coordinates,
/// M-space dimension and covariance, and the shared blocks.
pub fn map_json(estimator: &dyn Estimator<Pose2>) -> Result<String> {
    let context = MapContext {
        confirmed: &|id| confirmed(estimator, id),
        landmark_id: &|id| estimator.landmark_id(id),
        covariance: &|owner| estimator.row_covariance(owner),
    };
    map_file(estimator.map(), &context)
}

/// `map.json` of a map without an estimator (a post-processing stage's): every feature is
/// confirmed, no covariance.
pub fn plain_map_json(map: &FeatureMap) -> Result<String> {
    let context = MapContext {
        confirmed: &|_| true,
        landmark_id: &|_| None,
        covariance: &|_| None,
    };
    map_file(map, &context)
}

fn map_file(map: &FeatureMap, context: &MapContext<'_>) -> Result<String> {
    let mut features = Vec::new();
    for (id, feature) in map.iter() {
        let value = serde_json::to_value(feature as &dyn Feature).map_err(|e| {
            CliError::Runtime(slam_runtime::RuntimeError::Invariant(format!(
                "serializing feature {}: {e}",
                id.0
            )))
        })?;
        features.push(MapFeature {
            id: id.0,
            kind: feature.kind(),
            mspace_dim: feature.mspace_dim(),
            subspaces: feature.active_subspaces().iter().map(|s| s.name).collect(),
            confirmed: (context.confirmed)(id),
            landmark_id: (context.landmark_id)(id),
            coordinates: feature.coordinates().blocks().to_vec(),
            shared_blocks: map.links(id)?.iter().map(|l| l.map(|s| s.0)).collect(),
            covariance: (context.covariance)(RowOwner::Feature(id)).map(|c| rows(&c)),
            feature: value,
        });
    }
    let shared_blocks = map
        .shared_blocks()
        .map(|(id, block)| MapShared {
            id: id.0,
            value: block.value,
            members: block.members.iter().map(|(f, k)| (f.0, *k)).collect(),
            covariance: (context.covariance)(RowOwner::Shared(id)).map(|c| rows(&c)),
        })
        .collect();
    serde_json::to_string_pretty(&MapFile {
        frame: "map (world) frame, metres",
        features,
        shared_blocks,
    })
    .map_err(|e| {
        CliError::Runtime(slam_runtime::RuntimeError::Invariant(format!(
            "serializing the map: {e}"
        )))
    })
}

/// Writes `estimates.csv` into `dir`, streamed: every pose with its covariance, and where the
/// data give true poses, the true pose and the pose NEES.
pub fn write_estimates_csv(dir: &Path, output: &RunOutput) -> Result<()> {
    let record = &output.record;
    let truth = record.true_poses();
    let nees: BTreeMap<u64, f64> = pose_nees(&record.estimates, &truth)
        .into_iter()
        .map(|(t, n)| (t.to_bits(), n))
        .collect();
    write_atomically_with(&dir.join("estimates.csv"), |out| {
        writeln!(
            out,
            "time,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta,\
             true_x,true_y,true_theta,nees"
        )?;
        for r in &record.estimates {
            let c = &r.covariance;
            write!(
                out,
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
            )?;
            match truth.get(&r.time.to_bits()) {
                Some(t) => {
                    write!(out, ",{},{},{},", t.x, t.y, t.theta)?;
                    match nees.get(&r.time.to_bits()) {
                        Some(n) => writeln!(out, "{n}")?,
                        None => writeln!(out)?,
                    }
                }
                None => writeln!(out, ",,,,")?,
            }
        }
        Ok(())
    })?;
    Ok(())
}
