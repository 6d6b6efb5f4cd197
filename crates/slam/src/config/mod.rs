//! One configuration of the whole SLAM system, [`SlamConfig`], in sections that follow the
//! pipeline's stages (as Basalt's `vio_config.h` groups its knobs by stage): the extractor,
//! measured depth, map initialisation, tracking, the visibility rules of projection
//! searches, local mapping, place recognition, loop closing and the inertial stages. Every
//! default and every tuning constant of the crate lives here, with its unit and the reason
//! for its value (ORB-SLAM's, or why ours differs); the runs behind the choices are in
//! `docs/benchmarks.md`. Front ends (the CLI, `run_sequence`, the vSLAM objects) only
//! translate names.
//!
//! Named presets: [`SlamConfig::for_sensor`] per [`Sensor`] (the values that depend on the
//! sensor are the preset's), [`SlamConfig::for_camera`] with the extractor sized to the
//! image. [`SlamConfig::validate`] checks every field, naming it `section.field`.
//! [`user_options`] declares the fields a front end may set by name, with their ranges.

mod backend;
mod frontend;
mod options;
mod validate;

pub use backend::{InertialTuning, LoopClosingConfig, MappingConfig, PlaceRecognitionConfig};
pub use frontend::{
    DepthConfig, ExtractorConfig, InitializationConfig, TrackingConfig, VisibilityConfig,
};
pub use options::{
    user_options, OptionKind, OptionRange, OptionScope, UserOption, GRAVITY_RANGE_M_S2,
    MAX_IMU_TIME_OFFSET_S,
};

/// The camera setup a system tracks; decides which `track_*` call it accepts and the
/// sensor-specific rules of ORB-SLAM (keyframe ratio, triangulation, culling).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sensor {
    /// One camera: the map starts from two views and has no metric scale.
    Monocular,
    /// A rectified stereo pair: depth from disparity.
    Stereo,
    /// A depth camera registered to the colour image.
    Rgbd,
}

impl Sensor {
    /// Lower-case name as the Python API spells it.
    pub fn name(self) -> &'static str {
        match self {
            Sensor::Monocular => "mono",
            Sensor::Stereo => "stereo",
            Sensor::Rgbd => "rgbd",
        }
    }

    /// Whether frames carry measured depth (stereo or RGB-D).
    pub fn has_depth(self) -> bool {
        self != Sensor::Monocular
    }
}

/// Configuration of a [`crate::SlamSystem`]: the sensor, the seed and one section per stage.
///
/// Names mirror MATLAB's `rgbdvslam` where a knob exists there (`track_feature_range`,
/// `skip_max_frames`, `depth_range`) and ORB-SLAM's settings otherwise.
#[derive(Clone, Debug, PartialEq)]
pub struct SlamConfig {
    /// Camera setup.
    pub sensor: Sensor,
    /// Seed of every random choice (RANSAC), mixed with the frame or keyframe index.
    pub seed: u64,
    /// With the mapping thread: tracking waits for each keyframe's mapping job before the
    /// next frame and mapping is never hurried, so that a run's poses and map equal the
    /// inline ones (at the cost of the thread's overlap). No effect inline, which is always
    /// deterministic.
    pub deterministic: bool,
    /// ORB extraction (the extractor reads these; the core checks keypoint octaves against
    /// the pyramid).
    pub extractor: ExtractorConfig,
    /// Which measured depths count and which are trusted.
    pub depth: DepthConfig,
    /// Starting a map: from one frame with depth, or from a monocular two-view pair.
    pub initialization: InitializationConfig,
    /// Tracking frames against the map, keyframe decisions, relocalisation.
    pub tracking: TrackingConfig,
    /// Which map points the projection searches of tracking, point fusion and loop closing
    /// look for.
    pub visibility: VisibilityConfig,
    /// Local mapping: new points, culling, local bundle adjustment.
    pub mapping: MappingConfig,
    /// The bag-of-words keyframe index (relocalisation and loop candidates).
    pub place_recognition: PlaceRecognitionConfig,
    /// Loop detection, verification and correction.
    pub loop_closing: LoopClosingConfig,
    /// Camera-IMU alignment, local inertial BA and IMU-only prediction (with an IMU set).
    pub inertial: InertialTuning,
}

