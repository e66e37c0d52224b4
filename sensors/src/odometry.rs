//! Dead-reckoning motion models (paper eqs. 25-27): a relative pose increment, a unicycle
//! (forward speed and yaw rate), a differential drive (wheel distances), and the Ackermann
//! model of the Victoria Park truck.
//!
//! Each is one increment `x_d` with its covariance `C_d` and implements
//! [`slam_core::MotionModel`]: `f(x_r, x_d) = x_r ⊕ delta(x_d)` with `J_rr = d⊕/dx_r` and
//! `J_rd = d⊕/d delta · d delta/d x_d`.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix3x2, Vector3};
use slam_core::{MotionModel, MotionPrediction, Pose2, ensure_finite};

use crate::error::{Result, SensorError};

/// `x ⊕ delta` with the Jacobian chain to the control: the shared tail of every model here.
fn compose_prediction(
    pose: &Pose2,
    delta: &Vector3<f64>,
    d_delta_d_control: &DMatrix<f64>,
    cov_control: DMatrix<f64>,
) -> MotionPrediction<Pose2> {
    let (predicted, d_pose, d_delta) = pose.compose_with_jacobians(&Pose2::from_vector(delta));
    MotionPrediction {
        pose: predicted,
        d_pose_d_pose: DMatrix::from_column_slice(3, 3, d_pose.as_slice()),
        d_pose_d_control: DMatrix::from_column_slice(3, 3, d_delta.as_slice()) * d_delta_d_control,
        cov_control,
    }
}

fn control_of_len(control: &DVector<f64>, n: usize, what: &str) -> slam_core::Result<()> {
    if control.len() != n {
        return Err(slam_core::Error::DimensionMismatch {
            what: format!("{what} control"),
            expected: n,
            got: control.len(),
        });
    }
    ensure_finite(control.as_slice(), what)
}

fn positive(value: f64, what: &str) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SensorError::InvalidArgument(format!(
            "{what} must be finite and non-negative, got {value}"
        )))
    }
}

/// A relative pose increment `x_d = (dx, dy, dtheta)` in the frame of the previous pose, with
/// covariance `C_d`: `f(x, x_d) = x ⊕ x_d`.
///
/// ```
/// use slam_sensors::odometry::PoseIncrement;
/// use slam_core::{MotionModel, Pose2, nalgebra::Matrix3};
/// let step = PoseIncrement::new(Pose2::new(1.0, 0.0, 0.1), Matrix3::identity() * 1e-4).unwrap();
/// let prediction = step.predict(&Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2)).unwrap();
/// assert!((prediction.pose.y - 1.0).abs() < 1e-12);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseIncrement {
    /// The increment.
    pub delta: Pose2,
    /// Its covariance, over `(dx, dy, dtheta)`.
    pub cov: Matrix3<f64>,
}

impl PoseIncrement {
    /// An increment with a finite, symmetric covariance with a non-negative diagonal.
    pub fn new(delta: Pose2, cov: Matrix3<f64>) -> Result<Self> {
        ensure_finite(delta.to_vector().as_slice(), "odometry increment")?;
        ensure_finite(cov.as_slice(), "odometry covariance")?;
        if (cov - cov.transpose()).amax() > 1e-12 * cov.amax().max(1.0)
            || cov.diagonal().iter().any(|&v| v < 0.0)
        {
            return Err(SensorError::InvalidArgument(
                "odometry covariance must be symmetric with a non-negative diagonal".into(),
            ));
        }
        Ok(PoseIncrement { delta, cov })
    }

    /// The increment between two consecutive odometry poses (`⊖previous ⊕ current`), with the
    /// covariance of `noise`.
    pub fn between(previous: &Pose2, current: &Pose2, noise: &OdometryNoise) -> Result<Self> {
        let delta = previous.between(current);
        PoseIncrement::new(delta, noise.covariance(&delta))
    }
}

impl MotionModel<Pose2> for PoseIncrement {
    fn control(&self) -> DVector<f64> {
        DVector::from_column_slice(self.delta.to_vector().as_slice())
    }

