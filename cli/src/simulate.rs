//! `slam simulate [WORLD] --out DIR`: a simulated run written as files other tools read.
//!
//! Into `DIR` (created if missing), each file written completely or not at all:
//!
//! - `run.rb2d`: the range-bearing landmark log (`shared/formats/rb2d.md`): `PARAM` lines, the
//!   true landmarks (`LM`), the noisy odometry of each step (`ODOM`, the pose increment from
//!   pose k-1 to pose k: `dx = v dt, dy = 0, dth = w dt` for worlds with Euler integration,
//!   the exact arc increment otherwise), the observations (`OBS`) and the true poses (`GT`,
//!   world frame: `GT 0` is the world's start pose).
//! - `run.carmen.log`: the laser scans as `ROBOTLASER1` lines and the odometry as `ODOM`
//!   lines; their robot poses are **dead-reckoned** from the start pose (noisy odometry, as in
//!   a raw log), timestamps are simulation seconds. The truth is in `truth.tum`.
//! - `truth.tum`: the true trajectory (TUM format, time `k dt`).
//! - `truth_map.json`: the true map (walls, corners, poles, ceiling lines, lamps, landmarks).

use std::path::{Path, PathBuf};
use std::time::Instant;

use slam_core::Pose2;
use slam_sensors::data::carmen::carmen_text;
use slam_sensors::data::rb2d::rb2d_text;
use slam_sensors::data::{StampedPose, write_atomically, write_tum};
use slam_sensors::odometry::Integration;
use slam_sensors::sim::{Simulation, World, simulate};

use crate::error::Result;

