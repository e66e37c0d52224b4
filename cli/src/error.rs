//! The one error type of the `slam` command.

use std::path::PathBuf;

/// Everything the `slam` command reports to its user. Each variant keeps its cause
/// ([`std::error::Error::source`]); the command prints the whole chain.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CliError {
    /// A failure of the runtime: configuration (with its key), data (with file and line), a
    /// step of the run (with its time and cause).
    #[error(transparent)]
    Runtime(#[from] slam_runtime::RuntimeError),
    /// Bad input data or a sensor-side failure (with file and line where there is one).
    #[error(transparent)]
    Sensor(#[from] slam_sensors::SensorError),
    /// A failure of the M-space core.
    #[error(transparent)]
    Core(#[from] slam_core::Error),
    /// A structure prior that does not load or run.
    #[error(transparent)]
    Prior(#[from] slam_priors::PriorError),
    /// An argument the command cannot use (naming the flag).
    #[error("{0}")]
    Usage(String),
    /// An output that could not be written.
    #[error("writing {path}")]
    Output {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong.
        #[source]
        source: std::io::Error,
    },
    /// A figure that could not be drawn.
    #[error("drawing {path}: {message}")]
    Figure {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

impl CliError {
    /// The message with every cause, `a: b: c`.
    pub fn chain(&self) -> String {
        let mut text = self.to_string();
        let mut source = std::error::Error::source(self);
        while let Some(cause) = source {
            let line = cause.to_string();
            if !text.ends_with(&line) {
                text.push_str(": ");
                text.push_str(&line);
            }
            source = cause.source();
        }
        text
    }
}

/// `Result` with [`CliError`].
pub type Result<T> = std::result::Result<T, CliError>;
