//! Your own feature in the M-space EKF: a floor beacon (a 2-D point, M-space 0 -> 2) seen by
//! range and bearing on the simulated rb2d circle world. Prints the map error.
//! `cargo run --release -p slam-examples --example own_feature_ekf`
use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Vector3};
use slam_core::*;
use slam_runtime::frontend::{FeaturesFrontendConfig, FrontendConfig, SensorInfo};
use slam_runtime::{EstimatorConfig, Session, Start, eval::map_error_against_landmarks};
use slam_sensors::{Event, TimedEvent, models::RangeBearing, sim};
use std::sync::Arc;

const XY: Subspace = Subspace {
    name: "xy",
    rows: 2,
    description: "x and y",
};

/// Its position, and whether it is placed (M-space 2; 0 while tentative).
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Beacon(Coordinates, bool);

#[rustfmt::skip]
#[typetag::serde]
impl Feature for Beacon {
    fn kind(&self) -> &'static str { "beacon" }
    fn coordinates(&self) -> &Coordinates { &self.0 }
    fn set_coordinates(&mut self, at: Coordinates) -> Result<()> { self.0 = at; Ok(()) }
    fn active_subspaces(&self) -> Vec<Subspace> { if self.1 { vec![XY] } else { vec![] } }
    fn growth_options(&self) -> Vec<Subspace> { if self.1 { vec![] } else { vec![XY] } }
    fn activate(&mut self, _: &str) -> Result<Growth> {
        self.1 = true;
        Ok(Growth { subspace: XY, rows: 0..2 })
    }
    fn projection(&self) -> Result<DMatrix<f64>> { Ok(DMatrix::identity(self.mspace_dim(), 2)) }
    fn shape(&self) -> Option<Shape> {
        Some(Shape::PlanarPoint { position: self.0.to_vector().fixed_rows::<2>(0).into() })
    }
}

/// eta = predicted - measured (range, bearing).
#[derive(Clone, Debug)]
struct Sighting(RangeBearing);

#[rustfmt::skip]
impl MeasurementModel for Sighting {
    type Feature = Beacon;
    fn innovation(&self, _: &Beacon, x_o: &Coordinates) -> Result<Innovation> {
        let (p, s) = (x_o.to_vector(), &self.0);
        let (r2, sigmas) = (p[0] * p[0] + p[1] * p[1], [s.sigma_range, s.sigma_bearing]);
        let r = r2.sqrt();
        Ok(Innovation {
            eta: DVector::from_vec(vec![r - s.range, wrap_angle(p[1].atan2(p[0]) - s.bearing)]),
            d_eta_d_xo: DMatrix::from_row_slice(2, 2, &[p[0] / r, p[1] / r, -p[1] / r2, p[0] / r2]),
            d_eta_d_v: -DMatrix::identity(2, 2),
            cov_v: DMatrix::from_diagonal(&DVector::from_iterator(2, sigmas.map(|v| v * v))),
        })
    }
    fn measurement(&self) -> DVector<f64> { DVector::from_vec(vec![self.0.range, self.0.bearing]) }
    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        Ok(Sighting(RangeBearing::new(v[0], v[1], self.0.sigma_range, self.0.sigma_bearing)?))
    }
    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Beacon>> {
        let (s, c) = self.0.bearing.sin_cos();
        let hit = world_from_sensor.transform_point(&(Vector3::new(c, s, 0.0) * self.0.range));
        Ok(Some(Beacon(Coordinates::new(vec![CoordBlock::Point2(hit.xy())])?, false)))
    }
    fn revealed_subspaces(&self, _: &Beacon, _: &Coordinates) -> Vec<&'static str> { vec!["xy"] }
}

/// The simulated range-bearing observations, as beacon sightings.
fn as_beacons(mut event: TimedEvent) -> TimedEvent {
    if let Event::Observations(observations) = &mut event.event {
        for o in observations.iter_mut() {
            if let Some(rb) = o.measurement.as_any().downcast_ref::<RangeBearing>() {
                o.measurement = Arc::new(Sighting(rb.clone()));
            }
        }
    }
    event
}

fn main() -> slam_runtime::Result<()> {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml");
    let run = sim::simulate_stream(&sim::World::from_file(&file)?, 1)?;
    let start = Start {
        pose: Pose2::identity(),
        covariance: DMatrix::zeros(3, 3),
    };
    let ekf = slam_estimators::EkfParams::default().build(&start)?;
    // The features front-end passes the data's own observations on (no laser or camera here).
    let frontend = FeaturesFrontendConfig::default().build(&SensorInfo::default())?;
    let mut session = Session::new(ekf, frontend);
    session.run(run.events.map(|e| e.map(as_beacons)), &mut ())?;
    let landmarks = run.truth.point_landmarks();
    let error = map_error_against_landmarks(session.estimator(), &landmarks, false)?;
    println!(
        "{} beacons mapped, map error {:.3} m RMS",
        error.count, error.rms_m
    );
    assert!(
        error.count >= 45 && error.rms_m < 0.2,
        "beacons not mapped: {error:?}"
    );
    Ok(())
}
