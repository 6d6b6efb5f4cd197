//! A keyframe's 15 parameters in the visual-inertial BA and the inertial residual's
//! Jacobians with respect to them.
//!
//! The pose is the camera pose `T_c_w` (as in visual BA, LEFT perturbation
//! `T_c_w <- exp(xi) T_c_w`), while [`InertialFactor`] differentiates with respect to a LEFT
//! world-frame perturbation of the body pose `T_w_b = T_c_w^-1 T_b_c^-1`. Since
//! `(exp(xi) T_c_w)^-1 = T_w_c exp(-xi) = exp(-Ad(T_w_c) xi) T_w_c`, the body perturbation is
//! `delta = -Ad(T_w_c) xi` ([`body_perturbation_jacobian`]).

use std::ops::Range;

use ferroslam_geometry::se3;
use ferroslam_imu::residual::Vector9;
use ferroslam_imu::{ImuState, InertialFactor};
use nalgebra::{Isometry3, Matrix6, SMatrix};

/// Parameters of one keyframe state.
pub(crate) const STATE_DIM: usize = 15;
/// Camera pose tangent `xi = [rho; phi]` (left perturbation of `T_c_w`).
pub(crate) const POSE: Range<usize> = 0..6;
/// Velocity `v_w_b`, additive, m/s.
pub(crate) const VEL: Range<usize> = 6..9;
/// Gyro bias, additive, rad/s.
pub(crate) const GYRO_BIAS: Range<usize> = 9..12;
/// Accelerometer bias, additive, m/s^2.
pub(crate) const ACCEL_BIAS: Range<usize> = 12..15;

/// Jacobian of a keyframe's 9-residual (or 6 for the bias walk) over its 15 parameters.
pub(crate) type StateJacobian<const R: usize> = SMatrix<f64, R, STATE_DIM>;

/// `d delta / d xi = -Ad(T_w_c)`: the LEFT world-frame perturbation `delta` of the body pose
/// `T_w_b = T_c_w^-1 T_b_c^-1` caused by the LEFT perturbation `xi` of `T_c_w`. Exact (not
/// only to first order): `exp(xi) T_c_w` gives `exp(-Ad(T_w_c) xi) T_w_b`.
#[allow(non_snake_case)]
pub(crate) fn body_perturbation_jacobian(T_c_w: &Isometry3<f64>) -> Matrix6<f64> {
    -se3::adjoint(&T_c_w.inverse())
}

