//! The user-facing options: which configuration fields a front end may set by name, with
//! each one's type, admitted range, unit, sensors and one line of documentation.
//!
//! This is the one declaration every front end reads: the Python binding parses its keyword
//! options against it and exports it (`ferroslam._core.option_table()`, with each option's
//! default per sensor), `ferroslam.options` checks values with it and `docs/options.md` is
//! generated from it. Defaults are not repeated here: they are the presets'
//! ([`SlamConfig::for_camera`]) and [`InertialConfig::new`]'s. A test checks every range
//! against [`SlamConfig::validate`] / [`InertialConfig::validate`].
//!
//! [`SlamConfig::for_camera`]: super::SlamConfig::for_camera
//! [`SlamConfig::validate`]: super::SlamConfig::validate
//! [`InertialConfig::new`]: crate::InertialConfig::new
//! [`InertialConfig::validate`]: crate::InertialConfig::validate

use super::{LoopClosingConfig, Sensor};
use crate::inertial::MIN_ALIGNED_KEYFRAMES;

/// Admitted magnitudes of gravity, m/s^2: 9.780 (equator) to 9.832 (poles), 0.03 less at
/// 9 km, so every place on Earth, while gravity given in other units (1.0 in g, 32.2 in
/// ft/s^2) is refused: it would make every IMU-predicted pose wrong.
pub const GRAVITY_RANGE_M_S2: (f64, f64) = (9.7, 9.9);
/// Largest camera-IMU clock offset admitted, seconds. Calibrated offsets are milliseconds
/// (Kalibr); one of more than a second means two unrelated clocks (boot time against epoch),
/// which a constant shift would only hide: every frame's IMU batch would be empty or wrong.
pub const MAX_IMU_TIME_OFFSET_S: f64 = 1.0;
/// Largest value of the fields counted in `u32` by the bindings (budgets, frame counts).
const U32_MAX: f64 = u32::MAX as f64;
/// Largest seed (`u64`).
const U64_MAX: f64 = u64::MAX as f64;

/// How an option's value is spelled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OptionKind {
    /// An integer.
    Int,
    /// A real number.
    Float,
    /// `true` or `false`.
    Flag,
    /// `(lower, upper)` integers, lower below upper.
    IntPair,
    /// `(lower, upper)` real numbers, lower below upper.
    FloatPair,
}

impl OptionKind {
    /// The name the Python side spells it with (`"int"`, `"float_pair"`, ...).
    pub fn name(self) -> &'static str {
        match self {
            OptionKind::Int => "int",
            OptionKind::Float => "float",
            OptionKind::Flag => "flag",
            OptionKind::IntPair => "int_pair",
            OptionKind::FloatPair => "float_pair",
        }
    }
}

/// Who takes an option.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OptionScope {
    /// A field of [`super::SlamConfig`] (the binding's `SlamSystem` keywords).
    Core,
    /// A field of [`crate::InertialConfig`] (`SlamSystem.set_imu` keywords): inertial
    /// sensors only.
    Imu,
}

impl OptionScope {
    /// `"core"` or `"imu"`.
    pub fn name(self) -> &'static str {
        match self {
            OptionScope::Core => "core",
            OptionScope::Imu => "imu",
        }
    }
}

/// The values an option admits: each value (each element of a pair) lies in `low..high`,
/// `None` meaning no bound; `open_low` / `open_high` exclude the bound; `infinite_high`
/// admits `+inf` (a real number, or a pair's upper value) beyond any finite bound.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OptionRange {
    /// Lower bound.
    pub low: Option<f64>,
    /// Upper bound.
    pub high: Option<f64>,
    /// Whether `low` itself is excluded.
    pub open_low: bool,
    /// Whether `high` itself is excluded.
    pub open_high: bool,
    /// Whether `+inf` is admitted.
    pub infinite_high: bool,
}

impl OptionRange {
    /// `[low, high]`.
    const fn closed(low: f64, high: f64) -> Self {
        Self {
            low: Some(low),
            high: Some(high),
            open_low: false,
            open_high: false,
            infinite_high: false,
        }
    }

    /// `>= low`, unbounded above.
    const fn at_least(low: f64) -> Self {
        Self {
            high: None,
            ..Self::closed(low, 0.0)
        }
    }

    /// `> low`, unbounded above.
    const fn above(low: f64) -> Self {
        Self {
            open_low: true,
            ..Self::at_least(low)
        }
    }

