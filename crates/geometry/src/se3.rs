//! SE(3): rigid-body motions, their exponential and logarithm maps, and the adjoint.
//!
//! Tangent vectors are `xi = [rho; phi]`: translation part `rho` at [`TRANS`], rotation
//! part `phi` at [`ROT`]. `exp(xi) = [exp(phi) | J_l(phi) rho]` (the true group exponential,
//! not the "rotation and translation separately" retraction). Perturbations are left:
//! `T <- exp(delta) * T`.

use std::ops::Range;

use nalgebra::{Isometry3, Matrix6, Translation3, Vector6};

use crate::so3;

/// A rigid-body transform `T_a_b`, mapping points from frame `b` to frame `a`.
pub type SE3 = Isometry3<f64>;

/// Indices of the translation part `rho` in an se(3) tangent vector.
pub const TRANS: Range<usize> = 0..3;

/// Indices of the rotation part `phi` in an se(3) tangent vector.
pub const ROT: Range<usize> = 3..6;

/// Exponential map of `xi = [rho; phi]` (metres; radians).
///
/// ```
/// use approx::assert_relative_eq;
/// use ferroslam_geometry::se3;
/// use nalgebra::Vector6;
/// let xi = Vector6::new(0.1, -0.2, 0.3, 0.4, 0.0, -0.5);
/// assert_relative_eq!(se3::log(&se3::exp(&xi)), xi, epsilon = 1e-12);
/// ```
pub fn exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let rho = xi.fixed_rows::<3>(TRANS.start).into_owned();
    let phi = xi.fixed_rows::<3>(ROT.start).into_owned();
    let t = so3::left_jacobian(&phi) * rho;
    Isometry3::from_parts(Translation3::from(t), so3::exp(&phi))
}

/// Logarithm map: the `xi = [rho; phi]` with `exp(xi) == t`, rotation angle in `[0, pi]`.
pub fn log(t: &Isometry3<f64>) -> Vector6<f64> {
    let phi = so3::log(&t.rotation);
    let rho = so3::left_jacobian_inverse(&phi) * t.translation.vector;
    let mut xi = Vector6::zeros();
    xi.fixed_rows_mut::<3>(TRANS.start).copy_from(&rho);
    xi.fixed_rows_mut::<3>(ROT.start).copy_from(&phi);
    xi
}

/// Adjoint of `t = [R | p]` for the `[rho; phi]` order: `[[R, hat(p) R], [0, R]]`.
///
/// Satisfies `t * exp(xi) * t^-1 == exp(adjoint(t) * xi)`. It moves a left perturbation
/// across a transform: for `T_a_b`, `exp(delta_a) * T_a_b == T_a_b * exp(delta_b)` with
/// `delta_a = adjoint(T_a_b) * delta_b`.
pub fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(TRANS.start, TRANS.start)
        .copy_from(&r);
    ad.fixed_view_mut::<3, 3>(TRANS.start, ROT.start)
        .copy_from(&(so3::hat(&t.translation.vector) * r));
    ad.fixed_view_mut::<3, 3>(ROT.start, ROT.start)
        .copy_from(&r);
    ad
}

/// Left retraction `exp(delta) * T` (delta in the frame `T` maps into), with the rotation
/// renormalised: products of quaternions drift off unit norm by rounding, and through a
/// constant-velocity model (`T_k+1 = T_k T_k-1^-1 T_k`) that drift compounds geometrically
/// until poses scale points by `|q|^2`. Every iterative update should go through here.
#[allow(non_snake_case)]
pub fn retract(delta: &Vector6<f64>, T: &Isometry3<f64>) -> Isometry3<f64> {
    let mut out = exp(delta) * T;
    out.rotation.renormalize();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::Vector3;

    #[test]
    fn exp_of_pure_translation_is_translation() {
        let xi = Vector6::new(1.0, 2.0, 3.0, 0.0, 0.0, 0.0);
        assert_relative_eq!(exp(&xi).translation.vector, Vector3::new(1.0, 2.0, 3.0));
    }

    #[test]
    fn exp_log_round_trip_near_pi() {
        let xi = Vector6::new(0.5, -1.0, 2.0, 0.0, std::f64::consts::PI - 1e-7, 0.0);
        assert_relative_eq!(log(&exp(&xi)), xi, epsilon = 1e-8);
    }

    #[test]
    fn adjoint_moves_perturbation_across_transform() {
        let t = exp(&Vector6::new(0.3, -0.1, 1.2, 0.2, -0.4, 0.7));
        let xi = Vector6::new(-0.2, 0.5, 0.1, 0.3, 0.1, -0.2);
        let lhs = t * exp(&xi) * t.inverse();
        assert_relative_eq!(lhs, exp(&(adjoint(&t) * xi)), epsilon = 1e-12);
    }
}
