//! `SlamSystem`: the synchronous pipeline, one call per frame.

use std::time::Instant;

use ferroslam_features::ScalePyramid;
use ferroslam_geometry::camera::CameraModel;
use ferroslam_map::{KeyFrameId, Map, MapPointId};
#[cfg(feature = "bench")]
use ferroslam_optim::BaProblem;
use nalgebra::{Isometry3, Vector3};

use crate::atlas::StoredMap;
use crate::config::{Sensor, SlamConfig};
use crate::context::Context;
use crate::error::SlamError;
use crate::frame::Frame;
use crate::front_end::FrontEnd;
use crate::imu_prediction::ImuPredictor;
use crate::inertial::Inertial;
use crate::input_guard::InputGuard;
use crate::keyframe_insertion::insert_keyframe;
use crate::local_mapping::MappingReport;
use crate::loop_closing::MapMerge;
use crate::loop_closing::{LoopClosure, LoopStats};
use crate::mapping::{KeyFrameWork, Mapped, Mapping, MappingRequest};
use crate::mono_init::{create_initial_map, InitStatus, InitialMap, MonoInitializer};
use crate::place_recognition::PlaceRecognition;
use crate::stereo_pair::UnrectifiedPair;
pub use crate::track_result::TrackResult;
use crate::tracking::{Tracker, TrackingState};
use crate::trajectory::Trajectory;

mod door;
mod gap;
mod imu;
mod map_files;
mod maps;
use ferroslam_vocabulary::Vocabulary;
pub use map_files::load_map_file;
use std::sync::Arc;

/// The SLAM system: tracking and local mapping run inline, in call order (deterministic).
///
/// A system that stays lost for `tracking.relocalisation_window_s` of its configuration
/// ([`SlamConfig`]) keeps the current map in its atlas (with the frames tracked in it) and
/// starts a new map from the following frames; see [`Self::maps`] and the `maps` module.
pub struct SlamSystem {
    ctx: Context,
    map: Map,
    tracker: Tracker,
    /// Local mapping, the keyframe index and loop closing, inline or in their thread.
    mapping: Mapping,
    /// Points tracking created since the last keyframe handed to mapping, oldest first.
    new_points: Vec<MapPointId>,
    initializer: MonoInitializer,
    trajectory: Trajectory,
    /// The maps kept besides the current one, oldest first (see `crate::atlas`).
    atlas: Vec<StoredMap>,
    /// Id of the current map, and the id the next map gets.
    map_id: usize,
    next_map_id: usize,
    /// Maps merged so far.
    merges: Vec<MapMerge>,
    /// Keyframes mapped since the last frame, to look for a merge with.
    merge_checks: Vec<KeyFrameId>,
    lost_since: Option<f64>,
    /// Frames without a pose since the last frame with one (see `gap`).
    untracked: Vec<Frame>,
    /// The frames posed in the current map while it is young (see `gap`).
    young_frames: Vec<Frame>,
    /// Track against the map without changing it (no keyframes, no mapping).
    localization_only: bool,
    /// Bag-of-words index of the keyframes for relocalisation, once a vocabulary is set
    /// (the mapping pipeline keeps its own for loop detection and hands its entries over).
    place: Option<PlaceRecognition>,
    /// Loops closed so far (kept across map resets) and the detection counters.
    loops: Vec<LoopClosure>,
    loop_stats: LoopStats,
    frames_seen: usize,
    guard: InputGuard,
    /// ORB extraction, masks and sampling of [`Self::track`]'s images.
    front_end: FrontEnd,
    resets: usize,
    /// IMU samples, keyframe preintegrations and the camera-IMU alignment, once set.
    inertial: Option<Inertial>,
    /// IMU-only poses for frames vision cannot localise (aligned maps).
    predictor: ImuPredictor,
}

impl SlamSystem {
    /// Creates a system for `camera` (the calibration of the raw keypoints) and `config`.
    ///
    /// # Errors
    /// `InvalidConfig` for a configuration that fails validation, a pyramid the image cannot
    /// hold, and a stereo sensor with a camera other than the pinhole (stereo matching runs
    /// along the rows of rectified images).
    pub fn new(camera: impl Into<CameraModel>, config: SlamConfig) -> Result<Self, SlamError> {
        Self::build(camera.into(), None, config)
    }

