//! Finds the real datasets for the tests that need them (DATASETS.md): the folder
//! `SLAM_DATA_DIR` (absolute, or relative to the workspace root), by default
//! `../shared/datasets` beside the repository. When it exists, tests see `cfg(slam_data)` and
//! the folder as `env!("SLAM_DATA")`; when it is absent, those tests are compiled as ignored,
//! and `SLAM_REQUIRE_DATA=1` (set by CI) turns the absence into a build error.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(slam_data)");
    println!("cargo::rerun-if-env-changed=SLAM_DATA_DIR");
    println!("cargo::rerun-if-env-changed=SLAM_REQUIRE_DATA");
    let workspace =
        PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default()).join("..");
    let dir = match std::env::var_os("SLAM_DATA_DIR") {
        Some(dir) => workspace.join(dir),
        None => workspace.join("../shared/datasets"),
    };
    println!("cargo::rerun-if-changed={}", dir.display());
    if dir.is_dir() {
        println!("cargo::rustc-cfg=slam_data");
        println!("cargo::rustc-env=SLAM_DATA={}", dir.display());
    } else if std::env::var("SLAM_REQUIRE_DATA").as_deref() == Ok("1") {
        println!(
            "cargo::error=SLAM_REQUIRE_DATA=1 but the real datasets are absent at {} (set SLAM_DATA_DIR; see DATASETS.md)",
            dir.display()
        );
    }
}
