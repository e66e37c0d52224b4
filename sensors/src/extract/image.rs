//! Ceiling image -> lines and lamps: bright connected components of an upward camera image,
//! elongated ones as ceiling lines, compact ones as lamps. The lines can instead be found by a
//! Hough transform of the bright pixels, as in the paper's camera experiments (section VII:
//! "Lines were extracted using the Hough Transform"): [`LineMethod::Hough`], see
//! [`super::hough`].

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{Matrix2, Vector2};

use super::hough::{HoughParams, lines_from_voters};
use crate::camera::{GrayImage, PinholeCamera};
use crate::models::{ImageLineObservation, ImagePointObservation};

/// How [`extract_image_features`] finds ceiling lines. Lamps are found the same way by both.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LineMethod {
    /// Each elongated bright component is one line (`"components"`, the default).
    #[default]
    Components,
    /// Peaks of a (rho, theta) Hough transform of the bright pixels, each refined by a
    /// least-squares fit of the pixels that support it (`"hough"`; settings in
    /// [`ImageExtractorParams::hough`]).
    Hough,
}

/// Settings of [`extract_image_features`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImageExtractorParams {
    /// Pixels at or above this intensity are bright.
    pub threshold: u8,
    /// Smallest bright component kept, px.
    pub min_area: usize,
    /// Components at least this elongated (ratio of principal standard deviations) are lines.
    pub min_line_elongation: f64,
    /// Components at most this elongated are lamps.
    pub max_lamp_elongation: f64,
    /// Shortest line kept, px.
    pub min_line_length: f64,
    /// Standard deviation of a pixel position across a line or of a lamp centre, px.
    pub sigma_px: f64,
    /// Lines whose two ends lie within this distance of the same image edge are dropped: a
    /// lamp or strip cut by the edge leaves such a sliver, which is not a line, px.
    pub border_margin: f64,
    /// Deviation of the error that pixel quantization leaves in a line's position, shared by
    /// all its pixels (a strip aligned with the pixel grid keeps it along its whole length),
    /// px. It adds `2 q^2 / L^2` to the normal angle's variance and `q^2` to the shift's, for
    /// a line of `L` px.
    pub quantization_px: f64,
    /// How lines are found (`line_method = "components"` or `"hough"`).
    pub line_method: LineMethod,
    /// Settings of the Hough line method (used when `line_method = "hough"`).
    pub hough: HoughParams,
}

impl Default for ImageExtractorParams {
    fn default() -> Self {
        ImageExtractorParams {
            threshold: 128,
            min_area: 6,
            min_line_elongation: 4.0,
            max_lamp_elongation: 1.8,
            min_line_length: 15.0,
            sigma_px: 0.7,
            border_margin: 4.0,
            quantization_px: 0.1,
            line_method: LineMethod::Components,
            hough: HoughParams::default(),
        }
    }
}

/// A line found in an image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageLine {
    /// Its two ends, px.
    pub ends: [Vector2<f64>; 2],
    /// Covariance of its normal angle and distance in normalized image coordinates.
    pub cov: Matrix2<f64>,
    /// Whether it touches the image border (its ends are cut by the field of view).
    pub clipped: bool,
}

/// A compact bright blob (a lamp) found in an image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageBlob {
    /// Intensity-weighted centre, px.
    pub centre: Vector2<f64>,
    /// Area, px.
    pub area: usize,
}

/// What one image shows.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageFeatures {
    /// Ceiling lines.
    pub lines: Vec<ImageLine>,
    /// Lamps.
    pub lamps: Vec<ImageBlob>,
}

impl ImageFeatures {
    /// The features as measurements: lines of [`slam_features::HLine`]s, lamps of
    /// [`slam_features::Point`]s; one-view features are placed `assumed_depth` above the
    /// camera.
    pub fn observations(
        &self,
        camera: &PinholeCamera,
        params: &ImageExtractorParams,
        assumed_depth: f64,
    ) -> slam_core::Result<(Vec<ImageLineObservation>, Vec<ImagePointObservation>)> {
        let lines = self
            .lines
            .iter()
            .map(|l| {
                let ends = [camera.normalized(&l.ends[0]), camera.normalized(&l.ends[1])];
                ImageLineObservation::from_ends(ends, l.cov, *camera, assumed_depth)
            })
            .collect::<slam_core::Result<Vec<_>>>()?;
        let lamps = self
            .lamps
            .iter()
            .map(|b| ImagePointObservation::new(b.centre, params.sigma_px, *camera, assumed_depth))
            .collect::<slam_core::Result<Vec<_>>>()?;
        Ok((lines, lamps))
    }
}

