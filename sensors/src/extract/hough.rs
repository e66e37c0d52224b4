//! Ceiling lines by a standard (rho, theta) Hough transform of the bright areas' edges, the method of
//! the paper's camera experiments (Folkesson et al. 2007, section VII: "Lines were extracted
//! using the Hough Transform", with OpenCV). Selected by `line_method = "hough"` in the image
//! extractor settings ([`super::image::LineMethod::Hough`]); lamps are still found as compact
//! bright components.
//!
//! The steps, for one image:
//!
//! 1. **Voters.** The pixels of the bright components ([`super::image`]) of at least
//!    `min_area` px, except solid blobs that are too short to be lines (lamps, lamps cut by
//!    the border): see [`HoughParams::solid_fill`].
//! 2. **Accumulator.** The voters on the edge of the bright area (a dark 4-neighbour inside
//!    the image; a strip votes with its two long edges, a few times fewer votes than its whole
//!    width for the same peaks) vote: each, `p` (pixel centre, relative to the image centre),
//!    once for every angle `theta_k = k pi / n` (`n = 180 / theta_step_deg`) in the distance
//!    bin of `rho = p.x cos(theta) + p.y sin(theta)` (bins of `rho_step_px`).
//! 3. **Peaks.** Cells with at least `min_votes` votes that are the largest within
//!    `nms_theta_deg` and `nms_rho_px` (non-maximum suppression; the angle wraps at pi with
//!    `rho` negated; of equal cells the first in memory order wins), strongest first, at most
//!    `max_peaks`.
//! 4. **Support and refinement.** The voters (all, not only the edges) within `band_px` of a
//!    peak's line support it; a peak most of whose support (more than `max_shared`) belongs to
//!    lines already found is skipped (the other edge of a strip, a line across a strip). A
//!    least-squares fit of them (the intensity-weighted principal axis: total least squares,
//!    as for a component line) gives a refined line, whose band gives the support again
//!    (three rounds).
//! 5. **Segments.** The support, ordered along the refined line, is cut where two neighbours
//!    are more than `max_gap_px` apart. Each piece is fitted again and becomes an
//!    [`ImageLine`] exactly as a component line does: ends at its extent, the covariance of the
//!    normal angle and distance in normalized coordinates, `clipped` when it touches the
//!    border, and the same `min_line_length`, `min_line_elongation` and `border_margin` tests.
//!    A piece that shares more than `max_shared` of its pixels with lines of stronger peaks is
//!    the same strip seen again and is dropped.

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::Vector2;

use super::image::{ImageExtractorParams, ImageLine, Moments};
use crate::camera::{GrayImage, PinholeCamera};

/// Settings of the Hough line method: the table `hough` of the image extractor settings
/// ([`ImageExtractorParams::hough`]). Values outside the ranges of [`HoughParams::validate`]
/// are clamped into them when used.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HoughParams {
    /// Angular resolution of the accumulator, degrees (0.1 to 10).
    pub theta_step_deg: f64,
    /// Distance resolution of the accumulator, px (0.25 to 10).
    pub rho_step_px: f64,
    /// Fewest votes of a peak (an edge pixel gives one vote per angle, so a strip's edge of
    /// `L` px gets about `L` votes in its cell).
    pub min_votes: u32,
    /// Non-maximum suppression: a peak is the largest cell within this angle, degrees (0 to
    /// 45).
    pub nms_theta_deg: f64,
    /// Non-maximum suppression: a peak is the largest cell within this distance, px (0 to
    /// 100).
    pub nms_rho_px: f64,
    /// Half-width of the band around a line whose voters support it, px (0.5 to 100); wider
    /// than half a strip.
    pub band_px: f64,
    /// Largest gap between neighbouring supporting pixels along a line; a larger one cuts it
    /// in two, px (at least 1).
    pub max_gap_px: f64,
    /// Most peaks examined per image, strongest first (1 to 10,000).
    pub max_peaks: usize,
    /// A segment sharing more than this fraction of its pixels with lines already found (from
    /// stronger peaks) is dropped (0 to 1).
    pub max_shared: f64,
    /// A component too little elongated to be a line (`min_line_elongation`) that fills at
    /// least this fraction of the ellipse of its second moments is a solid blob (a lamp, a lamp
    /// cut by the border, a stub of strip) and does not vote. Crossing or touching strips fill
    /// little of their ellipse, so they vote (0 to 2; above about 1, every component votes).
    pub solid_fill: f64,
}

