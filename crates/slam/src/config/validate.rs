//! [`SlamConfig::validate`]: every field of every section, named `section.field` in the
//! error.

use super::{
    DepthConfig, ExtractorConfig, InertialTuning, InitializationConfig, LoopClosingConfig,
    MappingConfig, PlaceRecognitionConfig, SlamConfig, TrackingConfig,
};
use crate::error::SlamError;

/// The fields of one section, for messages that name `section.field`.
struct Section(&'static str);

impl Section {
    /// `InvalidConfig("section.field must ...")`.
    fn bad(&self, field: &str, rule: impl std::fmt::Display) -> SlamError {
        SlamError::InvalidConfig(format!("{}.{field} must {rule}", self.0))
    }

    /// A count of at least `min`.
    fn at_least(&self, field: &str, value: usize, min: usize) -> Result<(), SlamError> {
        if value >= min {
            Ok(())
        } else {
            Err(self.bad(field, format_args!("be >= {min}")))
        }
    }

    /// A finite number above 0.
    fn positive(&self, field: &str, value: f64) -> Result<(), SlamError> {
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(self.bad(field, format_args!("be a positive number, got {value}")))
        }
    }

    /// A number in `(0, max]`.
    fn fraction(&self, field: &str, value: f64, max: f64) -> Result<(), SlamError> {
        if value > 0.0 && value <= max {
            Ok(())
        } else {
            Err(self.bad(field, format_args!("be in (0, {max}], got {value}")))
        }
    }
}

impl SlamConfig {
    /// Checks every field of every section; the error names the first invalid one as
    /// `section.field`.
    pub fn validate(&self) -> Result<(), SlamError> {
        self.extractor.validate()?;
        self.depth.validate()?;
        self.initialization.validate()?;
        self.tracking.validate()?;
        self.mapping.validate()?;
        self.place_recognition.validate()?;
        self.loop_closing.validate()?;
        self.inertial.validate()
    }
}

impl ExtractorConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("extractor");
        s.at_least("n_features", self.n_features, 1)?;
        if !(0 < self.min_fast && self.min_fast <= self.ini_fast && self.ini_fast < 255) {
            return Err(s.bad(
                "ini_fast and extractor.min_fast",
                "satisfy 0 < min_fast <= ini_fast < 255",
            ));
        }
        if !(self.scale_factor.is_finite() && self.scale_factor > 1.0) {
            return Err(s.bad("scale_factor", "be > 1"));
        }
        if !(1..=32).contains(&self.n_levels) {
            return Err(s.bad("n_levels", "be in 1..=32"));
        }
        Ok(())
    }
}

impl DepthConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("depth");
        if !(self.bf.is_finite() && self.bf > 0.0) {
            return Err(s.bad("bf", "be a positive number (fx * baseline)"));
        }
        s.positive("depth_threshold", self.depth_threshold)?;
        let (dmin, dmax) = self.depth_range;
        if !(dmin.is_finite() && !dmax.is_nan() && 0.0 <= dmin && dmin < dmax) {
            return Err(s.bad("depth_range", "be (min, max) with 0 <= min < max"));
        }
        Ok(())
    }
}

impl InitializationConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("initialization");
        s.at_least("min_keypoints", self.min_keypoints, 1)?;
        s.at_least("min_depth_points", self.min_depth_points, 1)?;
        s.at_least("mono_min_keypoints", self.mono_min_keypoints, 1)?;
        // The essential and homography solvers need 8 matches.
        s.at_least("mono_min_matches", self.mono_min_matches, 8)?;
        s.positive("mono_window_px", self.mono_window_px)?;
        s.at_least("mono_min_points", self.mono_min_points, 1)
    }
}

impl TrackingConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("tracking");
        let (lo, hi) = self.track_feature_range;
        if lo == 0 || lo >= hi {
            return Err(s.bad(
                "track_feature_range",
                "be (lower, upper) with 0 < lower < upper",
            ));
        }
        s.at_least("skip_max_frames", self.skip_max_frames, 1)?;
        s.at_least(
            "post_relocalisation_frames",
            self.post_relocalisation_frames,
            1,
        )?;
        s.at_least("relocalised_min_inliers", self.relocalised_min_inliers, 1)?;
        s.at_least("min_search_matches", self.min_search_matches, 1)?;
        // PnP-RANSAC needs 4 correspondences.
        s.at_least("min_reference_matches", self.min_reference_matches, 4)?;
        s.at_least("strong_pose_inliers", self.strong_pose_inliers, 1)?;
        s.at_least("retry_search_matches", self.retry_search_matches, 1)?;
        s.at_least("min_pose_inliers", self.min_pose_inliers, 4)?;
        s.at_least("max_local_keyframes", self.max_local_keyframes, 1)?;
        s.fraction("redundant_view_share", self.redundant_view_share, 1.0)?;
        s.at_least("redundant_view_keyframes", self.redundant_view_keyframes, 1)?;
        s.positive("relocalisation_window_s", self.relocalisation_window_s)?;
        Ok(()) // min_keyframes_to_keep: any count (0 keeps every lost map)
    }
}

