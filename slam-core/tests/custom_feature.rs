//! The extension point "a new feature type": a user-defined feature and measurement model run
//! through the conformance suite and the generic chain, and the suite catches broken ones.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Vector2};
use slam_core::testing::{ConformanceParams, check_feature, check_measurement};
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, FeatureMap, Growth, Innovation, MeasurementModel,
    Pose2, Pose3, Result, RowOwner, Subspace, stack_rows, wrap_angle,
};

/// What to break on purpose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
enum Bug {
    #[default]
    None,
    /// B~ scaled by 1.1: B B~ != I.
    WrongDual,
    /// apply_perturbation also moves the unobserved beacon (not what B~ says).
    LeakyApply,
    /// While `b` is inactive, B~ of `a` also moves beacon b (which is unobserved then).
    DualLeak,
    /// Own B~ writes into a shared block.
    SharedLeak,
    /// Serialization forgets the active subspaces.
    LossySerde,
}

const A: Subspace = Subspace {
    name: "a",
    rows: 2,
    description: "position of beacon a",
};
const B: Subspace = Subspace {
    name: "b",
    rows: 2,
    description: "position of beacon b",
};

/// Two 2-D beacons; beacon b may be shared.
#[derive(Clone, Debug, PartialEq, Deserialize)]
struct Beacons {
    coordinates: Coordinates,
    active: Vec<String>,
    shared_b: bool,
    bug: Bug,
}

impl Serialize for Beacons {
    fn serialize<S: serde::Serializer>(
        &self,
        serializer: S,
    ) -> std::result::Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Repr<'a> {
            coordinates: &'a Coordinates,
            active: Vec<String>,
            shared_b: bool,
            bug: Bug,
        }
        let lossy = self.bug == Bug::LossySerde;
        Repr {
            coordinates: &self.coordinates,
            active: if lossy {
                Vec::new()
            } else {
                self.active.clone()
            },
            shared_b: self.shared_b,
            bug: self.bug,
        }
        .serialize(serializer)
    }
}

impl Beacons {
    fn new(a: Vector2<f64>, b: Vector2<f64>, bug: Bug) -> Self {
        Beacons {
            coordinates: Coordinates::new(vec![CoordBlock::Point2(a), CoordBlock::Point2(b)])
                .unwrap(),
            active: Vec::new(),
            shared_b: false,
            bug,
        }
    }

    fn spec(name: &str) -> Subspace {
        if name == "a" { A } else { B }
    }

    fn rows(&self, name: &str) -> DMatrix<f64> {
        let mut rows = DMatrix::zeros(2, 4);
        let offset = if name == "a" { 0 } else { 2 };
        rows[(0, offset)] = 1.0;
        rows[(1, offset + 1)] = 1.0;
        rows
    }
}

#[typetag::serde(name = "test-beacons")]
impl Feature for Beacons {
    fn kind(&self) -> &'static str {
        "test-beacons"
    }
    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }
    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        self.coordinates = coordinates;
        Ok(())
    }
    fn active_subspaces(&self) -> Vec<Subspace> {
        self.active.iter().map(|n| Self::spec(n)).collect()
    }
    fn growth_options(&self) -> Vec<Subspace> {
        [A, B]
            .into_iter()
            .filter(|s| !self.active.iter().any(|n| n == s.name))
            .filter(|s| !(self.shared_b && s.name == "b"))
            .collect()
    }
    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        let spec = self
            .growth_options()
            .into_iter()
            .find(|s| s.name == subspace)
            .ok_or(Error::Growth {
                feature: "test-beacons",
                subspace: subspace.into(),
                reason: "unavailable".into(),
            })?;
        let before = self.mspace_dim();
        self.active.push(spec.name.to_string());
        Ok(Growth {
            subspace: spec,
            rows: before..before + 2,
        })
    }
    fn projection(&self) -> Result<DMatrix<f64>> {
        stack_rows(4, &self.active, |n| Ok(self.rows(n)))
    }
    fn dual(&self) -> Result<DMatrix<f64>> {
        let mut dual = self.projection()?.transpose();
        match self.bug {
            Bug::WrongDual => dual *= 1.1,
            Bug::SharedLeak if self.shared_b && dual.ncols() > 0 => dual[(2, 0)] = 0.5,
            Bug::DualLeak if !self.shared_b && !self.active.iter().any(|n| n == "b") => {
                if let Some(column) = self.active.iter().position(|n| n == "a") {
                    dual[(2, 2 * column)] = 0.3;
                }
            }
            _ => {}
        }
        Ok(dual)
    }
    fn apply_perturbation(&mut self, dx_p: &DVector<f64>) -> Result<()> {
        if dx_p.len() != self.mspace_dim() || dx_p.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidArgument("bad perturbation".into()));
        }
        let mut dx = self.dual()? * dx_p;
        if self.bug == Bug::LeakyApply && !self.active.iter().any(|n| n == "b") && !dx_p.is_empty()
        {
            dx[3] += 0.01 * dx_p[0];
        }
        let mut c = self.coordinates.clone();
        c.add_vector(&dx)?;
        self.set_coordinates(c)
    }
    fn shareable_blocks(&self) -> Vec<usize> {
        vec![1]
    }
    fn is_shared(&self, index: usize) -> bool {
        index == 1 && self.shared_b
    }
    fn share_block(&mut self, index: usize) -> Result<()> {
        if index != 1 || self.shared_b {
            return Err(Error::Sharing("only beacon b, once".into()));
        }
        self.active.retain(|n| n != "b");
        self.shared_b = true;
        Ok(())
    }
}

/// Range and bearing to beacon a from a planar sensor.
#[derive(Clone, Debug)]
struct RangeBearing {
    range: f64,
    bearing: f64,
    sigma: f64,
    wrong_jacobian: bool,
}