    /// Creates a stereo system on an UNRECTIFIED pair: `left` is tracked (poses are its
    /// `T_w_c`), `right` is the second camera with its own model and distortion, at
    /// `T_left_right` (`p_left = T_left_right p_right`, metres). Each frame's left keypoints
    /// get depth by matching into the right image along epipolar curves
    /// ([`UnrectifiedPair::depths`]); the virtual right camera of that depth has the pair's
    /// baseline (`config.depth.bf` is set to `fx * baseline`).
    ///
    /// # Errors
    /// `InvalidConfig` as [`Self::new`], for a sensor other than stereo, cameras of
    /// different image sizes or a zero baseline.
    #[allow(non_snake_case)]
    pub fn with_unrectified_pair(
        left: impl Into<CameraModel>,
        right: impl Into<CameraModel>,
        T_left_right: Isometry3<f64>,
        mut config: SlamConfig,
    ) -> Result<Self, SlamError> {
        let left = left.into();
        if config.sensor != Sensor::Stereo {
            return Err(SlamError::InvalidConfig(format!(
                "a stereo pair is for a stereo system, not a {} one",
                config.sensor.name()
            )));
        }
        let pair = UnrectifiedPair::new(&left, right.into(), T_left_right)?;
        config.depth.bf = left.fx() * pair.baseline_m();
        Self::build(left, Some(pair), config)
    }

    fn build(
        camera: CameraModel,
        pair: Option<UnrectifiedPair>,
        config: SlamConfig,
    ) -> Result<Self, SlamError> {
        config.validate()?;
        let (width, height) = camera.size();
        config.extractor.check_pyramid(width, height)?;
        if !config.depth.match_pair_every_frame && pair.is_none() {
            return Err(SlamError::InvalidConfig(
                "match_pair_every_frame=false is for an unrectified pair (right_camera and \
                 T_left_right): rectified stereo is matched at every frame"
                    .into(),
            ));
        }
        if config.sensor == Sensor::Stereo && pair.is_none() && camera.as_pinhole().is_none() {
            return Err(SlamError::InvalidConfig(
                "stereo needs rectified pinhole images (matching runs along image rows), but \
                 the camera is a fisheye: pass the pair unrectified with its second camera and \
                 T_left_right, or rectify it first (StereoVSlam.from_raw)"
                    .into(),
            ));
        }
        let mut ctx = Context::new(camera, config);
        ctx.pair = pair;
        let guard = InputGuard::new(ctx.config.sensor, ctx.input_shape(), ctx.is_distorted())
            .with_observers(ctx.observer_shapes());
        let extractor = &ctx.config.extractor;
        let pyramid = ScalePyramid::new(extractor.scale_factor, extractor.n_levels)
            .map_err(|e| SlamError::InvalidConfig(e.to_string()))?;
        let mut map = Map::new(pyramid);
        map.set_rig(ctx.rig());
        let orb = ferroslam_features::OrbExtractor::new(extractor.orb())
            .map_err(|e| SlamError::InvalidConfig(e.to_string()))?;
        Ok(Self {
            front_end: FrontEnd::new(orb),
            ctx,
            map,
            tracker: Tracker::default(),
            mapping: Mapping::default(),
            new_points: Vec::new(),
            initializer: MonoInitializer::default(),
            trajectory: Trajectory::default(),
            atlas: Vec::new(),
            map_id: 0,
            next_map_id: 1,
            merges: Vec::new(),
            merge_checks: Vec::new(),
            lost_since: None,
            untracked: Vec::new(),
            young_frames: Vec::new(),
            localization_only: false,
            place: None,
            loops: Vec::new(),
            loop_stats: LoopStats::default(),
            frames_seen: 0,
            guard,
            resets: 0,
            inertial: None,
            predictor: ImuPredictor::default(),
        })
    }

    /// A fresh guard with this system's input rules (for a background submitter).
    pub fn input_guard(&self) -> InputGuard {
        let c = &self.ctx;
        InputGuard::new(c.config.sensor, c.input_shape(), c.is_distorted())
            .with_observers(c.observer_shapes())
    }

