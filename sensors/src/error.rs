//! The one error type of `slam-sensors`.

use std::path::Path;

/// Everything that can go wrong in `slam-sensors`.
///
/// Parse errors name the file and the line (1-based), so that a user can open the file at
/// the bad line.
///
/// ```
/// use slam_sensors::SensorError;
/// let e = SensorError::parse("run.log", 12, "expected 4 fields, got 3");
/// assert_eq!(e.to_string(), "run.log:12: expected 4 fields, got 3");
/// ```
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SensorError {
    /// A malformed line in a data file.
    #[error("{file}:{line}: {message}")]
    Parse {
        /// The file.
        file: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        message: String,
    },
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A world description that cannot be simulated.
    #[error("world description: {0}")]
    World(String),
    /// An argument outside its documented range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// An error of the M-space core (degenerate geometry, singular matrix, ...).
    #[error(transparent)]
    Core(#[from] slam_core::Error),
}

impl SensorError {
    /// A parse error at `file:line`.
    pub fn parse(file: impl AsRef<Path>, line: usize, message: impl Into<String>) -> Self {
        SensorError::Parse {
            file: file.as_ref().display().to_string(),
            line,
            message: message.into(),
        }
    }

    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        SensorError::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }
}

/// `Result` with [`SensorError`].
pub type Result<T> = std::result::Result<T, SensorError>;
