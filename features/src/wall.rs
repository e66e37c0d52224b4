//! The wall: a vertical plane seen by a 2-D laser as a line segment, parameterized by its two
//! 2-D endpoints (paper section IV-F, Table II, and eq. 33 for walls sharing a corner).

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Matrix2, Vector2};
use slam_core::{
    Coincidence, CoordBlock, Coordinates, Error, Extension, Feature, Growth, Ink, Mark, Result,
    Shape, Sketch, Subspace, downcast_feature, ensure_finite, stack_rows,
};

use crate::geometry::Segment2;

/// Rotation about the centre (scaled by 1/L) and normal offset of the centre (eqs. 14-15).
pub const LINE: Subspace = Subspace {
    name: "line",
    rows: 2,
    description: "rotation about the centre (scaled by 1/L) and normal offset of the centre: \
                  what a measured line (normal angle and distance) constrains (eqs. 14-15)",
};

/// Tangential position of the start point (Table II, row 3).
pub const START: Subspace = Subspace {
    name: "start",
    rows: 1,
    description: "tangential position of the start point: the start point was seen as a real \
                  end of the wall (a corner or an edge, not an occlusion or the field of view)",
};

/// Tangential position of the end point (Table II, row 4).
pub const END: Subspace = Subspace {
    name: "end",
    rows: 1,
    description: "tangential position of the end point: the end point was seen as a real end \
                  of the wall (a corner or an edge, not an occlusion or the field of view)",
};

/// Smallest angle between two walls that share a corner, degrees (also the default
/// `min_corner_angle` of the laser front-end, `slam_sensors::LineExtractorParams`).
pub const MIN_CORNER_ANGLE_DEG: f64 = 30.0;

/// Normal motion of the free endpoint about a shared corner, scaled by L/L_s (eq. 33).
pub const PIVOT: Subspace = Subspace {
    name: "pivot",
    rows: 1,
    description: "rotation about the shared corner: normal motion of the free endpoint scaled \
                  by L/L_s, L_s the length when the corner was joined (eq. 33)",
};

/// Which of the wall's own subspaces are active, in row order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum WallSubspace {
    Line,
    Start,
    End,
    Pivot,
}

impl WallSubspace {
    fn spec(self) -> Subspace {
        match self {
            WallSubspace::Line => LINE,
            WallSubspace::Start => START,
            WallSubspace::End => END,
            WallSubspace::Pivot => PIVOT,
        }
    }

    fn tangent_of(end: usize) -> Self {
        if end == 0 {
            WallSubspace::Start
        } else {
            WallSubspace::End
        }
    }
}

/// A wall: two 2-D endpoints `x_f = {x_start, x_end}` (Table I).
///
/// **Side.** The wall's free-space side (the side it was seen from) is on the left when
/// walking from `start` to `end`; the normal `n = (cos gamma, sin gamma)` points there, away
/// from the wall surface (eq. 13). The tangent `t` points from start to end. Table II's
/// tangential rows use `(-sin gamma, cos gamma) = -t`; this crate uses `+t` for both ends,
/// which changes only the sign of those perturbation coordinates.
///
/// **M-space.** Dimensions 0, 2 (`"line"`), 3 (`+ "start"` or `+ "end"`) and 4 (both). When an
/// endpoint becomes a shared corner ([`Feature::share_block`]) the corner's rows belong to
/// the shared block (identity in x, y) and the wall's own rows become `"pivot"` (normal
/// motion of the free end, scaled by `L / L_s`, eq. 33) plus the free end's tangential row if
/// it was active; with both ends shared the wall has no own rows.
///
/// ```
/// use slam_features::Wall;
/// use slam_core::{Feature, nalgebra::Vector2};
/// let mut wall = Wall::new(Vector2::new(0.0, 0.0), Vector2::new(4.0, 0.0)).unwrap();
/// assert_eq!(wall.mspace_dim(), 0);
/// wall.activate("line").unwrap();
/// let b = wall.projection().unwrap();
/// let b_dual = wall.dual().unwrap();
/// assert!((b * b_dual - slam_core::nalgebra::DMatrix::identity(2, 2)).amax() < 1e-12);
/// assert!(Wall::new(Vector2::new(0.0, 0.0), Vector2::new(1e-4, 0.0)).is_err()); // too short
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "WallRepr", into = "WallRepr")]
pub struct Wall {
    coordinates: Coordinates,
    active: Vec<WallSubspace>,
    shared: [bool; 2],
    /// `L_s`: the length when the first endpoint became a shared corner (eq. 33).
    length_at_join: Option<f64>,
}

