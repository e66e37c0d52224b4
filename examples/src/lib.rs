//! # slam-examples
//!
//! Runnable examples (`cargo run -p slam-examples --example <name>`) and a feature type
//! defined outside `slam-features`: [`Door`], a doorway between two jambs, with its
//! measurement model [`DoorObservation`]. It is the proof that a new feature type needs no
//! change elsewhere: it implements the slam-core traits, passes the conformance suite, and
//! runs through the generic map and measurement chain.
//!
//! [`EndpointWall`] is a second one: the naive wall representation (both endpoints in the
//! state, large variance along the wall) that the M-space paper's Fig. 1 argues against.
//! [`EndpointWalls`] registers it as the wall representation `"endpoints"`, so the `slam`
//! command (which links this crate) runs it by configuration, for the comparison.

#![warn(missing_docs)]

pub mod door;
pub mod endpoint_wall;

pub use door::{Door, DoorObservation};
pub use endpoint_wall::{EndpointWall, EndpointWallObservation, EndpointWalls};
