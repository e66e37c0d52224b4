//! Scan -> poles: free-standing clusters fitted with circles.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Matrix3, Vector2, Vector3};

use crate::models::PoleObservation;
use crate::scan::{LaserScan, ScanPoint};

use super::{Neighbour, clusters, far_or_unknown};

/// Settings of [`extract_poles`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoleExtractorParams {
    /// Standard deviation of a range reading, m.
    pub sigma_range: f64,
    /// Consecutive points farther apart than `max_gap + gap_per_metre * range` start a new
    /// cluster, m.
    pub max_gap: f64,
    /// See `max_gap`, m per m of range.
    pub gap_per_metre: f64,
    /// Fewest points on a pole.
    pub min_points: usize,
    /// Smallest radius accepted, m.
    pub min_radius: f64,
    /// Largest radius accepted, m.
    pub max_radius: f64,
    /// Both neighbouring readings must lie at least this much farther than the cluster (it
    /// stands free), m.
    pub min_jump: f64,
    /// Largest RMS distance of the points from the fitted circle, in units of `sigma_range`.
    pub max_rms: f64,
    /// Largest standard deviation of the fitted radius, m: arcs too short or too noisy to
    /// give the radius are not poles.
    pub max_radius_sigma: f64,
}

impl Default for PoleExtractorParams {
    fn default() -> Self {
        PoleExtractorParams {
            sigma_range: 0.02,
            max_gap: 0.1,
            gap_per_metre: 0.03,
            min_points: 4,
            min_radius: 0.02,
            max_radius: 0.8,
            min_jump: 0.5,
            max_rms: 3.0,
            max_radius_sigma: 0.02,
        }
    }
}

/// A pole found in a scan, in the sensor frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtractedPole {
    /// Centre, m.
    pub centre: Vector2<f64>,
    /// Radius, m.
    pub radius: f64,
    /// Covariance of `(centre x, centre y, radius)`.
    pub cov: Matrix3<f64>,
    /// Beam indices of the first and last point.
    pub beams: [usize; 2],
    /// Number of points.
    pub points: usize,
}

impl ExtractedPole {
    /// The [`PoleObservation`] of this pole: range and bearing of the centre and the radius,
    /// with deviations from the fit's covariance (at least `floor` metres, or the angle `floor`
    /// subtends at the pole for the bearing).
    pub fn to_observation(&self, floor: f64) -> slam_core::Result<PoleObservation> {
        let c = self.centre;
        let d = c.norm();
        let jacobian = Matrix3::new(
            c.x / d,
            c.y / d,
            0.0,
            -c.y / (d * d),
            c.x / (d * d),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        let polar = jacobian * self.cov * jacobian.transpose();
        let sigma = |k: usize| polar[(k, k)].max(0.0).sqrt();
        let sigmas = [
            sigma(0).max(floor),
            sigma(1).max(floor / d),
            sigma(2).max(floor),
        ];
        PoleObservation::new(d, c.y.atan2(c.x), self.radius, sigmas)
    }
}

/// Poles of a scan: clusters standing free of their surroundings (both neighbouring readings
/// much farther, or no return), fitted with a circle (algebraic fit refined by Gauss-Newton on
/// the geometric distances), whose centre lies beyond the points, whose radius is within
/// bounds and determined to `max_radius_sigma`. Invalid readings are skipped.
pub fn extract_poles(scan: &LaserScan, params: &PoleExtractorParams) -> Vec<ExtractedPole> {
    let points = scan.points();
    clusters(&points, scan, params.max_gap, params.gap_per_metre)
        .into_iter()
        .filter(|&(a, b)| b + 1 - a >= params.min_points)
        .filter(|&(a, b)| stands_free(scan, &points[a], &points[b], params.min_jump))
        .filter_map(|(a, b)| fit_pole(&points[a..=b], params))
        .collect()
}

fn stands_free(scan: &LaserScan, first: &ScanPoint, last: &ScanPoint, min_jump: f64) -> bool {
    let reach = first.range.max(last.range) + min_jump;
    let free = |beam: Option<usize>| match beam.map(|b| far_or_unknown(scan, b)) {
        Some(Neighbour::Range(r)) => r > reach,
        Some(Neighbour::NoReturn) => true,
        _ => false,
    };
    free(first.index.checked_sub(1)) && free(Some(last.index + 1))
}

fn fit_pole(points: &[ScanPoint], params: &PoleExtractorParams) -> Option<ExtractedPole> {
    let (mut centre, mut radius) = algebraic_circle(points)?;
    for _ in 0..20 {
        let (step, _) = gauss_newton_step(points, &centre, radius)?;
        centre += Vector2::new(step.x, step.y);
        radius += step.z;
        if step.norm() < 1e-10 {
            break;
        }
    }
    let (_, normal) = gauss_newton_step(points, &centre, radius)?;
    let rms = (points
        .iter()
        .map(|p| ((p.position - centre).norm() - radius).powi(2))
        .sum::<f64>()
        / points.len() as f64)
        .sqrt();
    let mean_range = points.iter().map(|p| p.range).sum::<f64>() / points.len() as f64;
    let plausible = radius >= params.min_radius
        && radius <= params.max_radius
        && centre.norm() > mean_range
        && rms <= params.max_rms * params.sigma_range;
    if !plausible {
        return None;
    }
    let cov = normal.try_inverse()? * params.sigma_range.powi(2);
    if cov[(2, 2)].sqrt() > params.max_radius_sigma {
        return None;
    }
    Some(ExtractedPole {
        centre,
        radius,
        cov,
        beams: [points.first()?.index, points.last()?.index],
        points: points.len(),
    })
}

/// Kasa's fit: least squares of `x^2 + y^2 + D x + E y + F = 0`.
fn algebraic_circle(points: &[ScanPoint]) -> Option<(Vector2<f64>, f64)> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for p in points {
        let row = Vector3::new(p.position.x, p.position.y, 1.0);
        a += row * row.transpose();
        b -= row * p.position.norm_squared();
    }
    let s = a.try_inverse()? * b;
    let centre = Vector2::new(-s.x / 2.0, -s.y / 2.0);
    let r2 = centre.norm_squared() - s.z;
    (r2 > 0.0).then(|| (centre, r2.sqrt()))
}

/// One Gauss-Newton step on `|p - c| - r`, and the normal matrix `J^T J`.
fn gauss_newton_step(
    points: &[ScanPoint],
    centre: &Vector2<f64>,
    radius: f64,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let mut normal = Matrix3::zeros();
    let mut gradient = Vector3::zeros();
    for p in points {
        let d = p.position - centre;
        let distance = d.norm();
        if distance < 1e-12 {
            return None;
        }
        let j = Vector3::new(-d.x / distance, -d.y / distance, -1.0);
        let residual = distance - radius;
        normal += j * j.transpose();
        gradient += j * residual;
    }
    let step = -(normal.try_inverse()? * gradient);
    step.iter().all(|v| v.is_finite()).then_some((step, normal))
}
