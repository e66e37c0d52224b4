//! Growth by triangulation: a feature that one measurement cannot place (a bearing-only
//! lamp, a ceiling line's position) is placed by several views of it.

use slam_core::{DynMeasurementModel, Feature, Pose3, Result, Skips};

/// The feature grown by the subspaces that `measurement` (taken at `current`) and the
/// earlier views `others` triangulate, or `None` while they do not triangulate it or reveal
/// nothing new. The new coordinates keep the already-estimated directions:
/// `x_new = x_tri - B~_new P_old B_new (x_tri - x_old)`, `P_old` selecting the old rows.
pub(crate) fn placed_by_triangulation(
    feature: &dyn Feature,
    measurement: &dyn DynMeasurementModel,
    current: &Pose3,
    others: &[(Pose3, &dyn DynMeasurementModel)],
    skips: &mut Skips,
) -> Result<Option<Box<dyn Feature>>> {
    let options = feature.growth_options();
    let blocks = feature.coordinates().num_blocks();
    if options.is_empty() || others.is_empty() || (0..blocks).any(|k| feature.is_shared(k)) {
        return Ok(None);
    }
    let triangulated = match measurement.triangulate_dyn(current, others) {
        Ok(Some(t)) => t,
        Ok(None) => return Ok(None),
        Err(_) => {
            skips.count("growth: triangulation failed");
            return Ok(None);
        }
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
        skips.count("growth: triangulated coordinates refused by the feature");
        return Ok(None);
    }
    Ok(Some(grown))
}
