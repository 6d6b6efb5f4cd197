//! Two-view triangulation of a point from normalized rays, and the epipolar constraint that
//! finds its matches.

use nalgebra::{Isometry3, Matrix3, Matrix3x4, Matrix4, SMatrix, Vector3};

/// Minimum camera baseline (metres) below which two views cannot triangulate.
const MIN_BASELINE: f64 = 1e-9;

/// Linear (DLT) triangulation of the world point seen along ray `x1` from camera 1 and
/// `x2` from camera 2.
///
/// `T_c1_w` and `T_c2_w` map world points into each camera; `x1`, `x2` are rays in each
/// camera frame, normally `(x, y, 1)` from [`crate::camera::PinholeCamera::unproject`]
/// (any non-zero scale works). Returns `p_w`, the point minimising the algebraic error
/// `x_i × (T_ci_w p_w) = 0`.
///
/// Returns `None` when the answer is not unique or not finite: zero baseline (pure
/// rotation), a zero ray, parallel rays (point at infinity), or non-finite input. The point may lie
/// behind a camera; callers check depth and parallax (see [`parallax_cos`]).
///
/// ```
/// use approx::assert_relative_eq;
/// use ferroslam_geometry::triangulation::triangulate_dlt;
/// use nalgebra::{Isometry3, Point3};
/// let T_c1_w = Isometry3::identity();
/// let T_c2_w = Isometry3::translation(-0.5, 0.0, 0.0); // camera 2 is 0.5 m to the right
/// let p_w = Point3::new(0.2, -0.1, 4.0);
/// let (p1, p2) = ((T_c1_w * p_w).coords, (T_c2_w * p_w).coords);
/// let x = triangulate_dlt(&T_c1_w, &T_c2_w, &(p1 / p1.z), &(p2 / p2.z)).unwrap();
/// assert_relative_eq!(x, p_w.coords, epsilon = 1e-9);
/// ```
#[allow(non_snake_case)]
pub fn triangulate_dlt(
    T_c1_w: &Isometry3<f64>,
    T_c2_w: &Isometry3<f64>,
    x1: &Vector3<f64>,
    x2: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let baseline =
        (T_c1_w.inverse().translation.vector - T_c2_w.inverse().translation.vector).norm();
    if !(baseline > MIN_BASELINE && x1.norm() > 0.0 && x2.norm() > 0.0) {
        return None;
    }
    let mut a = Matrix4::zeros();
    for (k, (t, x)) in [(T_c1_w, x1), (T_c2_w, x2)].into_iter().enumerate() {
        let p: Matrix3x4<f64> = t.to_homogeneous().fixed_view::<3, 4>(0, 0).into_owned();
        // Two independent rows of x × (P X) = 0.
        a.set_row(2 * k, &(p.row(2) * x.x - p.row(0) * x.z));
        a.set_row(2 * k + 1, &(p.row(2) * x.y - p.row(1) * x.z));
    }
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    // Normalise rows so that both views weigh the same whatever the ray scale.
    for mut row in a.row_iter_mut() {
        let n = row.norm();
        if n > 0.0 {
            row /= n;
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    // Singular values are sorted in decreasing order: the last row is the null vector.
    let h = v_t.row(3);
    if h[3].abs() < 1e-12 {
        return None;
    }
    let p_w = Vector3::new(h[0], h[1], h[2]) / h[3];
    p_w.iter().all(|v| v.is_finite()).then_some(p_w)
}

/// Triangulation from bearing vectors of any direction (a fisheye's rays may point sideways
/// or backwards, where [`triangulate_dlt`]'s two rows per view, which divide by `z`,
/// degenerate).
///
/// `r1`, `r2` are rays (any non-zero length) in camera 1 and camera 2. Minimises the algebraic
/// error of all three rows of `r_i × (T_ci_w p_w) = 0`, each view's rows scaled by `1 / |r_i|`.
/// Returns `None` as [`triangulate_dlt`] does, and also when the point lies behind either
/// ray (`r_i · p_ci <= 0`): a ray stands for one half-line, not a whole line.
///
/// ```
/// use approx::assert_relative_eq;
/// use ferroslam_geometry::triangulation::triangulate_rays;
/// use nalgebra::{Isometry3, Point3};
/// let T_c1_w = Isometry3::identity();
/// let T_c2_w = Isometry3::translation(0.0, 0.0, 0.5);
/// let p_w = Point3::new(3.0, 0.5, -1.0); // 108 degrees off both optical axes
/// let (p1, p2) = ((T_c1_w * p_w).coords, (T_c2_w * p_w).coords);
/// let x = triangulate_rays(&T_c1_w, &T_c2_w, &p1.normalize(), &p2.normalize()).unwrap();
/// assert_relative_eq!(x, p_w.coords, epsilon = 1e-9);
/// ```
#[allow(non_snake_case)]
pub fn triangulate_rays(
    T_c1_w: &Isometry3<f64>,
    T_c2_w: &Isometry3<f64>,
    r1: &Vector3<f64>,
    r2: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let baseline =
        (T_c1_w.inverse().translation.vector - T_c2_w.inverse().translation.vector).norm();
    let (n1, n2) = (r1.norm(), r2.norm());
    if !(baseline > MIN_BASELINE && n1 > 0.0 && n2 > 0.0) {
        return None;
    }
    let mut a = SMatrix::<f64, 6, 4>::zeros();
    for (k, (t, r, n)) in [(T_c1_w, r1, n1), (T_c2_w, r2, n2)].into_iter().enumerate() {
        let p: Matrix3x4<f64> = t.to_homogeneous().fixed_view::<3, 4>(0, 0).into_owned();
        let r = r / n;
        // r × (P X): rows of [r]x P.
        a.set_row(3 * k, &(p.row(2) * r.y - p.row(1) * r.z));
        a.set_row(3 * k + 1, &(p.row(0) * r.z - p.row(2) * r.x));
        a.set_row(3 * k + 2, &(p.row(1) * r.x - p.row(0) * r.y));
    }
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let smallest =
        (0..4).min_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]))?;
    let h = v_t.row(smallest);
    if h[3].abs() < 1e-12 {
        return None;
    }
    let p_w = Vector3::new(h[0], h[1], h[2]) / h[3];
    if !p_w.iter().all(|v| v.is_finite()) {
        return None;
    }
    let in_front = [(T_c1_w, r1), (T_c2_w, r2)]
        .iter()
        .all(|(t, r)| r.dot(&t.transform_point(&p_w.into()).coords) > 0.0);
    in_front.then_some(p_w)
}

