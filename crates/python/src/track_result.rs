//! The `TrackResult` Python class: what tracking one frame gave back.

use ferroslam_slam::{TrackResult, TrackingState};
use numpy::ndarray::Array2;
use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert;

pub(crate) fn state_name(state: TrackingState) -> &'static str {
    match state {
        TrackingState::NotInitialized => "not_initialized",
        TrackingState::Ok => "ok",
        TrackingState::Lost => "lost",
        TrackingState::RecentlyLost => "recently_lost",
    }
}

/// Result of tracking one frame.
#[pyclass(name = "TrackResult", module = "ferroslam._core", frozen)]
pub struct PyTrackResult {
    pub(crate) inner: TrackResult,
}

#[pymethods]
impl PyTrackResult {
    /// "not_initialized", "ok", "lost" or "recently_lost" (vision failed; the pose is the
    /// IMU's prediction, aligned visual-inertial maps only).
    #[getter]
    fn state(&self) -> &'static str {
        state_name(self.inner.state)
    }

    /// Camera pose in the world, (4, 4) float64, or None when not tracked.
    #[getter]
    fn T_w_c<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.inner.T_w_c.map(|T| {
            let m = convert::pose_matrix(&T);
            PyArray2::from_owned_array(py, Array2::from_shape_fn((4, 4), |(r, c)| m[r][c]))
        })
    }

    /// Wall time of the front end inside `track` (extraction, masks, sampling), milliseconds.
    #[getter]
    fn extraction_ms(&self) -> f64 {
        self.inner.extraction_ms
    }

    /// The first camera's raw keypoints as `track` extracted them, (N, 5) float32
    /// [x, y, octave, angle_deg, response]; empty (0, 5) when the features were given.
    #[getter]
    fn keypoints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        let first = self.inner.keypoints.first().map_or(&[][..], Vec::as_slice);
        convert::keypoint_array(py, first)
    }

    /// Every camera's raw keypoints as `track` extracted them (stereo: left, right), each
    /// (N, 5) float32 as `keypoints`; empty when the features were given.
    #[getter]
    fn camera_keypoints<'py>(&self, py: Python<'py>) -> Vec<Bound<'py, PyArray2<f32>>> {
        self.inner
            .keypoints
            .iter()
            .map(|k| convert::keypoint_array(py, k))
            .collect()
    }

    /// The map T_w_c is in (see SlamSystem.maps()).
    #[getter]
    fn map_id(&self) -> usize {
        self.inner.map_id
    }

    /// The merge this frame made, if any: a dict with the two map ids ("merged_map" into
    /// "into_map"), the keyframes ("current", "matched"), their "timestamps",
    /// "num_matches", the similarity's "scale", the essential graph's "graph_cost" and
    /// "welded_keyframes" (the seam's local BA).
    #[getter]
    fn merge<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner
            .merge
            .as_ref()
            .map(|m| crate::atlas::merge_dict(py, m))
            .transpose()
    }

    /// Whether this frame became a keyframe.
    #[getter]
    fn is_keyframe(&self) -> bool {
        self.inner.is_keyframe
    }

    /// Map points tracked as inliers.
    #[getter]
    fn num_tracked(&self) -> usize {
        self.inner.num_tracked
    }

    /// Tracking wall time, milliseconds.
    #[getter]
    fn tracking_ms(&self) -> f64 {
        self.inner.tracking_ms
    }

    /// Local mapping wall time, milliseconds.
    #[getter]
    fn mapping_ms(&self) -> f64 {
        self.inner.mapping_ms
    }

    /// Of `tracking_ms`, motion-only BA, milliseconds.
    #[getter]
    fn pose_optimisation_ms(&self) -> f64 {
        self.inner.pose_optimisation_ms
    }

    /// Of `mapping_ms`, local BA, milliseconds (inline mapping; 0 without a keyframe).
    #[getter]
    fn local_ba_ms(&self) -> f64 {
        self.inner.mapping.as_ref().map_or(0.0, |m| m.local_ba_ms)
    }

    /// Of `mapping_ms`, loop closing, milliseconds (inline mapping; 0 without a keyframe).
    #[getter]
    fn loop_closing_ms(&self) -> f64 {
        self.inner.loop_closing_ms
    }

    /// Monocular, before the map exists: why this frame did not initialise it; else None.
    #[getter]
    fn init_reason(&self) -> Option<String> {
        self.inner.init_status.as_ref().map(|s| s.to_string())
    }

    /// Whether this frame's keyframe closed a loop (details: `SlamSystem.loops()`).
    #[getter]
    fn loop_closed(&self) -> bool {
        self.inner.loop_closure.is_some()
    }

    fn __repr__(&self) -> String {
        format!(
            "TrackResult(state={:?}, is_keyframe={}, num_tracked={})",
            state_name(self.inner.state),
            self.inner.is_keyframe,
            self.inner.num_tracked
        )
    }
}
