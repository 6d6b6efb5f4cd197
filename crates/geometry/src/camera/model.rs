//! One type for every camera model the core tracks with.
//!
//! The core works in "core pixels": the ideal (undistorted) pinhole image for
//! [`PinholeCamera`], whose keypoints are undistorted once at extraction, and the raw image
//! for [`KannalaBrandtCamera`], whose field of view may exceed 180 degrees and so has no
//! undistorted plane. Geometry that must hold for both works on the unit rays of
//! [`CameraModel::unproject`].

use nalgebra::{Matrix2x3, Vector2, Vector3};

use super::{ImageBounds, KannalaBrandtCamera, PinholeCamera};
use crate::rolling_shutter::{ReadoutDirection, RollingShutter};
use crate::GeometryError;

/// A calibrated camera of one of the supported models.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraModel {
    /// Pinhole with radial-tangential distortion; core pixels are ideal pinhole pixels.
    Pinhole(PinholeCamera),
    /// Kannala-Brandt fisheye; core pixels are raw pixels.
    KannalaBrandt(KannalaBrandtCamera),
}

impl CameraModel {
    /// Focal length along x (pixels; per radian near the axis for a fisheye).
    pub fn fx(&self) -> f64 {
        match self {
            Self::Pinhole(c) => c.fx,
            Self::KannalaBrandt(c) => c.fx,
        }
    }

    /// Focal length along y (pixels).
    pub fn fy(&self) -> f64 {
        match self {
            Self::Pinhole(c) => c.fy,
            Self::KannalaBrandt(c) => c.fy,
        }
    }

    /// Image width and height (pixels).
    pub fn size(&self) -> (u32, u32) {
        match self {
            Self::Pinhole(c) => (c.width, c.height),
            Self::KannalaBrandt(c) => (c.width, c.height),
        }
    }

    /// When each line of the raw image is read (global shutter unless set by
    /// [`Self::with_readout`]).
    pub fn rolling_shutter(&self) -> &RollingShutter {
        match self {
            Self::Pinhole(c) => &c.shutter,
            Self::KannalaBrandt(c) => &c.shutter,
        }
    }

    /// The same camera with a rolling shutter reading its lines over `readout_s` seconds
    /// (first to last line, >= 0 and finite; 0 is a global shutter) in `direction`, the
    /// frame's timestamp at the middle line (see [`RollingShutter::from_readout`]).
    ///
    /// # Errors
    /// [`GeometryError::InvalidParameter`] naming `readout_s` for a negative or non-finite
    /// readout.
    pub fn with_readout(
        mut self,
        readout_s: f64,
        direction: ReadoutDirection,
    ) -> Result<Self, GeometryError> {
        if !(readout_s.is_finite() && readout_s >= 0.0) {
            return Err(GeometryError::InvalidParameter {
                name: "readout_s",
                value: readout_s,
                reason: "must be finite and >= 0 seconds (0 = global shutter)",
            });
        }
        let (width, height) = self.size();
        let lines = match direction {
            ReadoutDirection::TopToBottom | ReadoutDirection::BottomToTop => height,
            ReadoutDirection::LeftToRight | ReadoutDirection::RightToLeft => width,
        };
        // A 1-line image reads at once: nothing to model.
        let shutter = if readout_s == 0.0 || lines < 2 {
            RollingShutter::global()
        } else {
            RollingShutter::from_readout(readout_s, lines, direction)?
        };
        match &mut self {
            Self::Pinhole(c) => c.shutter = shutter,
            Self::KannalaBrandt(c) => c.shutter = shutter,
        }
        Ok(self)
    }

    /// Seconds from the frame's timestamp to the readout of the line through the RAW image
    /// pixel `uv_raw` (0 for a global shutter).
    pub fn time_offset_s(&self, uv_raw: &Vector2<f64>) -> f64 {
        let (width, height) = self.size();
        let extent = Vector2::new(f64::from(width), f64::from(height));
        self.rolling_shutter().time_offset_s(uv_raw, &extent)
    }

    /// The pinhole camera, if this is one (stereo rectification and the virtual right
    /// coordinate need it).
    pub fn as_pinhole(&self) -> Option<&PinholeCamera> {
        match self {
            Self::Pinhole(c) => Some(c),
            Self::KannalaBrandt(_) => None,
        }
    }

    /// A raw image pixel in core pixels (undistorted for the pinhole, unchanged otherwise).
    pub fn core_pixel(&self, uv_raw: &Vector2<f64>) -> Vector2<f64> {
        match self {
            Self::Pinhole(c) => c.undistort_pixel(uv_raw),
            Self::KannalaBrandt(_) => *uv_raw,
        }
    }

    /// A core pixel in the raw image, inverting [`Self::core_pixel`] (distorted for the
    /// pinhole, unchanged otherwise).
    pub fn raw_pixel(&self, uv_core: &Vector2<f64>) -> Vector2<f64> {
        match self {
            Self::Pinhole(c) => c.distort_pixel(uv_core),
            Self::KannalaBrandt(_) => *uv_core,
        }
    }

    /// Projection of `p_c` (camera frame, metres) to raw image pixels, with the lens
    /// distortion applied; `None` where [`Self::project`] gives none.
    pub fn project_raw(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.project(p_c).map(|uv| self.raw_pixel(&uv))
    }

