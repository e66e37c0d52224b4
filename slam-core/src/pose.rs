//! SE(2) and SE(3) poses with the compound operators of Smith, Self and Cheeseman
//! (the paper's ref. [11]: `⊕` compose, `⊖` inverse, and the relative pose `⊖a ⊕ b`),
//! each with its Jacobians.
//!
//! Names are frame-explicit: a `world_from_robot` pose maps robot coordinates into the
//! world, so `world_from_robot.compose(&robot_from_sensor)` is `world_from_sensor`
//! (paper eq. 17).

use std::f64::consts::{PI, TAU};
use std::fmt::Debug;

use nalgebra::{DMatrix, Matrix2, Matrix2x3, Matrix3, Matrix6, Vector2, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Wraps an angle to `(-pi, pi]`; NaN stays NaN.
///
/// ```
/// use slam_core::wrap_angle;
/// assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
/// assert!((wrap_angle(-0.5) + 0.5).abs() < 1e-15);
/// ```
pub fn wrap_angle(angle: f64) -> f64 {
    // `%` returns an angle smaller than a turn as it is, exactly; skipping it skips a
    // software `fmod` on the hot paths (every bearing innovation).
    let mut wrapped = if angle.abs() < TAU {
        angle
    } else {
        angle % TAU
    };
    if wrapped > PI {
        wrapped -= TAU;
    } else if wrapped <= -PI {
        wrapped += TAU;
    }
    wrapped
}

/// A planar pose `(x, y, theta)`: the pose of a frame in its parent frame.
///
/// ```
/// use slam_core::Pose2;
/// let world_from_robot = Pose2::new(1.0, 2.0, std::f64::consts::FRAC_PI_2);
/// let robot_from_sensor = Pose2::new(0.5, 0.0, 0.0);
/// let world_from_sensor = world_from_robot.compose(&robot_from_sensor);
/// assert!((world_from_sensor.x - 1.0).abs() < 1e-12);
/// assert!((world_from_sensor.y - 2.5).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose2 {
    /// x of the frame origin in the parent frame.
    pub x: f64,
    /// y of the frame origin in the parent frame.
    pub y: f64,
    /// Heading in radians, kept in `(-pi, pi]`.
    pub theta: f64,
}

impl Default for Pose2 {
    fn default() -> Self {
        Pose2::identity()
    }
}

impl Pose2 {
    /// A pose with its heading wrapped to `(-pi, pi]`.
    pub fn new(x: f64, y: f64, theta: f64) -> Self {
        Pose2 {
            x,
            y,
            theta: wrap_angle(theta),
        }
    }

    /// The identity pose.
    pub const fn identity() -> Self {
        Pose2 {
            x: 0.0,
            y: 0.0,
            theta: 0.0,
        }
    }

    /// `(x, y, theta)` as a vector.
    pub fn to_vector(&self) -> Vector3<f64> {
        Vector3::new(self.x, self.y, self.theta)
    }

    /// The pose `(v[0], v[1], v[2])`, heading wrapped.
    pub fn from_vector(v: &Vector3<f64>) -> Self {
        Pose2::new(v[0], v[1], v[2])
    }

