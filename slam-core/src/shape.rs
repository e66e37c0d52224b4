//! What outputs need of a feature without knowing its type: its geometry in the world frame
//! ([`Shape`], for map error against a true map) and how to draw it ([`Sketch`]).
//!
//! A feature type gives both through [`crate::Feature::shape`] and
//! [`crate::Feature::sketch`], so that a user's own feature is drawn and scored like a
//! built-in one.

use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// A feature's geometry in the world frame (metres), by kind. Map error compares an
/// estimated shape with the nearest true shape of the same kind ([`Shape::error_against`]).
///
/// ```
/// use slam_core::Shape;
/// use slam_core::nalgebra::Vector2;
/// let truth = [Shape::Wall { start: Vector2::new(0.0, 0.0), end: Vector2::new(4.0, 0.0) }];
/// let estimate = Shape::Wall { start: Vector2::new(1.0, 0.03), end: Vector2::new(3.0, 0.03) };
/// assert!((estimate.error_against(&truth).unwrap() - 0.03).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Shape {
    /// A wall: a vertical surface seen from above, a segment of the floor plan.
    Wall {
        /// One end.
        start: Vector2<f64>,
        /// The other end.
        end: Vector2<f64>,
    },
    /// A horizontal line in space, e.g. a ceiling line.
    Line {
        /// One end.
        start: Vector3<f64>,
        /// The other end (at the same height).
        end: Vector3<f64>,
    },
    /// A vertical cylinder, e.g. a pole or a tree trunk.
    Pole {
        /// Its axis in the floor plane.
        centre: Vector2<f64>,
        /// Its radius.
        radius: f64,
    },
    /// A point in space, e.g. a ceiling lamp.
    Point {
        /// Where it is.
        position: Vector3<f64>,
    },
    /// A point known in the floor plane only, e.g. a range-bearing landmark.
    PlanarPoint {
        /// Where it is.
        position: Vector2<f64>,
    },
}

/// Largest angle between an estimated segment and the true one it is compared with.
const SEGMENT_MATCH_ANGLE_DEG: f64 = 15.0;

impl Shape {
    /// The horizontal position that stands for the shape when it is matched by identity
    /// (a landmark id): a point's or pole's position, a segment's midpoint.
    pub fn anchor(&self) -> Vector2<f64> {
        match self {
            Shape::Wall { start, end } => (start + end) / 2.0,
            Shape::Line { start, end } => ((start + end) / 2.0).xy(),
            Shape::Pole { centre, .. } => *centre,
            Shape::Point { position } => position.xy(),
            Shape::PlanarPoint { position } => *position,
        }
    }

    /// The same shape moved by `place`, a map of points in space (e.g. an alignment of the
    /// estimate onto the truth); a point of the floor plane is moved as the point at height 0.
    pub fn placed(&self, place: impl Fn(Vector3<f64>) -> Vector3<f64>) -> Shape {
        let flat = |p: &Vector2<f64>| place(Vector3::new(p.x, p.y, 0.0)).xy();
        match self {
            Shape::Wall { start, end } => Shape::Wall {
                start: flat(start),
                end: flat(end),
            },
            Shape::Line { start, end } => Shape::Line {
                start: place(*start),
                end: place(*end),
            },
            Shape::Pole { centre, radius } => Shape::Pole {
                centre: flat(centre),
                radius: *radius,
            },
            Shape::Point { position } => Shape::Point {
                position: place(*position),
            },
            Shape::PlanarPoint { position } => Shape::PlanarPoint {
                position: flat(position),
            },
        }
    }

