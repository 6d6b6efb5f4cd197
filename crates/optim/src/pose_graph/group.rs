//! The Lie groups a pose graph can live on: SE(3) (`Isometry3`, 6 dof) and Sim(3) (7 dof).
//!
//! The solver only needs composition, inverse, `exp` / `log`, the adjoint `Ad(g)` and the
//! small adjoint `ad(xi)`; everything else (the residual and its Jacobians) is written once
//! in terms of these. Tangent orders follow `ferroslam_geometry`: se(3) `[rho; phi]`,
//! sim(3) `[rho; phi; sigma]`; perturbations are left, `g <- exp(delta) * g`.

use ferroslam_geometry::sim3::{Sim3, SCALE};
use ferroslam_geometry::{se3, so3};
use nalgebra::{Isometry3, Matrix3, SMatrix, SVector, Vector3};

const RHO: usize = se3::TRANS.start;
const PHI: usize = se3::ROT.start;

/// A matrix Lie group with `D` degrees of freedom, as used by the pose-graph solver.
pub trait PoseGroup<const D: usize>: Copy + Send + Sync + std::fmt::Debug {
    /// Group composition `self * other`.
    fn compose(&self, other: &Self) -> Self;
    /// Group inverse.
    fn inverse(&self) -> Self;
    /// Exponential map of a tangent vector.
    fn exp(xi: &SVector<f64, D>) -> Self;
    /// Logarithm map (rotation angle in `[0, pi]`).
    fn log(&self) -> SVector<f64, D>;
    /// Adjoint `Ad(g)`: `g exp(xi) g^-1 = exp(Ad(g) xi)`.
    fn adjoint(&self) -> SMatrix<f64, D, D>;
    /// Small adjoint `ad(xi)`: `ad(xi) eta = [xi, eta]` (Lie bracket).
    fn ad(xi: &SVector<f64, D>) -> SMatrix<f64, D, D>;
    /// True if every component is finite (and the scale, if any, positive).
    fn is_valid(&self) -> bool;

    /// Inverse right Jacobian: `log(exp(xi) exp(d)) ≈ xi + J_r^-1(xi) d`. Defaults to the
    /// truncated series [`bernoulli_right_jacobian_inverse`].
    fn right_jacobian_inverse(xi: &SVector<f64, D>) -> SMatrix<f64, D, D> {
        bernoulli_right_jacobian_inverse::<Self, D>(xi)
    }

    /// Left update `exp(delta) * self`, renormalised against rounding drift.
    #[must_use]
    fn retract(&self, delta: &SVector<f64, D>) -> Self {
        Self::exp(delta).compose(self)
    }
}

impl PoseGroup<6> for Isometry3<f64> {
    fn compose(&self, other: &Self) -> Self {
        self * other
    }

    fn inverse(&self) -> Self {
        Isometry3::inverse(self)
    }

    fn exp(xi: &SVector<f64, 6>) -> Self {
        se3::exp(xi)
    }

    fn log(&self) -> SVector<f64, 6> {
        se3::log(self)
    }

    fn adjoint(&self) -> SMatrix<f64, 6, 6> {
        se3::adjoint(self)
    }

    /// `[[hat(phi), hat(rho)], [0, hat(phi)]]`.
    fn ad(xi: &SVector<f64, 6>) -> SMatrix<f64, 6, 6> {
        let rho = so3::hat(&xi.fixed_rows::<3>(RHO).into_owned());
        let phi = so3::hat(&xi.fixed_rows::<3>(PHI).into_owned());
        let mut m = SMatrix::<f64, 6, 6>::zeros();
        m.fixed_view_mut::<3, 3>(RHO, RHO).copy_from(&phi);
        m.fixed_view_mut::<3, 3>(RHO, PHI).copy_from(&rho);
        m.fixed_view_mut::<3, 3>(PHI, PHI).copy_from(&phi);
        m
    }

    fn is_valid(&self) -> bool {
        self.translation.vector.iter().all(|v| v.is_finite())
            && self.rotation.coords.iter().all(|v| v.is_finite())
    }

    fn retract(&self, delta: &SVector<f64, 6>) -> Self {
        se3::retract(delta, self)
    }

