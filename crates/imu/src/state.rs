//! Navigation states and the preintegrated motion that moves one to the next.

use nalgebra::{UnitQuaternion, Vector3};

/// Pose and velocity of the IMU (body) frame `b` in the world `w`.
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavState {
    /// Orientation: maps vectors from `b` into `w`.
    pub R_w_b: UnitQuaternion<f64>,
    /// Velocity of `b` in `w`, m/s.
    pub v_w_b: Vector3<f64>,
    /// Position of `b` in `w`, m.
    pub p_w_b: Vector3<f64>,
}

/// Preintegrated motion between times `i` and `j`, expressed in the body frame at `i`
/// (Forster et al. 2017, eq. 33) and independent of the state at `i` and of gravity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuDelta {
    /// `t_j - t_i`, seconds.
    pub dt: f64,
    /// `Delta R_ij = R_w_bi^T R_w_bj`.
    pub delta_r: UnitQuaternion<f64>,
    /// `Delta v_ij = R_w_bi^T (v_j - v_i - g dt)`, m/s.
    pub delta_v: Vector3<f64>,
    /// `Delta p_ij = R_w_bi^T (p_j - p_i - v_i dt - g dt^2 / 2)`, m.
    pub delta_p: Vector3<f64>,
}

impl ImuDelta {
    /// The state at `j` from the state at `i` and gravity `gravity_w` (world frame, m/s^2,
    /// e.g. `(0, 0, -9.81)` for a z-up world):
    ///
    /// `R_j = R_i dR`, `v_j = v_i + g dt + R_i dv`, `p_j = p_i + v_i dt + g dt^2/2 + R_i dp`.
    #[allow(non_snake_case)]
    pub fn predict(&self, state_i: &NavState, gravity_w: &Vector3<f64>) -> NavState {
        let R_i = state_i.R_w_b;
        let dt = self.dt;
        NavState {
            R_w_b: R_i * self.delta_r,
            v_w_b: state_i.v_w_b + gravity_w * dt + R_i * self.delta_v,
            p_w_b: state_i.p_w_b
                + state_i.v_w_b * dt
                + gravity_w * (0.5 * dt * dt)
                + R_i * self.delta_p,
        }
    }

    /// The delta that [`predict`](Self::predict) would need to move `state_i` to `state_j`
    /// in `dt` seconds: the ground-truth delta when the states are ground truth.
    #[allow(non_snake_case)]
    pub fn between(
        state_i: &NavState,
        state_j: &NavState,
        dt: f64,
        gravity_w: &Vector3<f64>,
    ) -> Self {
        let R_i_inv = state_i.R_w_b.inverse();
        Self {
            dt,
            delta_r: R_i_inv * state_j.R_w_b,
            delta_v: R_i_inv * (state_j.v_w_b - state_i.v_w_b - gravity_w * dt),
            delta_p: R_i_inv
                * (state_j.p_w_b
                    - state_i.p_w_b
                    - state_i.v_w_b * dt
                    - gravity_w * (0.5 * dt * dt)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn between_inverts_predict() {
        let g = Vector3::new(0.0, 0.0, -9.81);
        let i = NavState {
            R_w_b: UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.4, 1.0)),
            v_w_b: Vector3::new(0.5, -0.1, 0.2),
            p_w_b: Vector3::new(1.0, 2.0, 3.0),
        };
        let delta = ImuDelta {
            dt: 0.4,
            delta_r: UnitQuaternion::from_scaled_axis(Vector3::new(0.05, 0.1, -0.2)),
            delta_v: Vector3::new(0.3, 0.0, 3.9),
            delta_p: Vector3::new(0.1, 0.02, 0.8),
        };
        let j = delta.predict(&i, &g);
        let back = ImuDelta::between(&i, &j, delta.dt, &g);
        assert_relative_eq!(back.delta_r, delta.delta_r, epsilon = 1e-14);
        assert_relative_eq!(back.delta_v, delta.delta_v, epsilon = 1e-13);
        assert_relative_eq!(back.delta_p, delta.delta_p, epsilon = 1e-13);
    }
}