impl Default for HoughParams {
    fn default() -> Self {
        HoughParams {
            theta_step_deg: 1.0,
            rho_step_px: 1.0,
            min_votes: 20,
            nms_theta_deg: 3.0,
            nms_rho_px: 5.0,
            band_px: 6.0,
            max_gap_px: 5.0,
            max_peaks: 50,
            max_shared: 0.5,
            solid_fill: 0.6,
        }
    }
}

impl HoughParams {
    /// Checks that every setting is finite and in its range (see the fields).
    pub fn validate(&self) -> slam_core::Result<()> {
        let checks: [(&str, f64, f64, f64); 8] = [
            ("theta_step_deg", self.theta_step_deg, 0.1, 10.0),
            ("rho_step_px", self.rho_step_px, 0.25, 10.0),
            ("nms_theta_deg", self.nms_theta_deg, 0.0, 45.0),
            ("nms_rho_px", self.nms_rho_px, 0.0, 100.0),
            ("band_px", self.band_px, 0.5, 100.0),
            ("max_gap_px", self.max_gap_px, 1.0, f64::MAX),
            ("max_shared", self.max_shared, 0.0, 1.0),
            ("solid_fill", self.solid_fill, 0.0, 2.0),
        ];
        for (name, value, lo, hi) in checks {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(slam_core::Error::InvalidArgument(format!(
                    "hough.{name} = {value} must be finite, from {lo} to {hi}"
                )));
            }
        }
        if !(1..=10_000).contains(&self.max_peaks) {
            return Err(slam_core::Error::InvalidArgument(format!(
                "hough.max_peaks = {} must be from 1 to 10000",
                self.max_peaks
            )));
        }
        Ok(())
    }
}

/// Clamps `value` into `lo..=hi`; not finite gives `fallback`.
fn clamped(value: f64, lo: f64, hi: f64, fallback: f64) -> f64 {
    if value.is_finite() {
        value.clamp(lo, hi)
    } else {
        fallback
    }
}

/// The (rho, theta) accumulator of a set of pixels.
struct Accumulator {
    /// `(cos, sin)` of each angle `k pi / n`.
    angles: Vec<(f64, f64)>,
    /// Distance bin width, px.
    rho_step: f64,
    /// Bin of `rho = 0`; there are `2 offset + 1` bins.
    offset: usize,
    /// Votes, row `k` (angle) by column (distance bin).
    votes: Vec<u32>,
}

impl Accumulator {
    fn bins(&self) -> usize {
        2 * self.offset + 1
    }

    /// Every point votes once per angle. `points` are relative to the image centre, so
    /// `|rho|` is at most `half_diagonal`.
    fn new(
        points: &[Vector2<f64>],
        theta_step_deg: f64,
        rho_step: f64,
        half_diagonal: f64,
    ) -> Self {
        let n = (180.0 / theta_step_deg).round().max(1.0) as usize;
        let angles = (0..n)
            .map(|k| {
                let theta = k as f64 * std::f64::consts::PI / n as f64;
                (theta.cos(), theta.sin())
            })
            .collect::<Vec<_>>();
        let offset = (half_diagonal / rho_step).ceil() as usize + 1;
        let bins = 2 * offset + 1;
        let mut votes = vec![0u32; n * bins];
        // `rho / rho_step + offset + 0.5` is positive, so truncation rounds it.
        let (scale, shift) = (1.0 / rho_step, offset as f64 + 0.5);
        for (row, &(c, s)) in votes.chunks_exact_mut(bins).zip(&angles) {
            let (c, s) = (c * scale, s * scale);
            for p in points {
                let bin = (p.x * c + p.y * s + shift) as usize;
                if let Some(cell) = row.get_mut(bin) {
                    *cell += 1;
                }
            }
        }
        Accumulator {
            angles,
            rho_step,
            offset,
            votes,
        }
    }

    /// The cell `(k + dk, b + db)`, across the wrap of the angle at pi (where `rho` changes
    /// sign), or `None` beyond the distance bins.
    fn neighbour(&self, k: usize, b: usize, dk: isize, db: isize) -> Option<usize> {
        let (n, bins) = (self.angles.len() as isize, self.bins() as isize);
        let (mut kk, mut bb) = (k as isize + dk, b as isize + db);
        if kk < 0 || kk >= n {
            kk = kk.rem_euclid(n);
            bb = bins - 1 - bb;
        }
        (0..bins).contains(&bb).then(|| (kk * bins + bb) as usize)
    }

