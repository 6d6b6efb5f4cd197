//! Homography between the two views from 4 or more correspondences (normalised DLT).

use nalgebra::{DMatrix, Matrix3};

use super::linalg::null_vector_9;
use super::normalization::Normalized;

/// `H21` (pixels of view 1 to pixels of view 2, `x2 ∝ H21 x1`) fitted to the matches
/// `indices` (into both normalised sets) by least squares on the algebraic error. `None`
/// with fewer than 4 matches, or if the system is not finite or `H21` is singular.
///
/// The algebraic error is close to the transfer error in pixels when the homography's
/// perspective part is small over the image, as between two views of one camera, so no
/// reweighting is done.
pub(super) fn fit_homography(
    n1: &Normalized,
    n2: &Normalized,
    indices: &[usize],
) -> Option<Matrix3<f64>> {
    if indices.len() < 4 {
        return None;
    }
    let mut a = DMatrix::zeros(2 * indices.len(), 9);
    for (k, &i) in indices.iter().enumerate() {
        let (p1, p2) = (n1.points[i], n2.points[i]);
        let (u1, v1, u2, v2) = (p1.x, p1.y, p2.x, p2.y);
        // Two rows of x2 × (H x1) = 0.
        a.row_mut(2 * k)
            .copy_from_slice(&[0.0, 0.0, 0.0, -u1, -v1, -1.0, v2 * u1, v2 * v1, v2]);
        a.row_mut(2 * k + 1).copy_from_slice(&[
            u1,
            v1,
            1.0,
            0.0,
            0.0,
            0.0,
            -u2 * u1,
            -u2 * v1,
            -u2,
        ]);
    }
    let h = null_vector_9(&a)?;
    let h_normalized = Matrix3::from_row_slice(h.as_slice());
    let h21 = n2.t.try_inverse()? * h_normalized * n1.t;
    (h21.iter().all(|v| v.is_finite())
        && h21.determinant().abs() > f64::EPSILON * h21.norm().powi(3))
    .then_some(h21)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_view::normalization::normalize;
    use nalgebra::Vector2;

    #[test]
    fn recovers_an_exact_homography() {
        #[rustfmt::skip]
        let truth = Matrix3::new(
            1.1, 0.05, 12.0,
            -0.03, 0.95, -7.0,
            1e-4, -2e-4, 1.0,
        );
        let p1: Vec<Vector2<f64>> = (0..8)
            .map(|i| Vector2::new(50.0 + 61.0 * i as f64, 40.0 + 37.0 * ((i * 5) % 8) as f64))
            .collect();
        let p2: Vec<Vector2<f64>> = p1
            .iter()
            .map(|p| {
                let q = truth * p.push(1.0);
                q.xy() / q.z
            })
            .collect();
        let (n1, n2) = (normalize(&p1).unwrap(), normalize(&p2).unwrap());
        let h = fit_homography(&n1, &n2, &[0, 1, 2, 3, 4, 5, 6, 7]).unwrap();
        let h = h / h[(2, 2)];
        assert!((h - truth).norm() < 1e-8, "{h}");
    }
}
