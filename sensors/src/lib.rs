//! # slam-sensors
//!
//! Laser and camera measurement models, extraction front-ends, odometry, dataset readers and
//! the simulator. This crate is empty until the sensors issue lands; it exists so that the
//! workspace layout of `DESIGN.md` is in place.

#![warn(missing_docs)]
