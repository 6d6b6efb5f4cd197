//! Sim(3): similarity transforms `p -> s R p + t`, their exponential and logarithm.
//!
//! `S_a_b` maps points from frame `b` into frame `a`, like an SE(3) `T_a_b`. Tangent
//! vectors are `zeta = [rho; phi; sigma]` with `rho` at `0..3`, `phi` at `3..6` and
//! `sigma = ln(s)` at [`SCALE`]. Perturbations are left: `S <- exp(delta) * S`.

use std::ops::Mul;

use nalgebra::{Isometry3, Matrix3, Matrix6, SVector, Translation3, UnitQuaternion, Vector3};

use crate::se3::{ROT, TRANS};
use crate::so3;

/// A sim(3) tangent vector `[rho; phi; sigma]` (nalgebra stops at `Vector6`).
pub type Vector7<T> = SVector<T, 7>;

/// Index of `sigma = ln(scale)` in a sim(3) tangent vector.
pub const SCALE: usize = 6;

/// A similarity transform `S_a_b`: `p_a = scale * rotation * p_b + translation`.
///
/// `scale` must be positive and finite; the fields are public, so this is not enforced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// Rotation part `R`.
    pub rotation: UnitQuaternion<f64>,
    /// Translation part `t`, in the units of frame `a`.
    pub translation: Vector3<f64>,
    /// Scale `s > 0`.
    pub scale: f64,
}

impl Sim3 {
    /// The identity similarity (`s = 1`, `R = I`, `t = 0`).
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// The similarity with scale 1 and the rotation and translation of `t`.
    pub fn from_isometry(t: &Isometry3<f64>) -> Self {
        Self {
            rotation: t.rotation,
            translation: t.translation.vector,
            scale: 1.0,
        }
    }

    /// ORB-SLAM's conversion of a corrected `S_c_w` to a camera pose: `[R | t / s]`.
    ///
    /// Since `S_c_w p_w / s = R p_w + t / s`, the result maps world points into the camera
    /// frame measured in units `1/s` of those of `S_c_w`'s target frame. After loop
    /// correction ORB-SLAM sets each keyframe's `T_c_w` to this, and rescales map points
    /// separately. Returns non-finite values if `scale` is 0.
    pub fn to_isometry_unscaled(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation / self.scale),
            self.rotation,
        )
    }

    /// Applies the similarity to a point: `s R p + t`.
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p * self.scale + self.translation
    }

    /// The inverse `S_b_a`: `p -> R^T (p - t) / s`.
    #[must_use]
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        let scale = 1.0 / self.scale;
        Self {
            rotation,
            translation: -(rotation * self.translation) * scale,
            scale,
        }
    }

    /// Exponential map of `zeta = [rho; phi; sigma]`: `s = e^sigma`, `R = exp(phi)`,
    /// `t = W(phi, sigma) rho`.
    ///
    /// ```
    /// use approx::assert_relative_eq;
    /// use ferroslam_geometry::sim3::{Sim3, Vector7};
    /// let zeta = Vector7::from([0.1, -0.2, 0.3, 0.4, 0.0, -0.5, 0.7]);
    /// assert_relative_eq!(Sim3::exp(&zeta).log(), zeta, epsilon = 1e-10);
    /// ```
    pub fn exp(zeta: &Vector7<f64>) -> Self {
        let rho = zeta.fixed_rows::<3>(TRANS.start).into_owned();
        let phi = zeta.fixed_rows::<3>(ROT.start).into_owned();
        let sigma = zeta[SCALE];
        Self {
            rotation: so3::exp(&phi),
            translation: w_matrix(&phi, sigma) * rho,
            scale: sigma.exp(),
        }
    }

    /// Logarithm map: the `zeta` with `Sim3::exp(&zeta) == *self`, rotation angle in
    /// `[0, pi]`. Non-finite if `scale <= 0`.
    pub fn log(&self) -> Vector7<f64> {
        let phi = so3::log(&self.rotation);
        let sigma = self.scale.ln();
        // W is invertible for rotation angles below 2 pi, which log guarantees.
        let rho = w_matrix(&phi, sigma)
            .lu()
            .solve(&self.translation)
            .unwrap_or_else(|| Vector3::repeat(f64::NAN));
        let mut zeta = Vector7::zeros();
        zeta.fixed_rows_mut::<3>(TRANS.start).copy_from(&rho);
        zeta.fixed_rows_mut::<3>(ROT.start).copy_from(&phi);
        zeta[SCALE] = sigma;
        zeta
    }
}