    /// Whether `value` lies in the range.
    pub fn admits(&self, value: f64) -> bool {
        if value.is_nan() {
            return false;
        }
        if value == f64::INFINITY && self.infinite_high {
            return true;
        }
        let above_low = self.low.is_none_or(|low| {
            if self.open_low {
                value > low
            } else {
                value >= low
            }
        });
        let below_high = self.high.map_or(value.is_finite(), |high| {
            if self.open_high {
                value < high
            } else {
                value <= high
            }
        });
        above_low && below_high
    }
}

/// One user-facing option.
#[derive(Clone, Debug, PartialEq)]
pub struct UserOption {
    /// The keyword (`n_features`, `gravity_magnitude`).
    pub name: &'static str,
    /// Who takes it.
    pub scope: OptionScope,
    /// The field it sets, `section.field` of [`super::SlamConfig`] or `imu.field` of
    /// [`crate::InertialConfig`]; `None` for `baseline`, which sets `depth.bf` through
    /// `fx * baseline`.
    pub field: Option<&'static str>,
    /// How its value is spelled.
    pub kind: OptionKind,
    /// Unit of its value, for messages and docs (`""`: none).
    pub unit: &'static str,
    /// The values admitted (flags: any).
    pub range: OptionRange,
    /// The camera sensors it applies to.
    pub sensors: &'static [Sensor],
    /// One line of documentation.
    pub doc: &'static str,
}

const ALL: &[Sensor] = &[Sensor::Monocular, Sensor::Stereo, Sensor::Rgbd];
const DEPTH: &[Sensor] = &[Sensor::Stereo, Sensor::Rgbd];
const STEREO: &[Sensor] = &[Sensor::Stereo];

/// An option with the defaults of most: core scope, every sensor.
const fn option(
    name: &'static str,
    field: &'static str,
    kind: OptionKind,
    unit: &'static str,
    range: OptionRange,
    doc: &'static str,
) -> UserOption {
    UserOption {
        name,
        scope: OptionScope::Core,
        field: Some(field),
        kind,
        unit,
        range,
        sensors: ALL,
        doc,
    }
}

