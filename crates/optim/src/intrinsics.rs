//! The camera model every residual in this crate projects with.

use ferroslam_geometry::camera::{CameraModel, KannalaBrandtCamera};
use nalgebra::{Matrix2x3, Vector2, Vector3};

use crate::error::OptimError;

/// The tracking camera (ideal pinhole on undistorted keypoints, or a Kannala-Brandt fisheye
/// on raw keypoints), plus the stereo `bf` term.
///
/// Pinhole: `u = fx * x / z + cx`, `v = fy * y / z + cy` (pixels, camera frame, z forward)
/// and the virtual right coordinate `u_r = u - bf / z`, with `bf = fx * baseline`
/// (pixels * metres). `bf = 0` for monocular-only use.
///
/// Fisheye (`fisheye = Some(camera)`, whose `fx, fy, cx, cy` equal the fields here): `(u, v)`
/// is the Kannala-Brandt projection and the virtual right coordinate is the `u` of a second,
/// identical camera `b = bf / fx` metres to the right: `u_r = project(p_c - [b, 0, 0]).x`,
/// which for the pinhole is exactly `u - bf / z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Focal length times stereo baseline, pixels * metres (0 if mono only).
    pub bf: f64,
    /// The fisheye lens the points project through; `None` for the ideal pinhole.
    pub fisheye: Option<KannalaBrandtCamera>,
}

impl Intrinsics {
    /// The intrinsics of a tracking camera with stereo term `bf` (pixels * metres).
    pub fn new(camera: &CameraModel, bf: f64) -> Self {
        let (fx, fy, cx, cy, fisheye) = match camera {
            CameraModel::Pinhole(c) => (c.fx, c.fy, c.cx, c.cy, None),
            CameraModel::KannalaBrandt(c) => (c.fx, c.fy, c.cx, c.cy, Some(*c)),
        };
        Self {
            fx,
            fy,
            cx,
            cy,
            bf,
            fisheye,
        }
    }

    /// Checks that all values are finite, the focal lengths positive and `bf >= 0`.
    pub fn validate(&self) -> Result<(), OptimError> {
        let all = [self.fx, self.fy, self.cx, self.cy, self.bf];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(OptimError::NonFinite {
                what: "intrinsics",
                index: 0,
            });
        }
        if self.fx <= 0.0 || self.fy <= 0.0 || self.bf < 0.0 {
            return Err(OptimError::InvalidInput(format!(
                "intrinsics need fx > 0, fy > 0, bf >= 0, got {self:?}"
            )));
        }
        Ok(())
    }

    /// Stereo baseline `bf / fx`, metres.
    pub fn baseline(&self) -> f64 {
        self.bf / self.fx
    }

    /// The virtual right coordinate (pixels) of the camera point `p_c` whose left projection
    /// has column `u`: `u - bf / z` for the pinhole (no check of `z`, as the callers have
    /// projected `p_c` already), the fisheye formula of the type docs otherwise; `None` where
    /// the fisheye does not project the right camera's point.
    pub fn u_right(&self, p_c: &Vector3<f64>, u: f64) -> Option<f64> {
        match &self.fisheye {
            None => Some(u - self.bf / p_c.z),
            Some(c) => c.project(&self.right_point(p_c)).map(|uv| uv.x),
        }
    }

    /// `p_c` in the virtual right camera, `b` metres to the right of the left one.
    pub(crate) fn right_point(&self, p_c: &Vector3<f64>) -> Vector3<f64> {
        p_c - Vector3::new(self.baseline(), 0.0, 0.0)
    }

    /// Fisheye projection with its Jacobian (`None` without a fisheye or outside its domain).
    pub(crate) fn project_fisheye(
        &self,
        p_c: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        self.fisheye.as_ref()?.project_with_jacobian(p_c)
    }
}