    fn apply_control(&self, pose: &Pose2, control: &DVector<f64>) -> slam_core::Result<Pose2> {
        control_of_len(control, 3, "pose increment")?;
        Ok(pose.compose(&Pose2::new(control[0], control[1], control[2])))
    }

    fn predict(&self, pose: &Pose2) -> slam_core::Result<MotionPrediction<Pose2>> {
        Ok(compose_prediction(
            pose,
            &self.delta.to_vector(),
            &DMatrix::identity(3, 3),
            DMatrix::from_column_slice(3, 3, self.cov.as_slice()),
        ))
    }
}

/// Odometry noise growing with the motion (the classic four-parameter model): standard
/// deviations `sigma_xy = a_tt |d| + a_tr |dtheta| + floor_xy` for each of dx and dy and
/// `sigma_theta = a_rr |dtheta| + a_rt |d| + floor_theta`, with `d = |(dx, dy)|`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OdometryNoise {
    /// Translation error per metre travelled.
    pub translation_per_metre: f64,
    /// Translation error per radian turned, metres per radian.
    pub translation_per_radian: f64,
    /// Rotation error per radian turned.
    pub rotation_per_radian: f64,
    /// Rotation error per metre travelled, radians per metre.
    pub rotation_per_metre: f64,
    /// Smallest translation standard deviation, metres.
    pub floor_translation: f64,
    /// Smallest rotation standard deviation, radians.
    pub floor_rotation: f64,
}

impl Default for OdometryNoise {
    fn default() -> Self {
        OdometryNoise {
            translation_per_metre: 0.05,
            translation_per_radian: 0.01,
            rotation_per_radian: 0.05,
            rotation_per_metre: 0.02,
            floor_translation: 1e-3,
            floor_rotation: 1e-3,
        }
    }
}

impl OdometryNoise {
    /// Checks that every term is finite and non-negative and that both floors are positive
    /// (a motion of zero would otherwise have a singular covariance).
    pub fn validate(&self) -> Result<()> {
        let terms = [
            ("translation_per_metre", self.translation_per_metre),
            ("translation_per_radian", self.translation_per_radian),
            ("rotation_per_radian", self.rotation_per_radian),
            ("rotation_per_metre", self.rotation_per_metre),
            ("floor_translation", self.floor_translation),
            ("floor_rotation", self.floor_rotation),
        ];
        for (name, value) in terms {
            positive(value, name)?;
        }
        if self.floor_translation == 0.0 || self.floor_rotation == 0.0 {
            return Err(SensorError::InvalidArgument(
                "floor_translation and floor_rotation must be positive (a motion of zero would \
                 have a singular covariance)"
                    .into(),
            ));
        }
        Ok(())
    }

    /// The diagonal covariance of an increment.
    pub fn covariance(&self, delta: &Pose2) -> Matrix3<f64> {
        let d = delta.translation().norm();
        let r = delta.theta.abs();
        let sigma_xy = self.translation_per_metre * d
            + self.translation_per_radian * r
            + self.floor_translation;
        let sigma_theta =
            self.rotation_per_radian * r + self.rotation_per_metre * d + self.floor_rotation;
        Matrix3::from_diagonal(&Vector3::new(
            sigma_xy * sigma_xy,
            sigma_xy * sigma_xy,
            sigma_theta * sigma_theta,
        ))
    }
}

/// How a unicycle's constant speed and yaw rate over `dt` become a pose increment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Integration {
    /// The exact constant-velocity arc.
    #[default]
    Arc,
    /// Straight ahead, then turn: `(v dt, 0, omega dt)` (the rb2d convention).
    Euler,
}