    /// Closed form: `J_r^-1(xi) = J_l^-1(-xi)` with
    /// `J_l^-1 = [[J^-1, -J^-1 Q J^-1], [0, J^-1]]`, `J = so3::left_jacobian(phi)` and
    /// Barfoot's `Q(rho, phi)` (State Estimation for Robotics, eq. 7.86).
    fn right_jacobian_inverse(xi: &SVector<f64, 6>) -> SMatrix<f64, 6, 6> {
        let rho = -xi.fixed_rows::<3>(RHO).into_owned();
        let phi = -xi.fixed_rows::<3>(PHI).into_owned();
        let j_inv = so3::left_jacobian_inverse(&phi);
        let mut m = SMatrix::<f64, 6, 6>::zeros();
        m.fixed_view_mut::<3, 3>(RHO, RHO).copy_from(&j_inv);
        m.fixed_view_mut::<3, 3>(RHO, PHI)
            .copy_from(&(-j_inv * barfoot_q(&rho, &phi) * j_inv));
        m.fixed_view_mut::<3, 3>(PHI, PHI).copy_from(&j_inv);
        m
    }
}

/// The translation-rotation block `Q(rho, phi)` of the SE(3) left Jacobian.
fn barfoot_q(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = phi.norm_squared();
    let t = t2.sqrt();
    // Taylor series below 1e-2 rad: the closed forms cancel catastrophically there.
    let (c1, c2, c3) = if t < 1e-2 {
        (
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
            1.0 / 24.0 - t2 / 720.0 + t2 * t2 / 40320.0,
            1.0 / 120.0 - t2 / 2520.0 + t2 * t2 / 120960.0,
        )
    } else {
        let (s, c) = t.sin_cos();
        (
            (t - s) / (t2 * t),
            (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2),
            (2.0 * t - 3.0 * s + t * c) / (2.0 * t2 * t2 * t),
        )
    };
    let r = so3::hat(rho);
    let p = so3::hat(phi);
    let pr = p * r;
    let rp = r * p;
    let prp = pr * p;
    r * 0.5 + (pr + rp + prp) * c1 + (p * pr + rp * p - prp * 3.0) * c2 + (prp * p + p * prp) * c3
}

impl PoseGroup<7> for Sim3 {
    fn compose(&self, other: &Self) -> Self {
        *self * *other
    }

    fn inverse(&self) -> Self {
        Sim3::inverse(self)
    }

    fn exp(xi: &SVector<f64, 7>) -> Self {
        Sim3::exp(xi)
    }

    fn log(&self) -> SVector<f64, 7> {
        Sim3::log(self)
    }

    /// For `S = [sR | t]`: `[[sR, hat(t) R, -t], [0, R, 0], [0, 0, 1]]`.
    fn adjoint(&self) -> SMatrix<f64, 7, 7> {
        let r = self.rotation.to_rotation_matrix().into_inner();
        let mut m = SMatrix::<f64, 7, 7>::zeros();
        m.fixed_view_mut::<3, 3>(RHO, RHO)
            .copy_from(&(r * self.scale));
        m.fixed_view_mut::<3, 3>(RHO, PHI)
            .copy_from(&(so3::hat(&self.translation) * r));
        m.fixed_view_mut::<3, 1>(RHO, SCALE)
            .copy_from(&-self.translation);
        m.fixed_view_mut::<3, 3>(PHI, PHI).copy_from(&r);
        m[(SCALE, SCALE)] = 1.0;
        m
    }

    /// `[[hat(phi) + sigma I, hat(rho), -rho], [0, hat(phi), 0], [0, 0, 0]]`.
    fn ad(xi: &SVector<f64, 7>) -> SMatrix<f64, 7, 7> {
        let rho = xi.fixed_rows::<3>(RHO).into_owned();
        let phi = so3::hat(&xi.fixed_rows::<3>(PHI).into_owned());
        let sigma = xi[SCALE];
        let mut m = SMatrix::<f64, 7, 7>::zeros();
        m.fixed_view_mut::<3, 3>(RHO, RHO)
            .copy_from(&(phi + Matrix3::identity() * sigma));
        m.fixed_view_mut::<3, 3>(RHO, PHI)
            .copy_from(&so3::hat(&rho));
        m.fixed_view_mut::<3, 1>(RHO, SCALE).copy_from(&-rho);
        m.fixed_view_mut::<3, 3>(PHI, PHI).copy_from(&phi);
        m
    }

    fn is_valid(&self) -> bool {
        self.translation.iter().all(|v| v.is_finite())
            && self.rotation.coords.iter().all(|v| v.is_finite())
            && self.scale.is_finite()
            && self.scale > 0.0
    }

    fn retract(&self, delta: &SVector<f64, 7>) -> Self {
        let mut out = Sim3::exp(delta) * *self;
        out.rotation.renormalize();
        out
    }
}

