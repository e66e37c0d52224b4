//! The map figures of `slam run`: the map (every feature drawn from its own
//! [`slam_core::Sketch`]), the path, the truth, GPS fixes and 95 % covariance ellipses.

use std::collections::BTreeMap;

use slam_core::nalgebra::{DMatrix, Matrix2, Vector2, Vector3};
use slam_core::{Estimator, FeatureMap, Mark, Pose2, chi2_quantile};
use slam_runtime::eval::{Alignment, confirmed, coordinate_covariance, umeyama};
use slam_runtime::{PostProcessOutput, RunOutput};
use slam_sensors::{KnownLandmark, TruthKind};

use crate::plot::{Colour, Figure, palette};

/// How to bring the estimate into the frame the figure's references use: onto the GPS fixes
/// (nearest estimate within 0.5 s) when there are some, onto known landmarks when the run has
/// no true poses, else none.
pub fn estimate_alignment(output: &RunOutput) -> Option<Alignment> {
    let as3 = |p: Vector2<f64>| Vector3::new(p.x, p.y, 0.0);
    let record = &output.record;
    if record.gps.len() >= 3 {
        let mut from = Vec::new();
        let mut to = Vec::new();
        for (time, fix) in &record.gps {
            let nearest = record
                .estimates
                .partition_point(|r| r.time < *time)
                .min(record.estimates.len().saturating_sub(1));
            let estimate = record.estimates.get(nearest)?;
            if (estimate.time - time).abs() <= 0.5 {
                from.push(as3(estimate.pose.translation()));
                to.push(as3(*fix));
            }
        }
        return umeyama(&from, &to, false).ok();
    }
    let has_truth_poses = record.truth.iter().any(|t| t.2 == TruthKind::True);
    if !has_truth_poses && !output.landmarks.is_empty() {
        let estimator = output.estimator.as_ref();
        let known: BTreeMap<u64, _> = output
            .landmarks
            .iter()
            .map(|l| (l.id, l.position))
            .collect();
        let (mut from, mut to) = (Vec::new(), Vec::new());
        for (id, feature) in estimator.map().iter() {
            let Some(truth) = estimator.landmark_id(id).and_then(|l| known.get(&l)) else {
                continue;
            };
            if let Some(shape) = feature.shape() {
                from.push(as3(shape.anchor()));
                to.push(as3(*truth));
            }
        }
        return umeyama(&from, &to, false).ok();
    }
    None
}

/// The figure of a run: its title, the true map, known landmarks, the truth's path, GPS
/// fixes, the path the map belongs to and the map.
pub fn run_figure(output: &RunOutput) -> Figure {
    let alignment = estimate_alignment(output);
    let suffix = if alignment.is_some() {
        " (estimate aligned onto the references)"
    } else {
        ""
    };
    let title = format!(
        "{}: {} map and path{suffix}",
        output.name,
        output.estimator.name()
    );
    let place = |p: Vector2<f64>| -> Vector2<f64> {
        match &alignment {
            Some(a) => a.apply(&Vector3::new(p.x, p.y, 0.0)).xy(),
            None => p,
        }
    };
    let mut figure = Figure::new(title, 1600);
    draw_references(&mut figure, output);
    // A particle filter's map belongs to one particle's path, drawn instead of the mean.
    let (path, label): (Vec<_>, _) = match &output.map_path {
        Some(path) => (
            path.iter().map(|(_, p)| place(p.translation())).collect(),
            "path of the map's particle",
        ),
        None => (
            output
                .record
                .estimates
                .iter()
                .map(|r| place(r.pose.translation()))
                .collect(),
            "estimated path",
        ),
    };
    figure.polyline(path, palette::PATH, 2);
    figure.legend(label, palette::PATH);
    draw_map(&mut figure, output.estimator.as_ref(), &place);
    figure
}