    /// The error of this estimated shape against the true shapes of the same kind, `None`
    /// when there is none to compare with:
    /// - walls: the true wall within 15 degrees whose segment is nearest to the estimate's
    ///   midpoint; the RMS distance of the estimate's two ends to that wall's line;
    /// - lines: the same in the floor plane, combined with the height error to the true line
    ///   of the nearest height;
    /// - poles, points and planar points: the distance to the nearest true one.
    pub fn error_against(&self, truths: &[Shape]) -> Option<f64> {
        match self {
            Shape::Wall { start, end } => {
                let walls: Vec<_> = truths
                    .iter()
                    .filter_map(|t| match t {
                        Shape::Wall { start, end } => Some((*start, *end)),
                        _ => None,
                    })
                    .collect();
                segment_error(*start, *end, &walls)
            }
            Shape::Line { start, end } => line_error(start, end, truths),
            Shape::Pole { centre, .. } => nearest(truths, |t| match t {
                Shape::Pole { centre: c, .. } => Some((c - centre).norm()),
                _ => None,
            }),
            Shape::Point { position } => nearest(truths, |t| match t {
                Shape::Point { position: p } => Some((p - position).norm()),
                _ => None,
            }),
            Shape::PlanarPoint { position } => nearest(truths, |t| match t {
                Shape::PlanarPoint { position: p } => Some((p - position).norm()),
                _ => None,
            }),
        }
    }
}

impl Shape {
    /// How far this shape lies from `other` where they overlap, `None` when they are not
    /// comparable: of different kinds, segments more than `max_angle` (rad) from parallel or
    /// facing opposite ways (the two sides of a thin wall), or segments whose extents do not
    /// overlap along `other`. For segments (walls, and lines in the floor plane) it is the
    /// larger distance from `other`'s line of this segment's part over `other`; for poles and
    /// points the distance between them.
    ///
    /// ```
    /// use slam_core::Shape;
    /// use slam_core::nalgebra::Vector2;
    /// let wall = |ax: f64, ay: f64, bx: f64, by: f64| Shape::Wall {
    ///     start: Vector2::new(ax, ay), end: Vector2::new(bx, by) };
    /// let a = wall(0.0, 0.0, 4.0, 0.0);
    /// assert!((wall(3.0, 0.1, 6.0, 0.1).overlap_separation(&a, 0.1).unwrap() - 0.1).abs() < 1e-12);
    /// assert_eq!(wall(5.0, 0.0, 6.0, 0.0).overlap_separation(&a, 0.1), None); // no overlap
    /// assert_eq!(wall(4.0, 0.1, 0.0, 0.1).overlap_separation(&a, 0.1), None); // the other side
    /// ```
    pub fn overlap_separation(&self, other: &Shape, max_angle: f64) -> Option<f64> {
        match (self, other) {
            (Shape::Wall { start, end }, Shape::Wall { start: s, end: e }) => {
                overlap_separation(start, end, s, e, max_angle)
            }
            (Shape::Line { start, end }, Shape::Line { start: s, end: e }) => {
                overlap_separation(&start.xy(), &end.xy(), &s.xy(), &e.xy(), max_angle)
            }
            (Shape::Pole { centre, .. }, Shape::Pole { centre: c, .. }) => {
                Some((centre - c).norm())
            }
            (Shape::Point { position }, Shape::Point { position: p }) => {
                Some((position - p).norm())
            }
            (Shape::PlanarPoint { position }, Shape::PlanarPoint { position: p }) => {
                Some((position - p).norm())
            }
            _ => None,
        }
    }
}

/// See [`Shape::overlap_separation`]: segment `a b` against segment `s e`.
fn overlap_separation(
    a: &Vector2<f64>,
    b: &Vector2<f64>,
    s: &Vector2<f64>,
    e: &Vector2<f64>,
    max_angle: f64,
) -> Option<f64> {
    let (length, other_length) = ((b - a).norm(), (e - s).norm());
    if length == 0.0 || other_length == 0.0 {
        return None;
    }
    let tangent = (e - s) / other_length;
    if (b - a).dot(&tangent) / length < max_angle.cos() {
        return None;
    }
    let normal = Vector2::new(-tangent.y, tangent.x);
    let along = |p: &Vector2<f64>| (p - s).dot(&tangent);
    let (ta, tb) = (along(a), along(b));
    let (lo, hi) = (ta.max(0.0), tb.min(other_length));
    if hi < lo {
        return None;
    }
    let offset = |t: f64| {
        let point = a + (b - a) * ((t - ta) / (tb - ta));
        (point - s).dot(&normal).abs()
    };
    Some(offset(lo).max(offset(hi)))
}

/// The smallest of `distance(truth)` over the truths it is defined for.
fn nearest(truths: &[Shape], distance: impl Fn(&Shape) -> Option<f64>) -> Option<f64> {
    truths.iter().filter_map(distance).min_by(f64::total_cmp)
}

