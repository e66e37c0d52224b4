//! `slam run` killed at any moment leaves either the previous complete output set or the new
//! complete one; Ctrl-C stops it at the next step with a consistent set marked as
//! interrupted; a diverged filter exits with its own code and keeps its outputs.
//!
//! The long kill loop: `cargo test --release -p slam-cli --test kill_loop -- --ignored`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rand::{RngExt, SeedableRng};

const SLAM: &str = env!("CARGO_BIN_EXE_slam");

/// A world of the range-bearing circle, shortened to `steps` steps.
fn world(dir: &Path, steps: usize) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml"),
    )
    .unwrap()
    .replace("steps = 1000", &format!("steps = {steps}"));
    let path = dir.join(format!("circle-{steps}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

fn start(world: &Path, out: &Path, seed: u64) -> Child {
    start_with(None, world, out, seed)
}

/// `slam run [CONFIG] --data world:WORLD --out OUT --seed SEED --quiet`, output discarded.
fn start_with(config: Option<&Path>, world: &Path, out: &Path, seed: u64) -> Child {
    let mut command = Command::new(SLAM);
    command.arg("run");
    if let Some(config) = config {
        command.arg(config);
    }
    command
        .args(["--quiet", "--seed", &seed.to_string(), "--out"])
        .arg(out)
        .arg("--data")
        .arg(format!("world:{}", world.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// The seed of the complete set in `out`, after checking that it is complete: the run's files
/// and nothing else, `metrics.json` parses, and the trajectory has one pose per step.
fn complete_set(out: &Path) -> Result<u64, String> {
    let mut names: Vec<String> = std::fs::read_dir(out)
        .map_err(|e| format!("{}: {e}", out.display()))?
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let expected = [
        "estimates.csv",
        "map.json",
        "map.png",
        "map.svg",
        "metrics.json",
        "trajectory.tum",
    ];
    if names != expected {
        return Err(format!("files {names:?}"));
    }
    let text = std::fs::read_to_string(out.join("metrics.json")).map_err(|e| e.to_string())?;
    let metrics: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let poses = std::fs::read_to_string(out.join("trajectory.tum"))
        .map_err(|e| e.to_string())?
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count();
    if metrics["steps"].as_u64() != Some(poses as u64) || metrics["status"] != "complete" {
        return Err(format!("{poses} poses for {}", metrics["steps"]));
    }
    metrics["seed"].as_u64().ok_or_else(|| "no seed".into())
}

/// Kills `kills` runs at random times (seeded) and checks the folder after each; returns how
/// many kills left the previous set and how many the new one.
fn kill_loop(steps: usize, kills: usize) -> (usize, usize) {
    let dir = tempfile::tempdir().unwrap();
    let world = world(dir.path(), steps);
    let out = dir.path().join("out");
    let clock = Instant::now();
    assert!(start(&world, &out, 1).wait().unwrap().success());
    let full = clock.elapsed();
    let mut previous = complete_set(&out).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2026);
    let (mut old, mut new) = (0, 0);
    for kill in 0..kills {
        let seed = 100 + kill as u64;
        let mut child = start(&world, &out, seed);
        let delay = full.mul_f64(rng.random_range(0.0..1.2));
        std::thread::sleep(delay);
        let _ = child.kill();
        let _ = child.wait();
        let found = complete_set(&out)
            .unwrap_or_else(|e| panic!("kill {kill} after {delay:?}: not a complete set: {e}"));
        assert!(
            found == previous || found == seed,
            "kill {kill}: the set of seed {found}, neither the previous ({previous}) nor the new ({seed})"
        );
        if found == seed {
            new += 1;
            previous = seed;
        } else {
            old += 1;
        }
    }
    (old, new)
}

#[test]
fn killed_runs_leave_a_complete_set() {
    let (old, new) = kill_loop(60, 4);
    assert_eq!(old + new, 4);
}

/// About 200 kills at random times over the whole run.
#[test]
#[ignore]
fn killed_runs_leave_a_complete_set_long_loop() {
    let (old, new) = kill_loop(1000, 200);
    eprintln!("kill loop: 200 kills, {old} left the previous set, {new} the new one");
    assert!(
        old > 0 && new > 0,
        "the kills did not cover the run: {old} / {new}"
    );
}

#[cfg(unix)]
#[test]
fn ctrl_c_stops_the_run_with_a_consistent_set_marked_interrupted() {
    let dir = tempfile::tempdir().unwrap();
    let world = world(dir.path(), 100_000);
    let out = dir.path().join("out");
    let child = start(&world, &out, 1);
    // Wait until the run is stepping (its set folder exists), then interrupt it.
    let deadline = Instant::now() + Duration::from_secs(60);
    std::thread::sleep(Duration::from_millis(1500));
    assert!(Instant::now() < deadline);
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let output = child.wait_with_output().unwrap();
    assert_eq!(
        output.status.code(),
        Some(i32::from(slam_cli::EXIT_INTERRUPTED))
    );
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["status"], "interrupted");
    let steps = metrics["steps"].as_u64().unwrap();
    assert!(steps > 0 && steps < 100_001, "{steps} steps");
    let poses = std::fs::read_to_string(out.join("trajectory.tum"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .count();
    assert_eq!(poses as u64, steps);
}

#[test]
fn a_diverged_filter_exits_with_its_code_and_keeps_its_outputs() {
    // Landmarks 100 times farther: the EKF linearization fails and the filter diverges.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(world(dir.path(), 200)).unwrap();
    let mut far = String::new();
    for line in text.lines() {
        let scaled = match line.trim().strip_prefix("{ x = ") {
            Some(rest) => {
                let (x, rest) = rest.split_once(", y = ").unwrap();
                let y = rest.trim_end_matches([' ', '}', ',']);
                let (x, y): (f64, f64) = (x.parse().unwrap(), y.parse().unwrap());
                format!("    {{ x = {}, y = {} }},", x * 100.0, y * 100.0)
            }
            None => line.replace("max_range = 10.0", "max_range = 3000.0"),
        };
        far.push_str(&scaled);
        far.push('\n');
    }
    let world = dir.path().join("far.toml");
    std::fs::write(&world, far).unwrap();
    // Without the known-id validation gate, which would reject the failing updates.
    let config = dir.path().join("ungated.toml");
    std::fs::write(
        &config,
        "[estimator]\ntype = \"ekf\"\nknown_id_gate_probability = 1.0\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let status = start_with(Some(&config), &world, &out, 1).wait().unwrap();
    assert_eq!(status.code(), Some(i32::from(slam_cli::EXIT_DIVERGED)));
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["status"], "diverged");
    assert!(
        metrics["divergence"]["reason"]
            .as_str()
            .unwrap()
            .contains("innovation test")
    );
    assert!(out.join("trajectory.tum").is_file());
}
