//! `SlamSystem` and `TrackResult` Python classes.

use crate::pool;
use crate::track_result::{state_name, PyTrackResult};
use std::mem::ManuallyDrop;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Mutex, MutexGuard, TryLockError};

use ferroslam_slam::{BackgroundSlam, InputGuard, OwnedFrame, SlamConfig, SlamError, SlamSystem};
use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyInt};

use crate::camera::{self, camera_model_of};
use crate::config;
use crate::convert;
use crate::errors::to_py;
use crate::inertial;
use crate::rig_frame;
use crate::vocabulary::PyVocabulary;
use ferroslam_features::OwnedGrayImage;

/// `(timestamps (N,), T_w_c (N, 4, 4))` of tracked frames, as numpy arrays.
type FrameArrays<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray3<f64>>);

/// `(ids (K,), timestamps (K,), T_w_c (K, 4, 4))` of keyframes, as numpy arrays.
type KeyFrameArrays<'py> = (
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray3<f64>>,
);

/// The SLAM system: tracking, local mapping and loop closing inside each call, or tracking in
/// a background thread and mapping in another (`threaded`), or mapping alone in its own
/// thread (`set_mapping_thread`).
#[pyclass(name = "SlamSystem", module = "ferroslam._core")]
pub struct PySlamSystem {
    /// Behind a mutex so that a second Python thread calling in meanwhile gets a clear
    /// error (the system is not thread-safe) rather than PyO3's "Already borrowed".
    /// `ManuallyDrop`: in a forked child an engine with threads is leaked, never dropped
    /// (see `Drop`).
    engine: Mutex<ManuallyDrop<Engine>>,
    /// The configuration the system was built with.
    config: SlamConfig,
    /// The process that created the system, the only one its threads exist in.
    pid: u32,
}

impl PySlamSystem {
    /// The engine, if no other thread is using it and its threads (if any) exist in this
    /// process.
    fn engine(&self) -> PyResult<MutexGuard<'_, ManuallyDrop<Engine>>> {
        let engine = self.engine.try_lock().map_err(|e| match e {
            TryLockError::WouldBlock => PyRuntimeError::new_err(
                "this SlamSystem is in use by another thread: it is not thread-safe; feed it \
                 from one thread (threaded=True already tracks and maps in threads of its own)",
            ),
            TryLockError::Poisoned(_) => PyRuntimeError::new_err(
                "this SlamSystem failed in an earlier call (internal error); create a new one",
            ),
        })?;
        if engine.has_threads() && std::process::id() != self.pid {
            // Every call would wait for threads that were not copied into the fork.
            return Err(PyRuntimeError::new_err(
                "this SlamSystem was created in another process (this is a fork of it) and \
                 runs threads (threaded, or a mapping thread), which do not exist here; \
                 create a new system in this process",
            ));
        }
        Ok(engine)
    }
}

impl Drop for PySlamSystem {
    /// Joins the threads, except in a forked child: there they do not exist and joining
    /// would wait forever, so the engine is leaked (the child's memory, freed at its exit).
    fn drop(&mut self) {
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        if !(engine.has_threads() && std::process::id() != self.pid) {
            // SAFETY: dropped once, here; the engine is never used after the system.
            unsafe { ManuallyDrop::drop(engine) };
        }
    }
}

