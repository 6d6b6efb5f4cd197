//! The single place where core errors become Python exceptions.

use ferroslam_features::FeaturesError;
use ferroslam_slam::SlamError as CoreError;
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::PyErr;

create_exception!(
    ferroslam,
    SlamError,
    PyException,
    "Base class of ferroslam errors that are not plain bad input."
);

/// Bad configuration or input -> `ValueError` (with the core's message naming the problem);
/// internal failures -> `SlamError`; a stage that failed in its thread -> `RuntimeError`.
pub fn to_py(err: CoreError) -> PyErr {
    match err {
        CoreError::InvalidConfig(_) | CoreError::InvalidInput(_) => {
            PyValueError::new_err(err.to_string())
        }
        CoreError::MapFile {
            not_found: true, ..
        } => PyFileNotFoundError::new_err(err.to_string()),
        CoreError::MapFile { .. } => PyValueError::new_err(err.to_string()),
        CoreError::Map(_) | CoreError::Optim(_) => SlamError::new_err(err.to_string()),
        CoreError::StageFailed { .. } => PyRuntimeError::new_err(err.to_string()),
    }
}

/// Feature-extraction errors are all bad input or settings -> `ValueError` (the message names
/// the problem).
pub fn features_to_py(err: FeaturesError) -> PyErr {
    match err {
        FeaturesError::InvalidPyramid { .. }
        | FeaturesError::InvalidImage { .. }
        | FeaturesError::InvalidOrbConfig(_)
        | FeaturesError::ImageTooSmall { .. } => PyValueError::new_err(err.to_string()),
    }
}
