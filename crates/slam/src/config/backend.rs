//! The sections of the back end: local mapping, place recognition, loop closing and the
//! inertial stages.

use super::Sensor;

/// Local mapping (ORB-SLAM `LocalMapping`): triangulation, culling of points and keyframes,
/// local bundle adjustment, and how far tracking may run ahead of it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MappingConfig {
    /// Covisible keyframes searched for new points and fusion (ORB-SLAM: 10 with depth, 20
    /// monocular, where triangulation is the only source of points).
    pub triangulation_neighbours: usize,
    /// Covisible keyframes searched for new points when mapping is hurried (frames come
    /// faster than it processed the last keyframe). With depth, the best 3: a keyframe's close
    /// points come from its own depth, and the further neighbours delay local BA and the next
    /// keyframe. Monocular maps search them all (`triangulation_neighbours`): there the
    /// further neighbours' wider baselines hold the scale.
    pub hurried_triangulation_neighbours: usize,
    /// Covisible keyframes a keyframe with depth always searches for new points. Past them,
    /// its search stops after the first neighbour that brings fewer than
    /// `min_points_to_search_on`: neighbours come by decreasing covisibility, the further ones
    /// bring a few points each (a keyframe's close points come from its own depth), and each
    /// search costs about as much as the best's. Monocular maps search on (wider baselines
    /// hold the scale).
    pub always_searched_with_depth: usize,
    /// See `always_searched_with_depth`; the result barely depends on it (3 to 20 tried).
    pub min_points_to_search_on: usize,
    /// Least ray parallax for triangulating a feature without close depth, degrees.
    /// Monocular maps use ORB-SLAM's 1.15 deg (nothing else makes points); with a depth
    /// sensor, points that poorly conditioned drifted the metric scale: 5 deg.
    pub min_ray_parallax_deg: f64,
    /// Observations a point needs to survive its first keyframes (stereo/RGB-D count 2 each,
    /// so ORB-SLAM asks for more than 3 with depth and more than 2 monocular).
    pub min_point_observations: usize,
    /// A recent point found in less than this share of the frames that should have seen it
    /// dies (ORB-SLAM `MapPointCulling`: 0.25).
    pub min_found_ratio: f64,
    /// Observations by other keyframes, at the same, a finer or a barely coarser scale
    /// (`redundant_level_margin`), that make a keyframe's point redundant (ORB-SLAM
    /// `KeyFrameCulling`: 3).
    pub redundant_observations: usize,
    /// A keyframe with more than this share of redundant close points is culled (ORB-SLAM
    /// `KeyFrameCulling`: 0.9).
    pub redundant_keyframe_share: f64,
    /// Largest distance of a point from its reference keyframe after bundle adjustment, in
    /// that keyframe's scene median depths. Points seen along nearly parallel rays (a
    /// monocular pair at a short baseline, a static stereo rig's points seen without
    /// disparity) are barely constrained in depth, and BA can slide them out to hundreds of
    /// times the scene. The bound keeps the farthest points a stereo rig measures (within
    /// `bf / MIN_DISPARITY_PX`; on KITTI, well inside 40 median depths).
    pub max_scene_depth_ratio: f64,
    /// Keyframes the mapping thread may have queued or in progress when tracking wants
    /// another; tracking then waits for them, or, monocular, may leave the keyframe to the
    /// next frame. ORB-SLAM instead refuses monocular keyframes while mapping is busy and
    /// queues up to 3 with depth, which loses tracking when frames come faster than real time.
    pub max_queued_keyframes: usize,
    /// With the mapping thread, tracking first waits for the mapping work in flight when the
    /// frame before tracked fewer inliers than this (0: never; 0 with depth). A monocular map
    /// grows only by local mapping's triangulation: weak tracking that runs ahead of it,
    /// on a map without the last keyframe's new points, lost the map where inline mapping
    /// kept it, at places that moved with the threads' timing (docs/benchmarks.md, "Weak
    /// monocular tracking waits for mapping"). 200: twice the monocular upper limit of
    /// `tracking.track_feature_range`, below which tracking already asks for keyframes.
    pub monocular_wait_inliers: usize,
    /// Keyframes after its first after which a recent point with too few observations
    /// (`min_point_observations`) dies (ORB-SLAM `MapPointCulling`: 2).
    pub recent_point_check_age: u32,
    /// Keyframes after its first after which a recent point is proven and no longer culled
    /// (ORB-SLAM `MapPointCulling`: 3).
    pub recent_point_proven_age: u32,
    /// Best covisible keyframes of each first-ring neighbour that also take part in point
    /// fusion, the second ring (ORB-SLAM `SearchInNeighbors`: 5).
    pub fusion_second_neighbours: usize,
    /// Window of the fusion of a new keyframe's points with its neighbours', pixels at level
    /// 0 (ORB-SLAM `ORBmatcher::Fuse`: 3; the loop's fusion has `loop_closing.fuse_radius_px`).
    pub fuse_radius_px: f64,
    /// Pyramid levels coarser than the culled keyframe's own at which another keyframe's
    /// observation still counts towards a point's redundancy (ORB-SLAM `KeyFrameCulling`: 1).
    pub redundant_level_margin: u8,
    /// Scale consistency of a new point: the ratio of its distances to the two cameras may
    /// differ from that of the features' scales by at most this many pyramid steps
    /// (ORB-SLAM `CreateNewMapPoints`: 1.5).
    pub scale_consistency_factor: f64,
}

