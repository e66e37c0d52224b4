//! One laser return measured against a line feature ([`slam_features::PpcaLine`], IPSLAM's
//! line cluster): the signed distance of the return from the line, in the scan plane.
//!
//! IPSLAM (Brunskill & Roy 2005) builds its line maps from the returns themselves; this
//! model is how a return travels to it as an ordinary observation, and what a point-to-line
//! update of a line would use.

use slam_core::nalgebra::{DMatrix, DVector, Matrix2, RowVector2, Vector2};
use slam_core::{
    CoordBlock, Coordinates, Error, Innovation, MeasurementModel, Observation, Result,
};
use slam_features::PpcaLine;

use super::check_sigmas;

/// A return at `point` (sensor frame, m) with deviation `sigma` on each axis.
///
/// `eta = n^T (v - a)`: the signed distance of the measured point `v` from the line through
/// the feature's ends `a`, `b` (sensor frame), `n` its left unit normal.
///
/// ```
/// use slam_sensors::models::LinePoint;
/// use slam_core::nalgebra::Vector2;
/// let hit = LinePoint::new(Vector2::new(2.0, 0.5), 0.02).unwrap();
/// assert_eq!(hit.point, Vector2::new(2.0, 0.5));
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct LinePoint {
    /// The return in the sensor frame, m.
    pub point: Vector2<f64>,
    /// Its deviation on each axis, m.
    pub sigma: f64,
}

impl LinePoint {
    /// A return at `point` with deviation `sigma` (finite, positive).
    pub fn new(point: Vector2<f64>, sigma: f64) -> Result<Self> {
        check_sigmas(&[sigma], "line point")?;
        slam_core::ensure_finite(point.as_slice(), "line point")?;
        Ok(LinePoint { point, sigma })
    }

    /// The return an observation carries when its measurement is a [`LinePoint`] (what
    /// IPSLAM's `LineMapTypes::scan_point` asks of a scan-point front-end).
    ///
    /// ```
    /// use std::sync::Arc;
    /// use slam_core::{Observation, Pose3, nalgebra::Vector2};
    /// use slam_sensors::models::LinePoint;
    /// let observation = Observation {
    ///     robot_from_sensor: Pose3::identity(),
    ///     measurement: Arc::new(LinePoint::new(Vector2::new(2.0, 0.5), 0.02).unwrap()),
    ///     landmark_id: None,
    /// };
    /// assert_eq!(LinePoint::point_of(&observation), Some(Vector2::new(2.0, 0.5)));
    /// ```
    pub fn point_of(observation: &Observation) -> Option<Vector2<f64>> {
        observation
            .measurement
            .as_any()
            .downcast_ref::<LinePoint>()
            .map(|p| p.point)
    }
}

impl MeasurementModel for LinePoint {
    type Feature = PpcaLine;

    fn innovation(&self, _line: &PpcaLine, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point2(a), CoordBlock::Point2(b)] = x_o.blocks() else {
            return Err(Error::InvalidArgument(
                "a line's coordinates are two 2-D points".into(),
            ));
        };
        let t = b - a;
        let length = t.norm();
        if length < 1e-9 {
            return Err(Error::Degenerate("line shorter than 1 nm".into()));
        }
        let rot90 = Matrix2::new(0.0, -1.0, 1.0, 0.0);
        let normal = rot90 * t / length;
        let d = self.point - a;
        let u = t / length;
        // d eta / d t = d^T R90 (I - u u^T) / L.
        let d_eta_d_t: RowVector2<f64> =
            d.transpose() * rot90 * (Matrix2::identity() - u * u.transpose()) / length;
        let d_eta_d_a = -normal.transpose() - d_eta_d_t;
        Ok(Innovation {
            eta: DVector::from_element(1, normal.dot(&d)),
            d_eta_d_xo: DMatrix::from_row_slice(
                1,
                4,
                &[d_eta_d_a[0], d_eta_d_a[1], d_eta_d_t[0], d_eta_d_t[1]],
            ),
            d_eta_d_v: DMatrix::from_row_slice(1, 2, &[normal.x, normal.y]),
            cov_v: DMatrix::identity(2, 2) * self.sigma * self.sigma,
        })
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_column_slice(self.point.as_slice())
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        if v.len() != 2 {
            return Err(Error::DimensionMismatch {
                what: "line point measurement".into(),
                expected: 2,
                got: v.len(),
            });
        }
        LinePoint::new(Vector2::new(v[0], v[1]), self.sigma)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::testing::{ConformanceParams, check_measurement};
    use slam_core::{Pose2, Pose3};

    #[test]
    fn conforms_and_measures_the_distance_to_the_line() {
        let line = PpcaLine::from_cluster(
            Vector2::new(3.0, 1.0),
            Vector2::new(0.6, 0.8),
            2.0,
            1e-4,
            50,
        )
        .unwrap();
        for (robot, point) in [
            (Pose2::new(0.0, 0.0, 0.0), Vector2::new(3.0, 1.5)),
            (Pose2::new(1.0, -1.0, 0.7), Vector2::new(2.0, 0.3)),
            (Pose2::new(-2.0, 2.0, -2.5), Vector2::new(-4.0, 1.0)),
        ] {
            let hit = LinePoint::new(point, 0.02).unwrap();
            check_measurement(
                &hit,
                &line,
                &robot,
                &Pose3::identity(),
                &ConformanceParams::default(),
            )
            .unwrap();
        }
        // From the origin, a point 0.5 m off the line along its normal.
        let normal = Vector2::new(-0.8, 0.6);
        let hit = LinePoint::new(Vector2::new(3.0, 1.0) + normal * 0.5, 0.02).unwrap();
        let lin =
            slam_core::linearize(&hit, &line, &Pose2::identity(), &Pose3::identity()).unwrap();
        assert!((lin.eta[0].abs() - 0.5).abs() < 1e-9, "{}", lin.eta);
        assert!(LinePoint::new(Vector2::new(f64::NAN, 0.0), 0.02).is_err());
        assert!(LinePoint::new(Vector2::zeros(), 0.0).is_err());
    }
}
