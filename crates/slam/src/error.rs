//! Errors of the SLAM system.

use ferroslam_map::MapError;
use ferroslam_optim::OptimError;
use thiserror::Error;

/// What can go wrong when feeding the SLAM system.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SlamError {
    /// A configuration value is out of range.
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    /// The input frame is malformed (lengths, non-finite values, timestamps).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A map file could not be written or read (missing, truncated, corrupt, wrong version,
    /// or made with another pyramid).
    #[error("map file {path}: {reason}")]
    MapFile {
        /// The file.
        path: String,
        /// What went wrong.
        reason: String,
        /// Whether the file does not exist.
        not_found: bool,
    },
    /// A map update was refused: an internal inconsistency, reported instead of hidden.
    #[error("internal map error (please report): {0}")]
    Map(#[from] MapError),
    /// An optimiser refused its input: an internal inconsistency, reported instead of hidden.
    #[error("internal optimiser error (please report): {0}")]
    Optim(#[from] OptimError),
    /// A stage (tracking, local mapping) failed inside its thread (a panic: a bug, please
    /// report) or its thread is gone; the system cannot go on.
    #[error("internal error in {stage} (please report): {message}")]
    StageFailed {
        /// The stage: `"tracking"` or `"local mapping"`.
        stage: &'static str,
        /// The panic's message, or what happened to the thread.
        message: String,
    },
}

impl SlamError {
    /// [`SlamError::StageFailed`] for a panic caught in `stage`, with the panic's message.
    pub fn from_panic(stage: &'static str, payload: &(dyn std::any::Any + Send)) -> Self {
        let message = payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".to_owned());
        SlamError::StageFailed { stage, message }
    }
}