impl MappingConfig {
    /// The preset of `sensor`: the triangulation and culling rules differ with and without
    /// depth (see each field).
    pub fn for_sensor(sensor: Sensor) -> Self {
        let depth = sensor.has_depth();
        let triangulation_neighbours = if depth { 10 } else { 20 };
        Self {
            triangulation_neighbours,
            hurried_triangulation_neighbours: if depth { 3 } else { triangulation_neighbours },
            always_searched_with_depth: 2,
            min_points_to_search_on: 5,
            min_ray_parallax_deg: if depth { 5.0 } else { 1.15 },
            min_point_observations: if depth { 3 } else { 2 },
            min_found_ratio: 0.25,
            redundant_observations: 3,
            redundant_keyframe_share: 0.9,
            max_scene_depth_ratio: 40.0,
            max_queued_keyframes: 1,
            monocular_wait_inliers: if depth { 0 } else { 200 },
            recent_point_check_age: 2,
            recent_point_proven_age: 3,
            fusion_second_neighbours: 5,
            fuse_radius_px: 3.0,
            redundant_level_margin: 1,
            scale_consistency_factor: 1.5,
        }
    }

    /// Least baseline of a monocular keyframe pair, as a fraction of the scene's median
    /// depth, for it to triangulate: the baseline that gives a point at that depth the least
    /// ray parallax (tan 1.15 deg, 2.0 %). ORB-SLAM takes 1 %; below tan(parallax), only
    /// points closer than the median, or whose rays are that far off through pose error (a
    /// rotation error of a degree between keyframes tracked through motion blur), pass the
    /// parallax check, and the latter are mapped too close: the map, and the translations
    /// tracked against it, shrink.
    pub fn min_baseline_depth_ratio(&self) -> f64 {
        self.min_ray_parallax_deg.to_radians().tan()
    }
}

/// The bag-of-words keyframe index (ORB-SLAM `KeyFrameDatabase`), queried for relocalisation
/// and loop candidates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaceRecognitionConfig {
    /// Levels above the vocabulary's leaves at which feature vectors group features for
    /// bag-of-words matching (ORB-SLAM: 4).
    pub feature_levels_up: u32,
    /// Covisible keyframes whose scores a candidate accumulates (ORB-SLAM: 10).
    pub group_size: usize,
    /// Keyframes retrieved from the database, best-scoring first, before grouping (ORB-SLAM
    /// keeps every keyframe sharing at least 80 % of the most words any shares; a fixed count
    /// bounds the cost of a query).
    pub max_retrieved: usize,
    /// Of the retrieved keyframes, those sharing more than this share of the most words any
    /// shares are scored (ORB-SLAM `DetectLoopCandidates`: 0.8).
    pub common_words_share: f64,
    /// Candidates whose group score reaches this share of the best group's are returned
    /// (ORB-SLAM: 0.75).
    pub group_score_ratio: f64,
}

