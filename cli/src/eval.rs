//! `slam eval GT.tum EST.tum`: absolute trajectory error and relative pose error.

use std::path::PathBuf;

use crate::error::{CliError, Result};

/// Arguments of `slam eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Ground-truth trajectory (TUM format).
    pub ground_truth: PathBuf,
    /// Estimated trajectory (TUM format).
    pub estimate: PathBuf,
}

/// Runs `slam eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    Err(CliError::Usage(format!(
        "slam eval is not implemented yet ({} vs {})",
        args.ground_truth.display(),
        args.estimate.display()
    )))
}
