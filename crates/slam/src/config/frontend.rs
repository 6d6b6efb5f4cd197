//! The sections of the front end: ORB extraction, measured depth, map initialisation,
//! tracking, and the visibility rules its local-map search shares with the back end's
//! projection searches.

use ferroslam_features::extractor::{FastThresholds, EDGE_PX};
use ferroslam_features::OrbConfig;

use super::Sensor;
use crate::error::SlamError;

/// Shorter side of the coarsest pyramid level, pixels: room for a keypoint with its
/// descriptor's border on both sides.
pub const MIN_LEVEL_SIDE_PX: usize = 2 * EDGE_PX + 1;

/// ORB keypoints per image column of the default budget. ORB-SLAM's settings keep about
/// this density across cameras: 1000 features at 640 px wide (TUM), 1200 at 752 (EuRoC),
/// 2000 at 1241 (KITTI). Wider images see more of the scene, and far, slow-moving features
/// are what tracking at speed keeps; the image height does not change the choices.
const FEATURES_PER_COLUMN: f64 = 1000.0 / 640.0;
/// Bounds of the default budget: below 500 keypoints a stereo or RGB-D map cannot start
/// ([`InitializationConfig::min_keypoints`]); above 2000, ORB-SLAM's largest setting,
/// extraction and matching time grow faster than tracking gains.
const DEFAULT_FEATURES_RANGE: (usize, usize) = (500, 2000);

/// The default ORB budget for images `width_px` wide: [`FEATURES_PER_COLUMN`] per column,
/// rounded to a hundred, within [`DEFAULT_FEATURES_RANGE`] (640 px: 1000, 752: 1200,
/// 1241: 1900).
pub(super) fn default_n_features(width_px: u32) -> usize {
    let n = (f64::from(width_px) * FEATURES_PER_COLUMN / 100.0).round() as usize * 100;
    n.clamp(DEFAULT_FEATURES_RANGE.0, DEFAULT_FEATURES_RANGE.1)
}

/// ORB extraction: budget, FAST thresholds and scale pyramid (ORB-SLAM's `ORBextractor`
/// settings). The defaults are the extractor's own ([`OrbConfig::default`], in the features
/// crate) but for the budget, which the preset sizes to the image ([`Self::for_width`]);
/// [`Self::orb`] is the extractor's configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtractorConfig {
    /// ORB keypoints extracted per image (ORB-SLAM `nFeatures`; MATLAB `MaxNumPoints`); the
    /// preset follows the image width, see [`Self::for_width`].
    pub n_features: usize,
    /// FAST threshold tried first in every cell of the extractor's grid, intensity levels
    /// (ORB-SLAM `iniThFAST`).
    pub ini_fast: u8,
    /// FAST threshold of the cells where `ini_fast` finds no corner, intensity levels
    /// (ORB-SLAM `minThFAST`).
    pub min_fast: u8,
    /// Scale between ORB pyramid levels (ORB-SLAM `scaleFactor`).
    pub scale_factor: f64,
    /// Number of ORB pyramid levels (ORB-SLAM `nLevels`).
    pub n_levels: usize,
}

impl ExtractorConfig {
    /// The extractor's defaults ([`OrbConfig::default`]: ORB-SLAM's TUM settings) with the
    /// budget of images `width_px` wide: 1000 keypoints per 640 columns, rounded to a
    /// hundred, within 500..=2000 (640 px: 1000, 752: 1200, 1241: 1900).
    pub fn for_width(width_px: u32) -> Self {
        let orb = OrbConfig::default();
        Self {
            n_features: default_n_features(width_px),
            ini_fast: orb.fast.initial,
            min_fast: orb.fast.min,
            scale_factor: orb.scale_factor,
            n_levels: orb.n_levels,
        }
    }

    /// The extractor's configuration (`ferroslam_features::OrbExtractor::new`).
    pub fn orb(&self) -> OrbConfig {
        OrbConfig {
            n_features: self.n_features,
            scale_factor: self.scale_factor,
            n_levels: self.n_levels,
            fast: FastThresholds {
                initial: self.ini_fast,
                min: self.min_fast,
            },
        }
    }