/// The increment of an arc of length `s` turning by `phi`, and its Jacobian w.r.t. `(s, phi)`.
fn arc_increment(s: f64, phi: f64, integration: Integration) -> (Vector3<f64>, Matrix3x2<f64>) {
    if integration == Integration::Euler {
        return (
            Vector3::new(s, 0.0, phi),
            Matrix3x2::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        );
    }
    // dx = s sinc(phi), dy = s (1 - cos phi) / phi, with series near phi = 0.
    let (sinc, d_sinc, g, d_g) = if phi.abs() < 1e-4 {
        let p2 = phi * phi;
        (
            1.0 - p2 / 6.0,
            -phi / 3.0,
            phi / 2.0 - phi * p2 / 24.0,
            0.5 - p2 / 8.0,
        )
    } else {
        let (sn, cs) = phi.sin_cos();
        (
            sn / phi,
            (phi * cs - sn) / (phi * phi),
            (1.0 - cs) / phi,
            (phi * sn - (1.0 - cs)) / (phi * phi),
        )
    };
    (
        Vector3::new(s * sinc, s * g, phi),
        Matrix3x2::new(sinc, s * d_sinc, g, s * d_g, 0.0, 1.0),
    )
}

/// A unicycle moving with forward speed `v` and yaw rate `omega` for `dt` seconds; the
/// control `x_d = (v, omega)` has independent noise `sigma_v`, `sigma_omega` (eqs. 25-27).
///
/// ```
/// use slam_sensors::odometry::{Integration, Unicycle};
/// use slam_core::{MotionModel, Pose2};
/// let step = Unicycle::new(1.0, 0.0, 0.1, 0.1, 0.035, Integration::Arc).unwrap();
/// assert!((step.predict(&Pose2::identity()).unwrap().pose.x - 0.1).abs() < 1e-12);
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Unicycle {
    /// Forward speed, m/s.
    pub v: f64,
    /// Yaw rate, rad/s.
    pub omega: f64,
    /// Duration, s.
    pub dt: f64,
    /// Standard deviation of `v`, m/s.
    pub sigma_v: f64,
    /// Standard deviation of `omega`, rad/s.
    pub sigma_omega: f64,
    /// Arc or Euler integration.
    pub integration: Integration,
}

impl Unicycle {
    /// A unicycle increment; values finite, `dt` and deviations non-negative.
    pub fn new(
        v: f64,
        omega: f64,
        dt: f64,
        sigma_v: f64,
        sigma_omega: f64,
        integration: Integration,
    ) -> Result<Self> {
        ensure_finite(&[v, omega], "unicycle speeds")?;
        positive(dt, "unicycle dt")?;
        positive(sigma_v, "sigma_v")?;
        positive(sigma_omega, "sigma_omega")?;
        Ok(Unicycle {
            v,
            omega,
            dt,
            sigma_v,
            sigma_omega,
            integration,
        })
    }

    fn increment(&self, v: f64, omega: f64) -> (Vector3<f64>, Matrix3x2<f64>) {
        let (delta, d_arc) = arc_increment(v * self.dt, omega * self.dt, self.integration);
        (delta, d_arc * self.dt)
    }
}

impl MotionModel<Pose2> for Unicycle {
    fn control(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.v, self.omega])
    }

    fn apply_control(&self, pose: &Pose2, control: &DVector<f64>) -> slam_core::Result<Pose2> {
        control_of_len(control, 2, "unicycle")?;
        let (delta, _) = self.increment(control[0], control[1]);
        Ok(pose.compose(&Pose2::from_vector(&delta)))
    }

    fn predict(&self, pose: &Pose2) -> slam_core::Result<MotionPrediction<Pose2>> {
        let (delta, d_delta) = self.increment(self.v, self.omega);
        let cov = Matrix2::new(self.sigma_v.powi(2), 0.0, 0.0, self.sigma_omega.powi(2));
        Ok(compose_prediction(
            pose,
            &delta,
            &DMatrix::from_column_slice(3, 2, d_delta.as_slice()),
            DMatrix::from_column_slice(2, 2, cov.as_slice()),
        ))
    }
}

/// A differential drive: the distances travelled by the left and right wheels, with variance
/// `k^2 |distance|` per wheel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DifferentialDrive {
    /// Left wheel travel, m.
    pub left: f64,
    /// Right wheel travel, m.
    pub right: f64,
    /// Distance between the wheels, m.
    pub wheel_base: f64,
    /// Standard deviation per square root of metre travelled, `sqrt(m)`.
    pub k: f64,
}

