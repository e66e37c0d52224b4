//! FastSLAM on a small simulated range-bearing world (points on a ring), and the
//! resampling's statistics.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use slam_core::nalgebra::{DMatrix, Vector3};
use slam_core::{Estimator, MotionModel, Observation, Pose2, Pose3, downcast_feature};
use slam_features::Point;
use slam_sensors::models::RangeBearing;
use slam_sensors::odometry::{Integration, Unicycle};
use std::sync::Arc;

use super::*;
use crate::particles::{normalized, systematic_resample};
use crate::test_support::wall_sighting;

const SIGMA_RANGE: f64 = 0.05;
const SIGMA_BEARING: f64 = 0.02;

/// A simulated run: the unicycle odometry of each step, its observations and the true pose.
struct World {
    landmarks: Vec<Vector3<f64>>,
    /// Landmarks seen at least once.
    seen: std::collections::BTreeSet<usize>,
    steps: Vec<(Unicycle, Vec<Observation>, Pose2)>,
}

/// A robot on a circle of radius 5 m among 16 landmarks on rings of 3 and 7 m, for `steps`
/// steps of 0.2 s; landmarks within 6 m are seen.
fn world(steps: usize, with_ids: bool, seed: u64) -> World {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = |sigma: f64, rng: &mut ChaCha8Rng| Normal::new(0.0, sigma).unwrap().sample(rng);
    let landmarks: Vec<Vector3<f64>> = (0..16)
        .map(|i| {
            let angle = i as f64 * std::f64::consts::TAU / 8.0 + if i >= 8 { 0.4 } else { 0.0 };
            let radius = if i < 8 { 3.0 } else { 7.0 };
            Vector3::new(radius * angle.cos(), 5.0 + radius * angle.sin(), 0.0)
        })
        .collect();
    let (v, omega, dt) = (1.0, 0.2, 0.2);
    let mut truth = Pose2::identity();
    let mut out = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..steps {
        let exact = Unicycle::new(v, omega, dt, 0.05, 0.02, Integration::Arc).unwrap();
        truth = exact.apply_control(&truth, &exact.control()).unwrap();
        let measured = Unicycle::new(
            v + noise(0.05, &mut rng),
            omega + noise(0.02, &mut rng),
            dt,
            0.05,
            0.02,
            Integration::Arc,
        )
        .unwrap();
        let mut observations = Vec::new();
        for (id, l) in landmarks.iter().enumerate() {
            let local = truth.inverse().transform_point(&l.xy());
            let range = local.norm();
            if range > 6.0 {
                continue;
            }
            seen.insert(id);
            let measurement = RangeBearing::new(
                range + noise(SIGMA_RANGE, &mut rng),
                local.y.atan2(local.x) + noise(SIGMA_BEARING, &mut rng),
                SIGMA_RANGE,
                SIGMA_BEARING,
            )
            .unwrap();
            observations.push(Observation {
                robot_from_sensor: Pose3::identity(),
                measurement: Arc::new(measurement),
                landmark_id: with_ids.then_some(id as u64),
            });
        }
        out.push((measured, observations, truth));
    }
    World {
        landmarks,
        seen,
        steps: out,
    }
}

fn run(world: &World, params: FastSlamParams) -> (FastSlam<Pose2>, f64) {
    let mut filter = FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), params).unwrap();
    let mut worst: f64 = 0.0;
    for (motion, observations, truth) in &world.steps {
        filter.predict(motion).unwrap();
        filter.update(observations).unwrap();
        worst = worst.max((filter.pose().translation() - truth.translation()).norm());
    }
    (filter, worst)
}

/// Without landmark ids: the confirmed features are as many as the landmarks seen, give or
/// take one.
fn assert_one_feature_per_seen_landmark(filter: &FastSlam<Pose2>, world: &World) {
    let confirmed = filter
        .map()
        .iter()
        .filter(|(_, f)| f.mspace_dim() > 0)
        .count();
    let seen = world.seen.len();
    assert!(
        (seen - 1..=seen + 1).contains(&confirmed),
        "{confirmed} features for {seen} landmarks"
    );
}

fn small(particles: usize) -> FastSlamParams {
    FastSlamParams {
        particles,
        confirm_after: 2,
        ..Default::default()
    }
}

