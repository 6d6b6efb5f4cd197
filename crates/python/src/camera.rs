//! `project_points` / `unproject_pixels`: the core's camera models on their own, behind
//! `ferroslam.Camera.project` and `Camera.unproject`.
//!
//! Both work on RAW image pixels (the lens distortion applied), for every model.

use crate::pool;
use ferroslam_geometry::camera::{CameraModel, KannalaBrandtCamera, PinholeCamera, RadTan};
use ferroslam_geometry::rolling_shutter::ReadoutDirection;
use nalgebra::{Isometry3, Vector2, Vector3};
use numpy::ndarray::Array2;
use numpy::{PyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::convert;
use crate::errors::geometry_to_py;
use crate::inertial;

/// The `CameraModel` of a `ferroslam.Camera` (its `model`, `fx fy cx cy`, `dist`, `width`,
/// `height`, `rolling_shutter_readout_s` attributes): the one conversion from the Python camera to the core's.
///
/// `TypeError` for a value of the wrong type, `ValueError` (naming the parameter) for an
/// unknown model, a wrong number of coefficients or values the core refuses.
pub fn camera_model(camera: &Bound<'_, PyAny>) -> PyResult<CameraModel> {
    let attr = |name: &str| {
        camera.getattr(name).map_err(|_| {
            PyTypeError::new_err(format!(
                "camera must be a ferroslam.Camera, got {} (no attribute {name})",
                camera
                    .get_type()
                    .name()
                    .map_or_else(|_| "another type".into(), |n| n.to_string())
            ))
        })
    };
    let number = |name: &str| -> PyResult<f64> {
        attr(name)?
            .extract()
            .map_err(|_| PyTypeError::new_err(format!("camera.{name} must be a real number")))
    };
    let size = |name: &str| -> PyResult<u32> {
        attr(name)?.extract().map_err(|_| {
            PyTypeError::new_err(format!(
                "camera.{name} must be a positive integer below 2^32"
            ))
        })
    };
    let model: String = attr("model")?
        .extract()
        .map_err(|_| PyTypeError::new_err("camera.model must be a string"))?;
    let dist: Vec<f64> = attr("dist")?
        .extract()
        .map_err(|_| PyTypeError::new_err("camera.dist must be a sequence of real numbers"))?;
    let (fx, fy, cx, cy) = (number("fx")?, number("fy")?, number("cx")?, number("cy")?);
    let (width, height) = (size("width")?, size("height")?);
    let readout_s = number("rolling_shutter_readout_s")?;
    camera_model_of(&model, [fx, fy, cx, cy], &dist, width, height, readout_s)
}

/// The camera of a `model` name, its `[fx, fy, cx, cy]` (pixels), `dist` and image size: the
/// one place model names and coefficient counts are read. "pinhole": `dist` holds 0, 4 or 5
/// radial-tangential coefficients (k1 k2 p1 p2 [k3]); "kannala_brandt": k1..k4. Rows are
/// read top first over `readout_s` seconds (0: a global shutter).
pub fn camera_model_of(
    model: &str,
    [fx, fy, cx, cy]: [f64; 4],
    dist: &[f64],
    width: u32,
    height: u32,
    readout_s: f64,
) -> PyResult<CameraModel> {
    let invalid = |e| geometry_to_py("invalid camera", e);
    let camera = match model {
        "pinhole" => {
            let [k1, k2, p1, p2, k3] = match *dist {
                [] => [0.0; 5],
                [k1, k2, p1, p2] => [k1, k2, p1, p2, 0.0],
                [k1, k2, p1, p2, k3] => [k1, k2, p1, p2, k3],
                _ => {
                    return Err(PyValueError::new_err(format!(
                        "dist must hold 0, 4 or 5 coefficients (k1 k2 p1 p2 [k3]), got {}",
                        dist.len()
                    )))
                }
            };
            let distortion = RadTan { k1, k2, p1, p2, k3 };
            PinholeCamera::new(fx, fy, cx, cy, distortion, width, height)
                .map(CameraModel::from)
                .map_err(invalid)
        }
        "kannala_brandt" => {
            let [k1, k2, k3, k4] = *dist else {
                return Err(PyValueError::new_err(format!(
                    "a kannala_brandt camera's dist must hold 4 coefficients (k1 k2 k3 k4), \
                     got {}",
                    dist.len()
                )));
            };
            KannalaBrandtCamera::new(fx, fy, cx, cy, [k1, k2, k3, k4], width, height)
                .map(CameraModel::from)
                .map_err(invalid)
        }
        other => Err(PyValueError::new_err(format!(
            "unknown camera model {other:?} (use pinhole, kannala_brandt)"
        ))),
    }?;
    camera
        .with_readout(readout_s, ReadoutDirection::TopToBottom)
        .map_err(|e| geometry_to_py("invalid camera: rolling_shutter_readout_s", e))
}

/// The rows of `obj`, a float64 `(N, columns)` array named `name`, copied out (the core
/// then reads them with the GIL released).
fn rows(obj: &Bound<'_, PyAny>, name: &str, columns: usize) -> PyResult<Vec<f64>> {
    let expected = format!("a float64 (N, {columns}) array");
    let arr: PyReadonlyArrayDyn<'_, f64> = convert::array(obj, name, &expected)?;
    let shape = arr.shape();
    if shape.len() != 2 || shape[1] != columns {
        return Err(PyValueError::new_err(format!(
            "{name} must be {expected}, got shape {}",
            convert::shape_tuple(shape)
        )));
    }
    Ok(arr.as_array().iter().copied().collect())
}

/// `f` applied to every row of `obj`, a float64 `(N, IN)` array named `name`, with the GIL
/// released: a float64 `(N, OUT)` array, NaN rows where `f` gives `None`.
fn map_rows<'py, const IN: usize, const OUT: usize>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    name: &str,
    f: impl Fn([f64; IN]) -> Option<[f64; OUT]> + Send + Sync,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let input = rows(obj, name, IN)?;
    let output: Vec<f64> = pool::detach(py, || {
        input
            .chunks_exact(IN)
            .flat_map(|row| {
                let row: [f64; IN] = std::array::from_fn(|i| row[i]);
                f(row).unwrap_or([f64::NAN; OUT])
            })
            .collect()
    })?;
    let a = Array2::from_shape_vec((output.len() / OUT, OUT), output)
        .unwrap_or_else(|_| unreachable!("OUT values per row"));
    Ok(PyArray2::from_owned_array(py, a))
}