    /// True when x, y and theta are finite.
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }

    /// The translation `(x, y)`.
    pub fn translation(&self) -> Vector2<f64> {
        Vector2::new(self.x, self.y)
    }

    /// The rotation matrix `R(theta)` (child to parent).
    pub fn rotation(&self) -> Matrix2<f64> {
        let (s, c) = self.theta.sin_cos();
        Matrix2::new(c, -s, s, c)
    }

    /// Additive perturbation `(x + dx, y + dy, theta + dtheta)`, the state update an EKF applies.
    pub fn plus_vector(&self, delta: &Vector3<f64>) -> Self {
        Pose2::new(self.x + delta[0], self.y + delta[1], self.theta + delta[2])
    }

    /// The compound `self ⊕ other`.
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let p = self.rotation() * other.translation() + self.translation();
        Pose2::new(p[0], p[1], self.theta + other.theta)
    }

    /// `self ⊕ other` with the Jacobians with respect to `self` and to `other`.
    pub fn compose_with_jacobians(&self, other: &Pose2) -> (Pose2, Matrix3<f64>, Matrix3<f64>) {
        let composed = self.compose(other);
        let (s, c) = self.theta.sin_cos();
        let d_self = Matrix3::new(
            1.0,
            0.0,
            -(composed.y - self.y),
            0.0,
            1.0,
            composed.x - self.x,
            0.0,
            0.0,
            1.0,
        );
        let d_other = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        (composed, d_self, d_other)
    }

    /// The inverse `⊖self`.
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2::new(
            -c * self.x - s * self.y,
            s * self.x - c * self.y,
            -self.theta,
        )
    }

    /// `⊖self` with its Jacobian.
    pub fn inverse_with_jacobian(&self) -> (Pose2, Matrix3<f64>) {
        let (s, c) = self.theta.sin_cos();
        let jacobian = Matrix3::new(
            -c,
            -s,
            s * self.x - c * self.y,
            s,
            -c,
            c * self.x + s * self.y,
            0.0,
            0.0,
            -1.0,
        );
        (self.inverse(), jacobian)
    }

    /// The relative pose `⊖self ⊕ other`: given `world_from_a` and `world_from_b`, `a_from_b`.
    pub fn between(&self, other: &Pose2) -> Pose2 {
        self.inverse().compose(other)
    }

    /// `⊖self ⊕ other` with the Jacobians with respect to `self` and `other`.
    pub fn between_with_jacobians(&self, other: &Pose2) -> (Pose2, Matrix3<f64>, Matrix3<f64>) {
        let (inverse, d_inverse) = self.inverse_with_jacobian();
        let (relative, d_first, d_second) = inverse.compose_with_jacobians(other);
        (relative, d_first * d_inverse, d_second)
    }

    /// A point of this frame expressed in the parent frame: `R p + t`.
    pub fn transform_point(&self, p: &Vector2<f64>) -> Vector2<f64> {
        self.rotation() * p + self.translation()
    }

    /// `R p + t` with the Jacobians with respect to the pose (2x3) and to the point (2x2).
    pub fn transform_point_with_jacobians(
        &self,
        p: &Vector2<f64>,
    ) -> (Vector2<f64>, Matrix2x3<f64>, Matrix2<f64>) {
        let rotation = self.rotation();
        let rotated = rotation * p;
        let d_pose = Matrix2x3::new(1.0, 0.0, -rotated[1], 0.0, 1.0, rotated[0]);
        (rotated + self.translation(), d_pose, rotation)
    }

    /// A parent-frame point expressed in this frame: `R^T (p - t)`.
    pub fn inverse_transform_point(&self, p: &Vector2<f64>) -> Vector2<f64> {
        self.rotation().transpose() * (p - self.translation())
    }

    /// This planar pose as a 3-D pose at height `z` with zero pitch and roll.
    pub fn to_pose3(&self, z: f64) -> Pose3 {
        Pose3::new(Vector3::new(self.x, self.y, z), self.theta, 0.0, 0.0)
    }

    /// `world_from_sensor` for a level mount (pitch and roll zero): a planar composition,
    /// with `sin_cos` of the heading and the sensor's offset rotated into the world.
    fn level_sensor(&self, robot_from_sensor: &Pose3) -> (Pose3, (f64, f64), Vector2<f64>) {
        let (s, c) = self.theta.sin_cos();
        let t = &robot_from_sensor.translation;
        let offset = Vector2::new(c * t.x - s * t.y, s * t.x + c * t.y);
        let world_from_sensor = Pose3 {
            translation: Vector3::new(self.x + offset.x, self.y + offset.y, t.z),
            yaw: wrap_angle(self.theta + robot_from_sensor.yaw),
            pitch: 0.0,
            roll: 0.0,
        };
        (world_from_sensor, (s, c), offset)
    }

    /// [`RobotPose::sensor_pose`] for a level mount in closed form: `J_sr` moves the sensor
    /// with the robot and turns its offset with the heading; `J_ss` rotates the offset's
    /// translation into the world and passes its angles through (ZYX angles of a level
    /// composition add).
    fn level_sensor_pose(&self, robot_from_sensor: &Pose3) -> SensorPose {
        let (world_from_sensor, (s, c), offset) = self.level_sensor(robot_from_sensor);
        let mut d_sensor_d_robot = DMatrix::zeros(6, 3);
        d_sensor_d_robot[(0, 0)] = 1.0;
        d_sensor_d_robot[(1, 1)] = 1.0;
        d_sensor_d_robot[(0, 2)] = -offset.y;
        d_sensor_d_robot[(1, 2)] = offset.x;
        d_sensor_d_robot[(3, 2)] = 1.0;
        let mut d_sensor_d_offset = Matrix6::identity();
        d_sensor_d_offset[(0, 0)] = c;
        d_sensor_d_offset[(0, 1)] = -s;
        d_sensor_d_offset[(1, 0)] = s;
        d_sensor_d_offset[(1, 1)] = c;
        SensorPose {
            world_from_sensor,
            d_sensor_d_robot,
            d_sensor_d_offset,
        }
    }

    /// [`RobotPose::sensor_pose`] through the general 3-D composition (any mount).
    fn sensor_pose_3d(&self, robot_from_sensor: &Pose3) -> Result<SensorPose> {
        let (world_from_sensor, d_composed_d_robot3, d_sensor_d_offset) = self
            .to_pose3(0.0)
            .compose_with_jacobians(robot_from_sensor)?;
        // d(pose3 parameters)/d(x, y, theta) of the planar embedding.
        let mut embedding = nalgebra::Matrix6x3::zeros();
        embedding[(0, 0)] = 1.0;
        embedding[(1, 1)] = 1.0;
        embedding[(3, 2)] = 1.0;
        let d_sensor_d_robot = d_composed_d_robot3 * embedding;
        Ok(SensorPose {
            world_from_sensor,
            d_sensor_d_robot: DMatrix::from_column_slice(6, 3, d_sensor_d_robot.as_slice()),
            d_sensor_d_offset,
        })
    }
}

/// Whether a mount is level: its pitch and roll are exactly zero (the planar paths apply).
fn is_level(robot_from_sensor: &Pose3) -> bool {
    robot_from_sensor.pitch == 0.0 && robot_from_sensor.roll == 0.0
}

