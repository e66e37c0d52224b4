//! Walls sharing a corner (paper section VI): one set of M-space rows for the corner, the
//! dual of eq. 33, and an update of the corner moving both walls.

use slam_core::nalgebra::{DMatrix, DVector, Vector2, Vector3};
use slam_core::testing::assert_measurement_conforms;
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, FeatureMap, Innovation, MeasurementModel, Pose2,
    Pose3, Result, RowOwner, wrap_angle,
};
use slam_features::Wall;

/// A test fixture: the infinite line through a wall as a 2-D laser sees it, by the angle of
/// its normal and its distance, in the sensor frame.
#[derive(Clone, Debug)]
struct LineSighting {
    angle: f64,
    distance: f64,
}

impl MeasurementModel for LineSighting {
    type Feature = Wall;

    fn innovation(&self, _wall: &Wall, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point2(s), CoordBlock::Point2(e)] = x_o.blocks() else {
            return Err(Error::InvalidArgument("wall".into()));
        };
        let u = e - s;
        let l = u.norm();
        let p = DMatrix::from_row_slice(2, 2, &[0.0, -1.0, 1.0, 0.0]);
        let n = Vector2::new(-u.y, u.x) / l;
        let t = u / l;
        // gamma = atan2(n): d gamma / d u = n^T / L.
        // d = -n . s: d d / d s = -n^T + (s^T P - (s . n) t^T) / L,  d d / d e = -(s^T P - (s . n) t^T) / L.
        let sp = DMatrix::from_row_slice(1, 2, s.as_slice()) * &p;
        let w = (sp - DMatrix::from_row_slice(1, 2, &[t.x, t.y]) * s.dot(&n)) / l;
        let mut d = DMatrix::zeros(2, 4);
        d[(0, 0)] = -n.x / l;
        d[(0, 1)] = -n.y / l;
        d[(0, 2)] = n.x / l;
        d[(0, 3)] = n.y / l;
        d[(1, 0)] = -n.x + w[(0, 0)];
        d[(1, 1)] = -n.y + w[(0, 1)];
        d[(1, 2)] = -w[(0, 0)];
        d[(1, 3)] = -w[(0, 1)];
        Ok(Innovation {
            eta: DVector::from_vec(vec![
                wrap_angle(n.y.atan2(n.x) - self.angle),
                -n.dot(s) - self.distance,
            ]),
            d_eta_d_xo: d,
            d_eta_d_v: -DMatrix::identity(2, 2),
            cov_v: DMatrix::from_diagonal(&DVector::from_vec(vec![1e-4, 4e-4])),
        })
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.angle, self.distance])
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        Ok(LineSighting {
            angle: v[0],
            distance: v[1],
        })
    }
}

/// Two walls of a room corner at (4, 3): A along y = 3 seen from below, B along x = 4 seen
/// from the left.
fn corner_map() -> (
    FeatureMap,
    slam_core::FeatureId,
    slam_core::FeatureId,
    slam_core::SharedBlockId,
) {
    let viewer = Vector2::new(1.0, 1.0);
    let a = Wall::seen_from(Vector2::new(0.0, 3.0), Vector2::new(3.95, 3.0), viewer)
        .unwrap()
        .with_subspaces(&["line"])
        .unwrap();
    let b = Wall::seen_from(Vector2::new(4.0, 2.9), Vector2::new(4.0, -1.0), viewer)
        .unwrap()
        .with_subspaces(&["line", "start"])
        .unwrap();
    let mut map = FeatureMap::new();
    let a = map.insert(Box::new(a)).unwrap();
    let b = map.insert(Box::new(b)).unwrap();
    // A runs from (3.95, 3) to (0, 3): its start is the corner; B runs (4, -1) -> (4, 2.9):
    // its end is the corner, and its "start" row is the tangent of the far end.
    let a_corner = corner_index(map.get(a).unwrap(), Vector2::new(4.0, 3.0));
    let b_corner = corner_index(map.get(b).unwrap(), Vector2::new(4.0, 3.0));
    let corner = map
        .share(
            &[(a, a_corner), (b, b_corner)],
            CoordBlock::Point2(Vector2::new(4.0, 3.0)),
        )
        .unwrap();
    (map, a, b, corner)
}