impl DifferentialDrive {
    /// A differential-drive increment; the wheel base must be positive.
    pub fn new(left: f64, right: f64, wheel_base: f64, k: f64) -> Result<Self> {
        ensure_finite(&[left, right], "wheel distances")?;
        if !(wheel_base.is_finite() && wheel_base > 0.0) {
            return Err(SensorError::InvalidArgument(format!(
                "wheel base must be positive, got {wheel_base}"
            )));
        }
        positive(k, "wheel noise k")?;
        Ok(DifferentialDrive {
            left,
            right,
            wheel_base,
            k,
        })
    }

    fn increment(&self, left: f64, right: f64) -> (Vector3<f64>, Matrix3x2<f64>) {
        let (delta, d_arc) = arc_increment(
            0.5 * (left + right),
            (right - left) / self.wheel_base,
            Integration::Arc,
        );
        let b = self.wheel_base;
        (delta, d_arc * Matrix2::new(0.5, 0.5, -1.0 / b, 1.0 / b))
    }
}

impl MotionModel<Pose2> for DifferentialDrive {
    fn control(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.left, self.right])
    }

    fn apply_control(&self, pose: &Pose2, control: &DVector<f64>) -> slam_core::Result<Pose2> {
        control_of_len(control, 2, "differential drive")?;
        let (delta, _) = self.increment(control[0], control[1]);
        Ok(pose.compose(&Pose2::from_vector(&delta)))
    }

    fn predict(&self, pose: &Pose2) -> slam_core::Result<MotionPrediction<Pose2>> {
        let (delta, d_delta) = self.increment(self.left, self.right);
        let k2 = self.k * self.k;
        let cov = Matrix2::new(k2 * self.left.abs(), 0.0, 0.0, k2 * self.right.abs());
        Ok(compose_prediction(
            pose,
            &delta,
            &DMatrix::from_column_slice(3, 2, d_delta.as_slice()),
            DMatrix::from_column_slice(2, 2, cov.as_slice()),
        ))
    }
}

/// Geometry of an Ackermann vehicle (the Victoria Park truck, Guivant & Nebot 2001).
///
/// The robot pose is the centre of the rear axle. The laser sits `laser_forward` ahead of it
/// and `laser_left` to its left. For Victoria Park we use `laser_forward = 3.78 m`: the
/// dataset's `info.txt` gives `a = 0.95 m` measured from the *front* axle, and
/// `L + a = 2.83 + 0.95 = 3.78 m` is the same point measured from the rear axle, which is the
/// value the widely used EKF code (`a = 3.78`) puts in the model referenced to the rear axle.
/// `laser_left = b = 0.5 m`, to the left, the sign for which that code's motion equations
/// describe the laser's velocity `v + omega x (a, b)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AckermannParams {
    /// Distance between the axles `L`, m.
    pub wheelbase: f64,
    /// Lateral offset `H` of the encoder wheel from the centre line, m.
    pub encoder_offset: f64,
    /// Laser position ahead of the rear axle, m.
    pub laser_forward: f64,
    /// Laser position left of the centre line, m.
    pub laser_left: f64,
}

impl Default for AckermannParams {
    /// The Victoria Park truck.
    fn default() -> Self {
        AckermannParams {
            wheelbase: 2.83,
            encoder_offset: 0.76,
            laser_forward: 3.78,
            laser_left: 0.5,
        }
    }
}

impl AckermannParams {
    /// Where the GPS antenna sits on the vehicle (x forward, y left), m: at the laser.
    ///
    /// The dataset does not document the antenna's place. The EKF code the dataset is usually
    /// run with (`VictoriaEKF.m`, after Guivant & Nebot's model) estimates the laser's
    /// position and compares the GPS fixes with it. Our runs agree: the RMS distance between
    /// the GPS fixes and a point fixed on the truck, over the whole run after the best rigid
    /// alignment, is smallest within about half a metre of the laser mount, and 1.8 m larger
    /// at the rear axle.
    pub fn gps_antenna(&self) -> slam_core::nalgebra::Vector2<f64> {
        slam_core::nalgebra::Vector2::new(self.laser_forward, self.laser_left)
    }