    /// The unit ray (camera frame) through the raw image pixel `uv_raw`; `None` where
    /// [`Self::unproject`] gives none.
    pub fn unproject_raw(&self, uv_raw: &Vector2<f64>) -> Option<Vector3<f64>> {
        self.unproject(&self.core_pixel(uv_raw))
    }

    /// Projection of `p_c` (camera frame, metres) to core pixels; `None` where the model
    /// does not project (behind a pinhole, past a fisheye's largest incidence angle).
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        match self {
            Self::Pinhole(c) => c.project(p_c),
            Self::KannalaBrandt(c) => c.project(p_c),
        }
    }

    /// [`Self::project`] with the 2x3 Jacobian `d_uv_d_p_c`.
    pub fn project_with_jacobian(
        &self,
        p_c: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        match self {
            Self::Pinhole(c) => c.project_with_jacobian(p_c),
            Self::KannalaBrandt(c) => c.project_with_jacobian(p_c),
        }
    }

    /// The unit ray (camera frame) through the core pixel `uv`; `None` for a non-finite
    /// pixel or, for a fisheye, one outside its image circle.
    pub fn unproject(&self, uv: &Vector2<f64>) -> Option<Vector3<f64>> {
        match self {
            Self::Pinhole(c) => {
                Some(c.unproject(uv).normalize()).filter(|r| r.iter().all(|v| v.is_finite()))
            }
            Self::KannalaBrandt(c) => c.unproject(uv),
        }
    }

    /// Bounds of the image in core pixels.
    pub fn bounds(&self) -> ImageBounds {
        match self {
            Self::Pinhole(c) => c.undistorted_bounds(),
            Self::KannalaBrandt(c) => ImageBounds {
                min_x: 0.0,
                max_x: f64::from(c.width),
                min_y: 0.0,
                max_y: f64::from(c.height),
            },
        }
    }
}

impl From<PinholeCamera> for CameraModel {
    fn from(camera: PinholeCamera) -> Self {
        Self::Pinhole(camera)
    }
}

impl From<KannalaBrandtCamera> for CameraModel {
    fn from(camera: KannalaBrandtCamera) -> Self {
        Self::KannalaBrandt(camera)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{test_cameras, test_fisheye_cameras};
    use approx::assert_relative_eq;

    /// Every test camera of both models.
    fn test_models() -> Vec<CameraModel> {
        test_cameras()
            .into_iter()
            .map(|(_, c)| c.into())
            .chain(test_fisheye_cameras().into_iter().map(|(_, c)| c.into()))
            .collect()
    }

    #[test]
    fn rays_of_projected_points_point_at_them_for_every_model() {
        let p = Vector3::new(0.3, -0.2, 2.0);
        for model in test_models() {
            let ray = model.unproject(&model.project(&p).unwrap()).unwrap();
            assert_relative_eq!(ray, p.normalize(), epsilon = 1e-10);
            let b = model.bounds();
            assert!(b.max_x > b.min_x && b.max_y > b.min_y);
        }
    }

    #[test]
    fn a_readout_spreads_row_times_over_it_for_every_model() {
        for model in test_models() {
            assert!(model.rolling_shutter().is_global());
            let (_, height) = model.size();
            let rs = model
                .with_readout(0.02, ReadoutDirection::TopToBottom)
                .unwrap();
            let top = rs.time_offset_s(&Vector2::new(5.0, 0.0));
            let bottom = rs.time_offset_s(&Vector2::new(5.0, f64::from(height - 1)));
            assert_relative_eq!(bottom - top, 0.02, epsilon = 1e-15);
            assert_relative_eq!(top, -0.01, epsilon = 1e-15);
            let global = model
                .with_readout(0.0, ReadoutDirection::TopToBottom)
                .unwrap();
            assert_eq!(global, model);
            assert_eq!(global.time_offset_s(&Vector2::new(5.0, 0.0)), 0.0);
            for bad in [-1e-3, f64::NAN, f64::INFINITY] {
                assert!(matches!(
                    model.with_readout(bad, ReadoutDirection::TopToBottom),
                    Err(GeometryError::InvalidParameter {
                        name: "readout_s",
                        ..
                    })
                ));
            }
        }
    }

    #[test]
    fn core_pixels_are_undistorted_only_for_the_pinhole() {
        let (_, pinhole) = test_cameras()[0];
        let (_, fisheye) = test_fisheye_cameras()[0];
        let raw = Vector2::new(100.0, 80.0);
        assert_eq!(CameraModel::from(fisheye).core_pixel(&raw), raw);
        assert_eq!(
            CameraModel::from(pinhole).core_pixel(&raw),
            pinhole.undistort_pixel(&raw)
        );
        assert!(CameraModel::from(fisheye).as_pinhole().is_none());
    }

    #[test]
    fn raw_pixels_round_trip_for_every_model() {
        let p = Vector3::new(-0.4, 0.25, 1.5);
        for model in test_models() {
            let raw = model.project_raw(&p).unwrap();
            assert_relative_eq!(
                model.core_pixel(&raw),
                model.project(&p).unwrap(),
                epsilon = 1e-8
            );
            assert_relative_eq!(
                model.unproject_raw(&raw).unwrap(),
                p.normalize(),
                epsilon = 1e-10
            );
        }
        let (_, pinhole) = test_cameras()[0];
        assert!(CameraModel::from(pinhole)
            .project_raw(&Vector3::new(0.0, 0.0, -1.0))
            .is_none());
    }
}