    /// Initialises or tracks a frame, then inserts a keyframe when needed.
    fn track_frame(&mut self, mut frame: Frame, start: Instant) -> Result<TrackResult, SlamError> {
        self.frames_seen += 1;
        self.mapping.frame_started();
        // See `MappingConfig::monocular_wait_inliers` (0 with depth).
        let weak = self.tracker.state == TrackingState::Ok
            && self.tracker.matches_inliers < self.ctx.config.mapping.monocular_wait_inliers;
        self.collect_mapping(weak)?;
        let lost_before = self.tracker.state == TrackingState::Lost;
        // A new map's first frames may show a stored map: tracking resumes there.
        let resumed = self.tracker.state == TrackingState::NotInitialized
            && self.relocalise_in_atlas(&mut frame)?;
        if self.tracker.state == TrackingState::NotInitialized {
            let kept = self.keeps_untracked().then(|| frame.clone());
            let (T_w_c, init_status) = if self.ctx.config.sensor.has_depth() {
                frame.match_pair(self.map.pyramid(), &self.ctx);
                (self.initialise(frame)?, None)
            } else {
                match self.initialise_monocular(frame)? {
                    Ok(T_w_c) => (Some(T_w_c), None),
                    Err(status) => (None, Some(status)),
                }
            };
            match (T_w_c, kept) {
                (None, Some(kept)) => self.keep_untracked(kept),
                (Some(_), kept) => {
                    if let Some(kept) = kept {
                        self.keep_young(&kept);
                    }
                    self.fill_gap()?;
                }
                (None, None) => {}
            }
            return Ok(TrackResult {
                state: self.tracker.state,
                T_w_c,
                map_id: self.map_id,
                merge: None,
                is_keyframe: T_w_c.is_some(),
                num_tracked: if T_w_c.is_some() {
                    self.tracker.matches_inliers
                } else {
                    0
                },
                tracking_ms: start.elapsed().as_secs_f64() * 1e3,
                mapping_ms: 0.0,
                pose_optimisation_ms: 0.0,
                loop_closing_ms: 0.0,
                mapping: None,
                init_status,
                loop_closure: None,
                keypoints: Vec::new(),
                extraction_ms: 0.0,
            });
        }
        let mut tracked = resumed
            || self
                .tracker
                .track(&mut frame, &mut self.map, &self.ctx, self.place.as_ref())?;
        // Lost in the current map since the last frame too: perhaps it is in a stored one.
        if !tracked && lost_before {
            tracked = self.relocalise_in_atlas(&mut frame)?;
        }
        let predicted = match (tracked, self.inertial.as_ref()) {
            (false, Some(inertial)) => self.predictor.predict(frame.timestamp, inertial),
            _ => None,
        };
        if let (Some(prediction), Some(inertial)) = (&predicted, self.inertial.as_ref()) {
            tracked = self.tracker.track_from_prediction(
                &mut frame,
                &mut self.map,
                &self.ctx,
                prediction,
                &inertial.config().T_b_c,
            )?;
        }
        if let (true, Some(inertial)) = (tracked, self.inertial.as_ref()) {
            self.predictor
                .record(frame.timestamp, &frame.T_c_w.inverse(), inertial);
        }
        let tracking_ms = start.elapsed().as_secs_f64() * 1e3;
        let mut result = TrackResult {
            state: self.tracker.state,
            T_w_c: tracked.then(|| frame.T_c_w.inverse()),
            map_id: self.map_id,
            merge: None,
            is_keyframe: false,
            num_tracked: if tracked {
                self.tracker.matches_inliers
            } else {
                0
            },
            tracking_ms,
            mapping_ms: 0.0,
            pose_optimisation_ms: self.tracker.take_pose_optimisation_ms(),
            loop_closing_ms: 0.0,
            mapping: None,
            init_status: None,
            loop_closure: None,
            keypoints: Vec::new(),
            extraction_ms: 0.0,
        };
        if !tracked && predicted.is_some() {
            // Carried by the IMU: the frame has its pose, nothing else changes.
            result.T_w_c = Some(frame.T_c_w.inverse());
            self.record_frame(&frame);
            return Ok(result);
        }
        if !tracked {
            self.handle_lost(frame.timestamp);
            if self.keeps_untracked() {
                self.keep_untracked(frame);
            }
            return Ok(result);
        }
        self.lost_since = None;
        let start = Instant::now();
        let mut new_keyframe = !self.localization_only
            && self.tracker.state == TrackingState::Ok
            && (self
                .tracker
                .need_new_keyframe(&frame, &self.map, &self.ctx, self.mapping_idle())
                || self.inertial_keyframe_due(frame.timestamp));
        // Tracking may run ahead of mapping by at most this many keyframes: beyond, the
        // frames would be tracked against a map missing the points of several keyframes
        // (fatal for monocular maps, which only grow by triangulation), so it waits, or
        // leaves the keyframe to the next frame (see `Tracker::defer_keyframe`).
        if new_keyframe && self.mapping.backlog() >= self.ctx.config.mapping.max_queued_keyframes {
            self.mapping.interrupt();
            if self.tracker.defer_keyframe(frame.index, &self.ctx) {
                new_keyframe = false;
            } else {
                self.finish_mapping()?;
            }
        }
        if new_keyframe {
            frame.match_pair(self.map.pyramid(), &self.ctx);
            let (kf, created) =
                insert_keyframe(&mut frame, &mut self.map, &self.ctx, self.ctx.close_depth_m)?;
            self.tracker.on_keyframe(frame.index, kf);
            result.is_keyframe = true;
            self.record_frame(&frame);
            let mut report = MappingReport {
                depth_points: created.len(),
                ..MappingReport::default()
            };
            self.new_points.extend(created);
            self.resume_inertial(kf);
            let work = KeyFrameWork {
                kf,
                new_points: std::mem::take(&mut self.new_points),
                inertial: self.inertial.as_mut().and_then(|i| i.window(&self.map)),
            };
            let vocabulary = self.place.as_ref().map(|p| Arc::clone(p.vocabulary()));
            let mapped = self.mapping.submit(
                MappingRequest::KeyFrame(work),
                &mut self.map,
                &self.ctx,
                vocabulary.as_ref(),
            );
            if let Some(mapped) = mapped {
                // Inline: this frame's keyframe was mapped within the call.
                if let Some((_, done)) = mapped.reports.first() {
                    report = MappingReport {
                        depth_points: report.depth_points,
                        ..done.clone()
                    };
                }
                result.loop_closure = mapped.loops.last().cloned();
                result.loop_closing_ms = mapped.loop_closing_ms;
                self.absorb(vec![mapped])?;
            }
            result.mapping = Some(report);
            self.update_inertial()?;
        }
        result.mapping_ms = start.elapsed().as_secs_f64() * 1e3;
        if !new_keyframe {
            self.record_frame(&frame);
        }
        self.keep_young(&frame);
        self.tracker
            .set_last_frame(frame, &self.map, &self.ctx, new_keyframe);
        self.fill_gap()?;
        let merges = self.merges.len();
        self.check_merges()?;
        result.merge = self.merges.get(merges).cloned();
        Ok(result)
    }

