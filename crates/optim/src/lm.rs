//! Levenberg-Marquardt damping shared by the pose and bundle adjustment solvers.
//!
//! The damped system is `(H + lambda * D) dx = -g` with `D = diag(H)` clamped to
//! `[MIN_DIAGONAL, MAX_DIAGONAL]` (Marquardt's scale-invariant damping, clamped as in
//! Ceres so that directions with no information still get a positive pivot).

/// Smallest diagonal used for damping.
pub(crate) const MIN_DIAGONAL: f64 = 1e-6;
/// Largest diagonal used for damping.
pub(crate) const MAX_DIAGONAL: f64 = 1e32;
/// Largest damping tried before an iteration gives up.
const MAX_LAMBDA: f64 = 1e16;

/// Damping term for a Hessian diagonal entry `h`.
pub(crate) fn damping_diagonal(h: f64) -> f64 {
    h.clamp(MIN_DIAGONAL, MAX_DIAGONAL)
}

/// Nielsen's lambda update: shrink after good steps by how well the quadratic model
/// predicted the decrease, grow geometrically after rejected ones.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Damping {
    lambda: f64,
    nu: f64,
}

impl Damping {
    pub(crate) fn new(initial_lambda: f64) -> Self {
        Self {
            lambda: initial_lambda,
            nu: 2.0,
        }
    }

    pub(crate) fn lambda(&self) -> f64 {
        self.lambda
    }

    /// True once lambda is so large that further tries cannot move the estimate.
    pub(crate) fn exhausted(&self) -> bool {
        self.lambda > MAX_LAMBDA
    }

    /// An accepted step with gain ratio `rho = actual / predicted decrease` (> 0).
    pub(crate) fn accept(&mut self, rho: f64) {
        let t = 2.0 * rho - 1.0;
        self.lambda *= (1.0 - t * t * t).max(1.0 / 3.0);
        self.nu = 2.0;
    }

    pub(crate) fn reject(&mut self) {
        self.lambda *= self.nu;
        self.nu *= 2.0;
    }
}

/// Decrease of the Gauss-Newton model `F + 2 g^T dx + dx^T H dx` for the step solving
/// `(H + lambda D) dx = -g`: `-g^T dx + lambda dx^T D dx` (cost `F = sum rho(chi2)`).
pub(crate) fn predicted_decrease(g_dot_dx: f64, lambda: f64, dx_d_dx: f64) -> f64 {
    -g_dot_dx + lambda * dx_d_dx
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejections_grow_lambda_and_acceptance_shrinks_it() {
        let mut d = Damping::new(1.0);
        d.reject();
        d.reject();
        assert_eq!(d.lambda(), 8.0);
        d.accept(1.0);
        assert!((d.lambda() - 8.0 / 3.0).abs() < 1e-12);
        d.accept(0.5);
        assert!((d.lambda() - 8.0 / 3.0).abs() < 1e-12);
    }
}