    /// Where the laser sits on the vehicle (`robot_from_laser`).
    pub fn robot_from_laser(&self) -> slam_core::Pose3 {
        slam_core::Pose3::new(
            slam_core::nalgebra::Vector3::new(self.laser_forward, self.laser_left, 0.0),
            0.0,
            0.0,
            0.0,
        )
    }
}

/// An Ackermann increment: encoder speed and steering angle held for `dt`.
///
/// The encoder measures the rear left wheel, so the centre speed is
/// `v_c = v / (1 - tan(steering) H / L)`; the yaw rate is `v_c tan(steering) / L`; the pose
/// integrates with Euler steps (`dt` is 25 ms in Victoria Park): `x ⊕ (v_c dt, 0, omega dt)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ackermann {
    /// Encoder speed, m/s.
    pub speed: f64,
    /// Steering angle, rad.
    pub steering: f64,
    /// Duration, s.
    pub dt: f64,
    /// Standard deviation of the speed, m/s.
    pub sigma_speed: f64,
    /// Standard deviation of the steering angle, rad.
    pub sigma_steering: f64,
    /// Vehicle geometry.
    pub params: AckermannParams,
}

impl Ackermann {
    /// An increment; the steering must stay below 80 degrees.
    pub fn new(
        speed: f64,
        steering: f64,
        dt: f64,
        sigma_speed: f64,
        sigma_steering: f64,
        params: AckermannParams,
    ) -> Result<Self> {
        ensure_finite(&[speed, steering], "Ackermann controls")?;
        positive(dt, "Ackermann dt")?;
        positive(sigma_speed, "sigma_speed")?;
        positive(sigma_steering, "sigma_steering")?;
        if steering.abs() > 80f64.to_radians() {
            return Err(SensorError::InvalidArgument(format!(
                "steering angle {steering} rad is beyond 80 degrees"
            )));
        }
        Ok(Ackermann {
            speed,
            steering,
            dt,
            sigma_speed,
            sigma_steering,
            params,
        })
    }

    fn increment(&self, speed: f64, steering: f64) -> (Vector3<f64>, Matrix3x2<f64>) {
        let (l, h, dt) = (self.params.wheelbase, self.params.encoder_offset, self.dt);
        let tan = steering.tan();
        let sec2 = 1.0 + tan * tan;
        let den = 1.0 - tan * h / l;
        let v_c = speed / den;
        let d_vc_d_speed = 1.0 / den;
        let d_vc_d_steering = speed * (h / l) * sec2 / (den * den);
        let omega = v_c * tan / l;
        let d_omega_d_speed = d_vc_d_speed * tan / l;
        let d_omega_d_steering = (d_vc_d_steering * tan + v_c * sec2) / l;
        (
            Vector3::new(v_c * dt, 0.0, omega * dt),
            Matrix3x2::new(
                d_vc_d_speed * dt,
                d_vc_d_steering * dt,
                0.0,
                0.0,
                d_omega_d_speed * dt,
                d_omega_d_steering * dt,
            ),
        )
    }
}