/// Every user-facing option, in the order of the binding's option dicts and errors: the
/// core's first, then the IMU's.
pub fn user_options() -> Vec<UserOption> {
    use OptionKind::{Flag, Float, FloatPair, Int, IntPair};
    let count = |low: f64| OptionRange::closed(low, U32_MAX);
    // The verification needs `min_stage_matches` before its final count (validate).
    let loop_matches = LoopClosingConfig::default().min_stage_matches as f64;
    vec![
        option(
            "n_features",
            "extractor.n_features",
            Int,
            "keypoints",
            count(1.0),
            "ORB keypoints per image (ORB-SLAM nFeatures); the default follows the image \
             width (ExtractorConfig::for_width)",
        ),
        option(
            "ini_fast",
            "extractor.ini_fast",
            Int,
            "intensity levels",
            OptionRange::closed(1.0, 254.0),
            "FAST threshold tried first in every extractor cell (ORB-SLAM iniThFAST)",
        ),
        option(
            "min_fast",
            "extractor.min_fast",
            Int,
            "intensity levels",
            OptionRange::closed(1.0, 254.0),
            "FAST threshold of the cells where ini_fast finds no corner, at most ini_fast \
             (ORB-SLAM minThFAST)",
        ),
        option(
            "scale_factor",
            "extractor.scale_factor",
            Float,
            "",
            OptionRange::above(1.0),
            "Scale between ORB pyramid levels (ORB-SLAM scaleFactor)",
        ),
        option(
            "n_levels",
            "extractor.n_levels",
            Int,
            "levels",
            OptionRange::closed(1.0, 32.0),
            "ORB pyramid levels (ORB-SLAM nLevels); the coarsest must keep room for keypoints",
        ),
        option(
            "track_feature_range",
            "tracking.track_feature_range",
            IntPair,
            "points",
            count(1.0),
            "(lower, upper): tracking fails below lower inliers; below upper the frame may \
             become a keyframe",
        ),
        option(
            "skip_max_frames",
            "tracking.skip_max_frames",
            Int,
            "frames",
            count(1.0),
            "Frames after which a keyframe is inserted regardless of tracking quality",
        ),
        option(
            "relocalisation_window_s",
            "tracking.relocalisation_window_s",
            Float,
            "seconds",
            OptionRange::above(0.0),
            "How long a lost map tries to relocalise before the atlas keeps it and a new map \
             starts (monocular, or with a vocabulary to find it again)",
        ),
        option(
            "gap_frames",
            "tracking.gap_frames",
            Int,
            "frames",
            OptionRange::closed(0.0, 300.0),
            "Frames without a pose (lost, before a map starts) kept and tracked backwards \
             once a later frame is tracked, so the trajectory fills in behind the live \
             results; 0 keeps none (visual maps only)",
        ),
        UserOption {
            sensors: &[Sensor::Rgbd],
            ..option(
                "bf",
                "depth.bf",
                Float,
                "pixels * metres",
                OptionRange::above(0.0),
                "fx times the baseline of the virtual right camera (ORB-SLAM Camera.bf)",
            )
        },
        UserOption {
            field: None,
            sensors: &[Sensor::Stereo],
            ..option(
                "baseline",
                "",
                Float,
                "metres",
                OptionRange::above(0.0),
                "Baseline of the rectified stereo pair (required); sets bf = fx * baseline",
            )
        },
        UserOption {
            sensors: DEPTH,
            ..option(
                "depth_threshold",
                "depth.depth_threshold",
                Float,
                "baselines",
                OptionRange::above(0.0),
                "Points closer than this many baselines trust their measured depth \
                 (ORB-SLAM ThDepth)",
            )
        },
        UserOption {
            sensors: DEPTH,
            ..option(
                "depth_range",
                "depth.depth_range",
                FloatPair,
                "metres",
                OptionRange {
                    infinite_high: true,
                    ..OptionRange::at_least(0.0)
                },
                "(min, max) valid measured depth; others count as missing; max may be inf",
            )
        },
        UserOption {
            sensors: STEREO,
            ..option(
                "match_pair_every_frame",
                "depth.match_pair_every_frame",
                Flag,
                "",
                OptionRange::default(),
                "Match an unrectified pair at every frame; false: at keyframes only, where \
                 its two cameras are triangulated",
            )
        },
        option(
            "seed",
            "seed",
            Int,
            "",
            OptionRange::closed(0.0, U64_MAX),
            "Seed of every random choice (RANSAC), mixed with the frame or keyframe index",
        ),
        option(
            "deterministic",
            "deterministic",
            Flag,
            "",
            OptionRange::default(),
            "With the mapping thread, wait for each keyframe's mapping so that the run \
             equals the inline one",
        ),
        option(
            "loop_closure",
            "loop_closing.loop_closure",
            Flag,
            "",
            OptionRange::default(),
            "Detect and close loops once a vocabulary is set",
        ),
        option(
            "loop_closure_threshold",
            "loop_closing.loop_closure_threshold",
            Int,
            "points",
            count(loop_matches),
            "Matched map points a verified loop needs",
        ),
        imu(
            "num_poses_threshold",
            "imu.num_poses_threshold",
            Int,
            "keyframes",
            count(MIN_ALIGNED_KEYFRAMES as f64),
            "Keyframes created before the camera-IMU alignment is tried",
        ),
        imu(
            "alignment_fraction",
            "imu.alignment_fraction",
            Float,
            "",
            OptionRange {
                open_low: true,
                ..OptionRange::closed(0.0, 1.0)
            },
            "Fraction of the keyframes, the newest, the alignment uses",
        ),
        imu(
            "gravity_magnitude",
            "imu.gravity_magnitude",
            Float,
            "m/s^2",
            OptionRange::closed(GRAVITY_RANGE_M_S2.0, GRAVITY_RANGE_M_S2.1),
            "Magnitude of gravity",
        ),
        imu(
            "imu_time_offset_s",
            "imu.imu_time_offset_s",
            Float,
            "s",
            OptionRange::closed(-MAX_IMU_TIME_OFFSET_S, MAX_IMU_TIME_OFFSET_S),
            "Offset of the IMU clock to the camera's, t_imu = t_cam + offset (Kalibr \
             timeshift_cam_imu)",
        ),
    ]
}