/// `W = integral_0^1 e^(sigma u) exp(u hat(phi)) du`, the translation Jacobian of the Sim(3)
/// exponential.
///
/// The closed form has several removable singularities (`sigma -> 0`, `theta -> 0`, both);
/// instead `W` is read off the matrix exponential of the block matrix
/// `[[sigma I + hat(phi), I], [0, 0]]`, whose top-right block is exactly this integral,
/// accurate everywhere.
///
/// Returns NaN for non-finite or absurd input (`|sigma| > 700`, where `e^sigma` overflows,
/// or `|phi| > 1e6`), which the Padé scaling-and-squaring would not survive.
fn w_matrix(phi: &Vector3<f64>, sigma: f64) -> Matrix3<f64> {
    if !(sigma.abs() <= 700.0 && phi.norm() <= 1e6) {
        return Matrix3::repeat(f64::NAN);
    }
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(so3::hat(phi) + Matrix3::identity() * sigma));
    m.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    m.exp().fixed_view::<3, 3>(0, 3).into_owned()
}

impl Mul for Sim3 {
    type Output = Sim3;

    /// Composition `S_a_c = S_a_b * S_b_c`.
    fn mul(self, rhs: Sim3) -> Sim3 {
        Sim3 {
            rotation: self.rotation * rhs.rotation,
            translation: self.rotation * rhs.translation * self.scale + self.translation,
            scale: self.scale * rhs.scale,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3;
    use approx::assert_relative_eq;
    use nalgebra::Vector6;

    #[test]
    fn w_matrix_matches_so3_left_jacobian_without_scale() {
        let phi = Vector3::new(0.3, -0.5, 0.2);
        assert_relative_eq!(
            w_matrix(&phi, 0.0),
            so3::left_jacobian(&phi),
            epsilon = 1e-13
        );
    }

    #[test]
    fn w_matrix_rejects_non_finite_input() {
        assert!(w_matrix(&Vector3::new(f64::NAN, 0.0, 0.0), 0.0)
            .iter()
            .all(|v| v.is_nan()));
        assert!(w_matrix(&Vector3::zeros(), f64::INFINITY)
            .iter()
            .all(|v| v.is_nan()));
    }

    #[test]
    fn w_matrix_pure_scale_is_scalar() {
        let sigma: f64 = 0.8;
        let expected = (sigma.exp() - 1.0) / sigma;
        assert_relative_eq!(
            w_matrix(&Vector3::zeros(), sigma),
            Matrix3::identity() * expected,
            epsilon = 1e-13
        );
    }

    #[test]
    fn w_matrix_matches_quadrature() {
        let (phi, sigma) = (Vector3::new(0.9, 0.4, -1.3), -0.6);
        let n = 20000;
        let integral = (0..n).fold(Matrix3::zeros(), |acc, k| {
            let u = (k as f64 + 0.5) / n as f64; // midpoint rule, error O(1/n^2)
            acc + so3::exp(&(phi * u)).to_rotation_matrix().into_inner() * (sigma * u).exp()
                / n as f64
        });
        assert_relative_eq!(w_matrix(&phi, sigma), integral, epsilon = 1e-8);
    }

    #[test]
    fn unit_scale_exp_equals_se3_exp() {
        let xi = Vector6::new(0.4, -0.3, 1.5, -0.2, 0.6, 0.1);
        let mut zeta = Vector7::zeros();
        zeta.fixed_rows_mut::<6>(0).copy_from(&xi);
        let s = Sim3::exp(&zeta);
        let t = se3::exp(&xi);
        assert_relative_eq!(s.to_isometry_unscaled(), t, epsilon = 1e-12);
    }

    #[test]
    fn inverse_and_composition() {
        let s = Sim3::exp(&Vector7::from([0.4, -0.3, 1.5, -0.2, 0.6, 0.1, 0.5]));
        let p = Vector3::new(1.0, -2.0, 3.0);
        assert_relative_eq!(
            s.inverse().transform_point(&s.transform_point(&p)),
            p,
            epsilon = 1e-12
        );
        let id = s * s.inverse();
        assert_relative_eq!(id.translation, Vector3::zeros(), epsilon = 1e-12);
        assert_relative_eq!(id.scale, 1.0, epsilon = 1e-12);
        assert_relative_eq!(
            (s * s).transform_point(&p),
            s.transform_point(&s.transform_point(&p)),
            epsilon = 1e-12
        );
    }

    #[test]
    fn to_isometry_unscaled_divides_translation() {
        let s = Sim3 {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::new(2.0, 4.0, 6.0),
            scale: 2.0,
        };
        assert_relative_eq!(
            s.to_isometry_unscaled().translation.vector,
            Vector3::new(1.0, 2.0, 3.0)
        );
    }
}