    /// Adds a tracked frame to the trajectory, anchored to its reference keyframe as the map
    /// was when the frame was tracked: a keyframe's frame is recorded before local mapping
    /// and loop closing move the keyframe, so that it moves with it (recorded after, it kept
    /// its uncorrected pose: an outlier at each loop).
    fn record_frame(&mut self, frame: &Frame) {
        if let Some(r) = self.tracker.reference_kf {
            self.trajectory
                .push(frame.timestamp, &frame.T_c_w, r, &self.map);
        }
    }

    /// Records (`true`) each local BA problem as local mapping builds it, before solving, for
    /// running other solvers on the same problems (`benches/solvers_compare.py`); `false`
    /// stops and drops the record. Mapping must run inline.
    ///
    /// # Errors
    /// [`SlamError::InvalidConfig`] while the mapping thread runs.
    #[cfg(feature = "bench")]
    pub fn record_local_ba_problems(&mut self, on: bool) -> Result<(), SlamError> {
        match self.mapping.inline_pipeline() {
            Some(pipeline) => {
                pipeline.record_local_ba_problems(on);
                Ok(())
            }
            None if !on => Ok(()),
            None => Err(SlamError::InvalidConfig(
                "local BA problems are recorded with mapping inline only: stop the mapping \
                 thread first"
                    .to_owned(),
            )),
        }
    }

    /// The local BA problems recorded since the last call (see
    /// [`Self::record_local_ba_problems`]), oldest first.
    #[cfg(feature = "bench")]
    pub fn take_local_ba_problems(&mut self) -> Vec<BaProblem> {
        self.mapping
            .inline_pipeline()
            .map(|p| p.take_local_ba_problems())
            .unwrap_or_default()
    }

