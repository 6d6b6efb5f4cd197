//! Kannala-Brandt fisheye camera (OpenCV `cv2.fisheye`, ORB-SLAM3 `KannalaBrandt8`, Kalibr
//! `pinhole-equi`).
//!
//! A camera point `p_c = (x, y, z)` (any direction, `z` may be negative) has incidence angle
//! `theta = atan2(r, z)`, `r = sqrt(x^2 + y^2)`, and projects to RAW pixels:
//!
//! ```text
//! theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
//! u = fx theta_d x / r + cx,   v = fy theta_d y / r + cy
//! ```
//!
//! The model is only one-to-one while `theta_d` grows with `theta`; beyond the first
//! turning point (or beyond pi) a pixel would stand for two directions, so such points do
//! not project ([`KannalaBrandtCamera::max_incidence_rad`]). Unprojection returns unit rays,
//! so fields of view beyond 180 degrees are represented without a image plane.

use nalgebra::{Matrix2x3, Vector2, Vector3};

use super::validation::{check_intrinsics, check_monotonic_over_image, corner_radius};
use crate::rolling_shutter::RollingShutter;
use crate::GeometryError;

/// Below this `r / |p|` a point is treated as on the optical axis (the `theta_d / r` limit).
const ON_AXIS: f64 = 1e-12;
/// Newton iterations for `theta` in [`KannalaBrandtCamera::unproject`].
const UNPROJECT_ITERATIONS: usize = 20;
/// Step (radians) of the scan for the first turning point of `theta_d(theta)`.
const SCAN_STEP_RAD: f64 = 1e-3;

/// Kannala-Brandt intrinsics (pixels), four distortion coefficients and image size.
///
/// Build through [`KannalaBrandtCamera::new`] to have them validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KannalaBrandtCamera {
    /// Focal length along x (pixels per radian of `theta_d`).
    pub fx: f64,
    /// Focal length along y (pixels per radian of `theta_d`).
    pub fy: f64,
    /// Principal point x (pixels).
    pub cx: f64,
    /// Principal point y (pixels).
    pub cy: f64,
    /// Coefficients `k1..k4` of `theta^3 .. theta^9`.
    pub k: [f64; 4],
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
    /// When each row of a raw image is read ([`RollingShutter::global`] from [`Self::new`]).
    pub shutter: RollingShutter,
    max_incidence_rad: f64,
}

