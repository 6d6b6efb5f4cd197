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
}
