//! One IMU sample and the checks every stream must pass before it is integrated.

use nalgebra::Vector3;

use crate::ImuError;

/// One IMU reading in the IMU (body) frame `b`.
///
/// `gyro_rad_s` is the measured angular velocity of `b` relative to the world, in `b`,
/// rad/s. `accel_m_s2` is the measured specific force in `b`, m/s^2:
/// `R_w_b^T * (a_w - g_w)` plus bias and noise, so a resting IMU reads `+9.81` upwards.
/// Both include the sensor biases ([`crate::Bias`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuMeasurement {
    /// Timestamp, seconds (same clock as the camera frames).
    pub t_s: f64,
    /// Angular velocity, rad/s, IMU frame.
    pub gyro_rad_s: Vector3<f64>,
    /// Specific force, m/s^2, IMU frame.
    pub accel_m_s2: Vector3<f64>,
}

impl ImuMeasurement {
    /// A measurement from its timestamp (s), gyro (rad/s) and accelerometer (m/s^2).
    pub fn new(t_s: f64, gyro_rad_s: Vector3<f64>, accel_m_s2: Vector3<f64>) -> Self {
        Self {
            t_s,
            gyro_rad_s,
            accel_m_s2,
        }
    }

    fn is_finite(&self) -> bool {
        self.t_s.is_finite()
            && self.gyro_rad_s.iter().all(|v| v.is_finite())
            && self.accel_m_s2.iter().all(|v| v.is_finite())
    }
}

/// Checks that every sample is finite and that timestamps strictly increase.
///
/// Fails with [`ImuError::NonFinite`] or [`ImuError::OutOfOrder`] naming the first bad
/// sample. An empty slice passes.
pub fn check_stream(measurements: &[ImuMeasurement]) -> Result<(), ImuError> {
    for (index, m) in measurements.iter().enumerate() {
        if !m.is_finite() {
            return Err(ImuError::NonFinite { index });
        }
        if index > 0 {
            let previous_s = measurements[index - 1].t_s;
            if m.t_s <= previous_s {
                return Err(ImuError::OutOfOrder {
                    index,
                    t_s: m.t_s,
                    previous_s,
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_s: f64) -> ImuMeasurement {
        ImuMeasurement::new(t_s, Vector3::zeros(), Vector3::new(0.0, 0.0, 9.81))
    }

    #[test]
    fn accepts_increasing_finite_samples() {
        assert_eq!(check_stream(&[]), Ok(()));
        assert_eq!(check_stream(&[sample(0.0), sample(0.005)]), Ok(()));
    }

    #[test]
    fn rejects_out_of_order_and_duplicates() {
        let err = check_stream(&[sample(0.0), sample(0.01), sample(0.005)]).unwrap_err();
        assert_eq!(
            err,
            ImuError::OutOfOrder {
                index: 2,
                t_s: 0.005,
                previous_s: 0.01
            }
        );
        assert!(matches!(
            check_stream(&[sample(0.0), sample(0.0)]),
            Err(ImuError::OutOfOrder { index: 1, .. })
        ));
    }

    #[test]
    fn rejects_non_finite_values() {
        let mut bad = sample(0.005);
        bad.gyro_rad_s.y = f64::NAN;
        assert_eq!(
            check_stream(&[sample(0.0), bad]),
            Err(ImuError::NonFinite { index: 1 })
        );
        let mut bad = sample(f64::INFINITY);
        bad.t_s = f64::INFINITY;
        assert_eq!(check_stream(&[bad]), Err(ImuError::NonFinite { index: 0 }));
    }
}
