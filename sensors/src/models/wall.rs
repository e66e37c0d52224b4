//! A laser observation of a wall: the measured line (normal angle and distance) and the
//! segment's endpoints, each flagged as a real end of the wall or not.

use slam_core::nalgebra::{DMatrix, DVector, Matrix2, RowVector2, Vector2};
use slam_core::{
    CoordBlock, Coordinates, Error, Extension, Feature, Innovation, MeasurementModel, Pose3,
    Result, ensure_finite, wrap_angle,
};
use slam_features::Wall;
use slam_features::wall::{END, LINE, PIVOT, START};

use super::{check_sigmas, scan_plane_to_world};

/// A wall segment seen by a 2-D laser, in the sensor frame.
///
/// The **line** is in normal form: the points `p` with `(cos alpha, sin alpha) . p = rho`,
/// `rho >= 0`, so `alpha` points from the sensor to the line. The **endpoints** are the
/// segment's ends on that line, in scan order; `real[k]` says whether endpoint `k` is a real
/// end of the wall (a corner or an edge) rather than an occlusion or the edge of the field of
/// view. The measurement vector is `v = (alpha, rho, e0x, e0y, e1x, e1y)`.
///
/// Innovation rows (predicted minus measured):
/// - always the line: `wrap(alpha_pred - alpha)` and `rho_pred - rho`, where the predicted
///   line is the wall's line seen from the sensor (the sensor must be on the wall's free side
///   for `rho_pred` to be positive);
/// - for each real measured endpoint whose wall endpoint is estimated (its `"start"`/`"end"`
///   subspace is active or it is a shared corner): the tangential offset
///   `t . (x_end_pred - x_end_measured)`, `t` the wall's unit tangent.
///
/// A tentative wall (dimension 0) gets the line rows, for association.
#[derive(Clone, Debug, PartialEq)]
pub struct WallObservation {
    /// Direction from the sensor to the line, rad.
    pub alpha: f64,
    /// Distance from the sensor to the line, m.
    pub rho: f64,
    /// Covariance of `(alpha, rho)`.
    pub line_cov: Matrix2<f64>,
    /// Segment ends in the sensor frame, in scan order.
    pub endpoints: [Vector2<f64>; 2],
    /// Whether each end is a real end of the wall.
    pub real: [bool; 2],
    /// Standard deviation of each endpoint's position (isotropic), in scan order, m.
    pub sigma_endpoints: [f64; 2],
    /// Largest gap between the segment and a wall end that is not estimated for the segment
    /// to still be of that wall, m (default [`MAX_GAP`]; see [`WallObservation::with_max_gap`]).
    pub max_gap: f64,
}

impl WallObservation {
    /// A wall observation; values finite, `rho >= 0`, covariance symmetric with a positive
    /// diagonal, `sigma_endpoints > 0`.
    pub fn new(
        alpha: f64,
        rho: f64,
        line_cov: Matrix2<f64>,
        endpoints: [Vector2<f64>; 2],
        real: [bool; 2],
        sigma_endpoints: [f64; 2],
    ) -> Result<Self> {
        ensure_finite(&[alpha, rho], "wall line")?;
        ensure_finite(line_cov.as_slice(), "wall line covariance")?;
        ensure_finite(endpoints[0].as_slice(), "wall endpoint")?;
        ensure_finite(endpoints[1].as_slice(), "wall endpoint")?;
        check_sigmas(
            &[
                sigma_endpoints[0],
                sigma_endpoints[1],
                line_cov[(0, 0)],
                line_cov[(1, 1)],
            ],
            "wall observation",
        )?;
        if rho < 0.0 || (line_cov[(0, 1)] - line_cov[(1, 0)]).abs() > 1e-12 * line_cov.amax() {
            return Err(Error::InvalidArgument(
                "wall observation needs rho >= 0 and a symmetric line covariance".into(),
            ));
        }
        Ok(WallObservation {
            alpha: wrap_angle(alpha),
            rho,
            line_cov,
            endpoints,
            real,
            sigma_endpoints,
            max_gap: MAX_GAP,
        })
    }

