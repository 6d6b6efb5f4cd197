//! Tracking: the camera pose of every frame against the map (ORB-SLAM `Tracking`).
//!
//! Order of attempts, as ORB-SLAM: constant-velocity motion model, then the reference
//! keyframe, then a PnP-RANSAC fallback against the reference keyframe's neighbourhood; a pose
//! found by any of them is refined against the local map.

mod pose_refinement;

pub use pose_refinement::optimize_frame_pose;
use pose_refinement::{discard_outliers, frame_observations};

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use ferroslam_features::matcher::{TH_HIGH, TH_LOW};
use ferroslam_features::{match_brute_force, Descriptor, MatchOptions, ProjectionQuery};
use ferroslam_geometry::pnp::{pnp_ransac, PnpRansacOptions};
use ferroslam_geometry::rolling_shutter::velocity_between;
use ferroslam_geometry::sim3::Sim3;
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_optim::{optimize_pose_inertial, InertialLink};
use nalgebra::{Isometry3, Point3, Translation3, Vector2, Vector3, Vector6};

use crate::config::TrackingConfig;
use crate::context::Context;
use crate::error::SlamError;
use crate::frame::{unproject_depth, Frame};
use crate::imu_prediction::ImuPrediction;
use crate::inertial::scale_translation;
use crate::place_recognition::PlaceRecognition;
use local_map::LocalMap;
use projection_search::ProjectionSearch;

/// Tracking state exposed to users.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackingState {
    /// No map yet: waiting for a frame good enough to start one.
    NotInitialized,
    /// The last frame was localised in the map.
    Ok,
    /// The last frame could not be localised.
    Lost,
    /// Vision could not localise the last frame; its pose is the IMU's prediction (an
    /// aligned visual-inertial map, for at most `inertial.imu_only_max_s` of the configuration).
    RecentlyLost,
}

/// The state machine of tracking between frames.
#[derive(Debug)]
pub struct Tracker {
    /// Current tracking state.
    pub state: TrackingState,
    /// Reference keyframe: the local keyframe sharing most points with the last frame.
    pub reference_kf: Option<KeyFrameId>,
    /// Last frame, with its temporary visual-odometry points.
    last_frame: Option<Frame>,
    /// Pose of the last frame relative to its reference keyframe, to follow BA corrections.
    last_T_c_r: Option<(KeyFrameId, Isometry3<f64>)>,
    /// Constant-velocity model `T_c_l`: motion from the last frame to the current one.
    velocity: Option<Isometry3<f64>>,
    /// Frame index of the last keyframe and of the last relocalisation.
    pub last_keyframe_frame: usize,
    last_relocalisation_frame: Option<usize>,
    local_keyframes: Vec<KeyFrameId>,
    local_map: LocalMap,
    /// The inliers of the frame, whose found counter is raised in one map call.
    found: Vec<MapPointId>,
    /// Map point inliers of the last tracked frame.
    pub matches_inliers: usize,
    /// Time spent in motion-only BA since the last [`Self::take_pose_optimisation_ms`].
    pose_optimisation: Duration,
    /// Frame index of the last keyframe deferred for busy local mapping.
    keyframe_deferred_at: Option<usize>,
}

impl Default for Tracker {
    fn default() -> Self {
        Self {
            state: TrackingState::NotInitialized,
            reference_kf: None,
            last_frame: None,
            last_T_c_r: None,
            velocity: None,
            last_keyframe_frame: 0,
            last_relocalisation_frame: None,
            local_keyframes: Vec::new(),
            local_map: LocalMap::default(),
            found: Vec::new(),
            matches_inliers: 0,
            pose_optimisation: Duration::ZERO,
            keyframe_deferred_at: None,
        }
    }
}

impl Tracker {
    /// Milliseconds spent in motion-only BA since the last call (the frame's share of
    /// tracking time that is pose optimisation rather than matching).
    pub fn take_pose_optimisation_ms(&mut self) -> f64 {
        std::mem::take(&mut self.pose_optimisation).as_secs_f64() * 1e3
    }

