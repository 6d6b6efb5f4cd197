//! numpy <-> core conversions with shape and value checks.

use ferroslam_features::{Descriptor, FeaturesError, GrayImage, Keypoint};
use nalgebra::Isometry3;
use numpy::ndarray::{Array1, Array2, Array3, Dimension};
use numpy::PyReadonlyArray2 as Image;
use numpy::{Element, PyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray};
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

/// Keypoints as a `(N, 5)` float32 array `[x, y, octave, angle_deg, response]`.
pub fn keypoint_array<'py>(py: Python<'py>, keypoints: &[Keypoint]) -> Bound<'py, PyArray2<f32>> {
    let rows = Array2::from_shape_fn((keypoints.len(), 5), |(i, c)| {
        let k = &keypoints[i];
        [k.x, k.y, f32::from(k.octave), k.angle_deg, k.response][c]
    });
    PyArray2::from_owned_array(py, rows)
}

/// `obj` as a read-only numpy array of element `T` and rank `D`.
///
/// A `TypeError` names the argument, what was `expected` and what was passed: numpy's own
/// conversion error ("'ndarray' object cannot be cast as 'ndarray'") names neither.
pub fn array<'py, T: Element, D: Dimension>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    expected: &str,
) -> PyResult<PyReadonlyArray<'py, T, D>> {
    match obj.cast::<PyArray<T, D>>() {
        // A borrow conflict (array mutably borrowed elsewhere) keeps numpy's own error.
        Ok(arr) => arr.try_readonly().map_err(PyErr::from),
        Err(_) => {
            let got = match obj.cast::<PyUntypedArray>() {
                Ok(a) => format!("{} array of shape {}", a.dtype(), shape_tuple(a.shape())),
                Err(_) => obj
                    .get_type()
                    .name()
                    .map_or_else(|_| "another type".into(), |n| n.to_string()),
            };
            Err(PyTypeError::new_err(format!(
                "{name} must be {expected}, got {got}"
            )))
        }
    }
}

/// A shape written as Python writes it: `(3,)`, `(3, 5)`.
pub fn shape_tuple(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Keypoints `(N, 5)` float32 `[x, y, octave, angle_deg, response]` in raw pixels.
pub fn keypoints(arr: &PyReadonlyArray2<'_, f32>) -> PyResult<Vec<Keypoint>> {
    let shape = arr.shape();
    if shape[1] != 5 {
        return Err(PyValueError::new_err(format!(
            "keypoints must have shape (N, 5) [x, y, octave, angle, response], got ({}, {})",
            shape[0], shape[1]
        )));
    }
    let a = arr.as_array();
    let mut out = Vec::with_capacity(shape[0]);
    for (i, row) in a.rows().into_iter().enumerate() {
        if row.iter().any(|v| !v.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "keypoints row {i} contains NaN or inf"
            )));
        }
        let octave = row[2];
        if octave < 0.0 || octave.fract() != 0.0 || octave > 255.0 {
            return Err(PyValueError::new_err(format!(
                "keypoints row {i}: octave {octave} is not a small non-negative integer"
            )));
        }
        out.push(Keypoint {
            x: row[0],
            y: row[1],
            octave: octave as u8,
            angle_deg: row[3],
            response: row[4],
        });
    }
    Ok(out)
}

/// Descriptors `(N, 32)` uint8.
pub fn descriptors(arr: &PyReadonlyArray2<'_, u8>) -> PyResult<Vec<Descriptor>> {
    let shape = arr.shape();
    if shape[1] != 32 {
        return Err(PyValueError::new_err(format!(
            "descriptors must have shape (N, 32) uint8 (256-bit ORB), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    Ok(arr
        .as_array()
        .rows()
        .into_iter()
        .map(|row| {
            let mut d = [0u8; 32];
            d.iter_mut().zip(row.iter()).for_each(|(o, v)| *o = *v);
            d
        })
        .collect())
}

/// A 1-D float32 array copied out.
pub fn floats(arr: &PyReadonlyArray1<'_, f32>) -> Vec<f32> {
    arr.as_array().iter().copied().collect()
}

/// A pose as a `(4, 4)` row-major homogeneous matrix.
pub fn pose_matrix(T: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m = T.to_homogeneous();
    let mut out = [[0.0; 4]; 4];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    out
}

/// Stacks poses into a `(K, 4, 4)` float64 array.
pub fn pose_stack<'py>(py: Python<'py>, poses: &[Isometry3<f64>]) -> Bound<'py, PyArray3<f64>> {
    let mut a = Array3::<f64>::zeros((poses.len(), 4, 4));
    for (k, T) in poses.iter().enumerate() {
        for (r, row) in pose_matrix(T).iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                a[(k, r, c)] = *v;
            }
        }
    }
    PyArray3::from_owned_array(py, a)
}

