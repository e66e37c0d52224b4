//! Range and bearing from a planar sensor to a point landmark (the classic EKF-SLAM case).

use slam_core::nalgebra::{DVector, Matrix2, Matrix2x3, Vector2, Vector3};
use slam_core::{
    CoordBlock, Coordinates, Error, Innovation, LinearizedMeasurement, MapToSensor,
    MeasurementModel, OwnLinearization, Pose3, Result, SensorFrame, assign_matrix, assign_vector,
    chain_covariance, chain_product, chain_product_into, ensure_finite, wrap_angle,
};
use slam_features::Point;

use super::{check_sigmas, dynamic};

/// Range and bearing to a [`Point`] in the plane of a 2-D sensor: the "2-D use of the 3-D
/// point". The prediction uses the point's x and y in the sensor frame (its height does not
/// enter), so a landmark map carries only the point's `"horizontal"` subspace.
///
/// `eta = (|p_xy| - range, wrap(atan2(p_y, p_x) - bearing))`.
///
/// ```
/// use slam_sensors::models::RangeBearing;
/// use slam_features::Point;
/// use slam_core::{MeasurementModel, Coordinates, CoordBlock, nalgebra::Vector3};
/// let z = RangeBearing::new(5.0, 0.0, 0.1, 0.01).unwrap();
/// let x_o = Coordinates::new([CoordBlock::Point3(Vector3::new(5.0, 0.0, 0.0))]).unwrap();
/// let point = Point::planar(Vector3::new(5.0, 0.0, 0.0)).unwrap();
/// assert!(z.innovation(&point, &x_o).unwrap().eta.norm() < 1e-12);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct RangeBearing {
    /// Measured range, m.
    pub range: f64,
    /// Measured bearing in the sensor frame, rad.
    pub bearing: f64,
    /// Range standard deviation, m.
    pub sigma_range: f64,
    /// Bearing standard deviation, rad.
    pub sigma_bearing: f64,
}

impl RangeBearing {
    /// A measurement; values finite, range positive, deviations positive.
    pub fn new(range: f64, bearing: f64, sigma_range: f64, sigma_bearing: f64) -> Result<Self> {
        ensure_finite(&[range, bearing], "range-bearing measurement")?;
        check_sigmas(&[sigma_range, sigma_bearing], "range-bearing")?;
        if range <= 0.0 {
            return Err(Error::InvalidArgument(format!(
                "range must be positive, got {range}"
            )));
        }
        Ok(RangeBearing {
            range,
            bearing: wrap_angle(bearing),
            sigma_range,
            sigma_bearing,
        })
    }
}

/// [`Innovation`]'s fields for a range and bearing, on the stack.
struct InnovationParts {
    eta: Vector2<f64>,
    d_eta_d_xo: Matrix2x3<f64>,
    d_eta_d_v: Matrix2<f64>,
    cov_v: Matrix2<f64>,
}

impl RangeBearing {
    /// `eta` and its Jacobians at the point `p` in the sensor frame.
    fn innovation_parts(&self, p: &Vector3<f64>) -> Result<InnovationParts> {
        let r2 = p.x * p.x + p.y * p.y;
        if r2 < 1e-18 {
            return Err(Error::Degenerate("landmark at the sensor origin".into()));
        }
        let r = r2.sqrt();
        Ok(InnovationParts {
            eta: Vector2::new(r - self.range, wrap_angle(p.y.atan2(p.x) - self.bearing)),
            d_eta_d_xo: Matrix2x3::new(p.x / r, p.y / r, 0.0, -p.y / r2, p.x / r2, 0.0),
            d_eta_d_v: Matrix2::new(-1.0, 0.0, 0.0, -1.0),
            cov_v: Matrix2::new(
                self.sigma_range.powi(2),
                0.0,
                0.0,
                self.sigma_bearing.powi(2),
            ),
        })
    }
}

impl MeasurementModel for RangeBearing {
    type Feature = Point;