    /// [`optimize_frame_pose`], timed, with the motion model's velocity as the prior of a
    /// rolling-shutter frame's.
    fn optimize_pose(
        &mut self,
        frame: &mut Frame,
        map: &Map,
        ctx: &Context,
    ) -> Result<usize, SlamError> {
        let start = Instant::now();
        let prior = self.velocity_prior(frame);
        let inliers = optimize_frame_pose(frame, map, ctx, &prior);
        self.pose_optimisation += start.elapsed();
        inliers
    }

    /// The velocity `[v; w]` of `T_c_w` the constant-velocity model predicts for `frame`:
    /// the last frame-to-frame motion over its time; zero without a motion model (after a
    /// relocalisation, where the prior then holds the rows to a still camera).
    fn velocity_prior(&self, frame: &Frame) -> Vector6<f64> {
        let (Some(last), Some(T_c_l)) = (self.last_frame.as_ref(), self.velocity) else {
            return Vector6::zeros();
        };
        let dt = frame.timestamp - last.timestamp;
        velocity_between(&Isometry3::identity(), &T_c_l, dt).unwrap_or_else(Vector6::zeros)
    }

    /// Estimates `frame.T_c_w` against the map. Returns whether tracking succeeded; on success
    /// `frame.map_points` holds the inlier associations.
    ///
    /// A lost frame is relocalised against the keyframes `place` recognises (when a
    /// vocabulary is set), else against the last reference keyframe's neighbourhood.
    pub fn track(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        ctx: &Context,
        place: Option<&PlaceRecognition>,
    ) -> Result<bool, SlamError> {
        self.refresh_last_frame_pose(map);
        let recovered = match self.state {
            TrackingState::Ok => {
                let by_motion = if self.velocity.is_some() {
                    self.track_with_motion_model(frame, map, ctx)?
                } else {
                    0
                };
                if by_motion >= ctx.config.tracking.strong_pose_inliers {
                    true
                } else {
                    // A weak motion-model pose under fast rotation is often wrong: let
                    // PnP against the reference keyframe compete and keep the better one.
                    let min_inliers = ctx.config.tracking.min_pose_inliers;
                    let motion_guess = (by_motion >= min_inliers).then(|| frame.clone());
                    let candidates = self.reference_neighbourhood(map, ctx);
                    let by_pnp = self.relocalise(frame, map, ctx, candidates)?;
                    match motion_guess {
                        Some(guess) if by_motion >= by_pnp => {
                            *frame = guess;
                            true
                        }
                        _ => by_pnp >= min_inliers,
                    }
                }
            }
            _ => {
                let candidates = match place {
                    Some(p) => p.relocalisation_candidates(&frame.features.descriptors, map),
                    None => self.reference_neighbourhood(map, ctx),
                };
                let found = self.relocalise(frame, map, ctx, candidates)?
                    >= ctx.config.tracking.min_pose_inliers;
                if found {
                    self.last_relocalisation_frame = Some(frame.index);
                }
                found
            }
        };
        let ok = recovered && self.track_local_map(frame, map, ctx)?;
        if ok {
            self.velocity = self.last_frame.as_ref().map(|last| {
                let mut velocity = frame.T_c_w * last.T_c_w.inverse();
                velocity.rotation.renormalize();
                velocity
            });
            self.state = TrackingState::Ok;
        } else {
            self.velocity = None;
            self.state = TrackingState::Lost;
        }
        Ok(ok)
    }

