//! Relative-pose hypotheses from a homography: Faugeras & Lustman's SVD decomposition
//! ("Motion and structure from motion in a piecewise planar environment", 1988) into
//! eight `(R, t)` candidates.

use nalgebra::{Isometry3, Matrix3, Vector3};

use super::from_fundamental::intrinsic_matrix;
use super::linalg::{rigid, svd3};
use crate::camera::PinholeCamera;

/// Singular values closer than this ratio count as repeated, where the decomposition
/// has no finite set of solutions.
const MIN_SINGULAR_RATIO: f64 = 1.00001;

/// The eight `T_c2_c1` candidates (unit translation) of `h21` (`x2 ∝ H21 x1` on pixels of
/// `camera`), from `K^-1 H21 K ∝ R + t n^T / d` for the scene plane `n^T p_c1 = d`.
///
/// `None` when two singular values of `K^-1 H21 K` coincide: pure rotation (all equal),
/// or translation along the plane normal, where the decomposition is not unique.
pub(super) fn poses_from_homography(
    h21: &Matrix3<f64>,
    camera: &PinholeCamera,
) -> Option<Vec<Isometry3<f64>>> {
    let k = intrinsic_matrix(camera);
    let svd = svd3(&(k.try_inverse()? * h21 * k))?;
    let (u, v_t) = (svd.u, svd.v_t);
    let s = u.determinant() * v_t.determinant();
    let (d1, d2, d3) = (svd.w[0], svd.w[1], svd.w[2]);
    if !(d3 > 0.0 && d1 / d2 >= MIN_SINGULAR_RATIO && d2 / d3 >= MIN_SINGULAR_RATIO) {
        return None;
    }
    let (q1, q2, q3) = (d1 * d1, d2 * d2, d3 * d3);
    // Components of the normal in the V basis (second one is 0), all four sign choices.
    let aux1 = ((q1 - q2) / (q1 - q3)).sqrt();
    let aux3 = ((q2 - q3) / (q1 - q3)).sqrt();
    let signs = [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)];
    let root = ((q1 - q2) * (q2 - q3)).sqrt();
    let candidate =
        |rp: Matrix3<f64>, tp: Vector3<f64>| rigid(&(s * u * rp * v_t), &(u * tp).normalize());

    let mut poses = Vec::with_capacity(8);
    // d' = d2: rotation about the second axis by theta.
    let cos_theta = (q2 + d1 * d3) / ((d1 + d3) * d2);
    let sin_theta = root / ((d1 + d3) * d2);
    for (e1, e3) in signs {
        let st = sin_theta * e1 * e3;
        #[rustfmt::skip]
        let rp = Matrix3::new(
            cos_theta, 0.0, -st,
            0.0, 1.0, 0.0,
            st, 0.0, cos_theta,
        );
        poses.push(candidate(
            rp,
            Vector3::new(e1 * aux1, 0.0, -e3 * aux3) * (d1 - d3),
        )?);
    }
    // d' = -d2: a reflection composed with a rotation by phi.
    let cos_phi = (d1 * d3 - q2) / ((d1 - d3) * d2);
    let sin_phi = root / ((d1 - d3) * d2);
    for (e1, e3) in signs {
        let sp = sin_phi * e1 * e3;
        #[rustfmt::skip]
        let rp = Matrix3::new(
            cos_phi, 0.0, sp,
            0.0, -1.0, 0.0,
            sp, 0.0, -cos_phi,
        );
        poses.push(candidate(
            rp,
            Vector3::new(e1 * aux1, 0.0, e3 * aux3) * (d1 + d3),
        )?);
    }
    Some(poses)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::test_cameras;
    use nalgebra::Rotation3;

    #[test]
    fn one_candidate_is_the_true_pose() {
        let camera = test_cameras()[2].1;
        let k = intrinsic_matrix(&camera);
        for (axis, t, n, d) in [
            (
                Vector3::new(0.02, 0.1, -0.03),
                Vector3::new(0.6, 0.1, 0.3),
                Vector3::new(0.1, -0.2, -1.0),
                5.0,
            ),
            (
                Vector3::new(-0.05, 0.0, 0.01),
                Vector3::new(-0.2, 0.0, 1.0),
                Vector3::new(0.0, -1.0, 0.0),
                1.5,
            ),
        ] {
            let r = Rotation3::from_scaled_axis(axis);
            let n = n.normalize();
            let h21 = k * (r.matrix() + t * n.transpose() / d) * k.try_inverse().unwrap();
            for scale in [1.0, -2.5] {
                let poses = poses_from_homography(&(h21 * scale), &camera).unwrap();
                assert_eq!(poses.len(), 8);
                let hits = poses
                    .iter()
                    .filter(|p| {
                        (p.rotation.to_rotation_matrix().matrix() - r.matrix()).norm() < 1e-8
                            && (p.translation.vector - t.normalize()).norm() < 1e-8
                    })
                    .count();
                assert_eq!(hits, 1, "{poses:?}");
            }
        }
    }

    #[test]
    fn pure_rotation_is_degenerate() {
        let camera = test_cameras()[0].1;
        let k = intrinsic_matrix(&camera);
        let r = Rotation3::from_scaled_axis(Vector3::new(0.02, 0.1, -0.03));
        let h21 = k * r.matrix() * k.try_inverse().unwrap();
        assert!(poses_from_homography(&h21, &camera).is_none());
    }
}