/// The serialized form of a [`Wall`], validated on the way in.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct WallRepr {
    start: Vector2<f64>,
    end: Vector2<f64>,
    active: Vec<WallSubspace>,
    #[serde(default)]
    shared: [bool; 2],
    #[serde(default)]
    length_at_join: Option<f64>,
}

impl From<Wall> for WallRepr {
    fn from(wall: Wall) -> Self {
        WallRepr {
            start: wall.start(),
            end: wall.end(),
            active: wall.active,
            shared: wall.shared,
            length_at_join: wall.length_at_join,
        }
    }
}

impl TryFrom<WallRepr> for Wall {
    type Error = Error;
    fn try_from(repr: WallRepr) -> Result<Self> {
        let mut wall = Wall::new(repr.start, repr.end)?;
        wall.shared = repr.shared;
        wall.length_at_join = repr.length_at_join;
        if repr.shared.iter().any(|&s| s) {
            match repr.length_at_join {
                Some(l) if l.is_finite() && l >= Wall::MIN_LENGTH => {}
                _ => {
                    return Err(Error::InvalidArgument(
                        "a wall with a shared corner needs length_at_join >= 1 mm".into(),
                    ));
                }
            }
        }
        for subspace in repr.active {
            if !wall.allowed_growth().contains(&subspace) {
                return Err(Error::InvalidArgument(format!(
                    "wall subspace list is not reachable: `{}`",
                    subspace.spec().name
                )));
            }
            wall.active.push(subspace);
        }
        Ok(wall)
    }
}

impl Wall {
    /// Shortest wall accepted, in metres: shorter segments have no reliable direction.
    pub const MIN_LENGTH: f64 = 1e-3;

    /// A tentative wall (M-space dimension 0) from `start` to `end`, free side on the left.
    ///
    /// Fails if a coordinate is not finite or the wall is shorter than [`Wall::MIN_LENGTH`].
    pub fn new(start: Vector2<f64>, end: Vector2<f64>) -> Result<Self> {
        let coordinates = Coordinates::new([CoordBlock::Point2(start), CoordBlock::Point2(end)])?;
        Segment2::new(start, end, Self::MIN_LENGTH)?;
        Ok(Wall {
            coordinates,
            active: Vec::new(),
            shared: [false; 2],
            length_at_join: None,
        })
    }

    /// A tentative wall through `a` and `b`, its endpoints ordered so that `viewpoint` (the
    /// sensor that saw it) is on the free side.
    pub fn seen_from(a: Vector2<f64>, b: Vector2<f64>, viewpoint: Vector2<f64>) -> Result<Self> {
        ensure_finite(viewpoint.as_slice(), "wall viewpoint")?;
        let forward = Wall::new(a, b)?;
        if forward.normal().dot(&(viewpoint - a)) >= 0.0 {
            Ok(forward)
        } else {
            Wall::new(b, a)
        }
    }

    /// The start point.
    pub fn start(&self) -> Vector2<f64> {
        self.point(0)
    }

    /// The end point.
    pub fn end(&self) -> Vector2<f64> {
        self.point(1)
    }

    fn point(&self, index: usize) -> Vector2<f64> {
        match self.coordinates.blocks()[index] {
            CoordBlock::Point2(p) => p,
            // The constructor and set_coordinates only admit two Point2 blocks.
            _ => Vector2::new(f64::NAN, f64::NAN),
        }
    }

