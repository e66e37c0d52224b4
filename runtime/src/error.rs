//! The one error type of `slam-runtime`.

/// Everything that can go wrong in a session: bad configuration (naming the table and key),
/// bad data (naming the file and line, from the readers), an estimator or front-end failure
/// at a given time (with its cause), an evaluation that cannot be computed, or an internal
/// invariant that does not hold.
///
/// Every variant keeps its cause as [`std::error::Error::source`], so a caller can print the
/// whole chain.
///
/// ```
/// use slam_runtime::RuntimeError;
/// let error = RuntimeError::Config {
///     origin: "run.toml".into(),
///     message: "[estimator] unknown field `gate`".into(),
/// };
/// assert_eq!(error.to_string(), "config run.toml: [estimator] unknown field `gate`");
/// ```
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RuntimeError {
    /// A configuration the runtime cannot use: where it came from and what is wrong (with
    /// the table and key).
    #[error("config {origin}: {message}")]
    Config {
        /// The file (or "inline").
        origin: String,
        /// What is wrong, naming the table and key.
        message: String,
    },
    /// A setting out of range, with the table it belongs to.
    #[error("[{table}] {message}")]
    Setting {
        /// The TOML table, e.g. `frontend.prior`.
        table: String,
        /// What is wrong.
        message: String,
    },
    /// The data cannot be used as configured (no scans for a stage that needs them, ...).
    #[error("{0}")]
    Data(String),
    /// Bad input data or a sensor-side failure (file and line where there is one).
    #[error(transparent)]
    Sensor(#[from] slam_sensors::SensorError),
    /// A structure prior that does not load or run.
    #[error(transparent)]
    Prior(#[from] slam_priors::PriorError),
    /// A failure of the M-space core outside a session step.
    #[error(transparent)]
    Core(#[from] slam_core::Error),
    /// A step of a session failed: what was being done, at which time of the data.
    #[error("{what} at time {time}")]
    Step {
        /// "prediction", "update", "front-end", ...
        what: &'static str,
        /// The time of the event, s (or sequence number).
        time: f64,
        /// The cause.
        #[source]
        source: Box<RuntimeError>,
    },
    /// An evaluation that cannot be computed from the data given.
    #[error("evaluation: {0}")]
    Eval(String),
    /// An internal invariant does not hold: a bug, not bad input.
    #[error("internal invariant broken (a bug, please report it): {0}")]
    Invariant(String),
}

impl RuntimeError {
    /// A configuration error for `origin`.
    pub fn config(origin: impl Into<String>, message: impl Into<String>) -> Self {
        RuntimeError::Config {
            origin: origin.into(),
            message: message.into(),
        }
    }

    /// A setting error in `table`.
    pub fn setting(table: impl Into<String>, message: impl Into<String>) -> Self {
        RuntimeError::Setting {
            table: table.into(),
            message: message.into(),
        }
    }

    /// This error as the cause of a failed step at `time`.
    pub fn at(self, what: &'static str, time: f64) -> Self {
        RuntimeError::Step {
            what,
            time,
            source: Box::new(self),
        }
    }
}

/// `Result` with [`RuntimeError`].
pub type Result<T> = std::result::Result<T, RuntimeError>;
