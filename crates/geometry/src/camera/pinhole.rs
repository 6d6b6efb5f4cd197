//! Pinhole camera with OpenCV radial-tangential ("plumb bob") distortion.
//!
//! Projection of a camera point `p_c = (x, y, z)`, `z > 0`, onto IDEAL (undistorted)
//! pixels: `u = fx x / z + cx`, `v = fy y / z + cy`. The core works on ideal pixels; the
//! distortion model is only used to undistort keypoints (and image bounds) once:
//!
//! ```text
//! (x, y) normalized ideal, r2 = x^2 + y^2, radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
//! x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
//! y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
//! ```

use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};

use super::validation::{check_intrinsics, check_monotonic_over_image, corner_radius};
use crate::rolling_shutter::RollingShutter;
use crate::GeometryError;

/// Smallest depth (metres) accepted by [`PinholeCamera::project`].
const MIN_DEPTH: f64 = 1e-6;

/// Radial-tangential distortion coefficients in OpenCV order `k1 k2 p1 p2 k3`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RadTan {
    /// Radial coefficient of `r^2`.
    pub k1: f64,
    /// Radial coefficient of `r^4`.
    pub k2: f64,
    /// First tangential coefficient.
    pub p1: f64,
    /// Second tangential coefficient.
    pub p2: f64,
    /// Radial coefficient of `r^6`.
    pub k3: f64,
}

impl RadTan {
    fn coefficients(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Distorts normalized coordinates; also returns `d(distorted)/d(ideal)`.
    fn distort(&self, p: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let d_radial_d_r2 = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        let cross = 2.0 * x * y * d_radial_d_r2 + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let jacobian = Matrix2::new(
            radial + 2.0 * x * x * d_radial_d_r2 + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            cross,
            cross,
            radial + 2.0 * y * y * d_radial_d_r2 + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        );
        (Vector2::new(xd, yd), jacobian)
    }
}

/// Axis-aligned bounds of the undistorted image, in ideal pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageBounds {
    /// Smallest x (pixels).
    pub min_x: f64,
    /// Largest x (pixels).
    pub max_x: f64,
    /// Smallest y (pixels).
    pub min_y: f64,
    /// Largest y (pixels).
    pub max_y: f64,
}

impl ImageBounds {
    /// Whether `uv` lies inside the bounds (edges included).
    pub fn contains(&self, uv: &Vector2<f64>) -> bool {
        uv.x >= self.min_x && uv.x <= self.max_x && uv.y >= self.min_y && uv.y <= self.max_y
    }
}

/// Pinhole intrinsics (pixels) plus the distortion of the physical lens.
///
/// Fields are public for reading; build through [`PinholeCamera::new`] to have them
/// validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    /// Focal length along x (pixels).
    pub fx: f64,
    /// Focal length along y (pixels).
    pub fy: f64,
    /// Principal point x (pixels).
    pub cx: f64,
    /// Principal point y (pixels).
    pub cy: f64,
    /// Lens distortion of the raw images.
    pub distortion: RadTan,
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
    /// When each row of a raw image is read ([`RollingShutter::global`] from [`Self::new`]).
    pub shutter: RollingShutter,
}

