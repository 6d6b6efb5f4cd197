//! Read-only sensor and configuration context shared by the tracking and mapping stages.

use ferroslam_features::ImageBounds;
use ferroslam_geometry::camera::PinholeCamera;
use ferroslam_optim::Intrinsics;

use ferroslam_map::Rig;

use crate::config::SlamConfig;

/// Calibration and settings every stage needs; fixed for the life of a system.
#[derive(Clone, Debug)]
pub struct Context {
    /// Calibrated camera (keypoints are undistorted with it).
    pub camera: PinholeCamera,
    /// Undistorted image bounds, pixels.
    pub bounds: ImageBounds,
    /// Ideal pinhole + bf used by the optimisers.
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
    pub fn new(camera: PinholeCamera, config: SlamConfig) -> Self {
        let b = camera.undistorted_bounds();
        let bounds = ImageBounds {
            min_x: b.min_x,
            max_x: b.max_x,
            min_y: b.min_y,
            max_y: b.max_y,
        };
        let intrinsics = Intrinsics {
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            bf: config.depth.bf,
        };
        let close_depth_m = config.depth.close_depth_m(camera.fx);
        let baseline_m = config.depth.bf / camera.fx;
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
        let (camera, d) = (&self.camera, &self.camera.distortion);
        Rig {
            sensor: self.config.sensor.name().to_owned(),
            intrinsics: [camera.fx, camera.fy, camera.cx, camera.cy],
            distortion: [d.k1, d.k2, d.p1, d.p2, d.k3],
            width: camera.width,
            height: camera.height,
        }
    }

    /// What input frames must fit: pyramid depth and image size.
    pub fn input_shape(&self) -> InputShape {
        InputShape {
            n_levels: self.config.extractor.n_levels,
            width: self.camera.width,
            height: self.camera.height,
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
