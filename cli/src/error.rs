//! The one error type of the `slam` command.

/// Everything the `slam` command reports to its user.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CliError {
    /// Bad input data or a sensor-side failure (with file and line where there is one).
    #[error(transparent)]
    Sensor(#[from] slam_sensors::SensorError),
    /// A failure of the M-space core.
    #[error(transparent)]
    Core(#[from] slam_core::Error),
    /// A configuration or argument the command cannot use.
    #[error("{0}")]
    Usage(String),
    /// An output that could not be written.
    #[error("writing {path}: {message}")]
    Output {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
}

/// `Result` with [`CliError`].
pub type Result<T> = std::result::Result<T, CliError>;
