//! `SlamSystem` keyword options <-> the core's `SlamConfig`, `default_options`: the
//! defaults the CLI, `run_sequence` and the vSLAM objects read, and `option_table`: the
//! core's declaration of every option ([`ferroslam_slam::user_options`]) with its defaults,
//! which `ferroslam.options` and `docs/options.md` are built from.
//!
//! The options are flat keywords (`n_features`, `skip_max_frames`, ...), each the field of
//! one section of the configuration. One table, [`OPTIONS`], says for each option which
//! field it is, how its Python value is read and how the field is written back: [`parse`],
//! [`options_dict`] and the unknown-option error all walk it. A value of the wrong type is a
//! `TypeError` naming the option and the type expected; a value out of range is the core's
//! `ValueError` from `SlamConfig::validate`, naming `section.field`.

use ferroslam_slam::{
    user_options, ImuParams, InertialConfig, OptionKind, OptionScope, Sensor, SlamConfig,
    UserOption,
};
use nalgebra::Isometry3;
use pyo3::conversion::FromPyObjectOwned;
use pyo3::exceptions::{PyNotImplementedError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use pyo3::IntoPyObjectExt;

/// Sensors the core can track.
const SENSORS: [Sensor; 3] = [Sensor::Monocular, Sensor::Stereo, Sensor::Rgbd];

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

/// A configuration being read from keyword options, with what the stereo rule needs.
struct Parsed {
    config: SlamConfig,
    /// `baseline`, metres, when given (stereo: `bf = fx * baseline`).
    baseline: Option<f64>,
    /// Whether `bf` was given.
    bf_given: bool,
}

/// Reads an option's Python value into the configuration being built.
type Reader = fn(&mut Parsed, &Bound<'_, PyAny>) -> PyResult<()>;
/// An option's value in a configuration, as a Python object.
type Writer = fn(&SlamConfig, Python<'_>) -> PyResult<Py<PyAny>>;

/// One keyword option: its name, how its value is read into the configuration and how its
/// field is written back (`None`: not written back, see `baseline`).
struct Opt {
    name: &'static str,
    read: Reader,
    write: Option<Writer>,
}

/// An option that is the field `$field` (a path into the sections) of the configuration,
/// read by `$read` (one of the typed readers below).
macro_rules! field {
    ($name:literal, $($field:ident).+, $read:ident) => {
        Opt {
            name: $name,
            read: |p, value| {
                p.config.$($field).+ = $read($name, value)?;
                Ok(())
            },
            write: Some(|config, py| config.$($field).+.into_py_any(py)),
        }
    };
}

/// Every keyword option of `SlamSystem`, in the order of [`options_dict`] and of the
/// unknown-option error: the core-scope options of [`user_options`], in its order (a test
/// of the package checks it).
const OPTIONS: &[Opt] = &[
    field!("n_features", extractor.n_features, int),
    field!("ini_fast", extractor.ini_fast, int),
    field!("min_fast", extractor.min_fast, int),
    field!("scale_factor", extractor.scale_factor, number),
    field!("n_levels", extractor.n_levels, int),
    field!("track_feature_range", tracking.track_feature_range, pair),
    field!("skip_max_frames", tracking.skip_max_frames, int),
    field!(
        "relocalisation_window_s",
        tracking.relocalisation_window_s,
        number
    ),
    field!("gap_frames", tracking.gap_frames, int),
    Opt {
        name: "bf",
        read: |p, value| {
            p.config.depth.bf = number("bf", value)?;
            p.bf_given = true;
            Ok(())
        },
        write: Some(|config, py| config.depth.bf.into_py_any(py)),
    },
    // A stereo rig's baseline, metres; written back as `bf`.
    Opt {
        name: "baseline",
        read: |p, value| {
            p.baseline = Some(number("baseline", value)?);
            Ok(())
        },
        write: None,
    },
    field!("depth_threshold", depth.depth_threshold, number),
    field!("depth_range", depth.depth_range, pair),
    field!("match_pair_every_frame", depth.match_pair_every_frame, flag),
    field!("seed", seed, int),
    field!("deterministic", deterministic, flag),
    field!("loop_closure", loop_closing.loop_closure, flag),
    field!(
        "loop_closure_threshold",
        loop_closing.loop_closure_threshold,
        int
    ),
];

/// The option names, comma-separated, for errors.
fn option_names() -> String {
    OPTIONS
        .iter()
        .map(|o| o.name)
        .collect::<Vec<_>>()
        .join(", ")
}

/// `TypeError`: `option` needs a value of type `expected`.
fn wrong_type(option: &str, expected: &str, value: &Bound<'_, PyAny>) -> PyErr {
    let got = value
        .get_type()
        .name()
        .map_or_else(|_| "?".to_owned(), |n| n.to_string());
    PyTypeError::new_err(format!("option {option}: expected {expected}, got {got}"))
}

/// An integer (Python int or anything with `__index__`, e.g. a numpy integer); one the
/// field's type cannot hold is a `ValueError`.
fn int<'py, T: FromPyObjectOwned<'py>>(option: &str, value: &Bound<'py, PyAny>) -> PyResult<T> {
    value
        .extract::<T>()
        .map_err(|_| match value.extract::<i128>() {
            Ok(n) => PyValueError::new_err(format!(
                "option {option}: {n} is out of range for its type ({})",
                std::any::type_name::<T>()
            )),
            Err(_) => wrong_type(option, "an int", value),
        })
}

/// A real number (an int is accepted).
fn number(option: &str, value: &Bound<'_, PyAny>) -> PyResult<f64> {
    value
        .extract()
        .map_err(|_| wrong_type(option, "a number", value))
}

/// `True` or `False`.
fn flag(option: &str, value: &Bound<'_, PyAny>) -> PyResult<bool> {
    value
        .extract()
        .map_err(|_| wrong_type(option, "a bool", value))
}

/// A two-element sequence (tuple, list or array) of numbers as a pair.
fn pair<'py, T: FromPyObjectOwned<'py> + Copy>(
    option: &str,
    value: &Bound<'py, PyAny>,
) -> PyResult<(T, T)> {
    let items: Vec<T> = value.extract().map_err(|e| {
        PyTypeError::new_err(format!("option {option}: expected a pair of numbers: {e}"))
    })?;
    match items[..] {
        [a, b] => Ok((a, b)),
        _ => Err(PyValueError::new_err(format!(
            "option {option}: expected 2 values, got {}",
            items.len()
        ))),
    }
}

/// Reads the keyword options over the defaults of `sensor` for a camera `width_px` wide
/// ([`SlamConfig::for_camera`]); unknown names are an error, not ignored.
///
/// A stereo system needs `baseline` (metres) and derives `bf = fx * baseline` from it, unless
/// it is an `unrectified_pair`, whose baseline is that of its extrinsics (and which then takes
/// neither); an RGB-D system takes the virtual baseline as `bf` directly (ORB-SLAM's setting).
pub fn parse(
    sensor: Sensor,
    fx: f64,
    width_px: u32,
    options: Option<&Bound<'_, PyDict>>,
    unrectified_pair: bool,
) -> PyResult<SlamConfig> {
    let mut parsed = Parsed {
        config: SlamConfig::for_camera(sensor, width_px),
        baseline: None,
        bf_given: false,
    };
    for (key, value) in options.map(|o| o.iter()).into_iter().flatten() {
        let key: String = key.extract()?;
        let Some(option) = OPTIONS.iter().find(|o| o.name == key) else {
            return Err(PyValueError::new_err(format!(
                "unknown option {key:?}; known: {}",
                option_names()
            )));
        };
        (option.read)(&mut parsed, &value)?;
    }
    let Parsed {
        mut config,
        baseline,
        bf_given,
    } = parsed;
    match (sensor, baseline) {
        (Sensor::Stereo, baseline) if unrectified_pair && (baseline.is_some() || bf_given) => {
            return Err(PyValueError::new_err(
                "an unrectified stereo pair takes its baseline from T_left_right: pass neither \
                 baseline nor bf",
            ))
        }
        (Sensor::Stereo, _) if unrectified_pair => {}
        (Sensor::Stereo, Some(b)) if b.is_finite() && b > 0.0 && !bf_given => {
            config.depth.bf = fx * b
        }
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
    for option in OPTIONS {
        if let Some(write) = option.write {
            d.set_item(option.name, write(config, py)?)?;
        }
    }
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
    let width = positive_width(width)?;
    options_dict(py, &SlamConfig::for_camera(self::sensor(sensor)?, width))
}

/// An IMU option's default: [`InertialConfig::new`]'s, the one place they are written.
fn imu_default(py: Python<'_>, name: &str) -> PyResult<Py<PyAny>> {
    let imu = InertialConfig::new(ImuParams::euroc(), Isometry3::identity());
    match name {
        "num_poses_threshold" => imu.num_poses_threshold.into_py_any(py),
        "alignment_fraction" => imu.alignment_fraction.into_py_any(py),
        "gravity_magnitude" => imu.gravity_magnitude.into_py_any(py),
        "imu_time_offset_s" => imu.imu_time_offset_s.into_py_any(py),
        other => Err(PyNotImplementedError::new_err(format!(
            "IMU option {other} has no default in the binding"
        ))),
    }
}

/// One option of [`user_options`] as a dict, its default per sensor for images `width` px
/// wide (`None` where it has none: `baseline`).
fn option_entry<'py>(
    py: Python<'py>,
    option: &UserOption,
    width: u32,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("name", option.name)?;
    d.set_item("scope", option.scope.name())?;
    d.set_item("field", option.field)?;
    d.set_item("kind", option.kind.name())?;
    d.set_item("unit", option.unit)?;
    let r = &option.range;
    if matches!(option.kind, OptionKind::Int | OptionKind::IntPair) {
        // Integer bounds as Python ints, exact: `u64::MAX as f64` rounds up to 2^64, and
        // the cast back saturates to `u64::MAX`, the seed's largest value.
        d.set_item("low", r.low.map(|l| l as i64))?;
        d.set_item("high", r.high.map(|h| h as u64))?;
    } else {
        d.set_item("low", r.low)?;
        d.set_item("high", r.high)?;
    }
    d.set_item("open_low", r.open_low)?;
    d.set_item("open_high", r.open_high)?;
    d.set_item("infinite_high", r.infinite_high)?;
    let sensors: Vec<&str> = option.sensors.iter().map(|s| s.name()).collect();
    d.set_item("sensors", PyTuple::new(py, sensors)?)?;
    d.set_item("doc", option.doc)?;
    let defaults = PyDict::new(py);
    for sensor in SENSORS {
        let value = match option.scope {
            OptionScope::Imu => imu_default(py, option.name)?,
            OptionScope::Core => {
                let config = SlamConfig::for_camera(sensor, width);
                match OPTIONS.iter().find(|o| o.name == option.name) {
                    Some(Opt {
                        write: Some(write), ..
                    }) => write(&config, py)?,
                    Some(_) => py.None(),
                    None => {
                        return Err(PyNotImplementedError::new_err(format!(
                            "option {} of the core's table is not parsed by the binding",
                            option.name
                        )))
                    }
                }
            }
        };
        defaults.set_item(sensor.name(), value)?;
    }
    d.set_item("defaults", defaults)?;
    Ok(d)
}

/// The core's declaration of every user-facing option, in order, as a list of dicts: `name`,
/// `scope` (`"core"`: `SlamSystem` keywords; `"imu"`: `set_imu` keywords), `field` (the
/// configuration field it sets, `section.field`), `kind`, `unit`, the range (`low`, `high`,
/// `open_low`, `open_high`, `infinite_high`), `sensors`, `doc` and `defaults` (sensor name
/// -> default for images `width` px wide; `None`: none, the option must be given).
#[pyfunction]
#[pyo3(signature = (width = 640))]
pub fn option_table<'py>(py: Python<'py>, width: i64) -> PyResult<Bound<'py, PyList>> {
    let width = positive_width(width)?;
    let entries = user_options()
        .iter()
        .map(|option| option_entry(py, option, width))
        .collect::<PyResult<Vec<_>>>()?;
    PyList::new(py, entries)
}

/// `width` as a positive `u32`.
fn positive_width(width: i64) -> PyResult<u32> {
    u32::try_from(width).ok().filter(|&w| w > 0).ok_or_else(|| {
        PyValueError::new_err(format!("width = {width}: image width must be positive"))
    })
}
