//! Ray casting against walls (segments) and poles (circles).

use slam_core::nalgebra::Vector2;

/// Distance along the unit ray `origin + t direction` to the nearest wall or pole, if any.
///
/// ```
/// use slam_sensors::sim::raycast::cast;
/// use slam_core::nalgebra::Vector2;
/// let walls = [(Vector2::new(2.0, -1.0), Vector2::new(2.0, 1.0))];
/// let poles = [(Vector2::new(1.0, 0.0), 0.25)];
/// let t = cast(&Vector2::zeros(), &Vector2::new(1.0, 0.0), &walls, &poles).unwrap();
/// assert!((t - 0.75).abs() < 1e-12);
/// ```
pub fn cast(
    origin: &Vector2<f64>,
    direction: &Vector2<f64>,
    walls: &[(Vector2<f64>, Vector2<f64>)],
    poles: &[(Vector2<f64>, f64)],
) -> Option<f64> {
    let wall_hits = walls
        .iter()
        .filter_map(|(a, b)| hit_segment(origin, direction, a, b));
    let pole_hits = poles
        .iter()
        .filter_map(|(c, r)| hit_circle(origin, direction, c, *r));
    wall_hits
        .chain(pole_hits)
        .fold(None, |best: Option<f64>, t| {
            Some(best.map_or(t, |b| b.min(t)))
        })
}

fn cross(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// `t > 0` where the ray meets the segment `a b`.
fn hit_segment(
    o: &Vector2<f64>,
    d: &Vector2<f64>,
    a: &Vector2<f64>,
    b: &Vector2<f64>,
) -> Option<f64> {
    let e = b - a;
    let den = cross(d, &e);
    if den.abs() < 1e-12 {
        return None;
    }
    let w = a - o;
    let t = cross(&w, &e) / den;
    let s = cross(&w, d) / den;
    (t > 1e-9 && (0.0..=1.0).contains(&s)).then_some(t)
}

/// Smallest `t > 0` where the ray meets the circle, from outside.
fn hit_circle(o: &Vector2<f64>, d: &Vector2<f64>, c: &Vector2<f64>, r: f64) -> Option<f64> {
    let w = o - c;
    let b = w.dot(d);
    let disc = b * b - (w.norm_squared() - r * r);
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    (t > 1e-9).then_some(t)
}
