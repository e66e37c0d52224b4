//! Free-space evidence against walls: a laser ray that returns well beyond a wall, having
//! crossed it inside its ends, saw through it. A wall most rays see through is not a surface
//! (a line fitted across furniture, a zigzag's peaks) or is not where the map puts it.

use slam_core::nalgebra::Vector2;

/// A return this close to a wall (m) counts as on it.
const ON_WALL: f64 = 0.1;
/// A ray must return at least this far beyond a wall (m) to count as through it.
const BEYOND: f64 = 0.3;
/// ... and cross it at least this far inside its ends (m): a ray past a wall's end is not
/// evidence against the wall.
const INSIDE_ENDS: f64 = 0.2;

/// What the rays say about one wall.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct RayEvidence {
    /// Returns within [`ON_WALL`] of the wall.
    pub on: usize,
    /// Rays that crossed the wall and returned beyond it.
    pub through: usize,
}

impl RayEvidence {
    /// Whether more than `max_fraction` of at least `min_rays` rays saw through the wall.
    pub fn seen_through(&self, max_fraction: f64, min_rays: usize) -> bool {
        let total = self.on + self.through;
        total >= min_rays && self.through as f64 > max_fraction * total as f64
    }
}

/// The evidence of the scans' rays for every wall segment: each scan is its sensor's position
/// and its returns, world frame.
pub(crate) fn ray_evidence(
    walls: &[(Vector2<f64>, Vector2<f64>)],
    scans: impl IntoIterator<Item = (Vector2<f64>, Vec<Vector2<f64>>)>,
) -> Vec<RayEvidence> {
    let grid = crate::eval::SegmentGrid::new(walls, 1.0);
    let boxes: Vec<Box2> = walls.iter().map(|(a, b)| Box2::around([a, b])).collect();
    let mut evidence = vec![RayEvidence::default(); walls.len()];
    let mut near: Vec<usize> = Vec::new();
    for (origin, ends) in scans {
        // The walls a ray of this scan can cross lie in the box of its rays.
        let reach = Box2::around(ends.iter().chain([&origin]));
        near.clear();
        near.extend((0..walls.len()).filter(|&k| boxes[k].overlaps(&reach)));
        for end in &ends {
            if let Some((k, _)) = grid.nearest_within(end, ON_WALL) {
                evidence[k].on += 1;
            }
            let ray = end - origin;
            let range = ray.norm();
            if range <= BEYOND {
                continue;
            }
            let direction = ray / range;
            for &k in &near {
                let (a, b) = &walls[k];
                if crosses(&origin, &direction, range - BEYOND, a, b) {
                    evidence[k].through += 1;
                }
            }
        }
    }
    evidence
}

/// An axis-aligned box.
#[derive(Clone, Copy, Debug)]
struct Box2 {
    min: Vector2<f64>,
    max: Vector2<f64>,
}

impl Box2 {
    /// The smallest box holding `points` (an empty box for none).
    fn around<'a>(points: impl IntoIterator<Item = &'a Vector2<f64>>) -> Box2 {
        let mut min = Vector2::repeat(f64::INFINITY);
        let mut max = Vector2::repeat(f64::NEG_INFINITY);
        for p in points {
            min = min.inf(p);
            max = max.sup(p);
        }
        Box2 { min, max }
    }

    fn overlaps(&self, other: &Box2) -> bool {
        self.min.x <= other.max.x
            && other.min.x <= self.max.x
            && self.min.y <= other.max.y
            && other.min.y <= self.max.y
    }
}

/// Whether the ray from `origin` along the unit `direction`, up to `reach`, crosses the
/// segment `a`-`b` at least [`INSIDE_ENDS`] inside its ends (and beyond the origin).
fn crosses(
    origin: &Vector2<f64>,
    direction: &Vector2<f64>,
    reach: f64,
    a: &Vector2<f64>,
    b: &Vector2<f64>,
) -> bool {
    let edge = b - a;
    let length = edge.norm();
    if length <= 2.0 * INSIDE_ENDS {
        return false;
    }
    let along = edge / length;
    // origin + t direction = a + u along.
    let det = along.x * direction.y - along.y * direction.x;
    if det.abs() < 1e-9 {
        return false;
    }
    let rel = a - origin;
    let t = (along.x * rel.y - along.y * rel.x) / det;
    let u = (direction.x * rel.y - direction.y * rel.x) / det;
    t > 0.0 && t < reach && u > INSIDE_ENDS && u < length - INSIDE_ENDS
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64) -> Vector2<f64> {
        Vector2::new(x, y)
    }

    #[test]
    fn a_ray_crosses_a_wall_only_inside_its_ends_and_before_its_return() {
        let (a, b) = (v(0.0, 2.0), v(4.0, 2.0));
        let up = v(0.0, 1.0);
        assert!(crosses(&v(2.0, 0.0), &up, 3.0, &a, &b));
        // Returned before the wall, or just past it.
        assert!(!crosses(&v(2.0, 0.0), &up, 1.9, &a, &b));
        // Past the wall's end, or within INSIDE_ENDS of it.
        assert!(!crosses(&v(4.5, 0.0), &up, 3.0, &a, &b));
        assert!(!crosses(&v(3.9, 0.0), &up, 3.0, &a, &b));
        // Behind the origin, or parallel.
        assert!(!crosses(&v(2.0, 3.0), &up, 3.0, &a, &b));
        assert!(!crosses(&v(0.0, 1.0), &v(1.0, 0.0), 9.0, &a, &b));
    }

    #[test]
    fn a_line_across_open_floor_is_seen_through_and_a_wall_with_a_door_is_not() {
        // A wall along y = 3 from x = 0 to 6 with a 1 m door at x 2.5-3.5, seen from (3, 0):
        // the rays through the door return at y = 8.
        let xs: Vec<f64> = (0..=60).map(|i| 0.1 * i as f64).collect();
        let ends: Vec<_> = xs
            .iter()
            .map(|&x| {
                if (2.5..=3.5).contains(&x) {
                    v(x, 8.0)
                } else {
                    v(x, 3.0)
                }
            })
            .collect();
        let scan = (v(3.0, 0.0), ends);
        // A "wall" fitted across the room at y = 1.5 the rays all pass through.
        let walls = [(v(0.0, 3.0), v(6.0, 3.0)), (v(1.0, 1.5), v(5.0, 1.5))];
        let evidence = ray_evidence(&walls, [scan]);
        assert!(!evidence[0].seen_through(0.5, 20), "{:?}", evidence[0]);
        assert!(evidence[0].through > 0 && evidence[0].on > 40);
        assert!(evidence[1].seen_through(0.5, 20), "{:?}", evidence[1]);
        // Too few rays decide nothing.
        assert!(!evidence[1].seen_through(0.5, 1000));
    }
}