    fn segment(&self) -> Segment2 {
        Segment2::unchecked(self.start(), self.end())
    }

    /// Length `L`.
    pub fn length(&self) -> f64 {
        self.segment().length
    }

    /// Unit tangent from start to end.
    pub fn tangent(&self) -> Vector2<f64> {
        self.segment().tangent
    }

    /// Unit normal `(cos gamma, sin gamma)` on the free side (eq. 13).
    pub fn normal(&self) -> Vector2<f64> {
        self.segment().normal
    }

    /// `L_s`, the length when the first corner was joined (eq. 33), if a corner is shared.
    pub fn length_at_join(&self) -> Option<f64> {
        self.length_at_join
    }

    /// Whether endpoint `k` (0 start, 1 end) has an estimated tangential position (its
    /// subspace is active or it is a shared corner).
    pub fn end_estimated(&self, k: usize) -> bool {
        let name = if k == 0 { START.name } else { END.name };
        self.is_shared(k) || self.active.iter().any(|s| s.spec().name == name)
    }

    /// The wall grown along its line to cover `points` (their projections onto the line), at
    /// each end whose position is not estimated; `None` when no end moves.
    ///
    /// The start moves by `a` and the end by `b` along the unit tangent `t`:
    /// `s' = s + a t`, `e' = e + b t`, so with `P = I - t t^T` and `L` the length,
    /// `d s' = d s + a P (d e - d s) / L` and `d e' = d e + b P (d e - d s) / L`: the new ends
    /// turn with the wall.
    pub fn extension_over(&self, points: &[Vector2<f64>]) -> Result<Option<Extension>> {
        let (start, end) = (self.start(), self.end());
        let (length, t) = (self.length(), self.tangent());
        let along = points.iter().map(|p| t.dot(&(p - start)));
        let lo = along.clone().fold(f64::INFINITY, f64::min);
        let hi = along.fold(f64::NEG_INFINITY, f64::max);
        let a = if lo < 0.0 && !self.end_estimated(0) {
            lo
        } else {
            0.0
        };
        let b = if hi > length && !self.end_estimated(1) {
            hi - length
        } else {
            0.0
        };
        if a == 0.0 && b == 0.0 {
            return Ok(None);
        }
        let p = (Matrix2::identity() - t * t.transpose()) / length;
        let mut d_new_d_old = DMatrix::identity(4, 4);
        for (row, scale) in [(0, a), (2, b)] {
            let turn = p * scale;
            let mut block = d_new_d_old.view_mut((row, 0), (2, 2));
            block -= turn;
            let mut block = d_new_d_old.view_mut((row, 2), (2, 2));
            block += turn;
        }
        let coordinates = Coordinates::new([
            CoordBlock::Point2(start + t * a),
            CoordBlock::Point2(end + t * b),
        ])?;
        Ok(Some(Extension {
            coordinates,
            d_new_d_old,
        }))
    }

    /// The distances of `points` from this wall's line (positive on the free side), with
    /// their Jacobian with respect to this wall's coordinates (`n x 4`; with respect to a
    /// point, a distance's derivative is the normal [`Wall::normal`]).
    ///
    /// With `u = e - s`, `L = |u|`, the normal `n = J u / L` (`J` the rotation by +90 deg) and
    /// `q = p - s`, the distance is `r = n . q`; `dr/du = (q^T J - r t^T) / L`, `dr/dq = n^T`,
    /// so `dr/ds = -dr/du - n^T` and `dr/de = dr/du`.
    pub fn line_distances(&self, points: &[Vector2<f64>]) -> (DVector<f64>, DMatrix<f64>) {
        let (start, length, t, n) = (self.start(), self.length(), self.tangent(), self.normal());
        let rotate = Matrix2::new(0.0, -1.0, 1.0, 0.0);
        let mut r = DVector::zeros(points.len());
        let mut d_wall = DMatrix::zeros(points.len(), 4);
        for (i, p) in points.iter().enumerate() {
            let q = p - start;
            r[i] = n.dot(&q);
            let d_u = (q.transpose() * rotate - t.transpose() * r[i]) / length;
            let d_s = -d_u - n.transpose();
            d_wall.view_mut((i, 0), (1, 2)).copy_from(&d_s);
            d_wall.view_mut((i, 2), (1, 2)).copy_from(&d_u);
        }
        (r, d_wall)
    }

