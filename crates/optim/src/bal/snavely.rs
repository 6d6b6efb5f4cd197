//! Snavely's BAL camera: projection and its analytic Jacobians.

use ferroslam_geometry::so3;
use nalgebra::{Matrix2, Matrix2x3, Matrix3, SMatrix, SVector, Vector2, Vector3};

/// Parameters per camera: `[w (angle-axis, 3), t (3), f, k1, k2]`.
pub const CAMERA_PARAMS: usize = 9;

/// One BAL camera, `[w1 w2 w3 t1 t2 t3 f k1 k2]` (see the [module docs](super)).
pub type CameraParams = SVector<f64, CAMERA_PARAMS>;

/// A BAL camera prepared for projecting many points: rotation matrix and the right Jacobian
/// of its angle-axis vector computed once.
///
/// `project(X) = f d(p) p` with `P = R(w) X + t`, `p = -P.xy / P.z`,
/// `d = 1 + k1 |p|^2 + k2 |p|^4` (pixels, centred). Defined for `P.z != 0`; BAL points lie
/// behind the camera plane (`P.z < 0`), which is not checked, as in Ceres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnavelyCamera {
    rotation: Matrix3<f64>,
    /// `J_r(w)`: `R(w + dw) X ≈ R(w) X - R(w) hat(X) J_r(w) dw` (additive angle-axis update).
    right_jacobian: Matrix3<f64>,
    translation: Vector3<f64>,
    focal: f64,
    k1: f64,
    k2: f64,
}

/// Residual `project(X) - uv` of one observation and its Jacobians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnavelyLinearization {
    /// Predicted minus observed, pixels.
    pub residual: Vector2<f64>,
    /// With respect to the 9 camera parameters `[w, t, f, k1, k2]` (additive updates).
    pub d_r_d_camera: SMatrix<f64, 2, 9>,
    /// With respect to the world point.
    pub d_r_d_point: Matrix2x3<f64>,
}

impl SnavelyCamera {
    /// Prepares `params = [w, t, f, k1, k2]`.
    pub fn new(params: &CameraParams) -> Self {
        let w = params.fixed_rows::<3>(0).into_owned();
        let rotation = so3::exp(&w).to_rotation_matrix().into_inner();
        Self {
            rotation,
            right_jacobian: so3::right_jacobian(&w),
            translation: params.fixed_rows::<3>(3).into_owned(),
            focal: params[6],
            k1: params[7],
            k2: params[8],
        }
    }

    /// Point in the camera frame, `R(w) X + t`.
    fn point_in_camera(&self, point: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * point + self.translation
    }

    /// Normalised coordinates `p = -P.xy / P.z`, `None` if not finite (`P.z == 0`).
    fn normalise(p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        let p = -p_c.xy() / p_c.z;
        p.iter().all(|v| v.is_finite()).then_some(p)
    }

    /// Radial factor `d = 1 + k1 r2 + k2 r2^2` for `r2 = |p|^2`.
    fn distortion(&self, r2: f64) -> f64 {
        1.0 + r2 * (self.k1 + self.k2 * r2)
    }

    /// Predicted image position of world point `point`, pixels; `None` if the point lies on
    /// the camera plane or anything is non-finite.
    pub fn project(&self, point: &Vector3<f64>) -> Option<Vector2<f64>> {
        let p = Self::normalise(&self.point_in_camera(point))?;
        let uv = self.focal * self.distortion(p.norm_squared()) * p;
        uv.iter().all(|v| v.is_finite()).then_some(uv)
    }

