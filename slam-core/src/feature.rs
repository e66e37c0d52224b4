//! The feature trait: coordinates, the projection matrix B, its dual B~, and an M-space that
//! grows as more of the feature is observed (paper section IV).

use std::any::Any;
use std::fmt::Debug;
use std::ops::Range;

use nalgebra::{DMatrix, DVector};

use crate::coords::{CoordBlock, Coordinates};
use crate::error::{Error, Result, ensure_finite};
use crate::shape::{Ink, Mark, Shape, Sketch};

/// A named group of M-space rows that a feature gains together, e.g. a wall's
/// `"line"` (rotation and normal offset) or its `"start"` (tangential position of the start
/// point).
///
/// ```
/// use slam_core::Subspace;
/// const LINE: Subspace = Subspace {
///     name: "line",
///     rows: 2,
///     description: "rotation about the centre (scaled by 1/L) and normal offset of the centre",
/// };
/// assert_eq!(LINE.rows, 2);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Subspace {
    /// Stable name, used in configuration, serialization and [`Feature::activate`].
    pub name: &'static str,
    /// Number of M-space rows (dimensions) it adds.
    pub rows: usize,
    /// What the rows measure and what observation reveals them.
    pub description: &'static str,
}

/// What [`Feature::activate`] reports: the subspace gained and where its rows went.
///
/// New rows are always appended: `rows` is `old_dim..old_dim + subspace.rows`, so an
/// estimator keeps the meaning of every existing row and only appends to its state.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Growth {
    /// The subspace that became active.
    pub subspace: Subspace,
    /// Indices of the new rows in the feature's own M-space.
    pub rows: Range<usize>,
}

impl Growth {
    /// Why the rows exist: the subspace's description.
    pub fn why(&self) -> &'static str {
        self.subspace.description
    }
}

/// How far two features of one kind are from being one ([`Feature::coincidence`]): a
/// residual, zero when they coincide, and its Jacobians with respect to the coordinates of
/// both.
#[derive(Clone, Debug, PartialEq)]
pub struct Coincidence {
    /// The residual.
    pub residual: DVector<f64>,
    /// `d residual / d x_f` of the feature asked (`residual.len() x dim(x_f)`).
    pub d_self: DMatrix<f64>,
    /// `d residual / d x_f` of the other feature.
    pub d_other: DMatrix<f64>,
}

/// A map feature in the M-space representation (paper section IV).
///
/// A feature owns its coordinates `x_f` (a list of 3-D point, 2-D point and scalar blocks) and
/// knows its current M-space: the ordered list of active [`Subspace`]s. It supplies
/// `B(x_f)` ([`projection`](Feature::projection), eq. 10) and its dual `B~(x_f)`
/// ([`dual`](Feature::dual), eq. 11) with `B B~ = I` (eq. 12), both at the current dimension.
/// An estimator holds only perturbations `dx_p` and their covariance; after an update it calls
/// [`apply_perturbation`](Feature::apply_perturbation) (`x_f += B~ dx_p`, eq. 24) and
/// re-evaluates B.
///
/// **Shared blocks.** A block may be shared with other features (a corner shared by two
/// walls, paper section VI). A shared block's M-space rows are the identity on its
/// coordinates and belong to the block, not to any feature: [`crate::FeatureMap`] gives them
/// one set of rows. The feature's own B and B~ must therefore be zero on shared blocks
/// (B~ has zero rows there and B zero columns), and [`share_block`](Feature::share_block) is
/// where a feature re-parameterizes its own rows (eq. 33).
///
/// Implementations carry `#[typetag::serde]` so that `Box<dyn Feature>` serializes with a
/// `"type"` tag, and should validate on deserialization. Run
/// [`crate::testing::assert_feature_conforms`] on every implementation.
#[typetag::serde(tag = "type")]
pub trait Feature: dyn_clone::DynClone + Debug + Send + Sync + Any {
    /// Short stable name of the feature type, e.g. `"wall"`.
    fn kind(&self) -> &'static str;

    /// The coordinates `x_f` in the map frame.
    fn coordinates(&self) -> &Coordinates;

    /// Replaces all coordinates, validating them (finite, non-degenerate, constraints such as
    /// equal heights). On error the feature is unchanged.
    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()>;

    /// Replaces one block (how a [`crate::FeatureMap`] propagates a shared block).
    fn set_block(&mut self, index: usize, value: CoordBlock) -> Result<()> {
        let mut coordinates = self.coordinates().clone();
        coordinates.set_block(index, value)?;
        self.set_coordinates(coordinates)
    }

    /// The active subspaces, in row order (activation order).
    fn active_subspaces(&self) -> Vec<Subspace>;

    /// The subspaces that [`activate`](Feature::activate) would accept now.
    fn growth_options(&self) -> Vec<Subspace>;

    /// Grows the M-space by the named subspace; its rows are appended (see [`Growth`]).
    fn activate(&mut self, subspace: &str) -> Result<Growth>;