impl MotionModel<Pose2> for Ackermann {
    fn control(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.speed, self.steering])
    }

    fn apply_control(&self, pose: &Pose2, control: &DVector<f64>) -> slam_core::Result<Pose2> {
        control_of_len(control, 2, "Ackermann")?;
        let (delta, _) = self.increment(control[0], control[1]);
        Ok(pose.compose(&Pose2::from_vector(&delta)))
    }

    fn predict(&self, pose: &Pose2) -> slam_core::Result<MotionPrediction<Pose2>> {
        let (delta, d_delta) = self.increment(self.speed, self.steering);
        let cov = Matrix2::new(
            self.sigma_speed.powi(2),
            0.0,
            0.0,
            self.sigma_steering.powi(2),
        );
        Ok(compose_prediction(
            pose,
            &delta,
            &DMatrix::from_column_slice(3, 2, d_delta.as_slice()),
            DMatrix::from_column_slice(2, 2, cov.as_slice()),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use slam_core::testing::numeric_jacobian;

    /// J_rr and J_rd of a model against central differences of `apply_control`.
    fn check_jacobians(
        model: &dyn MotionModel<Pose2>,
        pose: &Pose2,
    ) -> std::result::Result<(), TestCaseError> {
        let prediction = model.predict(pose).unwrap();
        let wrap = |p: Pose2| DVector::from_vec(vec![p.x, p.y, p.theta]);
        let base = prediction.pose;
        let diff = |p: Pose2| {
            let mut d = wrap(p) - wrap(base);
            d[2] = slam_core::wrap_angle(d[2]);
            d
        };
        let numeric_rr = numeric_jacobian(&wrap(*pose), 1e-6, |v| {
            diff(
                model
                    .apply_control(&Pose2::new(v[0], v[1], v[2]), &model.control())
                    .unwrap(),
            )
        });
        let numeric_rd = numeric_jacobian(&model.control(), 1e-6, |u| {
            diff(model.apply_control(pose, u).unwrap())
        });
        prop_assert!((prediction.d_pose_d_pose - numeric_rr).amax() < 1e-5);
        prop_assert!((prediction.d_pose_d_control - numeric_rd).amax() < 1e-5);
        let direct = model.apply_control(pose, &model.control()).unwrap();
        prop_assert!(diff(direct).amax() < 1e-12);
        Ok(())
    }

    fn pose() -> impl Strategy<Value = Pose2> {
        (-20.0..20.0f64, -20.0..20.0f64, -3.1..3.1f64).prop_map(|(x, y, t)| Pose2::new(x, y, t))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn unicycle_jacobians(p in pose(), v in -2.0..2.0f64, w in prop_oneof![-1.5..1.5f64, -1e-5..1e-5f64], euler in any::<bool>()) {
            let integration = if euler { Integration::Euler } else { Integration::Arc };
            check_jacobians(&Unicycle::new(v, w, 0.1, 0.1, 0.03, integration).unwrap(), &p)?;
        }

        #[test]
        fn differential_drive_jacobians(p in pose(), l in -0.3..0.3f64, r in -0.3..0.3f64) {
            check_jacobians(&DifferentialDrive::new(l, r, 0.4, 0.05).unwrap(), &p)?;
        }

        #[test]
        fn ackermann_jacobians(p in pose(), v in -1.0..8.0f64, s in -0.5..0.5f64) {
            check_jacobians(&Ackermann::new(v, s, 0.025, 0.1, 0.02, AckermannParams::default()).unwrap(), &p)?;
        }

        #[test]
        fn pose_increment_jacobians(p in pose(), d in pose()) {
            let noise = OdometryNoise::default();
            check_jacobians(&PoseIncrement::new(d, noise.covariance(&d)).unwrap(), &p)?;
        }
    }

    #[test]
    fn arc_matches_a_circle() {
        // Quarter circle of radius 2: v = 1, omega = 0.5, dt = pi.
        let step =
            Unicycle::new(1.0, 0.5, std::f64::consts::PI, 0.0, 0.0, Integration::Arc).unwrap();
        let end = step.predict(&Pose2::identity()).unwrap().pose;
        assert!(
            (end.x - 2.0).abs() < 1e-12 && (end.y - 2.0).abs() < 1e-12,
            "{end:?}"
        );
    }

    #[test]
    fn bad_controls_are_errors() {
        assert!(Unicycle::new(f64::NAN, 0.0, 0.1, 0.1, 0.1, Integration::Arc).is_err());
        assert!(Unicycle::new(1.0, 0.0, -0.1, 0.1, 0.1, Integration::Arc).is_err());
        assert!(DifferentialDrive::new(0.1, 0.1, 0.0, 0.1).is_err());
        assert!(Ackermann::new(1.0, 1.5, 0.025, 0.1, 0.1, AckermannParams::default()).is_err());
        let bad_cov = Matrix3::new(1.0, 2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(PoseIncrement::new(Pose2::identity(), bad_cov).is_err());
    }
}
