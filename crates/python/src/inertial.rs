//! IMU input and the camera-IMU alignment status: numpy/Python objects <-> core types.

use ferroslam_slam::{AlignmentStatus, Bias, ImuParams, ImuSample, InertialConfig};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert;

/// Field names of the IMU noise model, as `ferroslam.datasets.euroc.ImuParams` spells them.
const PARAM_NAMES: [&str; 5] = [
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
    "rate_hz",
];

/// The noise model from an object with the [`PARAM_NAMES`] attributes (e.g. `ImuParams`) or
/// a dict with those keys.
fn imu_params(params: &Bound<'_, PyAny>) -> PyResult<ImuParams> {
    let mut values = [0.0; 5];
    for (value, name) in values.iter_mut().zip(PARAM_NAMES) {
        let item = match params.cast::<PyDict>() {
            Ok(dict) => dict.get_item(name)?,
            Err(_) => params.getattr(name).ok(),
        };
        let item = item.ok_or_else(|| {
            PyTypeError::new_err(format!(
                "imu params: missing {name:?}; pass ferroslam.datasets.euroc.ImuParams or a \
                 dict with {PARAM_NAMES:?}"
            ))
        })?;
        *value = item
            .extract()
            .map_err(|e| PyTypeError::new_err(format!("imu params: {name}: {e}")))?;
    }
    Ok(ImuParams {
        gyro_noise_density: values[0],
        gyro_random_walk: values[1],
        accel_noise_density: values[2],
        accel_random_walk: values[3],
        rate_hz: values[4],
    })
}

/// A rigid `(4, 4)` float64 transform (rotation orthonormal to 1e-6, last row 0 0 0 1).
pub(crate) fn rigid_transform(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Isometry3<f64>> {
    let arr: PyReadonlyArray2<'_, f64> = convert::array(obj, name, "a (4, 4) float64 array")?;
    if arr.shape() != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (4, 4), got {:?}",
            arr.shape()
        )));
    }
    let m = arr.as_array();
    let r = Matrix3::from_fn(|i, j| m[(i, j)]);
    let t = Vector3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    let last_row_ok = (0..4).all(|j| m[(3, j)] == if j == 3 { 1.0 } else { 0.0 });
    let rigid = m.iter().all(|v| v.is_finite())
        && last_row_ok
        && (r.transpose() * r - Matrix3::identity()).amax() < 1e-6
        && r.determinant() > 0.0;
    if !rigid {
        return Err(PyValueError::new_err(format!(
            "{name} must be a finite rigid transform: orthonormal rotation with determinant \
             +1, last row [0, 0, 0, 1]"
        )));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Isometry3::from_parts(Translation3::from(t), rotation))
}

/// The core's IMU setup from the Python arguments of `SlamSystem.set_imu`.
pub fn inertial_config(
    params: &Bound<'_, PyAny>,
    T_b_c: &Bound<'_, PyAny>,
    num_poses_threshold: Option<usize>,
    alignment_fraction: Option<f64>,
    gravity_magnitude: Option<f64>,
    imu_time_offset_s: Option<f64>,
) -> PyResult<InertialConfig> {
    let mut config = InertialConfig::new(imu_params(params)?, rigid_transform(T_b_c, "T_b_c")?);
    // Only the options given replace the core's defaults.
    let c = &mut config;
    c.num_poses_threshold = num_poses_threshold.unwrap_or(c.num_poses_threshold);
    c.alignment_fraction = alignment_fraction.unwrap_or(c.alignment_fraction);
    c.gravity_magnitude = gravity_magnitude.unwrap_or(c.gravity_magnitude);
    c.imu_time_offset_s = imu_time_offset_s.unwrap_or(c.imu_time_offset_s);
    Ok(config)
}

