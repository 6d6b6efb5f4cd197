//! Tuning knobs of the SLAM system and their defaults, per sensor and image size: the one
//! place every front end (the CLI, `run_sequence`, the vSLAM objects) reads them from.

use ferroslam_features::extractor::EDGE_PX;

use crate::error::SlamError;

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

/// Configuration of a [`crate::SlamSystem`].
///
/// Names mirror MATLAB's `rgbdvslam` where a knob exists there (`track_feature_range`,
/// `skip_max_frames`, `depth_range`) and ORB-SLAM's settings otherwise.
#[derive(Clone, Debug, PartialEq)]
pub struct SlamConfig {
    /// Camera setup.
    pub sensor: Sensor,
    /// ORB keypoints extracted per image (ORB-SLAM `nFeatures`; MATLAB `MaxNumPoints`); the
    /// default depends on the image width, see [`default_n_features`].
    pub n_features: usize,
    /// FAST threshold tried first in every cell of the extractor's grid (ORB-SLAM `iniThFAST`).
    pub ini_fast: u8,
    /// FAST threshold of the cells where `ini_fast` finds no corner (ORB-SLAM `minThFAST`).
    pub min_fast: u8,
    /// Scale between ORB pyramid levels (ORB-SLAM `scaleFactor`).
    pub scale_factor: f64,
    /// Number of ORB pyramid levels.
    pub n_levels: usize,
    /// `(lower, upper)` tracked-feature limits: below `lower` tracking is lost; below `upper`
    /// the frame becomes a keyframe (MATLAB `TrackFeatureRange`; monocular, only when it also
    /// tracks under 0.9 of its reference keyframe's points); above it, only ORB-SLAM's rules
    /// or `skip_max_frames` make one.
    pub track_feature_range: (usize, usize),
    /// Maximum number of frames between two keyframes (ORB-SLAM `mMaxFrames`).
    pub skip_max_frames: usize,
    /// Stereo baseline times fx, in metres * pixels; the virtual right camera of RGB-D input.
    pub bf: f64,
    /// Points closer than `depth_threshold` baselines are "close" (trusted depth), metres / baseline.
    pub depth_threshold: f64,
    /// `(min, max)` valid measured depth in metres (RGB-D sensor depth or stereo depth from
    /// disparity); other depths count as missing. `max` may be infinite.
    pub depth_range: (f64, f64),
    /// Seed of every random choice (RANSAC).
    pub seed: u64,
    /// Detect and close loops (needs a vocabulary, see `SlamSystem::set_vocabulary`).
    pub loop_closure: bool,
    /// Minimum matched map points between a keyframe and a loop candidate for the loop to be
    /// accepted after Sim(3) verification (MATLAB `LoopClosureThreshold`; ORB-SLAM: 40).
    pub loop_closure_threshold: usize,
}

/// `track_feature_range` with an RGB-D sensor, see [`SlamConfig::for_sensor`].
pub const RGBD_TRACK_FEATURE_RANGE: (usize, usize) = (30, 250);

/// Shorter side of the coarsest pyramid level, pixels: room for a keypoint with its
/// descriptor's border on both sides.
pub const MIN_LEVEL_SIDE_PX: usize = 2 * EDGE_PX + 1;

/// ORB keypoints per image column of the default budget. ORB-SLAM's settings keep about
/// this density across cameras: 1000 features at 640 px wide (TUM), 1200 at 752 (EuRoC),
/// 2000 at 1241 (KITTI). Wider images see more of the scene, and far, slow-moving features
/// are what tracking at speed keeps; the image height does not change the choices.
const FEATURES_PER_COLUMN: f64 = 1000.0 / 640.0;
/// Bounds of the default budget: below 500 keypoints a stereo or RGB-D map cannot start
/// (see [`crate::SlamSystem`]'s initialisation rule); above 2000, ORB-SLAM's largest setting,
/// extraction and matching time grow faster than tracking gains.
const DEFAULT_FEATURES_RANGE: (usize, usize) = (500, 2000);

