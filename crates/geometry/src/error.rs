//! The error type of this crate.

use thiserror::Error;

/// Errors returned by constructors and solvers in `ferroslam-geometry`.
///
/// Bad input (a parameter a caller can fix) is kept apart from numerical failure.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GeometryError {
    /// A parameter is outside its valid domain (non-finite, non-positive, ...).
    #[error("invalid parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// Name of the offending parameter as written in the API.
        name: &'static str,
        /// The value that was passed.
        value: f64,
        /// What the parameter must satisfy.
        reason: &'static str,
    },
}