    /// The wall with its M-space grown by the named subspaces, in order (a convenience for
    /// tests and configuration).
    pub fn with_subspaces(mut self, names: &[&str]) -> Result<Self> {
        for name in names {
            self.activate(name)?;
        }
        Ok(self)
    }

    fn shared_count(&self) -> usize {
        self.shared.iter().filter(|&&s| s).count()
    }

    /// The free endpoint when exactly one endpoint is shared.
    fn free_end(&self) -> Option<usize> {
        match self.shared {
            [true, false] => Some(1),
            [false, true] => Some(0),
            _ => None,
        }
    }

    /// Subspaces that may be activated now.
    fn allowed_growth(&self) -> Vec<WallSubspace> {
        let has = |s| self.active.contains(&s);
        match (self.shared_count(), self.free_end()) {
            (0, _) if !has(WallSubspace::Line) => vec![WallSubspace::Line],
            (0, _) => [WallSubspace::Start, WallSubspace::End]
                .into_iter()
                .filter(|&s| !has(s))
                .collect(),
            (1, Some(_)) if !has(WallSubspace::Pivot) => vec![WallSubspace::Pivot],
            (1, Some(free)) if !has(WallSubspace::tangent_of(free)) => {
                vec![WallSubspace::tangent_of(free)]
            }
            _ => Vec::new(),
        }
    }

    /// Rows of B for one subspace (Table II; eq. 33 for the pivot).
    fn projection_rows(&self, subspace: WallSubspace) -> Result<DMatrix<f64>> {
        let segment = self.checked_segment()?;
        let (n, t, l) = (segment.normal, segment.tangent, segment.length);
        let s2 = std::f64::consts::SQRT_2;
        Ok(match subspace {
            WallSubspace::Line => DMatrix::from_row_slice(
                2,
                4,
                &[
                    n.x / (l * s2),
                    n.y / (l * s2),
                    -n.x / (l * s2),
                    -n.y / (l * s2),
                    n.x / s2,
                    n.y / s2,
                    n.x / s2,
                    n.y / s2,
                ],
            ),
            WallSubspace::Start => DMatrix::from_row_slice(1, 4, &[t.x, t.y, 0.0, 0.0]),
            WallSubspace::End => DMatrix::from_row_slice(1, 4, &[0.0, 0.0, t.x, t.y]),
            WallSubspace::Pivot => {
                let scale = self.pivot_scale(l)?;
                end_row(self.pivot_end()?, n / scale)
            }
        })
    }

    /// Columns of B~ for one subspace (eq. 15; eq. 33 for the pivot).
    fn dual_columns(&self, subspace: WallSubspace) -> Result<DMatrix<f64>> {
        let segment = self.checked_segment()?;
        let (n, t, l) = (segment.normal, segment.tangent, segment.length);
        let s2 = std::f64::consts::SQRT_2;
        Ok(match subspace {
            WallSubspace::Line => DMatrix::from_column_slice(
                4,
                2,
                &[
                    l * n.x / s2,
                    l * n.y / s2,
                    -l * n.x / s2,
                    -l * n.y / s2,
                    n.x / s2,
                    n.y / s2,
                    n.x / s2,
                    n.y / s2,
                ],
            ),
            WallSubspace::Start => DMatrix::from_column_slice(4, 1, &[t.x, t.y, 0.0, 0.0]),
            WallSubspace::End => DMatrix::from_column_slice(4, 1, &[0.0, 0.0, t.x, t.y]),
            WallSubspace::Pivot => {
                let scale = self.pivot_scale(l)?;
                end_row(self.pivot_end()?, n * scale).transpose()
            }
        })
    }

