//! Pieces of the feature lifecycle shared by the estimators ([`crate::Ekf`] and
//! [`crate::FastSlam`]): the spatial pre-filter of association candidates, the priors of
//! new M-space rows, and the placement of a feature that its views triangulate.

use std::collections::BTreeMap;

use slam_core::nalgebra::DMatrix;
use slam_core::{
    CoordBlock, Coordinates, DynMeasurementModel, Error, Feature, Growth, Pose3, Result, Subspace,
};

/// A horizontal axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BoundingBox {
    lo: [f64; 2],
    hi: [f64; 2],
}

impl Default for BoundingBox {
    fn default() -> Self {
        BoundingBox {
            lo: [f64::INFINITY; 2],
            hi: [f64::NEG_INFINITY; 2],
        }
    }
}

impl BoundingBox {
    /// The box of the x, y values of every point block (scalars ignored).
    pub(crate) fn of(coordinates: &Coordinates) -> Self {
        let mut bbox = BoundingBox::default();
        for block in coordinates.blocks() {
            let (x, y) = match block {
                CoordBlock::Point3(p) => (p.x, p.y),
                CoordBlock::Point2(p) => (p.x, p.y),
                CoordBlock::Scalar(_) => continue,
            };
            bbox.lo = [bbox.lo[0].min(x), bbox.lo[1].min(y)];
            bbox.hi = [bbox.hi[0].max(x), bbox.hi[1].max(y)];
        }
        bbox
    }

    /// Whether the boxes come within `margin` of each other.
    pub(crate) fn near(&self, other: &BoundingBox, margin: f64) -> bool {
        (0..2).all(|k| self.lo[k] - margin <= other.hi[k] && other.lo[k] - margin <= self.hi[k])
    }
}

/// The first growth option revealed at least `threshold` times (the lifecycle's
/// confirmation rule).
pub(crate) fn ready_subspace(
    options: &[Subspace],
    revealed: &BTreeMap<&'static str, usize>,
    threshold: usize,
) -> Option<Subspace> {
    options
        .iter()
        .find(|s| revealed.get(s.name).copied().unwrap_or(0) >= threshold)
        .copied()
}

/// The prior covariance of the rows `growth` added: the feature's own
/// ([`Feature::growth_prior`]) when valid, else `default_variance` times the identity.
pub(crate) fn growth_prior(
    feature: &dyn Feature,
    growth: &Growth,
    default_variance: f64,
) -> DMatrix<f64> {
    let n = growth.rows.len();
    feature
        .growth_prior(growth)
        .filter(|p| p.shape() == (n, n) && p.iter().all(|v| v.is_finite()))
        .unwrap_or_else(|| DMatrix::identity(n, n) * default_variance)
}

/// Block-diagonal stack of priors that must fill exactly `added` rows.
pub(crate) fn stack_priors(priors: &[DMatrix<f64>], added: usize) -> Result<DMatrix<f64>> {
    let mut block = DMatrix::zeros(added, added);
    let mut at = 0;
    for prior in priors {
        let n = prior.nrows();
        if at + n > added {
            return Err(Error::DimensionMismatch {
                what: "growth priors".into(),
                expected: added,
                got: at + n,
            });
        }
        block.view_mut((at, at), (n, n)).copy_from(prior);
        at += n;
    }
    Ok(block)
}

/// The feature grown by the subspaces that `measurement` (taken at `current`) and the
/// earlier views `others` triangulate, or `None` while they do not triangulate it or reveal
/// nothing new. The new coordinates keep the already-estimated directions:
/// `x_new = x_tri - B~_new P_old B_new (x_tri - x_old)`, `P_old` selecting the old rows.
pub(crate) fn placed_by_triangulation(
    feature: &dyn Feature,
    measurement: &dyn DynMeasurementModel,
    current: &Pose3,
    others: &[(Pose3, &dyn DynMeasurementModel)],
) -> Result<Option<Box<dyn Feature>>> {
    let options = feature.growth_options();
    let blocks = feature.coordinates().num_blocks();
    if options.is_empty() || others.is_empty() || (0..blocks).any(|k| feature.is_shared(k)) {
        return Ok(None);
    }
    let Ok(Some(triangulated)) = measurement.triangulate_dyn(current, others) else {
        return Ok(None);
    };
    let reveals: Vec<&'static str> = triangulated
        .reveals
        .iter()
        .copied()
        .filter(|name| options.iter().any(|s| s.name == *name))
        .collect();
    if reveals.is_empty() {
        return Ok(None);
    }
    let old_dim = feature.mspace_dim();
    let mut grown = slam_core::dyn_clone::clone_box(feature);
    for name in &reveals {
        grown.activate(name)?;
    }
    let x_old = feature.coordinates().to_vector();
    let x_tri = feature
        .conform(triangulated.feature.coordinates().clone())
        .to_vector();
    let x_new = if old_dim == 0 {
        x_tri
    } else {
        let b = grown.projection()?;
        let b_dual = grown.dual()?;
        let change = &x_tri - &x_old;
        let kept = b_dual.columns(0, old_dim) * (b.rows(0, old_dim) * change);
        x_tri - kept
    };
    let coordinates = feature.coordinates().with_vector(&x_new)?;
    // Views that place the feature where it cannot go (a line turned around) are ignored:
    // no growth this time.
    if grown.set_coordinates(coordinates).is_err() {
        return Ok(None);
    }
    Ok(Some(grown))
}