    /// Current number of own M-space rows, `dim(M)` (shared blocks not counted).
    fn mspace_dim(&self) -> usize {
        self.active_subspaces().iter().map(|s| s.rows).sum()
    }

    /// `B(x_f)` restricted to the own rows: `mspace_dim x dim(x_f)` (eq. 10, Table II).
    fn projection(&self) -> Result<DMatrix<f64>>;

    /// `B~(x_f)`, the dual: `dim(x_f) x mspace_dim` with `B B~ = I` (eqs. 11-12). The default
    /// is the minimum-norm right inverse `B^T (B B^T)^-1`; a feature whose paper form of B~
    /// differs (Table II) gives its own.
    fn dual(&self) -> Result<DMatrix<f64>> {
        let b = self.projection()?;
        let gram = &b * b.transpose();
        match gram.try_inverse() {
            Some(inverse) => Ok(b.transpose() * inverse),
            None => Err(Error::Singular(format!(
                "B of a {} (rows not independent)",
                self.kind()
            ))),
        }
    }

    /// `x_f += B~(x_f) dx_p` (eq. 24). On error the feature is unchanged.
    ///
    /// Override only to retract non-linearly; the first-order change must still be `B~ dx_p`
    /// (the conformance suite checks it by central differences).
    fn apply_perturbation(&mut self, dx_p: &DVector<f64>) -> Result<()> {
        check_perturbation(self.kind(), self.mspace_dim(), dx_p)?;
        let mut coordinates = self.coordinates().clone();
        coordinates.add_vector(&(self.dual()? * dx_p))?;
        self.set_coordinates(coordinates)
    }

    /// Prior covariance of the rows that `growth` added (`growth.rows.len()` square), for
    /// directions the observation that reveals them does not determine; `None` (the default)
    /// leaves them uninformative, with the estimator's large default variance.
    fn growth_prior(&self, growth: &Growth) -> Option<DMatrix<f64>> {
        let _ = growth;
        None
    }

    /// `coordinates` of this same feature written in this feature's conventions (a line's
    /// endpoints in this feature's order, say), for an estimator that re-places the feature
    /// from elsewhere (triangulation). Default: as given.
    fn conform(&self, coordinates: Coordinates) -> Coordinates {
        coordinates
    }

    /// Indices of the blocks that may be shared with other features (default: none).
    fn shareable_blocks(&self) -> Vec<usize> {
        Vec::new()
    }

    /// Whether block `index` of this feature and block `other_index` of `other` may become
    /// one shared block at all, whatever their values (two walls meet in a corner only at an
    /// angle: nearly parallel walls sharing an end are one wall drawn twice or a wall
    /// continued, not a corner). The estimator still tests that the blocks are the same
    /// point. Default: yes.
    fn may_share_with(&self, index: usize, other: &dyn Feature, other_index: usize) -> bool {
        let _ = (index, other, other_index);
        true
    }

    /// Whether block `index` is currently shared.
    fn is_shared(&self, index: usize) -> bool {
        let _ = index;
        false
    }

    /// The feature's geometry in the world frame, for map error against a true map (the
    /// nearest true shape of the same kind, [`Shape::error_against`]) and for matching a
    /// feature with a known landmark ([`Shape::anchor`]). `None` (the default) when the
    /// feature is not scored, e.g. while it is not placed in every direction its kind needs.
    fn shape(&self) -> Option<Shape> {
        None
    }

    /// How the feature is drawn in a map figure. The default marks each point block and
    /// counts the feature under "other features".
    fn sketch(&self) -> Sketch {
        let mut sketch = Sketch::new("other features", Ink::Point);
        for block in self.coordinates().blocks() {
            let at = match block {
                CoordBlock::Point3(p) => p.xy(),
                CoordBlock::Point2(p) => *p,
                CoordBlock::Scalar(_) => continue,
            };
            sketch.marks.push(Mark::Marker {
                at,
                ink: Ink::Point,
                size: 7,
                filled: false,
            });
        }
        sketch
    }

    /// The residual that is zero when `other`, a feature of the same kind, is this same
    /// physical feature (e.g. a wall mapped twice), with its Jacobians, for an estimator
    /// that merges duplicates: it tests the residual against its covariance and, when it
    /// passes, constrains the two together and removes one. `Ok(None)` (the default) when
    /// this type is never merged or `other` cannot be this feature (another kind, facing the
    /// other way). Only what both features estimate should enter the residual (a wall's line,
    /// not its extent).
    fn coincidence(&self, other: &dyn Feature) -> Result<Option<Coincidence>> {
        let _ = other;
        Ok(None)
    }

    /// After a merge: the coordinates of this feature grown, outside its M-space, to cover
    /// `other` (a wall extended along its line over the other's extent); `Ok(None)` (the
    /// default) when nothing changes.
    fn absorbed(&self, other: &dyn Feature) -> Result<Option<crate::Extension>> {
        let _ = other;
        Ok(None)
    }

