//! SO(3): rotation vectors, the exponential and logarithm maps, and their Jacobians.
//!
//! A rotation vector `phi` (radians) is axis times angle, `theta = |phi|`. Rotations are
//! unit quaternions. Jacobian conventions (first order in a small `delta`):
//!
//! * left:  `exp(phi + delta) ≈ exp(left_jacobian(phi) * delta) * exp(phi)`
//! * right: `exp(phi + delta) ≈ exp(phi) * exp(right_jacobian(phi) * delta)`
//!
//! All functions are smooth through `theta = 0` (Taylor expansions below a threshold) and
//! never panic; non-finite input gives non-finite output.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// Below this angle (radians) the Jacobian coefficients use their Taylor series, where the
/// closed forms lose digits to cancellation.
const SMALL_ANGLE: f64 = 1e-2;

/// Skew-symmetric matrix of `v`: `hat(v) * w == v.cross(&w)`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Exponential map: the rotation by angle `|phi|` (radians) about `phi / |phi|`.
pub fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta = phi.norm();
    let half = 0.5 * theta;
    // sin(theta/2)/theta, exact at 0 through its series.
    let k = if theta < 1e-6 {
        0.5 - theta * theta / 48.0
    } else {
        half.sin() / theta
    };
    let v = phi * k;
    UnitQuaternion::new_unchecked(Quaternion::new(half.cos(), v.x, v.y, v.z))
}

/// Logarithm map: the rotation vector of `q`, with angle in `[0, pi]`.
///
/// Robust near the identity (series) and near `pi` (uses `atan2`, never `acos`). At exactly
/// `pi` either of the two valid vectors `±pi * axis` may be returned.
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (mut w, mut v) = (q.w, q.imag());
    // q and -q are the same rotation; pick w >= 0 so the angle is <= pi.
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let n = v.norm();
    // theta / sin(theta/2) = 2 atan2(n, w) / n; finite and accurate for n > 0.
    let k = if n < 1e-10 {
        2.0 / w - 2.0 * n * n / (3.0 * w * w * w)
    } else {
        2.0 * n.atan2(w) / n
    };
    v * k
}

/// `(1 - cos t) / t^2` and `(t - sin t) / t^3` for `t = |phi|`.
fn jacobian_coefficients(theta: f64) -> (f64, f64) {
    let t2 = theta * theta;
    if theta < SMALL_ANGLE {
        let b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2 * t2 * t2 / 40320.0;
        let c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2 * t2 * t2 / 362880.0;
        (b, c)
    } else {
        let s = (0.5 * theta).sin();
        // 2 sin^2(t/2) avoids the cancellation in 1 - cos t.
        (2.0 * s * s / t2, (theta - theta.sin()) / (t2 * theta))
    }
}

/// `1/t^2 - (1 + cos t) / (2 t sin t)`, written with `cot(t/2)` so it stays finite at `pi`.
fn inverse_coefficient(theta: f64) -> f64 {
    let t2 = theta * theta;
    if theta < SMALL_ANGLE {
        1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2 * t2 * t2 / 1209600.0
    } else {
        1.0 / t2 - 0.5 / ((0.5 * theta).tan() * theta)
    }
}

/// Left Jacobian `J_l(phi) = I + (1-cos t)/t^2 hat(phi) + (t-sin t)/t^3 hat(phi)^2`.
///
/// `exp(phi + delta) ≈ exp(J_l delta) exp(phi)`. It is also the `V` matrix of the SE(3)
/// exponential: `t = J_l(phi) rho`.
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let (b, c) = jacobian_coefficients(phi.norm());
    let h = hat(phi);
    Matrix3::identity() + h * b + h * h * c
}

/// Right Jacobian `J_r(phi) = J_l(-phi)`: `exp(phi + delta) ≈ exp(phi) exp(J_r delta)`.
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    left_jacobian(&-phi)
}

/// Inverse of [`left_jacobian`], in closed form.
///
/// Finite for `|phi| < 2 pi` (so for every output of [`log`]); singular at `2 pi`.
pub fn left_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let e = inverse_coefficient(phi.norm());
    let h = hat(phi);
    Matrix3::identity() - h * 0.5 + h * h * e
}

/// Inverse of [`right_jacobian`]: `J_r^-1(phi) = J_l^-1(-phi)`. Finite for `|phi| < 2 pi`.
pub fn right_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    left_jacobian_inverse(&-phi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn hat_is_cross_product() {
        let (a, b) = (Vector3::new(0.3, -1.2, 2.0), Vector3::new(-0.7, 0.4, 1.1));
        assert_relative_eq!(hat(&a) * b, a.cross(&b), epsilon = 1e-15);
    }

    #[test]
    fn exp_matches_nalgebra_and_log_inverts_it() {
        for phi in [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1e-12, -2e-12, 0.0),
            Vector3::new(1e-5, 2e-5, -3e-5),
            Vector3::new(0.3, -0.2, 0.9),
            Vector3::new(0.0, 0.0, std::f64::consts::PI - 1e-9),
        ] {
            let q = exp(&phi);
            assert_relative_eq!(q, UnitQuaternion::from_scaled_axis(phi), epsilon = 1e-14);
            assert_relative_eq!(log(&q), phi, epsilon = 1e-12);
        }
    }

    #[test]
    fn log_at_pi_is_finite_and_exact() {
        let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI);
        let phi = log(&q);
        assert_relative_eq!(phi.norm(), std::f64::consts::PI, epsilon = 1e-12);
        assert_relative_eq!(exp(&phi), q, epsilon = 1e-12);
    }

    #[test]
    fn jacobian_inverses_are_inverses() {
        for phi in [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1e-3, -2e-3, 5e-3),
            Vector3::new(0.3, -0.2, 0.9),
            Vector3::new(0.0, 3.1, 0.0),
        ] {
            let i = Matrix3::identity();
            assert_relative_eq!(
                left_jacobian(&phi) * left_jacobian_inverse(&phi),
                i,
                epsilon = 1e-12
            );
            assert_relative_eq!(
                right_jacobian(&phi) * right_jacobian_inverse(&phi),
                i,
                epsilon = 1e-12
            );
        }
    }

    #[test]
    fn series_and_closed_forms_agree_at_the_threshold() {
        let (lo, hi) = (SMALL_ANGLE * (1.0 - 1e-9), SMALL_ANGLE * (1.0 + 1e-9));
        let (b0, c0) = jacobian_coefficients(lo);
        let (b1, c1) = jacobian_coefficients(hi);
        assert_relative_eq!(b0, b1, max_relative = 1e-10);
        assert_relative_eq!(c0, c1, max_relative = 1e-10);
        assert_relative_eq!(
            inverse_coefficient(lo),
            inverse_coefficient(hi),
            max_relative = 1e-10
        );
    }
}