impl MappingConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("mapping");
        s.at_least("triangulation_neighbours", self.triangulation_neighbours, 1)?;
        s.at_least(
            "hurried_triangulation_neighbours",
            self.hurried_triangulation_neighbours,
            1,
        )?;
        s.at_least(
            "always_searched_with_depth",
            self.always_searched_with_depth,
            1,
        )?;
        // min_points_to_search_on: any count (0 searches every neighbour).
        if !(self.min_ray_parallax_deg > 0.0 && self.min_ray_parallax_deg < 90.0) {
            return Err(s.bad(
                "min_ray_parallax_deg",
                format_args!("be in (0, 90) degrees, got {}", self.min_ray_parallax_deg),
            ));
        }
        s.at_least("min_point_observations", self.min_point_observations, 1)?;
        s.at_least("redundant_observations", self.redundant_observations, 1)?;
        if !(self.max_scene_depth_ratio > 1.0) {
            return Err(s.bad(
                "max_scene_depth_ratio",
                format_args!("be > 1 (median depths), got {}", self.max_scene_depth_ratio),
            ));
        }
        s.at_least("max_queued_keyframes", self.max_queued_keyframes, 1)
    }
}

impl PlaceRecognitionConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("place_recognition");
        // feature_levels_up: any level (past the vocabulary's depth, features group at the root).
        s.at_least("group_size", self.group_size, 1)?;
        s.at_least("max_retrieved", self.max_retrieved, 1)
    }
}

impl LoopClosingConfig {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("loop_closing");
        // The Sim(3) RANSAC samples 3 correspondences.
        s.at_least("min_stage_matches", self.min_stage_matches, 3)?;
        // The verification needs `min_stage_matches` before its final count: a lower bound
        // would never apply.
        s.at_least(
            "loop_closure_threshold",
            self.loop_closure_threshold,
            self.min_stage_matches,
        )?;
        s.at_least("consistency", self.consistency, 1)?;
        s.positive("sim3_huber_chi2", self.sim3_huber_chi2)?;
        s.positive("guided_radius_px", self.guided_radius_px)?;
        s.positive("projection_radius_px", self.projection_radius_px)?;
        s.positive("fuse_radius_px", self.fuse_radius_px)?;
        s.at_least(
            "essential_graph_iterations",
            self.essential_graph_iterations,
            1,
        )
        // min_keyframes_between, strong_covisibility: any count.
    }
}

impl InertialTuning {
    fn validate(&self) -> Result<(), SlamError> {
        let s = Section("inertial");
        s.positive("init_keyframe_interval_s", self.init_keyframe_interval_s)?;
        let spans = &self.refinement_spans_s;
        let increasing = spans.windows(2).all(|w| w[0] < w[1]);
        if !(increasing && spans.iter().all(|t| t.is_finite() && *t > 0.0)) {
            return Err(s.bad(
                "refinement_spans_s",
                format_args!("be positive seconds in increasing order, got {spans:?}"),
            ));
        }
        s.at_least("window_keyframes", self.window_keyframes, 2)?;
        s.positive("max_gyro_bias_rad_s", self.max_gyro_bias_rad_s)?;
        s.positive("max_accel_bias_m_s2", self.max_accel_bias_m_s2)?;
        s.positive("max_speed_m_s", self.max_speed_m_s)?;
        s.positive("velocity_baseline_s", self.velocity_baseline_s)?;
        s.positive("imu_only_max_s", self.imu_only_max_s)?;
        s.positive("anchor_sigma_velocity_m_s", self.anchor_sigma_velocity_m_s)?;
        s.positive("anchor_sigma_accel_m_s2", self.anchor_sigma_accel_m_s2)?;
        s.positive("anchor_sigma_gyro_rad_s", self.anchor_sigma_gyro_rad_s)
    }
}
