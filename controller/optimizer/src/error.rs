//! The crate's error type.

/// Everything that can go wrong when defining a problem or driving the optimizer.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A knob's definition is unusable.
    #[error("knob {name:?}: {reason}")]
    Knob { name: String, reason: String },
    /// An objective or constraint definition is unusable.
    #[error("problem: {0}")]
    Problem(String),
    /// An observation or configuration does not fit the problem.
    #[error("observation: {0}")]
    Observation(String),
    /// The optimizer settings are unusable.
    #[error("settings: {0}")]
    Settings(String),
    /// The Gaussian-process covariance stayed singular after adding jitter.
    #[error("gaussian process: covariance of {n} points is not positive definite")]
    Singular { n: usize },
    /// Saving or restoring the optimizer state failed.
    #[error("optimizer state json")]
    State(#[source] serde_json::Error),
}

/// Result alias for this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
