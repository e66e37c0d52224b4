//! The one error type of `slam-core`.

/// Everything that can go wrong in `slam-core`.
///
/// Library code returns these instead of panicking; a degenerate geometry (a wall of zero
/// length, a 2-D sensor tilted to vertical) is an error, never a NaN.
///
/// ```
/// use slam_core::Error;
/// let error = Error::Degenerate("wall shorter than 1 mm".into());
/// assert_eq!(error.to_string(), "degenerate geometry: wall shorter than 1 mm");
/// ```
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The geometry has no well-defined B matrix, normal or Jacobian (e.g. a zero-length wall).
    #[error("degenerate geometry: {0}")]
    Degenerate(String),
    /// A value that must be finite is NaN or infinite.
    #[error("non-finite value in {0}")]
    NonFinite(String),
    /// Two sizes that must agree do not.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    DimensionMismatch {
        /// What was being checked.
        what: String,
        /// The size that was required.
        expected: usize,
        /// The size that was given.
        got: usize,
    },
    /// A coordinate block of one kind was given where another kind was required.
    #[error("coordinate block {index} is a {expected:?}, got a {got:?}")]
    BlockKindMismatch {
        /// Index of the block in the feature's coordinate list.
        index: usize,
        /// The kind the feature has there.
        expected: crate::BlockKind,
        /// The kind that was given.
        got: crate::BlockKind,
    },
    /// A measurement model was applied to a feature of another type.
    #[error("measurement model for `{expected}` features applied to a `{got}` feature")]
    FeatureTypeMismatch {
        /// The feature kind the model explains.
        expected: &'static str,
        /// The kind of the feature it was given.
        got: &'static str,
    },
    /// A feature was asked to grow into a subspace it does not have or cannot take now.
    #[error("cannot activate M-space subspace `{subspace}` of a `{feature}`: {reason}")]
    Growth {
        /// The feature kind.
        feature: &'static str,
        /// The requested subspace name.
        subspace: String,
        /// Why it was refused.
        reason: String,
    },
    /// A request about coordinate sharing that cannot be honoured.
    #[error("cannot share coordinate block: {0}")]
    Sharing(String),
    /// An id that names nothing in a map.
    #[error("unknown {what} id {id}")]
    UnknownId {
        /// "feature" or "shared block".
        what: &'static str,
        /// The id given.
        id: usize,
    },
    /// A matrix that must be invertible is not.
    #[error("singular matrix in {0}")]
    Singular(String),
    /// An argument outside its documented range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Serialization or deserialization failed.
    #[error("serialization: {0}")]
    Serde(String),
    /// An internal invariant does not hold: a bug in the library, not bad input (e.g. a state
    /// row that an estimator lost track of).
    #[error("internal invariant broken (a bug, please report it): {0}")]
    Invariant(String),
}

/// `Result` with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

/// Returns `Err(Error::NonFinite(what))` unless every value is finite.
///
/// ```
/// assert!(slam_core::ensure_finite(&[1.0, 2.0], "x").is_ok());
/// assert!(slam_core::ensure_finite(&[f64::NAN], "x").is_err());
/// ```
pub fn ensure_finite(values: &[f64], what: &str) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::NonFinite(what.to_string()))
    }
}