    /// `L / L_s` of eq. 33.
    fn pivot_scale(&self, length: f64) -> Result<f64> {
        match self.length_at_join {
            Some(l_s) if l_s >= Self::MIN_LENGTH => Ok(length / l_s),
            _ => Err(Error::Degenerate(
                "wall pivot without a joined length L_s".into(),
            )),
        }
    }

    fn pivot_end(&self) -> Result<usize> {
        self.free_end()
            .ok_or_else(|| Error::Degenerate("wall pivot needs exactly one shared endpoint".into()))
    }

    fn checked_segment(&self) -> Result<Segment2> {
        Segment2::new(self.start(), self.end(), Self::MIN_LENGTH)
    }
}

/// A 1x4 row with `v` at the columns of endpoint `end`.
fn end_row(end: usize, v: Vector2<f64>) -> DMatrix<f64> {
    let mut row = DMatrix::zeros(1, 4);
    row[(0, 2 * end)] = v.x;
    row[(0, 2 * end + 1)] = v.y;
    row
}

#[typetag::serde(name = "wall")]
impl Feature for Wall {
    fn shape(&self) -> Option<Shape> {
        Some(Shape::Wall {
            start: self.start(),
            end: self.end(),
        })
    }

    /// Another wall facing the same way (within 90 degrees) is this wall when its ends lie
    /// on this wall's line: the residual is their two distances from it
    /// ([`Wall::line_distances`]).
    fn coincidence(&self, other: &dyn Feature) -> Result<Option<Coincidence>> {
        let Some(other) = downcast_feature::<Wall>(other) else {
            return Ok(None);
        };
        if other.tangent().dot(&self.tangent()) <= 0.0 {
            return Ok(None);
        }
        let ends = [other.start(), other.end()];
        let (residual, d_self) = self.line_distances(&ends);
        let n = self.normal().transpose();
        let mut d_other = DMatrix::zeros(2, 4);
        d_other.view_mut((0, 0), (1, 2)).copy_from(&n);
        d_other.view_mut((1, 2), (1, 2)).copy_from(&n);
        Ok(Some(Coincidence {
            residual,
            d_self,
            d_other,
        }))
    }

    /// Grown over the other wall's ends ([`Wall::extension_over`]).
    fn absorbed(&self, other: &dyn Feature) -> Result<Option<Extension>> {
        match downcast_feature::<Wall>(other) {
            Some(other) => self.extension_over(&[other.start(), other.end()]),
            None => Ok(None),
        }
    }

    /// The segment (strong once an end or a corner is estimated), with a marker and the 95 %
    /// ellipse at each estimated end (filled where the end is a shared corner).
    fn sketch(&self) -> Sketch {
        let shared_dims = 2 * (0..2).filter(|&k| self.is_shared(k)).count();
        let (ink, label) = if self.mspace_dim() + shared_dims >= 3 {
            (Ink::Wall, "walls with an estimated end or corner")
        } else {
            (Ink::WallLineOnly, "walls, line only (dim 2)")
        };
        let mut sketch = Sketch::new(label, ink).with(Mark::Segment {
            from: self.start(),
            to: self.end(),
            ink,
            width: 4,
        });
        for (k, end) in [self.start(), self.end()].into_iter().enumerate() {
            let subspace = if k == 0 { "start" } else { "end" };
            let estimated =
                self.is_shared(k) || self.active_subspaces().iter().any(|s| s.name == subspace);
            if estimated {
                sketch.marks.push(Mark::Marker {
                    at: end,
                    ink: Ink::Corner,
                    size: 8,
                    filled: self.is_shared(k),
                });
                sketch.marks.push(Mark::Ellipse {
                    offset: 2 * k,
                    at: end,
                    ink: Ink::Corner,
                });
            }
        }
        sketch
    }