#[pymethods]
impl PySlamSystem {
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, dist, width, height, *, sensor = "rgbd", model = "pinhole", rolling_shutter_readout_s = 0.0, threaded = false, right_camera = None, T_left_right = None, cameras = None, **options))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        dist: Vec<f64>,
        width: i64,
        height: i64,
        sensor: &str,
        model: &str,
        rolling_shutter_readout_s: f64,
        threaded: bool,
        right_camera: Option<&Bound<'_, PyAny>>,
        T_left_right: Option<&Bound<'_, PyAny>>,
        cameras: Option<&Bound<'_, PyAny>>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let sensor = config::sensor(sensor)?;
        let size = |name: &str, v: i64| {
            u32::try_from(v).ok().filter(|&v| v > 0).ok_or_else(|| {
                PyValueError::new_err(format!(
                    "invalid camera: {name} = {v}: image size must be positive"
                ))
            })
        };
        let (width, height) = (size("width", width)?, size("height", height)?);
        let left = camera_model_of(
            model,
            [fx, fy, cx, cy],
            &dist,
            width,
            height,
            rolling_shutter_readout_s,
        )?;
        // An unrectified pair: the second camera and where it is, or neither.
        let pair = (
            right_camera.filter(|c| !c.is_none()),
            T_left_right.filter(|t| !t.is_none()),
        );
        let config = config::parse(sensor, fx, width, options, pair.0.is_some())?;
        let system = match pair {
            (None, None) => SlamSystem::new(left, config.clone()),
            (Some(right), Some(pose)) => SlamSystem::with_unrectified_pair(
                left,
                camera::camera_model(right)?,
                inertial::rigid_transform(pose, "T_left_right")?,
                config.clone(),
            ),
            _ => {
                return Err(PyValueError::new_err(
                    "an unrectified stereo pair needs both right_camera and T_left_right",
                ))
            }
        }
        .map_err(to_py)?;
        let mut system = system;
        for (camera, T_c0_c, depth) in camera::further_cameras(cameras)? {
            match depth {
                camera::FurtherDepth::Partner(partner, T_left_right) => {
                    system.add_camera_pair(camera, T_c0_c, partner, T_left_right)
                }
                camera::FurtherDepth::Images => system.add_camera(camera, T_c0_c, true),
                camera::FurtherDepth::None => system.add_camera(camera, T_c0_c, false),
            }
            .map_err(to_py)?;
        }
        let engine = if threaded {
            let guard = system.input_guard();
            Engine::Background {
                slam: BackgroundSlam::spawn(system, true),
                guard,
            }
        } else {
            Engine::Inline {
                system: Box::new(system),
                failure: None,
            }
        };
        Ok(Self {
            engine: Mutex::new(ManuallyDrop::new(engine)),
            config,
            pid: std::process::id(),
        })
    }

    /// Tracks one instant of the camera(s) from images: the door every frame goes through
    /// (queues it in threaded mode and returns None). ORB extraction, masks, depth and colour
    /// sampling and stereo matching run in the core without the GIL.
    ///
    /// images: one uint8 image, grey (H, W) or BGR (H, W, 3), or a sequence of them, one per
    /// camera (stereo: left, right); depth: (H, W) float32/float64 metres registered to the
    /// first image (RGB-D only); colors: the same view(s) in colour for the map points'
    /// colours, when the images are grey; masks: per image a (H, W) uint8/bool mask, 0 = no
    /// keypoint there (combined with `set_mask`'s static mask), or None.
    #[pyo3(signature = (timestamp, images, *, depth = None, colors = None, masks = None))]
    fn track(
        &self,
        py: Python<'_>,
        timestamp: f64,
        images: &Bound<'_, PyAny>,
        depth: Option<&Bound<'_, PyAny>>,
        colors: Option<&Bound<'_, PyAny>>,
        masks: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Option<PyTrackResult>> {
        let arrays = rig_frame::FrameArrays::parse(timestamp, images, depth, colors, masks)?;
        let frame = arrays.frame();
        let mut engine = self.engine()?;
        match &mut **engine {
            Engine::Inline { system, failure } => {
                inline(py, system, failure, |system| system.track(&frame))
                    .map(|inner| Some(PyTrackResult { inner }))
            }
            Engine::Background { slam, guard } => {
                let frame = OwnedFrame::Images(rig_frame::owned(frame));
                frame.check(guard).map_err(to_py)?;
                pool::detach(py, || slam.submit(frame))?.map_err(to_py)?;
                Ok(None)
            }
        }
    }

    /// Sets camera `camera`'s static mask: (H, W) uint8/bool, 0 = no keypoint there, applied
    /// to every frame `track` measures; None removes it.
    #[pyo3(signature = (camera, mask))]
    fn set_mask(
        &self,
        py: Python<'_>,
        camera: usize,
        mask: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let mask = match mask.filter(|m| !m.is_none()) {
            None => None,
            Some(m) => {
                let (w, h, pixels) = rig_frame::mask_pixels(m, "mask")?;
                Some(
                    OwnedGrayImage::new(w, h, pixels)
                        .map_err(|e| PyValueError::new_err(e.to_string()))?,
                )
            }
        };
        self.engine()?
            .run(py, move |system| system.set_mask(camera, mask))?
            .map_err(to_py)
    }

    /// Tracks one RGB-D frame (queues it in threaded mode and returns None).
    ///
    /// keypoints: (N, 5) float32 [x, y, octave, angle_deg, response], raw pixels;
    /// descriptors: (N, 32) uint8; depth_m: (N,) float32 metres (0 = none); colors: None or
    /// (N, 3) uint8 RGB, kept by the map points the keypoints create.
    #[pyo3(signature = (timestamp, keypoints, descriptors, depth_m, *, colors = None))]
    fn track_rgbd(
        &self,
        py: Python<'_>,
        timestamp: f64,
        keypoints: &Bound<'_, PyAny>,
        descriptors: &Bound<'_, PyAny>,
        depth_m: &Bound<'_, PyAny>,
        colors: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Option<PyTrackResult>> {
        let (kps, descs) = convert::features(keypoints, descriptors, "")?;
        let depth_m: PyReadonlyArray1<'_, f32> =
            convert::array(depth_m, "depth_m", "a float32 (N,) array")?;
        if depth_m.len() != kps.len() {
            return Err(PyValueError::new_err(format!(
                "keypoints ({}), descriptors ({}) and depth_m ({}) must have the same length",
                kps.len(),
                descs.len(),
                depth_m.len()
            )));
        }
        let colors = convert::colors(colors, kps.len(), "keypoints")?;
        let frame = OwnedFrame::Rgbd {
            timestamp,
            keypoints: kps,
            descriptors: descs,
            depth_m: convert::floats(&depth_m),
            colors,
        };
        self.engine()?.track(py, frame)
    }

    /// Tracks one rectified stereo pair (queues it in threaded mode and returns None).
    ///
    /// left/right keypoints: (N, 5) float32 [x, y, octave, angle_deg, response] in rectified
    /// pixels; descriptors: (N, 32) uint8; pyramids: lists of 2-D uint8 arrays (level l is the
    /// image scaled by scale_factor^-l, as used for detection), equal sizes left and right;
    /// colors: None or (N, 3) uint8 RGB of the left keypoints.
    #[pyo3(signature = (timestamp, left_keypoints, left_descriptors, left_pyramid, right_keypoints, right_descriptors, right_pyramid, *, colors = None))]
    #[allow(clippy::too_many_arguments)]
    fn track_stereo(
        &self,
        py: Python<'_>,
        timestamp: f64,
        left_keypoints: &Bound<'_, PyAny>,
        left_descriptors: &Bound<'_, PyAny>,
        left_pyramid: &Bound<'_, PyAny>,
        right_keypoints: &Bound<'_, PyAny>,
        right_descriptors: &Bound<'_, PyAny>,
        right_pyramid: &Bound<'_, PyAny>,
        colors: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Option<PyTrackResult>> {
        let (lk, ld) = convert::features(left_keypoints, left_descriptors, "left")?;
        let (rk, rd) = convert::features(right_keypoints, right_descriptors, "right")?;
        let colors = convert::colors(colors, lk.len(), "left_keypoints")?;
        let frame = OwnedFrame::Stereo {
            timestamp,
            left: (lk, ld, convert::pyramid(left_pyramid, "left_pyramid")?),
            right: (rk, rd, convert::pyramid(right_pyramid, "right_pyramid")?),
            colors,
        };
        self.engine()?.track(py, frame)
    }

    /// Tracks one monocular frame (queues it in threaded mode and returns None).
    ///
    /// keypoints: (N, 5) float32 [x, y, octave, angle_deg, response], raw pixels;
    /// descriptors: (N, 32) uint8; colors: None or (N, 3) uint8 RGB.
    #[pyo3(signature = (timestamp, keypoints, descriptors, *, colors = None))]
    fn track_mono(
        &self,
        py: Python<'_>,
        timestamp: f64,
        keypoints: &Bound<'_, PyAny>,
        descriptors: &Bound<'_, PyAny>,
        colors: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Option<PyTrackResult>> {
        let (kps, descs) = convert::features(keypoints, descriptors, "")?;
        let colors = convert::colors(colors, kps.len(), "keypoints")?;
        let frame = OwnedFrame::Mono {
            timestamp,
            keypoints: kps,
            descriptors: descs,
            colors,
        };
        self.engine()?.track(py, frame)
    }

    /// Threaded mode: results of the frames processed since the last call, in order (frames
    /// the core rejected raise here). Synchronous mode: always empty (track_* returns them).
    fn take_results(&self) -> PyResult<Vec<PyTrackResult>> {
        let engine = self.engine()?;
        let Engine::Background { slam, .. } = &**engine else {
            return Ok(Vec::new());
        };
        slam.take_results()
            .into_iter()
            .map(|r| r.map(|inner| PyTrackResult { inner }).map_err(to_py))
            .collect()
    }

    /// Whether every submitted frame has been tracked and mapped (always true when
    /// synchronous).
    fn is_done(&self) -> PyResult<bool> {
        Ok(match &**self.engine()? {
            Engine::Inline { .. } => true,
            Engine::Background { slam, .. } => slam.is_idle(),
        })
    }

    /// Finishes the submitted frames, then stops and joins every thread this system started
    /// (tracking and mapping threads): the system stays usable inline (queries, more
    /// frames), with mapping inline. Idempotent.
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        let mut engine = self.engine()?;
        let closed = match &mut **engine {
            Engine::Inline { system, failure } => {
                return inline(py, system, failure, |s| s.set_concurrent_mapping(false));
            }
            Engine::Background { slam, .. } => pool::detach(py, || slam.stop())?.map_err(to_py)?,
        };
        **engine = Engine::Inline {
            system: Box::new(closed),
            failure: None,
        };
        Ok(())
    }

    /// Blocks (without the GIL) until every submitted frame has been tracked and mapped.
    fn wait(&self, py: Python<'_>) -> PyResult<()> {
        self.engine()?
            .run(py, SlamSystem::finish_mapping)?
            .map_err(to_py)
    }

    /// Runs local mapping and loop closing in a thread of their own (always so when
    /// threaded); off again, the queued keyframes are mapped first.
    fn set_mapping_thread(&self, py: Python<'_>, on: bool) -> PyResult<()> {
        self.engine()?
            .run(py, move |s| s.set_concurrent_mapping(on))?
            .map_err(to_py)
    }

    /// Records (`True`) each local BA problem as local mapping builds it, before solving;
    /// `False` stops and drops the record. Mapping must run inline. (Builds with the `bench`
    /// feature only.)
    #[cfg(feature = "bench")]
    fn record_local_ba_problems(&self, py: Python<'_>, on: bool) -> PyResult<()> {
        self.engine()?
            .run(py, move |s| s.record_local_ba_problems(on))?
            .map_err(to_py)
    }

    /// The local BA problems recorded since the last call, oldest first, each in the text
    /// form `BaProblem::to_text` writes. (Builds with the `bench` feature only.)
    #[cfg(feature = "bench")]
    fn take_local_ba_problems(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        self.engine()?.run(py, |s| {
            s.take_local_ba_problems()
                .iter()
                .map(|p| p.to_text())
                .collect()
        })
    }

    /// Wall time, microseconds, of handing the current map to the mapping thread
    /// (`snapshot_us`) and of the deep copy it used to take (`deep_copy_us`). (Builds with the
    /// `bench` feature only.)
    #[cfg(feature = "bench")]
    fn map_copy_cost(&self, py: Python<'_>) -> PyResult<(f64, f64)> {
        self.engine()?.run(py, |s| {
            let (snapshot, deep) = s.map_copy_cost();
            (snapshot.as_secs_f64() * 1e6, deep.as_secs_f64() * 1e6)
        })
    }

    /// Whether local mapping and loop closing run in a thread of their own.
    #[getter]
    fn mapping_thread(&self, py: Python<'_>) -> PyResult<bool> {
        self.engine()?.run(py, |s| s.concurrent_mapping())
    }

    /// Whether frames are processed in a background thread.
    #[getter]
    fn threaded(&self) -> PyResult<bool> {
        Ok(matches!(**self.engine()?, Engine::Background { .. }))
    }

    /// The sensor this system was created for: "mono", "stereo" or "rgbd".
    #[getter]
    fn sensor(&self) -> &'static str {
        self.config.sensor.name()
    }

    /// (lower, upper) tracked-point limits in use: the option given, else the sensor's default.
    #[getter]
    fn track_feature_range(&self) -> (usize, usize) {
        self.config.tracking.track_feature_range
    }

    /// Every option in use, as a dict of keyword options: those given, the defaults of the
    /// sensor and image width for the rest (see `ferroslam._core.default_options`).
    #[getter]
    fn options<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        config::options_dict(py, &self.config)
    }

    /// Map id of each frame of frame_trajectory(), (N,) uint32: a system lost for
    /// `relocalisation_window_s` starts a new map (own world and, monocular, scale).
    fn frame_map_ids<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let ids: Vec<u32> = self.engine()?.run(py, |s| {
            s.frame_map_ids().into_iter().map(|s| s as u32).collect()
        })?;
        Ok(PyArray1::from_vec(py, ids))
    }

    /// Every map of the run with keyframes (save_map's order): dicts "id", "frames", "keyframes",
    /// "points", "current" (the one tracked in), the atlas's oldest first.
    fn maps<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let maps = self.engine()?.run(py, |s| s.maps())?;
        crate::atlas::map_dicts(py, &maps)
    }

    /// Id of the map tracking runs in.
    #[getter]
    fn current_map_id(&self, py: Python<'_>) -> PyResult<usize> {
        self.engine()?.run(py, |s| s.current_map_id())
    }

    /// Maps merged so far, oldest first (see `TrackResult.merge` for the keys).
    fn merges<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let merges = self.engine()?.run(py, |s| s.merges().to_vec())?;
        merges
            .iter()
            .map(|m| crate::atlas::merge_dict(py, m))
            .collect()
    }

    /// Loops closed so far, oldest first: dicts with the two keyframe ids ("current",
    /// "matched"), their "timestamps", "num_matches", Sim(3) "scale", "correction_m" (how far
    /// the current keyframe moved) and the essential graph's "graph_cost" (before, after).
    fn loops<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let loops = self.engine()?.run(py, |s| s.loops().to_vec())?;
        loops
            .iter()
            .map(|l| crate::atlas::loop_dict(py, l))
            .collect()
    }

    /// Loop-detection counters: "keyframes_checked", "with_candidates" (bag-of-words
    /// candidates found), "verified" (consistent candidates checked geometrically),
    /// "rejected" (refused by the Sim(3) or the match count).
    fn loop_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let st = self.engine()?.run(py, |s| s.loop_stats())?;
        let d = PyDict::new(py);
        d.set_item("keyframes_checked", st.keyframes_checked)?;
        d.set_item("with_candidates", st.with_candidates)?;
        d.set_item("verified", st.verified)?;
        d.set_item("rejected", st.rejected)?;
        Ok(d)
    }

    /// (timestamps (N,), T_w_c (N, 4, 4)) of every tracked frame, with map corrections.
    fn frame_trajectory<'py>(&self, py: Python<'py>) -> PyResult<FrameArrays<'py>> {
        let traj = self.engine()?.run(py, |s| s.frame_trajectory())?;
        let stamps = traj.iter().map(|(t, _)| *t).collect();
        let poses: Vec<_> = traj.into_iter().map(|(_, T)| T).collect();
        Ok((
            convert::f64_array(py, stamps),
            convert::pose_stack(py, &poses),
        ))
    }

    /// (ids (K,) uint32, timestamps (K,), T_w_c (K, 4, 4)) of the live keyframes of map
    /// `map_id` (default: the current map).
    #[pyo3(signature = (map_id=None))]
    fn keyframe_trajectory<'py>(
        &self,
        py: Python<'py>,
        map_id: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<KeyFrameArrays<'py>> {
        let map_id = map_id_arg(map_id)?;
        let kfs = self.engine()?.run(py, move |s| {
            s.keyframe_trajectory_of(map_id.unwrap_or(s.current_map_id()))
        })?;
        let kfs = kfs.map_err(to_py)?;
        let ids: Vec<u32> = kfs.iter().map(|(id, _, _)| id.0).collect();
        let stamps = kfs.iter().map(|(_, t, _)| *t).collect();
        let poses: Vec<_> = kfs.into_iter().map(|(_, _, T)| T).collect();
        Ok((
            PyArray1::from_vec(py, ids),
            convert::f64_array(py, stamps),
            convert::pose_stack(py, &poses),
        ))
    }

    /// World positions of the map points of map `map_id` (default: the current map),
    /// (M, 3) float64 metres.
    #[pyo3(signature = (map_id=None))]
    fn map_points<'py>(
        &self,
        py: Python<'py>,
        map_id: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let map_id = map_id_arg(map_id)?;
        let pts = self
            .engine()?
            .run(py, move |s| {
                s.map_points_of(map_id.unwrap_or(s.current_map_id()))
            })?
            .map_err(to_py)?;
        Ok(PyArray2::from_owned_array(
            py,
            Array2::from_shape_fn((pts.len(), 3), |(i, c)| pts[i][c]),
        ))
    }

    /// Colours of the map points of map `map_id` (default: the current map), (M, 3) uint8
    /// RGB in the order of map_points(map_id): the colour of the keypoint that created each;
    /// grey 128 for points made without colours.
    #[pyo3(signature = (map_id=None))]
    fn map_point_colors<'py>(
        &self,
        py: Python<'py>,
        map_id: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let map_id = map_id_arg(map_id)?;
        let colors = self
            .engine()?
            .run(py, move |s| {
                s.map_point_colors_of(map_id.unwrap_or(s.current_map_id()))
            })?
            .map_err(to_py)?;
        Ok(convert::colors_array(py, &colors))
    }

    /// Map `map_id` (default: the current map) as images and tracks, in one dict of arrays
    /// (see `ferroslam._core.pyi`): every keyframe's pose and keypoints (raw image pixels) in
    /// each camera of the rig with the map point each observes (row of `points_xyz`, -1 for
    /// none), and the points.
    #[pyo3(signature = (map_id=None))]
    fn sparse_model<'py>(
        &self,
        py: Python<'py>,
        map_id: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let map_id = map_id_arg(map_id)?;
        let (rig, model) = self.engine()?.run(py, move |s| {
            let map = s
                .map_by_id(map_id.unwrap_or(s.current_map_id()))
                .map_err(to_py)?;
            crate::sparse_model::rig_sparse_model(map)
        })??;
        crate::sparse_model::model_dict(py, model, Some(&rig))
    }

    /// Writes the map to `path` (versioned binary file with a checksum).
    fn save_map(&self, py: Python<'_>, path: std::path::PathBuf) -> PyResult<()> {
        self.engine()?
            .run(py, move |s| s.save_map(&path))?
            .map_err(to_py)
    }

    /// Makes the last map saved at `path` the current one (the others of the file, and the
    /// map tracked until now, go to the atlas); the next frames relocalise in it.
    fn load_map(&self, py: Python<'_>, path: std::path::PathBuf) -> PyResult<()> {
        self.engine()?
            .run(py, move |s| s.load_map(&path))?
            .map_err(to_py)
    }

    /// Adds every map saved at `path` to the atlas (the current map stays); their new ids.
    fn add_maps(&self, py: Python<'_>, path: std::path::PathBuf) -> PyResult<Vec<usize>> {
        self.engine()?
            .run(py, move |s| s.add_maps(&path))?
            .map_err(to_py)
    }

    /// Merges the maps of the atlas where they overlap (offline); the merges made.
    fn merge_maps<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let merges = self.engine()?.run(py, |s| s.merge_maps())?.map_err(to_py)?;
        merges
            .iter()
            .map(|m| crate::atlas::merge_dict(py, m))
            .collect()
    }

    /// Sets the ORB vocabulary: keyframes are indexed by bag of words and lost frames are
    /// relocalised against the keyframes they resemble.
    fn set_vocabulary(&self, py: Python<'_>, vocabulary: PyRef<'_, PyVocabulary>) -> PyResult<()> {
        let shared = vocabulary.shared();
        self.engine()?.run(py, move |s| s.set_vocabulary(shared))
    }

    /// Localisation-only mode: track against the map without adding keyframes.
    #[getter]
    fn get_localization_only(&self, py: Python<'_>) -> PyResult<bool> {
        self.engine()?.run(py, |s| s.localization_only())
    }

    #[setter]
    fn set_localization_only(&self, py: Python<'_>, on: bool) -> PyResult<()> {
        self.engine()?
            .run(py, move |s| s.set_localization_only(on))?
            .map_err(to_py)
    }

    /// Clears the map; tracking restarts with the next frame.
    fn reset(&self, py: Python<'_>) -> PyResult<()> {
        self.engine()?.run(py, |s| s.reset())
    }

    /// "not_initialized", "ok", "lost" or "recently_lost" (vision failed; the pose is the
    /// IMU's prediction, aligned visual-inertial maps only).
    #[getter]
    fn state(&self, py: Python<'_>) -> PyResult<&'static str> {
        self.engine()?.run(py, |s| state_name(s.state()))
    }

    /// Live keyframes in the map.
    #[getter]
    fn num_keyframes(&self, py: Python<'_>) -> PyResult<usize> {
        self.engine()?.run(py, |s| s.map().num_keyframes())
    }

    /// Live map points.
    #[getter]
    fn num_map_points(&self, py: Python<'_>) -> PyResult<usize> {
        self.engine()?.run(py, |s| s.map().num_map_points())
    }

    /// Map resets so far (tracking lost right after initialisation).
    #[getter]
    fn num_resets(&self, py: Python<'_>) -> PyResult<usize> {
        self.engine()?.run(py, |s| s.resets())
    }

    /// Sets the IMU: noise model `params` (an ImuParams or a dict), `T_b_c` (4, 4) camera
    /// pose in the body frame, the alignment knobs (MATLAB NumPosesThreshold,
    /// AlignmentFraction) and the IMU clock's offset (`t_imu = t_cam + imu_time_offset_s`).
    /// Options left out (None) take the core's defaults (`InertialConfig::new`).
    #[pyo3(signature = (params, T_b_c, *, num_poses_threshold = None, alignment_fraction = None, gravity_magnitude = None, imu_time_offset_s = None))]
    #[allow(clippy::too_many_arguments)]
    fn set_imu(
        &self,
        py: Python<'_>,
        params: &Bound<'_, PyAny>,
        T_b_c: &Bound<'_, PyAny>,
        num_poses_threshold: Option<usize>,
        alignment_fraction: Option<f64>,
        gravity_magnitude: Option<f64>,
        imu_time_offset_s: Option<f64>,
    ) -> PyResult<()> {
        let config = inertial::inertial_config(
            params,
            T_b_c,
            num_poses_threshold,
            alignment_fraction,
            gravity_magnitude,
            imu_time_offset_s,
        )?;
        self.engine()?
            .run(py, move |s| s.set_imu(config))?
            .map_err(to_py)
    }

    /// Adds IMU samples: timestamps (M,) s, gyro (M, 3) rad/s, accel (M, 3) m/s^2, float64,
    /// body frame; feed each frame's samples before tracking it.
    fn add_imu(
        &self,
        py: Python<'_>,
        timestamps: &Bound<'_, PyAny>,
        gyro: &Bound<'_, PyAny>,
        accel: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let samples = inertial::samples(timestamps, gyro, accel)?;
        self.engine()?
            .run(py, move |s| s.add_imu(&samples))?
            .map_err(to_py)
    }

    /// The camera-IMU alignment of the current map as a dict, or None without an IMU.
    fn inertial_alignment<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let status = self
            .engine()?
            .run(py, |s| s.inertial_alignment().cloned())?;
        status.map(|s| inertial::status_dict(py, &s)).transpose()
    }

    /// The newest keyframe's IMU state once aligned, else None: ``{"keyframe_id",
    /// "timestamp", "velocity" (3,) m/s body velocity in the world, "gyro_bias" (3,) rad/s,
    /// "accel_bias" (3,) m/s^2}``.
    fn keyframe_imu_state<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let state = self.engine()?.run(py, |s| s.keyframe_imu_state())?;
        state
            .map(|(id, t, v, bias)| inertial::imu_state_dict(py, id.0, t, &v, &bias))
            .transpose()
    }
}

