//! IMU noise model: continuous-time white-noise densities, bias random walks and rate.

use std::path::Path;

use nalgebra::Matrix3;

use crate::ImuError;

/// Continuous-time IMU noise model (Kalibr / EuRoC `sensor.yaml` conventions).
///
/// Over a step of `dt` seconds the discrete white noise has standard deviation
/// `density / sqrt(dt)` (variance `density^2 / dt`), and a bias drifts by
/// `random_walk * sqrt(dt)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuParams {
    /// Gyro white-noise density, rad/s/sqrt(Hz).
    pub gyro_noise_density: f64,
    /// Gyro bias random walk, rad/s^2/sqrt(Hz).
    pub gyro_random_walk: f64,
    /// Accelerometer white-noise density, m/s^2/sqrt(Hz).
    pub accel_noise_density: f64,
    /// Accelerometer bias random walk, m/s^3/sqrt(Hz).
    pub accel_random_walk: f64,
    /// Nominal sample rate, Hz.
    pub rate_hz: f64,
}

impl ImuParams {
    /// The EuRoC MAV ADIS16448 values (`imu0/sensor.yaml` of every EuRoC sequence).
    pub fn euroc() -> Self {
        Self {
            gyro_noise_density: 1.6968e-4,
            gyro_random_walk: 1.9393e-5,
            accel_noise_density: 2.0e-3,
            accel_random_walk: 3.0e-3,
            rate_hz: 200.0,
        }
    }

    /// Parses an ASL/Kalibr `sensor.yaml` (keys `gyroscope_noise_density`,
    /// `gyroscope_random_walk`, `accelerometer_noise_density`, `accelerometer_random_walk`,
    /// `rate_hz`; other lines are ignored), then [`validate`](Self::validate)s it.
    ///
    /// A missing or unparsable key gives [`ImuError::InvalidParameter`] with value NaN.
    pub fn from_euroc_yaml(text: &str) -> Result<Self, ImuError> {
        let value = |key: &'static str| -> Result<f64, ImuError> {
            text.lines()
                .filter_map(|line| line.split('#').next()?.split_once(':'))
                .find(|(k, _)| k.trim() == key)
                .and_then(|(_, v)| v.trim().parse::<f64>().ok())
                .ok_or(ImuError::InvalidParameter {
                    name: key,
                    value: f64::NAN,
                    reason: "missing or not a number in the yaml",
                })
        };
        let params = Self {
            gyro_noise_density: value("gyroscope_noise_density")?,
            gyro_random_walk: value("gyroscope_random_walk")?,
            accel_noise_density: value("accelerometer_noise_density")?,
            accel_random_walk: value("accelerometer_random_walk")?,
            rate_hz: value("rate_hz")?,
        };
        params.validate()?;
        Ok(params)
    }

    /// Reads and parses an EuRoC `imu0/sensor.yaml`; see [`from_euroc_yaml`](Self::from_euroc_yaml).
    pub fn from_euroc_file(path: impl AsRef<Path>) -> Result<Self, ImuError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| ImuError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::from_euroc_yaml(&text)
    }

    /// Checks that the noise terms are finite and non-negative and the rate positive.
    pub fn validate(&self) -> Result<(), ImuError> {
        let noise = [
            ("gyro_noise_density", self.gyro_noise_density),
            ("gyro_random_walk", self.gyro_random_walk),
            ("accel_noise_density", self.accel_noise_density),
            ("accel_random_walk", self.accel_random_walk),
        ];
        for (name, value) in noise {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ImuError::InvalidParameter {
                    name,
                    value,
                    reason: "must be finite and >= 0",
                });
            }
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(ImuError::InvalidParameter {
                name: "rate_hz",
                value: self.rate_hz,
                reason: "must be finite and > 0",
            });
        }
        Ok(())
    }

    /// Covariances of the (gyro, accel) bias drift over `dt` seconds:
    /// `random_walk^2 * dt * I`, rad^2/s^2 and m^2/s^4.
    pub fn bias_walk_covariance(&self, dt: f64) -> (Matrix3<f64>, Matrix3<f64>) {
        (
            Matrix3::identity() * (self.gyro_random_walk.powi(2) * dt),
            Matrix3::identity() * (self.accel_random_walk.powi(2) * dt),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EUROC_YAML: &str = "%YAML:1.0\nsensor_type: imu\nrate_hz: 200\n\
        gyroscope_noise_density: 1.6968e-04     # [ rad / s / sqrt(Hz) ]\n\
        gyroscope_random_walk: 1.9393e-05\n\
        accelerometer_noise_density: 2.0000e-3  # [ m / s^2 / sqrt(Hz) ]\n\
        accelerometer_random_walk: 3.0000e-3    # [ m / s^3 / sqrt(Hz) ].\n";

    #[test]
    fn parses_the_euroc_yaml() {
        assert_eq!(
            ImuParams::from_euroc_yaml(EUROC_YAML),
            Ok(ImuParams::euroc())
        );
    }

    #[test]
    fn missing_or_bad_keys_are_errors() {
        let missing = EUROC_YAML.replace("rate_hz: 200", "");
        assert!(matches!(
            ImuParams::from_euroc_yaml(&missing),
            Err(ImuError::InvalidParameter {
                name: "rate_hz",
                ..
            })
        ));
        let negative = EUROC_YAML.replace("random_walk: 1.9393e-05", "random_walk: -1");
        assert!(matches!(
            ImuParams::from_euroc_yaml(&negative),
            Err(ImuError::InvalidParameter {
                name: "gyro_random_walk",
                ..
            })
        ));
        assert!(matches!(
            ImuParams::from_euroc_file("/nonexistent/sensor.yaml"),
            Err(ImuError::Io { .. })
        ));
    }
}
