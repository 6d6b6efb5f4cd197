//! Unit plausibility checks: catch streams in deg/s or in g before they are integrated.

use crate::{ImuError, ImuMeasurement};

/// Largest plausible `|gyro|` in rad/s: 2000 deg/s, the top range of common MEMS gyros.
/// A reading above it is almost certainly in deg/s.
pub const MAX_GYRO_RAD_S: f64 = 35.0;

/// Mean `|accel|` in this band (gravity plus moderate motion, expressed in g) means the
/// stream is in g. In m/s^2 a stream that is not in free fall averages about 9.81.
pub const ACCEL_IN_G_BAND: (f64, f64) = (0.5, 2.0);

/// Largest plausible mean `|accel|` over a stream, m/s^2: 16 g, the top range of common MEMS
/// accelerometers. Centimetres per second squared put a resting IMU at 981, millimetres at
/// 9810.
pub const MAX_MEAN_ACCEL_M_S2: f64 = 16.0 * GRAVITY_M_S2;

/// Below this mean `|accel|`, m/s^2 (and below [`ACCEL_IN_G_BAND`]), the accelerometer reads
/// nothing: an IMU reads gravity's 9.81 m/s^2 unless in free fall.
pub const MIN_MEAN_ACCEL_M_S2: f64 = ACCEL_IN_G_BAND.0;

/// Standard gravity, m/s^2, to name how far off a magnitude is.
const GRAVITY_M_S2: f64 = 9.81;

/// Checks that a stream looks like rad/s and m/s^2.
///
/// Returns [`ImuError::GyroLooksLikeDegrees`] if any `|gyro| > MAX_GYRO_RAD_S`, else
/// [`ImuError::AccelLooksLikeG`] if the mean `|accel|` lies in [`ACCEL_IN_G_BAND`],
/// [`ImuError::AccelBeyondRange`] above [`MAX_MEAN_ACCEL_M_S2`] and
/// [`ImuError::AccelNearZero`] below [`MIN_MEAN_ACCEL_M_S2`]. An empty stream passes. Limitation: deg/s at slow rotation (below 35 deg/s) is not detectable
/// from magnitudes; a gyro-bias estimate far above a few deg/s is the later symptom.
/// Non-finite samples are skipped here; [`crate::check_stream`] reports them.
pub fn check_units(measurements: &[ImuMeasurement]) -> Result<(), ImuError> {
    let finite = || {
        measurements.iter().filter(|m| {
            m.gyro_rad_s
                .iter()
                .chain(m.accel_m_s2.iter())
                .all(|v| v.is_finite())
        })
    };
    let max_norm = finite().map(|m| m.gyro_rad_s.norm()).fold(0.0, f64::max);
    if max_norm > MAX_GYRO_RAD_S {
        return Err(ImuError::GyroLooksLikeDegrees { max_norm });
    }
    let count = finite().count();
    if count > 0 {
        let mean_norm = finite().map(|m| m.accel_m_s2.norm()).sum::<f64>() / count as f64;
        if (ACCEL_IN_G_BAND.0..=ACCEL_IN_G_BAND.1).contains(&mean_norm) {
            return Err(ImuError::AccelLooksLikeG { mean_norm });
        }
        if mean_norm < MIN_MEAN_ACCEL_M_S2 {
            return Err(ImuError::AccelNearZero { mean_norm });
        }
        if mean_norm > MAX_MEAN_ACCEL_M_S2 {
            let times_gravity = mean_norm / GRAVITY_M_S2;
            let likely_unit = match times_gravity.log10().round() as i32 {
                2 => "cm/s^2 (divide by 100)",
                3 => "mm/s^2 (divide by 1000)",
                _ => "another unit than m/s^2",
            };
            return Err(ImuError::AccelBeyondRange {
                mean_norm,
                times_gravity,
                likely_unit,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn stream(gyro_scale: f64, accel_scale: f64) -> Vec<ImuMeasurement> {
        (0..100)
            .map(|k| {
                let s = (k as f64 * 0.1).sin();
                ImuMeasurement::new(
                    k as f64 * 0.005,
                    Vector3::new(1.5 * s, -0.8, 0.3) * gyro_scale,
                    Vector3::new(0.5 * s, 0.2, 9.81) * accel_scale,
                )
            })
            .collect()
    }

    #[test]
    fn si_units_pass() {
        assert_eq!(check_units(&stream(1.0, 1.0)), Ok(()));
        assert_eq!(check_units(&[]), Ok(()));
    }

    #[test]
    fn degrees_per_second_are_caught() {
        let deg = 180.0 / std::f64::consts::PI;
        assert!(matches!(
            check_units(&stream(deg, 1.0)),
            Err(ImuError::GyroLooksLikeDegrees { max_norm }) if max_norm > 90.0
        ));
    }

    #[test]
    fn centimetres_millimetres_and_zeros_are_caught() {
        for (scale, unit) in [(100.0, "cm/s^2"), (1000.0, "mm/s^2")] {
            let err = check_units(&stream(1.0, scale)).unwrap_err();
            assert!(matches!(err, ImuError::AccelBeyondRange { .. }), "{err}");
            assert!(err.to_string().contains(unit), "{err}");
            assert!(err.to_string().starts_with("accelerometer"), "{err}");
        }
        let err = check_units(&stream(1.0, 0.0)).unwrap_err();
        assert!(matches!(err, ImuError::AccelNearZero { mean_norm } if mean_norm == 0.0));
        // A hard manoeuvre at 10 g is still m/s^2.
        assert_eq!(check_units(&stream(1.0, 10.0)), Ok(()));
    }

    #[test]
    fn g_units_are_caught() {
        assert!(matches!(
            check_units(&stream(1.0, 1.0 / 9.81)),
            Err(ImuError::AccelLooksLikeG { mean_norm }) if (mean_norm - 1.0).abs() < 0.05
        ));
    }
}