/// Where frames are processed: in the calling thread, or in a background thread fed through
/// a bounded queue (input checked here first, so bad frames raise at once).
enum Engine {
    /// Each call runs on the caller's thread; after a panic (a bug) the system may be
    /// inconsistent, so `failure` refuses every later call.
    Inline {
        system: Box<SlamSystem>,
        failure: Option<SlamError>,
    },
    /// Tracking and mapping in threads of their own.
    Background {
        slam: BackgroundSlam,
        guard: InputGuard,
    },
}

impl Engine {
    /// Whether the engine runs threads: threaded, or inline with a mapping thread.
    fn has_threads(&self) -> bool {
        match self {
            Engine::Inline { system, .. } => system.concurrent_mapping(),
            Engine::Background { .. } => true,
        }
    }

    /// Runs `job` on the system (after the frames queued before it), without the GIL.
    fn run<R: Send + 'static>(
        &mut self,
        py: Python<'_>,
        job: impl FnOnce(&mut SlamSystem) -> R + Send + 'static,
    ) -> PyResult<R> {
        match self {
            Engine::Inline { system, failure } => {
                inline(py, system, failure, |system| Ok(job(system)))
            }
            Engine::Background { slam, .. } => pool::detach(py, || slam.run(job))?.map_err(to_py),
        }
    }

    /// Tracks `frame` now (synchronous: its result) or queues it (threaded: None).
    fn track(&mut self, py: Python<'_>, frame: OwnedFrame) -> PyResult<Option<PyTrackResult>> {
        match self {
            Engine::Inline { system, failure } => {
                inline(py, system, failure, |system| frame.track(system))
                    .map(|inner| Some(PyTrackResult { inner }))
            }
            Engine::Background { slam, guard } => {
                frame.check(guard).map_err(to_py)?;
                pool::detach(py, || slam.submit(frame))?.map_err(to_py)?;
                Ok(None)
            }
        }
    }
}

