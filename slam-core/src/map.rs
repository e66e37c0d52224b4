//! A map of features with shared coordinate blocks (paper section VI).
//!
//! The map owns the features and the shared blocks. It tells an estimator which M-space rows
//! exist ([`RowOwner`]): each feature's own rows, and one set of identity rows per shared block,
//! so that the end point of wall A and the start point of wall B "map to the same rows of the
//! covariance matrix". Updating a shared block moves it in every feature that holds it.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::coords::CoordBlock;
use crate::error::{Error, Result, ensure_finite};
use crate::feature::{Feature, Growth};
use crate::measurement::{DynMeasurementModel, LinearizedMeasurement, SensorFrame, linearize_at};
use crate::pose::{Pose3, RobotPose};

/// Identifies a feature in a [`FeatureMap`]; never reused after removal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct FeatureId(pub usize);

/// Identifies a shared coordinate block in a [`FeatureMap`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct SharedBlockId(pub usize);

/// Who owns a group of M-space rows: a feature (its own rows) or a shared block (identity rows).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum RowOwner {
    /// The own M-space rows of a feature, `mspace_dim()` of them.
    Feature(FeatureId),
    /// The rows of a shared block, as many as the block has coordinates.
    Shared(SharedBlockId),
}

/// A linear map of an estimator's rows: the rows of `owners` (concatenated, with their
/// sizes) become `matrix` times themselves (see
/// [`FeatureMap::set_coordinates_outside_mspace`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RowTransform {
    /// The row owners, in the order of the matrix's rows and columns, with their sizes.
    pub owners: Vec<(RowOwner, usize)>,
    /// The square map.
    pub matrix: DMatrix<f64>,
}

/// A coordinate block held by several features (a wall corner).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SharedBlock {
    /// The block's value in the map frame.
    pub value: CoordBlock,
    /// The features holding it, with the block index in each.
    pub members: Vec<(FeatureId, usize)>,
}

/// The columns of `J_eta,state` (eq. 30) for one measurement, keyed by row owner.
#[derive(Clone, Debug, PartialEq)]
pub struct MapLinearization {
    /// The linearized measurement (robot and sensor-offset columns, innovation, covariance).
    pub measurement: LinearizedMeasurement,
    /// `(owner, columns)` for the feature's own rows (if any) and each shared block it holds.
    pub columns: Vec<(RowOwner, DMatrix<f64>)>,
}

/// Features and their shared blocks.
///
/// ```
/// use slam_core::FeatureMap;
/// let map = FeatureMap::new();
/// assert_eq!(map.len(), 0);
/// ```
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(try_from = "FeatureMapRepr")]
pub struct FeatureMap {
    features: Vec<Option<Box<dyn Feature>>>,
    /// Per feature, per block: the shared block it is linked to.
    links: Vec<Vec<Option<SharedBlockId>>>,
    shared: Vec<Option<SharedBlock>>,
}

/// The serialized form, validated into a [`FeatureMap`].
#[derive(Deserialize)]
struct FeatureMapRepr {
    features: Vec<Option<Box<dyn Feature>>>,
    links: Vec<Vec<Option<SharedBlockId>>>,
    shared: Vec<Option<SharedBlock>>,
}

impl TryFrom<FeatureMapRepr> for FeatureMap {
    type Error = Error;
    fn try_from(repr: FeatureMapRepr) -> Result<Self> {
        let map = FeatureMap {
            features: repr.features,
            links: repr.links,
            shared: repr.shared,
        };
        map.check_links()?;
        map.check_consistency()?;
        Ok(map)
    }
}

impl FeatureMap {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of features.
    pub fn len(&self) -> usize {
        self.features.iter().filter(|f| f.is_some()).count()
    }

    /// True when the map holds no feature.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Adds a feature; its blocks start unshared.
    pub fn insert(&mut self, feature: Box<dyn Feature>) -> Result<FeatureId> {
        let blocks = feature.coordinates().num_blocks();
        if (0..blocks).any(|k| feature.is_shared(k)) {
            return Err(Error::Sharing(
                "insert features unshared; share blocks through FeatureMap::share".into(),
            ));
        }
        self.features.push(Some(feature));
        self.links.push(vec![None; blocks]);
        Ok(FeatureId(self.features.len() - 1))
    }