impl MeasurementModel for RangeBearing {
    type Feature = Beacons;
    fn innovation(&self, _feature: &Beacons, x_o: &Coordinates) -> Result<Innovation> {
        let CoordBlock::Point2(p) = x_o.blocks()[0] else {
            return Err(Error::InvalidArgument("beacon a is a 2-D point".into()));
        };
        let r = p.norm();
        let mut d_eta_d_xo = DMatrix::zeros(2, 4);
        d_eta_d_xo[(0, 0)] = p.x / r;
        d_eta_d_xo[(0, 1)] = p.y / r;
        d_eta_d_xo[(1, 0)] = -p.y / (r * r);
        d_eta_d_xo[(1, 1)] = if self.wrong_jacobian {
            -p.x / (r * r)
        } else {
            p.x / (r * r)
        };
        Ok(Innovation {
            eta: DVector::from_vec(vec![
                r - self.range,
                wrap_angle(p.y.atan2(p.x) - self.bearing),
            ]),
            d_eta_d_xo,
            d_eta_d_v: -DMatrix::identity(2, 2),
            cov_v: DMatrix::identity(2, 2) * self.sigma * self.sigma,
        })
    }
    fn measurement(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.range, self.bearing])
    }
    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        Ok(RangeBearing {
            range: v[0],
            bearing: v[1],
            ..self.clone()
        })
    }
}

fn beacons(bug: Bug) -> Beacons {
    Beacons::new(Vector2::new(3.0, 1.0), Vector2::new(-2.0, 4.0), bug)
}

fn failed_check(bug: Bug) -> &'static str {
    check_feature(&beacons(bug), &ConformanceParams::default())
        .map(|r| panic!("{bug:?} passed the conformance suite: {r:?}"))
        .unwrap_err()
        .check
}

#[test]
fn a_correct_user_feature_conforms() {
    let report = check_feature(&beacons(Bug::None), &ConformanceParams::default()).unwrap();
    // {}, {a}, {b}, {a,b}, and with b shared: {}, {a}.
    assert_eq!(
        report.configurations.len(),
        6,
        "{:#?}",
        report.configurations
    );
    assert_eq!(report.max_dim, 4);
}

#[test]
fn the_suite_catches_broken_features() {
    assert_eq!(failed_check(Bug::WrongDual), "B B~ = I");
    assert_eq!(failed_check(Bug::LeakyApply), "d x_f / d dx_p = B~");
    assert_eq!(failed_check(Bug::DualLeak), "unobserved directions");
    assert_eq!(failed_check(Bug::SharedLeak), "shared block");
    assert_eq!(failed_check(Bug::LossySerde), "serde");
}

#[test]
fn measurement_suite_checks_the_whole_chain() {
    let mut feature = beacons(Bug::None);
    feature.activate("a").unwrap();
    feature.share_block(1).unwrap();
    let model = RangeBearing {
        range: 2.0,
        bearing: 0.3,
        sigma: 0.1,
        wrong_jacobian: false,
    };
    let robot = Pose2::new(0.5, -0.5, 0.4);
    let mount = Pose3::new(
        slam_core::nalgebra::Vector3::new(0.2, 0.0, 0.3),
        0.1,
        0.05,
        -0.03,
    );
    check_measurement(
        &model,
        &feature,
        &robot,
        &mount,
        &ConformanceParams::default(),
    )
    .unwrap();
    let broken = RangeBearing {
        wrong_jacobian: true,
        ..model
    };
    let failure = check_measurement(
        &broken,
        &feature,
        &robot,
        &mount,
        &ConformanceParams::default(),
    )
    .expect_err("a wrong J_eta_o passed");
    assert_eq!(failure.check, "J_eta_o");
}

#[test]
fn a_user_feature_shares_a_block_in_a_map() {
    let mut map = FeatureMap::new();
    let first = map.insert(Box::new(beacons(Bug::None))).unwrap();
    let second = map
        .insert(Box::new(Beacons::new(
            Vector2::new(0.0, 5.0),
            Vector2::new(-2.1, 4.1),
            Bug::None,
        )))
        .unwrap();
    map.activate(first, "a").unwrap();
    let corner = map
        .share(
            &[(first, 1), (second, 1)],
            CoordBlock::Point2(Vector2::new(-2.0, 4.0)),
        )
        .unwrap();
    assert_eq!(
        map.row_owners(first).unwrap(),
        vec![(RowOwner::Feature(first), 2), (RowOwner::Shared(corner), 2)]
    );
    assert_eq!(
        map.row_owners(second).unwrap(),
        vec![(RowOwner::Shared(corner), 2)]
    );
    map.apply(&[(RowOwner::Shared(corner), DVector::from_vec(vec![0.1, -0.2]))])
        .unwrap();
    for id in [first, second] {
        assert_eq!(
            map.get(id).unwrap().coordinates().blocks()[1],
            CoordBlock::Point2(Vector2::new(-1.9, 3.8))
        );
    }
    map.check_consistency().unwrap();
    // A map survives serialization with its sharing intact.
    let json = serde_json::to_string(&map).unwrap();
    let back: FeatureMap = serde_json::from_str(&json).unwrap();
    assert_eq!(
        back.row_owners(first).unwrap(),
        map.row_owners(first).unwrap()
    );
    // Failed updates leave the map unchanged.
    let before = serde_json::to_string(&map).unwrap();
    assert!(
        map.apply(&[(
            RowOwner::Feature(first),
            DVector::from_vec(vec![f64::NAN, 0.0])
        )])
        .is_err()
    );
    assert_eq!(serde_json::to_string(&map).unwrap(), before);
}