#[test]
fn known_ids_map_every_landmark_close_to_the_truth() {
    let world = world(60, true, 3);
    let (filter, worst) = run(&world, small(20));
    assert!(worst < 0.3, "largest position error {worst}");
    let map = filter.map();
    assert!(
        world.seen.len() >= 10,
        "the test sees {} landmarks",
        world.seen.len()
    );
    assert_eq!(map.len(), world.seen.len(), "one feature per landmark id");
    for (id, feature) in map.iter() {
        let point = downcast_feature::<Point>(feature).unwrap();
        let landmark = filter.landmark_id(id).unwrap() as usize;
        let error = (point.position().xy() - world.landmarks[landmark].xy()).norm();
        assert!(error < 0.3, "landmark {landmark}: error {error}");
        assert!(filter.row_covariance(RowOwner::Feature(id)).is_some());
    }
}

#[test]
fn the_map_path_is_one_particle_s_path_through_every_step() {
    let world = world(60, true, 3);
    // One particle: its path is the estimate after every step.
    let mut single = FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), small(1)).unwrap();
    let mut estimates = Vec::new();
    for (motion, observations, _) in &world.steps {
        single.predict(motion).unwrap();
        single.update(observations).unwrap();
        single.end_step();
        estimates.push(single.pose());
    }
    let path = single.map_path().unwrap();
    assert_eq!(path.len(), estimates.len());
    for (recorded, estimate) in path.iter().zip(&estimates) {
        assert!((recorded.to_vector() - estimate.to_vector()).norm() < 1e-12);
    }
    // Many particles, resampled at every step: the path follows the truth and ends inside
    // the particle cloud.
    let params = FastSlamParams {
        resample_threshold: 1.0,
        ..small(20)
    };
    let mut filter = FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), params).unwrap();
    for (motion, observations, _) in &world.steps {
        filter.predict(motion).unwrap();
        filter.update(observations).unwrap();
        filter.end_step();
    }
    let path = filter.map_path().unwrap();
    assert_eq!(path.len(), world.steps.len());
    for (k, (pose, (_, _, truth))) in path.iter().zip(&world.steps).enumerate() {
        let error = (pose.translation() - truth.translation()).norm();
        assert!(error < 0.3, "step {k}: error {error}");
    }
    let mean = filter.pose();
    let last = path[path.len() - 1];
    let spread = filter.pose_covariance();
    let offset = (last.translation() - mean.translation()).norm();
    let sigma = (spread[(0, 0)] + spread[(1, 1)]).sqrt();
    assert!(
        offset <= 4.0 * sigma + 1e-9,
        "{offset} m from the mean, spread {sigma} m"
    );
}

#[test]
fn the_improved_proposal_tracks_with_few_particles() {
    let world = world(60, false, 4);
    let params = FastSlamParams {
        proposal: Proposal::Improved,
        ..small(5)
    };
    let (filter, worst) = run(&world, params);
    assert!(worst < 0.2, "largest position error {worst}");
    assert_one_feature_per_seen_landmark(&filter, &world);
}

#[test]
fn unknown_ids_are_associated_per_particle() {
    let world = world(60, false, 4);
    let (filter, worst) = run(&world, small(20));
    assert!(worst < 0.3, "largest position error {worst}");
    assert_one_feature_per_seen_landmark(&filter, &world);
}

#[test]
fn particles_associate_by_jcbb_from_the_settings() {
    let world = world(60, false, 4);
    let jcbb = FastSlamParams {
        association: crate::Association::Jcbb,
        ..small(20)
    };
    let (filter, worst) = run(&world, jcbb);
    assert!(worst < 0.3, "largest position error {worst}");
    assert_one_feature_per_seen_landmark(&filter, &world);
    // (The one-to-one pairing and the joint gate are tested in `association`.)
    let zero_nodes = FastSlamParams {
        jcbb_max_nodes: 0,
        ..small(20)
    };
    assert!(zero_nodes.validate().is_err());
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let world = world(25, false, 5);
    let outcome = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let (filter, _) = run(&world, small(16));
            let improved = FastSlamParams {
                proposal: Proposal::Improved,
                ..small(8)
            };
            let (improved, _) = run(&world, improved);
            let poses: Vec<(Pose2, f64)> = filter.particle_poses();
            let map: Vec<Vec<f64>> = filter
                .map()
                .iter()
                .map(|(_, f)| f.coordinates().to_vector().as_slice().to_vec())
                .collect();
            (poses, map, filter.resamplings(), improved.particle_poses())
        })
    };
    let one = outcome(1);
    let two = outcome(2);
    assert!(one.2 > 0, "the run resampled");
    assert_eq!(one, two);
    // Another seed gives another result (the seed is used).
    let (other, _) = run(
        &world,
        FastSlamParams {
            seed: 99,
            ..small(16)
        },
    );
    assert_ne!(other.particle_poses(), one.0);
}

