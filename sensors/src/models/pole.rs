//! A laser observation of a pole (tree trunk): range and bearing to its centre and its radius.

use slam_core::nalgebra::{DMatrix, DVector, Vector2};
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, Innovation, MeasurementModel, Pose3, Result,
    ensure_finite, wrap_angle,
};
use slam_features::Pole;

use super::{check_sigmas, scan_plane_to_world};

/// Range and bearing to a [`Pole`]'s centre in the scan plane, and its radius.
///
/// `eta = (|c| - range, wrap(atan2(c_y, c_x) - bearing), r - radius)` with `c` the centre and
/// `r` the radius in the sensor frame (eqs. 8-9).
#[derive(Clone, Debug, PartialEq)]
pub struct PoleObservation {
    /// Range to the centre, m.
    pub range: f64,
    /// Bearing of the centre, rad.
    pub bearing: f64,
    /// Radius, m.
    pub radius: f64,
    /// Standard deviations of range, bearing and radius.
    pub sigmas: [f64; 3],
}

impl PoleObservation {
    /// An observation; values finite, range and radius positive, deviations positive.
    pub fn new(range: f64, bearing: f64, radius: f64, sigmas: [f64; 3]) -> Result<Self> {
        ensure_finite(&[range, bearing, radius], "pole observation")?;
        check_sigmas(&sigmas, "pole observation")?;
        if range <= 0.0 || radius <= 0.0 {
            return Err(Error::InvalidArgument(format!(
                "pole range {range} and radius {radius} must be positive"
            )));
        }
        Ok(PoleObservation {
            range,
            bearing: wrap_angle(bearing),
            radius,
            sigmas,
        })
    }
}

impl MeasurementModel for PoleObservation {
    type Feature = Pole;

    fn innovation(&self, _pole: &Pole, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Scalar(r), CoordBlock::Point2(c)] = x_o.blocks() else {
            return Err(Error::InvalidArgument(
                "a pole is a radius and a 2-D centre".into(),
            ));
        };
        let d2 = c.norm_squared();
        if d2 < 1e-18 {
            return Err(Error::Degenerate("pole centre at the sensor origin".into()));
        }
        let d = d2.sqrt();
        Ok(Innovation {
            eta: DVector::from_vec(vec![
                d - self.range,
                wrap_angle(c.y.atan2(c.x) - self.bearing),
                r - self.radius,
            ]),
            d_eta_d_xo: DMatrix::from_row_slice(
                3,
                3,
                &[
                    0.0,
                    c.x / d,
                    c.y / d,
                    0.0,
                    -c.y / d2,
                    c.x / d2,
                    1.0,
                    0.0,
                    0.0,
                ],
            ),
            d_eta_d_v: -DMatrix::identity(3, 3),
            cov_v: DMatrix::from_diagonal(&DVector::from_iterator(
                3,
                self.sigmas.iter().map(|s| s * s),
            )),
        })
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.range, self.bearing, self.radius])
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        if v.len() != 3 {
            return Err(Error::DimensionMismatch {
                what: "pole observation".into(),
                expected: 3,
                got: v.len(),
            });
        }
        PoleObservation::new(v[0], v[1], v[2], self.sigmas)
    }

    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Pole>> {
        let (s, c) = self.bearing.sin_cos();
        let centre = scan_plane_to_world(
            world_from_sensor,
            &Vector2::new(self.range * c, self.range * s),
        );
        Pole::new(self.radius, centre).map(Some)
    }

    fn revealed_subspaces(&self, pole: &Pole, _x_o: &Coordinates) -> Vec<&'static str> {
        pole.growth_options().into_iter().map(|s| s.name).collect()
    }
}