/// The true map, known landmarks, the truth's path and GPS fixes.
fn draw_references(figure: &mut Figure, output: &RunOutput) {
    if let Some(truth) = &output.truth_map {
        for (a, b) in &truth.walls {
            figure.segment(*a, *b, palette::TRUTH, 3);
        }
        for (c, r) in &truth.poles {
            figure.circle(*c, *r, palette::TRUTH, false);
        }
        for (a, b) in &truth.ceiling_lines {
            figure.segment(a.xy(), b.xy(), palette::TRUTH_CEILING, 1);
        }
        figure.dots(
            truth.lamps.iter().map(|l| l.xy()).collect(),
            palette::TRUTH,
            4,
        );
        figure.legend("true map", palette::TRUTH);
    }
    draw_landmarks(figure, &output.landmarks);
    let record = &output.record;
    let truth_path: Vec<_> = record
        .truth
        .iter()
        .map(|(_, p, _)| p.translation())
        .collect();
    if !truth_path.is_empty() {
        let kind = if record.truth.iter().any(|t| t.2 == TruthKind::True) {
            "true path"
        } else {
            "reference path"
        };
        figure.polyline(truth_path, palette::TRUE_PATH, 1);
        figure.legend(kind, palette::TRUE_PATH);
    }
    if !record.gps.is_empty() {
        // The receiver's jumps, which the ATE leaves out, apart from the fixes it uses.
        let jumps = slam_runtime::eval::gps_jumps(&record.gps);
        let (left_out, used): (Vec<_>, Vec<_>) =
            record.gps.iter().zip(&jumps).partition(|(_, jump)| **jump);
        figure.dots(used.iter().map(|((_, g), _)| *g).collect(), palette::GPS, 2);
        figure.legend(format!("{} GPS fixes", used.len()), palette::GPS);
        if !left_out.is_empty() {
            for ((_, g), _) in &left_out {
                figure.marker(*g, palette::GPS_JUMP, 9, false);
            }
            figure.legend(
                format!(
                    "{} GPS {} (left out of the ATE)",
                    left_out.len(),
                    if left_out.len() == 1 { "jump" } else { "jumps" }
                ),
                palette::GPS_JUMP,
            );
        }
    }
}

fn draw_landmarks(figure: &mut Figure, landmarks: &[KnownLandmark]) {
    if !landmarks.is_empty() {
        for l in landmarks {
            figure.marker(l.position, palette::TRUTH, 9, false);
        }
        figure.legend("known landmarks", palette::TRUTH);
    }
}

/// The confirmed features of the estimator's map by their sketches, with the 95 % ellipses
/// of what the estimator's covariance gives, and one legend entry per sketch label.
pub fn draw_map(
    figure: &mut Figure,
    estimator: &dyn Estimator<Pose2>,
    place: &dyn Fn(Vector2<f64>) -> Vector2<f64>,
) {
    let mut legend: BTreeMap<&'static str, (usize, Colour)> = BTreeMap::new();
    for (id, feature) in estimator.map().iter() {
        if !confirmed(estimator, id) {
            continue;
        }
        let sketch = feature.sketch();
        let covariance = coordinate_covariance(estimator, id);
        draw_marks(figure, &sketch.marks, covariance.as_ref(), place);
        legend
            .entry(sketch.label)
            .or_insert((0, palette::ink(sketch.ink)))
            .0 += 1;
    }
    for (name, (n, colour)) in legend {
        figure.legend(format!("{n} {name}"), colour);
    }
}

/// Every feature of a map without an estimator (a post-processing stage's), by its sketch:
/// its lines and circles only, since markers of estimated ends and ellipses say nothing
/// without a covariance.
pub fn draw_plain_map(figure: &mut Figure, map: &FeatureMap) {
    let mut legend: BTreeMap<&'static str, (usize, Colour)> = BTreeMap::new();
    for (_, feature) in map.iter() {
        let sketch = feature.sketch();
        let geometry: Vec<Mark> = sketch
            .marks
            .iter()
            .filter(|m| matches!(m, Mark::Segment { .. } | Mark::Circle { .. }))
            .copied()
            .collect();
        draw_marks(figure, &geometry, None, &|p| p);
        legend
            .entry(sketch.label)
            .or_insert((0, palette::ink(sketch.ink)))
            .0 += 1;
    }
    for (name, (n, colour)) in legend {
        figure.legend(format!("{n} {name}"), colour);
    }
}