    /// What handing the map to the mapping thread costs now, and what it cost when the copy
    /// was deep: `(snapshot, deep copy)` wall times of copying the current map, for
    /// `benches/long_run.py`. The deep copy clones every keyframe and point, as copying the
    /// map's tables did before they shared their entries (see `ferroslam_map::Map`).
    #[cfg(feature = "bench")]
    pub fn map_copy_cost(&self) -> (std::time::Duration, std::time::Duration) {
        let start = Instant::now();
        let snapshot = std::hint::black_box(self.map.clone());
        let snapshot_time = start.elapsed();
        drop(snapshot);
        let start = Instant::now();
        let keyframes: Vec<_> = self.map.keyframes().cloned().collect();
        let points: Vec<_> = self.map.map_points().cloned().collect();
        std::hint::black_box((&keyframes, &points));
        (snapshot_time, start.elapsed())
    }

    /// Runs local mapping and loop closing in a thread of their own (`true`) or inline in
    /// each call (`false`, the default: deterministic). Concurrent mapping works on copies of
    /// the map and its edits are replayed here before each frame (see the `mapping` module);
    /// switching it off first finishes the work queued.
    ///
    /// # Errors
    /// An error local mapping met in the thread.
    pub fn set_concurrent_mapping(&mut self, on: bool) -> Result<(), SlamError> {
        if on == self.mapping.is_threaded() {
            return Ok(());
        }
        if on
            && self
                .mapping
                .inline_pipeline()
                .is_some_and(|p| p.is_recording())
        {
            return Err(SlamError::InvalidConfig(
                "local BA problems are recorded with mapping inline only: stop recording \
                 before starting the mapping thread"
                    .to_owned(),
            ));
        }
        let finished = if on { Ok(()) } else { self.finish_mapping() };
        self.mapping.set_threaded(on, &self.ctx);
        finished
    }

    /// Whether local mapping runs in its own thread.
    pub fn concurrent_mapping(&self) -> bool {
        self.mapping.is_threaded()
    }

    /// Keyframes the mapping thread has queued or is processing (0 inline), shared so
    /// another thread can poll it.
    pub fn mapping_backlog(&self) -> Option<Arc<std::sync::atomic::AtomicUsize>> {
        self.mapping.backlog_handle()
    }

    /// Whether local mapping can take a keyframe now: always inline (it ran inside the last
    /// keyframe's call), with the mapping thread when it has nothing queued or in progress.
    fn mapping_idle(&self) -> bool {
        self.mapping.backlog() == 0
    }

    /// Waits for the mapping thread to process every queued keyframe and applies its edits
    /// to the map (no-op inline).
    ///
    /// # Errors
    /// An error local mapping met in the thread.
    pub fn finish_mapping(&mut self) -> Result<(), SlamError> {
        self.collect_mapping(true)
    }

    /// Applies what the mapping thread finished (waiting for all of it if `wait`).
    fn collect_mapping(&mut self, wait: bool) -> Result<(), SlamError> {
        let vocabulary = self.place.as_ref().map(|p| Arc::clone(p.vocabulary()));
        let finished = self
            .mapping
            .collect(&mut self.map, vocabulary.as_ref(), wait)?;
        self.absorb(finished)
    }

    /// Takes in what the mapping pipeline did (inline or in its thread, whose edits are in
    /// the map by now): inertial states, the keyframes it indexed, loops; returns the first
    /// error it met.
    fn absorb(&mut self, finished: Vec<Mapped>) -> Result<(), SlamError> {
        if finished.is_empty() {
            return Ok(());
        }
        let mut error = None;
        for mapped in finished {
            self.merge_checks
                .extend(mapped.reports.iter().map(|(kf, _)| *kf));
            if let Some(inertial) = self.inertial.as_mut() {
                mapped.inertial.iter().for_each(|w| inertial.store(w));
            }
            if let Some(place) = self.place.as_mut() {
                // Keyframes culled since (by a later job) leave again below.
                for (kf, entry) in mapped.indexed {
                    place.insert(kf, entry);
                }
            }
            self.loops.extend(mapped.loops);
            self.loop_stats = mapped.stats;
            error = error.or(mapped.error);
        }
        if let Some(place) = self.place.as_mut() {
            place.forget_culled(&self.map);
        }
        error.map_or(Ok(()), Err)
    }