impl PinholeCamera {
    /// Validated constructor.
    ///
    /// Fails with [`GeometryError::InvalidParameter`] if any value is not finite, if
    /// `fx <= 0` or `fy <= 0`, if `width` or `height` is 0, if the principal point is
    /// outside the image, or if the radial distortion folds the image over or scales radii
    /// implausibly inside the image area (`validation::check_monotonic_over_image`).
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        distortion: RadTan,
        width: u32,
        height: u32,
    ) -> Result<Self, GeometryError> {
        let names = ["k1", "k2", "p1", "p2", "k3"];
        check_intrinsics(
            [fx, fy, cx, cy],
            names.into_iter().zip(distortion.coefficients()),
            [width, height],
        )?;
        let RadTan { k1, k2, k3, .. } = distortion;
        // The radial part: tangential coefficients are tiny in any real calibration and
        // do not change the radius' growth.
        check_monotonic_over_image(
            |r| r * (1.0 + r * r * (k1 + r * r * (k2 + r * r * k3))),
            |r| {
                let r2 = r * r;
                vec![
                    ("k1", k1, k1 * r2),
                    ("k2", k2, k2 * r2 * r2),
                    ("k3", k3, k3 * r2 * r2 * r2),
                ]
            },
            corner_radius([fx, fy, cx, cy], [width, height]),
            f64::INFINITY,
        )?;
        Ok(Self {
            fx,
            fy,
            cx,
            cy,
            distortion,
            width,
            height,
            shutter: RollingShutter::global(),
        })
    }

    /// Ideal pinhole projection of `p_c` (camera frame, metres) to undistorted pixels.
    ///
    /// `None` if `z <= 1e-6` or the input is not finite. Points outside the image still
    /// project; check against [`Self::undistorted_bounds`].
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        if !(p_c.z > MIN_DEPTH && p_c.iter().all(|v| v.is_finite())) {
            return None;
        }
        Some(Vector2::new(
            self.fx * p_c.x / p_c.z + self.cx,
            self.fy * p_c.y / p_c.z + self.cy,
        ))
    }

    /// [`Self::project`] together with `d_uv_d_p_c`, the 2x3 Jacobian of the pixel with
    /// respect to the camera point. `None` in the same cases as `project`.
    pub fn project_with_jacobian(
        &self,
        p_c: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        let uv = self.project(p_c)?;
        let z_inv = 1.0 / p_c.z;
        let d_uv_d_p_c = Matrix2x3::new(
            self.fx * z_inv,
            0.0,
            -self.fx * p_c.x * z_inv * z_inv,
            0.0,
            self.fy * z_inv,
            -self.fy * p_c.y * z_inv * z_inv,
        );
        Some((uv, d_uv_d_p_c))
    }

    /// The ray `(x, y, 1)` in the camera frame through the undistorted pixel `uv`.
    pub fn unproject(&self, uv: &Vector2<f64>) -> Vector3<f64> {
        Vector3::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy, 1.0)
    }

    /// Whether any distortion coefficient is non-zero.
    pub fn is_distorted(&self) -> bool {
        self.distortion.coefficients().iter().any(|&c| c != 0.0)
    }

    /// Maps an ideal pixel to the raw (distorted) image.
    pub fn distort_pixel(&self, uv_ideal: &Vector2<f64>) -> Vector2<f64> {
        let (xd, _) = self.distortion.distort(&self.normalize(uv_ideal));
        self.denormalize(&xd)
    }

    /// Maps a raw (distorted) pixel to the ideal pinhole image, inverting
    /// [`Self::distort_pixel`].
    ///
    /// Like OpenCV `undistortPoints` it iterates from the distorted point, but with Newton
    /// steps (the distortion Jacobian is cheap), so it converges to ~1e-12 px inside the
    /// image even for strong `k3`. Gives up after 20 iterations and returns its best
    /// estimate; non-finite input gives non-finite output.
    pub fn undistort_pixel(&self, uv_distorted: &Vector2<f64>) -> Vector2<f64> {
        let target = self.normalize(uv_distorted);
        let mut x = target;
        // The distortion (and its Jacobian) at `x`, reused from the step that reached it.
        let mut at_x = self.distortion.distort(&x);
        for _ in 0..20 {
            let (xd, jacobian) = at_x;
            let residual = xd - target;
            let Some(step) = jacobian.lu().solve(&residual) else {
                break;
            };
            // Halve a step that does not reduce the residual (far outside the image the
            // polynomial can fold over).
            let mut scale = 1.0;
            let mut next = x - step;
            let mut at_next = self.distortion.distort(&next);
            while scale > 1e-3 && (at_next.0 - target).norm() > residual.norm() {
                scale *= 0.5;
                next = x - step * scale;
                at_next = self.distortion.distort(&next);
            }
            if !next.iter().all(|v| v.is_finite()) {
                break;
            }
            x = next;
            at_x = at_next;
            if step.norm() * scale < 1e-15 {
                break;
            }
        }
        self.denormalize(&x)
    }

    /// Bounds of the undistorted image: the 4 raw image corners undistorted, combined like
    /// ORB-SLAM's `ComputeImageBounds` (min x of the left corners, max x of the right
    /// corners, and likewise for y). The plain rectangle `[0, width] x [0, height]` when
    /// there is no distortion.
    pub fn undistorted_bounds(&self) -> ImageBounds {
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        if !self.is_distorted() {
            return ImageBounds {
                min_x: 0.0,
                max_x: w,
                min_y: 0.0,
                max_y: h,
            };
        }
        let [tl, tr, bl, br] = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
            .map(|(u, v)| self.undistort_pixel(&Vector2::new(u, v)));
        ImageBounds {
            min_x: tl.x.min(bl.x),
            max_x: tr.x.max(br.x),
            min_y: tl.y.min(tr.y),
            max_y: bl.y.max(br.y),
        }
    }

    fn normalize(&self, uv: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy)
    }

    fn denormalize(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * xy.x + self.cx, self.fy * xy.y + self.cy)
    }
}

