//! Ceiling-camera measurements: an image point (a lamp) of a [`Point`], bearing-only, and an
//! image line of a horizontal line [`HLine`] (paper sections IV-E, IV-G and VII).

use slam_core::nalgebra::{
    DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, RowVector2, Vector2, Vector3,
};
use slam_core::{
    CoordBlock, Coordinates, Error, Extension, Feature, Innovation, MeasurementModel, Pose3,
    Result, Triangulation, ensure_finite, wrap_angle,
};
use slam_features::hline::{DIRECTION, POSITION};
use slam_features::point::{HEIGHT, HORIZONTAL};
use slam_features::{HLine, Point};

use super::check_sigmas;
use crate::camera::{MIN_DEPTH, PinholeCamera};

/// Largest difference between the predicted and measured offset of an image line whose
/// position is not estimated, for the two to be the same line (normalized image units).
pub const LINE_OFFSET_TOLERANCE: f64 = 0.2;

/// How far (normalized image units) a measured image segment may lie beyond the projected
/// extent of a line and still be of that line.
pub const LINE_OVERLAP_MARGIN: f64 = 0.3;

/// Smallest angle between two viewing rays (or viewing planes) for a triangulation, rad
/// (about 8.6 degrees). The depth error of a triangulation grows as one over the parallax:
/// with 0.7 px of noise at a 283 px focal length, 2 degrees leave the depth of a lamp 2 m up
/// uncertain by about 15 cm, far outside the linear range of the first updates; on the
/// built-in world 2 degrees doubled the pose NEES of the EKF against this value.
pub const MIN_PARALLAX: f64 = 0.15;

/// A lamp seen as an image point: a bearing-only measurement of a [`Point`].
///
/// `eta = project(x_o) - pixel`. One view cannot place the point: the tentative point of
/// [`MeasurementModel::initial_feature`] sits on the ray at `assumed_depth`, for association
/// only; [`MeasurementModel::triangulate`] places it from two or more views with enough
/// parallax and reveals its full M-space.
#[derive(Clone, Debug, PartialEq)]
pub struct ImagePointObservation {
    /// Measured pixel.
    pub pixel: Vector2<f64>,
    /// Pixel standard deviation (both axes).
    pub sigma_px: f64,
    /// The camera's intrinsics.
    pub camera: PinholeCamera,
    /// Depth along the optical axis at which a one-view point is placed, m.
    pub assumed_depth: f64,
}

impl ImagePointObservation {
    /// An observation; finite pixel, positive deviation and depth, valid intrinsics.
    pub fn new(
        pixel: Vector2<f64>,
        sigma_px: f64,
        camera: PinholeCamera,
        assumed_depth: f64,
    ) -> Result<Self> {
        ensure_finite(pixel.as_slice(), "image point")?;
        check_sigmas(&[sigma_px, assumed_depth], "image point")?;
        camera.validate()?;
        Ok(ImagePointObservation {
            pixel,
            sigma_px,
            camera,
            assumed_depth,
        })
    }

    /// The viewing ray in the world: camera centre and unit direction.
    fn world_ray(&self, world_from_sensor: &Pose3) -> (Vector3<f64>, Vector3<f64>) {
        let n = self.camera.normalized(&self.pixel);
        let direction = world_from_sensor.rotation() * Vector3::new(n.x, n.y, 1.0);
        (world_from_sensor.translation, direction.normalize())
    }
}

impl MeasurementModel for ImagePointObservation {
    type Feature = Point;

