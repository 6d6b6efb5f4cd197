//! Test helpers shared by every crate: numerical Jacobian checks.
//!
//! These functions panic on failure by design; they exist to fail tests. Do not call them
//! from library code.

use nalgebra::{DMatrix, DVector};

/// Compares `analytic` with the central-difference Jacobian of `f` at `x0`, and panics
/// (printing both matrices and the worst entry) if they disagree.
///
/// Column `j` of the numerical Jacobian is `(f(x0 + eps e_j) - f(x0 - eps e_j)) / (2 eps)`.
/// For a manifold-valued function, let `f` take a tangent vector and return a tangent
/// vector, e.g. `|d| log(exp(d) * T) - log(T)` for a left perturbation. An entry passes
/// when `|analytic - numeric| <= tol * max(1, |numeric|)`: absolute near zero, relative
/// for large entries.
///
/// Panics if the shapes differ, if any entry is not finite, or if an entry fails.
///
/// ```
/// use ferroslam_geometry::testing::check_jacobian;
/// use nalgebra::{DMatrix, DVector};
/// let x0 = DVector::from_vec(vec![0.5, -1.0]);
/// let f = |x: &DVector<f64>| DVector::from_vec(vec![x[0] * x[1], x[0].sin()]);
/// let j = DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, 0.5f64.cos(), 0.0]);
/// check_jacobian("product and sine", &j, f, &x0, 1e-6, 1e-7);
/// ```
pub fn check_jacobian(
    name: &str,
    analytic: &DMatrix<f64>,
    f: impl Fn(&DVector<f64>) -> DVector<f64>,
    x0: &DVector<f64>,
    eps: f64,
    tol: f64,
) {
    let f0 = f(x0);
    assert_eq!(
        analytic.shape(),
        (f0.len(), x0.len()),
        "{name}: analytic Jacobian has shape {:?}, expected (outputs, inputs) = ({}, {})",
        analytic.shape(),
        f0.len(),
        x0.len()
    );
    let mut numeric = DMatrix::zeros(f0.len(), x0.len());
    for j in 0..x0.len() {
        let (mut plus, mut minus) = (x0.clone(), x0.clone());
        plus[j] += eps;
        minus[j] -= eps;
        numeric.set_column(j, &((f(&plus) - f(&minus)) / (2.0 * eps)));
    }
    let report = || format!("{name}\nanalytic:{analytic}numeric:{numeric}at x0:{x0}");
    assert!(
        analytic.iter().all(|v| v.is_finite()),
        "{name}: analytic Jacobian is not finite\n{}",
        report()
    );
    assert!(
        numeric.iter().all(|v| v.is_finite()),
        "{name}: numerical Jacobian is not finite\n{}",
        report()
    );
    let mut worst = (0.0, 0, 0);
    for ((r, c), n) in numeric
        .iter()
        .enumerate()
        .map(|(k, n)| ((k % numeric.nrows(), k / numeric.nrows()), n))
    {
        let err = (analytic[(r, c)] - n).abs() / n.abs().max(1.0);
        if err > worst.0 {
            worst = (err, r, c);
        }
    }
    assert!(
        worst.0 <= tol,
        "{name}: Jacobians differ by {:.3e} (tol {tol:.1e}) at ({}, {})\n{}",
        worst.0,
        worst.1,
        worst.2,
        report()
    );
}
