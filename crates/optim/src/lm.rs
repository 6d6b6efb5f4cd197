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
/// Each entry is the one `w * j.transpose() * j` (and `* e`) gives, bit for bit, with no
/// temporary matrix. Columns of `h` are summed in blocks of contiguous entries, which
/// vectorise where the triangle's ragged rows do not, so some upper-triangle entries get
/// sums too (each entry still its own sum in the same order); [`mirror_lower_triangle`]
/// overwrites the upper triangle once all observations are added.
pub(crate) fn add_normal_equations<const R: usize, const N: usize>(
    h: &mut SMatrix<f64, N, N>,
    g: &mut SVector<f64, N>,
    w: f64,
    j: &SMatrix<f64, R, N>,
    e: &SVector<f64, R>,
    rows: usize,
) {
    debug_assert!((1..=R).contains(&rows));
    // Transposed, each row of `j` is a contiguous column.
    let (wj, jc) = ((w * j).transpose(), j.transpose());
    let args = (
        &mut h.data.0,
        &mut g.data.0[0],
        &wj.data.0,
        &jc.data.0,
        &e.data.0[0],
    );
    match rows {
        2 => add_columns::<R, N, 2>(args),
        3 => add_columns::<R, N, 3>(args),
        _ => add_columns::<R, N, 1>(args),
    }
}

/// Column `c` of `h` (`N` entries) gets `sum_k wj[k] * jc[k][c]` over `K` rows, `g[c]` the
/// same with `e`; `wj[k]` and `jc[k]` are the `k`-th rows of `w J` and `J`.
type Columns<'a, const R: usize, const N: usize> = (
    &'a mut [[f64; N]; N],
    &'a mut [f64; N],
    &'a [[f64; N]; R],
    &'a [[f64; N]; R],
    &'a [f64; R],
);

/// [`add_normal_equations`] over the first `K` rows, known at compile time so that the
/// inner sums unroll, 4 entries of a column at a time where the CPU has AVX.
fn add_columns<const R: usize, const N: usize, const K: usize>(columns: Columns<'_, R, N>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked above.
        unsafe { add_columns_avx::<R, N, K>(columns) };
        return;
    }
    add_columns_scalar::<R, N, K>(columns, 0);
}

/// Rows `from..N` of every column and all of `g`, one entry at a time (upper triangle
/// entries included: only the lower one is read).
fn add_columns_scalar<const R: usize, const N: usize, const K: usize>(
    (h, g, wj, jc, e): Columns<'_, R, N>,
    from: usize,
) {
    for (c, column) in h.iter_mut().enumerate() {
        for (r, entry) in column.iter_mut().enumerate().skip(from) {
            let mut s = wj[0][r] * jc[0][c];
            for k in 1..K {
                s += wj[k][r] * jc[k][c];
            }
            *entry += s;
        }
        let mut s = wj[0][c] * e[0];
        for k in 1..K {
            s += wj[k][c] * e[k];
        }
        g[c] += s;
    }
}

/// [`add_columns_scalar`] with the rows of each column in blocks of 4 lanes from the block
/// holding the diagonal (the blocks above it are upper triangle): each lane multiplies and
/// adds in the scalar order (AVX has no fused multiply-add), so every entry is the scalar
/// one bit for bit.
///
/// # Safety
/// The CPU must support AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn add_columns_avx<const R: usize, const N: usize, const K: usize>(
    (h, g, wj, jc, e): Columns<'_, R, N>,
) {
    use std::arch::x86_64::{
        _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_set1_pd, _mm256_storeu_pd,
    };
    let blocks = N / 4 * 4;
    for (c, column) in h.iter_mut().enumerate() {
        for r in (c / 4 * 4..blocks).step_by(4) {
            // SAFETY: r + 4 <= N for every array read or written.
            unsafe {
                let mut s = _mm256_mul_pd(
                    _mm256_loadu_pd(wj[0][r..].as_ptr()),
                    _mm256_set1_pd(jc[0][c]),
                );
                for k in 1..K {
                    let p = _mm256_mul_pd(
                        _mm256_loadu_pd(wj[k][r..].as_ptr()),
                        _mm256_set1_pd(jc[k][c]),
                    );
                    s = _mm256_add_pd(s, p);
                }
                let at = column[r..].as_mut_ptr();
                _mm256_storeu_pd(at, _mm256_add_pd(_mm256_loadu_pd(at), s));
            }
        }
    }
    add_columns_scalar::<R, N, K>((h, g, wj, jc, e), blocks);
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

    /// `add_normal_equations` against nalgebra's products on random `3 x N` Jacobians.
    fn check_normal_equations<const N: usize>(seed: u64) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut value =
            || -> f64 { rng.random_range(-1e3..1e3) * 10f64.powi(rng.random_range(-6..3)) };
        for trial in 0..200 {
            let rows = 2 + trial % 2;
            let mut j = SMatrix::<f64, 3, N>::from_fn(|_, _| value());
            let mut e = SVector::<f64, 3>::from_fn(|_, _| value());
            if rows == 2 {
                j.row_mut(2).fill(0.0);
                e[2] = 0.0;
            }
            let w = value().abs();
            let (h0, g0) = (
                SMatrix::<f64, N, N>::from_fn(|r, c| (r * N + c) as f64 * 0.37),
                SVector::<f64, N>::from_fn(|r, _| r as f64 * 1.9),
            );
            let (mut h, mut g) = (h0, g0);
            add_normal_equations(&mut h, &mut g, w, &j, &e, rows);
            mirror_lower_triangle(&mut h);
            let want_h = h0 + w * j.transpose() * j;
            let want_g = g0 + w * j.transpose() * e;
            for c in 0..N {
                assert_eq!(
                    g[c].to_bits(),
                    want_g[c].to_bits(),
                    "seed {seed}, trial {trial}, g[{c}]"
                );
                for r in c..N {
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
    fn normal_equations_equal_the_matrix_products_bit_for_bit() {
        // The pose-and-velocity system (12), the pose's (6: a block of 4 and a scalar tail).
        check_normal_equations::<12>(11);
        check_normal_equations::<6>(12);
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
