//! Reprojection residual of a world point in a camera, mono or stereo, and its Jacobians.
//!
//! `p_c = T_c_w * p_w`; predicted `[u, v, u_r] = [fx x/z + cx, fy y/z + cy, u - bf/z]` for
//! the pinhole, and for a fisheye `(u, v)` its projection of `p_c` and `u_r` the column of
//! `p_c` in the virtual right camera (see [`Intrinsics`]); residual `e = observed - predicted`. Monocular observations use rows 0..2 and leave row 2
//! (and the corresponding Jacobian row) zero, so one code path serves both kinds; the
//! information is `inv_sigma2 * I` on the used rows.

use crate::error::OptimError;
use crate::intrinsics::Intrinsics;
use ferroslam_geometry::so3;
use nalgebra::{Isometry3, Matrix3, Matrix3x6, Point3, Vector2, Vector3};

/// Residual and Jacobians of one observation at the current estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linearization {
    /// `observed - predicted`, pixels; row 2 is zero for monocular observations.
    pub e: Vector3<f64>,
    /// `d e / d xi` for the LEFT perturbation `T_c_w <- exp(xi) * T_c_w`, `xi = [rho; phi]`.
    pub d_e_d_xi: Matrix3x6<f64>,
    /// `d e / d p_w`, pixels per metre.
    pub d_e_d_p_w: Matrix3<f64>,
}

/// Camera-frame point and the prediction it makes, or `None` if it is not strictly in front
/// of the pinhole (outside the fisheye's domain, for it or the virtual right camera) or
/// anything is non-finite.
pub(crate) fn predict(k: &Intrinsics, p_c: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    if k.fisheye.is_some() {
        return predict_fisheye(k, p_c);
    }
    let (x, y, z) = (p_c.x, p_c.y, p_c.z);
    // Cameras see along +z; z <= 0 is ORB-SLAM's "depth not positive" outlier.
    if !p_c.iter().all(|v| v.is_finite()) || z <= 0.0 {
        return None;
    }
    let iz = 1.0 / z;
    let u = k.fx * x * iz + k.cx;
    let v = k.fy * y * iz + k.cy;
    let pred = Vector3::new(u, v, u - k.bf * iz);
    if !pred.iter().all(|v| v.is_finite()) {
        return None;
    }
    let iz2 = iz * iz;
    #[rustfmt::skip]
    let d_pred_d_p_c = Matrix3::new(
        k.fx * iz, 0.0,       -k.fx * x * iz2,
        0.0,       k.fy * iz, -k.fy * y * iz2,
        k.fx * iz, 0.0,       -k.fx * x * iz2 + k.bf * iz2,
    );
    Some((pred, d_pred_d_p_c))
}

/// [`predict`] through the fisheye; without a baseline the right row repeats `u`. Where
/// only the virtual right camera does not project, the right row is NaN (with a zero
/// Jacobian row), so that only a stereo residual of the point is refused.
fn predict_fisheye(k: &Intrinsics, p_c: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    if !p_c.iter().all(|v| v.is_finite()) {
        return None;
    }
    let (uv, d_uv_d_p_c) = k.project_fisheye(p_c)?;
    if !uv.iter().all(|v| v.is_finite()) {
        return None;
    }
    let (u_r, d_ur_d_p_c) = if k.bf > 0.0 {
        match k.project_fisheye(&k.right_point(p_c)) {
            Some((uv_r, d_r)) => (uv_r.x, d_r.row(0).into_owned()),
            None => (f64::NAN, nalgebra::RowVector3::zeros()),
        }
    } else {
        (uv.x, d_uv_d_p_c.row(0).into_owned())
    };
    let mut d_pred_d_p_c = Matrix3::zeros();
    d_pred_d_p_c
        .fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&d_uv_d_p_c);
    d_pred_d_p_c.set_row(2, &d_ur_d_p_c);
    Some((Vector3::new(uv.x, uv.y, u_r), d_pred_d_p_c))
}

