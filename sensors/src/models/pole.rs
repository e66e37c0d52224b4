//! A laser observation of a pole (tree trunk): range and bearing to its centre and its radius.

use slam_core::nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix3x6, Vector2, Vector3};
use slam_core::{
    CoordBlock, Coordinates, Error, Feature, Innovation, LinearizedMeasurement, MapToSensor,
    MeasurementModel, OwnLinearization, Pose3, Result, SensorFrame, all_finite, assign_matrix,
    assign_vector, chain_covariance, chain_product, chain_product_into, ensure_finite,
    reshape_zeroed, wrap_angle,
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

    /// `eta`, `J_eta_o`, `J_eta_v` and `C_v` on the stack for a pole of radius `radius` centred
    /// at `centre` in the sensor frame: the one formula behind
    /// [`MeasurementModel::innovation`] and [`MeasurementModel::linearize_own`].
    fn innovation_parts(&self, radius: f64, centre: &Vector2<f64>) -> Result<InnovationParts> {
        let d2 = centre.norm_squared();
        if d2 < 1e-18 {
            return Err(Error::Degenerate("pole centre at the sensor origin".into()));
        }
        let d = d2.sqrt();
        let (x, y) = (centre.x, centre.y);
        let parts = InnovationParts {
            eta: Vector3::new(
                d - self.range,
                wrap_angle(y.atan2(x) - self.bearing),
                radius - self.radius,
            ),
            d_eta_d_xo: Matrix3::new(0.0, x / d, y / d, 0.0, -y / d2, x / d2, 1.0, 0.0, 0.0),
            d_eta_d_v: -Matrix3::identity(),
            cov_v: Matrix3::from_diagonal(&Vector3::from_iterator(
                self.sigmas.iter().map(|s| s * s),
            )),
        };
        if all_finite(&[
            parts.eta.as_slice(),
            parts.d_eta_d_xo.as_slice(),
            parts.d_eta_d_v.as_slice(),
            parts.cov_v.as_slice(),
        ]) {
            Ok(parts)
        } else {
            Err(Error::NonFinite("innovation".into()))
        }
    }
}

/// `J_of` of a pole's `(radius, centre)`: `diag(1, d_centre)`.
fn scalar_and_point2(d_centre: &Matrix2<f64>) -> Matrix3<f64> {
    let mut d_xo_d_xm = Matrix3::zeros();
    d_xo_d_xm[(0, 0)] = 1.0;
    d_xo_d_xm.fixed_view_mut::<2, 2>(1, 1).copy_from(d_centre);
    d_xo_d_xm
}

/// `J_eta_f B~` into `out` (its storage reused): a full pole's `B~` is the identity, a
/// tentative pole's has no columns (Table II); the product as the chain takes it.
fn own_columns_into(pole: &Pole, d_eta_d_xf: &Matrix3<f64>, out: &mut DMatrix<f64>) {
    if pole.mspace_dim() == 3 {
        chain_product_into(d_eta_d_xf, &Matrix3::identity(), out);
    } else {
        reshape_zeroed(out, 3, 0);
    }
}

/// [`Innovation`]'s fields for a pole, on the stack.
struct InnovationParts {
    eta: Vector3<f64>,
    d_eta_d_xo: Matrix3<f64>,
    d_eta_d_v: Matrix3<f64>,
    cov_v: Matrix3<f64>,
}

impl MeasurementModel for PoleObservation {
    type Feature = Pole;

    fn innovation(&self, _pole: &Pole, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Scalar(r), CoordBlock::Point2(c)] = x_o.blocks() else {
            return Err(Error::InvalidArgument(
                "a pole is a radius and a 2-D centre".into(),
            ));
        };
        let parts = self.innovation_parts(*r, c)?;
        Ok(Innovation {
            eta: DVector::from_column_slice(parts.eta.as_slice()),
            d_eta_d_xo: DMatrix::from_column_slice(3, 3, parts.d_eta_d_xo.as_slice()),
            d_eta_d_v: DMatrix::from_column_slice(3, 3, parts.d_eta_d_v.as_slice()),
            cov_v: DMatrix::from_column_slice(3, 3, parts.cov_v.as_slice()),
        })
    }

    /// The generic chain on stack matrices: `x_o = (r, R (c - t))`, `J_of = diag(1, R)`, and
    /// `B~` the identity of a full pole or no columns for a tentative one (Table II).
    fn linearize_own(
        &self,
        pole: &Pole,
        to_sensor: &MapToSensor,
        out: &mut OwnLinearization,
    ) -> Option<Result<()>> {
        let mut own = || {
            let rotation = to_sensor.rotation_2d()?;
            let centre = to_sensor.transform_point2(&pole.centre())?;
            let parts = self.innovation_parts(pole.radius(), &centre)?;
            let d_xo_d_xm = scalar_and_point2(rotation);
            let d_eta_d_xf = chain_product(&parts.d_eta_d_xo, &d_xo_d_xm);
            assign_vector(&mut out.eta, parts.eta.as_slice());
            assign_matrix(
                &mut out.cov_eta,
                &chain_covariance(&parts.d_eta_d_v, &parts.cov_v),
            );
            own_columns_into(pole, &d_eta_d_xf, &mut out.d_eta_d_own);
            Ok(())
        };
        Some(own())
    }

    /// The generic chain on stack matrices, as [`MeasurementModel::linearize_own`] with the
    /// sensor columns `J_eta_o J_os` and the robot's `J_eta_o J_os J_sr`; a pole shares no
    /// block.
    fn linearize_at(
        &self,
        pole: &Pole,
        frame: &SensorFrame,
        out: &mut LinearizedMeasurement,
    ) -> Option<Result<()>> {
        let mut lin = || {
            let to_sensor = &frame.to_sensor;
            let (d_centre_d_sensor, d_centre_d_centre) =
                to_sensor.point2_jacobians(&pole.centre())?;
            let centre = to_sensor.transform_point2(&pole.centre())?;
            let parts = self.innovation_parts(pole.radius(), &centre)?;
            let mut d_xo_d_sensor = Matrix3x6::zeros();
            d_xo_d_sensor
                .fixed_view_mut::<2, 6>(1, 0)
                .copy_from(&d_centre_d_sensor);
            let d_xo_d_xm = scalar_and_point2(&d_centre_d_centre);
            let d_eta_d_sensor = chain_product(&parts.d_eta_d_xo, &d_xo_d_sensor);
            let d_eta_d_xf = chain_product(&parts.d_eta_d_xo, &d_xo_d_xm);
            out.write_unshared(
                parts.eta.as_slice(),
                &chain_covariance(&parts.d_eta_d_v, &parts.cov_v),
                &d_eta_d_sensor,
                frame,
                &d_eta_d_xf,
            );
            own_columns_into(pole, &d_eta_d_xf, &mut out.d_eta_d_own);
            Ok(())
        };
        Some(lin())
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