    /// Marks block `index` as shared and re-parameterizes the own rows accordingly (eq. 33).
    ///
    /// The caller (normally [`crate::FeatureMap::share`]) gives the shared block its own
    /// identity rows. Default: sharing is not supported.
    fn share_block(&mut self, index: usize) -> Result<()> {
        Err(Error::Sharing(format!(
            "a {} has no shareable block {index}",
            self.kind()
        )))
    }
}

dyn_clone::clone_trait_object!(Feature);

/// What [`Feature::apply_perturbation`] checks before it changes anything: `dx_p` has the
/// feature's M-space dimension (`mspace_dim`, of a feature of kind `kind`) and is finite.
/// For the overrides that retract without forming `B~`.
///
/// ```
/// use slam_core::{check_perturbation, nalgebra::DVector};
/// assert!(check_perturbation("pole", 3, &DVector::zeros(3)).is_ok());
/// assert!(check_perturbation("pole", 3, &DVector::zeros(2)).is_err());
/// assert!(check_perturbation("pole", 1, &DVector::from_element(1, f64::NAN)).is_err());
/// ```
pub fn check_perturbation(kind: &str, mspace_dim: usize, dx_p: &DVector<f64>) -> Result<()> {
    if dx_p.len() != mspace_dim {
        return Err(Error::DimensionMismatch {
            what: format!("M-space perturbation of a {kind}"),
            expected: mspace_dim,
            got: dx_p.len(),
        });
    }
    ensure_finite(dx_p.as_slice(), "M-space perturbation")
}

/// The concrete feature behind a `&dyn Feature`, if it is an `F`.
///
/// ```
/// # use slam_core::{downcast_feature, Feature};
/// # fn demo(feature: &dyn Feature) {
/// if let Some(point) = downcast_feature::<MyPoint>(feature) { /* ... */ }
/// # }
/// # #[derive(Clone, Debug, serde::Serialize, serde::Deserialize)] struct MyPoint;
/// # #[typetag::serde] impl Feature for MyPoint {
/// #   fn kind(&self) -> &'static str { "my-point" }
/// #   fn coordinates(&self) -> &slam_core::Coordinates { unimplemented!() }
/// #   fn set_coordinates(&mut self, _: slam_core::Coordinates) -> slam_core::Result<()> { Ok(()) }
/// #   fn active_subspaces(&self) -> Vec<slam_core::Subspace> { vec![] }
/// #   fn growth_options(&self) -> Vec<slam_core::Subspace> { vec![] }
/// #   fn activate(&mut self, _: &str) -> slam_core::Result<slam_core::Growth> { unimplemented!() }
/// #   fn projection(&self) -> slam_core::Result<slam_core::nalgebra::DMatrix<f64>> { unimplemented!() }
/// #   fn dual(&self) -> slam_core::Result<slam_core::nalgebra::DMatrix<f64>> { unimplemented!() }
/// # }
/// ```
pub fn downcast_feature<F: Feature>(feature: &dyn Feature) -> Option<&F> {
    let any: &dyn Any = feature;
    any.downcast_ref::<F>()
}

/// Mutable version of [`downcast_feature`].
pub fn downcast_feature_mut<F: Feature>(feature: &mut dyn Feature) -> Option<&mut F> {
    let any: &mut dyn Any = feature;
    any.downcast_mut::<F>()
}

/// Builds `B` or `B~` of the active subspaces by stacking per-subspace blocks.
///
/// `rows_of(subspace)` gives a subspace's rows of B (`rows x dim_f`); the result stacks them in
/// activation order. A helper for implementations whose subspaces are independent
/// (`B_g B~_h = 0` for different subspaces g, h), which is true of every feature in the paper.
///
/// ```
/// use slam_core::{stack_rows, nalgebra::DMatrix};
/// let b = stack_rows(4, &["a", "b"], |name| Ok(match *name {
///     "a" => DMatrix::from_row_slice(1, 4, &[1.0, 0.0, 0.0, 0.0]),
///     _ => DMatrix::from_row_slice(2, 4, &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
/// })).unwrap();
/// assert_eq!(b.shape(), (3, 4));
/// ```
pub fn stack_rows<S>(
    dim_f: usize,
    subspaces: &[S],
    mut rows_of: impl FnMut(&S) -> Result<DMatrix<f64>>,
) -> Result<DMatrix<f64>> {
    let blocks = subspaces
        .iter()
        .map(&mut rows_of)
        .collect::<Result<Vec<_>>>()?;
    let total: usize = blocks.iter().map(DMatrix::nrows).sum();
    let mut stacked = DMatrix::zeros(total, dim_f);
    let mut row = 0;
    for block in blocks {
        if block.ncols() != dim_f {
            return Err(Error::DimensionMismatch {
                what: "subspace rows of B".into(),
                expected: dim_f,
                got: block.ncols(),
            });
        }
        stacked.view_mut((row, 0), block.shape()).copy_from(&block);
        row += block.nrows();
    }
    Ok(stacked)
}
