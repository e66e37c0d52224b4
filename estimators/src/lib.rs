//! # slam-estimators
//!
//! SLAM estimators written against the `slam-core` traits only: this crate depends on no
//! feature type and no sensor (DESIGN.md, invariant 1).
//!
//! - [`Ekf`]: the M-space EKF of the paper's section V, with feature lifecycle, data
//!   association (nearest neighbour or JCBB), triangulation and shared corners.
//! - [`em_polygon`]: polygonal approximation of registered laser points by split-and-merge
//!   EM segment fitting (Latecki & Lakaemper 2006), a post-processing estimator.
//!
//! Errors are [`slam_core::Error`], the error of the [`slam_core::Estimator`] trait.

#![warn(missing_docs)]

mod covariance;
pub mod ekf;
pub mod em_polygon;

pub use ekf::{Association, Ekf, EkfParams, pose_error};
pub use em_polygon::{EmPolygonParams, PolygonMap, fit_polygons};