#[test]
fn systematic_resampling_keeps_the_weight_distribution() {
    // Each index is drawn floor(N w) or ceil(N w) times, and on average N w times.
    let weights = [0.05, 0.4, 0.0, 0.15, 0.3, 0.1];
    let n = weights.len();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let uniform = rand_distr::Uniform::new(0.0, 1.0 / n as f64).unwrap();
    let trials = 2000;
    let mut totals = [0usize; 6];
    for _ in 0..trials {
        let chosen = systematic_resample(&weights, uniform.sample(&mut rng));
        assert_eq!(chosen.len(), n);
        let mut counts = [0usize; 6];
        for i in chosen {
            counts[i] += 1;
        }
        for k in 0..n {
            let expected = n as f64 * weights[k];
            assert!(
                counts[k] as f64 >= expected.floor() - 1e-9
                    && counts[k] as f64 <= expected.ceil() + 1e-9,
                "index {k}: {} draws for weight {}",
                counts[k],
                weights[k]
            );
            totals[k] += counts[k];
        }
    }
    // Mean counts against N w: the fraction of u giving the extra draw has a binomial
    // spread of at most 0.5 / sqrt(trials); 4 sigma.
    for k in 0..n {
        let mean = totals[k] as f64 / trials as f64;
        let expected = n as f64 * weights[k];
        assert!(
            (mean - expected).abs() < 4.0 * 0.5 / (trials as f64).sqrt(),
            "index {k}: mean {mean}, expected {expected}"
        );
    }
    assert_eq!(totals[2], 0, "a zero weight is never drawn");
}

#[test]
fn log_weights_normalize_without_overflow() {
    let w = normalized(&[-1e4, -1e4 + 2f64.ln(), f64::NEG_INFINITY]);
    assert!((w[0] - 1.0 / 3.0).abs() < 1e-12 && (w[1] - 2.0 / 3.0).abs() < 1e-12);
    assert_eq!(w[2], 0.0);
}

#[test]
fn bad_parameters_are_errors() {
    for params in [
        FastSlamParams {
            particles: 0,
            ..Default::default()
        },
        FastSlamParams {
            resample_threshold: 1.5,
            ..Default::default()
        },
    ] {
        assert!(FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), params).is_err());
    }
}

/// One particle standing still that sees the two walls twice: the extents of the confirmed
/// walls of the map it reports. Its own map keeps both walls either way.
fn walls_seen_twice(merge: bool, offsets: [f64; 2]) -> Vec<(f64, f64, f64)> {
    let params = FastSlamParams {
        particles: 1,
        confirm_after: 1,
        merge_duplicates: merge,
        ..Default::default()
    };
    let mut filter = FastSlam::new(Pose2::identity(), DMatrix::zeros(3, 3), params).unwrap();
    let still = Unicycle::new(0.0, 0.0, 0.1, 1e-3, 1e-3, Integration::Arc).unwrap();
    for _ in 0..2 {
        filter.predict(&still).unwrap();
        let sightings = [
            wall_sighting(offsets[0], 0.0, 3.0),
            wall_sighting(offsets[1], 2.0, 5.0),
        ];
        filter.update(&sightings).unwrap();
    }
    let own = filter.set.best_particle().map.landmarks.iter();
    assert_eq!(own.filter(|(_, l)| l.feature.mspace_dim() > 0).count(), 2);
    let mut extents: Vec<(f64, f64, f64)> = filter
        .map()
        .iter()
        .filter(|(_, f)| f.mspace_dim() > 0)
        .filter_map(|(_, f)| match f.shape() {
            Some(slam_core::Shape::Wall { start, end }) => Some((
                start.x.min(end.x),
                start.x.max(end.x),
                0.5 * (start.y + end.y),
            )),
            _ => None,
        })
        .collect();
    extents.sort_by(|a, b| a.0.total_cmp(&b.0));
    extents
}

/// A wall mapped twice (two overlapping sightings 1 cm apart) is one wall over both extents
/// in the reported map when merging is on, and two when it is off; walls 30 cm apart stay
/// two.
#[test]
fn a_wall_mapped_twice_is_one_wall_in_the_reported_map() {
    assert_eq!(walls_seen_twice(false, [2.0, 2.01]).len(), 2);
    let merged = walls_seen_twice(true, [2.0, 2.01]);
    assert_eq!(merged.len(), 1, "{merged:?}");
    let (from, to, offset) = merged[0];
    assert!(from < 0.05 && to > 4.95, "{merged:?}");
    // Fused between the two, not pushed away from either.
    assert!((2.0..=2.01).contains(&offset), "{merged:?}");
    assert_eq!(walls_seen_twice(true, [2.0, 2.3]).len(), 2);
}