    /// The observation with another largest gap to a wall's open end ([`MAX_GAP`]); finite and
    /// non-negative, m.
    ///
    /// ```
    /// use slam_core::nalgebra::{Matrix2, Vector2};
    /// use slam_sensors::models::WallObservation;
    /// let cov = Matrix2::new(1e-4, 0.0, 0.0, 1e-4);
    /// let seen = WallObservation::from_segment(
    ///     Vector2::new(1.0, 2.0), Vector2::new(3.0, 2.0), cov, [false; 2], [0.05; 2])?;
    /// assert_eq!(seen.clone().with_max_gap(2.0)?.max_gap, 2.0);
    /// assert!(seen.with_max_gap(-1.0).is_err());
    /// # Ok::<(), slam_core::Error>(())
    /// ```
    pub fn with_max_gap(self, max_gap: f64) -> Result<Self> {
        if !(max_gap.is_finite() && max_gap >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "a wall's largest gap must be finite and at least 0, got {max_gap}"
            )));
        }
        Ok(WallObservation { max_gap, ..self })
    }

    /// The observation of the segment from `a` to `b` (sensor frame): its line, endpoints in
    /// the given order, with the given line covariance, endpoint flags and deviation.
    pub fn from_segment(
        a: Vector2<f64>,
        b: Vector2<f64>,
        line_cov: Matrix2<f64>,
        real: [bool; 2],
        sigma_endpoints: [f64; 2],
    ) -> Result<Self> {
        let d = b - a;
        if d.norm() < Wall::MIN_LENGTH {
            return Err(Error::Degenerate("wall segment shorter than 1 mm".into()));
        }
        let mut normal = Vector2::new(-d.y, d.x).normalize();
        if normal.dot(&a) < 0.0 {
            normal = -normal;
        }
        WallObservation::new(
            normal.y.atan2(normal.x),
            normal.dot(&a),
            line_cov,
            [a, b],
            real,
            sigma_endpoints,
        )
    }

    /// Measured endpoint indices ordered along `tangent`: `(towards start, towards end)`.
    fn matched_ends(&self, tangent: &Vector2<f64>) -> [usize; 2] {
        if tangent.dot(&self.endpoints[0]) <= tangent.dot(&self.endpoints[1]) {
            [0, 1]
        } else {
            [1, 0]
        }
    }
}

/// How far a measured segment may reach beyond an estimated (real) wall end and still be of
/// that wall, m: a few endpoint deviations of a real log (a corner seen from afar or through
/// clutter is placed tens of centimetres off; with 0.3 m the Intel lab's corridors were
/// started again as second walls).
pub const BEYOND_ESTIMATED_END: f64 = 1.0;

/// Largest gap between a measured segment and a wall end that is not estimated for the
/// segment to still be of that wall, by default, m: less than a doorway, so that the wall on
/// the far side of a door is a wall of its own. Real buildings do better with a corridor
/// wall kept whole across its doors (2 m in `configs/carmen-walls.toml`); on the built-in
/// world 2 m joins the collinear back walls of neighbouring rooms across their dividing
/// wall and the map breaks up (ATE 0.025 -> 0.14 m without merging).
pub const MAX_GAP: f64 = 0.5;

/// The measured segment's extent along the wall `start -> end` (frames must agree):
/// `(lowest, highest)` position along the tangent from `start`.
fn extent_along(
    start: &Vector2<f64>,
    end: &Vector2<f64>,
    points: &[Vector2<f64>; 2],
) -> (f64, f64) {
    let t = (end - start).normalize();
    let a = t.dot(&(points[0] - start));
    let b = t.dot(&(points[1] - start));
    (a.min(b), a.max(b))
}

/// Whether the wall's endpoint `k` (0 start, 1 end) has an estimated tangential position.
fn endpoint_estimated(wall: &Wall, k: usize) -> bool {
    wall.end_estimated(k)
}

/// One innovation row: `(eta, d eta / d start, d eta / d end, d eta / d measurement)`.
type InnovationRow = (f64, RowVector2<f64>, RowVector2<f64>, [f64; 6]);

impl MeasurementModel for WallObservation {
    type Feature = Wall;

    fn innovation(&self, wall: &Wall, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point2(s), CoordBlock::Point2(e)] = x_o.blocks() else {
            return Err(Error::InvalidArgument("a wall is two 2-D points".into()));
        };
        let (s, e) = (*s, *e);
        let u = e - s;
        let l = u.norm();
        if l < Wall::MIN_LENGTH {
            return Err(Error::Degenerate(
                "wall shorter than 1 mm in the sensor frame".into(),
            ));
        }
        let t = u / l;
        let n = Vector2::new(-t.y, t.x); // free side
        let p = Matrix2::new(0.0, -1.0, 1.0, 0.0);
        let projector = (Matrix2::identity() - t * t.transpose()) / l; // dt/du