impl Default for PlaceRecognitionConfig {
    fn default() -> Self {
        Self {
            feature_levels_up: 4,
            group_size: 10,
            max_retrieved: 50,
            common_words_share: 0.8,
            group_score_ratio: 0.75,
        }
    }
}

/// Loop closing (ORB-SLAM `LoopClosing`): detection, Sim(3) verification, correction and the
/// essential graph.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopClosingConfig {
    /// Detect and close loops (needs a vocabulary, see `SlamSystem::set_vocabulary`).
    pub loop_closure: bool,
    /// Minimum matched map points between a keyframe and a loop candidate for the loop to be
    /// accepted after Sim(3) verification (MATLAB `LoopClosureThreshold`; ORB-SLAM: 40). At
    /// least `min_stage_matches`, which the verification needs before its final count.
    pub loop_closure_threshold: usize,
    /// Consecutive keyframes whose candidate groups must overlap before a candidate is
    /// verified (ORB-SLAM `mnCovisibilityConsistencyTh`: 3).
    pub consistency: usize,
    /// Keyframes that must pass after a loop, and map size, before detection runs (ORB-SLAM:
    /// 10).
    pub min_keyframes_between: usize,
    /// Matches needed at each verification stage before the final count (ORB-SLAM: 20).
    pub min_stage_matches: usize,
    /// Huber threshold (chi2) of the Sim(3) refinement (ORB-SLAM `OptimizeSim3`: 10).
    pub sim3_huber_chi2: f64,
    /// Window of the Sim(3)-guided search, pixels at level 0 (ORB-SLAM: 7.5).
    pub guided_radius_px: f64,
    /// Window of the final projection of the loop's points, pixels at level 0 (ORB-SLAM: 10).
    pub projection_radius_px: f64,
    /// Window of the fusion of the loop's points into the corrected neighbourhood, pixels at
    /// level 0 (ORB-SLAM `SearchAndFuse`: 4).
    pub fuse_radius_px: f64,
    /// Covisibility weight, shared points, that makes an edge part of the essential graph
    /// (ORB-SLAM: 100).
    pub strong_covisibility: usize,
    /// Levenberg-Marquardt iterations of the essential-graph optimisation (ORB-SLAM: 20).
    pub essential_graph_iterations: usize,
    /// Ratio test of the bag-of-words matching of a loop candidate, best over second-best
    /// descriptor distance (ORB-SLAM `ComputeSim3`: 0.75).
    pub bow_nn_ratio: f32,
    /// Probability that the Sim(3) RANSAC draws an all-inlier sample (ORB-SLAM: 0.99).
    pub sim3_ransac_probability: f64,
    /// Most Sim(3) RANSAC iterations per candidate (ORB-SLAM: 300).
    pub sim3_ransac_iterations: usize,
    /// Best covisible keyframes of a merge candidate matched with it by bag of words
    /// (ORB-SLAM3 `DetectCommonRegionsFromBoW`'s `nNumCovisibles`: 10).
    pub merge_window: usize,
    /// Inliers the Sim(3) RANSAC of a merge needs (ORB-SLAM3 `nBoWInliers`: 15). It only
    /// proposes a similarity, which projection then checks: on fr1/rpy monocular, hypotheses
    /// of 6-10 inliers among 50 pooled matches project to 58-97 matches, and 15 are never
    /// reached.
    pub merge_ransac_inliers: usize,
    /// Inliers of a merge's refined Sim(3). Below `min_stage_matches`: the refinement sees
    /// only keypoints of the current keyframe with a map point, which a young monocular map
    /// has few of (24 of 83 projection matches on fr1/rpy).
    pub merge_refined_inliers: usize,
    /// Matched points a merge needs after the final projection, the bar that makes up for
    /// the lower stages (ORB-SLAM3 `nProjOptMatches`: 80).
    pub merge_threshold: usize,
    /// Largest scale, or inverse scale, of a merge's similarity: monocular maps of one camera
    /// start at a median depth of 1 and differ by a few times, a diverged one by orders of
    /// magnitude.
    pub max_merge_scale: f64,
}