/// An option of [`crate::InertialConfig`].
fn imu(
    name: &'static str,
    field: &'static str,
    kind: OptionKind,
    unit: &'static str,
    range: OptionRange,
    doc: &'static str,
) -> UserOption {
    UserOption {
        scope: OptionScope::Imu,
        ..option(name, field, kind, unit, range, doc)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ImuParams, InertialConfig, SlamConfig};
    use nalgebra::Isometry3;

    /// `config` with the option `name` set to `value` (each element of a pair, the other
    /// one moved out of the way), or `None` for an option without a field.
    fn set(config: &mut SlamConfig, imu: &mut InertialConfig, name: &str, value: f64) {
        let (c, n) = (config, imu);
        // Integer fields take the value truncated: the bounds tested are whole numbers.
        match name {
            "n_features" => c.extractor.n_features = value as usize,
            // min_fast <= ini_fast is a rule between the two: keep the other at its extreme.
            "ini_fast" => (c.extractor.ini_fast, c.extractor.min_fast) = (value as u8, 1),
            "min_fast" => (c.extractor.min_fast, c.extractor.ini_fast) = (value as u8, 254),
            "scale_factor" => c.extractor.scale_factor = value,
            "n_levels" => c.extractor.n_levels = value as usize,
            "track_feature_range" => {
                c.tracking.track_feature_range = (value as usize, value as usize + 1)
            }
            "skip_max_frames" => c.tracking.skip_max_frames = value as u32 as usize,
            "relocalisation_window_s" => c.tracking.relocalisation_window_s = value,
            "gap_frames" => c.tracking.gap_frames = value as u32 as usize,
            "bf" => c.depth.bf = value,
            "depth_threshold" => c.depth.depth_threshold = value,
            "depth_range" => c.depth.depth_range = (value, value + 1.0),
            "seed" => c.seed = value as u64,
            "loop_closure_threshold" => c.loop_closing.loop_closure_threshold = value as usize,
            "num_poses_threshold" => {
                // The window must keep 3 keyframes too: align them all.
                (n.num_poses_threshold, n.alignment_fraction) = (value as usize, 1.0)
            }
            "alignment_fraction" => {
                // Enough keyframes that the smallest fraction tested still aligns 3.
                (n.alignment_fraction, n.num_poses_threshold) = (value, 1 << 40)
            }
            "gravity_magnitude" => n.gravity_magnitude = value,
            "imu_time_offset_s" => n.imu_time_offset_s = value,
            other => panic!("option {other}: no setter in this test; add one"),
        }
    }

    fn accepted(name: &str, value: f64) -> bool {
        let mut config = SlamConfig::for_sensor(Sensor::Rgbd);
        let mut imu = InertialConfig::new(ImuParams::euroc(), Isometry3::identity());
        set(&mut config, &mut imu, name, value);
        config.validate().is_ok() && imu.validate().is_ok()
    }

    /// The table's ranges are the ones `validate` enforces: each bound is admitted or
    /// refused as the table says, and a value just beyond it is refused.
    #[test]
    fn ranges_are_the_ones_validate_enforces() {
        for option in user_options() {
            let (r, name) = (option.range, option.name);
            if option.field.is_none() || option.kind == OptionKind::Flag {
                continue; // baseline: the binding's rule; flags admit both values
            }
            let step = |x: f64| {
                if option.kind == OptionKind::Float {
                    1e-9 * x.abs().max(1.0)
                } else {
                    1.0
                }
            };
            if let Some(low) = r.low {
                assert_eq!(accepted(name, low), !r.open_low, "{name} at {low}");
                // Below 0 an unsigned field cannot be set at all: the type is the bound.
                let unsigned_floor = low == 0.0 && option.kind != OptionKind::Float;
                assert!(
                    unsigned_floor || !accepted(name, low - step(low)),
                    "{name} below {low}"
                );
                assert!(accepted(name, low + step(low)), "{name} above {low}");
            }
            // The integer fields' upper bounds are their types' (u32, u64): nothing to
            // check beyond them.
            if let (Some(high), OptionKind::Float) = (r.high, option.kind) {
                assert_eq!(accepted(name, high), !r.open_high, "{name} at {high}");
                assert!(!accepted(name, high + step(high)), "{name} above {high}");
            }
            if let (Some(high), OptionKind::Int) = (r.high, option.kind) {
                if high < 1e6 {
                    assert!(
                        accepted(name, high) && !accepted(name, high + 1.0),
                        "{name}"
                    );
                }
            }
            if option.kind == OptionKind::Float || option.kind == OptionKind::FloatPair {
                assert!(!accepted(name, f64::NAN), "{name} NaN");
            }
        }
    }

    #[test]
    fn every_field_is_named_once_and_imu_fields_are_inertial() {
        let options = user_options();
        let mut names: Vec<_> = options.iter().map(|o| o.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), options.len());
        for option in &options {
            let imu_field = option.field.is_some_and(|f| f.starts_with("imu."));
            assert_eq!(
                imu_field,
                option.scope == OptionScope::Imu,
                "{}",
                option.name
            );
            assert!(!option.doc.is_empty() && !option.sensors.is_empty());
        }
    }

    #[test]
    fn ranges_admit_as_written() {
        let r = OptionRange::above(0.0);
        assert!(!r.admits(0.0) && r.admits(1e-300) && !r.admits(f64::INFINITY));
        let depth = OptionRange {
            infinite_high: true,
            ..OptionRange::at_least(0.0)
        };
        assert!(depth.admits(0.0) && depth.admits(f64::INFINITY) && !depth.admits(f64::NAN));
        assert!(OptionRange::closed(9.7, 9.9).admits(9.81));
    }
}