/// What a point without a colour is given: mid grey, as the exporters draw uncoloured points.
const UNCOLORED: [u8; 3] = [128; 3];

/// `(N, 3)` uint8 RGB of per-point colours, [`UNCOLORED`] where there is none.
pub fn colors_array<'py>(py: Python<'py>, colors: &[Option<[u8; 3]>]) -> Bound<'py, PyArray2<u8>> {
    PyArray2::from_owned_array(
        py,
        Array2::from_shape_fn((colors.len(), 3), |(i, c)| {
            colors[i].unwrap_or(UNCOLORED)[c]
        }),
    )
}

/// A 1-D float64 array.
pub fn f64_array<'py>(py: Python<'py>, values: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_owned_array(py, Array1::from(values))
}

/// A 2-D uint8 array as `(width, height, pixels)`, the pixels copied row-major (numpy views
/// need not be contiguous, and the callers read them with the GIL released, when Python code
/// could write to the array).
pub fn gray_image(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(usize, usize, Vec<u8>)> {
    let img: Image<'_, u8> = array(obj, name, "a 2-D uint8 array")?;
    let shape = img.shape();
    if shape[0] == 0 || shape[1] == 0 {
        return Err(PyValueError::new_err(format!(
            "{name} is an empty image (shape {})",
            shape_tuple(shape)
        )));
    }
    let pixels = match img.as_slice() {
        Ok(contiguous) => contiguous.to_vec(),
        Err(_) => img.as_array().iter().copied().collect(),
    };
    Ok((shape[1], shape[0], pixels))
}

/// An image pyramid given as a sequence of 2-D uint8 arrays: [`gray_image`] per level.
pub fn pyramid(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<(usize, usize, Vec<u8>)>> {
    let levels: Vec<Bound<'_, PyAny>> = obj.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name} must be a list of 2-D uint8 arrays (pyramid levels)"
        ))
    })?;
    if levels.is_empty() {
        return Err(PyValueError::new_err(format!(
            "{name} is empty: give at least level 0"
        )));
    }
    levels
        .iter()
        .enumerate()
        .map(|(l, level)| gray_image(level, &format!("{name}[{l}]")))
        .collect()
}

/// Borrowed views of the levels returned by [`pyramid`].
pub fn views(levels: &[(usize, usize, Vec<u8>)]) -> Result<Vec<GrayImage<'_>>, FeaturesError> {
    levels
        .iter()
        .map(|(w, h, data)| GrayImage::new(*w, *h, data))
        .collect()
}

/// `{side}_keypoints (N, 5)` float32 and `{side}_descriptors (N, 32)` uint8 of one image
/// (`side` is "left", "right" or "" for the plain names).
pub fn features(
    keypoints: &Bound<'_, PyAny>,
    descriptors: &Bound<'_, PyAny>,
    side: &str,
) -> PyResult<(Vec<Keypoint>, Vec<Descriptor>)> {
    let prefix = if side.is_empty() {
        String::new()
    } else {
        format!("{side}_")
    };
    let kp: PyReadonlyArray2<'_, f32> = array(
        keypoints,
        &format!("{prefix}keypoints"),
        "a float32 (N, 5) array",
    )?;
    let desc: PyReadonlyArray2<'_, u8> = array(
        descriptors,
        &format!("{prefix}descriptors"),
        "a uint8 (N, 32) array",
    )?;
    let (kps, descs) = (self::keypoints(&kp)?, self::descriptors(&desc)?);
    if kps.len() != descs.len() {
        return Err(PyValueError::new_err(format!(
            "{prefix}keypoints ({}) and {prefix}descriptors ({}) must have the same length",
            kps.len(),
            descs.len()
        )));
    }
    Ok((kps, descs))
}

/// Optional `colors (N, 3)` uint8 RGB, one per keypoint of `keypoints` (its argument name,
/// for messages) of which there are `n`.
pub fn colors(
    obj: Option<&Bound<'_, PyAny>>,
    n: usize,
    keypoints: &str,
) -> PyResult<Option<Vec<[u8; 3]>>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    let arr: PyReadonlyArray2<'_, u8> = array(obj, "colors", "a uint8 (N, 3) RGB array")?;
    let shape = arr.shape();
    if shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "colors must have shape (N, 3) RGB, got {}",
            shape_tuple(shape)
        )));
    }
    if shape[0] != n {
        return Err(PyValueError::new_err(format!(
            "colors ({}) and {keypoints} ({n}) must have the same length: one RGB per keypoint",
            shape[0]
        )));
    }
    Ok(Some(
        arr.as_array()
            .rows()
            .into_iter()
            .map(|row| [row[0], row[1], row[2]])
            .collect(),
    ))
}