    fn kind(&self) -> &'static str {
        "wall"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        let (start, end) = match coordinates.blocks() {
            [CoordBlock::Point2(s), CoordBlock::Point2(e)] => (*s, *e),
            _ => {
                return Err(Error::InvalidArgument(
                    "a wall's coordinates are two 2-D points".into(),
                ));
            }
        };
        let segment = Segment2::new(start, end, Self::MIN_LENGTH)?;
        if segment.tangent.dot(&self.tangent()) <= 0.0 {
            return Err(Error::Degenerate(
                "wall update reverses its direction (the free side would flip)".into(),
            ));
        }
        self.coordinates = coordinates;
        Ok(())
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        self.active.iter().map(|s| s.spec()).collect()
    }

    /// The rows of the active subspaces, without collecting them.
    fn mspace_dim(&self) -> usize {
        self.active.iter().map(|s| s.spec().rows).sum()
    }

    fn growth_options(&self) -> Vec<Subspace> {
        self.allowed_growth()
            .into_iter()
            .map(WallSubspace::spec)
            .collect()
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        let wanted = self
            .allowed_growth()
            .into_iter()
            .find(|s| s.spec().name == subspace)
            .ok_or_else(|| Error::Growth {
                feature: "wall",
                subspace: subspace.to_string(),
                reason: format!(
                    "not available now (active {:?}, shared {:?})",
                    self.active, self.shared
                ),
            })?;
        let before = self.mspace_dim();
        self.active.push(wanted);
        Ok(Growth {
            subspace: wanted.spec(),
            rows: before..before + wanted.spec().rows,
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        stack_rows(4, &self.active, |&s| self.projection_rows(s))
    }

    fn dual(&self) -> Result<DMatrix<f64>> {
        let columns = stack_rows(4, &self.active, |&s| {
            self.dual_columns(s).map(|c| c.transpose())
        })?;
        Ok(columns.transpose())
    }

    fn shareable_blocks(&self) -> Vec<usize> {
        vec![0, 1]
    }

    fn is_shared(&self, index: usize) -> bool {
        self.shared.get(index).copied().unwrap_or(false)
    }

    /// Only another wall at least [`MIN_CORNER_ANGLE_DEG`] from parallel: two nearly
    /// parallel walls with a common end are one wall mapped twice (folded onto itself) or a
    /// wall continued past a gap, and a corner between them would pin a wall's direction to
    /// a point on the other.
    fn may_share_with(&self, _index: usize, other: &dyn Feature, _other_index: usize) -> bool {
        downcast_feature::<Wall>(other).is_some_and(|other| {
            self.tangent().perp(&other.tangent()).abs() >= MIN_CORNER_ANGLE_DEG.to_radians().sin()
        })
    }

    /// Re-parameterizes for a shared corner at endpoint `index` (eq. 33): `"line"` becomes
    /// `"pivot"` about the corner, and the corner's tangential row moves to the shared block.
    /// With the second corner shared the pivot goes too: the wall has no own rows.
    fn share_block(&mut self, index: usize) -> Result<()> {
        if index > 1 || self.shared[index] {
            return Err(Error::Sharing(format!(
                "wall endpoint {index} is not a free endpoint"
            )));
        }
        let length = self.checked_segment()?.length;
        let first_corner = self.shared_count() == 0;
        self.active
            .retain(|&s| s != WallSubspace::tangent_of(index));
        if first_corner {
            self.length_at_join = Some(length);
            for s in &mut self.active {
                if *s == WallSubspace::Line {
                    *s = WallSubspace::Pivot;
                }
            }
        } else {
            self.active.retain(|&s| s != WallSubspace::Pivot);
        }
        self.shared[index] = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam_core::nalgebra::DVector;

    fn wall() -> Wall {
        Wall::new(Vector2::new(1.0, 1.0), Vector2::new(5.0, 1.0)).unwrap()
    }

    /// A corner held by two walls takes a third member ([`FeatureMap::join_shared`]: a merged
    /// duplicate's corner passing to the wall kept), and a removed member leaves it
    /// ([`FeatureMap::remove_from_shared`]); the map stays consistent (its serialized form
    /// is validated on reading), and the last member cannot leave.
    #[test]
    fn a_corner_takes_a_third_wall_and_loses_a_removed_one() {
        use slam_core::FeatureMap;
        let v = Vector2::new;
        let mut map = FeatureMap::new();
        let a = map
            .insert(Box::new(Wall::new(v(0.0, 0.0), v(2.0, 0.0)).unwrap()))
            .unwrap();
        let b = map
            .insert(Box::new(Wall::new(v(2.0, 0.0), v(2.0, 2.0)).unwrap()))
            .unwrap();
        let c = map
            .insert(Box::new(Wall::new(v(4.0, 0.02), v(2.02, 0.0)).unwrap()))
            .unwrap();
        let corner = map
            .share(&[(a, 1), (b, 0)], CoordBlock::Point2(v(2.0, 0.0)))
            .unwrap();
        map.join_shared(c, 1, corner).unwrap();
        assert!(map.join_shared(c, 1, corner).is_err(), "already shared");
        let members = |map: &FeatureMap| map.shared_block(corner).unwrap().members.clone();
        assert_eq!(members(&map), vec![(a, 1), (b, 0), (c, 1)]);
        assert_eq!(
            map.get(c).unwrap().coordinates().block(1),
            Some(&CoordBlock::Point2(v(2.0, 0.0)))
        );
        let roundtrip = |map: &FeatureMap| -> FeatureMap {
            serde_json::from_str(&serde_json::to_string(map).unwrap()).unwrap()
        };
        roundtrip(&map).check_consistency().unwrap();
        map.remove_from_shared(a).unwrap();
        map.remove_from_shared(b).unwrap();
        assert_eq!(members(&map), vec![(c, 1)]);
        assert!(map.remove_from_shared(c).is_err(), "the last member stays");
        assert!(map.get(c).is_ok());
        assert_eq!(roundtrip(&map).len(), 1);
        assert!(map.get(a).is_err());
    }

    /// A corner needs an angle: a wall at 90 or 35 degrees may share the end, a wall folded
    /// back onto this one or continuing it at 10 degrees may not, and a pole never.
    #[test]
    fn walls_share_a_corner_only_at_an_angle() {
        let end = Vector2::new(5.0, 1.0);
        let at = |degrees: f64| {
            let direction = Vector2::new(degrees.to_radians().cos(), degrees.to_radians().sin());
            Wall::new(end, end + 3.0 * direction).unwrap()
        };
        let this = wall();
        for (degrees, allowed) in [(90.0, true), (35.0, true), (-145.0, true), (10.0, false)] {
            assert_eq!(
                this.may_share_with(1, &at(degrees), 0),
                allowed,
                "{degrees} degrees"
            );
            assert_eq!(
                at(degrees).may_share_with(0, &this, 1),
                allowed,
                "{degrees} degrees"
            );
        }
        let folded = Wall::new(Vector2::new(1.2, 1.08), end).unwrap();
        assert!(!this.may_share_with(1, &folded, 1));
        let pole = crate::Pole::new(0.1, end).unwrap();
        assert!(!this.may_share_with(1, &pole, 0));
    }

    #[test]
    fn full_projection_matches_table_ii() {
        let w = wall().with_subspaces(&["line", "start", "end"]).unwrap();
        let b = w.projection().unwrap();
        // Normal points left of start->end: +y; gamma = 90 degrees; L = 4.
        let s2 = std::f64::consts::SQRT_2;
        let expected = DMatrix::from_row_slice(
            4,
            4,
            &[
                0.0,
                1.0 / (4.0 * s2),
                0.0,
                -1.0 / (4.0 * s2),
                0.0,
                1.0 / s2,
                0.0,
                1.0 / s2,
                1.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                1.0,
                0.0,
            ],
        );
        assert!((b - expected).amax() < 1e-15);
    }

    #[test]
    fn line_perturbation_is_rotation_and_offset() {
        let mut w = wall().with_subspaces(&["line"]).unwrap();
        // dp_2 = sqrt(2) * normal offset of the centre.
        w.apply_perturbation(&DVector::from_vec(vec![
            0.0,
            0.1 * std::f64::consts::SQRT_2,
        ]))
        .unwrap();
        assert!((w.start() - Vector2::new(1.0, 1.1)).amax() < 1e-12);
        assert!((w.end() - Vector2::new(5.0, 1.1)).amax() < 1e-12);
        // dp_1 = -angle / sqrt(2): a small rotation about the centre, no tangential motion.
        let mut r = wall().with_subspaces(&["line"]).unwrap();
        r.apply_perturbation(&DVector::from_vec(vec![
            -0.01 / std::f64::consts::SQRT_2,
            0.0,
        ]))
        .unwrap();
        assert!((r.start() - Vector2::new(1.0, 1.0 - 0.02)).amax() < 1e-12);
        assert!((r.end() - Vector2::new(5.0, 1.0 + 0.02)).amax() < 1e-12);
    }

    #[test]
    fn seen_from_puts_the_viewer_on_the_free_side() {
        let w = Wall::seen_from(
            Vector2::new(0.0, 0.0),
            Vector2::new(2.0, 0.0),
            Vector2::new(1.0, -3.0),
        )
        .unwrap();
        assert!(w.normal().y < 0.0);
        assert_eq!(w.start(), Vector2::new(2.0, 0.0));
    }

    #[test]
    fn corner_dual_follows_eq_33() {
        let mut w = wall().with_subspaces(&["line"]).unwrap();
        w.share_block(1).unwrap();
        assert_eq!(w.length_at_join(), Some(4.0));
        // Extend the wall by moving the free start point along the wall: L = 6, L_s = 4.
        let mut c = w.coordinates().clone();
        c.set_block(0, CoordBlock::Point2(Vector2::new(-1.0, 1.0)))
            .unwrap();
        w.set_coordinates(c).unwrap();
        let dual = w.dual().unwrap();
        let expected = DMatrix::from_column_slice(4, 1, &[0.0, 6.0 / 4.0, 0.0, 0.0]);
        assert!((dual - expected).amax() < 1e-15);
        let b = w.projection().unwrap();
        assert!((b[(0, 1)] - 4.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn flipping_or_collapsing_updates_are_refused() {
        let mut w = wall().with_subspaces(&["line", "start"]).unwrap();
        let before = w.clone();
        assert!(
            w.apply_perturbation(&DVector::from_vec(vec![0.0, 0.0, 4.0]))
                .is_err()
        );
        assert!(
            w.apply_perturbation(&DVector::from_vec(vec![0.0, 0.0, 5.0]))
                .is_err()
        );
        assert!(
            w.apply_perturbation(&DVector::from_vec(vec![0.0, f64::NAN, 0.0]))
                .is_err()
        );
        assert_eq!(w, before);
    }

    #[test]
    fn unknown_or_unreachable_serde_is_an_error() {
        let json = r#"{"type":"wall","start":[0,0],"end":[0,0],"active":[]}"#;
        assert!(serde_json::from_str::<Box<dyn Feature>>(json).is_err());
        let json = r#"{"type":"wall","start":[0,0],"end":[1,0],"active":["start"]}"#;
        assert!(serde_json::from_str::<Box<dyn Feature>>(json).is_err());
        let json = r#"{"type":"wall","start":[0,0],"end":[1,0],"active":["line"],"colour":1}"#;
        assert!(serde_json::from_str::<Box<dyn Feature>>(json).is_err());
        let json = r#"{"type":"wall","start":[0,0],"end":[1,0],"active":["line","end"]}"#;
        let back = serde_json::from_str::<Box<dyn Feature>>(json).unwrap();
        assert_eq!(back.mspace_dim(), 3);
    }
}
