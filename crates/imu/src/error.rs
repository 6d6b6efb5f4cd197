//! The error type of this crate.

use thiserror::Error;

/// Errors returned by `ferroslam-imu`. Bad input is reported, never panicked on.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ImuError {
    /// Timestamps must strictly increase; sample `index` is not later than its predecessor.
    #[error(
        "IMU sample {index} at t = {t_s} s is not after the previous one at {previous_s} s: \
         sort the stream and drop duplicates"
    )]
    OutOfOrder {
        /// Index of the offending sample in the slice passed in.
        index: usize,
        /// Its timestamp, seconds.
        t_s: f64,
        /// The previous sample's timestamp, seconds.
        previous_s: f64,
    },
    /// A timestamp, gyro or accelerometer value is NaN or infinite.
    #[error("IMU sample {index} holds a non-finite value (timestamp, gyro or accel)")]
    NonFinite {
        /// Index of the offending sample (0 for a single integration step).
        index: usize,
    },
    /// The interval to integrate is empty or reversed (`end <= start`), or a step has
    /// `dt <= 0`.
    #[error("empty IMU interval: from {start_s} s to {end_s} s (the end must be after the start)")]
    EmptyInterval {
        /// Start of the interval, seconds.
        start_s: f64,
        /// End of the interval, seconds.
        end_s: f64,
    },
    /// The samples do not cover the interval: IMU data are missing at one of its ends.
    #[error(
        "IMU samples span [{first_s}, {last_s}] s but the interval [{start_s}, {end_s}] s was \
         requested: IMU data are missing for this frame (wait for more samples or skip it)"
    )]
    NotCovered {
        /// Requested start, seconds.
        start_s: f64,
        /// Requested end, seconds.
        end_s: f64,
        /// First sample's timestamp, seconds (NaN when there are no samples).
        first_s: f64,
        /// Last sample's timestamp, seconds (NaN when there are no samples).
        last_s: f64,
    },
    /// Consecutive samples inside the interval are further apart than
    /// [`crate::preintegration::MAX_GAP_PERIODS`] sample periods: readings are missing.
    #[error(
        "IMU samples at {before_s} s and {after_s} s are {gap_s:.3} s apart, more than {max_gap_s:.3} s: \
         IMU data are missing inside [{start_s}, {end_s}]"
    )]
    Gap {
        /// Requested start, seconds.
        start_s: f64,
        /// Requested end, seconds.
        end_s: f64,
        /// The sample before the gap, seconds.
        before_s: f64,
        /// The sample after the gap, seconds.
        after_s: f64,
        /// `after_s - before_s`.
        gap_s: f64,
        /// The largest spacing accepted, seconds.
        max_gap_s: f64,
    },
    /// A noise parameter is negative or not finite, or the rate is not positive.
    #[error("invalid IMU parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// Name of the parameter as written in [`crate::ImuParams`] or the EuRoC yaml.
        name: &'static str,
        /// The value found (NaN when missing or unparsable).
        value: f64,
        /// What the parameter must satisfy.
        reason: &'static str,
    },
    /// A covariance to invert is not positive definite: nothing was integrated over the
    /// interval, or the noise densities (or random walks) are zero.
    #[error(
        "IMU covariance over {dt} s is not positive definite: integrate at least one sample \
         and use non-zero noise densities and random walks"
    )]
    SingularCovariance {
        /// Length of the interval, seconds.
        dt: f64,
    },
    /// An IMU parameter file could not be read.
    #[error("cannot read IMU parameters from {path}: {message}")]
    Io {
        /// The path as given.
        path: String,
        /// The operating system's message.
        message: String,
    },
    /// Gyro readings are implausibly large for rad/s: probably deg/s.
    #[error(
        "gyro reaches {max_norm:.1} rad/s, beyond any MEMS gyro's range (~35 rad/s): the \
         stream looks like deg/s, multiply by pi/180"
    )]
    GyroLooksLikeDegrees {
        /// Largest `|gyro|` in the stream, in the units given.
        max_norm: f64,
    },
    /// Mean accelerometer magnitude beyond [`crate::plausibility::MAX_MEAN_ACCEL_M_S2`]:
    /// another unit (cm/s^2, mm/s^2).
    #[error(
        "accelerometer: mean |accel| is {mean_norm:.1}, {times_gravity:.0} times gravity, \
         beyond any MEMS accelerometer's range (16 g): the stream looks like {likely_unit}; \
         convert it to m/s^2"
    )]
    AccelBeyondRange {
        /// Mean `|accel|` over the stream, in the units given.
        mean_norm: f64,
        /// `mean_norm / 9.81`.
        times_gravity: f64,
        /// The unit the magnitude suggests.
        likely_unit: &'static str,
    },
    /// Mean accelerometer magnitude near zero: no accelerometer data, or gravity removed.
    #[error(
        "accelerometer: mean |accel| is {mean_norm:.3} m/s^2, but an IMU reads gravity's \
         9.81 m/s^2 (specific force) unless it is falling: the accelerometer is missing \
         (zeros) or gravity-compensated; pass the raw accelerometer"
    )]
    AccelNearZero {
        /// Mean `|accel|` over the stream.
        mean_norm: f64,
    },
    /// Mean accelerometer magnitude is about 1 instead of about 9.81: probably in g.
    #[error(
        "accelerometer: mean |accel| is {mean_norm:.2}, close to 1 instead of 9.81 m/s^2: \
         the stream looks like it is in g, multiply by 9.81"
    )]
    AccelLooksLikeG {
        /// Mean `|accel|` over the stream, in the units given.
        mean_norm: f64,
    },
}