/// Bright components of `image` classified as lines (elongated: a total-least-squares line
/// through their pixels, ends at their extent) and lamps (compact: their weighted centre).
/// With [`LineMethod::Hough`], the lines come instead from a Hough transform of the pixels of
/// the components that are not solid blobs ([`super::hough`]); the lamps are the same.
pub fn extract_image_features(
    image: &GrayImage,
    camera: &PinholeCamera,
    params: &ImageExtractorParams,
) -> ImageFeatures {
    let mut features = ImageFeatures::default();
    let hough = params.line_method == LineMethod::Hough;
    let mut voters = Vec::new();
    for component in components(image, params.threshold) {
        if component.len() < params.min_area {
            continue;
        }
        let moments = Moments::of(image, &component);
        let elongation = (moments.lambda_major / moments.lambda_minor.max(1e-9)).sqrt();
        if elongation >= params.min_line_elongation {
            if hough {
                voters.extend_from_slice(&component);
            } else if let Some(line) = moments.line(&component, image, camera, params) {
                features.lines.push(line);
            }
        } else {
            if elongation <= params.max_lamp_elongation && !touches_border(image, &component) {
                // A lamp cut by the image border has its centroid pulled inwards.
                features.lamps.push(ImageBlob {
                    centre: moments.centre,
                    area: component.len(),
                });
            }
            if hough && !moments.is_solid(component.len(), params.hough.solid_fill) {
                // Not elongated but not solid either: strips that cross or touch.
                voters.extend_from_slice(&component);
            }
        }
    }
    if hough {
        features.lines = lines_from_voters(&voters, image, camera, params);
    }
    features
}

/// 8-connected components of pixels at or above `threshold`, as pixel lists.
fn components(image: &GrayImage, threshold: u8) -> Vec<Vec<(i64, i64)>> {
    let (w, h) = (image.width as i64, image.height as i64);
    let mut seen = vec![false; image.data.len()];
    let mut out = Vec::new();
    for start in 0..image.data.len() {
        if seen[start] || image.data[start] < threshold {
            continue;
        }
        seen[start] = true;
        let mut stack = vec![(start as i64 % w, start as i64 / w)];
        let mut pixels = Vec::new();
        while let Some((x, y)) = stack.pop() {
            pixels.push((x, y));
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w || ny >= h {
                        continue;
                    }
                    let k = (ny * w + nx) as usize;
                    if !seen[k] && image.data[k] >= threshold {
                        seen[k] = true;
                        stack.push((nx, ny));
                    }
                }
            }
        }
        out.push(pixels);
    }
    out
}

/// Intensity-weighted first and second moments of a component.
pub(super) struct Moments {
    /// Weighted centre, px.
    pub(super) centre: Vector2<f64>,
    /// Unit direction of the major axis.
    pub(super) major: Vector2<f64>,
    /// Variance along the major axis, px^2.
    pub(super) lambda_major: f64,
    /// Variance along the minor axis (at least 1/12: one pixel), px^2.
    pub(super) lambda_minor: f64,
}

impl Moments {
    pub(super) fn of(image: &GrayImage, pixels: &[(i64, i64)]) -> Self {
        let weight = |x: i64, y: i64| image.get(x, y).map_or(0.0, f64::from);
        let total: f64 = pixels.iter().map(|&(x, y)| weight(x, y)).sum();
        let centre = pixels
            .iter()
            .map(|&(x, y)| Vector2::new(x as f64 + 0.5, y as f64 + 0.5) * weight(x, y))
            .sum::<Vector2<f64>>()
            / total;
        let mut scatter = Matrix2::zeros();
        for &(x, y) in pixels {
            let q = Vector2::new(x as f64 + 0.5, y as f64 + 0.5) - centre;
            scatter += q * q.transpose() * weight(x, y);
        }
        scatter /= total;
        let eigen = scatter.symmetric_eigen();
        let (major, minor) = if eigen.eigenvalues[0] >= eigen.eigenvalues[1] {
            (0, 1)
        } else {
            (1, 0)
        };
        Moments {
            centre,
            major: eigen.eigenvectors.column(major).into_owned(),
            lambda_major: eigen.eigenvalues[major],
            lambda_minor: eigen.eigenvalues[minor].max(1.0 / 12.0),
        }
    }

