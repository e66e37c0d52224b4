//! # slam-estimators
//!
//! SLAM estimators (M-space EKF, FastSLAM, IPSLAM, EM polygonal approximation), written
//! against the `slam-core` traits only: this crate depends on no feature type and no sensor.
//! It is empty until the EKF issue lands.

#![warn(missing_docs)]
