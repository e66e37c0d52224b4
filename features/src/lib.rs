//! # slam-features
//!
//! The four feature types of the M-space paper (Folkesson, Jensfelt & Christensen, IEEE T-RO
//! 2007, Tables I and II), implemented against the `slam-core` traits:
//!
//! | type | coordinates | M-space dimensions |
//! |---|---|---|
//! | [`Point`] | one 3-D point | 0, 2 (`horizontal`), 1 (`height`), 3 |
//! | [`Wall`] | two 2-D endpoints | 0, 2 (`line`), 3 (`start` or `end`), 4; shared corners (eq. 33) |
//! | [`HLine`] | two 3-D endpoints at one height | 0, 1 (`direction`), 3 (`position`) |
//! | [`Pole`] | radius scalar + 2-D centre | 0, 3 (`full`) |
//! | [`PpcaLine`] | two 2-D endpoints (IPSLAM's PPCA cluster) | 2 (`line`) |
//!
//! Every type passes the slam-core conformance suite (`slam_core::testing`). The types know
//! no estimator and no sensor.

#![warn(missing_docs)]

mod geometry;
pub mod hline;
pub mod point;
pub mod pole;
pub mod ppca_line;
pub mod wall;

pub use hline::HLine;
pub use point::Point;
pub use pole::Pole;
pub use ppca_line::PpcaLine;
pub use wall::Wall;
