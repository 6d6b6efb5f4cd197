//! Relative-pose hypotheses from a fundamental matrix: the essential matrix, one of its
//! `(R, t)` factorisations refined on the Sampson error, and the four candidates that
//! share its epipolar geometry.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector2, Vector3};

use super::essential_refinement::refine_essential;
use super::linalg::{rigid, svd3};
use crate::camera::PinholeCamera;

/// The four `T_c2_c1` candidates (unit translation) of `f21` (`x2^T F21 x1 = 0` on pixels
/// of `camera`). `E = K^T F21 K = [t]x R` is factorised, `(R, t)` refined on the Sampson
/// error of the matches `(pixels1[i], pixels2[i])` (starting from `inliers`, pixel noise
/// `sigma`), and the candidates are `±t` with `R` or its twisted pair. Exactly one of them puts the scene in front of both
/// cameras; [`super::pose_check`] finds it. `None` if `E` is not finite.
pub(super) fn poses_from_fundamental(
    f21: &Matrix3<f64>,
    camera: &PinholeCamera,
    pixels1: &[Vector2<f64>],
    pixels2: &[Vector2<f64>],
    inliers: &[bool],
    sigma: f64,
) -> Option<Vec<Isometry3<f64>>> {
    let k = intrinsic_matrix(camera);
    let (r, t) = factorize_essential(&(k.transpose() * f21 * k))?;
    let indices: Vec<usize> = (0..inliers.len()).filter(|&i| inliers[i]).collect();
    let (r, t) = refine_essential(&r, &t, &k, pixels1, pixels2, &indices, sigma);
    Some(essential_hypotheses(&r, &t))
}

/// One `(R, t)` with `E ∝ [t]x R`, `|t| = 1`: `R = U W V^T` (sign fixed to a rotation; `E`
/// is only defined up to sign), `t = u3`. `None` if `E` is not finite.
fn factorize_essential(e: &Matrix3<f64>) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    let svd = svd3(e)?;
    let t = svd.u.column(2).into_owned();
    #[rustfmt::skip]
    let w = Matrix3::new(
        0.0, -1.0, 0.0,
        1.0, 0.0, 0.0,
        0.0, 0.0, 1.0,
    );
    let r = svd.u * w * svd.v_t;
    let r = if r.determinant() < 0.0 { -r } else { r };
    Some((rigid(&r, &t)?.rotation, t))
}

/// The four poses with the epipolar geometry of `(r, t)`: `±t`, and `r` or its twisted
/// pair `R_t(pi) r` (rotated half a turn about the baseline).
fn essential_hypotheses(r: &UnitQuaternion<f64>, t: &Vector3<f64>) -> Vec<Isometry3<f64>> {
    let twisted = UnitQuaternion::from_scaled_axis(t * std::f64::consts::PI) * r;
    [(*r, *t), (twisted, *t), (*r, -t), (twisted, -t)]
        .into_iter()
        .map(|(r, t)| Isometry3::from_parts(Translation3::from(t), r))
        .collect()
}

/// `K = [fx 0 cx; 0 fy cy; 0 0 1]`.
pub(super) fn intrinsic_matrix(camera: &PinholeCamera) -> Matrix3<f64> {
    Matrix3::new(
        camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::test_cameras;
    use crate::so3::hat;
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn one_candidate_is_the_true_pose() {
        let camera = test_cameras()[0].1;
        let k_inv = intrinsic_matrix(&camera).try_inverse().unwrap();
        let r = Rotation3::from_scaled_axis(Vector3::new(0.05, -0.1, 0.02));
        let t = Vector3::new(0.3, -0.1, 0.9).normalize();
        let f21 = k_inv.transpose() * hat(&t) * r.matrix() * k_inv;
        let poses = poses_from_fundamental(&(f21 * 3.7), &camera, &[], &[], &[], 1.0).unwrap();
        assert_eq!(poses.len(), 4);
        let hits = poses
            .iter()
            .filter(|p| {
                (p.rotation.to_rotation_matrix().matrix() - r.matrix()).norm() < 1e-9
                    && (p.translation.vector - t).norm() < 1e-9
            })
            .count();
        assert_eq!(hits, 1, "{poses:?}");
    }
}