/// The default ORB budget for images `width_px` wide: [`FEATURES_PER_COLUMN`] per column,
/// rounded to a hundred, within [`DEFAULT_FEATURES_RANGE`] (640 px: 1000, 752: 1200,
/// 1241: 1900).
pub fn default_n_features(width_px: u32) -> usize {
    let n = (f64::from(width_px) * FEATURES_PER_COLUMN / 100.0).round() as usize * 100;
    n.clamp(DEFAULT_FEATURES_RANGE.0, DEFAULT_FEATURES_RANGE.1)
}

impl Default for SlamConfig {
    /// [`SlamConfig::for_sensor`] of an RGB-D sensor (build other sensors' configurations
    /// from `for_sensor`: some defaults depend on the sensor).
    fn default() -> Self {
        Self::for_sensor(Sensor::Rgbd)
    }
}

impl SlamConfig {
    /// The defaults for `sensor`: MATLAB's `TrackFeatureRange` (30, 100), except with an
    /// RGB-D sensor (30, 250); stereo depth unbounded (disparity bounds it), RGB-D depth
    /// within (0.1, 8.0) m.
    ///
    /// With depth, a new keyframe's own points count for ORB-SLAM's reference ratio only once
    /// another keyframe sees them, so the ratio rule fires near the points tracked when the
    /// keyframe was made: with the upper limit at 100, keyframes came as tracking fell to
    /// about 100 points, and those poses (fast rotations) erred by 5-7 cm frame to frame.
    /// fr1/rpy RGB-D, mapping inline, with ORB-SLAM's TUM extractor settings (1000 features,
    /// FAST 20 / 7) and four neighbours (1100 or 900 features, FAST 19 or 21): ATE 2.67 /
    /// 3.31 / 3.09 / 3.53 / 3.03 cm with 100, 2.64 / 2.69 / 2.34 / 2.58 / 2.39 cm with 250
    /// (2.86 cm on average with 150, 2.61 with 200, 2.54 with 300); 37-47 keyframes become
    /// 55-69. Stereo keeps 100: on KITTI 01 a keyframe is made
    /// almost every frame already (250: 51 keyframes in 51 frames, ATE 57.4 -> 58.1 cm).
    ///
    /// The extractor budget is that of a 640 px wide image; [`Self::for_camera`] sizes it to
    /// the camera.
    pub fn for_sensor(sensor: Sensor) -> Self {
        Self {
            sensor,
            n_features: default_n_features(640),
            ini_fast: 20,
            min_fast: 7,
            scale_factor: 1.2,
            n_levels: 8,
            track_feature_range: if sensor == Sensor::Rgbd {
                RGBD_TRACK_FEATURE_RANGE
            } else {
                (30, 100)
            },
            skip_max_frames: 30,
            bf: 40.0,
            depth_threshold: 40.0,
            depth_range: if sensor == Sensor::Stereo {
                (0.0, f64::INFINITY)
            } else {
                (0.1, 8.0)
            },
            seed: 0,
            loop_closure: true,
            loop_closure_threshold: 40,
        }
    }

    /// The defaults for `sensor` with images `width_px` wide: [`Self::for_sensor`] with the
    /// extractor budget of [`default_n_features`].
    pub fn for_camera(sensor: Sensor, width_px: u32) -> Self {
        Self {
            n_features: default_n_features(width_px),
            ..Self::for_sensor(sensor)
        }
    }
}