/// A horizontal line against the true lines: the floor-plan error of [`segment_error`] and
/// the height error to the true line of the nearest height.
fn line_error(start: &Vector3<f64>, end: &Vector3<f64>, truths: &[Shape]) -> Option<f64> {
    let lines: Vec<(Vector3<f64>, Vector3<f64>)> = truths
        .iter()
        .filter_map(|t| match t {
            Shape::Line { start, end } => Some((*start, *end)),
            _ => None,
        })
        .collect();
    let flat: Vec<_> = lines.iter().map(|(a, b)| (a.xy(), b.xy())).collect();
    let horizontal = segment_error(start.xy(), end.xy(), &flat);
    let height = start.z;
    let height_error = lines
        .iter()
        .map(|(a, _)| a.z)
        .min_by(|x, y| (x - height).abs().total_cmp(&(y - height).abs()))
        .map(|z| z - height);
    horizontal
        .zip(height_error)
        .map(|(h, z)| (h * h + z * z).sqrt())
}

/// Distance from `p` to the segment `a b`.
pub fn segment_distance(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let e = b - a;
    let t = ((p - a).dot(&e) / e.norm_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + e * t)).norm()
}

/// Distance from `p` to the infinite line through `a` and `b`.
pub fn line_distance(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let t = (b - a).normalize();
    let d = p - a;
    (d - t * t.dot(&d)).norm()
}

/// The error of an estimated segment against the closest true segment of similar direction
/// (within 15 degrees): RMS of the distances of its two ends to the true line.
fn segment_error(
    a: Vector2<f64>,
    b: Vector2<f64>,
    truths: &[(Vector2<f64>, Vector2<f64>)],
) -> Option<f64> {
    let mid = (a + b) / 2.0;
    let direction = (b - a).normalize();
    truths
        .iter()
        .filter(|(p, q)| {
            (q - p).normalize().dot(&direction).abs() > SEGMENT_MATCH_ANGLE_DEG.to_radians().cos()
        })
        .min_by(|x, y| {
            segment_distance(&mid, &x.0, &x.1).total_cmp(&segment_distance(&mid, &y.0, &y.1))
        })
        .map(|(p, q)| {
            let (da, db) = (line_distance(&a, p, q), line_distance(&b, p, q));
            ((da * da + db * db) / 2.0).sqrt()
        })
}

/// A colour role in a map figure; the plotting code picks the colour of each.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Ink {
    /// A wall estimated beyond its line (an end or a corner).
    Wall,
    /// A wall whose line only is estimated.
    WallLineOnly,
    /// An estimated end or shared corner.
    Corner,
    /// A ceiling feature placed in every direction.
    Ceiling,
    /// A ceiling line whose direction only is estimated.
    CeilingDirection,
    /// A pole.
    Pole,
    /// A point or any other feature.
    Point,
}

/// One element of a [`Sketch`], in the world frame (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mark {
    /// A line segment.
    Segment {
        /// One end.
        from: Vector2<f64>,
        /// The other end.
        to: Vector2<f64>,
        /// Its colour role.
        ink: Ink,
        /// Its width in pixels.
        width: u32,
    },
    /// A circle of the given radius.
    Circle {
        /// Its centre.
        centre: Vector2<f64>,
        /// Its radius, m.
        radius: f64,
        /// Its colour role.
        ink: Ink,
        /// Whether it is filled.
        filled: bool,
    },
    /// A marker of fixed size in pixels.
    Marker {
        /// Where.
        at: Vector2<f64>,
        /// Its colour role.
        ink: Ink,
        /// Its size in pixels.
        size: u32,
        /// Whether it is filled.
        filled: bool,
    },
    /// The 95 % ellipse of the horizontal position whose coordinates start at `offset` in
    /// the feature's coordinate vector `x_f` (a 2-D point block, or the x and y of a 3-D
    /// one), drawn around `at` from the estimator's covariance of the feature.
    Ellipse {
        /// Offset of the position's x in `x_f`.
        offset: usize,
        /// The position.
        at: Vector2<f64>,
        /// Its colour role.
        ink: Ink,
    },
}

