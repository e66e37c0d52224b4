//! `slam run` with the structure-prior wall front-end, end to end through the binary.

use std::path::PathBuf;
use std::process::Command;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("slam-cli-it-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The built-in world without its camera, driven only to a turn into the corridor's north
/// side (a few seconds: the inference on each 361-beam scan is the slow part in a debug
/// build, and a path with a turn lets the run align the estimate with the truth).
fn short_world(dir: &std::path::Path) -> PathBuf {
    let mut world = slam_sensors::sim::World::default_world();
    world.camera = None;
    world.robot.waypoints = vec![[2.5, 8.3], [3.5, 8.3]];
    let path = dir.join("short-world.toml");
    std::fs::write(&path, toml::to_string(&world).unwrap()).unwrap();
    path
}

#[test]
fn slam_run_segments_walls_with_a_prior() {
    let dir = temp_dir("prior-frontend");
    let out = dir.join("out");
    let config = dir.join("prior.toml");
    let world = short_world(&dir);
    std::fs::write(
        &config,
        format!(
            "[data]\nspec = \"world:{}\"\nmax_events = 30\n\
         [frontend]\nwall_segmentation = \"prior\"\ncamera = false\n\
         [frontend.prior]\nprior = \"rectangular\"\n\
         [output]\nplots = false\n",
            world.display()
        ),
    )
    .unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_slam"))
        .arg("run")
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "slam run failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["config"]["frontend"]["wall_segmentation"], "prior");
    let walls = metrics["frontend"]["walls"].as_u64().unwrap();
    assert!(walls > 0, "no walls: {}", metrics["frontend"]);
    assert_eq!(metrics["frontend"]["prior_failures"], 0);
    assert!(metrics["ate_rmse_m"].as_f64().is_some());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unknown_prior_stops_slam_run_with_a_clear_error() {
    let dir = temp_dir("prior-unknown");
    let config = dir.join("prior.toml");
    std::fs::write(
        &config,
        "[data]\nspec = \"sim\"\nmax_events = 10\n\
         [frontend]\nwall_segmentation = \"prior\"\n[frontend.prior]\nprior = \"hexagonal\"\n",
    )
    .unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_slam"))
        .arg("run")
        .arg(&config)
        .arg("--out")
        .arg(dir.join("out"))
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("unknown prior \"hexagonal\""), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}
