//! `ferroslam._core`: thin PyO3 bindings over the Rust SLAM system.
//!
//! Arrays are checked here (dtype, shape, finiteness) before the core sees them, so no panic
//! reaches Python; errors are translated in one place, `errors.rs`.
#![allow(non_snake_case)]
#![warn(missing_docs)]

mod atlas;
mod camera;
mod config;
mod convert;
mod errors;
mod extractor;
mod inertial;
mod map_merge;
mod pool;
mod rig_frame;
mod sparse_model;
mod stereo;
mod system;
mod track_result;
mod vocabulary;

use pyo3::prelude::*;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SlamError", m.py().get_type::<errors::SlamError>())?;
    m.add_class::<system::PySlamSystem>()?;
    m.add_class::<track_result::PyTrackResult>()?;
    m.add_function(wrap_pyfunction!(config::default_options, m)?)?;
    m.add_function(wrap_pyfunction!(config::option_table, m)?)?;
    m.add_function(wrap_pyfunction!(stereo::match_stereo, m)?)?;
    m.add_function(wrap_pyfunction!(camera::project_points, m)?)?;
    m.add_function(wrap_pyfunction!(camera::unproject_pixels, m)?)?;
    m.add_function(wrap_pyfunction!(sparse_model::load_sparse_model, m)?)?;
    m.add_function(wrap_pyfunction!(map_merge::merge_map_files, m)?)?;
    m.add_class::<extractor::PyOrbExtractor>()?;
    m.add_class::<vocabulary::PyVocabulary>()?;
    m.add_class::<vocabulary::PyKeyframeDatabase>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