    fn innovation(&self, _point: &Point, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point3(p)] = x_o.blocks() else {
            return Err(Error::InvalidArgument("a point is one 3-D block".into()));
        };
        let (pixel, d_pixel) = self.camera.project(p)?;
        Ok(Innovation {
            eta: DVector::from_column_slice((pixel - self.pixel).as_slice()),
            d_eta_d_xo: DMatrix::from_column_slice(2, 3, d_pixel.as_slice()),
            d_eta_d_v: -DMatrix::identity(2, 2),
            cov_v: DMatrix::identity(2, 2) * self.sigma_px * self.sigma_px,
        })
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_column_slice(self.pixel.as_slice())
    }

    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        if v.len() != 2 {
            return Err(Error::DimensionMismatch {
                what: "image point".into(),
                expected: 2,
                got: v.len(),
            });
        }
        ImagePointObservation::new(
            Vector2::new(v[0], v[1]),
            self.sigma_px,
            self.camera,
            self.assumed_depth,
        )
    }

    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<Point>> {
        let n = self.camera.normalized(&self.pixel);
        let in_camera = Vector3::new(n.x, n.y, 1.0) * self.assumed_depth;
        Point::new(world_from_sensor.transform_point(&in_camera)).map(Some)
    }

    /// Least-squares intersection of the viewing rays; needs two rays at least
    /// [`MIN_PARALLAX`] apart, and the point in front of every camera.
    fn triangulates(&self) -> bool {
        true
    }

    fn triangulate(views: &[(Pose3, &Self)]) -> Result<Option<Triangulation<Point>>> {
        let rays: Vec<_> = views.iter().map(|(pose, z)| z.world_ray(pose)).collect();
        let parallax = rays
            .iter()
            .flat_map(|a| {
                rays.iter()
                    .map(move |b| a.1.dot(&b.1).clamp(-1.0, 1.0).acos())
            })
            .fold(0.0, f64::max);
        if rays.len() < 2 || parallax < MIN_PARALLAX {
            return Ok(None);
        }
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        for (origin, direction) in &rays {
            let reject = Matrix3::identity() - direction * direction.transpose();
            a += reject;
            b += reject * origin;
        }
        let Some(point) = a.try_inverse().map(|inverse| inverse * b) else {
            return Ok(None);
        };
        let in_front = views
            .iter()
            .all(|(pose, _)| pose.inverse_transform_point(&point).z > MIN_DEPTH);
        if !in_front {
            return Ok(None);
        }
        Ok(Some(Triangulation {
            feature: Point::new(point)?,
            reveals: vec![HORIZONTAL.name, HEIGHT.name],
        }))
    }
}

/// A horizontal ceiling line seen as an image line, in normalized image coordinates
/// `x_n = ((u - cx)/fx, (v - cy)/fy)`: the points with `(cos theta, sin theta) . x_n = d`,
/// `d >= 0`, plus the segment's two ends (normalized) for placing a new line.
///
/// Innovation (predicted minus measured, the predicted normal taken on the measured side):
/// `wrap(theta_pred - theta)` alone while the line has only its `"direction"` (one image gives
/// the direction), both rows `(theta, d)` once its `"position"` is known, and both rows for a
/// tentative line (for association). [`MeasurementModel::triangulate`] intersects the viewing
/// planes of two or more images and reveals the position.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageLineObservation {
    /// Normal angle of the image line, rad.
    pub theta: f64,
    /// Distance of the image line from the principal point, normalized units.
    pub d: f64,
    /// Covariance of `(theta, d)`.
    pub cov: Matrix2<f64>,
    /// The segment's ends, normalized image coordinates.
    pub ends: [Vector2<f64>; 2],
    /// The camera's intrinsics.
    pub camera: PinholeCamera,
    /// Depth along the optical axis at which a one-view line is placed, m.
    pub assumed_depth: f64,
}

impl ImageLineObservation {
    /// The line through two normalized image points, with covariance `cov` of `(theta, d)`.
    pub fn from_ends(
        ends: [Vector2<f64>; 2],
        cov: Matrix2<f64>,
        camera: PinholeCamera,
        assumed_depth: f64,
    ) -> Result<Self> {
        ensure_finite(ends[0].as_slice(), "image line end")?;
        ensure_finite(ends[1].as_slice(), "image line end")?;
        ensure_finite(cov.as_slice(), "image line covariance")?;
        check_sigmas(&[cov[(0, 0)], cov[(1, 1)], assumed_depth], "image line")?;
        camera.validate()?;
        let u = ends[1] - ends[0];
        if u.norm() < 1e-9 {
            return Err(Error::Degenerate("image line of zero length".into()));
        }
        let mut normal = Vector2::new(-u.y, u.x).normalize();
        if normal.dot(&ends[0]) < 0.0 {
            normal = -normal;
        }
        Ok(ImageLineObservation {
            theta: normal.y.atan2(normal.x),
            d: normal.dot(&ends[0]),
            cov,
            ends,
            camera,
            assumed_depth,
        })
    }

