//! # slam-runtime
//!
//! Between the estimators and the `slam` command: everything a program needs to run a SLAM
//! session on simulated or real data, as a library.
//!
//! - [`Config`]: the TOML configuration (data, estimator, front-end, post-processing,
//!   outputs), with estimators, front-ends, wall representations and post-processing stages
//!   **found by name** through `typetag` ([`EstimatorConfig`], [`FrontendConfig`],
//!   [`frontend::WallModel`], [`PostProcessConfig`]): a crate of its own registers another,
//!   and a program linked with it runs it from the TOML word.
//! - [`data`]: data specs read as streams of events (a run's memory does not grow with the
//!   log).
//! - [`frontend`]: raw sensor frames in, observations of the map's feature types out.
//! - [`Session`]: an estimator and a front-end stepping through events, with
//!   [`Observer`]s; [`Recorder`] keeps the standard record.
//! - [`run()`]: a whole run from a config; [`eval`]: ATE, RPE, NEES / NIS and map error, and
//!   [`RunMetrics`] (`metrics.json`); [`compute_run`]: both, what `slam run` computes before
//!   it writes its files.
//! - [`postprocess`]: stages after the estimator (EM polygonal approximation, relocalization
//!   of the scans against the final map).
//! - [`grid`]: the log-odds occupancy grid built from the laser scans during a run (an
//!   [`Observer`]), with its map_server images; [`g2o`]: the run as a pose graph in g2o's
//!   text format.
//! - [`study`]: the consistency study over many seeded simulated runs (average pose NEES
//!   against its 95% band, per wall representation); [`mod@bench`]: what a run costs (time per
//!   step, state size).
//!
//! ```no_run
//! use slam_runtime::{Config, RunMetrics, run};
//! let config = Config::from_toml("[estimator]\ntype = \"ekf\"\n", "inline")?;
//! let output = run(&config, &mut ())?;
//! let metrics = RunMetrics::compute(&output, &config)?;
//! println!("ATE {:?} m", metrics.ate_rmse_m);
//! # Ok::<(), slam_runtime::RuntimeError>(())
//! ```

#![warn(missing_docs)]

pub mod bench;
mod config;
pub mod data;
mod error;
mod estimators;
pub mod eval;
pub mod frontend;
pub mod g2o;
pub mod grid;
pub mod health;
pub mod mcap_log;
mod metrics;
pub mod postprocess;
mod record;
mod run;
mod session;
pub mod study;

pub use config::{Config, OutputConfig};
pub use error::{Result, RuntimeError};
pub use estimators::{EstimatorConfig, Start};
pub use frontend::{Frontend, FrontendConfig, load_prior};
pub use metrics::{LaserOdometryReportView, RevisitFigures, RunMetrics, RunResults, compute_run};
pub use postprocess::{FinishedRun, PostProcess, PostProcessConfig, PostProcessOutput};
pub use record::{Recorder, UpdateTotals};
pub use run::{InputReport, RunOutput, run, run_until};
pub use session::{Observer, Session};

/// Re-exported so that a crate registering its own estimator, front-end or stage uses the
/// same version: with `use slam_runtime::typetag;` in scope, `#[typetag::serde(name = "...")]`
/// works without a dependency of its own (the macro's expansion names `typetag`).
pub use typetag;
