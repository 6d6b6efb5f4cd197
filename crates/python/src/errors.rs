//! The single place where core errors become Python exceptions.

use std::path::Path;

use ferroslam_features::FeaturesError;
use ferroslam_geometry::GeometryError;
use ferroslam_slam::SlamError as CoreError;
use ferroslam_vocabulary::VocabularyError;
use pyo3::create_exception;
use pyo3::exceptions::{
    PyFileNotFoundError, PyIsADirectoryError, PyOSError, PyRuntimeError, PyValueError,
};
use pyo3::PyErr;

create_exception!(
    ferroslam,
    SlamError,
    PyRuntimeError,
    "An internal failure of the SLAM core (not bad input): a `RuntimeError`."
);

/// Two kinds, as in polars' error mapping: bad configuration or input -> `ValueError` (a
/// missing map file -> `FileNotFoundError`), with the core's message naming the problem;
/// internal failures (map invariants, solvers, a stage that failed in its thread) ->
/// `SlamError`, a `RuntimeError`.
pub fn to_py(err: CoreError) -> PyErr {
    match err {
        CoreError::InvalidConfig(_) | CoreError::InvalidInput(_) => {
            PyValueError::new_err(err.to_string())
        }
        CoreError::MapFile {
            not_found: true, ..
        } => PyFileNotFoundError::new_err(err.to_string()),
        CoreError::MapFile { .. } => PyValueError::new_err(err.to_string()),
        CoreError::Map(_) | CoreError::Optim(_) | CoreError::StageFailed { .. } => {
            SlamError::new_err(err.to_string())
        }
    }
}

/// A vocabulary error about the file at `path` as a Python exception naming the file.
pub fn vocabulary_file_error(path: &Path, err: VocabularyError) -> PyErr {
    let message = format!("{}: {err}", path.display());
    match err {
        VocabularyError::Io(e) => match e.kind() {
            std::io::ErrorKind::NotFound => PyFileNotFoundError::new_err(message),
            std::io::ErrorKind::IsADirectory => PyIsADirectoryError::new_err(message),
            // a special file or one too large: the caller's path is wrong
            std::io::ErrorKind::InvalidInput => PyValueError::new_err(message),
            _ => PyOSError::new_err(message),
        },
        _ => PyValueError::new_err(message),
    }
}

/// Feature-extraction errors are all bad input or settings -> `ValueError` (the message names
/// the problem).
pub fn features_to_py(err: FeaturesError) -> PyErr {
    match err {
        FeaturesError::InvalidPyramid { .. }
        | FeaturesError::InvalidImage { .. }
        | FeaturesError::InvalidOrbConfig(_)
        | FeaturesError::ImageTooSmall { .. }
        | FeaturesError::MaskSizeMismatch { .. }
        | FeaturesError::InvalidMask(_) => PyValueError::new_err(err.to_string()),
    }
}

/// Geometry errors are bad parameters (a camera's intrinsics, coefficients, size) ->
/// `ValueError` naming `what` and the parameter.
pub fn geometry_to_py(what: &str, err: GeometryError) -> PyErr {
    match err {
        GeometryError::InvalidParameter { .. } => PyValueError::new_err(format!("{what}: {err}")),
    }
}