/// The inertial residual between keyframes `i` and `j` (body states `state_*` derived from
/// the camera poses `T_c_w_*`) and its Jacobians over the 15 parameters of each keyframe
/// (the columns of `j`'s biases are zero: only `i`'s bias enters the preintegration).
#[allow(non_snake_case)]
pub(crate) fn linearize_inertial(
    factor: &InertialFactor,
    T_c_w_i: &Isometry3<f64>,
    state_i: &ImuState,
    T_c_w_j: &Isometry3<f64>,
    state_j: &ImuState,
) -> (Vector9, StateJacobian<9>, StateJacobian<9>) {
    let (r, jac) = factor.evaluate(state_i, state_j);
    let mut d_i = StateJacobian::<9>::zeros();
    let mut d_j = StateJacobian::<9>::zeros();
    d_i.fixed_columns_mut::<6>(POSE.start)
        .copy_from(&(jac.d_res_d_pose_i * body_perturbation_jacobian(T_c_w_i)));
    d_i.fixed_columns_mut::<3>(VEL.start)
        .copy_from(&jac.d_res_d_vel_i);
    d_i.fixed_columns_mut::<3>(GYRO_BIAS.start)
        .copy_from(&jac.d_res_d_bias_gyro_i);
    d_i.fixed_columns_mut::<3>(ACCEL_BIAS.start)
        .copy_from(&jac.d_res_d_bias_accel_i);
    d_j.fixed_columns_mut::<6>(POSE.start)
        .copy_from(&(jac.d_res_d_pose_j * body_perturbation_jacobian(T_c_w_j)));
    d_j.fixed_columns_mut::<3>(VEL.start)
        .copy_from(&jac.d_res_d_vel_j);
    (r, d_i, d_j)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inertial_ba::problem::body_pose;
    use ferroslam_geometry::testing::check_jacobian;
    use ferroslam_imu::{Bias, ImuParams, Preintegrated};
    use nalgebra::{DMatrix, DVector, Translation3, UnitQuaternion, Vector3, Vector6};

    fn pose(t: [f64; 3], r: [f64; 3]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(r)),
        )
    }

    #[allow(non_snake_case)]
    fn T_b_c() -> Isometry3<f64> {
        pose([-0.02, 0.065, 0.01], [1.2, -1.1, 0.3])
    }

    #[test]
    #[allow(non_snake_case)]
    fn body_perturbation_is_minus_adjoint_of_camera_pose() {
        let T_c_w = pose([0.4, -1.3, 2.0], [0.3, 0.9, -0.4]);
        let base = body_pose(&T_c_w, &T_b_c());
        let analytic = body_perturbation_jacobian(&T_c_w);
        let f = |x: &DVector<f64>| {
            let xi = Vector6::from_column_slice(x.as_slice());
            let moved = body_pose(&(se3::exp(&xi) * T_c_w), &T_b_c());
            DVector::from_column_slice(se3::log(&(moved * base.inverse())).as_slice())
        };
        check_jacobian(
            "d delta_body / d xi_camera",
            &DMatrix::from_column_slice(6, 6, analytic.as_slice()),
            f,
            &DVector::zeros(6),
            1e-6,
            1e-8,
        );
        // Exact, not only to first order.
        let xi = Vector6::new(0.3, -0.2, 0.5, 0.4, -0.6, 0.2);
        let moved = body_pose(&(se3::exp(&xi) * T_c_w), &T_b_c());
        let predicted = se3::exp(&(analytic * xi)) * base;
        assert!((moved.to_homogeneous() - predicted.to_homogeneous()).norm() < 1e-12);
    }

    /// Perturbs the 15 parameters of a keyframe as the solver does.
    #[allow(non_snake_case)]
    fn perturbed(
        x: &[f64],
        T_c_w: &Isometry3<f64>,
        v: &Vector3<f64>,
        b: &Bias,
    ) -> (Isometry3<f64>, ImuState) {
        let T = se3::exp(&Vector6::from_column_slice(&x[POSE])) * T_c_w;
        let state = ImuState {
            T_w_b: body_pose(&T, &T_b_c()),
            v_w_b: v + Vector3::from_column_slice(&x[VEL]),
            bias: Bias::new(
                b.gyro + Vector3::from_column_slice(&x[GYRO_BIAS]),
                b.accel + Vector3::from_column_slice(&x[ACCEL_BIAS]),
            ),
        };
        (T, state)
    }

    #[test]
    #[allow(non_snake_case)]
    fn inertial_jacobians_over_camera_states_match_central_differences() {
        let params = ImuParams::euroc();
        let mut pre = Preintegrated::new(
            Bias::new(
                Vector3::new(0.01, -0.02, 0.015),
                Vector3::new(0.1, 0.05, -0.08),
            ),
            &params,
        )
        .unwrap();
        for k in 0..60 {
            let t = k as f64 * 0.005;
            let gyro = Vector3::new(0.5 * (3.0 * t).sin(), -0.3 + t, 0.8 * (2.0 * t).cos());
            let accel = Vector3::new(1.0 + t, -0.5 * (4.0 * t).sin(), 9.5 + 0.3 * t);
            pre.integrate(0.005, &gyro, &accel).unwrap();
        }
        let factor = InertialFactor::new(pre, Vector3::new(0.0, 0.0, -9.81)).unwrap();
        let (T_i, T_j) = (
            pose([0.4, -1.3, 2.0], [0.3, 0.9, -0.4]),
            pose([0.1, -1.1, 2.3], [0.5, 0.7, -0.2]),
        );
        let (v_i, v_j) = (Vector3::new(0.4, 0.1, -0.3), Vector3::new(0.9, -0.2, 0.1));
        // Bias of i away from the linearisation bias so the bias terms are exercised.
        let (b_i, b_j) = (
            Bias::new(Vector3::new(0.03, -0.01, 0.0), Vector3::new(0.2, -0.1, 0.0)),
            Bias::default(),
        );
        let eval = |x: &DVector<f64>| {
            let (Ti, si) = perturbed(&x.as_slice()[..STATE_DIM], &T_i, &v_i, &b_i);
            let (Tj, sj) = perturbed(&x.as_slice()[STATE_DIM..], &T_j, &v_j, &b_j);
            linearize_inertial(&factor, &Ti, &si, &Tj, &sj)
        };
        let x0 = DVector::zeros(2 * STATE_DIM);
        let (r, d_i, d_j) = eval(&x0);
        assert!(
            r.norm() > 0.1,
            "test states must be far from a zero residual"
        );
        let mut analytic = DMatrix::zeros(9, 2 * STATE_DIM);
        analytic.columns_mut(0, STATE_DIM).copy_from(&d_i);
        analytic.columns_mut(STATE_DIM, STATE_DIM).copy_from(&d_j);
        check_jacobian(
            "inertial residual over [state i; state j] (camera pose, v, b_g, b_a)",
            &analytic,
            |x| DVector::from_column_slice(eval(x).0.as_slice()),
            &x0,
            1e-6,
            1e-6,
        );
    }
}
