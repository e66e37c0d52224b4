//! Ceiling lines found in camera images scored against the true ceiling lines of a simulated
//! world ([`ImageLineScore`]): which found lines match a true one, which visible true lines
//! are missed, the angle and offset errors and the NEES of the matching lines' covariances.
//! `slam camera --compare` uses it to compare the line methods of the image front-end.

use slam_core::nalgebra::{Matrix2, Vector2};
use slam_core::{Pose3, wrap_angle};
use slam_sensors::camera::PinholeCamera;
use slam_sensors::extract::image::ImageLine;
use slam_sensors::sim::TrueMap;

/// A found line matches a true line when both its ends lie within this distance across the
/// true line's projection, px.
pub const MATCH_ACROSS_PX: f64 = 3.0;
/// ... and within this distance beyond the projected ends along it (a strip's bright area
/// reaches half its width, 3-3.5 px, beyond its ends), px.
pub const MATCH_ALONG_PX: f64 = 8.0;
/// ... and its direction is within this angle of the projection's, degrees.
pub const MATCH_DEG: f64 = 3.0;
/// A true line counts as visible (and as missed when no found line matches it) when at least
/// this much of its projection lies inside the image, px (twice the default
/// `min_line_length`).
pub const VISIBLE_PX: f64 = 30.0;

/// A true ceiling line projected into one image.
pub struct TrueLine {
    /// Its projected ends, px (they may lie outside the image).
    pub ends: [Vector2<f64>; 2],
    /// Length of the part inside the image, px.
    pub visible: f64,
}

/// The true ceiling lines of `truth` as the camera at `world_from_camera` sees them (those
/// with both ends in front of it).
pub fn true_lines(
    truth: &TrueMap,
    world_from_camera: &Pose3,
    camera: &PinholeCamera,
) -> Vec<TrueLine> {
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    truth
        .ceiling_lines
        .iter()
        .filter_map(|(a, b)| {
            let (pa, _) = camera
                .project(&world_from_camera.inverse_transform_point(a))
                .ok()?;
            let (pb, _) = camera
                .project(&world_from_camera.inverse_transform_point(b))
                .ok()?;
            Some(TrueLine {
                ends: [pa, pb],
                visible: clipped_length(&pa, &pb, w, h),
            })
        })
        .collect()
}