    /// Cells with at least `min_votes` that are the largest within `wk` angles and `wb`
    /// distance bins (ties: the first in memory order), as `(votes, cell)`, strongest first.
    fn peaks(&self, min_votes: u32, wk: usize, wb: usize, most: usize) -> Vec<(u32, usize)> {
        let bins = self.bins();
        let (wk, wb) = (wk.min(self.angles.len() / 2) as isize, wb as isize);
        let mut peaks = Vec::new();
        for (cell, &v) in self.votes.iter().enumerate() {
            if v < min_votes.max(1) {
                continue;
            }
            let (k, b) = (cell / bins, cell % bins);
            let beaten = (-wk..=wk).any(|dk| {
                (-wb..=wb).any(|db| {
                    self.neighbour(k, b, dk, db).is_some_and(|other| {
                        let u = self.votes[other];
                        other != cell && (u > v || (u == v && other < cell))
                    })
                })
            });
            if !beaten {
                peaks.push((v, cell));
            }
        }
        peaks.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        peaks.truncate(most);
        peaks
    }

    /// The unit normal and distance (px, from the image centre) of a cell's line.
    fn line(&self, cell: usize) -> (Vector2<f64>, f64) {
        let bins = self.bins();
        let (c, s) = self.angles[cell / bins];
        let rho = ((cell % bins) as f64 - self.offset as f64) * self.rho_step;
        (Vector2::new(c, s), rho)
    }
}

