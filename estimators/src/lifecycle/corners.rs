//! Which blocks of two features may become one shared corner (paper section VI): both
//! shareable, free, fully estimated, of one kind, within `corner_distance` of each other and
//! allowed by the features themselves ([`slam_core::Feature::may_share_with`]: walls at an
//! angle).
//! The statistical test and the re-parameterization of the covariance are the estimator's
//! (`crate::ekf`).

use slam_core::{CoordBlock, Coordinates, Feature, FeatureId, FeatureMap, Result};

use crate::association::BoundingBox;

/// Whether block `k` of `feature` is fully in its own M-space (`E_k B~` has full row rank): a
/// wall end seen as a real end.
pub(crate) fn block_estimated(feature: &dyn Feature, k: usize) -> Result<bool> {
    if feature.mspace_dim() == 0 {
        return Ok(false);
    }
    let coordinates = feature.coordinates();
    let dim = coordinates.blocks()[k].dim();
    let rows = feature
        .dual()?
        .rows(coordinates.offset(k), dim)
        .into_owned();
    if rows.ncols() < dim {
        return Ok(false);
    }
    let singular = rows.singular_values();
    let largest = singular.max();
    Ok(singular.len() == dim && largest > 0.0 && singular.min() > 1e-6 * largest.max(1.0))
}

/// The free shareable blocks of block `k` of feature `id` could join with: blocks of other
/// confirmed features, of the same kind, within `corner_distance`, not shared yet, fully
/// estimated and allowed by both features, in map order.
pub(crate) fn corner_partners(
    map: &FeatureMap,
    id: FeatureId,
    k: usize,
    corner_distance: f64,
    confirmed: &dyn Fn(FeatureId) -> bool,
) -> Result<Vec<(FeatureId, usize)>> {
    let this = map.get(id)?;
    let value = this.coordinates().blocks()[k];
    let here = BoundingBox::of(&Coordinates::new([value])?);
    let mut partners = Vec::new();
    for (other, feature) in map.iter() {
        if other == id
            || !confirmed(other)
            || !BoundingBox::of(feature.coordinates()).near(&here, corner_distance)
        {
            continue;
        }
        for j in feature.shareable_blocks() {
            let block = feature.coordinates().blocks()[j];
            if block.kind() != value.kind()
                || distance(&block, &value) > corner_distance
                || !this.may_share_with(k, feature, j)
                || !feature.may_share_with(j, this, k)
            {
                continue;
            }
            if map.links(other)?[j].is_none() && block_estimated(feature, j)? {
                partners.push((other, j));
            }
        }
    }
    Ok(partners)
}

/// The block of feature `id` that can take over a shared block of value `corner` from a
/// duplicate merged into it: its free (not shared, not in `taken`), fully estimated,
/// shareable block of the same kind nearest to `corner`, if within `corner_distance`.
pub(crate) fn heir_block(
    map: &FeatureMap,
    id: FeatureId,
    corner: &CoordBlock,
    taken: &[usize],
    corner_distance: f64,
) -> Result<Option<usize>> {
    let feature = map.get(id)?;
    let links = map.links(id)?;
    let nearest = feature
        .shareable_blocks()
        .into_iter()
        .filter(|k| links[*k].is_none() && !taken.contains(k))
        .map(|k| (k, feature.coordinates().blocks()[k]))
        .filter(|(_, block)| block.kind() == corner.kind())
        .map(|(k, block)| (k, distance(&block, corner)))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    match nearest {
        Some((k, d)) if d <= corner_distance && block_estimated(feature, k)? => Ok(Some(k)),
        _ => Ok(None),
    }
}

/// Euclidean distance between two blocks of the same kind.
fn distance(a: &CoordBlock, b: &CoordBlock) -> f64 {
    a.as_slice()
        .iter()
        .zip(b.as_slice())
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}
