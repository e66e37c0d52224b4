//! The generic map-to-sensor transform of feature coordinates (paper eqs. 7-9, with the 2-D
//! "rotation" of appendix eq. 34) and its Jacobians `J_os` and `J_of` (eqs. 19-21).
//!
//! This is the part of the measurement chain that is the same for every feature type: it
//! depends only on the kinds of the coordinate blocks.

use nalgebra::{DMatrix, Matrix2, Matrix2x6, Matrix3, Matrix3x6, Vector2, Vector3};

use crate::coords::{CoordBlock, Coordinates};
use crate::error::{Error, Result};
use crate::pose::Pose3;

/// Smallest `|cos(pitch) cos(roll)|` for which a 2-D sensor's plane still cuts vertical lines.
const MIN_PLANE_TILT_COS: f64 = 1e-9;

/// Feature coordinates in the sensor frame, `x_o`, with the Jacobians of eq. 19.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorFrameCoordinates {
    /// `x_o = T(x_m,f | x_m,s)` (eqs. 7-9, 18).
    pub x_o: Coordinates,
    /// `J_os = d x_o / d x_m,s`, `dim(x_f) x 6`, with respect to `(x, y, z, yaw, pitch, roll)`.
    pub d_xo_d_sensor: DMatrix<f64>,
    /// `J_of = d x_o / d x_m,f`, `dim(x_f) x dim(x_f)`, block diagonal.
    pub d_xo_d_xm: DMatrix<f64>,
}

/// The transform from map (world) coordinates into one sensor's frame.
///
/// ```
/// use slam_core::{CoordBlock, Coordinates, MapToSensor, Pose3, nalgebra::{Vector2, Vector3}};
/// let world_from_sensor = Pose3::new(Vector3::new(1.0, 0.0, 0.3), std::f64::consts::FRAC_PI_2, 0.0, 0.0);
/// let to_sensor = MapToSensor::new(&world_from_sensor).unwrap();
/// let pole = Coordinates::new(vec![CoordBlock::Scalar(0.2), CoordBlock::Point2(Vector2::new(1.0, 2.0))]).unwrap();
/// let seen = to_sensor.transform(&pole).unwrap();
/// assert_eq!(seen.blocks()[0], CoordBlock::Scalar(0.2)); // eq. 9: scalars unchanged
/// if let CoordBlock::Point2(p) = seen.blocks()[1] {
///     assert!((p.x - 2.0).abs() < 1e-12 && p.y.abs() < 1e-12); // straight ahead, 2 m
/// }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct MapToSensor {
    world_from_sensor: Pose3,
    /// `R_m,s` of eq. 7: sensor-from-world rotation.
    sensor_from_world_3d: Matrix3<f64>,
    /// Derivatives of `R_m,s` with respect to yaw, pitch, roll.
    d_rotation_3d: [Matrix3<f64>; 3],
    /// `R^2D_m,s` of eq. 34 and its derivatives; `None` when the scan plane is vertical.
    plane: Option<ScanPlane>,
}

/// The 2-D "rotation" of eq. 34 and its derivatives with respect to yaw, pitch, roll.
#[derive(Clone, Debug, PartialEq)]
struct ScanPlane {
    sensor_from_world_2d: Matrix2<f64>,
    d_rotation_2d: [Matrix2<f64>; 3],
}

impl MapToSensor {
    /// Prepares the transform for a sensor at `world_from_sensor`; fails if the pose is not
    /// finite.
    ///
    /// A sensor tilted so far that its x-y plane no longer cuts vertical lines (eq. 34 divides
    /// by `cos(pitch)` and `cos(roll)`) can still see 3-D points and scalars; transforming a
    /// 2-D block with it is an error.
    pub fn new(world_from_sensor: &Pose3) -> Result<Self> {
        if !world_from_sensor.is_finite() {
            return Err(Error::NonFinite("sensor pose".into()));
        }
        if world_from_sensor.pitch == 0.0 && world_from_sensor.roll == 0.0 {
            return Ok(Self::level(world_from_sensor));
        }
        Ok(Self::tilted(world_from_sensor))
    }

