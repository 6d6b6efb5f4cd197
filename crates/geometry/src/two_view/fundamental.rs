//! Fundamental matrix between the two views from 8 or more correspondences (normalised 8-point
//! algorithm with the rank-2 constraint enforced).

use nalgebra::{DMatrix, Matrix3};

use super::linalg::{null_vector_9, svd3};
use super::normalization::Normalized;

/// `F21` (pixels, `x2^T F21 x1 = 0`) fitted to the matches `indices` (into both
/// normalised sets) by least squares, then made rank 2.
///
/// Without `previous` the algebraic error is minimised (the 8-point algorithm). With a
/// previous estimate each equation is divided by that estimate's Sampson denominator, so
/// the fit minimises (to first order) the Sampson distance in pixels: one step of
/// iteratively reweighted least squares, much more accurate than the algebraic fit on
/// noisy data. `None` with fewer than 8 matches or if the system is not finite.
pub(super) fn fit_fundamental(
    n1: &Normalized,
    n2: &Normalized,
    indices: &[usize],
    previous: Option<&Matrix3<f64>>,
) -> Option<Matrix3<f64>> {
    if indices.len() < 8 {
        return None;
    }
    let (t1_inv, t2_inv) = (n1.t.try_inverse()?, n2.t.try_inverse()?);
    let mut a = DMatrix::zeros(indices.len(), 9);
    for (k, &i) in indices.iter().enumerate() {
        let (p1, p2) = (n1.points[i], n2.points[i]);
        let (u1, v1, u2, v2) = (p1.x, p1.y, p2.x, p2.y);
        // The row's residual q2^T Fn q1 equals x2^T F21 x1 in pixels.
        let weight = previous.map_or(1.0, |f| {
            let (x1, x2) = (t1_inv * p1.push(1.0), t2_inv * p2.push(1.0));
            let (l2, l1) = (f * x1, f.transpose() * x2);
            1.0 / (l2.xy().norm_squared() + l1.xy().norm_squared()).sqrt()
        });
        if !weight.is_finite() {
            continue;
        }
        a.row_mut(k).copy_from_slice(
            &[u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, 1.0].map(|v| v * weight),
        );
    }
    let f = null_vector_9(&a)?;
    // Closest rank-2 matrix: zero the smallest singular value.
    let svd = svd3(&Matrix3::from_row_slice(f.as_slice()))?;
    let mut w = svd.w;
    w[2] = 0.0;
    let f_normalized = svd.u * Matrix3::from_diagonal(&w) * svd.v_t;
    let f21 = n2.t.transpose() * f_normalized * n1.t;
    f21.iter().all(|v| v.is_finite()).then_some(f21)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::so3::hat;
    use crate::two_view::normalization::normalize;
    use nalgebra::{Rotation3, Vector2, Vector3};

    #[test]
    fn fits_exact_epipolar_geometry_with_rank_two() {
        let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0);
        let r = Rotation3::from_scaled_axis(Vector3::new(0.02, -0.05, 0.01));
        let t = Vector3::new(0.5, 0.1, 0.05);
        let project = |p: Vector3<f64>| (k * p).xy() / p.z;
        let points: Vec<Vector3<f64>> = (0..8)
            .map(|i| {
                let i = i as f64;
                Vector3::new(
                    (i * 0.37).sin() * 2.0,
                    (i * 1.3).cos(),
                    4.0 + (i * 0.7) % 3.0,
                )
            })
            .collect();
        let p1: Vec<Vector2<f64>> = points.iter().map(|p| project(*p)).collect();
        let p2: Vec<Vector2<f64>> = points.iter().map(|p| project(r * p + t)).collect();
        let (n1, n2) = (normalize(&p1).unwrap(), normalize(&p2).unwrap());
        let f = fit_fundamental(&n1, &n2, &[0, 1, 2, 3, 4, 5, 6, 7], None).unwrap();
        let k_inv = k.try_inverse().unwrap();
        let truth = k_inv.transpose() * hat(&t) * r.matrix() * k_inv;
        let (f, truth) = (f / f.norm(), truth / truth.norm());
        let sign = if (f - truth).norm() < (f + truth).norm() {
            1.0
        } else {
            -1.0
        };
        let rel = (f * sign - truth).component_div(&truth).abs().max();
        assert!(rel < 1e-6, "{rel} {f}\n{truth}");
        assert!(f.determinant().abs() < 1e-12);
    }
}