    /// Checks that every pyramid level of a `width_px` x `height_px` image keeps room for
    /// keypoints: a keypoint with its descriptor's border on both sides (`MIN_LEVEL_SIDE_PX`,
    /// pixels) on its shorter side. A pyramid too deep for the image
    /// (`scale_factor` 2 with 12 levels shrinks 640x480 to under a pixel) would fail inside
    /// the extractor at the first frame.
    pub fn check_pyramid(&self, width_px: u32, height_px: u32) -> Result<(), SlamError> {
        let side = f64::from(width_px.min(height_px));
        let coarsest = side / self.scale_factor.powi(self.n_levels as i32 - 1);
        if coarsest >= MIN_LEVEL_SIDE_PX as f64 {
            return Ok(());
        }
        let fitting = if side < MIN_LEVEL_SIDE_PX as f64 {
            0
        } else {
            ((side / MIN_LEVEL_SIDE_PX as f64).ln() / self.scale_factor.ln()).floor() as usize + 1
        };
        Err(SlamError::InvalidConfig(format!(
            "extractor.n_levels = {} with scale_factor {} shrinks the \
             {width_px}x{height_px} images to {coarsest:.1} px on the shorter side at the \
             coarsest level; levels need at least {MIN_LEVEL_SIDE_PX} px (keypoints keep \
             {EDGE_PX} px from the border): at most {fitting} levels fit",
            self.n_levels, self.scale_factor
        )))
    }
}

/// Measured depth (stereo disparity or a depth camera): which depths count, and which are
/// close enough to trust from one view (ORB-SLAM's close/far rule).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthConfig {
    /// Stereo baseline times fx, metres * pixels; with RGB-D, that of the virtual right camera
    /// (ORB-SLAM `Camera.bf`; 40 for the TUM RGB-D cameras). The bindings set a stereo rig's
    /// from its baseline.
    pub bf: f64,
    /// Points closer than this many baselines are "close": their measured depth is trusted
    /// (ORB-SLAM `ThDepth`: 40).
    pub depth_threshold: f64,
    /// `(min, max)` valid measured depth, metres; other depths count as missing. `max` may be
    /// infinite.
    pub depth_range: (f64, f64),
    /// Whether an unrectified stereo pair is matched at every frame (depth for tracking, as
    /// rectified stereo) or only at the frames that become keyframes (and until the map
    /// starts): then the two cameras meet only where a keyframe's keypoints are triangulated
    /// across them, and tracking sees the first camera alone.
    pub match_pair_every_frame: bool,
}

impl DepthConfig {
    /// ORB-SLAM's TUM values (`bf` 40, `ThDepth` 40); depth within (0.1, 8.0) m for RGB-D
    /// (a structured-light camera's working range), unbounded for stereo (the disparity
    /// search bounds it).
    pub fn for_sensor(sensor: Sensor) -> Self {
        Self {
            bf: 40.0,
            depth_threshold: 40.0,
            depth_range: if sensor == Sensor::Stereo {
                (0.0, f64::INFINITY)
            } else {
                (0.1, 8.0)
            },
            match_pair_every_frame: true,
        }
    }

    /// Depth below which a point is close enough to trust its measured depth, metres.
    pub fn close_depth_m(&self, fx: f64) -> f64 {
        self.bf * self.depth_threshold / fx
    }
}

/// Starting a map: from the first frame with enough depth (stereo, RGB-D), or from a
/// monocular two-view pair (ORB-SLAM `StereoInitialization`, `MonocularInitialization`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InitializationConfig {
    /// Keypoints a stereo or RGB-D frame needs to start the map (ORB-SLAM: more than 500); of
    /// them, those with depth become its points.
    pub min_keypoints: usize,
    /// Of those, keypoints with depth the first keyframe needs: as many points as a
    /// monocular initial map needs (`mono_min_points`); fewer cannot be tracked (a pair whose
    /// right image is the left one has none).
    pub min_depth_points: usize,
    /// Keypoints (more than this) a frame needs to serve in a monocular initialisation pair
    /// (ORB-SLAM: 100).
    pub mono_min_keypoints: usize,
    /// Matches a monocular pair needs; with fewer the reference frame is replaced (ORB-SLAM:
    /// 100).
    pub mono_min_matches: usize,
    /// Half-side of the window around a reference feature's last match where it is
    /// searched, pixels (ORB-SLAM `SearchForInitialization`: 100).
    pub mono_window_px: f64,
    /// Map points the second keyframe must keep after the initial bundle adjustment
    /// (ORB-SLAM: 100).
    pub mono_min_points: usize,
    /// Ratio test of the pair's window search, best over second-best descriptor distance
    /// (ORB-SLAM `SearchForInitialization`: 0.9): loose, as the window already filters.
    pub mono_nn_ratio: f32,
}