impl Default for SlamConfig {
    /// [`SlamConfig::for_sensor`] of an RGB-D sensor (build other sensors' configurations
    /// from `for_sensor`: some defaults depend on the sensor).
    fn default() -> Self {
        Self::for_sensor(Sensor::Rgbd)
    }
}

impl SlamConfig {
    /// The preset of `sensor`, for images 640 px wide ([`Self::for_camera`] sizes the
    /// extractor to the camera). Each section's preset holds the values that depend on the
    /// sensor: [`TrackingConfig::for_sensor`] (the tracked-feature range),
    /// [`DepthConfig::for_sensor`] (the valid depths), [`MappingConfig::for_sensor`]
    /// (triangulation and culling rules).
    pub fn for_sensor(sensor: Sensor) -> Self {
        Self {
            sensor,
            seed: 0,
            deterministic: false,
            extractor: ExtractorConfig::for_width(640),
            depth: DepthConfig::for_sensor(sensor),
            initialization: InitializationConfig::default(),
            tracking: TrackingConfig::for_sensor(sensor),
            visibility: VisibilityConfig::default(),
            mapping: MappingConfig::for_sensor(sensor),
            place_recognition: PlaceRecognitionConfig::default(),
            loop_closing: LoopClosingConfig::default(),
            inertial: InertialTuning::default(),
        }
    }

