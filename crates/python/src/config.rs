//! `SlamSystem` keyword options <-> the core's `SlamConfig`, and `default_options`: the
//! defaults the CLI, `run_sequence` and the vSLAM objects read.

use ferroslam_slam::{Sensor, SlamConfig};
use pyo3::exceptions::{PyNotImplementedError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Sensors the core can track.
const SENSORS: [Sensor; 3] = [Sensor::Monocular, Sensor::Stereo, Sensor::Rgbd];

/// Option names `SlamSystem` takes, in the order of [`options_dict`] (plus `baseline`).
const OPTIONS: &str = "n_features, ini_fast, min_fast, scale_factor, n_levels, \
                       track_feature_range, skip_max_frames, bf, baseline, depth_threshold, \
                       depth_range, seed, loop_closure, loop_closure_threshold";

/// The sensor named `name` ("mono", "stereo", "rgbd").
pub fn sensor(name: &str) -> PyResult<Sensor> {
    SENSORS
        .iter()
        .copied()
        .find(|s| s.name() == name)
        .ok_or_else(|| {
            let names: Vec<_> = SENSORS.iter().map(|s| s.name()).collect();
            PyNotImplementedError::new_err(format!(
                "sensor {name:?} is not implemented yet (available: {names:?})"
            ))
        })
}

/// A two-element sequence (tuple, list or array) as a pair.
fn pair<'py, T: pyo3::conversion::FromPyObjectOwned<'py> + Copy>(
    key: &str,
    value: &Bound<'py, PyAny>,
) -> PyResult<(T, T)> {
    let items: Vec<T> = value.extract().map_err(|e| {
        PyTypeError::new_err(format!("option {key}: expected a pair of numbers: {e}"))
    })?;
    match items[..] {
        [a, b] => Ok((a, b)),
        _ => Err(PyValueError::new_err(format!(
            "option {key}: expected 2 values, got {}",
            items.len()
        ))),
    }
}

/// Reads the keyword options over the defaults of `sensor` for a camera `width_px` wide
/// ([`SlamConfig::for_camera`]); unknown names are an error, not ignored.
///
/// A stereo system needs `baseline` (metres) and derives `bf = fx * baseline` from it; an
/// RGB-D system takes the virtual baseline as `bf` directly (ORB-SLAM's setting).
pub fn parse(
    sensor: Sensor,
    fx: f64,
    width_px: u32,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<SlamConfig> {
    let mut config = SlamConfig::for_camera(sensor, width_px);
    let mut baseline: Option<f64> = None;
    let mut bf_given = false;
    for (key, value) in options.map(|o| o.iter()).into_iter().flatten() {
        let key: String = key.extract()?;
        let wrong = |e: PyErr| PyTypeError::new_err(format!("option {key}: {e}"));
        match key.as_str() {
            "n_features" => config.n_features = value.extract().map_err(wrong)?,
            "ini_fast" => config.ini_fast = value.extract().map_err(wrong)?,
            "min_fast" => config.min_fast = value.extract().map_err(wrong)?,
            "scale_factor" => config.scale_factor = value.extract().map_err(wrong)?,
            "n_levels" => config.n_levels = value.extract().map_err(wrong)?,
            "track_feature_range" => config.track_feature_range = pair(&key, &value)?,
            "skip_max_frames" => config.skip_max_frames = value.extract().map_err(wrong)?,
            "bf" => {
                config.bf = value.extract().map_err(wrong)?;
                bf_given = true;
            }
            "baseline" => baseline = Some(value.extract().map_err(wrong)?),
            "depth_threshold" => config.depth_threshold = value.extract().map_err(wrong)?,
            "depth_range" => config.depth_range = pair(&key, &value)?,
            "seed" => config.seed = value.extract().map_err(wrong)?,
            "loop_closure" => config.loop_closure = value.extract().map_err(wrong)?,
            "loop_closure_threshold" => {
                config.loop_closure_threshold = value.extract().map_err(wrong)?
            }
            _ => {
                return Err(PyValueError::new_err(format!(
                    "unknown option {key:?}; known: {OPTIONS}"
                )))
            }
        }
    }
    match (sensor, baseline) {
        (Sensor::Stereo, Some(b)) if b.is_finite() && b > 0.0 && !bf_given => config.bf = fx * b,
        (Sensor::Stereo, Some(b)) if !bf_given => {
            return Err(PyValueError::new_err(format!(
                "option baseline: must be a positive number of metres, got {b}"
            )))
        }
        (Sensor::Stereo, _) => {
            return Err(PyValueError::new_err(
                "sensor 'stereo' needs baseline=<metres> (and no bf: it is fx * baseline)",
            ))
        }
        (_, Some(_)) => {
            return Err(PyValueError::new_err(format!(
                "option baseline applies to sensor 'stereo', not {:?} (RGB-D uses bf)",
                sensor.name()
            )))
        }
        _ => {}
    }
    Ok(config)
}

/// `config` as the keyword options that rebuild it (`bf` stands for a stereo `baseline`).
pub fn options_dict<'py>(py: Python<'py>, config: &SlamConfig) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("n_features", config.n_features)?;
    d.set_item("ini_fast", config.ini_fast)?;
    d.set_item("min_fast", config.min_fast)?;
    d.set_item("scale_factor", config.scale_factor)?;
    d.set_item("n_levels", config.n_levels)?;
    d.set_item("track_feature_range", config.track_feature_range)?;
    d.set_item("skip_max_frames", config.skip_max_frames)?;
    d.set_item("bf", config.bf)?;
    d.set_item("depth_threshold", config.depth_threshold)?;
    d.set_item("depth_range", config.depth_range)?;
    d.set_item("seed", config.seed)?;
    d.set_item("loop_closure", config.loop_closure)?;
    d.set_item("loop_closure_threshold", config.loop_closure_threshold)?;
    Ok(d)
}

/// The default options of `sensor` ("mono", "stereo" or "rgbd") for images `width` pixels
/// wide, as a dict of `SlamSystem` keyword options: what a system built without options
/// uses. The ORB budget `n_features` follows the width (1000 at 640 px, 1200 at 752,
/// 1900 at 1241).
#[pyfunction]
pub fn default_options<'py>(
    py: Python<'py>,
    sensor: &str,
    width: i64,
) -> PyResult<Bound<'py, PyDict>> {
    let width = u32::try_from(width)
        .ok()
        .filter(|&w| w > 0)
        .ok_or_else(|| {
            PyValueError::new_err(format!("width = {width}: image width must be positive"))
        })?;
    options_dict(py, &SlamConfig::for_camera(self::sensor(sensor)?, width))
}
