//! The tilted-sensor study of BENCHMARKS.md ("A tilted laser and camera") in small: on the
//! built-in office with a laser pitched and rolled and a camera not pointing straight up
//! (`worlds/tilted-sensors.toml`), the M-space EKF, which takes the mounts as they are (paper
//! appendix, eq. 34), maps the walls within centimetres with a pose error its covariance
//! explains; with the tilt ignored (`[frontend] level_mounts = true`, what a planar SLAM
//! system assumes) the same run maps them decimetres off and is overconfident.

mod common;

use common::run_toml;
use slam_runtime::RunMetrics;

/// One run of the tilted office (seed 2), the mounts taken as they are or levelled.
fn tilted_office(level_mounts: bool) -> RunMetrics {
    let world = concat!(env!("CARGO_MANIFEST_DIR"), "/../worlds/tilted-sensors.toml");
    let text = format!(
        "[data]\nspec = \"world:{world}\"\nseed = 2\n\
         [frontend]\ntype = \"features\"\nlevel_mounts = {level_mounts}\n"
    );
    run_toml(&text).2
}

#[test]
fn the_tilt_modelled_maps_the_office_and_the_tilt_ignored_does_not() {
    let modelled = tilted_office(false);
    let ignored = tilted_office(true);
    let map_error = |m: &RunMetrics| m.map_error_m.expect("a simulated run has a map error");
    let nees = |m: &RunMetrics| m.nees.as_ref().expect("a pose NEES").mean_per_dof;
    let (modelled_error, ignored_error) = (map_error(&modelled), map_error(&ignored));
    assert!(
        modelled_error < 0.03,
        "tilt modelled: map error {modelled_error} m"
    );
    assert!(
        ignored_error > 5.0 * modelled_error,
        "tilt ignored: map error {ignored_error} m against {modelled_error} m"
    );
    let (modelled_nees, ignored_nees) = (nees(&modelled), nees(&ignored));
    assert!(
        modelled_nees < 2.0,
        "tilt modelled: NEES per dof {modelled_nees}"
    );
    assert!(
        ignored_nees > 2.0 * modelled_nees,
        "tilt ignored: NEES per dof {ignored_nees} against {modelled_nees}"
    );
}
