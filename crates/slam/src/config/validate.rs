//! [`SlamConfig::validate`]: every field of every section, named `section.field` in the
//! error.

use super::SlamConfig;
use crate::error::SlamError;

/// The fields of one section, for messages that name `section.field`.
struct Section(&'static str);

impl Section {
    /// `InvalidConfig("section.field must ...")`.
    fn bad(&self, field: &str, rule: impl std::fmt::Display) -> SlamError {
        SlamError::InvalidConfig(format!("{}.{field} must {rule}", self.0))
    }

    /// A count, or a number other than NaN, of at least `min`.
    fn at_least<T>(&self, field: &str, value: T, min: T) -> Result<(), SlamError>
    where
        T: PartialOrd + std::fmt::Display,
    {
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

    /// A number in `(0, max]` (`f64` or `f32`).
    fn fraction(&self, field: &str, value: impl Into<f64>, max: f64) -> Result<(), SlamError> {
        let value = value.into();
        if value > 0.0 && value <= max {
            Ok(())
        } else {
            Err(self.bad(field, format_args!("be in (0, {max}], got {value}")))
        }
    }
}

/// `check!(s, >= min, self.a, self.b)` (counts, or numbers at least another), `check!(s, > 0, self.a)` (finite positive
/// numbers) or `check!(s, <= max, self.a)` (numbers in `(0, max]`): each field named once,
/// the error naming it `section.field`.
macro_rules! check {
    ($s:ident, >= $min:expr, $($c:ident . $f:ident),+ $(,)?) => {
        $($s.at_least(stringify!($f), $c.$f, $min)?;)+
    };
    ($s:ident, > 0, $($c:ident . $f:ident),+ $(,)?) => {
        $($s.positive(stringify!($f), $c.$f)?;)+
    };
    ($s:ident, <= $max:expr, $($c:ident . $f:ident),+ $(,)?) => {
        $($s.fraction(stringify!($f), $c.$f, $max)?;)+
    };
}

impl SlamConfig {
    /// Checks every field of every section; the error names the first invalid one as
    /// `section.field`.
    pub fn validate(&self) -> Result<(), SlamError> {
        let (x, s) = (&self.extractor, Section("extractor"));
        check!(s, >= 1, x.n_features);
        if !(0 < x.min_fast && x.min_fast <= x.ini_fast && x.ini_fast < 255) {
            return Err(s.bad(
                "ini_fast and extractor.min_fast",
                "satisfy 0 < min_fast <= ini_fast < 255",
            ));
        }
        if !(x.scale_factor.is_finite() && x.scale_factor > 1.0) {
            return Err(s.bad("scale_factor", "be > 1"));
        }
        if !(1..=32).contains(&x.n_levels) {
            return Err(s.bad("n_levels", "be in 1..=32"));
        }

        let (d, s) = (&self.depth, Section("depth"));
        if !(d.bf.is_finite() && d.bf > 0.0) {
            return Err(s.bad("bf", "be a positive number (fx * baseline)"));
        }
        check!(s, > 0, d.depth_threshold);
        let (dmin, dmax) = d.depth_range;
        if !(dmin.is_finite() && !dmax.is_nan() && 0.0 <= dmin && dmin < dmax) {
            return Err(s.bad("depth_range", "be (min, max) with 0 <= min < max"));
        }

        let (i, s) = (&self.initialization, Section("initialization"));
        check!(s, >= 1, i.min_keypoints, i.min_depth_points, i.mono_min_keypoints);
        // The essential and homography solvers need 8 matches.
        check!(s, >= 8, i.mono_min_matches);
        check!(s, >= 1, i.mono_min_points);
        check!(s, > 0, i.mono_window_px);
        check!(s, <= 1.0, i.mono_nn_ratio);

        let (t, s) = (&self.tracking, Section("tracking"));
        let (lower, upper) = t.track_feature_range;
        if lower == 0 || lower >= upper {
            return Err(s.bad(
                "track_feature_range",
                "be (lower, upper) with 0 < lower < upper",
            ));
        }
        check!(s, >= 1, t.skip_max_frames, t.post_relocalisation_frames);
        check!(s, >= 1, t.relocalised_min_inliers, t.strong_pose_inliers);
        check!(s, >= 1, t.min_search_matches, t.retry_search_matches);
        check!(s, >= 1, t.max_local_keyframes, t.redundant_view_keyframes);
        // PnP-RANSAC needs 4 correspondences.
        check!(s, >= 4, t.min_reference_matches, t.min_pose_inliers);
        check!(s, <= 1.0, t.redundant_view_share, t.weak_tracking_share);
        check!(s, <= 1.0, t.reference_ratio, t.first_keyframes_reference_ratio);
        // close_tracked_max, close_untracked_min, min_keyframe_inliers: any count.
        check!(s, > 0, t.relocalisation_window_s);
        // Ten seconds at 30 fps: the frames are held in memory while tracking is lost.
        if t.gap_frames > 300 {
            return Err(s.bad("gap_frames", "be in 0..=300"));
        }
        check!(s, > 0, t.motion_search_radius_px, t.local_search_width);
        check!(s, > 0, t.relocalised_search_width, t.imu_prediction_search_width);
        check!(s, > 0, t.velocity_prior_sigma_rad_s, t.velocity_prior_sigma_m_s);
        check!(s, > 0, t.frontal_radius, t.oblique_radius);
        check!(s, >= t.motion_search_radius_px, t.motion_retry_radius_px);
        check!(s, >= 1, t.neighbourhood_covisibles);
        check!(s, <= 1.0, t.reference_nn_ratio, t.local_search_nn_ratio);
        check!(s, <= 1.0, t.frontal_view_cos);
        check!(s, >= 1, t.reference_min_observations);
        check!(s, >= 1, t.young_map_reference_min_observations);
        // deferral_inliers_factor: any count (0 defers whenever tracking is not lost).
        // relocalised_wide_search_frames: any count (0 never widens the search).
        // min_keyframes_to_keep: any count (0 keeps every lost map).

        let (v, s) = (&self.visibility, Section("visibility"));
        check!(s, <= 1.0, v.min_view_cos);
        check!(s, <= 1.0, v.min_distance_factor);
        // Infinite: no far limit.
        check!(s, >= 1.0, v.max_distance_factor);

        let (m, s) = (&self.mapping, Section("mapping"));
        check!(s, >= 1, m.triangulation_neighbours, m.hurried_triangulation_neighbours);
        check!(s, >= 1, m.always_searched_with_depth, m.max_queued_keyframes);
        // monocular_wait_inliers: any count (0 never waits).
        check!(s, >= 1, m.min_point_observations, m.redundant_observations);
        check!(s, <= 1.0, m.min_found_ratio, m.redundant_keyframe_share);
        check!(s, >= 1, m.recent_point_check_age);
        check!(s, >= m.recent_point_check_age, m.recent_point_proven_age);
        check!(s, > 0, m.fuse_radius_px);
        // fusion_second_neighbours: any count (0 fuses with the first ring only).
        // redundant_level_margin: any level count (0: the same or finer scales only).
        // A point's distance ratio may at least match its scales' ratio.
        if !(m.scale_consistency_factor.is_finite() && m.scale_consistency_factor >= 1.0) {
            let got = m.scale_consistency_factor;
            return Err(s.bad(
                "scale_consistency_factor",
                format_args!("be >= 1, got {got}"),
            ));
        }
        // min_points_to_search_on: any count (0 searches every neighbour).
        if !(m.min_ray_parallax_deg > 0.0 && m.min_ray_parallax_deg < 90.0) {
            let got = m.min_ray_parallax_deg;
            return Err(s.bad(
                "min_ray_parallax_deg",
                format_args!("be in (0, 90), got {got}"),
            ));
        }
        if m.max_scene_depth_ratio.is_nan() || m.max_scene_depth_ratio <= 1.0 {
            let got = m.max_scene_depth_ratio;
            return Err(s.bad("max_scene_depth_ratio", format_args!("be > 1, got {got}")));
        }

        let (p, s) = (&self.place_recognition, Section("place_recognition"));
        // feature_levels_up: any level (past the vocabulary's depth, features group at the root).
        check!(s, >= 1, p.group_size, p.max_retrieved);
        check!(s, <= 1.0, p.common_words_share, p.group_score_ratio);

        let (l, s) = (&self.loop_closing, Section("loop_closing"));
        // The Sim(3) RANSAC samples 3 correspondences.
        check!(s, >= 3, l.min_stage_matches);
        check!(s, >= 3, l.merge_ransac_inliers, l.merge_refined_inliers);
        // The verification needs `min_stage_matches` before its final count: a lower bound
        // would never apply.
        check!(s, >= l.min_stage_matches, l.loop_closure_threshold);
        // A merge's projection stage needs `min_stage_matches` too.
        check!(s, >= l.min_stage_matches, l.merge_threshold);
        check!(s, >= 1, l.consistency, l.essential_graph_iterations);
        check!(s, > 0, l.sim3_huber_chi2, l.guided_radius_px);
        check!(s, > 0, l.projection_radius_px, l.fuse_radius_px);
        check!(s, >= 1, l.sim3_ransac_iterations);
        check!(s, >= 1.0, l.max_merge_scale);
        check!(s, <= 1.0, l.bow_nn_ratio);
        if !(l.sim3_ransac_probability > 0.0 && l.sim3_ransac_probability < 1.0) {
            let got = l.sim3_ransac_probability;
            return Err(s.bad(
                "sim3_ransac_probability",
                format_args!("be in (0, 1), got {got}"),
            ));
        }
        // min_keyframes_between, strong_covisibility: any count.

        let (n, s) = (&self.inertial, Section("inertial"));
        let spans = &n.refinement_spans_s;
        let increasing = spans.windows(2).all(|w| w[0] < w[1]);
        if !(increasing && spans.iter().all(|t| t.is_finite() && *t > 0.0)) {
            return Err(s.bad(
                "refinement_spans_s",
                format_args!("be positive seconds in increasing order, got {spans:?}"),
            ));
        }
        check!(s, >= 2, n.window_keyframes);
        check!(s, > 0, n.init_keyframe_interval_s, n.velocity_baseline_s);
        check!(s, > 0, n.imu_only_max_s, n.max_speed_m_s);
        check!(s, > 0, n.max_gyro_bias_rad_s, n.max_accel_bias_m_s2);
        check!(s, > 0, n.anchor_sigma_velocity_m_s, n.anchor_sigma_accel_m_s2);
        check!(s, > 0, n.anchor_sigma_gyro_rad_s);
        Ok(())
    }
}
