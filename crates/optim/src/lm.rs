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

/// Adds one observation's weighted normal equations to `(h, g)`: `w J^T J` to the lower
/// triangle of `h` (diagonal included) and `w J^T e` to `g`, over the first `rows` rows of
/// `j` and `e` (the others must be zero, as a monocular observation's right row).
///
/// Each entry is the one `w * j.transpose() * j` (and `* e`) gives, bit for bit, at about
/// half the products of the full matrix and with no temporary matrix. The upper triangle of
/// `h` is left alone: [`mirror_lower_triangle`] fills it once all observations are added.
pub(crate) fn add_normal_equations<const R: usize, const N: usize>(
    h: &mut SMatrix<f64, N, N>,
    g: &mut SVector<f64, N>,
    w: f64,
    j: &SMatrix<f64, R, N>,
    e: &SVector<f64, R>,
    rows: usize,
) {
    debug_assert!((1..=R).contains(&rows));
    let wj = w * j;
    for c in 0..N {
        for r in c..N {
            let mut s = wj[(0, r)] * j[(0, c)];
            for k in 1..rows {
                s += wj[(k, r)] * j[(k, c)];
            }
            h[(r, c)] += s;
        }
        let mut s = wj[(0, c)] * e[0];
        for k in 1..rows {
            s += wj[(k, c)] * e[k];
        }
        g[c] += s;
    }
}

/// Copies the lower triangle of `h` onto its upper one, once [`add_normal_equations`] has
/// filled the lower: a symmetric matrix for every reader (the Cholesky factor reads only the
/// lower triangle).
pub(crate) fn mirror_lower_triangle<const N: usize>(h: &mut SMatrix<f64, N, N>) {
    h.fill_upper_triangle_with_lower_triangle();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_equations_equal_the_matrix_products_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let seed = 11;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut value =
            || -> f64 { rng.random_range(-1e3..1e3) * 10f64.powi(rng.random_range(-6..3)) };
        for trial in 0..200 {
            let rows = 2 + trial % 2;
            let mut j = SMatrix::<f64, 3, 12>::from_fn(|_, _| value());
            let mut e = SVector::<f64, 3>::from_fn(|_, _| value());
            if rows == 2 {
                j.row_mut(2).fill(0.0);
                e[2] = 0.0;
            }
            let w = value().abs();
            let (h0, g0) = (
                SMatrix::<f64, 12, 12>::from_fn(|r, c| (r * 12 + c) as f64 * 0.37),
                SVector::<f64, 12>::from_fn(|r, _| r as f64 * 1.9),
            );
            let (mut h, mut g) = (h0, g0);
            add_normal_equations(&mut h, &mut g, w, &j, &e, rows);
            mirror_lower_triangle(&mut h);
            let want_h = h0 + w * j.transpose() * j;
            let want_g = g0 + w * j.transpose() * e;
            for c in 0..12 {
                assert_eq!(
                    g[c].to_bits(),
                    want_g[c].to_bits(),
                    "seed {seed}, trial {trial}, g[{c}]"
                );
                for r in c..12 {
                    assert_eq!(
                        h[(r, c)].to_bits(),
                        want_h[(r, c)].to_bits(),
                        "seed {seed}, trial {trial}, h[({r}, {c})]"
                    );
                    assert_eq!(h[(c, r)].to_bits(), h[(r, c)].to_bits());
                }
            }
        }
    }

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
