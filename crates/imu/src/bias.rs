//! IMU biases.

use nalgebra::Vector3;

/// Gyro and accelerometer biases, IMU frame: `measured = true + bias + noise`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bias {
    /// Gyro bias, rad/s.
    pub gyro: Vector3<f64>,
    /// Accelerometer bias, m/s^2.
    pub accel: Vector3<f64>,
}

impl Bias {
    /// A bias from its gyro (rad/s) and accelerometer (m/s^2) parts.
    pub fn new(gyro: Vector3<f64>, accel: Vector3<f64>) -> Self {
        Self { gyro, accel }
    }
}