    /// A lost map with few keyframes is discarded (ORB-SLAM); a lost map that does not
    /// relocalise within `tracking.relocalisation_window_s` goes to the atlas and a new map
    /// starts. Maps with depth but no vocabulary (nothing could find them again), and any
    /// map in localisation-only mode, wait for relocalisation.
    fn handle_lost(&mut self, timestamp: f64) {
        // A map being localised in is never discarded or closed.
        if self.tracker.state != TrackingState::Lost || self.localization_only {
            return;
        }
        if self.map.num_keyframes() <= self.ctx.config.tracking.min_keyframes_to_keep {
            self.unpose_young_frames();
            self.reset();
            return;
        }
        let since = *self.lost_since.get_or_insert(timestamp);
        let window_s = self.ctx.config.tracking.relocalisation_window_s;
        let findable = self.place.is_some() || !self.ctx.config.sensor.has_depth();
        if findable && timestamp - since >= window_s {
            self.store_current_map();
        }
    }

    /// Starts the map from a two-view pair (see [`crate::mono_init`]); `Ok(T_w_c)` of the
    /// frame when the map was created.
    fn initialise_monocular(
        &mut self,
        mut frame: Frame,
    ) -> Result<Result<Isometry3<f64>, InitStatus>, SlamError> {
        let pair = match self.initializer.add_frame(&frame, &self.ctx) {
            Ok(pair) => pair,
            Err(status) => return Ok(Err(status)),
        };
        let (ref_timestamp, ref_T_c_w) = (pair.reference.timestamp, Isometry3::identity());
        let InitialMap { kf1, kf2, points } =
            match create_initial_map(pair, &mut frame, &mut self.map, &self.ctx)? {
                Ok(initial) => initial,
                Err(status) => {
                    self.initializer.reset();
                    return Ok(Err(status));
                }
            };
        self.new_points.extend(points);
        self.tracker.on_keyframe(frame.index, kf2);
        self.tracker.state = TrackingState::Ok;
        self.tracker.matches_inliers = frame.map_points.iter().flatten().count();
        self.trajectory
            .push(ref_timestamp, &ref_T_c_w, kf1, &self.map);
        self.trajectory
            .push(frame.timestamp, &frame.T_c_w, kf2, &self.map);
        let T_w_c = frame.T_c_w.inverse();
        self.tracker
            .set_last_frame(frame, &self.map, &self.ctx, true);
        self.index_keyframes();
        Ok(Ok(T_w_c))
    }

    /// Creates the map from the first frame with `initialization.min_keypoints` keypoints, of
    /// which at least `initialization.min_depth_points` have depth (ORB-SLAM
    /// `StereoInitialization` asks for the keypoints only): the camera is the world origin and every feature with depth becomes a
    /// map point.
    fn initialise(&mut self, mut frame: Frame) -> Result<Option<Isometry3<f64>>, SlamError> {
        let with_depth = frame.features.depth.iter().filter(|&&z| z > 0.0).count();
        let init = &self.ctx.config.initialization;
        if frame.features.keypoints.len() < init.min_keypoints || with_depth < init.min_depth_points
        {
            return Ok(None);
        }
        frame.T_c_w = Isometry3::identity();
        // Every feature with depth becomes a point at initialisation, not only the close ones.
        let (kf, created) = insert_keyframe(&mut frame, &mut self.map, &self.ctx, f64::INFINITY)?;
        self.tracker.on_keyframe(frame.index, kf);
        self.tracker.state = TrackingState::Ok;
        self.tracker.matches_inliers = created.len();
        self.new_points.extend(created);
        self.trajectory
            .push(frame.timestamp, &frame.T_c_w, kf, &self.map);
        self.tracker
            .set_last_frame(frame, &self.map, &self.ctx, true);
        self.index_keyframes();
        Ok(Some(Isometry3::identity()))
    }

    /// Discards the current map and its trajectory (the atlas's maps stay) and starts again
    /// from the next frame; counted in [`Self::resets`].
    pub fn reset(&mut self) {
        self.clear_map();
        self.resets += 1;
    }

    fn clear_map(&mut self) {
        self.map.clear();
        if let Some(place) = self.place.as_mut() {
            place.clear();
        }
        self.tracker.reset();
        self.trajectory.clear();
        self.forget_map_work();
        if let Some(inertial) = self.inertial.as_mut() {
            inertial.clear_map();
        }
    }

    /// Forgets what belonged to the current map's tracking and mapping (it was cleared or
    /// replaced): the mapping pipeline's state, the points and keyframes waiting for it,
    /// the initialiser, the lost time and the IMU-only poses.
    fn forget_map_work(&mut self) {
        self.mapping.reset();
        self.new_points.clear();
        self.initializer.reset();
        self.lost_since = None;
        self.merge_checks.clear();
        self.predictor.clear();
        self.young_frames.clear();
    }