impl Default for InitializationConfig {
    fn default() -> Self {
        Self {
            min_keypoints: 500,
            min_depth_points: 100,
            mono_min_keypoints: 100,
            mono_min_matches: 100,
            mono_window_px: 100.0,
            mono_min_points: 100,
            mono_nn_ratio: 0.9,
        }
    }
}

/// Which map points a projection search looks for in an image (ORB-SLAM
/// `Frame::isInFrustum` and the same tests in `ORBmatcher::Fuse` and
/// `SearchByProjection`): tracking's local-map search, point fusion and the loop's final
/// projection share these rules.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VisibilityConfig {
    /// Least cosine between a point's mean viewing direction and the ray from the camera
    /// for it to be searched (ORB-SLAM: 0.5, 60 deg): its descriptor, taken from views near
    /// the mean direction, rarely matches from further aside.
    pub min_view_cos: f64,
    /// A point is searched no closer than this share of the nearest distance its
    /// observations' scales cover (ORB-SLAM `GetMinDistanceInvariance`: 0.8), a margin for
    /// the scale's quantisation.
    pub min_distance_factor: f64,
    /// A point is searched no farther than this multiple of the farthest distance its
    /// observations' scales cover (ORB-SLAM `GetMaxDistanceInvariance`: 1.2).
    pub max_distance_factor: f64,
}

impl VisibilityConfig {
    /// Whether a point `dist` from the camera lies within `(min, max)`, the distances its
    /// observations' scales cover, widened by the two factors (the same unit throughout).
    pub fn in_scale_range(&self, dist: f64, (min, max): (f64, f64)) -> bool {
        !(dist < self.min_distance_factor * min || dist > self.max_distance_factor * max)
    }
}

impl Default for VisibilityConfig {
    fn default() -> Self {
        Self {
            min_view_cos: 0.5,
            min_distance_factor: 0.8,
            max_distance_factor: 1.2,
        }
    }
}