/// Real calibrations for tests and benches: TUM RGB-D fr1, EuRoC cam0 and KITTI 00 (left,
/// rectified, so undistorted).
pub fn test_cameras() -> Vec<(&'static str, PinholeCamera)> {
    let camera = |fx, fy, cx, cy, distortion, width, height| PinholeCamera {
        fx,
        fy,
        cx,
        cy,
        distortion,
        width,
        height,
        shutter: RollingShutter::global(),
    };
    vec![
        (
            "tum_fr1",
            camera(
                517.3,
                516.5,
                318.6,
                255.3,
                RadTan {
                    k1: 0.2624,
                    k2: -0.9531,
                    p1: -0.0054,
                    p2: 0.0026,
                    k3: 1.1633,
                },
                640,
                480,
            ),
        ),
        (
            "euroc_cam0",
            camera(
                458.654,
                457.296,
                367.215,
                248.375,
                RadTan {
                    k1: -0.28340811,
                    k2: 0.07395907,
                    p1: 0.00019359,
                    p2: 1.76187114e-05,
                    k3: 0.0,
                },
                752,
                480,
            ),
        ),
        (
            "kitti_00",
            camera(
                718.856,
                718.856,
                607.1928,
                185.2157,
                RadTan::default(),
                1241,
                376,
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

    #[test]
    fn test_cameras_are_valid() {
        for (name, c) in test_cameras() {
            let rebuilt =
                PinholeCamera::new(c.fx, c.fy, c.cx, c.cy, c.distortion, c.width, c.height);
            assert_eq!(rebuilt, Ok(c), "{name}");
        }
    }

    #[test]
    fn new_rejects_bad_parameters() {
        let d = RadTan::default();
        assert!(PinholeCamera::new(0.0, 500.0, 320.0, 240.0, d, 640, 480).is_err());
        assert!(PinholeCamera::new(500.0, f64::NAN, 320.0, 240.0, d, 640, 480).is_err());
        assert!(PinholeCamera::new(500.0, 500.0, f64::INFINITY, 240.0, d, 640, 480).is_err());
        assert!(PinholeCamera::new(
            500.0,
            500.0,
            320.0,
            240.0,
            RadTan { k1: f64::NAN, ..d },
            640,
            480
        )
        .is_err());
        assert!(PinholeCamera::new(500.0, 500.0, 320.0, 240.0, d, 0, 480).is_err());
    }

    #[test]
    fn project_rejects_points_behind_and_non_finite() {
        let (_, c) = test_cameras()[0];
        assert!(c.project(&Vector3::new(0.0, 0.0, 0.0)).is_none());
        assert!(c.project(&Vector3::new(0.1, 0.0, -1.0)).is_none());
        assert!(c.project(&Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
        assert!(c
            .project_with_jacobian(&Vector3::new(0.0, 0.0, 1e-9))
            .is_none());
    }

    #[test]
    fn unproject_inverts_project() {
        for (_, c) in test_cameras() {
            let p = Vector3::new(0.4, -0.3, 2.5);
            let ray = c.unproject(&c.project(&p).unwrap());
            assert_relative_eq!(ray * p.z, p, epsilon = 1e-12);
        }
    }

    #[test]
    fn project_jacobian_matches_numeric() {
        for (name, c) in test_cameras() {
            let p = Vector3::new(0.4, -0.3, 2.5);
            let (_, j) = c.project_with_jacobian(&p).unwrap();
            let f = |x: &DVector<f64>| {
                DVector::from_column_slice(
                    c.project(&Vector3::new(x[0], x[1], x[2]))
                        .unwrap()
                        .as_slice(),
                )
            };
            let analytic = DMatrix::from_column_slice(2, 3, j.as_slice());
            check_jacobian(
                name,
                &analytic,
                f,
                &DVector::from_column_slice(p.as_slice()),
                1e-6,
                1e-6,
            );
        }
    }

    #[test]
    fn distortion_jacobian_matches_numeric() {
        let (_, c) = test_cameras()[0];
        let x0 = Vector2::new(-0.5, 0.4);
        let (_, j) = c.distortion.distort(&x0);
        let f = |x: &DVector<f64>| {
            DVector::from_column_slice(c.distortion.distort(&Vector2::new(x[0], x[1])).0.as_slice())
        };
        let analytic = DMatrix::from_column_slice(2, 2, j.as_slice());
        check_jacobian(
            "radtan",
            &analytic,
            f,
            &DVector::from_column_slice(x0.as_slice()),
            1e-6,
            1e-8,
        );
    }

    #[test]
    fn undistort_inverts_distort_over_the_image() {
        for (name, c) in test_cameras() {
            let mut worst: f64 = 0.0;
            for i in 0..=32 {
                for j in 0..=24 {
                    let raw = Vector2::new(
                        f64::from(c.width) * i as f64 / 32.0,
                        f64::from(c.height) * j as f64 / 24.0,
                    );
                    let ideal = c.undistort_pixel(&raw);
                    worst = worst.max((c.distort_pixel(&ideal) - raw).norm());
                }
            }
            assert!(
                worst < 1e-6,
                "{name}: distort(undistort(uv)) off by {worst} px"
            );
        }
    }

    #[test]
    fn bounds_are_the_image_when_undistorted() {
        let (_, kitti) = test_cameras()[2];
        assert!(!kitti.is_distorted());
        assert_eq!(
            kitti.undistorted_bounds(),
            ImageBounds {
                min_x: 0.0,
                max_x: 1241.0,
                min_y: 0.0,
                max_y: 376.0
            }
        );
    }

    #[test]
    fn bounds_contain_undistorted_corners() {
        for (name, c) in test_cameras().into_iter().filter(|(_, c)| c.is_distorted()) {
            let b = c.undistorted_bounds();
            assert!(b.min_x < b.max_x && b.min_y < b.max_y, "{name}: {b:?}");
            let center = c.undistort_pixel(&Vector2::new(c.cx, c.cy));
            assert!(b.contains(&center), "{name}");
        }
    }

    #[test]
    fn implausible_distortion_and_principal_points_are_named() {
        let radtan = |k1, k2, k3| RadTan {
            k1,
            k2,
            p1: 0.0,
            p2: 0.0,
            k3,
        };
        let new = |d, cx, cy| PinholeCamera::new(517.3, 516.5, cx, cy, d, 640, 480);
        let name_of = |r: Result<PinholeCamera, GeometryError>| match r.unwrap_err() {
            GeometryError::InvalidParameter { name, .. } => name,
        };
        // Pincushion so strong that radii grow 60-fold (monotonic, yet no lens): k1 named.
        assert_eq!(name_of(new(radtan(100.0, 0.0, 0.0), 320.0, 240.0)), "k1");
        assert_eq!(name_of(new(radtan(1e9, 0.0, 0.0), 320.0, 240.0)), "k1");
        // Barrel that folds over before the corner (d r_d / d r < 0 from r = 0.58).
        let err = new(radtan(-1.0, 0.0, 0.0), 320.0, 240.0).unwrap_err();
        assert!(err.to_string().contains("folds"), "{err}");
        assert_eq!(name_of(new(radtan(0.0, 0.0, -50.0), 320.0, 240.0)), "k3");
        assert_eq!(name_of(new(radtan(0.0, 0.0, 0.0), 641.0, 240.0)), "cx");
        assert_eq!(name_of(new(radtan(0.0, 0.0, 0.0), 320.0, -0.5)), "cy");
        // The image's edge is still inside it.
        new(radtan(0.0, 0.0, 0.0), 0.0, 480.0).unwrap();
    }
}