    /// Looks for the local map around the IMU's prediction for a frame vision could not
    /// localise otherwise (ORB-SLAM3's `RECENTLY_LOST` tracking): the reference keyframe's
    /// neighbourhood is searched with the wide radius used after a relocalisation. Enough
    /// matches to track on their own: the frame is tracked (returns true). Otherwise the
    /// few matches found are fused with the IMU (visual-inertial motion-only BA with the
    /// prediction's inertial factor as prior; the prediction itself when there is none),
    /// the frame takes that pose without its matches and the state becomes
    /// [`TrackingState::RecentlyLost`].
    #[allow(non_snake_case)]
    pub(crate) fn track_from_prediction(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        ctx: &Context,
        prediction: &ImuPrediction,
        T_b_c: &Isometry3<f64>,
    ) -> Result<bool, SlamError> {
        frame.T_c_w = prediction.T_c_w;
        frame.clear_associations();
        self.local_keyframes = self.reference_neighbourhood(map, ctx);
        self.local_map.gather(map, &self.local_keyframes);
        let width = ctx.config.tracking.imu_prediction_search_width;
        self.local_map.search(frame, map, ctx, width)?;
        let searched = frame.map_points.clone();
        let tracking = &ctx.config.tracking;
        if searched.iter().flatten().count() >= tracking.min_search_matches {
            self.optimize_pose(frame, map, ctx)?;
            if discard_outliers(frame) >= tracking.min_pose_inliers
                && self.track_local_map(frame, map, ctx)?
            {
                self.state = TrackingState::Ok;
                return Ok(true);
            }
        }
        frame.clear_associations();
        frame.T_c_w = prediction.T_c_w;
        frame.map_points = searched;
        let (obs, _) = frame_observations(frame, map);
        let mut outlier = vec![false; obs.len()];
        let link = InertialLink {
            previous: &prediction.previous,
            factor: &prediction.factor,
            bias_walk: &prediction.bias_walk,
        };
        let start = Instant::now();
        let fused = optimize_pose_inertial(
            &prediction.predicted,
            &link,
            T_b_c,
            &obs,
            &ctx.optim_cameras,
            &mut outlier,
        );
        self.pose_optimisation += start.elapsed();
        let fused = fused?;
        frame.T_c_w = fused.T_c_w;
        frame.clear_associations();
        self.matches_inliers = fused.num_inliers;
        self.state = TrackingState::RecentlyLost;
        Ok(false)
    }

    /// Keeps `frame` as the last frame, adding depth-backed temporary points (ORB-SLAM
    /// `UpdateLastFrame`) so the motion model has matches where the map is thin.
    pub fn set_last_frame(
        &mut self,
        mut frame: Frame,
        map: &Map,
        ctx: &Context,
        is_keyframe: bool,
    ) {
        frame.vo_points.iter_mut().for_each(|p| *p = None);
        for (i, m) in frame.map_points.iter_mut().enumerate() {
            if frame.outlier[i] || m.is_some_and(|id| map.map_point(id).is_none()) {
                *m = None;
            }
        }
        if !is_keyframe {
            let T_w_c = frame.T_c_w.inverse();
            for i in frame.closest_depth_features(ctx.close_depth_m) {
                if frame.map_points[i].is_none() {
                    frame.vo_points[i] = unproject_depth(&frame.features, i, ctx, &T_w_c);
                }
            }
        }
        self.last_T_c_r = self
            .reference_kf
            .and_then(|r| map.keyframe(r).map(|kf| (r, frame.T_c_w * kf.T_w_c())));
        frame.outlier.iter_mut().for_each(|o| *o = false);
        self.last_frame = Some(frame);
    }

    /// A tracker that follows frames backwards in time from this one's last frame (tracked
    /// in `self`'s map): the same state and reference keyframe, and a motion model that
    /// starts from standing still; each frame it tracks becomes its last one.
    pub(crate) fn backwards(&self) -> Option<Self> {
        Some(Self {
            state: TrackingState::Ok,
            reference_kf: self.reference_kf,
            last_frame: Some(self.last_frame.clone()?),
            last_T_c_r: self.last_T_c_r,
            velocity: Some(Isometry3::identity()),
            ..Self::default()
        })
    }

    /// Starts tracking from scratch (after a map reset).
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// Expresses the last frame and the motion model in a world scaled by `s` (the monocular
    /// map rescaled to metres by the inertial alignment).
    pub(crate) fn rescale(&mut self, s: f64) {
        if let Some(last) = self.last_frame.as_mut() {
            last.T_c_w = scale_translation(&last.T_c_w, s);
            last.vo_points.iter_mut().flatten().for_each(|p| *p *= s);
        }
        if let Some((_, T_l_r)) = self.last_T_c_r.as_mut() {
            *T_l_r = scale_translation(T_l_r, s);
        }
        if let Some(velocity) = self.velocity.as_mut() {
            *velocity = scale_translation(velocity, s);
        }
    }