/// Samples from `timestamps (M,)`, `gyro (M, 3)` rad/s and `accel (M, 3)` m/s^2, float64.
pub fn samples(
    timestamps: &Bound<'_, PyAny>,
    gyro: &Bound<'_, PyAny>,
    accel: &Bound<'_, PyAny>,
) -> PyResult<Vec<ImuSample>> {
    let t: PyReadonlyArray1<'_, f64> =
        convert::array(timestamps, "timestamps", "a float64 (M,) array")?;
    let g: PyReadonlyArray2<'_, f64> = convert::array(gyro, "gyro", "a float64 (M, 3) array")?;
    let a: PyReadonlyArray2<'_, f64> = convert::array(accel, "accel", "a float64 (M, 3) array")?;
    let m = t.len();
    if g.shape() != [m, 3] || a.shape() != [m, 3] {
        return Err(PyValueError::new_err(format!(
            "gyro {:?} and accel {:?} must have shape ({m}, 3) for {m} timestamps",
            g.shape(),
            a.shape()
        )));
    }
    let (t, g, a) = (t.as_array(), g.as_array(), a.as_array());
    Ok((0..m)
        .map(|i| {
            ImuSample::new(
                t[i],
                Vector3::new(g[(i, 0)], g[(i, 1)], g[(i, 2)]),
                Vector3::new(a[(i, 0)], a[(i, 1)], a[(i, 2)]),
            )
        })
        .collect())
}

fn vector<'py>(py: Python<'py>, v: &Vector3<f64>) -> Bound<'py, PyArray1<f64>> {
    convert::f64_array(py, v.iter().copied().collect())
}

/// A keyframe's IMU state as a dict (see `SlamSystem.keyframe_imu_state` in the stub).
pub fn imu_state_dict<'py>(
    py: Python<'py>,
    keyframe_id: u32,
    timestamp: f64,
    velocity: &Vector3<f64>,
    bias: &Bias,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("keyframe_id", keyframe_id)?;
    d.set_item("timestamp", timestamp)?;
    d.set_item("velocity", vector(py, velocity))?;
    d.set_item("gyro_bias", vector(py, &bias.gyro))?;
    d.set_item("accel_bias", vector(py, &bias.accel))?;
    Ok(d)
}

/// The alignment status as a dict (see `SlamSystem.inertial_alignment` in the stub).
pub fn status_dict<'py>(py: Python<'py>, status: &AlignmentStatus) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    match status {
        AlignmentStatus::Waiting { keyframes, needed } => {
            d.set_item("status", "waiting")?;
            d.set_item("keyframes", keyframes)?;
            d.set_item("needed", needed)?;
        }
        AlignmentStatus::Failed { keyframes, reason } => {
            d.set_item("status", "failed")?;
            d.set_item("keyframes", keyframes)?;
            d.set_item("reason", reason)?;
        }
        AlignmentStatus::Aligned(a) => {
            d.set_item("status", "aligned")?;
            d.set_item("keyframes", a.velocities.len())?;
            d.set_item("scale", a.scale)?;
            d.set_item("map_rescaled", a.map_rescaled)?;
            d.set_item("gravity_w", vector(py, &a.gravity_w))?;
            let r = a.R_w_g.to_rotation_matrix();
            let r = Array2::from_shape_fn((3, 3), |(i, j)| r[(i, j)]);
            d.set_item("R_w_g", PyArray2::from_owned_array(py, r))?;
            d.set_item("gyro_bias", vector(py, &a.gyro_bias))?;
            d.set_item("accel_bias", vector(py, &a.accel_bias))?;
            let ids: Vec<u32> = a.keyframes.iter().map(|(id, _)| id.0).collect();
            d.set_item("keyframe_ids", PyArray1::from_vec(py, ids))?;
            let stamps = a.keyframes.iter().map(|&(_, t)| t).collect();
            d.set_item("keyframe_timestamps", convert::f64_array(py, stamps))?;
            let v = Array2::from_shape_fn((a.velocities.len(), 3), |(i, c)| a.velocities[i][c]);
            d.set_item("velocities", PyArray2::from_owned_array(py, v))?;
            d.set_item("timestamp", a.timestamp)?;
            d.set_item("acceleration_excitation", a.acceleration_excitation)?;
            d.set_item("refinement", a.refinement)?;
        }
    }
    Ok(d)
}