fn error_of(pred: &Vector3<f64>, uv: &Vector2<f64>, u_right: Option<f64>) -> Vector3<f64> {
    Vector3::new(
        uv.x - pred.x,
        uv.y - pred.y,
        u_right.map_or(0.0, |ur| ur - pred.z),
    )
}

/// Residual `observed - predicted` (pixels) of `p_w` seen at `uv` (and `u_right` for stereo)
/// from `T_c_w`; `None` if the point is not in front of the camera or a value is non-finite.
#[allow(non_snake_case)]
pub fn residual(
    k: &Intrinsics,
    T_c_w: &Isometry3<f64>,
    p_w: &Vector3<f64>,
    uv: &Vector2<f64>,
    u_right: Option<f64>,
) -> Option<Vector3<f64>> {
    let p_c = T_c_w.transform_point(&Point3::from(*p_w)).coords;
    let (pred, _) = predict(k, &p_c)?;
    let e = error_of(&pred, uv, u_right);
    e.iter().all(|v| v.is_finite()).then_some(e)
}

/// Residual and Jacobians (see [`Linearization`]); `None` exactly when [`residual`] is `None`.
#[allow(non_snake_case)]
pub fn linearize(
    k: &Intrinsics,
    T_c_w: &Isometry3<f64>,
    p_w: &Vector3<f64>,
    uv: &Vector2<f64>,
    u_right: Option<f64>,
) -> Option<Linearization> {
    let (e, d_e_d_xi) = linearize_pose(k, T_c_w, p_w, uv, u_right)?;
    // The translation block of d e / d xi is d e / d p_c.
    let d_e_d_p_c = d_e_d_xi.fixed_view::<3, 3>(0, 0);
    let r_c_w = T_c_w.rotation.to_rotation_matrix().into_inner();
    Some(Linearization {
        e,
        d_e_d_xi,
        d_e_d_p_w: d_e_d_p_c * r_c_w,
    })
}

/// The residual and `d e / d xi` of [`linearize`], without the point Jacobian (motion-only
/// BA); `None` exactly when [`residual`] is `None`.
#[allow(non_snake_case)]
pub(crate) fn linearize_pose(
    k: &Intrinsics,
    T_c_w: &Isometry3<f64>,
    p_w: &Vector3<f64>,
    uv: &Vector2<f64>,
    u_right: Option<f64>,
) -> Option<(Vector3<f64>, Matrix3x6<f64>)> {
    let p_c = T_c_w.transform_point(&Point3::from(*p_w)).coords;
    let (pred, mut d_pred_d_p_c) = predict(k, &p_c)?;
    let e = error_of(&pred, uv, u_right);
    if !e.iter().all(|v| v.is_finite()) {
        return None;
    }
    if u_right.is_none() {
        d_pred_d_p_c.row_mut(2).fill(0.0);
    }
    let d_e_d_p_c = -d_pred_d_p_c;
    // Left perturbation: exp(xi) * p_c ~ p_c + rho + phi x p_c.
    let mut d_p_c_d_xi = Matrix3x6::zeros();
    d_p_c_d_xi
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    d_p_c_d_xi
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(-so3::hat(&p_c)));
    Some((e, d_e_d_p_c * d_p_c_d_xi))
}

/// `inv_sigma2 * |e|^2` of an observation, `None` where [`residual`] is `None`.
#[allow(non_snake_case)]
pub fn chi2(
    k: &Intrinsics,
    T_c_w: &Isometry3<f64>,
    p_w: &Vector3<f64>,
    uv: &Vector2<f64>,
    u_right: Option<f64>,
    inv_sigma2: f64,
) -> Option<f64> {
    residual(k, T_c_w, p_w, uv, u_right).map(|e| inv_sigma2 * e.norm_squared())
}

