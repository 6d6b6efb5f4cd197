//! The map as images, keypoints and tracks (`SlamSystem.sparse_model`,
//! `load_sparse_model` for a map file): the arrays `ferroslam.colmap` writes a COLMAP model
//! from.

use std::path::PathBuf;

use ferroslam_map::{Rig, SparseModel};
use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::camera::camera_model_of;
use crate::convert;
use crate::errors::to_py;
use crate::pool;

/// The model as a dict of arrays: `keyframe_ids (K,) uint32`, `timestamps (K,) float64`,
/// `T_w_c (K, 4, 4)`, `keypoint_offsets (K + 1,) int64` (image `k`'s keypoints are rows
/// `offsets[k]:offsets[k + 1]`), `keypoints_px (N, 2) float64` (raw image pixels, as seen
/// from `T_w_c`: rolling-shutter compensated, `ferroslam_map::sparse_model`),
/// `point_index (N,) int64` (row of `points_xyz`, -1 for none), `points_xyz (M, 3)`,
/// `point_colors (M, 3) uint8` (128 grey without colour).
pub fn model_dict<'py>(py: Python<'py>, model: SparseModel) -> PyResult<Bound<'py, PyDict>> {
    let mut offsets = vec![0i64];
    let mut keypoints = Vec::new();
    let mut point_index = Vec::new();
    for image in &model.images {
        keypoints.extend(image.keypoints_raw_px.iter().map(|uv| [uv.x, uv.y]));
        point_index.extend(image.point_index.iter().map(|p| p.map_or(-1, |i| i as i64)));
        offsets.push(keypoints.len() as i64);
    }
    let poses: Vec<_> = model.images.iter().map(|image| image.T_w_c).collect();
    let d = PyDict::new(py);
    d.set_item(
        "keyframe_ids",
        PyArray1::from_vec(py, model.images.iter().map(|i| i.id.0).collect()),
    )?;
    d.set_item(
        "timestamps",
        convert::f64_array(py, model.images.iter().map(|i| i.timestamp_s).collect()),
    )?;
    d.set_item("T_w_c", convert::pose_stack(py, &poses))?;
    d.set_item("keypoint_offsets", PyArray1::from_vec(py, offsets))?;
    d.set_item(
        "keypoints_px",
        PyArray2::from_owned_array(
            py,
            Array2::from_shape_fn((keypoints.len(), 2), |(i, c)| keypoints[i][c]),
        ),
    )?;
    d.set_item("point_index", PyArray1::from_vec(py, point_index))?;
    let points = &model.points;
    d.set_item(
        "points_xyz",
        PyArray2::from_owned_array(
            py,
            Array2::from_shape_fn((points.len(), 3), |(i, c)| points[i].position[c]),
        ),
    )?;
    let colors: Vec<_> = points.iter().map(|p| p.color).collect();
    d.set_item("point_colors", convert::colors_array(py, &colors))?;
    Ok(d)
}

/// `(camera, model)` of the map file at `path`: `camera` a dict (`sensor`, `model`, `fx`,
/// `fy`, `cx`, `cy`, `dist`, `width`, `height`) of the camera the map was built with, and
/// the model as `SlamSystem.sparse_model` gives it. The map is read without the GIL.
///
/// Raises `FileNotFoundError` for a missing file, `ValueError` for a corrupt one or one
/// without its camera record.
#[pyfunction]
pub fn load_sparse_model<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
    let (rig, model) = pool::detach(py, || -> PyResult<(Rig, SparseModel)> {
        let map = ferroslam_slam::load_map_file(&path).map_err(to_py)?;
        let rig = map.rig().cloned().ok_or_else(|| {
            PyValueError::new_err(format!(
                "{}: the map file records no camera (written before format version 3)",
                path.display()
            ))
        })?;
        let camera = camera_model_of(
            &rig.model,
            rig.intrinsics,
            distortion(&rig),
            rig.width,
            rig.height,
            // Row times are the keyframes' own, stored in the file (version 6 on): the
            // camera's readout is not needed to move keypoints to their reference poses.
            0.0,
        )?;
        Ok((rig.clone(), map.sparse_model(&camera)))
    })??;
    let camera = PyDict::new(py);
    let [fx, fy, cx, cy] = rig.intrinsics;
    camera.set_item("sensor", &rig.sensor)?;
    camera.set_item("model", &rig.model)?;
    for (name, value) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
        camera.set_item(name, value)?;
    }
    camera.set_item("dist", distortion(&rig).to_vec())?;
    camera.set_item("width", rig.width)?;
    camera.set_item("height", rig.height)?;
    Ok((camera, model_dict(py, model)?))
}

/// The rig's distortion coefficients as its model counts them: 5 radial-tangential for the
/// pinhole, 4 for Kannala-Brandt (whose record pads a zero).
fn distortion(rig: &Rig) -> &[f64] {
    let n = if rig.model == Rig::PINHOLE { 5 } else { 4 };
    &rig.distortion[..n]
}