    /// The line through the component: its extent along the major axis, and the covariance of
    /// its normal form in normalized coordinates for `n` pixels with `sigma_px` across.
    pub(super) fn line(
        &self,
        pixels: &[(i64, i64)],
        image: &GrayImage,
        camera: &PinholeCamera,
        params: &ImageExtractorParams,
    ) -> Option<ImageLine> {
        let along = |&(x, y): &(i64, i64)| {
            (Vector2::new(x as f64 + 0.5, y as f64 + 0.5) - self.centre).dot(&self.major)
        };
        let lo = pixels.iter().map(along).fold(f64::INFINITY, f64::min);
        let hi = pixels.iter().map(along).fold(f64::NEG_INFINITY, f64::max);
        let length = hi - lo;
        if length < params.min_line_length {
            return None;
        }
        let ends = [self.centre + self.major * lo, self.centre + self.major * hi];
        if along_one_edge(&ends, image, params.border_margin) {
            return None;
        }
        let clipped = touches_border(image, pixels);
        // Normal-form covariance for pixels spread evenly over `length` with deviation sigma
        // across the line (one effective point per pixel of length), in normalized units:
        // a rotation about the centre (var 12 sigma^2 / (n L^2)) and a shift across
        // (var sigma^2 / n); d = n . x moves with the rotation by perp(n) . centre.
        let n_eff = length.max(2.0);
        let f = 0.5 * (camera.fx + camera.fy);
        let sigma = params.sigma_px / f;
        let q = params.quantization_px / f;
        let length_normalized = length / f;
        let var_theta = 12.0 * sigma * sigma / (n_eff * length_normalized.powi(2))
            + 2.0 * q * q / length_normalized.powi(2);
        let var_shift = sigma * sigma / n_eff + q * q;
        let (a, b) = (camera.normalized(&ends[0]), camera.normalized(&ends[1]));
        let u = (b - a).normalize();
        let mut normal = Vector2::new(-u.y, u.x);
        if normal.dot(&a) < 0.0 {
            normal = -normal;
        }
        let k = Vector2::new(-normal.y, normal.x).dot(&camera.normalized(&self.centre));
        let cov = Matrix2::new(
            var_theta,
            var_theta * k,
            var_theta * k,
            var_shift + var_theta * k * k,
        );
        Some(ImageLine { ends, cov, clipped })
    }

    /// Whether `area` pixels with these moments fill at least `min_fill` of the ellipse of
    /// the same second moments (area `4 pi sqrt(lambda_major lambda_minor)`): about 0.95-1
    /// for a disc, a half disc or a rectangle, about `4 w / L` for two strips of width `w`
    /// and length `L` that cross.
    pub(super) fn is_solid(&self, area: usize, min_fill: f64) -> bool {
        let ellipse = 4.0 * std::f64::consts::PI * (self.lambda_major * self.lambda_minor).sqrt();
        area as f64 >= min_fill * ellipse
    }
}

/// Whether any of `pixels` lies on the border of `image`.
pub(super) fn touches_border(image: &GrayImage, pixels: &[(i64, i64)]) -> bool {
    pixels.iter().any(|&(x, y)| {
        x == 0 || y == 0 || x + 1 == i64::from(image.width) || y + 1 == i64::from(image.height)
    })
}

/// Whether both `ends` lie within `margin` px of the same edge of `image`.
pub(super) fn along_one_edge(ends: &[Vector2<f64>; 2], image: &GrayImage, margin: f64) -> bool {
    let (w, h) = (f64::from(image.width), f64::from(image.height));
    let near = |distance: fn(&Vector2<f64>, f64, f64) -> f64| {
        ends.iter().all(|e| distance(e, w, h) <= margin)
    };
    near(|e, _, _| e.x) || near(|e, w, _| w - e.x) || near(|e, _, _| e.y) || near(|e, _, h| h - e.y)
}