/// Checks one measurement: finite `uv` / `u_right` / `inv_sigma2` and positive information.
/// `index` names the observation in the error.
pub fn validate_measurement(
    index: usize,
    uv: &Vector2<f64>,
    u_right: Option<f64>,
    inv_sigma2: f64,
) -> Result<(), OptimError> {
    let finite = uv.iter().all(|v| v.is_finite())
        && u_right.is_none_or(f64::is_finite)
        && inv_sigma2.is_finite();
    if !finite {
        return Err(OptimError::NonFinite {
            what: "observation",
            index,
        });
    }
    if inv_sigma2 <= 0.0 {
        return Err(OptimError::InvalidInput(format!(
            "observation {index} has inv_sigma2 = {inv_sigma2} (must be > 0)"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ferroslam_geometry::{se3, testing::check_jacobian};
    use nalgebra::{DMatrix, DVector, UnitQuaternion, Vector6};

    const K: Intrinsics = Intrinsics {
        fx: 517.3,
        fy: 516.5,
        cx: 318.6,
        cy: 255.3,
        bf: 41.4,
        fisheye: None,
    };

    #[allow(non_snake_case)]
    fn setup() -> (Isometry3<f64>, Vector3<f64>, Vector2<f64>) {
        let T_c_w = Isometry3::from_parts(
            Vector3::new(0.3, -0.2, 0.5).into(),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, -0.3, 0.2)),
        );
        let p_w = Vector3::new(0.4, 0.7, 4.0);
        (T_c_w, p_w, Vector2::new(300.0, 260.0))
    }

    fn dvec(v: &Vector3<f64>) -> DVector<f64> {
        DVector::from_column_slice(v.as_slice())
    }

    #[test]
    #[allow(non_snake_case)]
    fn jacobians_match_central_differences() {
        let (T_c_w, p_w, uv) = setup();
        for (name, u_right) in [("mono", None), ("stereo", Some(290.0))] {
            let lin = linearize(&K, &T_c_w, &p_w, &uv, u_right).unwrap();
            let d_xi = DMatrix::from_column_slice(3, 6, lin.d_e_d_xi.as_slice());
            check_jacobian(
                &format!("{name} d_e_d_xi (left, exp(xi) * T_c_w)"),
                &d_xi,
                |x| {
                    let xi = Vector6::from_column_slice(x.as_slice());
                    dvec(&residual(&K, &(se3::exp(&xi) * T_c_w), &p_w, &uv, u_right).unwrap())
                },
                &DVector::zeros(6),
                1e-6,
                1e-6,
            );
            let d_p = DMatrix::from_column_slice(3, 3, lin.d_e_d_p_w.as_slice());
            check_jacobian(
                &format!("{name} d_e_d_p_w"),
                &d_p,
                |x| {
                    dvec(
                        &residual(
                            &K,
                            &T_c_w,
                            &Vector3::from_column_slice(x.as_slice()),
                            &uv,
                            u_right,
                        )
                        .unwrap(),
                    )
                },
                &dvec(&p_w),
                1e-6,
                1e-6,
            );
            assert_eq!(lin.e, residual(&K, &T_c_w, &p_w, &uv, u_right).unwrap());
        }
    }

    #[test]
    #[allow(non_snake_case)]
    fn stereo_row_is_virtual_right_coordinate_and_mono_row_is_zero() {
        let T_c_w = Isometry3::identity();
        let p_w = Vector3::new(0.5, -0.25, 2.0);
        let u = K.fx * 0.25 + K.cx;
        let v = K.fy * -0.125 + K.cy;
        let uv = Vector2::new(u, v);
        let e = residual(&K, &T_c_w, &p_w, &uv, Some(u - K.bf / 2.0)).unwrap();
        assert!(e.norm() < 1e-12);
        let lin = linearize(&K, &T_c_w, &p_w, &(uv + Vector2::new(1.0, 2.0)), None).unwrap();
        assert_eq!(lin.e, Vector3::new(1.0, 2.0, 0.0));
        assert!(
            lin.d_e_d_xi.row(2).iter().all(|&x| x == 0.0)
                && lin.d_e_d_p_w.row(2).iter().all(|&x| x == 0.0)
        );
        assert_eq!(
            chi2(&K, &T_c_w, &p_w, &(uv + Vector2::new(1.0, 2.0)), None, 4.0),
            Some(20.0)
        );
    }

    #[test]
    #[allow(non_snake_case)]
    fn fisheye_jacobians_match_central_differences_beyond_ninety_degrees() {
        let (_, lens) = ferroslam_geometry::camera::test_fisheye_cameras()[0];
        let k = Intrinsics::new(&lens.into(), lens.fx * 0.1);
        let T_c_w = Isometry3::from_parts(
            Vector3::new(0.1, -0.2, 0.05).into(),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.05, 0.1, -0.02)),
        );
        // 100 degrees off the axis in the camera (z < 0), and an ordinary point.
        let dir = Vector3::new(100f64.to_radians().sin(), 0.3, 100f64.to_radians().cos());
        for p_c in [dir.normalize() * 3.0, Vector3::new(0.4, 0.3, 2.0)] {
            let p_w = (T_c_w.inverse() * Point3::from(p_c)).coords;
            let uv = lens.project(&p_c).unwrap() + Vector2::new(0.7, -0.4);
            let u_r = lens
                .project(&(p_c - Vector3::new(0.1, 0.0, 0.0)))
                .unwrap()
                .x;
            assert_eq!(k.u_right(&p_c, uv.x), Some(u_r));
            for u_right in [None, Some(u_r + 1.5)] {
                let lin = linearize(&k, &T_c_w, &p_w, &uv, u_right).unwrap();
                let d_xi = DMatrix::from_column_slice(3, 6, lin.d_e_d_xi.as_slice());
                check_jacobian(
                    "fisheye d_e_d_xi",
                    &d_xi,
                    |x| {
                        let xi = Vector6::from_column_slice(x.as_slice());
                        let T = se3::exp(&xi) * T_c_w;
                        dvec(&residual(&k, &T, &p_w, &uv, u_right).unwrap())
                    },
                    &DVector::zeros(6),
                    1e-6,
                    1e-5,
                );
                let d_p = DMatrix::from_column_slice(3, 3, lin.d_e_d_p_w.as_slice());
                check_jacobian(
                    "fisheye d_e_d_p_w",
                    &d_p,
                    |x| {
                        let p = Vector3::from_column_slice(x.as_slice());
                        dvec(&residual(&k, &T_c_w, &p, &uv, u_right).unwrap())
                    },
                    &dvec(&p_w),
                    1e-6,
                    1e-5,
                );
                let e = residual(&k, &T_c_w, &p_w, &uv, u_right).unwrap();
                assert!((e.xy() - Vector2::new(0.7, -0.4)).norm() < 1e-9);
                assert!(u_right.is_none_or(|_| (e.z - 1.5).abs() < 1e-9));
            }
        }
        // Straight behind the camera, past the lens's largest incidence angle.
        let behind = Vector3::new(0.0, 0.0, -2.0);
        let uv = Vector2::new(250.0, 250.0);
        assert!(residual(&k, &Isometry3::identity(), &behind, &uv, None).is_none());
    }

    #[test]
    #[allow(non_snake_case)]
    fn behind_camera_and_non_finite_are_none() {
        let T_c_w = Isometry3::identity();
        let uv = Vector2::new(320.0, 240.0);
        assert!(residual(&K, &T_c_w, &Vector3::new(0.0, 0.0, -1.0), &uv, None).is_none());
        assert!(residual(&K, &T_c_w, &Vector3::new(0.0, 0.0, 0.0), &uv, None).is_none());
        assert!(linearize(&K, &T_c_w, &Vector3::new(f64::NAN, 0.0, 1.0), &uv, None).is_none());
        assert!(residual(
            &K,
            &T_c_w,
            &Vector3::new(0.0, 0.0, 1.0),
            &uv,
            Some(f64::INFINITY)
        )
        .is_none());
    }
}