/// The ceiling lines through `voters` (pixels of `image`) by the Hough transform: the steps of
/// the [module documentation](self). Used by [`super::image::extract_image_features`] with
/// `line_method = "hough"`.
pub(super) fn lines_from_voters(
    voters: &[(i64, i64)],
    image: &GrayImage,
    camera: &PinholeCamera,
    params: &ImageExtractorParams,
) -> Vec<ImageLine> {
    let h = &params.hough;
    let defaults = HoughParams::default();
    let theta_step = clamped(h.theta_step_deg, 0.1, 10.0, defaults.theta_step_deg);
    let rho_step = clamped(h.rho_step_px, 0.25, 10.0, defaults.rho_step_px);
    let band = clamped(h.band_px, 0.5, 100.0, defaults.band_px);
    let max_gap = clamped(h.max_gap_px, 1.0, f64::MAX, defaults.max_gap_px);
    let max_shared = clamped(h.max_shared, 0.0, 1.0, defaults.max_shared);
    let wk = (clamped(h.nms_theta_deg, 0.0, 45.0, defaults.nms_theta_deg) / theta_step).round();
    let wb = (clamped(h.nms_rho_px, 0.0, 100.0, defaults.nms_rho_px) / rho_step).round();
    if voters.is_empty() {
        return Vec::new();
    }
    let half = Vector2::new(f64::from(image.width), f64::from(image.height)) * 0.5;
    let points = voters
        .iter()
        .map(|&(x, y)| Vector2::new(x as f64 + 0.5, y as f64 + 0.5) - half)
        .collect::<Vec<_>>();
    // Only the edge pixels vote: a bright pixel with a dark 4-neighbour in the image.
    let dark = |x: i64, y: i64| image.get(x, y).is_some_and(|v| v < params.threshold);
    let edges = voters
        .iter()
        .zip(&points)
        .filter(|&(&(x, y), _)| {
            dark(x - 1, y) || dark(x + 1, y) || dark(x, y - 1) || dark(x, y + 1)
        })
        .map(|(_, p)| *p)
        .collect::<Vec<_>>();
    let accumulator = Accumulator::new(&edges, theta_step, rho_step, half.norm());
    let peaks = accumulator.peaks(
        h.min_votes,
        wk as usize,
        wb as usize,
        h.max_peaks.clamp(1, 10_000),
    );
    let within = |normal: &Vector2<f64>, rho: f64| -> Vec<usize> {
        (0..points.len())
            .filter(|&i| (normal.dot(&points[i]) - rho).abs() <= band)
            .collect()
    };
    let pixels = |indices: &[usize]| indices.iter().map(|&i| voters[i]).collect::<Vec<_>>();
    let smallest = params.min_area.max(2);
    let mut claimed = vec![false; voters.len()];
    let mut lines = Vec::new();
    for (_, cell) in peaks {
        let (normal, rho) = accumulator.line(cell);
        let mut support = within(&normal, rho);
        // Mostly pixels of lines already found: the other edge of a strip, or a line across
        // a strip (the wings of its peak).
        let shared = support.iter().filter(|&&i| claimed[i]).count();
        if shared as f64 > max_shared * support.len() as f64 {
            continue;
        }
        // Least-squares refinement: the principal axis of the support, then its band again.
        let mut fit = None;
        for _ in 0..3 {
            if support.len() < smallest {
                break;
            }
            let moments = Moments::of(image, &pixels(&support));
            if !(moments.centre.x.is_finite() && moments.centre.y.is_finite()) {
                break;
            }
            let normal = Vector2::new(-moments.major.y, moments.major.x);
            support = within(&normal, normal.dot(&(moments.centre - half)));
            fit = Some(moments);
        }
        let Some(fit) = fit else { continue };
        if support.len() < smallest {
            continue;
        }
        // Pieces along the line, cut at gaps.
        let along = |i: &usize| fit.major.dot(&(points[*i] + half - fit.centre));
        let mut ordered = support.iter().map(|i| (along(i), *i)).collect::<Vec<_>>();
        ordered.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut start = 0;
        for end in 1..=ordered.len() {
            if end < ordered.len() && ordered[end].0 - ordered[end - 1].0 <= max_gap {
                continue;
            }
            let piece = ordered[start..end]
                .iter()
                .map(|&(_, i)| i)
                .collect::<Vec<_>>();
            start = end;
            if piece.len() < smallest {
                continue;
            }
            let shared = piece.iter().filter(|&&i| claimed[i]).count();
            if shared as f64 > max_shared * piece.len() as f64 {
                continue;
            }
            let piece_pixels = pixels(&piece);
            let moments = Moments::of(image, &piece_pixels);
            let elongation = (moments.lambda_major / moments.lambda_minor.max(1e-9)).sqrt();
            // A NaN elongation (all weights zero) is not a line either.
            if elongation.is_nan() || elongation < params.min_line_elongation {
                continue;
            }
            if let Some(line) = moments.line(&piece_pixels, image, camera, params) {
                for &i in &piece {
                    claimed[i] = true;
                }
                lines.push(line);
            }
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strip_points(from: Vector2<f64>, to: Vector2<f64>) -> Vec<Vector2<f64>> {
        let steps = (to - from).norm().ceil() as usize;
        (0..=steps)
            .map(|i| from + (to - from) * (i as f64 / steps as f64))
            .collect()
    }

    #[test]
    fn a_thin_line_peaks_at_its_angle_and_distance() {
        // The line x cos 30 + y sin 30 = 20 (relative to the centre), 100 px long.
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let foot = Vector2::new(c, s) * 20.0;
        let along = Vector2::new(-s, c);
        let points = strip_points(foot - along * 50.0, foot + along * 50.0);
        let accumulator = Accumulator::new(&points, 1.0, 1.0, 200.0);
        let peaks = accumulator.peaks(20, 3, 5, 10);
        assert_eq!(peaks.len(), 1, "{peaks:?}");
        let (normal, rho) = accumulator.line(peaks[0].1);
        assert!((normal.y.atan2(normal.x).to_degrees() - 30.0).abs() < 0.6);
        assert!((rho - 20.0).abs() <= 1.0);
        assert!(peaks[0].0 >= 90);
    }

    #[test]
    fn suppression_wraps_at_pi() {
        // A nearly vertical line in the image: theta near 0 and near 180 degrees are the same
        // line with rho negated; one peak only.
        let points = strip_points(Vector2::new(-10.0, -60.0), Vector2::new(-10.5, 60.0));
        let accumulator = Accumulator::new(&points, 1.0, 1.0, 200.0);
        let peaks = accumulator.peaks(20, 3, 5, 10);
        assert_eq!(peaks.len(), 1, "{peaks:?}");
    }

    #[test]
    fn settings_out_of_range_are_reported() {
        assert!(HoughParams::default().validate().is_ok());
        let bad = HoughParams {
            theta_step_deg: 0.0,
            ..HoughParams::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("theta_step_deg"), "{e}");
        let nan = HoughParams {
            band_px: f64::NAN,
            ..HoughParams::default()
        };
        assert!(nan.validate().is_err());
        let none = HoughParams {
            max_peaks: 0,
            ..HoughParams::default()
        };
        assert!(none.validate().is_err());
    }
}