/// Arguments of `slam simulate`.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// World description (TOML or JSON); the built-in default world when absent.
    pub world: Option<PathBuf>,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the simulation's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs `slam simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    let started = Instant::now();
    let (world, source) = match &args.world {
        Some(path) => (World::from_file(path)?, path.display().to_string()),
        None => (
            World::default_world(),
            "the built-in default world".to_string(),
        ),
    };
    // No file holds camera images: skip rendering them. Each sensor draws its noise from its
    // own random stream, so the other outputs are the same as with the camera.
    let run = simulate(
        &World {
            camera: None,
            ..world.clone()
        },
        args.seed,
    )?;
    let counts = run.dataset.counts();
    println!(
        "simulated `{}` ({source}, seed {}): {} steps, {} events",
        world.name,
        args.seed,
        run.trajectory.len().saturating_sub(1),
        run.dataset.events.len()
    );
    crate::outputs::create_dir(&args.out)?;
    let header = format!(
        "written by `slam simulate`: world `{}` ({source}), seed {}",
        world.name, args.seed
    );

    let rb2d = rb2d_text(
        &run.dataset,
        &world.rb2d_params(),
        &rb2d_comment(&world, &header),
    )?;
    write(&args.out, "run.rb2d", &rb2d)?;
    let (odom, obs, gt, lm) = (
        count(&rb2d, "ODOM"),
        count(&rb2d, "OBS"),
        count(&rb2d, "GT"),
        count(&rb2d, "LM"),
    );
    let per_step = if counts.observation_events > 0 {
        format!(
            ", {:.2} per observation step",
            obs as f64 / counts.observation_events as f64
        )
    } else {
        " (the world has no range-bearing sensor)".to_string()
    };
    println!(
        "run.rb2d: {odom} ODOM, {obs} OBS in {} steps{per_step}, {gt} GT, {lm} LM",
        counts.observation_events
    );

    let carmen = carmen_text(&run.dataset, &world.start_pose(), &carmen_comment(&header))?;
    write(&args.out, "run.carmen.log", &carmen)?;
    let no_laser = if world.laser.is_none() {
        " (the world has no laser)"
    } else {
        ""
    };
    println!(
        "run.carmen.log: {} ROBOTLASER1 scans{no_laser}, {} ODOM (dead-reckoned)",
        count(&carmen, "ROBOTLASER1"),
        count(&carmen, "ODOM")
    );

    let truth = true_trajectory(&run, world.robot.dt);
    write_tum(&args.out.join("truth.tum"), &truth)?;
    println!(
        "truth.tum: {} true poses, {:.1} s to {:.1} s",
        truth.len(),
        truth.first().map_or(0.0, |p| p.time),
        truth.last().map_or(0.0, |p| p.time)
    );

    let map = &run.truth;
    crate::outputs::write_json(&args.out, "truth_map.json", map)?;
    println!(
        "truth_map.json: {} walls, {} corners, {} poles, {} ceiling lines, {} lamps, {} landmarks",
        map.walls.len(),
        map.corners.len(),
        map.poles.len(),
        map.ceiling_lines.len(),
        map.lamps.len(),
        map.landmarks.len()
    );
    println!(
        "wrote 4 files to {} in {:.2} s",
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Writes `text` to `dir/name`, completely or not at all.
fn write(dir: &Path, name: &str, text: &str) -> Result<()> {
    Ok(write_atomically(&dir.join(name), text.as_bytes())?)
}

/// How many lines of `text` start with the record `tag`.
fn count(text: &str, tag: &str) -> usize {
    text.lines()
        .filter(|l| l.split_whitespace().next() == Some(tag))
        .count()
}

/// The true poses stamped `k dt`.
fn true_trajectory(run: &Simulation, dt: f64) -> Vec<StampedPose> {
    run.trajectory
        .iter()
        .enumerate()
        .map(|(k, pose)| StampedPose {
            time: k as f64 * dt,
            pose: pose.to_pose3(0.0),
        })
        .collect()
}

fn rb2d_comment(world: &World, header: &str) -> String {
    let start: Pose2 = world.start_pose();
    let odometry = match world.robot.integration {
        Integration::Euler => {
            "ODOM: the noisy odometry of each step, dx = v dt, dy = 0, dth = w dt (Euler \
             integration, exactly what the simulator did)"
        }
        Integration::Arc => {
            "ODOM: the noisy odometry of each step as its exact arc increment (the simulator \
             integrates arcs), dy != 0 when turning: read as a pose increment"
        }
    };
    format!(
        "rb2d log (shared/formats/rb2d.md) {header}\n\
         {odometry}\n\
         OBS: range-bearing from the robot origin, ids as LM (pole centres first, then \
         [[landmarks]])\n\
         GT: true poses in the world frame; GT 0 is the start pose ({} {} {})",
        start.x, start.y, start.theta
    )
}

fn carmen_comment(header: &str) -> String {
    format!(
        "CARMEN log {header}\n\
         Timestamps are simulation seconds (step k at k dt).\n\
         ODOM poses and the robot pose of ROBOTLASER1 lines are DEAD-RECKONED (the noisy \
         odometry integrated from the start pose), not truth: the true trajectory is in \
         truth.tum.\n\
         ROBOTLASER1 laser pose = robot pose composed with the laser mount (x, y, yaw; the \
         mount height is not in this format)."
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_sensors::data::{CarmenOptions, read_carmen, read_rb2d, read_tum};
    use slam_sensors::sim::TrueMap;

    #[test]
    fn the_circle_world_is_written_and_read_back() {
        let out = tempfile::tempdir().unwrap();
        let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
        let args = SimulateArgs {
            world: Some(world),
            out: out.path().join("new-folder"),
            seed: 3,
        };
        run(&args).unwrap();
        let dir = &args.out;
        let rb2d = read_rb2d(&dir.join("run.rb2d")).unwrap();
        let counts = rb2d.counts();
        assert_eq!((counts.motion, counts.ground_truth), (1000, 1001));
        assert_eq!(rb2d.landmarks.len(), 50);
        let carmen = read_carmen(&dir.join("run.carmen.log"), &CarmenOptions::default()).unwrap();
        assert_eq!((carmen.counts().motion, carmen.counts().scans), (1000, 0));
        let truth = read_tum(&dir.join("truth.tum")).unwrap();
        assert_eq!(truth.len(), 1001);
        assert!((truth[1000].time - 100.0).abs() < 1e-9);
        let text = std::fs::read_to_string(dir.join("truth_map.json")).unwrap();
        let map: TrueMap = serde_json::from_str(&text).unwrap();
        assert_eq!(map.landmarks.len(), 50);
    }

    #[test]
    fn a_bad_world_is_an_error_naming_the_file() {
        let out = tempfile::tempdir().unwrap();
        let args = SimulateArgs {
            world: Some(PathBuf::from("no/such/world.toml")),
            out: out.path().join("never"),
            seed: 1,
        };
        let e = run(&args).unwrap_err().to_string();
        assert!(e.contains("no/such/world.toml"), "{e}");
        assert!(!args.out.exists());
    }
}