impl KannalaBrandtCamera {
    /// Validated constructor: finite values, positive focal lengths and image size, the
    /// principal point inside the image, a model one-to-one for at least the first 10
    /// degrees off the axis, and `theta_d(theta)` scaling angles plausibly
    /// (`validation::check_monotonic_over_image`) out to the farthest image corner or the
    /// end of the field of view.
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        k: [f64; 4],
        width: u32,
        height: u32,
    ) -> Result<Self, GeometryError> {
        let names = ["k1", "k2", "k3", "k4"];
        check_intrinsics([fx, fy, cx, cy], names.into_iter().zip(k), [width, height])?;
        let max_incidence_rad = first_turning_point(&k);
        if max_incidence_rad < 10f64.to_radians() {
            return Err(GeometryError::InvalidParameter {
                name: "k1",
                value: k[0],
                reason: "the coefficients fold the image over within 10 degrees of the axis",
            });
        }
        check_monotonic_over_image(
            |theta| distort(&k, theta).0,
            |theta| {
                let t2 = theta * theta;
                (0..4)
                    .map(|i| (names[i], k[i], k[i] * t2.powi(i as i32 + 1)))
                    .collect()
            },
            corner_radius([fx, fy, cx, cy], [width, height]),
            max_incidence_rad,
        )?;
        Ok(Self {
            fx,
            fy,
            cx,
            cy,
            k,
            width,
            height,
            shutter: RollingShutter::global(),
            max_incidence_rad,
        })
    }

    /// Largest incidence angle (radians from the optical axis, at most pi) that projects:
    /// where `theta_d(theta)` stops growing.
    pub fn max_incidence_rad(&self) -> f64 {
        self.max_incidence_rad
    }

    /// Projection of `p_c` (camera frame, metres) to raw pixels. `None` for a non-finite or
    /// zero point and beyond [`Self::max_incidence_rad`].
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.project_with_jacobian(p_c).map(|(uv, _)| uv)
    }

    /// [`Self::project`] together with `d_uv_d_p_c`, the 2x3 Jacobian of the pixel with
    /// respect to the camera point.
    pub fn project_with_jacobian(
        &self,
        p_c: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        let norm = p_c.norm();
        if !(norm.is_finite() && norm > 0.0) {
            return None;
        }
        let (x, y, z) = (p_c.x, p_c.y, p_c.z);
        let r2 = x * x + y * y;
        let r = r2.sqrt();
        if r < ON_AXIS * norm {
            if z <= 0.0 {
                return None;
            }
            // On the axis theta_d / r -> 1 / z: the pinhole Jacobian.
            let uv = Vector2::new(self.fx * x / z + self.cx, self.fy * y / z + self.cy);
            let j = Matrix2x3::new(self.fx / z, 0.0, 0.0, 0.0, self.fy / z, 0.0);
            return Some((uv, j));
        }
        let theta = r.atan2(z);
        if theta > self.max_incidence_rad {
            return None;
        }
        let (theta_d, d_theta_d) = distort(&self.k, theta);
        let psi = theta_d / r;
        // d theta / d(x, y, z) and d r / d(x, y, z); rho2 = |p|^2.
        let rho2 = r2 + z * z;
        let d_theta = Vector3::new(z * x / (r * rho2), z * y / (r * rho2), -r / rho2);
        let d_r = Vector3::new(x / r, y / r, 0.0);
        let d_psi = (d_theta * d_theta_d * r - d_r * theta_d) / r2;
        let uv = Vector2::new(self.fx * psi * x + self.cx, self.fy * psi * y + self.cy);
        let j = Matrix2x3::new(
            self.fx * (psi + x * d_psi.x),
            self.fx * x * d_psi.y,
            self.fx * x * d_psi.z,
            self.fy * y * d_psi.x,
            self.fy * (psi + y * d_psi.y),
            self.fy * y * d_psi.z,
        );
        Some((uv, j))
    }

    /// The unit ray through the raw pixel `uv`. `None` for a non-finite pixel or one beyond
    /// the image circle of [`Self::max_incidence_rad`].
    pub fn unproject(&self, uv: &Vector2<f64>) -> Option<Vector3<f64>> {
        let m = Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy);
        let theta_d = m.norm();
        if !theta_d.is_finite() {
            return None;
        }
        if theta_d < ON_AXIS {
            return Some(Vector3::z());
        }
        if theta_d > distort(&self.k, self.max_incidence_rad).0 {
            return None;
        }
        // theta_d(theta) is increasing on [0, max]: Newton from theta_d, kept in range.
        let mut theta = theta_d.min(self.max_incidence_rad);
        for _ in 0..UNPROJECT_ITERATIONS {
            let (f, df) = distort(&self.k, theta);
            let step = (f - theta_d) / df;
            theta = (theta - step).clamp(0.0, self.max_incidence_rad);
            if step.abs() < 1e-15 {
                break;
            }
        }
        let s = theta.sin() / theta_d;
        Some(Vector3::new(m.x * s, m.y * s, theta.cos()))
    }
}

/// `theta_d(theta)` and its derivative.
fn distort(k: &[f64; 4], theta: f64) -> (f64, f64) {
    let t2 = theta * theta;
    let poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])));
    let d_poly = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
    (theta * poly, d_poly)
}

/// The first `theta` in `(0, pi]` where `d theta_d / d theta` is no longer positive (pi if
/// none), found by a scan then bisection.
fn first_turning_point(k: &[f64; 4]) -> f64 {
    let pi = std::f64::consts::PI;
    let mut lo = 0.0;
    while lo < pi {
        let hi = (lo + SCAN_STEP_RAD).min(pi);
        if distort(k, hi).1 <= 0.0 {
            let (mut a, mut b) = (lo, hi);
            for _ in 0..60 {
                let mid = 0.5 * (a + b);
                if distort(k, mid).1 > 0.0 {
                    a = mid;
                } else {
                    b = mid;
                }
            }
            return a;
        }
        lo = hi;
    }
    pi
}

