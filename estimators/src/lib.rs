//! # slam-estimators
//!
//! SLAM estimators written against the `slam-core` traits only: this crate depends on no
//! feature type and no sensor (DESIGN.md, invariant 1). The folders read as the
//! architecture:
//!
//! - [`association`]: which feature an observation is of (gated nearest neighbour, JCBB),
//!   shared by the EKF and by every particle.
//! - [`lifecycle`]: tentative features, growth of the M-space, triangulation, extension,
//!   removal and shared corners, shared by the EKF and FastSLAM.
//! - `particles`: weights, seeded streams, sampling, resampling and paths, shared by the
//!   particle filters.
//! - [`DeadReckoning`]: the motion model alone, the baseline.
//! - [`Ekf`]: the M-space EKF of the paper's section V.
//! - [`FastSlam`]: FastSLAM 1.0 and 2.0 whose particles carry maps of the same features,
//!   each with a small EKF over its M-space perturbation, sharing features after resampling.
//! - [`Ipslam`]: Brunskill & Roy's IPSLAM, particles carrying maps of 1-D PPCA line clusters
//!   built from the raw scan points (G-means, incremental PCA).
//! - [`em_polygon`]: polygonal approximation of registered laser points by split-and-merge
//!   EM segment fitting (Latecki & Lakaemper 2006), a post-processing stage.
//!
//! Errors are [`slam_core::Error`], the error of the [`slam_core::Estimator`] trait; what an
//! update leaves out is counted by reason in its [`slam_core::UpdateReport`].

#![warn(missing_docs)]

pub mod association;
mod dead_reckoning;
pub mod ekf;
pub mod em_polygon;
pub mod fastslam;
pub mod ipslam;
pub mod lifecycle;
mod particles;
#[cfg(test)]
mod test_support;
pub use particles::MAX_PARTICLES;

pub use association::{Association, AssociationSettings};
pub use dead_reckoning::{DeadReckoning, DeadReckoningParams};
pub use ekf::{Ekf, EkfParams};
pub use em_polygon::{EmPolygonParams, PolygonMap, fit_polygons};
pub use fastslam::{FastSlam, FastSlamParams, Proposal};
pub use ipslam::{Cluster, Ipslam, IpslamParams, IpslamProposal, LineMapTypes};
pub use lifecycle::LifecycleSettings;
