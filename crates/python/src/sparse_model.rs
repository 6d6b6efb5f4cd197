//! The map as images, keypoints and tracks (`SlamSystem.sparse_model`,
//! `load_sparse_model` for a map file): the arrays `ferroslam.colmap` writes a COLMAP model
//! from.

use std::path::PathBuf;

use ferroslam_geometry::camera::CameraModel;
use ferroslam_map::{Map, Rig, SparseModel};
use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::camera::camera_model_of;
use crate::convert;
use crate::errors::to_py;
use crate::pool;

/// The model as a dict of arrays: `keyframe_ids (K,) uint32`, `timestamps (K,) float64`,
/// `T_w_c (K, 4, 4)`, `keypoint_offsets (K + 1,) int64` (image `k`'s keypoints are rows
/// `offsets[k]:offsets[k + 1]`), `keypoints_px (N, 2) float64` (raw image pixels, as seen
/// from `T_w_c`: rolling-shutter compensated, `ferroslam_map::sparse_model`),
/// `point_index (N,) int64` (row of `points_xyz`, -1 for none), `points_xyz (M, 3)`,
/// `point_colors (M, 3) uint8` (128 grey without colour); `camera_index (K,) uint32` (the
/// rig camera of each image) and `rig_cameras`, a list of camera dicts (as
/// [`load_sparse_model`]'s, with `T_c0_c (4, 4)`) of cameras 1.. of `rig` (empty for one).
pub fn model_dict<'py>(
    py: Python<'py>,
    model: SparseModel,
    rig: Option<&Rig>,
) -> PyResult<Bound<'py, PyDict>> {
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
    d.set_item(
        "camera_index",
        PyArray1::from_vec(py, model.images.iter().map(|i| i.camera as u32).collect()),
    )?;
    let members = PyList::empty(py);
    for m in rig.map_or(&[][..], |r| &r.cameras) {
        let camera = camera_dict(py, &m.model, m.intrinsics, &m.distortion, m.width, m.height)?;
        camera.set_item("T_c0_c", convert::pose_matrix(&m.T_c0_c))?;
        members.append(camera)?;
    }
    d.set_item("rig_cameras", members)?;
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

/// The model of `map` with every camera of its rig record (one image per keyframe and
/// camera), and the record. Row times are the keyframes' own, stored with them: the cameras'
/// readouts are not needed to move keypoints to their reference poses.
///
/// Raises `ValueError` for a map without its record (files before format version 3) or an
/// invalid camera in it.
pub fn rig_sparse_model(map: &Map) -> PyResult<(Rig, SparseModel)> {
    let rig = map.rig().cloned().ok_or_else(|| {
        PyValueError::new_err("the map records no camera (written before format version 3)")
    })?;
    let first = (
        &rig.model,
        rig.intrinsics,
        &rig.distortion,
        rig.width,
        rig.height,
    );
    let members = rig
        .cameras
        .iter()
        .map(|m| (&m.model, m.intrinsics, &m.distortion, m.width, m.height));
    let cameras = std::iter::once(first)
        .chain(members)
        .map(|(model, k, dist, w, h)| camera_model_of(model, k, distortion(model, dist), w, h, 0.0))
        .collect::<PyResult<Vec<CameraModel>>>()?;
    let model = map.rig_sparse_model(&cameras);
    Ok((rig, model))
}

/// `(camera, model)` of the map file at `path`: `camera` a dict (`sensor`, `model`, `fx`,
/// `fy`, `cx`, `cy`, `dist`, `width`, `height`) of the first camera the map was built with,
/// and the model as `SlamSystem.sparse_model` gives it. The map is read without the GIL.
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
        rig_sparse_model(&map)
            .map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))
    })??;
    let camera = camera_dict(
        py,
        &rig.model,
        rig.intrinsics,
        &rig.distortion,
        rig.width,
        rig.height,
    )?;
    camera.set_item("sensor", &rig.sensor)?;
    let model = model_dict(py, model, Some(&rig))?;
    Ok((camera, model))
}

/// A camera's dict (`model`, `fx`, `fy`, `cx`, `cy`, `dist`, `width`, `height`), as
/// `ferroslam.Camera` takes it.
fn camera_dict<'py>(
    py: Python<'py>,
    model: &str,
    [fx, fy, cx, cy]: [f64; 4],
    dist: &[f64; 5],
    width: u32,
    height: u32,
) -> PyResult<Bound<'py, PyDict>> {
    let camera = PyDict::new(py);
    camera.set_item("model", model)?;
    for (name, value) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
        camera.set_item(name, value)?;
    }
    camera.set_item("dist", distortion(model, dist).to_vec())?;
    camera.set_item("width", width)?;
    camera.set_item("height", height)?;
    Ok(camera)
}

/// A record's distortion coefficients as its model counts them: 5 radial-tangential for the
/// pinhole, 4 for Kannala-Brandt (whose record pads a zero).
fn distortion<'a>(model: &str, dist: &'a [f64; 5]) -> &'a [f64] {
    let n = if model == Rig::PINHOLE { 5 } else { 4 };
    &dist[..n]
}
