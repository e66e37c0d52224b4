use super::*;

/// The settings of these synthetic tests: the default with an M-step that ignores points
/// farther than 3 sigma (the clutter of the room, the other strip of Fig. 1).
fn robust() -> EmPolygonParams {
    EmPolygonParams {
        outlier_sigmas: Some(3.0),
        ..Default::default()
    }
}

/// Deterministic noise in `[-1, 1]` (splitmix64).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

/// Points along `a b` every `step`, moved across the strip by up to `half_width`.
fn strip(
    a: Vector2<f64>,
    b: Vector2<f64>,
    step: f64,
    half_width: f64,
    noise: &mut Noise,
) -> Vec<Vector2<f64>> {
    let d = b - a;
    let n = Vector2::new(-d.y, d.x) / d.norm();
    let count = (d.norm() / step) as usize;
    (0..=count)
        .map(|k| a + d * (k as f64 / count as f64) + n * (half_width * noise.next()))
        .collect()
}

fn v(x: f64, y: f64) -> Vector2<f64> {
    Vector2::new(x, y)
}

/// Angle between the directions of two segments, degrees.
fn angle_deg(a: &Segment, b: &Segment) -> f64 {
    let (u, w) = (a.end - a.start, b.end - b.start);
    (u.dot(&w).abs() / (u.norm() * w.norm()))
        .min(1.0)
        .acos()
        .to_degrees()
}

/// Whether `s` runs from near `a` to near `b` (either way), within `tolerance`.
fn matches(s: &Segment, a: Vector2<f64>, b: Vector2<f64>, tolerance: f64) -> bool {
    let forward = (s.start - a).norm().max((s.end - b).norm());
    let backward = (s.start - b).norm().max((s.end - a).norm());
    forward.min(backward) <= tolerance
}

/// The paper's Fig. 1: two crossing strips of points, two starting lines that each see the
/// upper or lower half of both strips.
#[test]
fn figure_1_plain_em_stays_in_the_local_optimum_split_and_merge_finds_both_strips() {
    let mut noise = Noise(7);
    let strips = [(v(-5.0, -3.0), v(5.0, 3.0)), (v(-5.0, 3.0), v(5.0, -3.0))];
    let mut points = strip(strips[0].0, strips[0].1, 0.02, 0.04, &mut noise);
    points.extend(strip(strips[1].0, strips[1].1, 0.02, 0.04, &mut noise));
    let start = [
        Segment::new(v(-5.0, 1.5), v(5.0, 1.5)),
        Segment::new(v(-5.0, -1.5), v(5.0, -1.5)),
    ];
    let truth = [
        Segment::new(strips[0].0, strips[0].1),
        Segment::new(strips[1].0, strips[1].1),
    ];

    // Plain EM segment fitting: EMSF repeated, with the same sigma rule, no split or merge.
    let params = robust();
    let mut segments = start.to_vec();
    for _ in 0..50 {
        let sigma = robust_spread(&nearest_distances(&points, &segments)).max(params.sigma_min);
        segments = emsf(&points, &segments, sigma, params.outlier_sigmas).unwrap();
    }
    let plain_mean = mean(&nearest_distances(&points, &segments)).unwrap();
    assert_eq!(segments.len(), 2);
    for s in &segments {
        // Each line lies across the "V" of half of both strips: far from either direction.
        for t in &truth {
            assert!(
                angle_deg(s, t) > 20.0,
                "plain EM found a strip: {segments:?}"
            );
        }
    }
    assert!(plain_mean > 0.3, "plain EM mean distance {plain_mean}");

    // Split-and-merge EM from the same two lines.
    let fitted = fit_polygons_from(&points, start.to_vec(), &params).unwrap();
    assert_eq!(fitted.segments.len(), 2, "{:?}", fitted.segments);
    for t in &truth {
        assert!(
            fitted
                .segments
                .iter()
                .any(|s| matches(s, t.start, t.end, 0.15)),
            "strip {t:?} not found in {:?}",
            fitted.segments
        );
    }
    let mean_distance = fitted.mean_distance.unwrap();
    assert!(mean_distance < 0.03, "SMEMSF mean distance {mean_distance}");
    assert!(fitted.converged);
    // And from the bounding-box diagonals, the paper's default start.
    let from_diagonals = fit_polygons(&points, &params).unwrap();
    assert_eq!(
        from_diagonals.segments.len(),
        2,
        "{:?}",
        from_diagonals.segments
    );
}

/// A small room: four walls with a doorway, noisy points, some clutter.
fn room(noise: &mut Noise) -> Vec<Vector2<f64>> {
    let mut points = Vec::new();
    for (a, b) in [
        (v(0.0, 0.0), v(6.0, 0.0)),
        (v(6.0, 0.0), v(6.0, 4.0)),
        (v(6.0, 4.0), v(3.5, 4.0)),
        (v(2.5, 4.0), v(0.0, 4.0)),
        (v(0.0, 4.0), v(0.0, 0.0)),
    ] {
        points.extend(strip(a, b, 0.01, 0.02, noise));
    }
    points.extend((0..40).map(|_| v(3.0 + 2.5 * noise.next(), 2.0 + 1.5 * noise.next())));
    points
}

