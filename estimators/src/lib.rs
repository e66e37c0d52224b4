//! # slam-estimators
//!
//! SLAM estimators written against the `slam-core` traits only: this crate depends on no
//! feature type and no sensor (DESIGN.md, invariant 1).
//!
//! - [`Ekf`]: the M-space EKF of the paper's section V, with feature lifecycle, data
//!   association (nearest neighbour or JCBB), triangulation and shared corners.
//! - [`em_polygon`]: polygonal approximation of registered laser points by split-and-merge
//!   EM segment fitting (Latecki & Lakaemper 2006), a post-processing estimator.
//! - [`FastSlam`]: FastSLAM 1.0 whose particles carry maps of the same features, each with a
//!   small EKF over its M-space perturbation, sharing features after resampling.
//! - [`Ipslam`]: Brunskill & Roy's IPSLAM, particles carrying maps of 1-D PPCA line clusters
//!   built from raw scan points (G-means, incremental PCA).
//!
//! Errors are [`slam_core::Error`], the error of the [`slam_core::Estimator`] trait.

#![warn(missing_docs)]

mod ancestry;
mod covariance;
pub mod ekf;
pub mod em_polygon;
pub mod fastslam;
pub mod ipslam;
mod lifecycle;

pub use ekf::{Association, Ekf, EkfParams, pose_error};
pub use em_polygon::{EmPolygonParams, PolygonMap, fit_polygons};
pub use fastslam::{FastSlam, FastSlamParams, Proposal};
pub use ipslam::{ClusterFeatureFactory, Ipslam, IpslamParams, IpslamProposal};