impl SlamConfig {
    /// Checks every field, naming the first invalid one.
    pub fn validate(&self) -> Result<(), SlamError> {
        let bad = |what: &str| Err(SlamError::InvalidConfig(what.to_owned()));
        if self.n_features == 0 {
            return bad("n_features must be >= 1");
        }
        if !(0 < self.min_fast && self.min_fast <= self.ini_fast && self.ini_fast < 255) {
            return bad("ini_fast and min_fast must satisfy 0 < min_fast <= ini_fast < 255");
        }
        if !(self.scale_factor.is_finite() && self.scale_factor > 1.0) {
            return bad("scale_factor must be > 1");
        }
        if !(1..=32).contains(&self.n_levels) {
            return bad("n_levels must be in 1..=32");
        }
        let (lo, hi) = self.track_feature_range;
        if lo == 0 || lo >= hi {
            return bad("track_feature_range must be (lower, upper) with 0 < lower < upper");
        }
        if self.skip_max_frames == 0 {
            return bad("skip_max_frames must be >= 1");
        }
        if !(self.bf.is_finite() && self.bf > 0.0) {
            return bad("bf must be a positive number (fx * baseline)");
        }
        if !(self.depth_threshold.is_finite() && self.depth_threshold > 0.0) {
            return bad("depth_threshold must be positive");
        }
        if self.loop_closure_threshold < 20 {
            // Sim(3) verification alone needs 20 inliers; a lower bound would never apply.
            return bad("loop_closure_threshold must be >= 20");
        }
        let (dmin, dmax) = self.depth_range;
        if !(dmin.is_finite() && !dmax.is_nan() && 0.0 <= dmin && dmin < dmax) {
            return bad("depth_range must be (min, max) with 0 <= min < max");
        }
        Ok(())
    }

    /// Checks that every pyramid level of a `width_px` x `height_px` image keeps room for
    /// keypoints: [`MIN_LEVEL_SIDE_PX`] on its shorter side. A pyramid too deep for the image
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
            "n_levels = {} with scale_factor {} shrinks the {width_px}x{height_px} images to \
             {coarsest:.1} px on the shorter side at the coarsest level; levels need at least \
             {MIN_LEVEL_SIDE_PX} px (keypoints keep {EDGE_PX} px from the border): at most {fitting} \
             levels fit",
            self.n_levels, self.scale_factor
        )))
    }

    /// Depth below which a point is close enough to trust its measured depth, metres.
    pub fn close_depth_m(&self, fx: f64) -> f64 {
        self.bf * self.depth_threshold / fx
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_budget_follows_the_image_width() {
        assert_eq!(default_n_features(640), 1000);
        assert_eq!(default_n_features(752), 1200);
        assert_eq!(default_n_features(1241), 1900);
        assert_eq!(default_n_features(1226), 1900);
        assert_eq!(default_n_features(160), 500);
        assert_eq!(default_n_features(4096), 2000);
        let kitti = SlamConfig::for_camera(Sensor::Stereo, 1241);
        assert_eq!(kitti.n_features, 1900);
        assert_eq!(
            SlamConfig {
                n_features: 1000,
                ..kitti
            },
            SlamConfig::for_sensor(Sensor::Stereo)
        );
    }

    #[test]
    fn pyramids_too_deep_for_the_image_are_refused() {
        let ok = SlamConfig::for_sensor(Sensor::Monocular);
        assert!(ok.check_pyramid(640, 480).is_ok());
        let deep = SlamConfig {
            scale_factor: 2.0,
            n_levels: 12,
            ..ok.clone()
        };
        let err = deep.check_pyramid(640, 480).unwrap_err().to_string();
        assert!(
            err.contains("n_levels = 12") && err.contains("at most 4 levels"),
            "{err}"
        );
        // 480 / 2^3 = 60 px fits, 480 / 2^4 = 30 px does not.
        assert!(SlamConfig {
            n_levels: 4,
            ..deep.clone()
        }
        .check_pyramid(640, 480)
        .is_ok());
        let err = ok.check_pyramid(5, 1).unwrap_err().to_string();
        assert!(err.contains("at most 0 levels"), "{err}");
    }

    #[test]
    fn extractor_settings_are_validated() {
        let ok = SlamConfig::for_sensor(Sensor::Monocular);
        assert!(ok.validate().is_ok());
        for bad in [
            SlamConfig {
                n_features: 0,
                ..ok.clone()
            },
            SlamConfig {
                min_fast: 0,
                ..ok.clone()
            },
            SlamConfig {
                min_fast: 21,
                ..ok.clone()
            },
            SlamConfig {
                ini_fast: 255,
                ..ok.clone()
            },
        ] {
            assert!(matches!(bad.validate(), Err(SlamError::InvalidConfig(_))));
        }
    }
}