/// A 3-D pose: translation and ZYX Euler angles (yaw about z, then pitch about y, then roll
/// about x), so that the rotation is `Rz(yaw) Ry(pitch) Rx(roll)`.
///
/// These are the angles (theta, phi, psi) of the paper's appendix eq. 34. Jacobians are
/// taken with respect to the parameter vector `(x, y, z, yaw, pitch, roll)`; they are
/// singular at pitch = ±90° (gimbal lock), where the Jacobian functions return an error.
///
/// ```
/// use slam_core::{Pose3, nalgebra::Vector3};
/// let world_from_camera = Pose3::new(Vector3::new(1.0, 0.0, 0.5), 0.0, -std::f64::consts::FRAC_PI_2, 0.0);
/// let up = world_from_camera.rotation() * Vector3::new(1.0, 0.0, 0.0);
/// assert!((up.z - 1.0).abs() < 1e-12); // the camera's x axis points up
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose3 {
    /// Origin of the frame in the parent frame.
    pub translation: Vector3<f64>,
    /// Rotation about z, radians.
    pub yaw: f64,
    /// Rotation about the once-rotated y axis, radians.
    pub pitch: f64,
    /// Rotation about the twice-rotated x axis, radians.
    pub roll: f64,
}

impl Default for Pose3 {
    fn default() -> Self {
        Pose3::identity()
    }
}

/// Smallest `cos(pitch)^2` for which Euler-angle Jacobians are computed.
const GIMBAL_LOCK_COS2: f64 = 1e-12;

impl Pose3 {
    /// A pose from translation and ZYX Euler angles (each wrapped to `(-pi, pi]`).
    pub fn new(translation: Vector3<f64>, yaw: f64, pitch: f64, roll: f64) -> Self {
        Pose3 {
            translation,
            yaw: wrap_angle(yaw),
            pitch: wrap_angle(pitch),
            roll: wrap_angle(roll),
        }
    }

    /// The identity pose.
    pub fn identity() -> Self {
        Pose3::new(Vector3::zeros(), 0.0, 0.0, 0.0)
    }

    /// The parameter vector `(x, y, z, yaw, pitch, roll)`.
    pub fn to_vector(&self) -> Vector6<f64> {
        Vector6::new(
            self.translation.x,
            self.translation.y,
            self.translation.z,
            self.yaw,
            self.pitch,
            self.roll,
        )
    }

    /// The pose with parameter vector `v`.
    pub fn from_vector(v: &Vector6<f64>) -> Self {
        Pose3::new(Vector3::new(v[0], v[1], v[2]), v[3], v[4], v[5])
    }

    /// True when all six parameters are finite.
    pub fn is_finite(&self) -> bool {
        self.to_vector().iter().all(|v| v.is_finite())
    }

    /// The rotation matrix `Rz(yaw) Ry(pitch) Rx(roll)` (child to parent).
    pub fn rotation(&self) -> Matrix3<f64> {
        euler_rotation(self.yaw, self.pitch, self.roll)
    }

    /// Derivatives of the rotation matrix with respect to yaw, pitch and roll.
    pub fn rotation_derivatives(&self) -> [Matrix3<f64>; 3] {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        let (sr, cr) = self.roll.sin_cos();
        let rz = Matrix3::new(cy, -sy, 0.0, sy, cy, 0.0, 0.0, 0.0, 1.0);
        let ry = Matrix3::new(cp, 0.0, sp, 0.0, 1.0, 0.0, -sp, 0.0, cp);
        let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, cr, -sr, 0.0, sr, cr);
        let drz = Matrix3::new(-sy, -cy, 0.0, cy, -sy, 0.0, 0.0, 0.0, 0.0);
        let dry = Matrix3::new(-sp, 0.0, cp, 0.0, 0.0, 0.0, -cp, 0.0, -sp);
        let drx = Matrix3::new(0.0, 0.0, 0.0, 0.0, -sr, -cr, 0.0, cr, -sr);
        [drz * ry * rx, rz * dry * rx, rz * ry * drx]
    }

    /// The pose with translation `t` and rotation matrix `rotation` (Euler angles extracted).
    pub fn from_rotation(translation: Vector3<f64>, rotation: &Matrix3<f64>) -> Self {
        let (yaw, pitch, roll) = euler_from_rotation(rotation);
        Pose3::new(translation, yaw, pitch, roll)
    }

    /// The compound `self ⊕ other`.
    pub fn compose(&self, other: &Pose3) -> Pose3 {
        let rotation = self.rotation();
        Pose3::from_rotation(
            self.translation + rotation * other.translation,
            &(rotation * other.rotation()),
        )
    }

    /// `self ⊕ other` with the 6x6 Jacobians with respect to `self` and `other`.
    pub fn compose_with_jacobians(
        &self,
        other: &Pose3,
    ) -> Result<(Pose3, Matrix6<f64>, Matrix6<f64>)> {
        let r1 = self.rotation();
        let r2 = other.rotation();
        let rotation = r1 * r2;
        let composed = Pose3::from_rotation(self.translation + r1 * other.translation, &rotation);
        let dr1 = self.rotation_derivatives();
        let dr2 = other.rotation_derivatives();
        let mut d_self = Matrix6::zeros();
        let mut d_other = Matrix6::zeros();
        d_self
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        d_other.fixed_view_mut::<3, 3>(0, 0).copy_from(&r1);
        for k in 0..3 {
            d_self
                .fixed_view_mut::<3, 1>(0, 3 + k)
                .copy_from(&(dr1[k] * other.translation));
            d_self
                .fixed_view_mut::<3, 1>(3, 3 + k)
                .copy_from(&euler_differential(&rotation, &(dr1[k] * r2))?);
            d_other
                .fixed_view_mut::<3, 1>(3, 3 + k)
                .copy_from(&euler_differential(&rotation, &(r1 * dr2[k]))?);
        }
        Ok((composed, d_self, d_other))
    }

    /// The inverse `⊖self`.
    pub fn inverse(&self) -> Pose3 {
        let rotation_t = self.rotation().transpose();
        Pose3::from_rotation(-(rotation_t * self.translation), &rotation_t)
    }

    /// `⊖self` with its 6x6 Jacobian.
    pub fn inverse_with_jacobian(&self) -> Result<(Pose3, Matrix6<f64>)> {
        let rotation_t = self.rotation().transpose();
        let inverse = Pose3::from_rotation(-(rotation_t * self.translation), &rotation_t);
        let dr = self.rotation_derivatives();
        let mut jacobian = Matrix6::zeros();
        jacobian
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-rotation_t));
        for (k, dr_k) in dr.iter().enumerate() {
            let dr_t = dr_k.transpose();
            jacobian
                .fixed_view_mut::<3, 1>(0, 3 + k)
                .copy_from(&(-(dr_t * self.translation)));
            jacobian
                .fixed_view_mut::<3, 1>(3, 3 + k)
                .copy_from(&euler_differential(&rotation_t, &dr_t)?);
        }
        Ok((inverse, jacobian))
    }

    /// The relative pose `⊖self ⊕ other`.
    pub fn between(&self, other: &Pose3) -> Pose3 {
        self.inverse().compose(other)
    }

    /// `⊖self ⊕ other` with the Jacobians with respect to `self` and `other`.
    pub fn between_with_jacobians(
        &self,
        other: &Pose3,
    ) -> Result<(Pose3, Matrix6<f64>, Matrix6<f64>)> {
        let (inverse, d_inverse) = self.inverse_with_jacobian()?;
        let (relative, d_first, d_second) = inverse.compose_with_jacobians(other)?;
        Ok((relative, d_first * d_inverse, d_second))
    }

    /// A point of this frame expressed in the parent frame: `R p + t`.
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation() * p + self.translation
    }

    /// A parent-frame point expressed in this frame: `R^T (p - t)` (paper eq. 7).
    pub fn inverse_transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation().transpose() * (p - self.translation)
    }
}