/// How a feature appears in a map figure: its marks and the legend entry it counts under.
///
/// ```
/// use slam_core::{Ink, Mark, Sketch};
/// use slam_core::nalgebra::Vector2;
/// let sketch = Sketch::new("doors", Ink::Wall).with(Mark::Segment {
///     from: Vector2::new(0.0, 0.0),
///     to: Vector2::new(0.9, 0.0),
///     ink: Ink::Wall,
///     width: 2,
/// });
/// assert_eq!(sketch.marks.len(), 1);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Sketch {
    /// The legend entry (features are counted per entry), e.g. `"poles"`.
    pub label: &'static str,
    /// The colour role of the legend entry.
    pub ink: Ink,
    /// What to draw.
    pub marks: Vec<Mark>,
}

impl Sketch {
    /// A sketch with no marks yet.
    pub fn new(label: &'static str, ink: Ink) -> Self {
        Sketch {
            label,
            ink,
            marks: Vec::new(),
        }
    }

    /// The sketch with one more mark.
    pub fn with(mut self, mark: Mark) -> Self {
        self.marks.push(mark);
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall(a: (f64, f64), b: (f64, f64)) -> Shape {
        Shape::Wall {
            start: Vector2::new(a.0, a.1),
            end: Vector2::new(b.0, b.1),
        }
    }

    #[test]
    fn walls_compare_with_the_nearest_true_wall_of_similar_direction() {
        let truth = [wall((0.0, 0.0), (10.0, 0.0)), wall((0.0, 1.0), (0.0, 5.0))];
        // Ends 0.1 and 0.3 m off the x axis: RMS sqrt((0.01 + 0.09) / 2).
        let estimate = wall((2.0, 0.1), (4.0, 0.3));
        let expected = (0.05f64).sqrt();
        assert!((estimate.error_against(&truth).unwrap() - expected).abs() < 1e-12);
        // Turned 30 degrees: no true wall within 15 degrees.
        let turned = wall((2.0, 0.0), (2.0 + 30f64.to_radians().cos(), 0.5));
        assert_eq!(turned.error_against(&truth), None);
        // Another kind has nothing to compare with.
        let pole = Shape::Pole {
            centre: Vector2::new(1.0, 1.0),
            radius: 0.2,
        };
        assert_eq!(pole.error_against(&truth), None);
    }

    #[test]
    fn lines_add_the_height_error_and_points_take_the_nearest() {
        let line = |z: f64| Shape::Line {
            start: Vector3::new(0.0, 0.0, z),
            end: Vector3::new(4.0, 0.0, z),
        };
        let truth = [line(2.5), line(3.5)];
        let estimate = Shape::Line {
            start: Vector3::new(1.0, 0.3, 2.9),
            end: Vector3::new(2.0, 0.3, 2.9),
        };
        let error = estimate.error_against(&truth).unwrap();
        assert!((error - (0.3f64.powi(2) + 0.4f64.powi(2)).sqrt()).abs() < 1e-12);
        let lamps = [
            Shape::Point {
                position: Vector3::new(0.0, 0.0, 3.0),
            },
            Shape::Point {
                position: Vector3::new(5.0, 0.0, 3.0),
            },
        ];
        let lamp = Shape::Point {
            position: Vector3::new(4.0, 0.0, 3.0),
        };
        assert_eq!(lamp.error_against(&lamps), Some(1.0));
        assert_eq!(lamp.anchor(), Vector2::new(4.0, 0.0));
    }

    #[test]
    fn placing_moves_every_kind_and_keeps_radii() {
        let shift = |p: Vector3<f64>| p + Vector3::new(1.0, 2.0, 0.5);
        let pole = Shape::Pole {
            centre: Vector2::new(0.0, 0.0),
            radius: 0.3,
        };
        assert_eq!(
            pole.placed(shift),
            Shape::Pole {
                centre: Vector2::new(1.0, 2.0),
                radius: 0.3
            }
        );
        let planar = Shape::PlanarPoint {
            position: Vector2::new(1.0, 1.0),
        };
        assert_eq!(planar.placed(shift).anchor(), Vector2::new(2.0, 3.0));
    }
}