/// Fisheye calibrations for tests: the TUM-VI `cam0` (512x512, about 195 degrees) and a
/// T265-class lens (848x800, fx 285).
pub fn test_fisheye_cameras() -> Vec<(&'static str, KannalaBrandtCamera)> {
    let camera = |fx, fy, cx, cy, k, width, height| {
        KannalaBrandtCamera::new(fx, fy, cx, cy, k, width, height).expect("valid test camera")
    };
    vec![
        (
            "tum_vi_cam0",
            camera(
                190.978_477_098_74,
                190.973_436_850_97,
                254.931_706_264_52,
                256.897_442_328_91,
                [
                    0.003_482_389_636_13,
                    0.000_715_034_845_738_3,
                    -0.002_053_236_849_287_6,
                    0.000_202_936_735_060_33,
                ],
                512,
                512,
            ),
        ),
        (
            "t265_class",
            camera(
                284.929_992_675_78,
                285.469_390_869_14,
                421.040_008_544_92,
                403.178_985_595_7,
                [
                    -0.006_580_620_911_7,
                    0.041_487_898_677_5,
                    -0.038_747_899_234_3,
                    0.006_461_910_065_1,
                ],
                848,
                800,
            ),
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::check_jacobian;
    use approx::assert_relative_eq;
    use nalgebra::{DMatrix, DVector};

    fn direction(theta: f64, phi: f64, range: f64) -> Vector3<f64> {
        Vector3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        ) * range
    }

    #[test]
    fn unproject_inverts_project_beyond_ninety_degrees() {
        for (name, c) in test_fisheye_cameras() {
            assert!(
                c.max_incidence_rad() > 1.7,
                "{name}: {}",
                c.max_incidence_rad()
            );
            for theta_deg in [0.0, 1.0, 30.0, 60.0, 89.0, 95.0] {
                for phi in [0.3, 2.0, -1.2] {
                    let p = direction(f64::to_radians(theta_deg), phi, 3.0);
                    let ray = c.unproject(&c.project(&p).unwrap()).unwrap();
                    assert_relative_eq!(ray, p / 3.0, epsilon = 1e-10);
                }
            }
        }
    }

    #[test]
    fn project_jacobian_matches_numeric() {
        for (name, c) in test_fisheye_cameras() {
            for p in [
                Vector3::new(0.4, -0.3, 2.5),
                Vector3::new(1.0, 0.5, -0.2),
                Vector3::new(1e-14, 0.0, 2.0),
            ] {
                let (_, j) = c.project_with_jacobian(&p).unwrap();
                let f = |x: &DVector<f64>| {
                    let uv = c.project(&Vector3::new(x[0], x[1], x[2])).unwrap();
                    DVector::from_column_slice(uv.as_slice())
                };
                let analytic = DMatrix::from_column_slice(2, 3, j.as_slice());
                let x0 = DVector::from_column_slice(p.as_slice());
                check_jacobian(name, &analytic, f, &x0, 1e-7, 1e-5);
            }
        }
    }

    #[test]
    fn rejects_folding_coefficients_and_directions_past_the_fold() {
        // theta_d = theta - theta^3 turns at theta = 1/sqrt(3) (theta_d 0.385), before the
        // image corners (1.33): their pixels do not unproject.
        let c =
            KannalaBrandtCamera::new(300.0, 300.0, 320.0, 240.0, [-1.0, 0.0, 0.0, 0.0], 640, 480)
                .unwrap();
        assert_relative_eq!(c.max_incidence_rad(), 1.0 / 3f64.sqrt(), epsilon = 1e-9);
        assert!(c.project(&direction(0.7, 0.0, 1.0)).is_none());
        assert!(c.project(&direction(0.5, 0.0, 1.0)).is_some());
        assert!(
            KannalaBrandtCamera::new(300.0, 300.0, 0.0, 0.0, [-100.0, 0.0, 0.0, 0.0], 64, 64)
                .is_err()
        );
        assert!(KannalaBrandtCamera::new(0.0, 300.0, 0.0, 0.0, [0.0; 4], 64, 64).is_err());
        assert!(KannalaBrandtCamera::new(
            300.0,
            300.0,
            0.0,
            0.0,
            [f64::NAN, 0.0, 0.0, 0.0],
            64,
            64
        )
        .is_err());
    }

    #[test]
    fn no_projection_for_zero_or_backward_axis_points() {
        let (_, c) = test_fisheye_cameras()[0];
        assert!(c.project(&Vector3::zeros()).is_none());
        assert!(c.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(c.project(&Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
        assert!(c.unproject(&Vector2::new(f64::NAN, 1.0)).is_none());
    }

    #[test]
    fn implausible_coefficients_and_principal_points_are_named() {
        let new = |k, cx, cy| KannalaBrandtCamera::new(285.0, 285.0, cx, cy, k, 848, 800);
        // The T265 fisheye's calibration passes.
        new([-0.00730, 0.04343, -0.04120, 0.00762], 424.5, 400.3).unwrap();
        let err = new([1e3, -1e3, 1e3, -1e3], 424.0, 400.0).unwrap_err();
        assert!(
            matches!(err, GeometryError::InvalidParameter { name: "k1", .. }),
            "{err}"
        );
        assert!(err.to_string().contains("factor 3"), "{err}");
        let err = new([0.0; 4], 900.0, 400.0).unwrap_err();
        assert!(
            matches!(err, GeometryError::InvalidParameter { name: "cx", .. }),
            "{err}"
        );
        let err = new([0.0; 4], 424.0, -1.0).unwrap_err();
        assert!(
            matches!(err, GeometryError::InvalidParameter { name: "cy", .. }),
            "{err}"
        );
    }
}