#[test]
fn a_room_with_a_doorway_becomes_five_walls_in_one_polyline() {
    let points = room(&mut Noise(3));
    let map = fit_polygons(&points, &robust()).unwrap();
    assert_eq!(map.segments.len(), 5, "{:?}", map.segments);
    assert_eq!(map.polylines.len(), 1, "{:?}", map.polylines);
    assert!(!map.polylines[0].closed);
    for corner in [v(0.0, 0.0), v(6.0, 0.0), v(6.0, 4.0), v(0.0, 4.0)] {
        assert!(
            map.polylines[0]
                .vertices
                .iter()
                .any(|p| (p - corner).norm() < 0.05),
            "corner {corner:?}: {:?}",
            map.polylines[0].vertices
        );
    }
    let median_distance = map.median_distance.unwrap();
    assert!(median_distance < 0.015, "median distance {median_distance}");
    assert_eq!(map.compression_ratio, Some(points.len() as f64 / 10.0));
    // The walls' noise (uniform in +-2 cm: deviation 1.15 cm) is measured from the points,
    // and the annealed sigma ends there.
    let noise = map.noise_level.unwrap();
    assert!(
        (noise / (0.02 / 3f64.sqrt()) - 1.0).abs() < 0.15,
        "noise {noise}"
    );
    let last = map.iterations.last().unwrap();
    assert_eq!(last.sigma, noise.max(robust().sigma_min));
}

#[test]
fn a_mean_distance_bound_gives_fewer_segments_and_is_kept_after_the_joins() {
    // The room with clutter and, outside three walls, a short shelf of 120 points 60 cm off
    // it. Without the selection the fit keeps the shelves; a bound on the mean distance
    // removes what it can afford, and no wall (the bound applies on its own, without the selection).
    let mut noise = Noise(5);
    let mut points = room(&mut noise);
    for (a, b) in [
        (v(1.0, -0.6), v(1.6, -0.6)),
        (v(6.6, 1.0), v(6.6, 1.6)),
        (v(1.0, 4.6), v(1.6, 4.6)),
    ] {
        points.extend(strip(a, b, 0.005, 0.005, &mut noise));
    }
    let unselected = EmPolygonParams {
        select_segments: false,
        ..robust()
    };
    let default = fit_polygons(&points, &unselected).unwrap();
    // A shelf's points are 0.6 m from anything else: removing one adds about 3 cm to the
    // mean of the 2,300 points.
    let bound = default.mean_distance.unwrap() + 0.05;
    let compact = fit_polygons(
        &points,
        &EmPolygonParams {
            max_mean_distance: Some(bound),
            ..unselected.clone()
        },
    )
    .unwrap();
    let mean = compact.mean_distance.unwrap();
    assert!(mean <= bound, "mean {mean}");
    assert!(
        compact.segments.len() < default.segments.len(),
        "{} against {}",
        compact.segments.len(),
        default.segments.len()
    );
    assert!(compact.segments.len() >= 5, "{:?}", compact.segments);
    // A bound below the fit's mean removes nothing.
    let tight = fit_polygons(
        &points,
        &EmPolygonParams {
            max_mean_distance: Some(1e-4),
            ..unselected
        },
    )
    .unwrap();
    assert_eq!(tight.segments, default.segments);
    let invalid = EmPolygonParams {
        max_mean_distance: Some(0.0),
        ..Default::default()
    };
    assert!(fit_polygons(&points, &invalid).is_err());
}

#[test]
fn results_do_not_depend_on_the_number_of_threads() {
    let points = room(&mut Noise(11));
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| fit_polygons(&points, &EmPolygonParams::default()).unwrap())
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn degenerate_inputs_give_clear_errors_or_trivial_maps() {
    let params = EmPolygonParams::default();
    // No points.
    let error = fit_polygons(&[], &params).unwrap_err().to_string();
    assert!(error.contains("no points"), "{error}");
    // A NaN or infinite coordinate is named by its index.
    let mut points: Vec<_> = (0..10).map(|k| v(k as f64, 0.0)).collect();
    points[4].y = f64::NAN;
    let error = fit_polygons(&points, &params).unwrap_err().to_string();
    assert!(error.contains("point 4"), "{error}");
    points[4].y = f64::INFINITY;
    assert!(fit_polygons(&points, &params).is_err());
    // All points on one spot: no segment, no panic.
    let spot = vec![v(1.0, 2.0); 100];
    let map = fit_polygons(&spot, &params).unwrap();
    assert!(map.segments.is_empty() && map.mean_distance.is_none());
    // One point.
    assert!(
        fit_polygons(&[v(1.0, 1.0)], &params)
            .unwrap()
            .segments
            .is_empty()
    );
    // Collinear points, along an axis (a flat bounding box) and slanted: one segment.
    for direction in [v(1.0, 0.0), v(0.0, 1.0), v(0.6, 0.8)] {
        let line: Vec<_> = (0..500)
            .map(|k| v(1.0, -2.0) + direction * (k as f64 * 0.01))
            .collect();
        let map = fit_polygons(&line, &params).unwrap();
        assert_eq!(map.segments.len(), 1, "{direction:?}: {:?}", map.segments);
        assert!(map.mean_distance.unwrap() < 1e-9);
        assert!(
            matches(&map.segments[0], line[0], line[499], 1e-6),
            "{:?}",
            map.segments
        );
    }
    // Two distinct points.
    let map = fit_polygons(&[v(0.0, 0.0), v(1.0, 1.0)], &params).unwrap();
    assert!(map.segments.len() <= 1);
    // Bad parameters and a bad sigma are errors, not panics.
    let bad = EmPolygonParams {
        r_min: -1.0,
        ..Default::default()
    };
    assert!(
        fit_polygons(&points[..4], &bad)
            .unwrap_err()
            .to_string()
            .contains("r_min")
    );
    assert!(emsf(&spot, &[], f64::NAN, None).is_err());
    assert!(emsf(&spot, &[], 0.1, Some(3.0)).unwrap().is_empty());
}