    fn innovation(&self, _point: &Point, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point3(p)] = x_o.blocks() else {
            return Err(Error::InvalidArgument("a point is one 3-D block".into()));
        };
        let parts = self.innovation_parts(p)?;
        Ok(Innovation {
            eta: DVector::from_column_slice(parts.eta.as_slice()),
            d_eta_d_xo: dynamic(&parts.d_eta_d_xo),
            d_eta_d_v: dynamic(&parts.d_eta_d_v),
            cov_v: dynamic(&parts.cov_v),
        })
    }

    /// The generic chain on stack matrices: `x_o = R (p - t)`, `J_of = R`, and `B~` the
    /// point's own (its active subspaces).
    fn linearize_own(
        &self,
        point: &Point,
        to_sensor: &MapToSensor,
        out: &mut OwnLinearization,
    ) -> Option<Result<()>> {
        let mut own = || {
            let position = point.position();
            let parts = self.innovation_parts(&to_sensor.transform_point3(&position))?;
            let d_eta_d_xf = chain_product(&parts.d_eta_d_xo, to_sensor.rotation_3d());
            let (dual, dim) = point.dual_columns();
            assign_vector(&mut out.eta, parts.eta.as_slice());
            assign_matrix(
                &mut out.cov_eta,
                &chain_covariance(&parts.d_eta_d_v, &parts.cov_v),
            );
            chain_product_into(&d_eta_d_xf, &dual.columns(0, dim), &mut out.d_eta_d_own);
            Ok(())
        };
        Some(own())
    }

    /// The generic chain on stack matrices, as [`MeasurementModel::linearize_own`] with the
    /// sensor columns `J_eta_o J_os` and the robot's `J_eta_o J_os J_sr`; a point shares no
    /// block. The EKF calls it for every pairing of a step, with one `out` kept across
    /// steps: once `out` has the shapes, no allocation.
    fn linearize_at(
        &self,
        point: &Point,
        frame: &SensorFrame,
        out: &mut LinearizedMeasurement,
    ) -> Option<Result<()>> {
        let mut lin = || {
            let position = point.position();
            let to_sensor = &frame.to_sensor;
            let (d_xo_d_sensor, d_xo_d_xm) = to_sensor.point3_jacobians(&position);
            let parts = self.innovation_parts(&to_sensor.transform_point3(&position))?;
            let d_eta_d_sensor = chain_product(&parts.d_eta_d_xo, &d_xo_d_sensor);
            let d_eta_d_xf = chain_product(&parts.d_eta_d_xo, &d_xo_d_xm);
            out.write_unshared(
                parts.eta.as_slice(),
                &chain_covariance(&parts.d_eta_d_v, &parts.cov_v),
                &d_eta_d_sensor,
                frame,
                &d_eta_d_xf,
            );
            let (dual, dim) = point.dual_columns();
            chain_product_into(&d_eta_d_xf, &dual.columns(0, dim), &mut out.d_eta_d_own);
            Ok(())
        };
        Some(lin())
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.range, self.bearing])
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        if v.len() != 2 {
            return Err(Error::DimensionMismatch {
                what: "range-bearing measurement".into(),
                expected: 2,
                got: v.len(),
            });
        }
        RangeBearing::new(v[0], v[1], self.sigma_range, self.sigma_bearing)
    }

    /// The point where the beam hit, in 3-D (on the scan plane, however tilted).
    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Point>> {
        let (s, c) = self.bearing.sin_cos();
        let hit =
            world_from_sensor.transform_point(&Vector3::new(self.range * c, self.range * s, 0.0));
        Point::new(hit).map(Some)
    }

    /// The horizontal subspace while the point does not have it (no allocation once it
    /// does: this runs for every sighting).
    fn revealed_subspaces(&self, point: &Point, _x_o: &Coordinates) -> Vec<&'static str> {
        let horizontal = slam_features::point::HORIZONTAL.name;
        if point.is_active(horizontal) {
            Vec::new()
        } else {
            vec![horizontal]
        }
    }
}