/// `Rz(yaw) Ry(pitch) Rx(roll)`.
fn euler_rotation(yaw: f64, pitch: f64, roll: f64) -> Matrix3<f64> {
    let (sy, cy) = yaw.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sr, cr) = roll.sin_cos();
    Matrix3::new(
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
        -sp,
        cp * sr,
        cp * cr,
    )
}

/// ZYX Euler angles `(yaw, pitch, roll)` of a rotation matrix.
fn euler_from_rotation(r: &Matrix3<f64>) -> (f64, f64, f64) {
    let pitch = (-r[(2, 0)]).clamp(-1.0, 1.0).asin();
    let yaw = r[(1, 0)].atan2(r[(0, 0)]);
    let roll = r[(2, 1)].atan2(r[(2, 2)]);
    (yaw, pitch, roll)
}

/// The change of `(yaw, pitch, roll)` of `rotation` when it changes by `d_rotation`.
fn euler_differential(rotation: &Matrix3<f64>, d_rotation: &Matrix3<f64>) -> Result<Vector3<f64>> {
    let r = rotation;
    let dr = d_rotation;
    let cos2_pitch = 1.0 - r[(2, 0)] * r[(2, 0)];
    if cos2_pitch < GIMBAL_LOCK_COS2 {
        return Err(Error::Degenerate(
            "Euler-angle Jacobian at pitch = ±90 degrees (gimbal lock)".into(),
        ));
    }
    let yaw_den = r[(0, 0)] * r[(0, 0)] + r[(1, 0)] * r[(1, 0)];
    let roll_den = r[(2, 1)] * r[(2, 1)] + r[(2, 2)] * r[(2, 2)];
    Ok(Vector3::new(
        (r[(0, 0)] * dr[(1, 0)] - r[(1, 0)] * dr[(0, 0)]) / yaw_den,
        -dr[(2, 0)] / cos2_pitch.sqrt(),
        (r[(2, 2)] * dr[(2, 1)] - r[(2, 1)] * dr[(2, 2)]) / roll_den,
    ))
}

/// The sensor's pose in the world and its Jacobians (paper eq. 17 and eq. 20).
#[derive(Clone, Debug, PartialEq)]
pub struct SensorPose {
    /// `x_m,s = x_m,r ⊕ x_r,s` (eq. 17).
    pub world_from_sensor: Pose3,
    /// `J_sr = d x_m,s / d x_m,r` (6 x robot dim).
    pub d_sensor_d_robot: DMatrix<f64>,
    /// `J_ss = d x_m,s / d x_r,s` (6 x 6).
    pub d_sensor_d_offset: Matrix6<f64>,
}

