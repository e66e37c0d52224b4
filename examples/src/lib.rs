//! # slam-examples
//!
//! Runnable examples (`cargo run -p slam-examples --example <name>`) and a feature type
//! defined outside `slam-features`: [`Door`], a doorway between two jambs, with its
//! measurement model [`DoorObservation`]. It is the proof that a new feature type needs no
//! change elsewhere: it implements the slam-core traits, passes the conformance suite, and
//! runs through the generic map and measurement chain.

#![warn(missing_docs)]

pub mod door;

pub use door::{Door, DoorObservation};

#[cfg(doctest)]
#[doc = include_str!("../../README.md")]
struct ReadmeDoctests;