/// Tracking: matching thresholds, the keyframe decision and what happens when tracking is
/// lost (ORB-SLAM `Tracking`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackingConfig {
    /// `(lower, upper)` tracked-feature limits: below `lower` tracking is lost; below `upper`
    /// the frame becomes a keyframe (MATLAB `TrackFeatureRange`; monocular, only when it also
    /// tracks under `reference_ratio` of its reference keyframe's points); above it, only
    /// ORB-SLAM's rules or `skip_max_frames` make one. See [`Self::for_sensor`].
    pub track_feature_range: (usize, usize),
    /// ORB-SLAM's keyframe rule: a frame tracking fewer than this share of its reference
    /// keyframe's points is a keyframe when mapping can take it (ORB-SLAM `thRefRatio`: 0.75
    /// with depth, 0.9 monocular).
    pub reference_ratio: f64,
    /// `reference_ratio` while the map has a single keyframe (ORB-SLAM: 0.4).
    pub first_keyframes_reference_ratio: f64,
    /// Observations (one with measured depth counts 2, as for
    /// `mapping.min_point_observations`) a reference keyframe's point needs to count among
    /// the points `reference_ratio` compares with (ORB-SLAM `nMinObs`: 3): younger points may
    /// still be culled.
    pub reference_min_observations: usize,
    /// `reference_min_observations` while the map has at most two keyframes (ORB-SLAM: 2): a
    /// monocular point has at most two observations then.
    pub young_map_reference_min_observations: usize,
    /// With depth, tracking is weak, and a keyframe is made even while mapping is busy, below
    /// this share of the reference keyframe's points (ORB-SLAM `c1c`: 0.25).
    pub weak_tracking_share: f64,
    /// With depth, close structure counts as left untracked (a keyframe is needed) when fewer
    /// than this many close points are tracked and more than `close_untracked_min` are not
    /// (ORB-SLAM `bNeedToInsertClose`: 100).
    pub close_tracked_max: usize,
    /// See `close_tracked_max` (ORB-SLAM: 70).
    pub close_untracked_min: usize,
    /// A keyframe needs more inliers than this, whatever rule asks for it (ORB-SLAM `c2`: 15);
    /// the same holds for the keyframes the inertial alignment asks for.
    pub min_keyframe_inliers: usize,
    /// A monocular keyframe asked for while mapping is busy may wait for the next frame
    /// only if tracking keeps at least this many times the lower `track_feature_range` limit
    /// (below which it is lost): a deferral with weak tracking lost KITTI 06 (ORB-SLAM
    /// refuses the keyframe instead).
    pub deferral_inliers_factor: usize,
    /// Maximum number of frames between two keyframes (MATLAB `SkipMaxFrames`; ORB-SLAM
    /// `mMaxFrames`, one second of frames: 30).
    pub skip_max_frames: usize,
    /// Frames after a relocalisation during which the pose counts as unconfirmed (it needs
    /// `relocalised_min_inliers`) and, once the map holds more keyframes than this, no
    /// keyframe is made (ORB-SLAM reuses `mMaxFrames`, one second of frames: 30).
    pub post_relocalisation_frames: usize,
    /// Inliers an unconfirmed relocalised pose needs against the local map (ORB-SLAM: 50).
    pub relocalised_min_inliers: usize,
    /// Matches the motion-model search needs before pose optimisation (ORB-SLAM: 20).
    pub min_search_matches: usize,
    /// Descriptor matches a candidate keyframe needs before PnP-RANSAC, in reference-keyframe
    /// tracking and relocalisation (ORB-SLAM: 15).
    pub min_reference_matches: usize,
    /// Motion-model inliers above which the pose is trusted without a PnP cross-check against
    /// the reference keyframe: a weak motion-model pose under fast rotation is often wrong
    /// (ORB-SLAM has no cross-check).
    pub strong_pose_inliers: usize,
    /// Below this many motion-model matches the search is repeated with twice the radius
    /// (ORB-SLAM retries only below `min_search_matches`; here a weak search is widened too,
    /// as its count decides the PnP cross-check, `strong_pose_inliers`).
    pub retry_search_matches: usize,
    /// Inliers a pose needs after motion-only BA, before the local-map refinement (ORB-SLAM:
    /// 10).
    pub min_pose_inliers: usize,
    /// Local keyframes kept for local-map tracking (ORB-SLAM: 80).
    pub max_local_keyframes: usize,
    /// With depth, a frame whose inliers are at least this share of points already observed
    /// by `redundant_view_keyframes` keyframes views mapped structure: idle mapping alone does
    /// not make it a keyframe (revisits would add one every frame or two).
    pub redundant_view_share: f64,
    /// Observing keyframes that make a point "mapped structure" for `redundant_view_share`
    /// (three, as keyframe culling's `mapping.redundant_observations`).
    pub redundant_view_keyframes: usize,
    /// How long a lost map keeps trying to relocalise before the atlas keeps it and a new map
    /// starts, seconds (monocular, or with a vocabulary, which can find it again).
    pub relocalisation_window_s: f64,
    /// Frames without a pose (lost, or before a map starts) kept to be tracked backwards
    /// once a later frame is tracked, which poses as many of them as it can follow; 0 keeps
    /// none. Enough for a second at 30 fps: longer gaps are rarely bridged by tracking.
    pub gap_frames: usize,
    /// A lost map with at most this many keyframes is discarded, not kept (ORB-SLAM: 5).
    pub min_keyframes_to_keep: usize,
    /// Window of the motion-model search around the last frame's projected points, pixels
    /// at level 0 (ORB-SLAM `TrackWithMotionModel`: 7 stereo, 15 otherwise; 15 for every
    /// sensor here, as the PnP cross-check catches its mismatches).
    pub motion_search_radius_px: f64,
    /// Window of the motion-model search when it is repeated (`retry_search_matches`),
    /// pixels at level 0: twice `motion_search_radius_px` (ORB-SLAM doubles it).
    pub motion_retry_radius_px: f64,
    /// Window of the local-map search, in units of the viewing-angle radius
    /// (`frontal_radius`, `oblique_radius`), pixels at the point's level (ORB-SLAM: 3 with
    /// RGB-D, the widest of its usual values).
    pub local_search_width: f64,
    /// `local_search_width` right after a relocalisation, for `relocalised_wide_search_frames`
    /// frames (ORB-SLAM: 5).
    pub relocalised_search_width: f64,
    /// `local_search_width` after an IMU prediction: the predicted pose is less sure than a
    /// tracked one (ORB-SLAM3 searches 6 before the inertial BA, 2 after).
    pub imu_prediction_search_width: f64,
    /// Frames after a relocalisation searched with `relocalised_search_width` (ORB-SLAM: 2).
    pub relocalised_wide_search_frames: usize,
    /// Rolling shutter: how far (standard deviation, radians per second) a frame's angular
    /// velocity may differ from the motion model's average over the last frame interval.
    /// A hand-held camera changes its rate by a few rad/s^2, so about 0.1 rad/s in 33 ms;
    /// twice that leaves the rows room to pull it where the model lags.
    pub velocity_prior_sigma_rad_s: f64,
    /// The same for the linear velocity, metres per second (hand-held: about 1 m/s^2).
    pub velocity_prior_sigma_m_s: f64,
    /// Ratio test of the bag-of-words matching against reference and relocalisation
    /// candidates, best over second-best descriptor distance (ORB-SLAM `SearchByBoW`: 0.7
    /// reference, 0.75 relocalisation; 0.75 for both).
    pub reference_nn_ratio: f32,
    /// Ratio test of the local-map search (ORB-SLAM `SearchLocalPoints`: 0.8).
    pub local_search_nn_ratio: f32,
    /// Best covisible keyframes of each local keyframe, and of the reference keyframe, that
    /// join the local map and the reference-tracking candidates (ORB-SLAM: 10).
    pub neighbourhood_covisibles: usize,
    /// Cosine above which a point is seen from nearly its mean direction, and searched in the
    /// narrower `frontal_radius` (ORB-SLAM `RadiusByViewingCos`: 0.998, 3.6 deg).
    pub frontal_view_cos: f64,
    /// Search radius, in units of the search width, of points seen frontally (ORB-SLAM: 2.5).
    pub frontal_radius: f64,
    /// Search radius, in units of the search width, of the other points (ORB-SLAM: 4).
    pub oblique_radius: f64,
}