    /// Expresses the last frame and the motion model in the world of the map this one was
    /// merged into (`p_new = S_new_old p_old`): the world scaled by `s`, then moved rigidly.
    pub(crate) fn transform_world(&mut self, S_new_old: &Sim3) {
        self.rescale(S_new_old.scale);
        let T_new_scaled = Isometry3::from_parts(
            Translation3::from(S_new_old.translation),
            S_new_old.rotation,
        );
        if let Some(last) = self.last_frame.as_mut() {
            last.T_c_w *= T_new_scaled.inverse();
            for p in last.vo_points.iter_mut().flatten() {
                *p = T_new_scaled.transform_point(&Point3::from(*p)).coords;
            }
        }
    }

    /// Marks the frame index of a new keyframe.
    pub fn on_keyframe(&mut self, frame_index: usize, kf: KeyFrameId) {
        self.last_keyframe_frame = frame_index;
        self.reference_kf = Some(kf);
    }

    /// Re-anchors the last frame to its reference keyframe, which local BA may have moved.
    fn refresh_last_frame_pose(&mut self, map: &Map) {
        if let (Some(last), Some((r, T_l_r))) = (self.last_frame.as_mut(), self.last_T_c_r) {
            if let Some(kf) = map.keyframe(r) {
                last.T_c_w = T_l_r * kf.T_c_w();
            }
        }
    }

    /// Returns the number of map point inliers (0 on failure).
    fn track_with_motion_model(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        ctx: &Context,
    ) -> Result<usize, SlamError> {
        let (Some(last), Some(velocity)) = (self.last_frame.as_ref(), self.velocity) else {
            return Ok(0);
        };
        frame.T_c_w = velocity * last.T_c_w;
        frame.clear_associations();
        let tracking = &ctx.config.tracking;
        let mut found = search_last_frame(frame, last, map, ctx, tracking.motion_search_radius_px);
        if found < tracking.retry_search_matches {
            frame.clear_associations();
            found = search_last_frame(frame, last, map, ctx, tracking.motion_retry_radius_px);
        }
        if found < tracking.min_search_matches {
            return Ok(0);
        }
        self.optimize_pose(frame, map, ctx)?;
        let inliers = discard_outliers(frame);
        Ok(if inliers >= tracking.min_pose_inliers {
            inliers
        } else {
            0
        })
    }

