//! `SlamSystem`: the synchronous pipeline, one call per frame.

use std::time::Instant;

use ferroslam_features::ScalePyramid;
use ferroslam_geometry::camera::PinholeCamera;
use ferroslam_map::{KeyFrameId, Map};
use nalgebra::{Isometry3, Vector3};

use crate::config::SlamConfig;
use crate::context::Context;
use crate::error::SlamError;
use crate::frame::{Frame, RgbdInput, StereoInput};
use crate::local_mapping::{LocalMapper, MappingReport};
use crate::tracking::{Tracker, TrackingState, MIN_INIT_FEATURES};
use crate::trajectory::Trajectory;

/// Outcome of tracking one frame.
#[derive(Clone, Debug)]
pub struct TrackResult {
    /// Tracking state after this frame.
    pub state: TrackingState,
    /// Camera pose in the world when tracked.
    pub T_w_c: Option<Isometry3<f64>>,
    /// Whether this frame became a keyframe.
    pub is_keyframe: bool,
    /// Map points matched as inliers in this frame.
    pub num_tracked: usize,
    /// Wall time of tracking, milliseconds.
    pub tracking_ms: f64,
    /// Wall time of local mapping triggered by this frame, milliseconds.
    pub mapping_ms: f64,
    /// What local mapping did, when a keyframe was inserted.
    pub mapping: Option<MappingReport>,
}

/// The SLAM system: tracking and local mapping run inline, in call order (deterministic).
pub struct SlamSystem {
    ctx: Context,
    map: Map,
    tracker: Tracker,
    mapper: LocalMapper,
    trajectory: Trajectory,
    frames_seen: usize,
    last_timestamp: Option<f64>,
    resets: usize,
}

impl SlamSystem {
    /// Creates a system for `camera` (the calibration of the raw keypoints) and `config`.
    pub fn new(camera: PinholeCamera, config: SlamConfig) -> Result<Self, SlamError> {
        config.validate()?;
        let pyramid = ScalePyramid::new(config.scale_factor, config.n_levels)
            .map_err(|e| SlamError::InvalidConfig(e.to_string()))?;
        Ok(Self {
            ctx: Context::new(camera, config),
            map: Map::new(pyramid),
            tracker: Tracker::default(),
            mapper: LocalMapper::default(),
            trajectory: Trajectory::default(),
            frames_seen: 0,
            last_timestamp: None,
            resets: 0,
        })
    }

    /// Tracks one RGB-D frame; keypoints are raw (distorted) pixels with sensor depth.
    ///
    /// # Errors
    /// `InvalidInput` for mismatched lengths, non-finite values, octaves beyond the pyramid or
    /// a timestamp not after the previous one; the system state is unchanged then.
    pub fn track_rgbd(&mut self, input: &RgbdInput<'_>) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        input.validate(self.ctx.config.n_levels)?;
        self.check_timestamp(input.timestamp)?;
        let frame = Frame::from_rgbd(self.frames_seen, input, &self.ctx)?;
        self.track_frame(frame, start)
    }