    /// [`MapToSensor::new`] for a level sensor (pitch and roll zero) in closed form: the
    /// rotations about z alone, the 2-D rotation the plain inverse one (eq. 34 with level
    /// angles), whose pitch and roll derivatives vanish.
    fn level(world_from_sensor: &Pose3) -> Self {
        let (s, c) = world_from_sensor.yaw.sin_cos();
        // World-from-sensor rotation Rz(yaw) and its derivatives by yaw, pitch and roll at
        // pitch = roll = 0, transposed.
        let sensor_from_world_3d = Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
        let d_yaw = Matrix3::new(-s, c, 0.0, -c, -s, 0.0, 0.0, 0.0, 0.0);
        let d_pitch = Matrix3::new(0.0, 0.0, -1.0, 0.0, 0.0, 0.0, c, s, 0.0);
        let d_roll = Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 1.0, s, -c, 0.0);
        MapToSensor {
            world_from_sensor: *world_from_sensor,
            sensor_from_world_3d,
            d_rotation_3d: [d_yaw, d_pitch, d_roll],
            plane: Some(ScanPlane {
                sensor_from_world_2d: Matrix2::new(c, s, -s, c),
                d_rotation_2d: [
                    Matrix2::new(-s, c, -c, -s),
                    Matrix2::zeros(),
                    Matrix2::zeros(),
                ],
            }),
        }
    }

    /// [`MapToSensor::new`] for any finite sensor pose.
    fn tilted(world_from_sensor: &Pose3) -> Self {
        let world_from_sensor_rotation = world_from_sensor.rotation();
        let d_world_from_sensor = world_from_sensor.rotation_derivatives();
        let plane = world_from_sensor_rotation
            .fixed_view::<2, 2>(0, 0)
            .into_owned();
        let plane = if plane.determinant().abs() < MIN_PLANE_TILT_COS {
            None
        } else {
            plane.try_inverse().map(|sensor_from_world_2d| ScanPlane {
                sensor_from_world_2d,
                d_rotation_2d: d_world_from_sensor.map(|d| {
                    let d_plane = d.fixed_view::<2, 2>(0, 0).into_owned();
                    -(sensor_from_world_2d * d_plane * sensor_from_world_2d)
                }),
            })
        };
        MapToSensor {
            world_from_sensor: *world_from_sensor,
            sensor_from_world_3d: world_from_sensor_rotation.transpose(),
            d_rotation_3d: d_world_from_sensor.map(|d| d.transpose()),
            plane,
        }
    }

    /// The sensor pose this transform was made for.
    pub fn world_from_sensor(&self) -> &Pose3 {
        &self.world_from_sensor
    }

    /// `R_m,s` of eq. 7 (rotates world vectors into the sensor frame).
    pub fn rotation_3d(&self) -> &Matrix3<f64> {
        &self.sensor_from_world_3d
    }

    /// `R^2D_m,s` of appendix eq. 34: maps the horizontal offset of a vertical line to the point
    /// where it cuts the (possibly tilted) scan plane. The plain 2-D rotation when level.
    pub fn rotation_2d(&self) -> Result<&Matrix2<f64>> {
        Ok(&self.scan_plane()?.sensor_from_world_2d)
    }

    fn scan_plane(&self) -> Result<&ScanPlane> {
        self.plane.as_ref().ok_or_else(|| {
            Error::Degenerate(
                "2-D sensor tilted to vertical: its plane does not cut vertical lines (eq. 34)"
                    .into(),
            )
        })
    }

    /// A 2-D point of the map (a vertical line's foot) in the sensor's scan plane: the
    /// `Point2` case of [`MapToSensor::transform_block`] (appendix eq. 34).
    pub fn transform_point2(&self, world_point: &Vector2<f64>) -> Result<Vector2<f64>> {
        let t = &self.world_from_sensor.translation;
        Ok(self.scan_plane()?.sensor_from_world_2d * (world_point - Vector2::new(t.x, t.y)))
    }

    /// `J_os` and `J_of` of a 2-D point of the map ([`MapToSensor::transform_point2`]): the
    /// `Point2` rows of [`MapToSensor::transform_with_jacobians`], on the stack.
    pub fn point2_jacobians(
        &self,
        world_point: &Vector2<f64>,
    ) -> Result<(Matrix2x6<f64>, Matrix2<f64>)> {
        let plane = self.scan_plane()?;
        let t = &self.world_from_sensor.translation;
        let offset = world_point - Vector2::new(t.x, t.y);
        let r = &plane.sensor_from_world_2d;
        let mut d_xo_d_sensor = Matrix2x6::zeros();
        d_xo_d_sensor.fixed_view_mut::<2, 2>(0, 0).copy_from(&(-r));
        for k in 0..3 {
            d_xo_d_sensor
                .fixed_view_mut::<2, 1>(0, 3 + k)
                .copy_from(&(plane.d_rotation_2d[k] * offset));
        }
        Ok((d_xo_d_sensor, *r))
    }

    /// `J_os` and `J_of` of a 3-D point of the map (eq. 7): the `Point3` rows of
    /// [`MapToSensor::transform_with_jacobians`], on the stack.
    pub fn point3_jacobians(&self, world_point: &Vector3<f64>) -> (Matrix3x6<f64>, Matrix3<f64>) {
        let offset = world_point - self.world_from_sensor.translation;
        let r = &self.sensor_from_world_3d;
        let mut d_xo_d_sensor = Matrix3x6::zeros();
        d_xo_d_sensor.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r));
        for k in 0..3 {
            d_xo_d_sensor
                .fixed_view_mut::<3, 1>(0, 3 + k)
                .copy_from(&(self.d_rotation_3d[k] * offset));
        }
        (d_xo_d_sensor, *r)
    }

    /// A 3-D point of the map in the sensor frame (eq. 7): the `Point3` case of
    /// [`MapToSensor::transform_block`].
    pub fn transform_point3(&self, world_point: &Vector3<f64>) -> Vector3<f64> {
        self.sensor_from_world_3d * (world_point - self.world_from_sensor.translation)
    }

    /// One block in the sensor frame (eq. 7, 8 or 9 by kind).
    pub fn transform_block(&self, block: &CoordBlock) -> Result<CoordBlock> {
        Ok(match block {
            CoordBlock::Point3(p) => CoordBlock::Point3(self.transform_point3(p)),
            CoordBlock::Point2(p) => CoordBlock::Point2(self.transform_point2(p)?),
            CoordBlock::Scalar(s) => CoordBlock::Scalar(*s),
        })
    }

    /// `x_o`: all blocks in the sensor frame (eqs. 7-9).
    pub fn transform(&self, x_m: &Coordinates) -> Result<Coordinates> {
        let blocks = x_m
            .blocks()
            .iter()
            .map(|b| self.transform_block(b))
            .collect::<Result<smallvec::SmallVec<[CoordBlock; crate::INLINE_BLOCKS]>>>()?;
        Coordinates::from_blocks(blocks)
    }

    /// `x_o` with `J_of` alone (eq. 19): what a filter over the feature alone needs.
    pub fn transform_with_feature_jacobian(
        &self,
        x_m: &Coordinates,
    ) -> Result<(Coordinates, DMatrix<f64>)> {
        let dim = x_m.dim();
        let mut d_xo_d_xm = DMatrix::zeros(dim, dim);
        let mut row = 0;
        for block in x_m.blocks() {
            match block {
                CoordBlock::Point3(_) => d_xo_d_xm
                    .view_mut((row, row), (3, 3))
                    .copy_from(&self.sensor_from_world_3d),
                CoordBlock::Point2(_) => d_xo_d_xm
                    .view_mut((row, row), (2, 2))
                    .copy_from(&self.scan_plane()?.sensor_from_world_2d),
                CoordBlock::Scalar(_) => d_xo_d_xm[(row, row)] = 1.0,
            }
            row += block.dim();
        }
        Ok((self.transform(x_m)?, d_xo_d_xm))
    }

    /// `x_o` with `J_os` and `J_of` (eq. 19).
    pub fn transform_with_jacobians(&self, x_m: &Coordinates) -> Result<SensorFrameCoordinates> {
        let dim = x_m.dim();
        let mut d_xo_d_sensor = DMatrix::zeros(dim, 6);
        let mut d_xo_d_xm = DMatrix::zeros(dim, dim);
        let mut row = 0;
        for block in x_m.blocks() {
            match block {
                CoordBlock::Point3(p) => {
                    let (d_sensor, d_xm) = self.point3_jacobians(p);
                    d_xo_d_sensor
                        .view_mut((row, 0), (3, 6))
                        .copy_from(&d_sensor);
                    d_xo_d_xm.view_mut((row, row), (3, 3)).copy_from(&d_xm);
                }
                CoordBlock::Point2(p) => {
                    let (d_sensor, d_xm) = self.point2_jacobians(p)?;
                    d_xo_d_sensor
                        .view_mut((row, 0), (2, 6))
                        .copy_from(&d_sensor);
                    d_xo_d_xm.view_mut((row, row), (2, 2)).copy_from(&d_xm);
                }
                CoordBlock::Scalar(_) => {
                    d_xo_d_xm[(row, row)] = 1.0;
                }
            }
            row += block.dim();
        }
        Ok(SensorFrameCoordinates {
            x_o: self.transform(x_m)?,
            d_xo_d_sensor,
            d_xo_d_xm,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::numeric_jacobian;
    use approx::assert_relative_eq;
    use nalgebra::{DVector, Vector3, Vector6};
    use proptest::prelude::*;

    /// The closed form printed in the paper's appendix, eq. 34.
    fn paper_eq34(theta: f64, phi: f64, psi: f64) -> Matrix2<f64> {
        Matrix2::new(
            (theta.cos() + theta.sin() * phi.sin() * psi.tan()) / phi.cos(),
            (theta.sin() - theta.cos() * phi.sin() * psi.tan()) / phi.cos(),
            -theta.sin() / psi.cos(),
            theta.cos() / psi.cos(),
        )
    }

    #[test]
    fn level_sensor_gives_plain_rotation() {
        let pose = Pose3::new(Vector3::new(1.0, 2.0, 0.4), 0.8, 0.0, 0.0);
        let t = MapToSensor::new(&pose).unwrap();
        let expected = Matrix2::new(0.8f64.cos(), 0.8f64.sin(), -(0.8f64.sin()), 0.8f64.cos());
        assert_relative_eq!(*t.rotation_2d().unwrap(), expected, epsilon = 1e-14);
    }

    #[test]
    fn vertical_scan_plane_is_an_error_for_2d_blocks_only() {
        let pose = Pose3::new(Vector3::zeros(), 0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let t = MapToSensor::new(&pose).unwrap();
        let vertical_line = CoordBlock::Point2(Vector2::new(1.0, 0.0));
        assert!(matches!(
            t.transform_block(&vertical_line),
            Err(Error::Degenerate(_))
        ));
        assert!(
            t.transform_block(&CoordBlock::Point3(Vector3::new(1.0, 0.0, 0.0)))
                .is_ok()
        );
        let nan = Pose3::new(Vector3::new(f64::NAN, 0.0, 0.0), 0.0, 0.0, 0.0);
        assert!(matches!(MapToSensor::new(&nan), Err(Error::NonFinite(_))));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// The closed form for a level sensor agrees with the general construction.
        #[test]
        fn level_sensor_matches_general_construction(
            x in -10.0..10.0f64, y in -10.0..10.0f64, z in -2.0..2.0f64, yaw in -3.2..3.2f64,
        ) {
            let pose = Pose3::new(Vector3::new(x, y, z), yaw, 0.0, 0.0);
            let level = MapToSensor::level(&pose);
            let general = MapToSensor::tilted(&pose);
            prop_assert_eq!(MapToSensor::new(&pose).unwrap(), level.clone());
            prop_assert!((level.sensor_from_world_3d - general.sensor_from_world_3d).amax() < 1e-12);
            for k in 0..3 {
                prop_assert!((level.d_rotation_3d[k] - general.d_rotation_3d[k]).amax() < 1e-12);
            }
            let (Some(a), Some(b)) = (&level.plane, &general.plane) else {
                unreachable!("a level sensor's plane cuts vertical lines")
            };
            prop_assert!((a.sensor_from_world_2d - b.sensor_from_world_2d).amax() < 1e-12);
            for k in 0..3 {
                prop_assert!((a.d_rotation_2d[k] - b.d_rotation_2d[k]).amax() < 1e-12);
            }
        }

        #[test]
        fn tilted_rotation_matches_paper_eq34(yaw in -3.1..3.1f64, pitch in -1.2..1.2f64, roll in -1.2..1.2f64) {
            let pose = Pose3::new(Vector3::zeros(), yaw, pitch, roll);
            let t = MapToSensor::new(&pose).unwrap();
            prop_assert!((t.rotation_2d().unwrap() - paper_eq34(yaw, pitch, roll)).amax() < 1e-9);
        }

        /// A vertical line at (x, y) cuts the tilted scan plane at R2 (x - t): check that the
        /// 3-D point of the plane at those sensor coordinates lies on the line.
        #[test]
        fn tilted_2d_point_lies_on_the_vertical_line(
            yaw in -3.1..3.1f64, pitch in -1.0..1.0f64, roll in -1.0..1.0f64,
            x in -10.0..10.0f64, y in -10.0..10.0f64,
        ) {
            let pose = Pose3::new(Vector3::new(0.5, -1.0, 0.7), yaw, pitch, roll);
            let t = MapToSensor::new(&pose).unwrap();
            let Ok(CoordBlock::Point2(uv)) = t.transform_block(&CoordBlock::Point2(Vector2::new(x, y))) else {
                unreachable!()
            };
            let in_world = pose.transform_point(&Vector3::new(uv.x, uv.y, 0.0));
            prop_assert!((in_world.x - x).abs() < 1e-8 && (in_world.y - y).abs() < 1e-8);
        }

        #[test]
        fn jacobians_match_central_differences(
            yaw in -3.1..3.1f64, pitch in -1.0..1.0f64, roll in -1.0..1.0f64,
            sx in -5.0..5.0f64, sy in -5.0..5.0f64, sz in -2.0..2.0f64,
            px in -20.0..20.0f64, py in -20.0..20.0f64, pz in -3.0..3.0f64, radius in 0.01..2.0f64,
        ) {
            let pose = Pose3::new(Vector3::new(sx, sy, sz), yaw, pitch, roll);
            let x_m = Coordinates::new(vec![
                CoordBlock::Point3(Vector3::new(px, py, pz)),
                CoordBlock::Scalar(radius),
                CoordBlock::Point2(Vector2::new(py, px)),
            ]).unwrap();
            let t = MapToSensor::new(&pose).unwrap();
            let result = t.transform_with_jacobians(&x_m).unwrap();
            let num_f = numeric_jacobian(&x_m.to_vector(), 1e-6, |v| {
                t.transform(&x_m.with_vector(v).unwrap()).unwrap().to_vector()
            });
            let v0 = DVector::from_column_slice(pose.to_vector().as_slice());
            let num_s = numeric_jacobian(&v0, 1e-6, |v| {
                let p = Pose3::from_vector(&Vector6::from_column_slice(v.as_slice()));
                MapToSensor::new(&p).unwrap().transform(&x_m).unwrap().to_vector()
            });
            prop_assert!((result.d_xo_d_xm - num_f).amax() < 1e-5);
            prop_assert!((result.d_xo_d_sensor - num_s).amax() < 1e-4);
        }
    }
}