    /// Reference keyframe tracking and relocalisation in one: descriptor matches against each
    /// candidate keyframe in turn (the reference keyframe and its best covisible keyframes,
    /// or the keyframes place recognition found), each solved by PnP-RANSAC before
    /// motion-only BA. Used when the motion model fails or tracking was lost; RANSAC
    /// keeps brute-force mismatches from dragging the pose (ORB-SLAM starts BA from the last
    /// pose, which diverges under fast rotation).
    /// Returns the number of map point inliers of the first keyframe that localises the
    /// frame (0 on failure, with the associations cleared).
    fn relocalise(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        ctx: &Context,
        candidates: Vec<KeyFrameId>,
    ) -> Result<usize, SlamError> {
        let tracking = &ctx.config.tracking;
        for kf in candidates {
            frame.clear_associations();
            if match_keyframe(frame, kf, map, tracking.reference_nn_ratio)
                < tracking.min_reference_matches
            {
                continue;
            }
            // PnP runs in the camera with the most matches; the other cameras' matches
            // join in motion-only BA.
            let counts = (0..ctx.num_cameras()).map(|k| {
                let range = frame.features.camera_range(k);
                frame.map_points[range].iter().flatten().count()
            });
            let camera = counts
                .enumerate()
                .max_by_key(|&(k, n)| (n, std::cmp::Reverse(k)))
                .map_or(0, |(k, _)| k);
            let view = ctx.view(camera);
            let matched: Vec<(usize, MapPointId)> = frame
                .map_points
                .iter()
                .enumerate()
                .filter_map(|(i, m)| m.map(|m| (i, m)))
                .filter(|&(i, _)| frame.features.camera_of(i) == camera)
                .collect();
            let points_w: Vec<_> = matched
                .iter()
                .map(|&(_, m)| map.map_point(m).unwrap().position())
                .collect();
            let pixels: Vec<_> = matched
                .iter()
                .map(|&(i, _)| {
                    let kp = &frame.features.keypoints[i];
                    Vector2::new(kp.x as f64, kp.y as f64)
                })
                .collect();
            let sigma2: Vec<_> = matched
                .iter()
                .map(|&(i, _)| map.pyramid().sigma2[frame.features.keypoints[i].octave as usize])
                .collect();
            let options = PnpRansacOptions {
                min_inliers: tracking.min_pose_inliers,
                seed: ctx.config.seed ^ frame.index as u64,
                ..PnpRansacOptions::default()
            };
            let Some(solution) = pnp_ransac(&points_w, &pixels, &sigma2, view.camera, &options)
            else {
                continue;
            };
            for (k, &(i, _)) in matched.iter().enumerate() {
                if !solution.inliers[k] {
                    frame.map_points[i] = None;
                }
            }
            // The body (first camera) pose of the camera PnP found: T_c0_w = T_c_c0^-1 T_c_w.
            let T_c0_w = view
                .T_c_c0
                .map_or(solution.T_c_w, |T| T.inverse() * solution.T_c_w);
            frame.T_c_w = T_c0_w;
            self.optimize_pose(frame, map, ctx)?;
            let inliers = discard_outliers(frame);
            if inliers >= tracking.min_pose_inliers {
                self.reference_kf = Some(kf);
                return Ok(inliers);
            }
        }
        frame.clear_associations();
        Ok(0)
    }

    /// The reference keyframe and its best covisible keyframes
    /// (`tracking.neighbourhood_covisibles`); without a reference (a freshly loaded map and no
    /// vocabulary) every keyframe, oldest first.
    fn reference_neighbourhood(&self, map: &Map, ctx: &Context) -> Vec<KeyFrameId> {
        let n = ctx.config.tracking.neighbourhood_covisibles;
        match self.reference_kf.filter(|&r| map.keyframe(r).is_some()) {
            Some(r) => std::iter::once(r)
                .chain(map.best_covisibles(r, n))
                .collect(),
            None => map.keyframe_ids(),
        }
    }

    /// Refines the pose against every map point of the local keyframes (ORB-SLAM
    /// `TrackLocalMap`), and counts the inliers that decide success.
    fn track_local_map(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        ctx: &Context,
    ) -> Result<bool, SlamError> {
        frame.vo_points.iter_mut().for_each(|p| *p = None);
        self.update_local_keyframes(frame, map, &ctx.config.tracking);
        self.local_map.gather(map, &self.local_keyframes);
        // ORB-SLAM: a wider search right after relocalisation, and a stricter inlier count
        // while the relocalised pose is still unconfirmed.
        let tracking = &ctx.config.tracking;
        let since_relocalisation = self.last_relocalisation_frame.map(|f| frame.index - f);
        let recently_relocalised =
            since_relocalisation.is_some_and(|n| n < tracking.relocalised_wide_search_frames);
        let unconfirmed =
            since_relocalisation.is_some_and(|n| n < tracking.post_relocalisation_frames);
        self.local_map.search(
            frame,
            map,
            ctx,
            if recently_relocalised {
                tracking.relocalised_search_width
            } else {
                tracking.local_search_width
            },
        )?;
        self.optimize_pose(frame, map, ctx)?;
        let mut inliers = 0;
        self.found.clear();
        for i in 0..frame.len() {
            let Some(m) = frame.map_points[i] else {
                continue;
            };
            if frame.outlier[i] {
                frame.map_points[i] = None;
                continue;
            }
            self.found.push(m);
            if map.map_point(m).is_some_and(|p| p.num_observations() > 0) {
                inliers += 1;
            }
        }
        map.increase_found_many(&self.found)?;
        self.matches_inliers = inliers;
        let min_inliers = if unconfirmed {
            tracking.relocalised_min_inliers
        } else {
            tracking.track_feature_range.0
        };
        Ok(inliers >= min_inliers)
    }