    /// The feature `id`.
    pub fn get(&self, id: FeatureId) -> Result<&dyn Feature> {
        self.features
            .get(id.0)
            .and_then(|f| f.as_deref())
            .ok_or(Error::UnknownId {
                what: "feature",
                id: id.0,
            })
    }

    /// Removes a feature that holds no shared block.
    pub fn remove(&mut self, id: FeatureId) -> Result<Box<dyn Feature>> {
        self.get(id)?;
        if self.links[id.0].iter().any(Option::is_some) {
            return Err(Error::Sharing(format!(
                "feature {} holds a shared block; it cannot be removed alone",
                id.0
            )));
        }
        self.features[id.0].take().ok_or(Error::UnknownId {
            what: "feature",
            id: id.0,
        })
    }

    /// All features with their ids.
    pub fn iter(&self) -> impl Iterator<Item = (FeatureId, &dyn Feature)> {
        self.features
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f.as_deref().map(|f| (FeatureId(i), f)))
    }

    /// The shared block `id`.
    pub fn shared_block(&self, id: SharedBlockId) -> Result<&SharedBlock> {
        self.shared
            .get(id.0)
            .and_then(Option::as_ref)
            .ok_or(Error::UnknownId {
                what: "shared block",
                id: id.0,
            })
    }

    /// All shared blocks with their ids.
    pub fn shared_blocks(&self) -> impl Iterator<Item = (SharedBlockId, &SharedBlock)> {
        self.shared
            .iter()
            .enumerate()
            .filter_map(|(i, b)| b.as_ref().map(|b| (SharedBlockId(i), b)))
    }

    /// For each block of feature `id`, the shared block it is linked to.
    pub fn links(&self, id: FeatureId) -> Result<&[Option<SharedBlockId>]> {
        self.get(id)?;
        Ok(&self.links[id.0])
    }

    /// The row groups that a measurement of feature `id` touches, with their sizes:
    /// the feature's own rows (if it has any) and each shared block it holds.
    pub fn row_owners(&self, id: FeatureId) -> Result<Vec<(RowOwner, usize)>> {
        let feature = self.get(id)?;
        let mut owners = Vec::new();
        if feature.mspace_dim() > 0 {
            owners.push((RowOwner::Feature(id), feature.mspace_dim()));
        }
        for (k, link) in self.links[id.0].iter().enumerate() {
            if let Some(shared) = link {
                owners.push((
                    RowOwner::Shared(*shared),
                    feature.coordinates().blocks()[k].dim(),
                ));
            }
        }
        Ok(owners)
    }

    /// Makes one block shared by several features (a corner of two walls) with the given
    /// value: each member re-parameterizes its own rows ([`Feature::share_block`], eq. 33)
    /// and takes the value. All or nothing: on error the map is unchanged.
    pub fn share(
        &mut self,
        members: &[(FeatureId, usize)],
        value: CoordBlock,
    ) -> Result<SharedBlockId> {
        ensure_finite(value.as_slice(), "shared block value")?;
        if members.is_empty() {
            return Err(Error::Sharing(
                "a shared block needs at least one member".into(),
            ));
        }
        let mut updated = Vec::with_capacity(members.len());
        for (i, &(id, block)) in members.iter().enumerate() {
            if members[..i].iter().any(|&(other, _)| other == id) {
                return Err(Error::Sharing(format!("feature {} listed twice", id.0)));
            }
            updated.push(self.sharing(id, block, value)?);
        }
        let shared_id = SharedBlockId(self.shared.len());
        for (&(id, block), feature) in members.iter().zip(updated) {
            self.features[id.0] = Some(feature);
            self.links[id.0][block] = Some(shared_id);
        }
        self.shared.push(Some(SharedBlock {
            value,
            members: members.to_vec(),
        }));
        Ok(shared_id)
    }

    /// Feature `id` as it would be with its free block `block` shared at `value` (the
    /// checks and the re-parameterization of [`Self::share`] and [`Self::join_shared`]).
    fn sharing(&self, id: FeatureId, block: usize, value: CoordBlock) -> Result<Box<dyn Feature>> {
        let feature = self.get(id)?;
        let current = feature
            .coordinates()
            .block(block)
            .ok_or_else(|| Error::Sharing(format!("feature {} has no block {block}", id.0)))?;
        if current.kind() != value.kind() {
            return Err(Error::BlockKindMismatch {
                index: block,
                expected: current.kind(),
                got: value.kind(),
            });
        }
        if self.links[id.0][block].is_some() {
            return Err(Error::Sharing(format!(
                "block {block} of feature {} is already shared",
                id.0
            )));
        }
        let mut candidate = dyn_clone::clone_box(feature);
        candidate.set_block(block, value)?;
        candidate.share_block(block)?;
        Ok(candidate)
    }

    /// Makes block `block` of feature `id` a member of the existing shared block `shared` (a
    /// third wall reaching a corner, or a merged duplicate's corner passing to the wall
    /// kept): the feature re-parameterizes its own rows ([`Feature::share_block`], eq. 33)
    /// and takes the shared value. All or nothing: on error the map is unchanged.
    pub fn join_shared(
        &mut self,
        id: FeatureId,
        block: usize,
        shared: SharedBlockId,
    ) -> Result<()> {
        let value = self.shared_block(shared)?.value;
        let candidate = self.sharing(id, block, value)?;
        self.features[id.0] = Some(candidate);
        self.links[id.0][block] = Some(shared);
        if let Some(Some(entry)) = self.shared.get_mut(shared.0) {
            entry.members.push((id, block));
        }
        Ok(())
    }

    /// Removes a feature together with its memberships of shared blocks (a merged duplicate
    /// whose corners have passed to the feature kept). Every shared block it holds must keep
    /// another member: a block's rows stay in the estimator. On error the map is unchanged.
    pub fn remove_from_shared(&mut self, id: FeatureId) -> Result<Box<dyn Feature>> {
        self.get(id)?;
        for shared in self.links[id.0].iter().flatten() {
            let block = self.shared_block(*shared)?;
            if !block.members.iter().any(|(member, _)| *member != id) {
                return Err(Error::Sharing(format!(
                    "feature {} is the last member of shared block {}",
                    id.0, shared.0
                )));
            }
        }
        for shared in std::mem::take(&mut self.links[id.0]).into_iter().flatten() {
            if let Some(Some(entry)) = self.shared.get_mut(shared.0) {
                entry.members.retain(|(member, _)| *member != id);
            }
        }
        let feature = self.features[id.0].take().ok_or(Error::UnknownId {
            what: "feature",
            id: id.0,
        })?;
        self.links[id.0] = vec![None; feature.coordinates().num_blocks()];
        Ok(feature)
    }

    /// Grows feature `id` by the named subspace ([`Feature::activate`]).
    pub fn activate(&mut self, id: FeatureId, subspace: &str) -> Result<Growth> {
        self.get(id)?;
        let feature = self.features[id.0].as_deref_mut().ok_or(Error::UnknownId {
            what: "feature",
            id: id.0,
        })?;
        feature.activate(subspace)
    }

    /// Replaces feature `id` by another feature with the same block layout (e.g. a tentative
    /// feature by its triangulated version). Features holding a shared block cannot be
    /// replaced; the caller keeps its estimator rows consistent with the new M-space.
    pub fn replace(&mut self, id: FeatureId, feature: Box<dyn Feature>) -> Result<()> {
        let current = self.get(id)?;
        if self.links[id.0].iter().any(Option::is_some) {
            return Err(Error::Sharing(format!(
                "feature {} holds a shared block; it cannot be replaced",
                id.0
            )));
        }
        if current.coordinates().layout() != feature.coordinates().layout() {
            return Err(Error::InvalidArgument(format!(
                "replacing feature {}: block layout {:?} differs from {:?}",
                id.0,
                feature.coordinates().layout(),
                current.coordinates().layout()
            )));
        }
        if (0..feature.coordinates().num_blocks()).any(|k| feature.is_shared(k)) {
            return Err(Error::Sharing(
                "a replacement feature must hold no shared block".into(),
            ));
        }
        self.features[id.0] = Some(feature);
        Ok(())
    }

    /// Sets the coordinates of feature `id` where they differ only **outside** its M-space:
    /// `|B (x_new - x_old)| <= tolerance` and shared blocks unchanged (a wall's extent growing
    /// along its line, section IV).
    ///
    /// Returns how the estimator's rows carry over (`None` for a feature without own rows):
    /// the feature's own rows become `dx_p' = B(x_new) D (B~(x_old) dx_p + sum_k E_k dx_k)`,
    /// `D` the extension's `d_new_d_old` and `dx_k` the rows of its shared blocks (which stay
    /// as they are), because the rows now describe the feature at its new coordinates.
    pub fn set_coordinates_outside_mspace(
        &mut self,
        id: FeatureId,
        extension: crate::Extension,
        tolerance: f64,
    ) -> Result<Option<RowTransform>> {
        let feature = self.get(id)?;
        let old = feature.coordinates();
        let coordinates = extension.coordinates;
        let n = old.dim();
        let d = &extension.d_new_d_old;
        if old.layout() != coordinates.layout() || d.shape() != (n, n) {
            return Err(Error::InvalidArgument(format!(
                "extension of feature {}: another block layout or a Jacobian of the wrong size",
                id.0
            )));
        }
        ensure_finite(d.as_slice(), "extension Jacobian")?;
        for (k, link) in self.links[id.0].iter().enumerate() {
            if link.is_some() && old.blocks()[k] != coordinates.blocks()[k] {
                return Err(Error::Sharing(format!(
                    "block {k} of feature {} is shared and cannot move outside the M-space",
                    id.0
                )));
            }
        }
        let change = coordinates.to_vector() - old.to_vector();
        let own = feature.mspace_dim();
        let mut candidate = dyn_clone::clone_box(feature);
        if own == 0 {
            candidate.set_coordinates(coordinates)?;
            self.features[id.0] = Some(candidate);
            return Ok(None);
        }
        let observed = feature.projection()? * &change;
        if observed.amax() > tolerance {
            return Err(Error::InvalidArgument(format!(
                "coordinate change of feature {} moves it inside its M-space by {:.3e}",
                id.0,
                observed.amax()
            )));
        }
        // Columns: how each old row moves the old coordinates, then through D.
        let mut owners = vec![(RowOwner::Feature(id), own)];
        let mut moves = vec![feature.dual()?];
        for (k, link) in self.links[id.0].iter().enumerate() {
            if let Some(shared) = link {
                let dim = old.blocks()[k].dim();
                let mut e = DMatrix::zeros(n, dim);
                e.view_mut((old.offset(k), 0), (dim, dim))
                    .fill_with_identity();
                owners.push((RowOwner::Shared(*shared), dim));
                moves.push(e);
            }
        }
        candidate.set_coordinates(coordinates)?;
        let b_new = candidate.projection()?;
        let total: usize = owners.iter().map(|(_, k)| k).sum();
        let mut matrix = DMatrix::identity(total, total);
        let mut column = 0;
        for m in &moves {
            let block = &b_new * d * m;
            matrix
                .view_mut((0, column), block.shape())
                .copy_from(&block);
            column += m.ncols();
        }
        self.features[id.0] = Some(candidate);
        Ok(Some(RowTransform { owners, matrix }))
    }

    /// Applies an estimator's update: `x_f += B~ dx_p` for every owner listed (eq. 24). Own
    /// perturbations are applied with each feature's B~ at its pre-update coordinates, then
    /// shared blocks move in every member. All or nothing: on error the map is unchanged.
    pub fn apply(&mut self, perturbations: &[(RowOwner, DVector<f64>)]) -> Result<()> {
        self.apply_all(
            perturbations
                .iter()
                .map(|(owner, dx)| (*owner, Perturbation::Vector(dx))),
        )
    }

    /// [`FeatureMap::apply`] with each owner's perturbation read from the state change `dx`
    /// at the owner's state rows (`dx_owner[k] = dx[rows[k]]`), without a vector per owner:
    /// a filter's update moves every feature it holds.
    ///
    /// ```
    /// use slam_core::{FeatureId, FeatureMap, RowOwner};
    /// let mut map = FeatureMap::new();
    /// let rows = [(RowOwner::Feature(FeatureId(7)), vec![3, 4])];
    /// let moved = map.apply_at_rows(rows.iter().map(|(o, r)| (*o, r.as_slice())), &[0.0; 5]);
    /// assert!(moved.is_err()); // no feature 7 in the map
    /// ```
    pub fn apply_at_rows<'a>(
        &mut self,
        rows: impl Iterator<Item = (RowOwner, &'a [usize])> + Clone,
        dx: &'a [f64],
    ) -> Result<()> {
        self.apply_all(rows.map(move |(owner, rows)| (owner, Perturbation::Rows(rows, dx))))
    }

    /// [`FeatureMap::apply`] over any source of perturbations (two passes: own, then shared).
    fn apply_all<'a>(
        &mut self,
        perturbations: impl Iterator<Item = (RowOwner, Perturbation<'a>)> + Clone,
    ) -> Result<()> {
        // Applied in place; on error every touched feature gets its coordinates back.
        let mut saved: Vec<(usize, crate::Coordinates)> = Vec::new();
        let mut touched = vec![false; self.features.len()];
        let result = self.apply_in_place(perturbations, &mut saved, &mut touched);
        if result.is_err() {
            for (index, coordinates) in saved.into_iter().rev() {
                if let Some(feature) = self.features[index].as_mut() {
                    // The coordinates were valid before this call: restoring them succeeds.
                    let _ = feature.set_coordinates(coordinates);
                }
            }
        }
        result
    }

    fn apply_in_place<'a>(
        &mut self,
        perturbations: impl Iterator<Item = (RowOwner, Perturbation<'a>)> + Clone,
        saved: &mut Vec<(usize, crate::Coordinates)>,
        touched: &mut [bool],
    ) -> Result<()> {
        let mut save = |index: usize, feature: &dyn Feature, touched: &mut [bool]| {
            if !touched[index] {
                touched[index] = true;
                saved.push((index, feature.coordinates().clone()));
            }
        };
        let mut scratch = Scratch::default();
        for (owner, perturbation) in perturbations.clone() {
            if let RowOwner::Feature(id) = owner {
                let feature = self
                    .features
                    .get_mut(id.0)
                    .and_then(|f| f.as_deref_mut())
                    .ok_or(Error::UnknownId {
                        what: "feature",
                        id: id.0,
                    })?;
                save(id.0, feature, touched);
                feature.apply_perturbation(perturbation.vector(&mut scratch)?)?;
            }
        }
        let mut shared_values = Vec::new();
        for (owner, perturbation) in perturbations {
            if let RowOwner::Shared(id) = owner {
                let dx = perturbation.vector(&mut scratch)?;
                let shared = self.shared_block(id)?;
                if dx.len() != shared.value.dim() {
                    return Err(Error::DimensionMismatch {
                        what: "shared block perturbation".into(),
                        expected: shared.value.dim(),
                        got: dx.len(),
                    });
                }
                let mut value = shared.value;
                for (v, d) in value.as_mut_slice().iter_mut().zip(dx.iter()) {
                    *v += d;
                }
                ensure_finite(value.as_slice(), "shared block after update")?;
                let members = shared.members.clone();
                for (member, block) in members {
                    let feature = self
                        .features
                        .get_mut(member.0)
                        .and_then(|f| f.as_deref_mut())
                        .ok_or(Error::UnknownId {
                            what: "feature",
                            id: member.0,
                        })?;
                    save(member.0, feature, touched);
                    feature.set_block(block, value)?;
                }
                shared_values.push((id.0, value));
            }
        }
        for (index, value) in shared_values {
            if let Some(shared) = self.shared[index].as_mut() {
                shared.value = value;
            }
        }
        Ok(())
    }

    /// Linearizes a measurement of feature `id` and files the columns of `J_eta,state` by row
    /// owner (eq. 30 with the shared rows of section VI).
    pub fn linearize<P: RobotPose>(
        &self,
        id: FeatureId,
        measurement: &dyn DynMeasurementModel,
        world_from_robot: &P,
        robot_from_sensor: &Pose3,
    ) -> Result<MapLinearization> {
        let frame = SensorFrame::new(world_from_robot, robot_from_sensor)?;
        self.linearize_at(id, measurement, &frame)
    }

    /// [`FeatureMap::linearize`] in a sensor frame made beforehand (once per step and mount).
    pub fn linearize_at(
        &self,
        id: FeatureId,
        measurement: &dyn DynMeasurementModel,
        frame: &SensorFrame,
    ) -> Result<MapLinearization> {
        let lin = linearize_at(measurement, self.get(id)?, frame)?;
        let mut columns = Vec::with_capacity(1 + lin.d_eta_d_shared.len());
        self.visit_columns(id, &lin, |owner, d| {
            columns.push((owner, d.clone()));
            Ok(())
        })?;
        Ok(MapLinearization {
            measurement: lin,
            columns,
        })
    }

    /// Calls `visit` with the columns of `J_eta,state` (eq. 30 with the shared rows of
    /// section VI) of `lin`, a linearization of a measurement of feature `id`, by row owner:
    /// the feature's own rows (when it has any), then each shared block it holds. The
    /// borrowing form of [`FeatureMap::linearize_at`]'s `columns`, for a filter that fills
    /// its own buffers.
    pub fn visit_columns(
        &self,
        id: FeatureId,
        lin: &LinearizedMeasurement,
        mut visit: impl FnMut(RowOwner, &DMatrix<f64>) -> Result<()>,
    ) -> Result<()> {
        if self.get(id)?.mspace_dim() > 0 {
            visit(RowOwner::Feature(id), &lin.d_eta_d_own)?;
        }
        for (block, d) in &lin.d_eta_d_shared {
            let shared = self.links[id.0]
                .get(*block)
                .copied()
                .flatten()
                .ok_or_else(|| {
                    Error::Sharing(format!(
                        "feature {} says block {block} is shared but the map has no link",
                        id.0
                    ))
                })?;
            visit(RowOwner::Shared(shared), d)?;
        }
        Ok(())
    }

    /// Checks that links, sharing flags and shared-block member lists agree.
    fn check_links(&self) -> Result<()> {
        if self.links.len() != self.features.len() {
            return Err(Error::Sharing(
                "one link list per feature is required".into(),
            ));
        }
        for (index, (feature, links)) in self.features.iter().zip(&self.links).enumerate() {
            let Some(feature) = feature else { continue };
            if links.len() != feature.coordinates().num_blocks() {
                return Err(Error::Sharing(format!(
                    "feature {index} has {} blocks but {} links",
                    feature.coordinates().num_blocks(),
                    links.len()
                )));
            }
            for (block, link) in links.iter().enumerate() {
                let listed = link.is_some_and(|id| {
                    self.shared_block(id)
                        .is_ok_and(|s| s.members.contains(&(FeatureId(index), block)))
                });
                if link.is_some() != feature.is_shared(block) || (link.is_some() && !listed) {
                    return Err(Error::Sharing(format!(
                        "block {block} of feature {index}: link and sharing flag disagree"
                    )));
                }
            }
        }
        Ok(())
    }

    /// Checks that every shared block's value equals the block in each member feature.
    pub fn check_consistency(&self) -> Result<()> {
        for (id, shared) in self.shared_blocks() {
            for &(member, block) in &shared.members {
                let held = self.get(member)?.coordinates().block(block).copied();
                let linked = self.links[member.0].get(block).copied().flatten() == Some(id);
                if held != Some(shared.value) || !linked {
                    return Err(Error::Sharing(format!(
                        "shared block {} is not block {block} of feature {} (value or link)",
                        id.0, member.0
                    )));
                }
            }
        }
        Ok(())
    }
}

/// One owner's perturbation: a vector, or its rows of a state change.
#[derive(Clone, Copy)]
enum Perturbation<'a> {
    Vector(&'a DVector<f64>),
    Rows(&'a [usize], &'a [f64]),
}

/// Vectors of every length met, reused for [`Perturbation::Rows`].
#[derive(Default)]
struct Scratch(Vec<DVector<f64>>);

impl<'a> Perturbation<'a> {
    /// The perturbation as a vector (rows of a state change are gathered into `scratch`).
    fn vector<'s>(self, scratch: &'s mut Scratch) -> Result<&'s DVector<f64>>
    where
        'a: 's,
    {
        match self {
            Perturbation::Vector(dx) => Ok(dx),
            Perturbation::Rows(rows, dx) => {
                let k = rows.len();
                while scratch.0.len() <= k {
                    let len = scratch.0.len();
                    scratch.0.push(DVector::zeros(len));
                }
                let vector = &mut scratch.0[k];
                for (value, &row) in vector.iter_mut().zip(rows) {
                    *value = *dx.get(row).ok_or_else(|| Error::DimensionMismatch {
                        what: "state change rows".into(),
                        expected: row + 1,
                        got: dx.len(),
                    })?;
                }
                Ok(vector)
            }
        }
    }
}
