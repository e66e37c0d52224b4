//! The one error type of `slam-priors`.

/// Everything that can go wrong in `slam-priors`.
///
/// Errors in prior files name the file (its origin), the 1-based line and the 1-based column.
///
/// ```
/// use slam_priors::parse_prior;
/// let error = parse_prior("name: x\norder: 2\npriorlet same_region:\n  rho_1 == * 2\n", "bad.prior")
///     .unwrap_err();
/// assert!(error.to_string().starts_with("bad.prior:4:12:"), "{error}");
/// ```
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PriorError {
    /// A prior file that does not follow the grammar.
    #[error("{origin}:{line}:{column}: syntax error: {message}")]
    Syntax {
        /// The file (or other origin) of the text.
        origin: String,
        /// 1-based line.
        line: usize,
        /// 1-based column (in characters).
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// A prior that parses but does not make sense (unknown variable, wrong order, a vector
    /// where a scalar is needed, ...).
    #[error("{origin}:{line}:{column}: {message}")]
    Check {
        /// The file (or other origin) of the text.
        origin: String,
        /// 1-based line.
        line: usize,
        /// 1-based column (in characters).
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// A prior named (by `specializes:` or by a user) that is not in the library.
    #[error("unknown prior {0:?}")]
    UnknownPrior(String),
    /// Priors that specialize each other in a cycle.
    #[error("inheritance cycle: {0}")]
    InheritanceCycle(String),
    /// Bad input data or parameters (empty scan, non-finite readings, ...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A numerical failure (non-finite values, a failed factorization).
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
}

/// The result type of `slam-priors`.
pub type Result<T> = std::result::Result<T, PriorError>;