/// Raw image pixels `(N, 2)` float64 of camera-frame points `(N, 3)` float64 (metres); NaN
/// rows where the model does not project (behind a pinhole, past a fisheye's largest
/// incidence angle, non-finite points).
#[pyfunction]
pub fn project_points<'py>(
    py: Python<'py>,
    camera: &Bound<'py, PyAny>,
    points: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let model = camera_model(camera)?;
    map_rows(py, points, "points", |p: [f64; 3]| {
        model.project_raw(&Vector3::from(p)).map(|uv| [uv.x, uv.y])
    })
}

/// Unit rays `(N, 3)` float64 (camera frame) through raw image pixels `(N, 2)` float64; NaN
/// rows where the model has none (outside a fisheye's image circle, non-finite pixels).
#[pyfunction]
pub fn unproject_pixels<'py>(
    py: Python<'py>,
    camera: &Bound<'py, PyAny>,
    pixels: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let model = camera_model(camera)?;
    map_rows(py, pixels, "pixels", |uv: [f64; 2]| {
        model
            .unproject_raw(&Vector2::from(uv))
            .map(|r| [r.x, r.y, r.z])
    })
}

/// How a further camera of the rig gets depth: none, its own depth images, or its stereo
/// partner (the partner camera and `T_left_right`, its pose in this camera).
pub enum FurtherDepth {
    None,
    Images,
    Partner(CameraModel, Isometry3<f64>),
}

/// `cameras` of the constructor: `(camera, T_c0_c)` or `(camera, T_c0_c, depth)` per further
/// camera of the rig, `depth` a bool (depth images) or `(partner_camera, T_left_right)`.
#[allow(non_snake_case)]
pub fn further_cameras(
    cameras: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<(CameraModel, Isometry3<f64>, FurtherDepth)>> {
    let Some(cameras) = cameras.filter(|c| !c.is_none()) else {
        return Ok(Vec::new());
    };
    let entry_error = |k: usize| {
        PyTypeError::new_err(format!(
            "cameras[{k}] must be (camera, T_c0_c) or (camera, T_c0_c, depth), depth a bool \
             or (partner_camera, T_left_right)"
        ))
    };
    let mut out = Vec::new();
    for (k, entry) in cameras.try_iter()?.enumerate() {
        let entry = entry?;
        let items: Vec<Bound<'_, PyAny>> = entry
            .try_iter()
            .map_err(|_| entry_error(k))?
            .collect::<PyResult<_>>()?;
        if !(2..=3).contains(&items.len()) {
            return Err(entry_error(k));
        }
        let camera = camera_model(&items[0])?;
        let T_c0_c = inertial::rigid_transform(&items[1], &format!("cameras[{k}] T_c0_c"))?;
        let depth = match items.get(2) {
            None => FurtherDepth::None,
            Some(d) => match d.extract::<bool>() {
                Ok(true) => FurtherDepth::Images,
                Ok(false) => FurtherDepth::None,
                Err(_) => {
                    let partner: Vec<Bound<'_, PyAny>> = d
                        .try_iter()
                        .map_err(|_| entry_error(k))?
                        .collect::<PyResult<_>>()?;
                    let [partner, T] = partner.as_slice() else {
                        return Err(entry_error(k));
                    };
                    let T = inertial::rigid_transform(T, &format!("cameras[{k}] T_left_right"))?;
                    FurtherDepth::Partner(camera_model(partner)?, T)
                }
            },
        };
        out.push((camera, T_c0_c, depth));
    }
    Ok(out)
}