/// A robot pose an estimator can hold: planar ([`Pose2`]) or full 3-D ([`Pose3`]).
///
/// It says how a sensor mounted on the robot sits in the world (eq. 17) and gives `J_sr` and
/// `J_ss` (eq. 20), so that the chain of eq. 21 is written once for both.
pub trait RobotPose: Copy + Debug + PartialEq + Send + Sync + 'static {
    /// Number of pose parameters the estimator carries (3 for [`Pose2`], 6 for [`Pose3`]).
    const DIM: usize;

    /// `world_from_sensor = self ⊕ robot_from_sensor` (eq. 17).
    fn world_from_sensor(&self, robot_from_sensor: &Pose3) -> Pose3;

    /// `world_from_sensor = self ⊕ robot_from_sensor` with `J_sr` and `J_ss`.
    fn sensor_pose(&self, robot_from_sensor: &Pose3) -> Result<SensorPose>;

    /// The pose parameters as a vector of length [`Self::DIM`].
    fn parameters(&self) -> Vec<f64>;

    /// The pose with the given parameters (the inverse of [`RobotPose::parameters`]).
    fn from_parameters(parameters: &[f64]) -> Result<Self>;

    /// How the parameters change under a small motion of the whole world in the plane:
    /// translation along x, along y, and rotation about the z axis through the origin (the
    /// directions that no measurement of a map can observe).
    fn planar_motion_generators(&self) -> [Vec<f64>; 3];

    /// Index of the heading (yaw) among the [`parameters`](RobotPose::parameters).
    const HEADING: usize;

    /// `self ⊞ delta`: the pose moved by a small change `delta` of its parameters (length
    /// [`Self::DIM`]), angles wrapped; the update an estimator applies to its pose
    /// (`x_r += dx_r`, eq. 24 for the robot rows).
    ///
    /// ```
    /// use slam_core::{Pose2, RobotPose};
    /// let moved = Pose2::new(1.0, 2.0, 3.0).oplus(&[0.5, 0.0, 0.3]).unwrap();
    /// assert!((moved.theta - (3.3 - std::f64::consts::TAU)).abs() < 1e-12);
    /// ```
    fn oplus(&self, delta: &[f64]) -> Result<Self> {
        if delta.len() != Self::DIM {
            return Err(Error::DimensionMismatch {
                what: "pose perturbation".into(),
                expected: Self::DIM,
                got: delta.len(),
            });
        }
        let mut parameters = self.parameters();
        for (p, d) in parameters.iter_mut().zip(delta) {
            *p += d;
        }
        Self::from_parameters(&parameters)
    }

    /// `self ⊟ other`: the parameter difference with angle differences wrapped to
    /// `(-pi, pi]`, so that `other.oplus(&self.ominus(other))` is `self` (the error of an
    /// estimate `other` against the truth `self`, as NEES and weighted means use it).
    ///
    /// ```
    /// use slam_core::{Pose2, RobotPose};
    /// let (a, b) = (Pose2::new(0.0, 0.0, 3.1), Pose2::new(1.0, 0.0, -3.1));
    /// let d = a.ominus(&b);
    /// assert!((d[0] + 1.0).abs() < 1e-12 && (d[2] - (6.2 - std::f64::consts::TAU)).abs() < 1e-12);
    /// ```
    fn ominus(&self, other: &Self) -> Vec<f64> {
        let angles_from = Self::HEADING;
        self.parameters()
            .iter()
            .zip(other.parameters())
            .enumerate()
            .map(|(k, (a, b))| {
                if k >= angles_from {
                    wrap_angle(a - b)
                } else {
                    a - b
                }
            })
            .collect()
    }

    /// [`RobotPose::ominus`] appended to `out` (a particle filter's mean over its particles
    /// takes every difference into one buffer, with no vector per particle).
    ///
    /// ```
    /// use slam_core::{Pose2, RobotPose};
    /// let (a, b) = (Pose2::new(0.0, 0.0, 3.1), Pose2::new(1.0, 0.0, -3.1));
    /// let mut out = vec![7.0];
    /// a.ominus_into(&b, &mut out);
    /// assert_eq!(out[1..], a.ominus(&b)[..]);
    /// ```
    fn ominus_into(&self, other: &Self, out: &mut Vec<f64>) {
        out.extend(self.ominus(other));
    }

    /// How far apart two poses are: the distance between their positions and the largest
    /// wrapped difference of their angles (how much the robot moved or turned between them).
    ///
    /// ```
    /// use slam_core::{Pose2, RobotPose};
    /// let (d, a) = Pose2::new(3.0, 4.0, 0.5).distance_and_angle(&Pose2::identity());
    /// assert_eq!((d, a), (5.0, 0.5));
    /// ```
    fn distance_and_angle(&self, other: &Self) -> (f64, f64) {
        let d = self.ominus(other);
        let (position, angles) = d.split_at(Self::HEADING);
        let distance = position.iter().map(|v| v * v).sum::<f64>().sqrt();
        let angle = angles.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        (distance, angle)
    }
}

impl RobotPose for Pose2 {
    const DIM: usize = 3;
    const HEADING: usize = 2;

    /// A level mount (pitch and roll zero) takes the planar path (one `sin_cos`); any other
    /// the general 3-D composition.
    fn world_from_sensor(&self, robot_from_sensor: &Pose3) -> Pose3 {
        if is_level(robot_from_sensor) {
            self.level_sensor(robot_from_sensor).0
        } else {
            self.to_pose3(0.0).compose(robot_from_sensor)
        }
    }

    /// A level mount takes the planar path (closed-form Jacobians), any other the general
    /// 3-D one; the two agree to round-off (tested).
    fn sensor_pose(&self, robot_from_sensor: &Pose3) -> Result<SensorPose> {
        if is_level(robot_from_sensor) {
            Ok(self.level_sensor_pose(robot_from_sensor))
        } else {
            self.sensor_pose_3d(robot_from_sensor)
        }
    }

    fn parameters(&self) -> Vec<f64> {
        vec![self.x, self.y, self.theta]
    }

