//! # slam-core
//!
//! The M-space feature representation (Folkesson, Jensfelt & Christensen, "The M-Space
//! Feature Representation for SLAM", IEEE T-RO 23(5), 2007) as Rust traits and generic math:
//!
//! - [`Coordinates`]: a feature's coordinates `x_f`, blocks of 3-D points, 2-D points and
//!   scalars (section IV).
//! - [`Pose2`] / [`Pose3`] with the compound operators and their Jacobians; [`RobotPose`]
//!   gives `J_sr` and `J_ss` (eqs. 17, 20).
//! - [`MapToSensor`]: the generic map-to-sensor transform (eqs. 7-9, appendix eq. 34) with
//!   `J_os` and `J_of` (eq. 19).
//! - [`Feature`]: B and its dual B~ (eqs. 10-12), a growing M-space, perturbations
//!   `x_f += B~ dx_p` (eq. 24), shared blocks (section VI, eq. 33).
//! - [`MeasurementModel`]: the innovation `eta(x_o, v)` with `J_eta_v`, `J_eta_o` and `C_v`
//!   (eq. 16); [`linearize`] gives `J_eta,state = J_eta_o (J_or | J_of B~)` (eqs. 21, 30).
//! - [`FeatureMap`]: features with shared blocks; one set of rows per shared block.
//! - [`MotionModel`] (eqs. 25-27) and [`Estimator`].
//! - [`Shape`] and [`Sketch`]: a feature's world-frame geometry for map error, and how it is
//!   drawn, so that outputs never need its concrete type.
//! - [`chi2_quantile`] and [`chi2_cdf`] for gates and consistency bands.
//! - [`testing`]: the conformance suite every feature and measurement model runs.
//!
//! `nalgebra` is re-exported so that every crate uses one version.

#![warn(missing_docs)]

mod coords;
mod error;
mod estimator;
mod feature;
pub mod grid;
mod map;
mod measurement;
mod motion;
mod pose;
mod shape;
mod stats;
pub mod testing;
mod transform;

pub use nalgebra;

pub use coords::{BlockKind, CoordBlock, Coordinates, INLINE_BLOCKS};
pub use error::{Error, Result, ensure_finite};
pub use estimator::{Estimator, Observation, Skips, UpdateReport};
pub use feature::{
    Coincidence, Feature, Growth, Subspace, check_perturbation, downcast_feature,
    downcast_feature_mut, stack_rows,
};
pub use map::{
    FeatureId, FeatureMap, MapLinearization, RowOwner, RowTransform, SharedBlock, SharedBlockId,
};
pub use measurement::{
    DynMeasurementModel, Extension, Innovation, LinearizedMeasurement, MeasurementModel,
    OwnLinearization, SensorFrame, Triangulation, all_finite, assign_matrix, assign_vector,
    chain_covariance, chain_linearize_at, chain_linearize_own_at, chain_product,
    chain_product_into, innovation_at, linearize, linearize_at, linearize_at_into,
    linearize_own_at, linearize_own_at_into, reshape_zeroed,
};
pub use motion::{MotionModel, MotionPrediction};
pub use pose::{Pose2, Pose3, RobotPose, SensorPose, wrap_angle};
pub use shape::{Ink, Mark, Shape, Sketch, line_distance, segment_distance};
pub use stats::{chi2_cdf, chi2_quantile};
pub use transform::{MapToSensor, SensorFrameCoordinates};

/// Re-exported so that feature implementations outside this crate use the same version: with
/// `use slam_core::typetag;` in scope, `#[typetag::serde]` works without a dependency of their
/// own (the macro's expansion names `typetag`).
pub use typetag;

/// Re-exported for `dyn_clone::clone_box` on `dyn Feature`.
pub use dyn_clone;
