//! `slam simulate [WORLD] --out DIR`: a simulated run written as files other tools read.

use std::path::PathBuf;

use crate::error::{CliError, Result};

/// Arguments of `slam simulate`.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// World description (TOML); the built-in default world when absent.
    pub world: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `slam simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    Err(CliError::Usage(format!(
        "slam simulate is not implemented yet ({:?} -> {})",
        args.world,
        args.out.display()
    )))
}
