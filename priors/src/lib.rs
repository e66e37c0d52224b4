//! Structure priors for a single range scan, written by users in a small language
//! ("priorlets"), and the inference engine that applies them.
//!
//! Source: the fourth source of this project, structure priors for dense scans written in a
//! domain-specific language (`papers/003_80e46aa064e8c63c.txt`). A scan is
//! represented by its readings `rho_i`, the surface normals `alpha_i` and a topology between
//! consecutive readings (same region / different region / different surface). A prior file
//! states, per topology case, equalities, inequalities, disjunctions and energies over
//! `order` consecutive readings ([`parser`] gives the grammar; the shipped priors are in
//! [`SHIPPED`]). [`infer`] solves the constrained MAP problem (Problem 4 of the source) and
//! [`dof::analyze`] recovers the degrees of freedom and the posterior covariance (section 4).
//!
//! Readings of the source that go beyond its text, each documented where it is implemented:
//! a child prior (`specializes:`) inherits the parent's definitions (a redefinition
//! overrides) and *adds* its priorlet lines to the parent's; the circular prior adds the
//! chord-symmetry equalities the source's figure omits; the Hessian is convexified window by
//! window; a last pass moves region boundaries by one reading while the fit improves; and the
//! first topology guess separates readings too far apart for one surface.
//!
//! ```
//! use slam_priors::{Library, Params, ScanInput, infer};
//! let library = Library::shipped().unwrap();
//! let prior = library.compile("Rectangular prior").unwrap();
//! // Three walls of a room seen from (0, 0): readings of the line x = 2 for 30 bearings.
//! let phi: Vec<f64> = (0..30).map(|i| -0.5 + i as f64 * 0.03).collect();
//! let rho: Vec<f64> = phi.iter().map(|p| 2.0 / p.cos()).collect();
//! let scan = ScanInput::new(phi, rho, 0.01).unwrap();
//! let solution = infer(&prior, &scan, &Params::default()).unwrap();
//! assert!(solution.feasible);
//! assert_eq!(solution.regions().len(), 1);
//! ```

#![warn(missing_docs)]
// Dense and banded numerical kernels read best with explicit indices.
#![allow(clippy::needless_range_loop)]

pub mod compile;
pub mod dof;
pub mod dual;
pub mod engine;
pub mod error;
pub mod lexer;
pub mod parser;
pub mod scene;
mod window;

pub use compile::{Library, MAX_ORDER, Prior, SHIPPED, parse_prior};
pub use dof::{Dof, analyze};
pub use engine::{Params, RegionSegment, ScanInput, Solution, infer};
pub use error::{PriorError, Result};
pub use parser::Topology;
