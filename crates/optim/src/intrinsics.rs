//! Ideal pinhole intrinsics used by every residual in this crate.

use crate::error::OptimError;

/// Ideal pinhole on undistorted keypoints, plus the stereo `bf` term.
///
/// `u = fx * x / z + cx`, `v = fy * y / z + cy` (pixels, camera frame, z forward) and
/// the virtual right coordinate `u_r = u - bf / z`, with `bf = fx * baseline`
/// (pixels * metres). `bf = 0` for monocular-only use.
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
}

impl Intrinsics {
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
}
