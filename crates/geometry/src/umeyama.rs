//! Least-squares alignment of two point sets (Umeyama 1991).

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::sim3::Sim3;

/// The similarity `S_dst_src` minimising `sum |dst_i - (s R src_i + t)|^2`.
///
/// With `with_scale == false` the scale is fixed to 1 (rigid alignment, Horn/Kabsch).
/// The rotation is a proper rotation (reflections are excluded).
///
/// Returns `None` if the slices differ in length, hold fewer than 3 points, contain
/// non-finite values, or if the rotation is not unique: all source points equal, or
/// both sets collinear.
///
/// ```
/// use approx::assert_relative_eq;
/// use ferroslam_geometry::umeyama::umeyama;
/// use nalgebra::Vector3;
/// let src = [Vector3::new(0.0, 0.0, 0.0), Vector3::x(), Vector3::y(), Vector3::z()];
/// let dst: Vec<_> = src.iter().map(|p| p * 2.0 + Vector3::new(1.0, 2.0, 3.0)).collect();
/// let s = umeyama(&src, &dst, true).unwrap();
/// assert_relative_eq!(s.scale, 2.0, epsilon = 1e-12);
/// assert_relative_eq!(s.translation, Vector3::new(1.0, 2.0, 3.0), epsilon = 1e-12);
/// ```
pub fn umeyama(src: &[Vector3<f64>], dst: &[Vector3<f64>], with_scale: bool) -> Option<Sim3> {
    let n = src.len();
    if n < 3
        || dst.len() != n
        || !src
            .iter()
            .chain(dst)
            .all(|p| p.iter().all(|v| v.is_finite()))
    {
        return None;
    }
    let mean = |ps: &[Vector3<f64>]| ps.iter().sum::<Vector3<f64>>() / n as f64;
    let (mu_src, mu_dst) = (mean(src), mean(dst));
    let mut cov = Matrix3::zeros();
    let mut var_src = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (s, d) = (s - mu_src, d - mu_dst);
        cov += d * s.transpose();
        var_src += s.norm_squared();
    }
    cov /= n as f64;
    var_src /= n as f64;
    let svd = cov.svd(true, true);
    let (u, v_t, sv) = (svd.u?, svd.v_t?, svd.singular_values);
    // Rank < 2 leaves a rotation about the common line free.
    if !(var_src > 0.0 && sv[1] > 1e-12 * sv[0]) {
        return None;
    }
    let mut signs = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        signs.z = -1.0; // flip the weakest direction to turn a reflection into a rotation
    }
    let rotation = u * Matrix3::from_diagonal(&signs) * v_t;
    let scale = if with_scale {
        sv.dot(&signs) / var_src
    } else {
        1.0
    };
    let rotation = UnitQuaternion::from_matrix(&rotation);
    let translation = mu_dst - rotation * mu_src * scale;
    Some(Sim3 {
        rotation,
        translation,
        scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_degenerate_input() {
        let p = [Vector3::x(), Vector3::y(), Vector3::z()];
        assert!(umeyama(&p[..2], &p[..2], true).is_none());
        assert!(umeyama(&p, &p[..2], true).is_none());
        let same = [Vector3::x(); 3];
        assert!(umeyama(&same, &p, true).is_none());
        let line = [Vector3::x(), Vector3::x() * 2.0, Vector3::x() * 3.0];
        assert!(umeyama(&line, &line, false).is_none());
        let nan = [Vector3::new(f64::NAN, 0.0, 0.0), Vector3::y(), Vector3::z()];
        assert!(umeyama(&nan, &p, true).is_none());
    }

    #[test]
    fn mirrored_points_give_a_rotation() {
        let src: [Vector3<f64>; 4] = [Vector3::x(), Vector3::y(), Vector3::z(), Vector3::zeros()];
        let dst: Vec<_> = src.iter().map(|p| Vector3::new(-p.x, p.y, p.z)).collect();
        let s = umeyama(&src, &dst, false).unwrap();
        assert!((s.rotation.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
    }
}