impl Default for LoopClosingConfig {
    fn default() -> Self {
        Self {
            loop_closure: true,
            loop_closure_threshold: 40,
            consistency: 3,
            min_keyframes_between: 10,
            min_stage_matches: 20,
            sim3_huber_chi2: 10.0,
            guided_radius_px: 7.5,
            projection_radius_px: 10.0,
            fuse_radius_px: 4.0,
            strong_covisibility: 100,
            essential_graph_iterations: 20,
            bow_nn_ratio: 0.75,
            sim3_ransac_probability: 0.99,
            sim3_ransac_iterations: 300,
            merge_window: 10,
            merge_ransac_inliers: 6,
            merge_refined_inliers: 15,
            merge_threshold: 80,
            max_merge_scale: 20.0,
        }
    }
}

/// The inertial stages once an IMU is set (`SlamSystem::set_imu`, whose `InertialConfig`
/// holds the sensor's noise, the camera-IMU pose and MATLAB's alignment knobs): when the
/// alignment runs, what makes it plausible, local inertial BA and IMU-only prediction.
#[derive(Clone, Debug, PartialEq)]
pub struct InertialTuning {
    /// Before the first alignment, a keyframe at least this often, seconds (ORB-SLAM3: 0.25):
    /// the alignment needs poses spread over time, also while the camera barely moves.
    pub init_keyframe_interval_s: f64,
    /// Spans of keyframe time since the first alignment, seconds, increasing, after which the
    /// alignment is re-run over the newest keyframes of that span (ORB-SLAM3 re-initialises at
    /// about 5 s and 15 s).
    pub refinement_spans_s: Vec<f64>,
    /// Keyframes of the local inertial BA window, the fixed oldest one included (ORB-SLAM3
    /// optimises 10).
    pub window_keyframes: usize,
    /// Largest gyro bias an alignment may find, rad/s (29 deg/s): MEMS gyro biases stay
    /// within a few deg/s (EuRoC's ADIS16448: 0.08 rad/s). Beyond, the readings do not
    /// describe the rotation vision sees: another unit (deg/s during slow motion), a
    /// constant, wrong axes.
    pub max_gyro_bias_rad_s: f64,
    /// Largest accelerometer bias an alignment may find, m/s^2 (MEMS: a few tenths).
    pub max_accel_bias_m_s2: f64,
    /// Largest keyframe speed an alignment may find, m/s (360 km/h): garbage IMU data
    /// (cm/s^2 that passed the unit checks, samples from another clock) "aligns" at hundreds
    /// of m/s.
    pub max_speed_m_s: f64,
    /// Time over which the velocity of an IMU-only stretch's anchor is measured, seconds:
    /// long enough that millimetre pose noise gives millimetres per second, short enough
    /// that the bias error stays small.
    pub velocity_baseline_s: f64,
    /// Longest IMU-only stretch, seconds, after which the frame is lost (ORB-SLAM3's
    /// `time_recently_lost`: 5).
    pub imu_only_max_s: f64,
    /// Uncertainty (1 sigma) of the anchor's velocity, m/s, which the preintegration's own
    /// covariance does not hold: keyframe velocities after the alignment are centimetres per
    /// second off. Without the anchor terms a prediction a second old claims millimetres and
    /// the few matches it is fused with cannot move it.
    pub anchor_sigma_velocity_m_s: f64,
    /// Uncertainty (1 sigma) of the anchor's accelerometer bias and gravity direction
    /// together, m/s^2 (a degree of gravity tilt is 0.17 m/s^2).
    pub anchor_sigma_accel_m_s2: f64,
    /// Uncertainty (1 sigma) of the anchor's gyro bias, rad/s: the error the alignment and
    /// local inertial BA leave in it.
    pub anchor_sigma_gyro_rad_s: f64,
}

impl Default for InertialTuning {
    fn default() -> Self {
        Self {
            init_keyframe_interval_s: 0.25,
            refinement_spans_s: vec![5.0, 15.0],
            window_keyframes: 11,
            max_gyro_bias_rad_s: 0.5,
            max_accel_bias_m_s2: 2.0,
            max_speed_m_s: 100.0,
            velocity_baseline_s: 0.5,
            imu_only_max_s: 5.0,
            anchor_sigma_velocity_m_s: 0.05,
            anchor_sigma_accel_m_s2: 0.1,
            anchor_sigma_gyro_rad_s: 0.002,
        }
    }
}
