//! Read-only sensor and configuration context shared by the tracking and mapping stages.

use ferroslam_features::ImageBounds;
use ferroslam_geometry::camera::CameraModel;
use ferroslam_optim::Intrinsics;
use nalgebra::Vector3;

use ferroslam_map::Rig;

use crate::config::SlamConfig;

/// The Kannala-Brandt model's name in map files and the bindings.
pub const KANNALA_BRANDT: &str = "kannala_brandt";

/// Calibration and settings every stage needs; fixed for the life of a system.
#[derive(Clone, Debug)]
pub struct Context {
    /// Calibrated camera: keypoints are moved to its core pixels (undistorted for the
    /// pinhole, raw for a fisheye) and map points projected through it.
    pub camera: CameraModel,
    /// Image bounds in core pixels.
    pub bounds: ImageBounds,
    /// Projection model + bf used by the optimisers.
    pub intrinsics: Intrinsics,
    /// User configuration.
    pub config: SlamConfig,
    /// Depth below which measured depth is trusted ("close" points), metres.
    pub close_depth_m: f64,
    /// Stereo baseline, metres (bf / fx).
    pub baseline_m: f64,
}

impl Context {
    /// Derives the context from a validated configuration.
    pub fn new(camera: impl Into<CameraModel>, config: SlamConfig) -> Self {
        let camera = camera.into();
        let b = camera.bounds();
        let bounds = ImageBounds {
            min_x: b.min_x,
            max_x: b.max_x,
            min_y: b.min_y,
            max_y: b.max_y,
        };
        let intrinsics = Intrinsics::new(&camera, config.depth.bf);
        let close_depth_m = config.depth.close_depth_m(camera.fx());
        let baseline_m = config.depth.bf / camera.fx();
        Self {
            camera,
            bounds,
            intrinsics,
            config,
            close_depth_m,
            baseline_m,
        }
    }

    /// The sensor and camera, as map files record them.
    pub fn rig(&self) -> Rig {
        let (model, intrinsics, distortion) = match &self.camera {
            CameraModel::Pinhole(c) => {
                let d = &c.distortion;
                let distortion = [d.k1, d.k2, d.p1, d.p2, d.k3];
                (Rig::PINHOLE, [c.fx, c.fy, c.cx, c.cy], distortion)
            }
            CameraModel::KannalaBrandt(c) => {
                let [k1, k2, k3, k4] = c.k;
                let distortion = [k1, k2, k3, k4, 0.0];
                (KANNALA_BRANDT, [c.fx, c.fy, c.cx, c.cy], distortion)
            }
        };
        let (width, height) = self.camera.size();
        Rig {
            sensor: self.config.sensor.name().to_owned(),
            model: model.to_owned(),
            intrinsics,
            distortion,
            width,
            height,
        }
    }

    /// Whether the camera is the (ideal) pinhole, whose arithmetic the core keeps exactly as
    /// ORB-SLAM's; otherwise geometry runs on unit rays.
    pub fn is_pinhole(&self) -> bool {
        self.camera.as_pinhole().is_some()
    }

    /// Whether raw keypoints are distorted pinhole pixels (stereo input must not be).
    pub fn is_distorted(&self) -> bool {
        self.camera.as_pinhole().is_some_and(|c| c.is_distorted())
    }

    /// The virtual right coordinate (pixels) of camera point `p_c` projected at column `u`
    /// (see [`Intrinsics::u_right`]); NaN where the fisheye cannot project it, so that no
    /// measured right coordinate agrees with it.
    pub fn u_right(&self, p_c: &Vector3<f64>, u: f64) -> f64 {
        self.intrinsics.u_right(p_c, u).unwrap_or(f64::NAN)
    }

    /// The unit ray of core pixel `(x, y)` (NaN for a pixel outside a fisheye's image circle).
    pub fn ray(&self, x: f32, y: f32) -> Vector3<f64> {
        self.camera
            .unproject(&nalgebra::Vector2::new(f64::from(x), f64::from(y)))
            .unwrap_or_else(|| Vector3::repeat(f64::NAN))
    }

    /// What input frames must fit: pyramid depth and image size.
    pub fn input_shape(&self) -> InputShape {
        InputShape {
            n_levels: self.config.extractor.n_levels,
            width: self.camera.size().0,
            height: self.camera.size().1,
        }
    }
}

/// What a system's input must fit: the pyramid depth and the camera's image size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputShape {
    /// Pyramid levels: keypoint octaves must be below.
    pub n_levels: usize,
    /// Image width, pixels: raw keypoints lie in `[0, width)`.
    pub width: u32,
    /// Image height, pixels: raw keypoints lie in `[0, height)`.
    pub height: u32,
}