    /// The viewing plane in the world: a unit normal and a point (the camera centre).
    fn world_plane(&self, world_from_sensor: &Pose3) -> (Vector3<f64>, Vector3<f64>) {
        let (s, c) = self.theta.sin_cos();
        let normal = world_from_sensor.rotation() * Vector3::new(c, s, -self.d);
        (normal.normalize(), world_from_sensor.translation)
    }
}

/// Projection of a camera-frame point to normalized coordinates, with its Jacobian.
fn normalize(p: &Vector3<f64>) -> Result<(Vector2<f64>, Matrix2x3<f64>)> {
    if p.z <= MIN_DEPTH {
        return Err(Error::Degenerate("line end behind the camera".into()));
    }
    let iz = 1.0 / p.z;
    Ok((
        Vector2::new(p.x * iz, p.y * iz),
        Matrix2x3::new(iz, 0.0, -p.x * iz * iz, 0.0, iz, -p.y * iz * iz),
    ))
}

impl MeasurementModel for ImageLineObservation {
    type Feature = HLine;

    fn innovation(&self, line: &HLine, x_o: &Coordinates) -> Result<Innovation> {
        let [CoordBlock::Point3(s), CoordBlock::Point3(e)] = x_o.blocks() else {
            return Err(Error::InvalidArgument(
                "a horizontal line is two 3-D points".into(),
            ));
        };
        let (a, d_a) = normalize(s)?;
        let (b, d_b) = normalize(e)?;
        let u = b - a;
        let length = u.norm();
        if length < 1e-12 {
            return Err(Error::Degenerate("line seen end-on".into()));
        }
        let t = u / length;
        let m = Vector2::new(-t.y, t.x);
        let sign = if (m.y.atan2(m.x) - self.theta).cos() < 0.0 {
            -1.0
        } else {
            1.0
        };
        let normal = m * sign;
        let theta_pred = normal.y.atan2(normal.x);
        // d theta / d u = perp(u) / |u|^2 whatever the sign; d = sign m . a.
        let d_theta_d_b: RowVector2<f64> = m.transpose() / length;
        let p = Matrix2::new(0.0, -1.0, 1.0, 0.0);
        let lever = a.transpose() * (p - m * t.transpose()) / length;
        let d_d_d_a = (m.transpose() - lever) * sign;
        let d_d_d_b = lever * sign;

        let theta_row = [(-d_theta_d_b) * d_a, d_theta_d_b * d_b];
        let d_row = [d_d_d_a * d_a, d_d_d_b * d_b];
        let direction_only = line.active_subspaces().len() == 1;
        let rows: Vec<(f64, [slam_core::nalgebra::RowVector3<f64>; 2], usize)> = if direction_only {
            vec![(wrap_angle(theta_pred - self.theta), theta_row, 0)]
        } else {
            vec![
                (wrap_angle(theta_pred - self.theta), theta_row, 0),
                (sign * m.dot(&a) - self.d, d_row, 1),
            ]
        };
        let k = rows.len();
        let mut eta = DVector::zeros(k);
        let mut d_eta_d_xo = DMatrix::zeros(k, 6);
        let mut d_eta_d_v = DMatrix::zeros(k, 2);
        for (i, (value, [d_s, d_e], v_index)) in rows.into_iter().enumerate() {
            eta[i] = value;
            d_eta_d_xo.view_mut((i, 0), (1, 3)).copy_from(&d_s);
            d_eta_d_xo.view_mut((i, 3), (1, 3)).copy_from(&d_e);
            d_eta_d_v[(i, v_index)] = -1.0;
        }
        Ok(Innovation {
            eta,
            d_eta_d_xo,
            d_eta_d_v,
            cov_v: DMatrix::from_column_slice(2, 2, self.cov.as_slice()),
        })
    }

    fn measurement(&self) -> DVector<f64> {
        DVector::from_vec(vec![self.theta, self.d])
    }

    /// A changed `(theta, d)` moves the stored ends onto the new line.
    fn with_measurement(&self, v: &DVector<f64>) -> Result<Self> {
        if v.len() != 2 {
            return Err(Error::DimensionMismatch {
                what: "image line".into(),
                expected: 2,
                got: v.len(),
            });
        }
        ensure_finite(v.as_slice(), "image line")?;
        let normal = Vector2::new(v[0].cos(), v[0].sin());
        let onto = |q: Vector2<f64>| q + normal * (v[1] - normal.dot(&q));
        Ok(ImageLineObservation {
            theta: wrap_angle(v[0]),
            d: v[1],
            ends: [onto(self.ends[0]), onto(self.ends[1])],
            ..self.clone()
        })
    }