    /// Local keyframes: those observing the frame's points, their best covisibles, children and
    /// parents (ORB-SLAM `UpdateLocalKeyFrames`); the most voted one becomes the reference.
    fn update_local_keyframes(&mut self, frame: &Frame, map: &Map, tracking: &TrackingConfig) {
        let mut votes: HashMap<KeyFrameId, usize> = HashMap::new();
        for m in frame.map_points.iter().flatten() {
            if let Some(p) = map.map_point(*m) {
                for kf in p.observations().keys() {
                    *votes.entry(*kf).or_default() += 1;
                }
            }
        }
        let mut voted: Vec<(KeyFrameId, usize)> = votes.into_iter().collect();
        voted.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        if let Some(&(best, _)) = voted.first() {
            self.reference_kf = Some(best);
        }
        let mut local: Vec<KeyFrameId> = voted.iter().map(|v| v.0).collect();
        let mut seen: HashSet<KeyFrameId> = local.iter().copied().collect();
        let first_ring = local.clone();
        for kf in first_ring {
            if local.len() >= tracking.max_local_keyframes {
                break;
            }
            let Some(k) = map.keyframe(kf) else { continue };
            let neighbours = map.best_covisibles(kf, tracking.neighbourhood_covisibles);
            let family = k.children().iter().copied().chain(k.parent());
            for n in neighbours.into_iter().chain(family) {
                if map.keyframe(n).is_some() && seen.insert(n) {
                    local.push(n);
                }
            }
        }
        self.local_keyframes = local;
    }

    /// Whether the keyframe that frame `frame_index` asks for, while local mapping is still
    /// busy with the previous one, waits for the next frame instead of tracking waiting for
    /// mapping (which is asked to finish early meanwhile); records the deferral.
    ///
    /// Monocular only, and at most one frame in a row: ORB-SLAM refuses monocular keyframes
    /// whenever mapping is busy, which loses a forward-driving sequence fed at full speed
    /// (KITTI 06), and a deferral with weak tracking lost it too. So tracking must keep at
    /// least `tracking.deferral_inliers_factor` times `TrackFeatureRange`'s lower limit
    /// (below which it is lost). With depth a
    /// keyframe brings its own points at once; waiting costs little there.
    pub fn defer_keyframe(&mut self, frame_index: usize, ctx: &Context) -> bool {
        let deferred_last_frame = self
            .keyframe_deferred_at
            .is_some_and(|f| f + 1 == frame_index);
        let defer = !ctx.config.sensor.has_depth()
            && !deferred_last_frame
            && self.matches_inliers
                >= ctx.config.tracking.deferral_inliers_factor
                    * ctx.config.tracking.track_feature_range.0;
        if defer {
            self.keyframe_deferred_at = Some(frame_index);
        }
        defer
    }