/// Length of the part of the segment `a`-`b` inside `[0, w] x [0, h]` (Liang-Barsky).
pub fn clipped_length(a: &Vector2<f64>, b: &Vector2<f64>, w: f64, h: f64) -> f64 {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-d.x, a.x), (d.x, w - a.x), (-d.y, a.y), (d.y, h - a.y)] {
        if p == 0.0 {
            if q < 0.0 {
                return 0.0;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    if t1 > t0 { (t1 - t0) * d.norm() } else { 0.0 }
}

/// The angle error (degrees) and the distance of the midpoint from the true line (px) when
/// `line` matches `truth` ([`MATCH_ACROSS_PX`], [`MATCH_ALONG_PX`], [`MATCH_DEG`]).
pub fn match_error(line: &ImageLine, truth: &TrueLine) -> Option<(f64, f64)> {
    let [a, b] = truth.ends;
    let length = (b - a).norm();
    if length < 1e-9 {
        return None;
    }
    let d = (b - a) / length;
    let n = Vector2::new(-d.y, d.x);
    let e = (line.ends[1] - line.ends[0]).try_normalize(1e-12)?;
    let angle = d.dot(&e).abs().min(1.0).acos().to_degrees();
    let ends_ok = line.ends.iter().all(|q| {
        let along = d.dot(&(q - a));
        n.dot(&(q - a)).abs() <= MATCH_ACROSS_PX
            && along >= -MATCH_ALONG_PX
            && along <= length + MATCH_ALONG_PX
    });
    let middle = 0.5 * (line.ends[0] + line.ends[1]);
    (ends_ok && angle <= MATCH_DEG).then(|| (angle, n.dot(&(middle - a)).abs()))
}

/// The normal form `(angle, distance)` in normalized coordinates of the line through the
/// normalized points `a`, `b`, with the convention of [`ImageLine::cov`]: the normal points
/// away from the principal point (`n . a >= 0`).
fn normal_form(a: &Vector2<f64>, b: &Vector2<f64>) -> Option<(Vector2<f64>, f64)> {
    let u = (b - a).try_normalize(1e-12)?;
    let mut normal = Vector2::new(-u.y, u.x);
    if normal.dot(a) < 0.0 {
        normal = -normal;
    }
    Some((normal, normal.dot(a)))
}

/// The normalized squared error of `line`'s normal form against the true line's under
/// `line.cov` (2 on average when the covariance is right).
fn nees(line: &ImageLine, truth: &TrueLine, camera: &PinholeCamera) -> Option<f64> {
    let (found_n, found_d) = normal_form(
        &camera.normalized(&line.ends[0]),
        &camera.normalized(&line.ends[1]),
    )?;
    let (mut true_n, mut true_d) = normal_form(
        &camera.normalized(&truth.ends[0]),
        &camera.normalized(&truth.ends[1]),
    )?;
    if found_n.dot(&true_n) < 0.0 {
        (true_n, true_d) = (-true_n, -true_d);
    }
    let error = Vector2::new(
        wrap_angle(found_n.y.atan2(found_n.x) - true_n.y.atan2(true_n.x)),
        found_d - true_d,
    );
    let information: Matrix2<f64> = line.cov.try_inverse()?;
    Some(error.dot(&(information * error)))
}

/// What one line method found over a set of images, against the truth.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageLineScore {
    /// Images scored.
    pub images: usize,
    /// Lines found.
    pub found: usize,
    /// Found lines that match a true line.
    pub matching: usize,
    /// Visible true lines ([`VISIBLE_PX`]).
    pub visible: usize,
    /// Visible true lines that a found line matches.
    pub detected: usize,
    /// Sum of the matching lines' angle errors, degrees.
    pub angle_sum: f64,
    /// Sum of the matching lines' midpoint offsets from the true lines, px.
    pub offset_sum: f64,
    /// Sum of the matching lines' NEES (normal angle and distance, 2 dof).
    pub nees_sum: f64,
    /// Matching lines with a NEES (an invertible covariance).
    pub nees_count: usize,
}

impl ImageLineScore {
    /// Adds the lines found in one image whose true lines (as the camera saw them) are
    /// `truths`.
    pub fn add(&mut self, lines: &[ImageLine], truths: &[TrueLine], camera: &PinholeCamera) {
        self.images += 1;
        self.found += lines.len();
        let mut seen = vec![false; truths.len()];
        for line in lines {
            let best = truths
                .iter()
                .enumerate()
                .filter_map(|(i, t)| match_error(line, t).map(|e| (i, e)))
                .min_by(|x, y| x.1.1.total_cmp(&y.1.1));
            let Some((i, (angle, offset))) = best else {
                continue;
            };
            self.matching += 1;
            seen[i] = true;
            self.angle_sum += angle;
            self.offset_sum += offset;
            if let Some(value) = nees(line, &truths[i], camera) {
                self.nees_sum += value;
                self.nees_count += 1;
            }
        }
        for (t, seen) in truths.iter().zip(seen) {
            if t.visible >= VISIBLE_PX {
                self.visible += 1;
                self.detected += usize::from(seen);
            }
        }
    }

    /// Adds another score's counts and sums.
    pub fn merge(&mut self, other: &ImageLineScore) {
        self.images += other.images;
        self.found += other.found;
        self.matching += other.matching;
        self.visible += other.visible;
        self.detected += other.detected;
        self.angle_sum += other.angle_sum;
        self.offset_sum += other.offset_sum;
        self.nees_sum += other.nees_sum;
        self.nees_count += other.nees_count;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_and_matching() {
        assert!(
            (clipped_length(
                &Vector2::new(-10.0, 5.0),
                &Vector2::new(30.0, 5.0),
                20.0,
                10.0
            ) - 20.0)
                .abs()
                < 1e-9
        );
        assert_eq!(
            clipped_length(
                &Vector2::new(-10.0, 15.0),
                &Vector2::new(30.0, 15.0),
                20.0,
                10.0
            ),
            0.0
        );
        let truth = TrueLine {
            ends: [Vector2::new(10.0, 10.0), Vector2::new(110.0, 10.0)],
            visible: 100.0,
        };
        let line = |a: Vector2<f64>, b: Vector2<f64>| ImageLine {
            ends: [a, b],
            cov: Matrix2::identity(),
            clipped: false,
        };
        let (angle, offset) = match_error(
            &line(Vector2::new(8.0, 11.0), Vector2::new(112.0, 11.0)),
            &truth,
        )
        .unwrap();
        assert!(angle < 1e-9 && (offset - 1.0).abs() < 1e-9);
        assert!(
            match_error(
                &line(Vector2::new(8.0, 14.0), Vector2::new(112.0, 14.0)),
                &truth
            )
            .is_none()
        );
        assert!(
            match_error(
                &line(Vector2::new(8.0, 10.0), Vector2::new(130.0, 10.0)),
                &truth
            )
            .is_none()
        );
        assert!(
            match_error(
                &line(Vector2::new(10.0, 8.0), Vector2::new(60.0, 12.0)),
                &truth
            )
            .is_none()
        );
    }
}
