//! Tuning knobs of the SLAM system, with ORB-SLAM2/3 RGB-D defaults.

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
    pub fn for_sensor(sensor: Sensor) -> Self {
        Self {
            sensor,
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
}

impl SlamConfig {
    /// Checks every field, naming the first invalid one.
    pub fn validate(&self) -> Result<(), SlamError> {
        let bad = |what: &str| Err(SlamError::InvalidConfig(what.to_owned()));
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

    /// Depth below which a point is close enough to trust its measured depth, metres.
    pub fn close_depth_m(&self, fx: f64) -> f64 {
        self.bf * self.depth_threshold / fx
    }
}