fn corner_index(wall: &dyn Feature, corner: Vector2<f64>) -> usize {
    let distance = |k: usize| match wall.coordinates().blocks()[k] {
        CoordBlock::Point2(p) => (p - corner).norm(),
        _ => f64::INFINITY,
    };
    if distance(0) < distance(1) { 0 } else { 1 }
}

#[test]
fn the_corner_has_one_set_of_rows() {
    let (map, a, b, corner) = corner_map();
    // A had only "line": it keeps one own row (the pivot). B had "line" and the tangent of the
    // far end: pivot + that tangent. The corner has two rows of its own, seen by both.
    assert_eq!(
        map.row_owners(a).unwrap(),
        vec![(RowOwner::Feature(a), 1), (RowOwner::Shared(corner), 2)]
    );
    assert_eq!(
        map.row_owners(b).unwrap(),
        vec![(RowOwner::Feature(b), 2), (RowOwner::Shared(corner), 2)]
    );
    assert_eq!(map.get(b).unwrap().active_subspaces()[1].name, "start");
    map.check_consistency().unwrap();
}

#[test]
fn moving_the_corner_moves_both_walls() {
    let (mut map, a, b, corner) = corner_map();
    map.apply(&[(
        RowOwner::Shared(corner),
        DVector::from_vec(vec![0.05, -0.02]),
    )])
    .unwrap();
    let expected = CoordBlock::Point2(Vector2::new(4.05, 2.98));
    for id in [a, b] {
        let wall = map.get(id).unwrap();
        let k = corner_index(wall, Vector2::new(4.05, 2.98));
        assert_eq!(wall.coordinates().blocks()[k], expected);
    }
    map.check_consistency().unwrap();
}

#[test]
fn the_pivot_rotates_about_the_corner_as_eq_33_says() {
    let (mut map, a, _, _) = corner_map();
    let before = map.get(a).unwrap().coordinates().clone();
    map.apply(&[(RowOwner::Feature(a), DVector::from_vec(vec![0.1]))])
        .unwrap();
    let wall = map.get(a).unwrap();
    let wall: &Wall = slam_core::downcast_feature(wall).unwrap();
    // L = L_s here, so the free end moves by exactly 0.1 along the normal; the corner stays.
    assert_eq!(wall.coordinates().blocks()[0], before.blocks()[0]);
    let CoordBlock::Point2(free_before) = before.blocks()[1] else {
        unreachable!()
    };
    let normal_before: Vector2<f64> = Vector2::new(0.0, -1.0);
    assert!((wall.end() - (free_before + 0.1 * normal_before)).norm() < 1e-12);
}

#[test]
fn measurements_of_a_cornered_wall_see_the_corner_rows() {
    let (map, a, _, corner) = corner_map();
    let robot = Pose2::new(1.0, 1.0, 0.3);
    let mount = Pose3::new(Vector3::new(0.2, 0.0, 0.3), 0.0, 0.0, 0.0);
    let sighting = LineSighting {
        angle: -1.9,
        distance: 1.9,
    };
    let lin = map.linearize(a, &sighting, &robot, &mount).unwrap();
    let owners: Vec<RowOwner> = lin.columns.iter().map(|(o, _)| *o).collect();
    assert_eq!(owners, vec![RowOwner::Feature(a), RowOwner::Shared(corner)]);
    assert_eq!(lin.columns[1].1.shape(), (2, 2));
    // The whole chain, shared columns included, against central differences.
    let wall: &Wall = slam_core::downcast_feature(map.get(a).unwrap()).unwrap();
    assert_measurement_conforms(&sighting, wall, &robot, &mount);
}

#[test]
fn a_wall_cannot_join_a_corner_twice_or_with_a_wrong_block() {
    let (mut map, a, b, _) = corner_map();
    let a_corner = corner_index(map.get(a).unwrap(), Vector2::new(4.0, 3.0));
    assert!(
        map.share(&[(a, a_corner)], CoordBlock::Point2(Vector2::new(4.0, 3.0)))
            .is_err()
    );
    assert!(map.share(&[(b, 0)], CoordBlock::Scalar(1.0)).is_err());
    assert!(
        map.remove(a).is_err(),
        "a cornered wall cannot be removed alone"
    );
    map.check_consistency().unwrap();
}