    /// ORB-SLAM's keyframe decision (`tracking.reference_ratio` of the configuration), with
    /// MATLAB's `TrackFeatureRange` upper limit and `SkipMaxFrames`: a frame tracking fewer
    /// than `upper` points, or `skip_max_frames` frames after the last keyframe, is one.
    /// Monocular, fewer than `upper` points counts only below the reference ratio too
    /// (MATLAB's monocular example, `helperIsKeyFrame`): a monocular map tracks few points
    /// (on KITTI, a small share of its features), so the bare limit fired on most frames and
    /// tracking spent its time waiting for local mapping.
    ///
    /// `mapping_idle` is ORB-SLAM's `c1b`: while local mapping is still busy with earlier
    /// keyframes, the reference-ratio rule only fires when tracking is weak (`c1c`: with
    /// depth, `weak_tracking_share` of the reference's points or close structure left
    /// untracked). Without
    /// it every revisit of a mapped place adds keyframes as fast as frames come, and a long
    /// run's map (and the time to track against it) keeps growing.
    ///
    /// With depth, idle mapping alone does not fire the ratio rule for a frame whose inliers
    /// are mostly (`tracking.redundant_view_share`) points three keyframes already observe: on a
    /// revisit the new reference keyframe's fused points outnumber what the next frame finds
    /// again, so the rule would fire every frame or two, each keyframe kept by culling for its
    /// few new close points. Exploring frames track young points and are barely affected.
    pub fn need_new_keyframe(
        &self,
        frame: &Frame,
        map: &Map,
        ctx: &Context,
        mapping_idle: bool,
    ) -> bool {
        let Some(r) = self.reference_kf else {
            return false;
        };
        let n_kfs = map.num_keyframes();
        let tracking = &ctx.config.tracking;
        let window = tracking.post_relocalisation_frames;
        if self
            .last_relocalisation_frame
            .is_some_and(|f| frame.index < f + window)
            && n_kfs > window
        {
            return false;
        }
        let min_obs = if n_kfs <= 2 {
            tracking.young_map_reference_min_observations
        } else {
            tracking.reference_min_observations
        };
        let ref_matches = map.tracked_points(r, min_obs) as f64;
        let (mut tracked_close, mut untracked_close) = (0, 0);
        for i in 0..frame.len() {
            let z = frame.features.depth[i] as f64;
            if z > 0.0 && z < ctx.close_depth_m {
                if frame.map_points[i].is_some() && !frame.outlier[i] {
                    tracked_close += 1;
                } else {
                    untracked_close += 1;
                }
            }
        }
        let need_close = tracked_close < tracking.close_tracked_max
            && untracked_close > tracking.close_untracked_min;
        let inliers = self.matches_inliers;
        let since_kf = frame.index.saturating_sub(self.last_keyframe_frame);
        let ratio = if n_kfs < 2 {
            tracking.first_keyframes_reference_ratio
        } else {
            tracking.reference_ratio
        };
        // MATLAB's rule (fewer tracked points than the upper limit, or SkipMaxFrames reached)
        // or ORB-SLAM's (tracking much less than the reference keyframe, or close structure
        // left untracked, when mapping can take the keyframe). Monocular, the upper limit
        // also needs the reference ratio, as in MATLAB's monocular example.
        let below_ratio = (inliers as f64) < ref_matches * ratio;
        let few_tracked = inliers < tracking.track_feature_range.1
            && (ctx.config.sensor.has_depth() || below_ratio);
        let matlab = few_tracked || since_kf >= tracking.skip_max_frames;
        let weak = ctx.config.sensor.has_depth()
            && ((inliers as f64) < tracking.weak_tracking_share * ref_matches || need_close);
        // The redundancy count walks every inlier's point: only when it decides.
        let views_mapped_structure = || {
            ctx.config.sensor.has_depth()
                && (inliers_seen_by(frame, map, tracking.redundant_view_keyframes) as f64)
                    >= tracking.redundant_view_share * inliers as f64
        };
        let orb_slam =
            (below_ratio || need_close) && (weak || (mapping_idle && !views_mapped_structure()));
        (matlab || orb_slam) && inliers > tracking.min_keyframe_inliers
    }
}

/// Inlier map points of the frame observed by at least `min_keyframes` keyframes.
fn inliers_seen_by(frame: &Frame, map: &Map, min_keyframes: usize) -> usize {
    frame
        .map_points
        .iter()
        .zip(&frame.outlier)
        .filter_map(|(m, &outlier)| m.filter(|_| !outlier))
        .filter(|m| {
            map.map_point(*m)
                .is_some_and(|p| p.observations().len() >= min_keyframes)
        })
        .count()
}

