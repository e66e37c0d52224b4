//! Degrees of freedom recovered as the source reports (section 5, Fig. 8): a circular room
//! with the circular prior has 1 intrinsic degree of freedom, a rectangular room 2 with the
//! rectangular prior and 5 with the polygonal prior, two circles 3.

mod common;

/// Range noise of the simulated scans, m.
const NOISE: f64 = 0.005;

use common::{circle, full_scan};
use slam_priors::scene::Scene;
use slam_priors::{Dof, Library, Params, ScanInput, analyze, infer};

/// Runs `prior` on a simulated scan, keeping only the readings whose beam meets the surface
/// at less than `max_incidence_deg` from its normal.
fn run(
    prior: &str,
    scene: &Scene,
    pose: [f64; 3],
    angle_min: f64,
    beams: usize,
    max_incidence_deg: f64,
) -> Dof {
    let library = Library::shipped().unwrap();
    let prior = library.compile(prior).unwrap();
    let sim = full_scan(scene, pose, angle_min, beams, NOISE, 0, 11);
    let all = ScanInput::from_scan(&sim.scan, NOISE).unwrap();
    let keep: Vec<usize> = (0..all.len())
        .filter(|&i| {
            let hit = sim.truth[all.beam[i]].unwrap();
            let incidence = (hit.normal - all.phi[i] - std::f64::consts::PI).cos();
            incidence >= max_incidence_deg.to_radians().cos()
        })
        .collect();
    let input = ScanInput::new(
        keep.iter().map(|&i| all.phi[i]).collect(),
        keep.iter().map(|&i| all.rho[i]).collect(),
        NOISE,
    )
    .unwrap();
    let solution = infer(&prior, &input, &Params::default()).unwrap();
    assert!(solution.feasible);
    let dof = analyze(&prior, &solution).unwrap();
    eprintln!(
        "{}: {} regions, {} surfaces, {} outliers, Free {}, Extr {}, Intr {}",
        prior.name,
        solution.regions().len(),
        solution.surfaces().len(),
        solution.outliers().len(),
        dof.free_dim(),
        dof.extrinsic_dim(),
        dof.intrinsic_dim()
    );
    dof
}

/// A 4 m x 3 m room seen from its centre, the scan starting just past a corner so that each
/// wall is one region.
fn rectangle_dof(prior: &str) -> Dof {
    let scene = Scene::rectangle(4.0, 3.0);
    let beams = 120;
    let corner = (1.5_f64).atan2(2.0);
    let increment = std::f64::consts::TAU / beams as f64;
    run(
        prior,
        &scene,
        [2.0, 1.5, 0.0],
        corner + 0.5 * increment,
        beams,
        90.0,
    )
}

#[test]
fn circular_room_circular_prior_has_one_intrinsic_dof() {
    let scene = Scene {
        shapes: vec![circle([0.0, 0.0], 3.0)],
    };
    let dof = run("Circular prior", &scene, [0.7, -0.4, 0.2], -3.0, 90, 90.0);
    assert_eq!(dof.free_dim(), 3);
    assert_eq!(dof.extrinsic_dim(), 2);
    assert_eq!(dof.intrinsic_dim(), 1);
}

#[test]
fn rectangular_room_rectangular_prior_has_two_intrinsic_dof() {
    let dof = rectangle_dof("Rectangular prior");
    assert_eq!(dof.free_dim(), 5);
    assert_eq!(dof.extrinsic_dim(), 3);
    assert_eq!(dof.intrinsic_dim(), 2);
    // Covariance shrinking (Fig. 8d): every posterior range deviation is below the prior one.
    let std = dof.range_std();
    assert!(std.iter().all(|&s| s < 0.005), "{std:?}");
    assert_eq!(dof.variations.len(), 5);
}

#[test]
fn rectangular_room_polygonal_prior_has_five_intrinsic_dof() {
    let dof = rectangle_dof("Polygonal prior");
    assert_eq!(dof.free_dim(), 8);
    assert_eq!(dof.extrinsic_dim(), 3);
    assert_eq!(dof.intrinsic_dim(), 5);
}

#[test]
fn two_circles_have_three_intrinsic_dof() {
    let scene = Scene {
        shapes: vec![circle([2.0, 1.0], 0.5), circle([2.0, -1.5], 0.7)],
    };
    // Two pillars seen from outside: two arcs, grazing readings at their edges included.
    let dof = run("Circular prior", &scene, [0.0, 0.0, 0.0], -3.1, 360, 90.0);
    assert_eq!(dof.free_dim(), 6);
    assert_eq!(dof.extrinsic_dim(), 3);
    assert_eq!(dof.intrinsic_dim(), 3);
}