/// `job` on an inline system without the GIL; a panic becomes [`SlamError::StageFailed`]
/// (never a `PanicException`) and is kept in `failure`, which refuses every later call.
fn inline<R>(
    py: Python<'_>,
    system: &mut SlamSystem,
    failure: &mut Option<SlamError>,
    job: impl FnOnce(&mut SlamSystem) -> Result<R, SlamError> + Send,
) -> PyResult<R>
where
    R: Send,
{
    if let Some(error) = failure {
        return Err(to_py(error.clone()));
    }
    let outcome = pool::detach(py, || catch_unwind(AssertUnwindSafe(|| job(system))))?;
    outcome
        .unwrap_or_else(|panic| {
            let error = SlamError::from_panic("tracking", &*panic);
            *failure = Some(error.clone());
            Err(error)
        })
        .map_err(to_py)
}

/// A `map_id` argument: `None` or an int that can be a map id (the core says which exist).
fn map_id_arg(map_id: Option<&Bound<'_, PyAny>>) -> PyResult<Option<usize>> {
    let Some(obj) = map_id.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    if obj.is_instance_of::<PyBool>() || !obj.is_instance_of::<PyInt>() {
        return Err(PyTypeError::new_err(format!(
            "map_id must be an int or None, got {}",
            obj.get_type().name()?
        )));
    }
    obj.extract::<usize>().map(Some).map_err(|_| {
        PyValueError::new_err(format!("map_id must be a map id (0 or more), got {obj}"))
    })
}