    /// The default's arithmetic without its parameter vectors.
    fn ominus(&self, other: &Self) -> Vec<f64> {
        vec![
            self.x - other.x,
            self.y - other.y,
            wrap_angle(self.theta - other.theta),
        ]
    }

    /// [`RobotPose::ominus`]'s numbers, pushed without a vector of their own.
    fn ominus_into(&self, other: &Self, out: &mut Vec<f64>) {
        out.extend_from_slice(&[
            self.x - other.x,
            self.y - other.y,
            wrap_angle(self.theta - other.theta),
        ]);
    }

    /// The default's arithmetic without its parameter vectors.
    fn oplus(&self, delta: &[f64]) -> Result<Self> {
        match delta {
            [dx, dy, dtheta] => Ok(Pose2::new(self.x + dx, self.y + dy, self.theta + dtheta)),
            _ => Err(Error::DimensionMismatch {
                what: "pose perturbation".into(),
                expected: 3,
                got: delta.len(),
            }),
        }
    }

    /// The default's arithmetic without its parameter vectors.
    fn distance_and_angle(&self, other: &Self) -> (f64, f64) {
        let (dx, dy) = (self.x - other.x, self.y - other.y);
        let dtheta = wrap_angle(self.theta - other.theta);
        ((dx * dx + dy * dy).sqrt(), 0.0f64.max(dtheta.abs()))
    }

    fn planar_motion_generators(&self) -> [Vec<f64>; 3] {
        [
            vec![1.0, 0.0, 0.0],
            vec![0.0, 1.0, 0.0],
            vec![-self.y, self.x, 1.0],
        ]
    }

    fn from_parameters(parameters: &[f64]) -> Result<Self> {
        match parameters {
            [x, y, theta] => Ok(Pose2::new(*x, *y, *theta)),
            _ => Err(Error::DimensionMismatch {
                what: "Pose2 parameters".into(),
                expected: 3,
                got: parameters.len(),
            }),
        }
    }
}

impl RobotPose for Pose3 {
    const DIM: usize = 6;
    const HEADING: usize = 3;

    fn world_from_sensor(&self, robot_from_sensor: &Pose3) -> Pose3 {
        self.compose(robot_from_sensor)
    }

    fn sensor_pose(&self, robot_from_sensor: &Pose3) -> Result<SensorPose> {
        let (world_from_sensor, d_sensor_d_robot, d_sensor_d_offset) =
            self.compose_with_jacobians(robot_from_sensor)?;
        Ok(SensorPose {
            world_from_sensor,
            d_sensor_d_robot: DMatrix::from_column_slice(6, 6, d_sensor_d_robot.as_slice()),
            d_sensor_d_offset,
        })
    }

    fn parameters(&self) -> Vec<f64> {
        self.to_vector().as_slice().to_vec()
    }