    /// Sets the ORB vocabulary: keyframes are indexed by their bag of words and a lost frame
    /// is relocalised against the keyframes it recognises (ORB-SLAM), instead of the last
    /// reference keyframe's neighbourhood (or, in a loaded map, every keyframe).
    pub fn set_vocabulary(&mut self, vocabulary: Arc<Vocabulary>) {
        let config = self.ctx.config.place_recognition;
        self.place = Some(PlaceRecognition::new(vocabulary, config));
        self.index_keyframes();
    }

    /// Brings the keyframe index up to date with the map (new and culled keyframes).
    fn index_keyframes(&mut self) {
        if let Some(place) = self.place.as_mut() {
            place.sync(&self.map);
        }
    }

    /// Loops closed so far, oldest first (kept across map resets).
    pub fn loops(&self) -> &[LoopClosure] {
        &self.loops
    }

    /// What loop detection has done so far.
    pub fn loop_stats(&self) -> LoopStats {
        self.loop_stats
    }

    /// Localisation-only mode: frames are tracked (and relocalised) against the map but never
    /// become keyframes, so the map stays as it is (e.g. a loaded map).
    ///
    /// # Errors
    /// `InvalidInput` when switched on without a map: there is nothing to localise in, and
    /// the first frames would build one.
    pub fn set_localization_only(&mut self, on: bool) -> Result<(), SlamError> {
        if on && self.map.num_keyframes() == 0 {
            return Err(SlamError::InvalidInput(
                "localization_only needs a map to localise in: load_map first (this system's \
                 map is empty)"
                    .into(),
            ));
        }
        self.localization_only = on;
        Ok(())
    }

    /// Whether localisation-only mode is on.
    pub fn localization_only(&self) -> bool {
        self.localization_only
    }

    /// Current tracking state.
    pub fn state(&self) -> TrackingState {
        self.tracker.state
    }

    /// The map (keyframes, points, covisibility).
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The bag-of-words index of the keyframes relocalisation searches (with a vocabulary).
    /// With the mapping thread, a keyframe enters it once the thread has processed it.
    pub fn place_recognition(&self) -> Option<&PlaceRecognition> {
        self.place.as_ref()
    }

    /// Number of map resets after tracking was lost right after initialisation.
    pub fn resets(&self) -> usize {
        self.resets
    }

    /// `(id, timestamp, T_w_c)` of every live keyframe of the current map, in id order.
    pub fn keyframe_trajectory(&self) -> Vec<(KeyFrameId, f64, Isometry3<f64>)> {
        keyframes_of(&self.map)
    }

    /// The map's keyframes, points and tracks with every keypoint in raw image pixels
    /// ([`Map::sparse_model`] for this system's camera): what a COLMAP model needs.
    pub fn sparse_model(&self) -> ferroslam_map::SparseModel {
        self.map.sparse_model(&self.ctx.camera)
    }

    /// World positions of every live map point of the current map, metres.
    pub fn map_points(&self) -> Vec<Vector3<f64>> {
        points_of(&self.map)
    }

    /// Colour of every live map point, in the order of [`Self::map_points`] (see
    /// [`ferroslam_map::MapPoint::color`]); `None` for points made from frames without colours.
    pub fn map_point_colors(&self) -> Vec<Option<ferroslam_map::Rgb>> {
        colors_of(&self.map)
    }
}

/// The colour of every live point of `map`, in the order of [`points_of`].
fn colors_of(map: &Map) -> Vec<Option<ferroslam_map::Rgb>> {
    map.map_point_ids()
        .into_iter()
        .filter_map(|m| map.map_point(m).map(|p| p.color()))
        .collect()
}

/// `(id, timestamp, T_w_c)` of every live keyframe of `map`, in id order.
fn keyframes_of(map: &Map) -> Vec<(KeyFrameId, f64, Isometry3<f64>)> {
    map.keyframe_ids()
        .into_iter()
        .filter_map(|id| map.keyframe(id).map(|k| (id, k.timestamp(), k.T_w_c())))
        .collect()
}

/// World positions of every live map point of `map`, in id order.
fn points_of(map: &Map) -> Vec<Vector3<f64>> {
    map.map_point_ids()
        .into_iter()
        .filter_map(|m| map.map_point(m).map(|p| p.position()))
        .collect()
}
