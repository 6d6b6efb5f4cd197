//! Levenberg-Marquardt damping shared by the pose and bundle adjustment solvers.
//!
//! The damped system is `(H + lambda * D) dx = -g` with `D = diag(H)` clamped to
//! `[MIN_DIAGONAL, MAX_DIAGONAL]` (Marquardt's scale-invariant damping, clamped as in
//! Ceres so that directions with no information still get a positive pivot).

use nalgebra::{SMatrix, SVector};

use crate::error::OptimError;

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

impl Damping {
    /// The inner loop of one LM iteration: damped steps are solved (`solve(lambda)`) and
    /// tried (`try_step(&step)` returns `(actual decrease, predicted decrease, new cost)`)
    /// with growing damping until one lowers the cost.
    ///
    /// Returns the accepted step's new cost, or `None` when no damping can lower it any more
    /// (converged). A damping level whose factorisation fails is skipped; if every one
    /// failed the system is indefinite, not converged, and that error is returned.
    pub(crate) fn find_step<S>(
        &mut self,
        mut solve: impl FnMut(f64) -> Result<S, OptimError>,
        mut try_step: impl FnMut(&S) -> (f64, f64, f64),
    ) -> Result<Option<f64>, OptimError> {
        let mut last_failure = None;
        let mut factorised = false;
        while !self.exhausted() {
            let step = match solve(self.lambda) {
                Ok(step) => {
                    factorised = true;
                    step
                }
                Err(OptimError::NotPositiveDefinite { column }) => {
                    last_failure = Some(column);
                    self.reject();
                    continue;
                }
                Err(e) => return Err(e),
            };
            let (actual, predicted, new_cost) = try_step(&step);
            if actual > 0.0 && predicted > 0.0 {
                self.accept(actual / predicted);
                return Ok(Some(new_cost));
            }
            self.reject();
        }
        match (last_failure, factorised) {
            (Some(column), false) => Err(OptimError::NotPositiveDefinite { column }),
            _ => Ok(None),
        }
    }
}

/// Decrease of the Gauss-Newton model `F + 2 g^T dx + dx^T H dx` for the step solving
/// `(H + lambda D) dx = -g`: `-g^T dx + lambda dx^T D dx` (cost `F = sum rho(chi2)`).
pub(crate) fn predicted_decrease(g_dot_dx: f64, lambda: f64, dx_d_dx: f64) -> f64 {
    -g_dot_dx + lambda * dx_d_dx
}

/// The damped step of a small dense system: `dx` solving `(H + lambda diag(d)) dx = -g`, and
/// the model's [`predicted_decrease`] for it.
///
/// # Errors
/// [`OptimError::NotPositiveDefinite`] when the damped matrix has no Cholesky factor.
pub(crate) fn dense_damped_step<const N: usize>(
    h: &SMatrix<f64, N, N>,
    g: &SVector<f64, N>,
    d: &SVector<f64, N>,
    lambda: f64,
) -> Result<(SVector<f64, N>, f64), OptimError> {
    let hd = h + SMatrix::<f64, N, N>::from_diagonal(&(lambda * d));
    let dx = hd
        .cholesky()
        .ok_or(OptimError::NotPositiveDefinite { column: 0 })?
        .solve(&(-g));
    let predicted = predicted_decrease(g.dot(&dx), lambda, dx.component_mul(d).dot(&dx));
    Ok((dx, predicted))
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