impl TrackingConfig {
    /// The preset of `sensor`: MATLAB's `TrackFeatureRange` (30, 100), except with an RGB-D
    /// sensor (30, 250), and ORB-SLAM's thresholds.
    ///
    /// With depth, a new keyframe's own points count for ORB-SLAM's reference ratio only once
    /// another keyframe sees them, so the ratio rule fires near the points tracked when the
    /// keyframe was made: with the upper limit at 100, keyframes came as tracking fell to
    /// about 100 points, and those poses (fast rotations) erred by centimetres frame to
    /// frame; 250 makes keyframes earlier and more often. Stereo keeps 100: on KITTI a
    /// keyframe is made almost every frame already, and a higher limit did not help.
    pub fn for_sensor(sensor: Sensor) -> Self {
        Self {
            track_feature_range: if sensor == Sensor::Rgbd {
                (30, 250)
            } else {
                (30, 100)
            },
            reference_ratio: if sensor.has_depth() { 0.75 } else { 0.9 },
            first_keyframes_reference_ratio: 0.4,
            reference_min_observations: 3,
            young_map_reference_min_observations: 2,
            weak_tracking_share: 0.25,
            close_tracked_max: 100,
            close_untracked_min: 70,
            min_keyframe_inliers: 15,
            deferral_inliers_factor: 2,
            skip_max_frames: 30,
            post_relocalisation_frames: 30,
            relocalised_min_inliers: 50,
            min_search_matches: 20,
            min_reference_matches: 15,
            strong_pose_inliers: 50,
            retry_search_matches: 100,
            min_pose_inliers: 10,
            max_local_keyframes: 80,
            redundant_view_share: 0.8,
            redundant_view_keyframes: 3,
            relocalisation_window_s: 1.0,
            gap_frames: 30,
            min_keyframes_to_keep: 5,
            motion_search_radius_px: 15.0,
            motion_retry_radius_px: 30.0,
            local_search_width: 3.0,
            relocalised_search_width: 5.0,
            imu_prediction_search_width: 5.0,
            relocalised_wide_search_frames: 2,
            velocity_prior_sigma_rad_s: 0.2,
            velocity_prior_sigma_m_s: 0.05,
            reference_nn_ratio: 0.75,
            local_search_nn_ratio: 0.8,
            neighbourhood_covisibles: 10,
            frontal_view_cos: 0.998,
            frontal_radius: 2.5,
            oblique_radius: 4.0,
        }
    }
}
