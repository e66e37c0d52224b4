//! The one error type of `slam-sensors`.

use std::path::Path;

/// Everything that can go wrong in `slam-sensors`.
///
/// Parse errors name the file and the line (1-based), and the column (1-based, in
/// characters) when one field is at fault, so that a user can open the file at the bad spot.
///
/// ```
/// use slam_sensors::SensorError;
/// let e = SensorError::parse("run.log", 12, "expected 4 fields, got 3");
/// assert_eq!(e.to_string(), "run.log:12: expected 4 fields, got 3");
/// let e = SensorError::parse_at("run.log", 12, 9, "field 3 (x): expected a number, got `a`");
/// assert_eq!(e.to_string(), "run.log:12:9: field 3 (x): expected a number, got `a`");
/// ```
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SensorError {
    /// A malformed line in a data file.
    #[error("{file}:{line}{}: {message}", column.map_or(String::new(), |c| format!(":{c}")))]
    Parse {
        /// The file.
        file: String,
        /// 1-based line number.
        line: usize,
        /// 1-based column (characters) of the field at fault, if one is.
        column: Option<usize>,
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
    /// Data that cannot be used as a whole, naming the file: no record at all, or readings in
    /// the wrong unit.
    #[error("{0}")]
    Input(String),
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
            column: None,
            message: message.into(),
        }
    }

    /// A parse error at `file:line:column`.
    pub fn parse_at(
        file: impl AsRef<Path>,
        line: usize,
        column: usize,
        message: impl Into<String>,
    ) -> Self {
        SensorError::Parse {
            file: file.as_ref().display().to_string(),
            line,
            column: Some(column),
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