        // Line rows: alpha_pred = angle(-n), rho_pred = -n . s.
        let mut rows: Vec<InnovationRow> = Vec::with_capacity(4);
        let d_alpha_d_e = n.transpose() / l;
        let w = (s.transpose() * p - t.transpose() * s.dot(&n)) / l;
        rows.push((
            wrap_angle((-n.y).atan2(-n.x) - self.alpha),
            -d_alpha_d_e,
            d_alpha_d_e,
            [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ));
        rows.push((
            -n.dot(&s) - self.rho,
            -n.transpose() + w,
            -w,
            [0.0, -1.0, 0.0, 0.0, 0.0, 0.0],
        ));

        // Endpoint rows: t . (x_k - q_k) for real, estimated endpoints.
        if wall.mspace_dim() > 0 || wall.is_shared(0) || wall.is_shared(1) {
            for (k, &m) in self.matched_ends(&t).iter().enumerate() {
                if !self.real[m] || !endpoint_estimated(wall, k) {
                    continue;
                }
                let x = if k == 0 { s } else { e };
                let q = self.endpoints[m];
                let lever = (x - q).transpose() * projector; // d t/d u applied to (x - q)
                let (d_s, d_e) = if k == 0 {
                    (t.transpose() - lever, lever)
                } else {
                    (-lever, t.transpose() + lever)
                };
                let mut d_v = [0.0; 6];
                d_v[2 + 2 * m] = -t.x;
                d_v[3 + 2 * m] = -t.y;
                rows.push((t.dot(&(x - q)), d_s, d_e, d_v));
            }
        }

        let m = rows.len();
        let mut eta = DVector::zeros(m);
        let mut d_eta_d_xo = DMatrix::zeros(m, 4);
        let mut d_eta_d_v = DMatrix::zeros(m, 6);
        for (i, (value, d_s, d_e, d_v)) in rows.into_iter().enumerate() {
            eta[i] = value;
            d_eta_d_xo.view_mut((i, 0), (1, 2)).copy_from(&d_s);
            d_eta_d_xo.view_mut((i, 2), (1, 2)).copy_from(&d_e);
            d_eta_d_v.row_mut(i).copy_from_slice(&d_v);
        }
        let mut cov_v = DMatrix::zeros(6, 6);
        cov_v.view_mut((0, 0), (2, 2)).copy_from(&self.line_cov);
        for k in 2..6 {
            let sigma = self.sigma_endpoints[(k - 2) / 2];
            cov_v[(k, k)] = sigma * sigma;
        }
        Ok(Innovation {
            eta,
            d_eta_d_xo,
            d_eta_d_v,
            cov_v,
        })
    }

    fn measurement(&self) -> DVector<f64> {
        let [a, b] = self.endpoints;
        DVector::from_vec(vec![self.alpha, self.rho, a.x, a.y, b.x, b.y])
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        if v.len() != 6 {
            return Err(Error::DimensionMismatch {
                what: "wall observation".into(),
                expected: 6,
                got: v.len(),
            });
        }
        WallObservation::new(
            v[0],
            v[1],
            self.line_cov,
            [Vector2::new(v[2], v[3]), Vector2::new(v[4], v[5])],
            self.real,
            self.sigma_endpoints,
        )
    }

    /// The wall through the measured endpoints (projected onto the measured line), seen from
    /// the sensor, i.e. with the sensor on its free side.
    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Wall>> {
        let normal = Vector2::new(self.alpha.cos(), self.alpha.sin());
        let on_line = |q: Vector2<f64>| q + normal * (self.rho - normal.dot(&q));
        let a = scan_plane_to_world(world_from_sensor, &on_line(self.endpoints[0]));
        let b = scan_plane_to_world(world_from_sensor, &on_line(self.endpoints[1]));
        let viewpoint = world_from_sensor.translation.xy();
        Wall::seen_from(a, b, viewpoint).map(Some)
    }

    /// The measured segment must overlap the wall or lie within `max_gap` of an end that
    /// is not estimated, and may not reach more than [`BEYOND_ESTIMATED_END`] beyond an
    /// estimated (real) end.
    fn plausible(&self, wall: &Wall, x_o: &Coordinates) -> bool {
        let [CoordBlock::Point2(s), CoordBlock::Point2(e)] = x_o.blocks() else {
            return false;
        };
        let length = (e - s).norm();
        if length < Wall::MIN_LENGTH {
            return false;
        }
        let (lo, hi) = extent_along(s, e, &self.endpoints);
        let start_ok = if endpoint_estimated(wall, 0) {
            lo >= -BEYOND_ESTIMATED_END
        } else {
            hi >= -self.max_gap
        };
        let end_ok = if endpoint_estimated(wall, 1) {
            hi <= length + BEYOND_ESTIMATED_END
        } else {
            lo <= length + self.max_gap
        };
        start_ok && end_ok
    }

    /// Grows the wall along its line to cover the measured segment, at each end whose
    /// position is not estimated (neither in the M-space nor a shared corner):
    /// [`Wall::extension_over`].
    fn extend(&self, wall: &Wall, world_from_sensor: &Pose3) -> Result<Option<Extension>> {
        let measured = self
            .endpoints
            .map(|q| scan_plane_to_world(world_from_sensor, &q));
        wall.extension_over(&measured)
    }

    fn revealed_subspaces(&self, wall: &Wall, x_o: &Coordinates) -> Vec<&'static str> {
        let tangent = match x_o.blocks() {
            [CoordBlock::Point2(s), CoordBlock::Point2(e)] => e - s,
            _ => return Vec::new(),
        };
        let [to_start, to_end] = self.matched_ends(&tangent);
        wall.growth_options()
            .into_iter()
            .map(|s| s.name)
            .filter(|&name| {
                name == LINE.name
                    || name == PIVOT.name
                    || (name == START.name && self.real[to_start])
                    || (name == END.name && self.real[to_end])
            })
            .collect()
    }
}