    /// The line where the viewing rays of the two ends meet the horizontal plane
    /// `assumed_depth` above the camera centre.
    fn initial_feature(&self, world_from_sensor: &Pose3) -> Result<Option<HLine>> {
        let rotation = world_from_sensor.rotation();
        let centre = world_from_sensor.translation;
        let height = centre.z + self.assumed_depth;
        let mut ends = [Vector3::zeros(); 2];
        for (end, q) in ends.iter_mut().zip(&self.ends) {
            let ray = rotation * Vector3::new(q.x, q.y, 1.0);
            if ray.z <= MIN_DEPTH {
                return Ok(None);
            }
            *end = centre + ray * ((height - centre.z) / ray.z);
            end.z = height;
        }
        HLine::new(ends[0], ends[1]).map(Some)
    }

    /// The line must project near the measured image line: within
    /// [`LINE_OFFSET_TOLERANCE`] in offset while its position is not estimated (a one-view
    /// line sits at an assumed depth, so its offset is only roughly right, but two parallel
    /// strips a metre apart are told apart), and its projected extent must overlap the
    /// measured segment within [`LINE_OVERLAP_MARGIN`].
    fn plausible(&self, line: &HLine, x_o: &Coordinates) -> bool {
        let [CoordBlock::Point3(s), CoordBlock::Point3(e)] = x_o.blocks() else {
            return false;
        };
        let (Ok((a, _)), Ok((b, _))) = (normalize(s), normalize(e)) else {
            return false;
        };
        let u = b - a;
        let length = u.norm();
        if length < 1e-9 {
            return false;
        }
        let t = u / length;
        let mut normal = Vector2::new(-t.y, t.x);
        if (normal.y.atan2(normal.x) - self.theta).cos() < 0.0 {
            normal = -normal;
        }
        let offset_ok =
            line.mspace_dim() >= 3 || (normal.dot(&a) - self.d).abs() <= LINE_OFFSET_TOLERANCE;
        let along = |q: &Vector2<f64>| t.dot(&(q - a));
        let (p, q) = (along(&self.ends[0]), along(&self.ends[1]));
        let overlap = p.max(q) >= -LINE_OVERLAP_MARGIN && p.min(q) <= length + LINE_OVERLAP_MARGIN;
        offset_ok && overlap
    }

    /// Grows a placed line (its position estimated) along itself to cover the measured
    /// segment: the viewing ray of each measured end meets the line's horizontal plane, and
    /// an end moves out along the line when that point lies beyond it. Each end moves a fixed
    /// distance along the line, so it turns with the line (as for a wall).
    fn extend(&self, line: &HLine, world_from_sensor: &Pose3) -> Result<Option<Extension>> {
        if line.mspace_dim() < 3 {
            return Ok(None);
        }
        let (start, end) = (line.start(), line.end());
        let horizontal = end.xy() - start.xy();
        let length = horizontal.norm();
        if length < HLine::MIN_LENGTH {
            return Ok(None);
        }
        let t2 = horizontal / length;
        let rotation = world_from_sensor.rotation();
        let centre = world_from_sensor.translation;
        let mut along = Vec::new();
        for q in &self.ends {
            let ray = rotation * Vector3::new(q.x, q.y, 1.0);
            if ray.z <= MIN_DEPTH {
                return Ok(None);
            }
            let hit = centre + ray * ((line.height() - centre.z) / ray.z);
            along.push(t2.dot(&(hit.xy() - start.xy())));
        }
        let (lo, hi) = (along[0].min(along[1]), along[0].max(along[1]));
        let a = lo.min(0.0);
        let b = (hi - length).max(0.0);
        if a == 0.0 && b == 0.0 {
            return Ok(None);
        }
        let t = Vector3::new(t2.x, t2.y, 0.0);
        let p = (Matrix3::identity() - t * t.transpose()) / length;
        let mut d_new_d_old = DMatrix::identity(6, 6);
        for (row, scale) in [(0, a), (3, b)] {
            let turn = p * scale;
            let mut block = d_new_d_old.view_mut((row, 0), (3, 3));
            block -= turn;
            let mut block = d_new_d_old.view_mut((row, 3), (3, 3));
            block += turn;
        }
        let coordinates = Coordinates::new([
            CoordBlock::Point3(start + t * a),
            CoordBlock::Point3(end + t * b),
        ])?;
        Ok(Some(Extension {
            coordinates,
            d_new_d_old,
        }))
    }