/// Inverse right Jacobian `J_r^-1(xi) = ad(xi) / (1 - e^-ad(xi))`, from its Bernoulli series
/// `I + ad/2 + ad^2/12 - ad^4/720 + ...` through `ad^10`, for any group.
///
/// The series converges while the rotation angle stays below `2 pi` (every output of
/// `log`); the truncation error grows like `n |ad|^(n-1) / (2 pi)^n` (about `1e-3` at a
/// rotation of `pi` with unit translation) and is below `1e-15` once `|xi| < 0.05`, where the
/// solver converges, so Gauss-Newton keeps its local quadratic rate; far from the optimum
/// an approximate Jacobian only slows Levenberg-Marquardt down.
pub fn bernoulli_right_jacobian_inverse<G: PoseGroup<D>, const D: usize>(
    xi: &SVector<f64, D>,
) -> SMatrix<f64, D, D> {
    // B_2k / (2k)! for k = 1..=5.
    const EVEN: [f64; 5] = [
        1.0 / 12.0,
        -1.0 / 720.0,
        1.0 / 30240.0,
        -1.0 / 1209600.0,
        1.0 / 47900160.0,
    ];
    let a = G::ad(xi);
    let a2 = a * a;
    let mut out = SMatrix::<f64, D, D>::identity() + a * 0.5;
    let mut power = a2;
    for c in EVEN {
        out += power * c;
        power *= a2;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use ferroslam_geometry::sim3::Vector7;
    use nalgebra::Vector6;

    fn check_group<G: PoseGroup<D>, const D: usize>(xi: SVector<f64, D>, eta: SVector<f64, D>) {
        let g = G::exp(&xi);
        // Adjoint: g exp(eta) g^-1 == exp(Ad(g) eta).
        let lhs = g.compose(&G::exp(&eta)).compose(&g.inverse()).log();
        assert_relative_eq!(lhs, g.adjoint() * eta, epsilon = 1e-10);
        // Right Jacobian inverse against a central difference of log(exp(xi) exp(d)).
        let jr_inv = G::right_jacobian_inverse(&xi);
        let h = 1e-6;
        for k in 0..D {
            let mut d = SVector::<f64, D>::zeros();
            d[k] = h;
            let plus = g.compose(&G::exp(&d)).log();
            let minus = g.compose(&G::exp(&-d)).log();
            let numeric = (plus - minus) / (2.0 * h);
            assert_relative_eq!(numeric, jr_inv.column(k).into_owned(), epsilon = 1e-7);
        }
        // Small adjoint: d/dt Ad(exp(t eta)) xi at 0 equals [eta, xi].
        let t = 1e-6;
        let numeric =
            (G::exp(&(eta * t)).adjoint() - G::exp(&(eta * -t)).adjoint()) * xi / (2.0 * t);
        assert_relative_eq!(numeric, G::ad(&eta) * xi, epsilon = 1e-7);
    }

    #[test]
    fn se3_adjoint_and_jacobian_match_numerics() {
        check_group::<Isometry3<f64>, 6>(
            Vector6::new(0.3, -0.2, 0.5, 0.4, -0.3, 0.2),
            Vector6::new(-0.1, 0.7, 0.2, 0.1, 0.2, -0.5),
        );
    }

    #[test]
    fn se3_closed_form_matches_numerics_far_out_and_the_series_near_zero() {
        // A large twist (2.5 rad, 4 m), where the truncated series would be off by ~1e-3.
        check_group::<Isometry3<f64>, 6>(
            Vector6::new(3.0, -2.0, 1.5, 1.5, -1.5, 1.4),
            Vector6::new(-0.1, 0.7, 0.2, 0.1, 0.2, -0.5),
        );
        for scale in [1e-9, 1e-3, 5e-3, 2e-2, 0.1] {
            let xi = Vector6::new(0.3, -0.2, 0.5, 0.4, -0.3, 0.2) * scale;
            let closed = <Isometry3<f64> as PoseGroup<6>>::right_jacobian_inverse(&xi);
            let series = bernoulli_right_jacobian_inverse::<Isometry3<f64>, 6>(&xi);
            assert_relative_eq!(closed, series, epsilon = 1e-14);
        }
    }

    #[test]
    fn sim3_adjoint_and_jacobian_match_numerics() {
        check_group::<Sim3, 7>(
            Vector7::from([0.3, -0.2, 0.5, 0.4, -0.3, 0.2, 0.3]),
            Vector7::from([-0.1, 0.7, 0.2, 0.1, 0.2, -0.5, -0.2]),
        );
    }
}