/// Matches the frame against the keypoints of keyframe `kf` that carry map points
/// (brute force with ratio test and rotation consistency; a BoW search once a vocabulary exists).
fn match_keyframe(frame: &mut Frame, kf: KeyFrameId, map: &Map, ratio: f32) -> usize {
    let Some(k) = map.keyframe(kf) else { return 0 };
    let mut train_kps = Vec::new();
    let mut train_desc: Vec<Descriptor> = Vec::new();
    let mut train_ids = Vec::new();
    for (i, m) in k.map_points().iter().enumerate() {
        if let Some(m) = m.filter(|m| map.map_point(*m).is_some()) {
            train_kps.push(k.features().keypoints[i]);
            train_desc.push(k.features().descriptors[i]);
            train_ids.push(m);
        }
    }
    let opts = MatchOptions {
        max_distance: TH_LOW,
        nn_ratio: Some(ratio),
        check_orientation: true,
    };
    let matches = match_brute_force(
        &frame.features.keypoints,
        &frame.features.descriptors,
        &train_kps,
        &train_desc,
        &opts,
    );
    let mut n = 0;
    for (i, m) in matches.iter().enumerate() {
        if let Some(t) = m {
            frame.map_points[i] = Some(train_ids[*t]);
            n += 1;
        }
    }
    n
}

/// Projects the last frame's map points and temporary points with the predicted pose and
/// matches them in a radius `radius_px * scale(octave)` (ORB-SLAM motion-model search).
fn search_last_frame(
    frame: &mut Frame,
    last: &Frame,
    map: &Map,
    ctx: &Context,
    radius_px: f64,
) -> usize {
    let pyramid = map.pyramid();
    let n_levels = pyramid.n_levels as u8;
    // With depth, a camera moving forward sees last frame's points at coarser levels (and
    // finer moving back); a monocular map has no metric baseline to tell (ORB-SLAM).
    let center_in_last = last.T_c_w * Point3::from(frame.camera_center());
    let has_depth = ctx.config.sensor.has_depth();
    let forward = has_depth && center_in_last.z > ctx.baseline_m;
    let backward = has_depth && -center_in_last.z > ctx.baseline_m;
    let mut searches: Vec<ProjectionSearch<(Option<MapPointId>, Vector3<f64>)>> = (0..ctx
        .num_cameras())
        .map(|_| ProjectionSearch::default())
        .collect();
    for i in 0..last.len() {
        let (p_w, descriptor, point) = if let Some(m) = last.map_points[i] {
            let Some(p) = map.map_point(m) else { continue };
            (p.position(), *p.descriptor(), Some(m))
        } else if let Some(p_w) = last.vo_points[i] {
            (p_w, last.features.descriptors[i], None)
        } else {
            continue;
        };
        let kp = &last.features.keypoints[i];
        let octave = kp.octave;
        let (min_level, max_level) = if forward {
            (octave, n_levels - 1)
        } else if backward {
            (0, octave)
        } else {
            (octave.saturating_sub(1), (octave + 1).min(n_levels - 1))
        };
        for (k, search) in searches.iter_mut().enumerate() {
            let view = ctx.view(k);
            let p_c = view.pose(&frame.T_c_w) * Point3::from(p_w);
            let Some(uv) = view.camera.project(&p_c.coords) else {
                continue;
            };
            if !view.contains(&uv) {
                continue;
            }
            search.push(
                ProjectionQuery {
                    u: uv.x,
                    v: uv.y,
                    radius: radius_px * pyramid.scale[octave as usize],
                    min_level,
                    max_level,
                    descriptor,
                    angle_deg: Some(kp.angle_deg),
                },
                view.u_right(&p_c.coords, uv.x),
                (point, p_w),
            );
        }
    }
    let taken = vec![false; frame.len()];
    let opts = MatchOptions {
        max_distance: TH_HIGH,
        nn_ratio: None,
        check_orientation: true,
    };
    let mut n = 0;
    for (k, search) in searches.iter().enumerate() {
        for (i, source) in search.run(frame, k, &taken, &opts) {
            match source {
                (Some(m), _) => frame.map_points[i] = Some(m),
                (None, p_w) => frame.vo_points[i] = Some(p_w),
            }
            n += 1;
        }
    }
    n
}

mod local_map;
mod projection_search;
#[cfg(test)]
mod tests;