    fn revealed_subspaces(&self, line: &HLine, _x_o: &Coordinates) -> Vec<&'static str> {
        line.growth_options()
            .into_iter()
            .filter(|s| s.name == DIRECTION.name)
            .map(|s| s.name)
            .collect()
    }

    /// The horizontal line lying in every viewing plane: its direction is orthogonal to the
    /// planes' normals, its position the least-squares solution of the plane equations.
    /// Needs two planes at least [`MIN_PARALLAX`] apart (seen across the line, not along it).
    fn triangulates(&self) -> bool {
        true
    }

    fn triangulate(views: &[(Pose3, &Self)]) -> Result<Option<Triangulation<HLine>>> {
        if views.len() < 2 {
            return Ok(None);
        }
        let planes: Vec<_> = views.iter().map(|(pose, z)| z.world_plane(pose)).collect();
        // Direction: the horizontal unit vector most orthogonal to all normals.
        let mut scatter = Matrix2::zeros();
        for (normal, _) in &planes {
            let h = normal.xy();
            scatter += h * h.transpose();
        }
        let eigen = scatter.symmetric_eigen();
        let smallest = if eigen.eigenvalues[0] <= eigen.eigenvalues[1] {
            0
        } else {
            1
        };
        let direction = eigen.eigenvectors.column(smallest).into_owned();
        let direction3 = Vector3::new(direction.x, direction.y, 0.0);
        // The planes must differ by the parallax angle about the line.
        let parallax = planes
            .iter()
            .flat_map(|a| {
                planes
                    .iter()
                    .map(move |b| a.0.dot(&b.0).abs().clamp(0.0, 1.0).acos())
            })
            .fold(0.0, f64::max);
        if parallax < MIN_PARALLAX {
            return Ok(None);
        }
        // Position: N_i . p = N_i . c_i, plus direction . p = direction . mean(c).
        let mean = planes.iter().map(|(_, c)| c).sum::<Vector3<f64>>() / planes.len() as f64;
        let mut normal_matrix = direction3 * direction3.transpose();
        let mut rhs = direction3 * direction3.dot(&mean);
        for (normal, centre) in &planes {
            normal_matrix += normal * normal.transpose();
            rhs += normal * normal.dot(centre);
        }
        let Some(point) = normal_matrix.try_inverse().map(|inverse| inverse * rhs) else {
            return Ok(None);
        };
        if views
            .iter()
            .any(|(pose, _)| pose.inverse_transform_point(&point).z <= MIN_DEPTH)
        {
            return Ok(None);
        }
        // Extent: where the end rays of all views come closest to the line.
        let mut along = Vec::new();
        for (pose, z) in views {
            for q in &z.ends {
                let ray = pose.rotation() * Vector3::new(q.x, q.y, 1.0);
                along.push(closest_along_line(
                    &point,
                    &direction3,
                    &pose.translation,
                    &ray,
                ));
            }
        }
        let lo = along.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = along.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if hi - lo < HLine::MIN_LENGTH || hi.is_nan() || lo.is_nan() {
            return Ok(None);
        }
        let line = HLine::new(point + direction3 * lo, point + direction3 * hi)?;
        Ok(Some(Triangulation {
            feature: line,
            reveals: vec![DIRECTION.name, POSITION.name],
        }))
    }
}

/// Parameter along the line `point + s * direction` of its closest approach to a ray.
fn closest_along_line(
    point: &Vector3<f64>,
    direction: &Vector3<f64>,
    origin: &Vector3<f64>,
    ray: &Vector3<f64>,
) -> f64 {
    let w = point - origin;
    let (a, b, c) = (direction.dot(direction), direction.dot(ray), ray.dot(ray));
    let (d, e) = (direction.dot(&w), ray.dot(&w));
    let den = a * c - b * b;
    if den.abs() < 1e-12 {
        return -d / a;
    }
    (b * e - c * d) / den
}