    /// ZYX Euler angles: a world rotation about z adds to the yaw only.
    fn planar_motion_generators(&self) -> [Vec<f64>; 3] {
        let t = self.translation;
        [
            vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            vec![0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            vec![-t.y, t.x, 0.0, 1.0, 0.0, 0.0],
        ]
    }

    fn from_parameters(parameters: &[f64]) -> Result<Self> {
        if parameters.len() != 6 {
            return Err(Error::DimensionMismatch {
                what: "Pose3 parameters".into(),
                expected: 6,
                got: parameters.len(),
            });
        }
        Ok(Pose3::from_vector(&Vector6::from_column_slice(parameters)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::numeric_jacobian;
    use approx::assert_relative_eq;
    use nalgebra::DVector;
    use proptest::prelude::*;

    fn pose2_strategy() -> impl Strategy<Value = Pose2> {
        (-50.0..50.0, -50.0..50.0, -PI..PI).prop_map(|(x, y, t)| Pose2::new(x, y, t))
    }

    fn pose3_strategy() -> impl Strategy<Value = Pose3> {
        (
            -20.0..20.0f64,
            -20.0..20.0f64,
            -5.0..5.0f64,
            -PI..PI,
            -1.3..1.3f64,
            -PI..PI,
        )
            .prop_map(|(x, y, z, yaw, pitch, roll)| {
                Pose3::new(Vector3::new(x, y, z), yaw, pitch, roll)
            })
    }

    fn pose2_diff(a: &Pose2, b: &Pose2) -> Vec<f64> {
        vec![a.x - b.x, a.y - b.y, wrap_angle(a.theta - b.theta)]
    }

    fn pose3_diff(a: &Pose3, b: &Pose3) -> Vec<f64> {
        let d = a.to_vector() - b.to_vector();
        vec![
            d[0],
            d[1],
            d[2],
            wrap_angle(d[3]),
            wrap_angle(d[4]),
            wrap_angle(d[5]),
        ]
    }

    fn p2(v: &DVector<f64>) -> Pose2 {
        Pose2::new(v[0], v[1], v[2])
    }

    fn p3(v: &DVector<f64>) -> Pose3 {
        Pose3::new(Vector3::new(v[0], v[1], v[2]), v[3], v[4], v[5])
    }

    #[test]
    fn wrap_angle_range() {
        assert_eq!(wrap_angle(PI), PI);
        assert_eq!(wrap_angle(-PI), PI);
        assert!(wrap_angle(f64::NAN).is_nan());
        assert_relative_eq!(wrap_angle(7.0), 7.0 - TAU, epsilon = 1e-12);
    }

    #[test]
    fn euler_round_trip_and_axes() {
        let pose = Pose3::new(Vector3::zeros(), 0.3, -0.4, 1.1);
        let back = Pose3::from_rotation(Vector3::zeros(), &pose.rotation());
        assert_relative_eq!(back.to_vector(), pose.to_vector(), epsilon = 1e-12);
        let yaw_only = Pose3::new(Vector3::zeros(), 0.7, 0.0, 0.0);
        assert_relative_eq!(
            yaw_only.rotation().fixed_view::<2, 2>(0, 0).into_owned(),
            Pose2::new(0.0, 0.0, 0.7).rotation(),
            epsilon = 1e-15
        );
    }

    #[test]
    fn gimbal_lock_is_an_error_not_nan() {
        let locked = Pose3::new(Vector3::zeros(), 0.2, std::f64::consts::FRAC_PI_2, 0.1);
        assert!(matches!(
            locked.compose_with_jacobians(&Pose3::identity()),
            Err(Error::Degenerate(_))
        ));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn pose2_compose_inverse_round_trip(a in pose2_strategy(), b in pose2_strategy()) {
            let back = a.compose(&b).compose(&b.inverse());
            prop_assert!(pose2_diff(&back, &a).iter().all(|d| d.abs() < 1e-9));
            let rel = a.between(&a.compose(&b));
            prop_assert!(pose2_diff(&rel, &b).iter().all(|d| d.abs() < 1e-9));
        }

        #[test]
        fn pose2_jacobians_match_central_differences(a in pose2_strategy(), b in pose2_strategy()) {
            let (_, d_a, d_b) = a.compose_with_jacobians(&b);
            let base = a.compose(&b);
            let num_a = numeric_jacobian(&DVector::from_column_slice(a.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose2_diff(&p2(v).compose(&b), &base))
            });
            let num_b = numeric_jacobian(&DVector::from_column_slice(b.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose2_diff(&a.compose(&p2(v)), &base))
            });
            prop_assert!((DMatrix::from_column_slice(3, 3, d_a.as_slice()) - num_a).amax() < 1e-5);
            prop_assert!((DMatrix::from_column_slice(3, 3, d_b.as_slice()) - num_b).amax() < 1e-5);

            let (inv, d_inv) = a.inverse_with_jacobian();
            let num_inv = numeric_jacobian(&DVector::from_column_slice(a.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose2_diff(&p2(v).inverse(), &inv))
            });
            prop_assert!((DMatrix::from_column_slice(3, 3, d_inv.as_slice()) - num_inv).amax() < 1e-5);

            let (rel, d_first, d_second) = a.between_with_jacobians(&b);
            let num_first = numeric_jacobian(&DVector::from_column_slice(a.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose2_diff(&p2(v).between(&b), &rel))
            });
            let num_second = numeric_jacobian(&DVector::from_column_slice(b.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose2_diff(&a.between(&p2(v)), &rel))
            });
            prop_assert!((DMatrix::from_column_slice(3, 3, d_first.as_slice()) - num_first).amax() < 1e-5);
            prop_assert!((DMatrix::from_column_slice(3, 3, d_second.as_slice()) - num_second).amax() < 1e-5);
        }

        #[test]
        fn pose2_point_jacobians(a in pose2_strategy(), px in -30.0..30.0f64, py in -30.0..30.0f64) {
            let p = Vector2::new(px, py);
            let (q, d_pose, d_point) = a.transform_point_with_jacobians(&p);
            prop_assert!((a.inverse_transform_point(&q) - p).amax() < 1e-9);
            let num_pose = numeric_jacobian(&DVector::from_column_slice(a.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_column_slice(p2(v).transform_point(&p).as_slice())
            });
            let num_point = numeric_jacobian(&DVector::from_column_slice(p.as_slice()), 1e-6, |v| {
                DVector::from_column_slice(a.transform_point(&Vector2::new(v[0], v[1])).as_slice())
            });
            prop_assert!((DMatrix::from_column_slice(2, 3, d_pose.as_slice()) - num_pose).amax() < 1e-5);
            prop_assert!((DMatrix::from_column_slice(2, 2, d_point.as_slice()) - num_point).amax() < 1e-5);
        }

        #[test]
        fn pose3_compose_inverse_round_trip(a in pose3_strategy(), b in pose3_strategy()) {
            let back = a.compose(&b).compose(&b.inverse());
            prop_assert!((back.rotation() - a.rotation()).amax() < 1e-9);
            prop_assert!((back.translation - a.translation).amax() < 1e-9);
            let rel = a.between(&a.compose(&b));
            prop_assert!((rel.rotation() - b.rotation()).amax() < 1e-9);
            let p = Vector3::new(1.0, -2.0, 0.5);
            prop_assert!((a.inverse_transform_point(&a.transform_point(&p)) - p).amax() < 1e-9);
        }

