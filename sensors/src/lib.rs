//! # slam-sensors
//!
//! Everything between the world and an estimator:
//!
//! - [`models`]: measurement models (`eta`, `J_eta_o`, `J_eta_v`, `C_v`) pairing a sensor with
//!   a feature type: laser wall segments, laser poles, range-bearing points, ceiling-camera
//!   lines and lamps (with triangulation).
//! - [`laser_odometry`]: consecutive scans matched by ICP, replacing the odometry between them.
//! - [`odometry`]: dead-reckoning motion models (eqs. 25-27): pose increments, unicycle,
//!   differential drive, and the Ackermann model of the Victoria Park truck.
//! - [`LaserScan`], [`camera`]: raw sensor data.
//! - [`events`]: the common stream of timestamped events that readers and the simulator
//!   produce and estimators consume.

#![warn(missing_docs)]

pub mod camera;
pub mod data;
mod error;
pub mod events;
pub mod extract;
pub mod laser_odometry;
pub mod models;
pub mod odometry;
mod scan;
pub mod sim;

pub use error::{Result, SensorError};
pub use events::{
    Clock, Dataset, DatasetInfo, Event, EventStream, KnownLandmark, SkipCounter, TimedEvent,
    TruthKind,
};
pub use scan::{LaserScan, ScanPoint};