    /// The preset of `sensor` for images `width_px` wide: [`Self::for_sensor`] with the
    /// extractor budget of [`ExtractorConfig::for_width`]. The entry point of the bindings.
    pub fn for_camera(sensor: Sensor, width_px: u32) -> Self {
        Self {
            extractor: ExtractorConfig::for_width(width_px),
            ..Self::for_sensor(sensor)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::SlamError;
    use frontend::default_n_features;

    #[test]
    fn the_default_budget_follows_the_image_width() {
        assert_eq!(default_n_features(640), 1000);
        assert_eq!(default_n_features(752), 1200);
        assert_eq!(default_n_features(1241), 1900);
        assert_eq!(default_n_features(1226), 1900);
        assert_eq!(default_n_features(160), 500);
        assert_eq!(default_n_features(4096), 2000);
        let kitti = SlamConfig::for_camera(Sensor::Stereo, 1241);
        assert_eq!(kitti.extractor.n_features, 1900);
        let mut narrow = kitti.clone();
        narrow.extractor.n_features = 1000;
        assert_eq!(narrow, SlamConfig::for_sensor(Sensor::Stereo));
        // The extractor's defaults are the features crate's, the budget aside.
        let orb = ferroslam_features::OrbConfig::default();
        assert_eq!(ExtractorConfig::for_width(640).orb(), orb);
        let wide = ExtractorConfig::for_width(1241).orb();
        assert_eq!((wide.n_features, wide.fast), (1900, orb.fast));
    }

    /// The values that depend on the sensor are those of its preset.
    #[test]
    fn presets_hold_the_sensor_rules() {
        let presets = [Sensor::Monocular, Sensor::Stereo, Sensor::Rgbd].map(SlamConfig::for_sensor);
        // The field of each preset: monocular, stereo, RGB-D.
        macro_rules! per_sensor {
            ($($path:ident).+) => {
                [0, 1, 2].map(|k| presets[k].$($path).+)
            };
        }
        let limits = per_sensor!(tracking.track_feature_range);
        assert_eq!(limits, [(30, 100), (30, 100), (30, 250)]);
        let depths = per_sensor!(depth.depth_range);
        assert_eq!(depths[1..], [(0.0, f64::INFINITY), (0.1, 8.0)]);
        assert_eq!(per_sensor!(tracking.reference_ratio), [0.9, 0.75, 0.75]);
        assert_eq!(per_sensor!(mapping.triangulation_neighbours), [20, 10, 10]);
        assert_eq!(
            per_sensor!(mapping.hurried_triangulation_neighbours),
            [20, 3, 3]
        );
        assert_eq!(per_sensor!(mapping.min_ray_parallax_deg), [1.15, 5.0, 5.0]);
        assert_eq!(per_sensor!(mapping.min_point_observations), [2, 3, 3]);
        let mono = &presets[0];
        let tan = 1.15f64.to_radians().tan();
        assert_eq!(mono.mapping.min_baseline_depth_ratio(), tan);
        let tracking = &mono.tracking;
        assert_eq!(
            tracking.post_relocalisation_frames,
            tracking.skip_max_frames
        );
        for preset in presets {
            assert!(preset.validate().is_ok(), "{preset:?}");
        }
    }

    #[test]
    fn pyramids_too_deep_for_the_image_are_refused() {
        let ok = SlamConfig::for_sensor(Sensor::Monocular).extractor;
        assert!(ok.check_pyramid(640, 480).is_ok());
        let deep = ExtractorConfig {
            scale_factor: 2.0,
            n_levels: 12,
            ..ok
        };
        let err = deep.check_pyramid(640, 480).unwrap_err().to_string();
        assert!(
            err.contains("n_levels = 12") && err.contains("at most 4 levels"),
            "{err}"
        );
        // 480 / 2^3 = 60 px fits, 480 / 2^4 = 30 px does not.
        assert!(ExtractorConfig {
            n_levels: 4,
            ..deep
        }
        .check_pyramid(640, 480)
        .is_ok());
        let err = ok.check_pyramid(5, 1).unwrap_err().to_string();
        assert!(err.contains("at most 0 levels"), "{err}");
    }

    /// Every section is checked, and the error names the field as `section.field`.
    #[test]
    fn invalid_fields_are_named_by_section() {
        let ok = SlamConfig::for_sensor(Sensor::Monocular);
        assert!(ok.validate().is_ok());
        // `section.field = value`: the expected name and the change that spoils it.
        macro_rules! case {
            ($s:ident . $f:ident = $v:expr) => {
                (
                    concat!(stringify!($s), ".", stringify!($f)),
                    |c: &mut SlamConfig| c.$s.$f = $v,
                )
            };
        }
        type Case = (&'static str, fn(&mut SlamConfig));
        let cases: [Case; 27] = [
            case!(extractor.n_features = 0),
            case!(extractor.min_fast = 0),
            case!(extractor.min_fast = 21),
            case!(extractor.ini_fast = 255),
            case!(depth.bf = f64::NAN),
            case!(initialization.mono_window_px = 0.0),
            case!(initialization.mono_nn_ratio = 1.5),
            case!(tracking.post_relocalisation_frames = 0),
            case!(tracking.redundant_view_share = 1.5),
            case!(tracking.motion_retry_radius_px = 10.0),
            case!(tracking.reference_min_observations = 0),
            case!(visibility.min_view_cos = 1.5),
            case!(visibility.min_distance_factor = 0.0),
            case!(visibility.max_distance_factor = 0.9),
            case!(mapping.min_ray_parallax_deg = 90.0),
            case!(mapping.max_queued_keyframes = 0),
            case!(mapping.recent_point_proven_age = 1),
            case!(mapping.fuse_radius_px = f64::NAN),
            case!(place_recognition.group_size = 0),
            case!(place_recognition.group_score_ratio = 0.0),
            case!(loop_closing.loop_closure_threshold = 19),
            case!(loop_closing.sim3_ransac_probability = 1.0),
            case!(loop_closing.merge_refined_inliers = 2),
            case!(loop_closing.merge_threshold = 19),
            case!(loop_closing.max_merge_scale = 0.5),
            case!(inertial.refinement_spans_s = vec![15.0, 5.0]),
            case!(inertial.anchor_sigma_gyro_rad_s = -1.0),
        ];
        for (field, spoil) in cases {
            let mut bad = ok.clone();
            spoil(&mut bad);
            match bad.validate() {
                Err(SlamError::InvalidConfig(m)) => assert!(m.contains(field), "{field}: {m}"),
                other => panic!("{field}: {other:?}"),
            }
        }
    }
}
