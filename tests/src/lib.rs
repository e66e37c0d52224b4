//! Workspace-level integration tests live in `tests/`. This crate also runs the Rust examples
//! of the README and of the user guide (`docs/GUIDE.md`) as doctests, so the documents stay
//! true (the crate is not published; its doctests may read files outside it).

#[cfg(doctest)]
#[doc = include_str!("../../README.md")]
struct ReadmeDoctests;

#[cfg(doctest)]
#[doc = include_str!("../../docs/GUIDE.md")]
struct GuideDoctests;