        #[test]
        fn oplus_undoes_ominus(a in pose2_strategy(), b in pose2_strategy(), c in pose3_strategy(), d in pose3_strategy()) {
            let back = b.oplus(&a.ominus(&b)).unwrap();
            prop_assert!((back.translation() - a.translation()).norm() < 1e-9);
            prop_assert!(wrap_angle(back.theta - a.theta).abs() < 1e-12);
            let back3 = d.oplus(&c.ominus(&d)).unwrap();
            prop_assert!((back3.to_vector() - c.to_vector()).amax() < 1e-9);
            let (distance, angle) = a.distance_and_angle(&b);
            prop_assert!((distance - (a.translation() - b.translation()).norm()).abs() < 1e-9);
            prop_assert!(angle <= PI && (angle - wrap_angle(a.theta - b.theta).abs()).abs() < 1e-12);
            prop_assert!(a.oplus(&[0.0; 2]).is_err());
            // Pose2's own oplus and distance_and_angle are the defaults' arithmetic exactly.
            let delta = b.parameters();
            let summed: Vec<f64> = a.parameters().iter().zip(&delta).map(|(p, d)| p + d).collect();
            prop_assert_eq!(a.oplus(&delta).unwrap(), Pose2::from_parameters(&summed).unwrap());
            let d = a.ominus(&b);
            prop_assert_eq!((distance, angle), ((d[0] * d[0] + d[1] * d[1]).sqrt(), d[2].abs()));
        }

        #[test]
        fn pose3_jacobians_match_central_differences(a in pose3_strategy(), b in pose3_strategy()) {
            let (base, d_a, d_b) = a.compose_with_jacobians(&b).unwrap();
            // The composed pitch must stay away from gimbal lock for differences to be smooth.
            prop_assume!(base.pitch.cos() > 0.2);
            let va = DVector::from_column_slice(a.to_vector().as_slice());
            let vb = DVector::from_column_slice(b.to_vector().as_slice());
            let num_a = numeric_jacobian(&va, 1e-6, |v| DVector::from_vec(pose3_diff(&p3(v).compose(&b), &base)));
            let num_b = numeric_jacobian(&vb, 1e-6, |v| DVector::from_vec(pose3_diff(&a.compose(&p3(v)), &base)));
            prop_assert!((DMatrix::from_column_slice(6, 6, d_a.as_slice()) - num_a).amax() < 1e-5);
            prop_assert!((DMatrix::from_column_slice(6, 6, d_b.as_slice()) - num_b).amax() < 1e-5);

            let (inv, d_inv) = a.inverse_with_jacobian().unwrap();
            // So must the inverse's (a pose pitched 1.26 rad and rolled 90 degrees inverts to
            // one near gimbal lock).
            prop_assume!(inv.pitch.cos() > 0.2);
            let num_inv = numeric_jacobian(&va, 1e-6, |v| DVector::from_vec(pose3_diff(&p3(v).inverse(), &inv)));
            prop_assert!((DMatrix::from_column_slice(6, 6, d_inv.as_slice()) - num_inv).amax() < 1e-5);

            let (rel, d_first, d_second) = a.between_with_jacobians(&b).unwrap();
            prop_assume!(rel.pitch.cos() > 0.2);
            let num_first = numeric_jacobian(&va, 1e-6, |v| DVector::from_vec(pose3_diff(&p3(v).between(&b), &rel)));
            let num_second = numeric_jacobian(&vb, 1e-6, |v| DVector::from_vec(pose3_diff(&a.between(&p3(v)), &rel)));
            prop_assert!((DMatrix::from_column_slice(6, 6, d_first.as_slice()) - num_first).amax() < 1e-5);
            prop_assert!((DMatrix::from_column_slice(6, 6, d_second.as_slice()) - num_second).amax() < 1e-5);
        }

        /// The planar path of a level mount agrees with the general 3-D composition.
        #[test]
        fn level_mount_planar_path_matches_3d(
            robot in pose2_strategy(), offset in pose3_strategy(), flip in proptest::bool::ANY,
        ) {
            let level = Pose3::new(offset.translation, if flip { PI } else { offset.yaw }, 0.0, 0.0);
            let planar = robot.sensor_pose(&level).unwrap();
            let general = robot.sensor_pose_3d(&level).unwrap();
            prop_assert!(pose3_diff(&planar.world_from_sensor, &general.world_from_sensor)
                .iter().all(|d| d.abs() < 1e-9));
            prop_assert_eq!(planar.world_from_sensor, robot.world_from_sensor(&level));
            let composed = robot.to_pose3(0.0).compose(&level);
            prop_assert!(pose3_diff(&planar.world_from_sensor, &composed).iter().all(|d| d.abs() < 1e-9));
            prop_assert!((&planar.d_sensor_d_robot - &general.d_sensor_d_robot).amax() < 1e-9);
            prop_assert!((planar.d_sensor_d_offset - general.d_sensor_d_offset).amax() < 1e-9);
        }

        #[test]
        fn robot_pose_sensor_jacobians(robot in pose2_strategy(), offset in pose3_strategy()) {
            let sensor = robot.sensor_pose(&offset).unwrap();
            prop_assume!(sensor.world_from_sensor.pitch.cos() > 0.2);
            let base = sensor.world_from_sensor;
            let num_r = numeric_jacobian(&DVector::from_column_slice(robot.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose3_diff(&p2(v).to_pose3(0.0).compose(&offset), &base))
            });
            let num_s = numeric_jacobian(&DVector::from_column_slice(offset.to_vector().as_slice()), 1e-6, |v| {
                DVector::from_vec(pose3_diff(&robot.to_pose3(0.0).compose(&p3(v)), &base))
            });
            prop_assert!((sensor.d_sensor_d_robot.clone() - num_r).amax() < 1e-5);
            prop_assert!((DMatrix::from_column_slice(6, 6, sensor.d_sensor_d_offset.as_slice()) - num_s).amax() < 1e-5);
        }
    }
}