    /// Residual `project(point) - uv` and its Jacobians; `None` where [`Self::project`] is.
    pub fn linearize(
        &self,
        point: &Vector3<f64>,
        uv: &Vector2<f64>,
    ) -> Option<SnavelyLinearization> {
        let p_c = self.point_in_camera(point);
        let p = Self::normalise(&p_c)?;
        let r2 = p.norm_squared();
        let d = self.distortion(r2);
        let predicted = self.focal * d * p;
        // d(f d p)/dp = f (d I + 2 (k1 + 2 k2 r2) p p^T).
        let d_uv_d_p = self.focal
            * (Matrix2::identity() * d + 2.0 * (self.k1 + 2.0 * self.k2 * r2) * p * p.transpose());
        let inv_z = 1.0 / p_c.z;
        // p = -P.xy / P.z.
        let d_p_d_p_c = Matrix2x3::new(
            -inv_z,
            0.0,
            p_c.x * inv_z * inv_z,
            0.0,
            -inv_z,
            p_c.y * inv_z * inv_z,
        );
        let d_uv_d_p_c = d_uv_d_p * d_p_d_p_c;
        let mut d_r_d_camera = SMatrix::<f64, 2, 9>::zeros();
        let d_uv_d_w = -d_uv_d_p_c * self.rotation * so3::hat(point) * self.right_jacobian;
        d_r_d_camera.fixed_columns_mut::<3>(0).copy_from(&d_uv_d_w);
        d_r_d_camera
            .fixed_columns_mut::<3>(3)
            .copy_from(&d_uv_d_p_c);
        d_r_d_camera.set_column(6, &(d * p));
        d_r_d_camera.set_column(7, &(self.focal * r2 * p));
        d_r_d_camera.set_column(8, &(self.focal * r2 * r2 * p));
        let linearization = SnavelyLinearization {
            residual: predicted - uv,
            d_r_d_camera,
            d_r_d_point: d_uv_d_p_c * self.rotation,
        };
        let finite = linearization.residual.iter().all(|v| v.is_finite())
            && linearization.d_r_d_camera.iter().all(|v| v.is_finite());
        finite.then_some(linearization)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bal::{fixtures, read_bal};
    use ferroslam_geometry::testing::check_jacobian;
    use nalgebra::{DMatrix, DVector};

    /// Checks both Jacobians of observation `uv` of `point` by `params` numerically.
    fn check(label: &str, params: &CameraParams, point: &Vector3<f64>, uv: &Vector2<f64>) {
        let l = SnavelyCamera::new(params).linearize(point, uv).unwrap();
        let residual = |c: &CameraParams, x: &Vector3<f64>| {
            let r = SnavelyCamera::new(c).linearize(x, uv).unwrap().residual;
            DVector::from_column_slice(r.as_slice())
        };
        check_jacobian(
            &format!("{label}: d r / d camera"),
            &DMatrix::from_column_slice(2, 9, l.d_r_d_camera.as_slice()),
            |d| residual(&CameraParams::from_column_slice(d.as_slice()), point),
            &DVector::from_column_slice(params.as_slice()),
            1e-6,
            1e-6,
        );
        check_jacobian(
            &format!("{label}: d r / d point"),
            &DMatrix::from_column_slice(2, 3, l.d_r_d_point.as_slice()),
            |d| residual(params, &Vector3::from_column_slice(d.as_slice())),
            &DVector::from_column_slice(point.as_slice()),
            1e-6,
            1e-6,
        );
        let predicted = SnavelyCamera::new(params).project(point).unwrap();
        assert_eq!(l.residual, predicted - uv);
    }

    #[test]
    fn jacobians_match_numeric_derivatives_on_dubrovnik() {
        let problem = read_bal(fixtures::path("dubrovnik-3-7-pre.txt")).unwrap();
        for (i, o) in problem.observations.iter().enumerate() {
            check(
                &format!("observation {i}"),
                &problem.cameras[o.camera],
                &problem.points[o.point],
                &o.uv,
            );
        }
    }

    #[test]
    fn jacobians_hold_at_zero_rotation_and_the_model_matches_its_formula() {
        let params =
            CameraParams::from_column_slice(&[0.0, 0.0, 0.0, 0.1, -0.2, 0.3, 500.0, -0.1, 0.02]);
        let point = Vector3::new(0.4, -0.3, -4.0);
        check("zero rotation", &params, &point, &Vector2::new(3.0, -2.0));
        // P = X + t = (0.5, -0.5, -3.7), p = (0.5, -0.5) / 3.7.
        let p = Vector2::new(0.5, -0.5) / 3.7;
        let r2 = p.norm_squared();
        let expected: Vector2<f64> = 500.0 * (1.0 - 0.1 * r2 + 0.02 * r2 * r2) * p;
        let uv = SnavelyCamera::new(&params).project(&point).unwrap();
        assert!((uv - expected).norm() < 1e-12);
        let on_plane = Vector3::new(1.0, 1.0, -0.3);
        assert!(SnavelyCamera::new(&params).project(&on_plane).is_none());
    }
}