    /// Tracks one rectified stereo pair: the left keypoints are matched into the right image
    /// (depth from disparity, `bf` of the configuration) and the left frame is tracked.
    ///
    /// # Errors
    /// `InvalidInput` as [`Self::track_rgbd`], for pyramids that miss levels or differ in size
    /// between the images, and when the camera has distortion (stereo input must be rectified).
    pub fn track_stereo(&mut self, input: &StereoInput<'_>) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        if self.ctx.camera.is_distorted() {
            return Err(SlamError::InvalidInput(
                "stereo input must come from rectified images, but the camera has distortion \
                 coefficients: rectify the pair and pass the rectified pinhole intrinsics"
                    .into(),
            ));
        }
        input.validate(self.ctx.config.n_levels)?;
        self.check_timestamp(input.timestamp)?;
        let frame = Frame::from_stereo(self.frames_seen, input, self.map.pyramid(), &self.ctx)?;
        self.track_frame(frame, start)
    }

    fn check_timestamp(&mut self, timestamp: f64) -> Result<(), SlamError> {
        if let Some(t) = self.last_timestamp.filter(|&t| timestamp <= t) {
            return Err(SlamError::InvalidInput(format!(
                "timestamp {timestamp} is not after the previous frame's {t}"
            )));
        }
        self.last_timestamp = Some(timestamp);
        Ok(())
    }

    /// Initialises or tracks a frame with depth, then inserts a keyframe when needed.
    fn track_frame(&mut self, mut frame: Frame, start: Instant) -> Result<TrackResult, SlamError> {
        self.frames_seen += 1;
        if self.tracker.state == TrackingState::NotInitialized {
            let initialised = self.initialise(frame)?;
            return Ok(TrackResult {
                state: self.tracker.state,
                T_w_c: initialised.then(Isometry3::identity),
                is_keyframe: initialised,
                num_tracked: self.tracker.matches_inliers,
                tracking_ms: start.elapsed().as_secs_f64() * 1e3,
                mapping_ms: 0.0,
                mapping: None,
            });
        }
        let tracked = self.tracker.track(&mut frame, &mut self.map, &self.ctx)?;
        let tracking_ms = start.elapsed().as_secs_f64() * 1e3;
        let mut result = TrackResult {
            state: self.tracker.state,
            T_w_c: tracked.then(|| frame.T_c_w.inverse()),
            is_keyframe: false,
            num_tracked: if tracked {
                self.tracker.matches_inliers
            } else {
                0
            },
            tracking_ms,
            mapping_ms: 0.0,
            mapping: None,
        };
        if !tracked {
            if self.tracker.state == TrackingState::Lost && self.map.num_keyframes() <= 5 {
                self.reset();
            }
            return Ok(result);
        }
        let start = Instant::now();
        let new_keyframe = self.tracker.state == TrackingState::Ok
            && self.tracker.need_new_keyframe(&frame, &self.map, &self.ctx);
        if new_keyframe {
            let mut report = MappingReport::default();
            let kf = self.mapper.insert_keyframe(
                &mut frame,
                &mut self.map,
                &self.ctx,
                self.ctx.close_depth_m,
                &mut report,
            )?;
            self.tracker.on_keyframe(frame.index, kf);
            self.mapper
                .process_keyframe(kf, &mut self.map, &self.ctx, &mut report)?;
            result.is_keyframe = true;
            result.mapping = Some(report);
        }
        result.mapping_ms = start.elapsed().as_secs_f64() * 1e3;
        if let Some(r) = self.tracker.reference_kf {
            self.trajectory
                .push(frame.timestamp, &frame.T_c_w, r, &self.map);
        }
        self.tracker
            .set_last_frame(frame, &self.map, &self.ctx, new_keyframe);
        Ok(result)
    }

    /// Creates the map from the first frame with enough depth (ORB-SLAM `StereoInitialization`):
    /// the camera is the world origin and every feature with depth becomes a map point.
    fn initialise(&mut self, mut frame: Frame) -> Result<bool, SlamError> {
        let with_depth = frame.features.depth.iter().filter(|&&z| z > 0.0).count();
        if with_depth < MIN_INIT_FEATURES {
            return Ok(false);
        }
        frame.T_c_w = Isometry3::identity();
        let mut report = MappingReport::default();
        // Every feature with depth becomes a point at initialisation, not only the close ones.
        let kf = self.mapper.insert_keyframe(
            &mut frame,
            &mut self.map,
            &self.ctx,
            f64::INFINITY,
            &mut report,
        )?;
        self.tracker.on_keyframe(frame.index, kf);
        self.tracker.state = TrackingState::Ok;
        self.tracker.matches_inliers = report.depth_points;
        self.trajectory
            .push(frame.timestamp, &frame.T_c_w, kf, &self.map);
        self.tracker
            .set_last_frame(frame, &self.map, &self.ctx, true);
        Ok(true)
    }

    /// Clears the map and starts again from the next frame.
    pub fn reset(&mut self) {
        self.map.clear();
        self.tracker.reset();
        self.mapper.reset();
        self.trajectory.clear();
        self.resets += 1;
    }

    /// Current tracking state.
    pub fn state(&self) -> TrackingState {
        self.tracker.state
    }

    /// The map (keyframes, points, covisibility).
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// Number of map resets after tracking was lost right after initialisation.
    pub fn resets(&self) -> usize {
        self.resets
    }

    /// `(timestamp, T_w_c)` of every tracked frame, with all map corrections applied.
    pub fn frame_trajectory(&self) -> Vec<(f64, Isometry3<f64>)> {
        self.trajectory.poses(&self.map)
    }

    /// `(id, timestamp, T_w_c)` of every live keyframe, in id order.
    pub fn keyframe_trajectory(&self) -> Vec<(KeyFrameId, f64, Isometry3<f64>)> {
        self.map
            .keyframe_ids()
            .into_iter()
            .filter_map(|id| {
                self.map
                    .keyframe(id)
                    .map(|k| (id, k.timestamp(), k.T_w_c()))
            })
            .collect()
    }

    /// World positions of every live map point, metres.
    pub fn map_points(&self) -> Vec<Vector3<f64>> {
        self.map
            .map_point_ids()
            .into_iter()
            .filter_map(|m| self.map.map_point(m).map(|p| p.position()))
            .collect()
    }
}