fn draw_marks(
    figure: &mut Figure,
    marks: &[Mark],
    covariance: Option<&DMatrix<f64>>,
    place: &dyn Fn(Vector2<f64>) -> Vector2<f64>,
) {
    for mark in marks {
        match *mark {
            Mark::Segment {
                from,
                to,
                ink,
                width,
            } => figure.segment(place(from), place(to), palette::ink(ink), width),
            Mark::Circle {
                centre,
                radius,
                ink,
                filled,
            } => figure.circle(place(centre), radius, palette::ink(ink), filled),
            Mark::Marker {
                at,
                ink,
                size,
                filled,
            } => figure.marker(place(at), palette::ink(ink), size, filled),
            Mark::Ellipse { offset, at, ink } => {
                if let Some(points) =
                    covariance.and_then(|c| ellipse(at, &point_covariance(c, offset)?))
                {
                    figure.polyline(
                        points.into_iter().map(place).collect(),
                        palette::ink(ink),
                        1,
                    );
                }
            }
        }
    }
}

/// The 2 x 2 covariance of the horizontal position at `offset` of a coordinate covariance.
fn point_covariance(c: &DMatrix<f64>, offset: usize) -> Option<Matrix2<f64>> {
    if offset + 1 >= c.nrows() {
        return None;
    }
    Some(Matrix2::new(
        c[(offset, offset)],
        c[(offset, offset + 1)],
        c[(offset + 1, offset)],
        c[(offset + 1, offset + 1)],
    ))
}

/// An ellipse is not drawn when a deviation is above this, m: the coordinate is unknown (an
/// EKF row still at its uninformative prior, `new_row_variance` = 1e4 m^2 by default, when the
/// update that would have measured it was refused), and a circle hundreds of metres wide would
/// only shrink the map to a corner of the figure.
const ELLIPSE_MAX_DEVIATION_M: f64 = 30.0;

/// The 95% ellipse of a 2-D covariance around `centre`, as a closed polyline; `None` for an
/// unknown coordinate ([`ELLIPSE_MAX_DEVIATION_M`]) or a covariance that is not one.
fn ellipse(centre: Vector2<f64>, covariance: &Matrix2<f64>) -> Option<Vec<Vector2<f64>>> {
    let eigen = covariance.symmetric_eigen();
    if eigen
        .eigenvalues
        .iter()
        .any(|v| !v.is_finite() || *v < 0.0 || v.sqrt() > ELLIPSE_MAX_DEVIATION_M)
    {
        return None;
    }
    let scale = chi2_quantile(0.95, 2).ok()?.sqrt();
    let axes = eigen.eigenvectors * Matrix2::from_diagonal(&eigen.eigenvalues.map(f64::sqrt));
    Some(
        (0..=48)
            .map(|k| {
                let t = k as f64 / 48.0 * std::f64::consts::TAU;
                centre + axes * Vector2::new(t.cos(), t.sin()) * scale
            })
            .collect(),
    )
}

/// The figure of a post-processing stage: the points it used (grey, when `with_points`), its
/// path and its map.
pub fn stage_figure(output: &PostProcessOutput, data: &str, with_points: bool) -> Figure {
    let mut figure = Figure::new(
        format!(
            "{data}: {}, {} features over {} points",
            output.name,
            output.map.len(),
            output.points.len()
        ),
        1600,
    );
    if with_points && !output.points.is_empty() {
        figure.dots(output.points.clone(), palette::TRUTH, 1);
        figure.legend(
            format!("{} registered points", output.points.len()),
            palette::TRUTH,
        );
    }
    figure.polyline(
        output.path.iter().map(|p| p.1.translation()).collect(),
        palette::PATH,
        1,
    );
    figure.legend("path", palette::PATH);
    draw_plain_map(&mut figure, &output.map);
    figure
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ellipses_of_known_coordinates_are_drawn_and_unknown_ones_are_not() {
        let centre = Vector2::new(1.0, 2.0);
        // 95 % of a unit 2-D Gaussian lies within sqrt(5.991) = 2.448 of its mean.
        let points = ellipse(centre, &Matrix2::identity()).unwrap();
        assert!(
            points
                .iter()
                .all(|p| ((p - centre).norm() - 2.4477).abs() < 1e-3)
        );
        let wide = Matrix2::new(25.0 * 25.0, 0.0, 0.0, 0.01);
        assert!(ellipse(centre, &wide).is_some());
        // A row still at the EKF's uninformative prior (1e4 m^2): unknown, not drawn.
        let unknown = Matrix2::new(1e4, 0.0, 0.0, 0.01);
        assert!(ellipse(centre, &unknown).is_none());
        assert!(ellipse(centre, &Matrix2::new(f64::NAN, 0.0, 0.0, 1.0)).is_none());
    }
}