/// Cosine of the parallax angle at `p_w` between the rays to the two camera centres
/// (all in the world frame). Near 1 means little parallax (poorly constrained depth).
///
/// Returns 1.0 (no parallax) if the point coincides with a centre.
pub fn parallax_cos(p_w: &Vector3<f64>, center1_w: &Vector3<f64>, center2_w: &Vector3<f64>) -> f64 {
    let (r1, r2) = (p_w - center1_w, p_w - center2_w);
    let denom = r1.norm() * r2.norm();
    if denom > 0.0 {
        (r1.dot(&r2) / denom).clamp(-1.0, 1.0)
    } else {
        1.0
    }
}

/// Essential matrix `E21 = [t21]x R21` of two posed cameras: `r2^T E21 r1 = 0` for the rays
/// `r1`, `r2` (each camera's frame) of one point, `T_c2_c1 = T_c2_w * T_c1_w^-1 = [R21 | t21]`.
/// The constraint keyframe triangulation and an unrectified pair search along.
#[allow(non_snake_case)]
pub fn essential_matrix(T_c1_w: &Isometry3<f64>, T_c2_w: &Isometry3<f64>) -> Matrix3<f64> {
    let T_21 = T_c2_w * T_c1_w.inverse();
    let t = T_21.translation.vector;
    let t_hat = Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
    t_hat * T_21.rotation.to_rotation_matrix().into_inner()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3;
    use approx::assert_relative_eq;
    use nalgebra::Vector6;

    #[allow(non_snake_case)]
    fn two_views() -> (Isometry3<f64>, Isometry3<f64>) {
        let T_w_c1 = se3::exp(&Vector6::new(0.1, -0.2, 0.0, 0.05, 0.1, -0.02));
        let T_w_c2 = se3::exp(&Vector6::new(0.6, -0.1, 0.1, -0.03, 0.05, 0.04));
        (T_w_c1.inverse(), T_w_c2.inverse())
    }

    #[test]
    #[allow(non_snake_case)]
    fn recovers_synthetic_points() {
        let (T_c1_w, T_c2_w) = two_views();
        for p_w in [
            Vector3::new(0.2, 0.3, 3.0),
            Vector3::new(-1.0, 0.5, 8.0),
            Vector3::new(0.0, 0.0, 40.0),
        ] {
            let (p1, p2) = (
                T_c1_w * nalgebra::Point3::from(p_w),
                T_c2_w * nalgebra::Point3::from(p_w),
            );
            let x = triangulate_dlt(&T_c1_w, &T_c2_w, &(p1.coords / p1.z), &(p2.coords / p2.z))
                .unwrap();
            assert_relative_eq!(x, p_w, epsilon = 1e-8 * p_w.norm());
        }
    }

    #[test]
    #[allow(non_snake_case)]
    fn rejects_pure_rotation_and_parallel_rays() {
        let (T_c1_w, T_c2_w) = two_views();
        // Same centre as camera 1, different orientation: no baseline.
        let pure = Isometry3::rotation(Vector3::new(0.0, 0.2, 0.0)) * T_c1_w;
        let ray = Vector3::new(0.1, 0.0, 1.0);
        assert!(triangulate_dlt(&T_c1_w, &pure, &ray, &ray).is_none());
        assert!(triangulate_dlt(&T_c1_w, &T_c2_w, &ray, &Vector3::zeros()).is_none());
        // Camera 2 translated along x; both rays along z: they never meet.
        let shifted = Isometry3::translation(-1.0, 0.0, 0.0);
        let z = Vector3::new(0.0, 0.0, 1.0);
        assert!(triangulate_dlt(&Isometry3::identity(), &shifted, &z, &z).is_none());
        assert!(triangulate_dlt(
            &Isometry3::identity(),
            &shifted,
            &Vector3::new(f64::NAN, 0.0, 1.0),
            &z
        )
        .is_none());
    }

    #[test]
    #[allow(non_snake_case)]
    fn rays_triangulate_in_every_direction_and_only_in_front() {
        let (T_c1_w, T_c2_w) = two_views();
        let (T_w_c1, T_w_c2) = (T_c1_w.inverse(), T_c2_w.inverse());
        // Points at 0, 80, 100 and 150 degrees from camera 1's axis.
        for (deg, range) in [(0.0f64, 3.0), (80.0, 4.0), (100.0, 5.0), (150.0, 6.0)] {
            let t = deg.to_radians();
            let p_c1 = Vector3::new(t.sin() * 0.8, t.sin() * 0.6, t.cos()) * range;
            let p_w = (T_w_c1 * nalgebra::Point3::from(p_c1)).coords;
            let p_c2 = (T_c2_w * nalgebra::Point3::from(p_w)).coords;
            let x = triangulate_rays(&T_c1_w, &T_c2_w, &p_c1.normalize(), &(p_c2 * 2.0)).unwrap();
            assert_relative_eq!(x, p_w, epsilon = 1e-8 * p_w.norm());
            // The opposite rays meet at the same line intersection, behind both cameras.
            assert!(triangulate_rays(&T_c1_w, &T_c2_w, &-p_c1, &-p_c2).is_none());
        }
        let ray = Vector3::new(0.1, 0.0, 1.0);
        let pure = Isometry3::rotation(Vector3::new(0.0, 0.2, 0.0)) * T_c1_w;
        assert!(triangulate_rays(&T_c1_w, &pure, &ray, &ray).is_none());
        let same = T_w_c2.rotation.inverse() * (T_w_c1.rotation * ray);
        assert!(triangulate_rays(&T_c1_w, &T_c2_w, &ray, &same).is_none());
    }

    #[test]
    fn parallax_of_symmetric_views() {
        let c = parallax_cos(
            &Vector3::new(0.0, 0.0, 1.0),
            &Vector3::new(-1.0, 0.0, 0.0),
            &Vector3::new(1.0, 0.0, 0.0),
        );
        assert_relative_eq!(c, 0.0, epsilon = 1e-15);
        assert_eq!(
            parallax_cos(&Vector3::zeros(), &Vector3::zeros(), &Vector3::x()),
            1.0
        );
    }

    #[test]
    #[allow(non_snake_case)]
    fn rays_of_one_point_satisfy_the_epipolar_constraint() {
        let T_c1_w = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.2, -0.1, 0.05));
        let T_c2_w = Isometry3::new(Vector3::new(-0.4, 0.1, 0.2), Vector3::new(-0.1, 0.3, 0.1));
        let E = essential_matrix(&T_c1_w, &T_c2_w);
        for p_w in [Vector3::new(0.5, -0.3, 3.0), Vector3::new(-1.0, 0.4, 6.0)] {
            let r1 = (T_c1_w * nalgebra::Point3::from(p_w)).coords.normalize();
            let r2 = (T_c2_w * nalgebra::Point3::from(p_w)).coords.normalize();
            assert!((r2.transpose() * E * r1)[0].abs() < 1e-12);
            // Another point's ray in camera 2 breaks it.
            let off = (r2 + Vector3::new(0.0, 0.05, 0.0)).normalize();
            assert!((off.transpose() * E * r1)[0].abs() > 1e-3);
        }
    }
}
