//! Read-only sensor and configuration context shared by the tracking and mapping stages.

use ferroslam_features::ImageBounds;
use ferroslam_geometry::camera::CameraModel;
use ferroslam_optim::{Intrinsics, RigCamera};
use nalgebra::{Isometry3, Point3, Vector3};

use ferroslam_map::{PairCamera, Rig, RigMember};

use crate::config::SlamConfig;
use crate::stereo_pair::UnrectifiedPair;

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
    /// The second camera of an unrectified stereo pair (stereo depth from matching on
    /// rays), `None` for rectified stereo and the other sensors.
    pub pair: Option<UnrectifiedPair>,
    /// The rig's further cameras (cameras 1.. of every frame's keypoints), beside the first
    /// camera (and its pair partner, which only gives it depth).
    pub observers: Vec<Observer>,
    /// Every camera as the optimisers see it, the first one first.
    pub optim_cameras: Vec<RigCamera>,
}

/// A further camera of a multi-camera rig: it sees its own part of the scene, beside the
/// first camera, from a fixed pose on the rig.
#[derive(Clone, Debug)]
#[allow(non_snake_case)]
pub struct Observer {
    /// Calibrated camera (keypoints in its core pixels, as the first camera's).
    pub camera: CameraModel,
    /// Image bounds in core pixels.
    pub bounds: ImageBounds,
    /// Projection model and the depth sensor's virtual `bf`, for the optimisers.
    pub intrinsics: Intrinsics,
    /// Maps points from the first camera's frame to this camera's, metres.
    pub T_c_c0: Isometry3<f64>,
    /// Whether its keypoints come with depths: from a registered depth image, or from its
    /// stereo partner.
    pub has_depth: bool,
    /// Its stereo partner, whose image follows its own in every frame: its keypoints get
    /// depth by matching into the partner's along epipolar curves (as the first camera's
    /// unrectified pair), the partner observing nothing itself.
    pub pair: Option<UnrectifiedPair>,
}

/// One camera of the rig as geometry sees it: the first camera or an [`Observer`].
#[derive(Clone, Copy, Debug)]
#[allow(non_snake_case)]
pub struct CameraView<'a> {
    /// Calibrated camera.
    pub camera: &'a CameraModel,
    /// Image bounds in core pixels.
    pub bounds: &'a ImageBounds,
    /// Projection model and `bf`, for the optimisers and the right coordinate.
    pub intrinsics: &'a Intrinsics,
    /// Maps points from the first camera's frame to this one's; `None` for the first camera,
    /// whose arithmetic stays that of the pose itself.
    pub T_c_c0: Option<&'a Isometry3<f64>>,
}

#[allow(non_snake_case)]
impl CameraView<'_> {
    /// This camera's pose `T_c_w` on a rig whose first camera is at `T_c0_w`.
    pub fn pose(&self, T_c0_w: &Isometry3<f64>) -> Isometry3<f64> {
        self.T_c_c0.map_or(*T_c0_w, |T| T * T_c0_w)
    }

    /// Camera centre in the world frame (metres) on a rig whose first camera is at `T_c0_w`.
    pub fn center(&self, T_c0_w: &Isometry3<f64>) -> Vector3<f64> {
        self.pose(T_c0_w)
            .inverse_transform_point(&Point3::origin())
            .coords
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

    /// Point `p_c0` of the first camera's frame (metres) in this camera's frame.
    pub fn point_in_camera(&self, p_c0: &Vector3<f64>) -> Vector3<f64> {
        self.T_c_c0
            .map_or(*p_c0, |T| (T * Point3::from(*p_c0)).coords)
    }

    /// Whether core pixel `uv` lies inside the image bounds.
    pub fn contains(&self, uv: &nalgebra::Vector2<f64>) -> bool {
        let b = self.bounds;
        uv.x >= b.min_x && uv.x < b.max_x && uv.y >= b.min_y && uv.y < b.max_y
    }
}

impl Context {
    /// Derives the context from a validated configuration.
    pub fn new(camera: impl Into<CameraModel>, config: SlamConfig) -> Self {
        let camera = camera.into();
        let bounds = image_bounds(&camera);
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
            pair: None,
            observers: Vec::new(),
            optim_cameras: vec![RigCamera::first(intrinsics)],
        }
    }

    /// Adds a further camera at `T_c0_c` (its pose in the first camera's frame, metres),
    /// with depth images when `has_depth` (their virtual baseline is the first camera's `bf`).
    #[allow(non_snake_case)]
    pub fn add_observer(&mut self, camera: CameraModel, T_c0_c: Isometry3<f64>, has_depth: bool) {
        let bf = if has_depth { self.config.depth.bf } else { 0.0 };
        self.push_observer(camera, T_c0_c, bf, has_depth, None);
    }

    /// Adds a further camera at `T_c0_c` whose keypoints get depth from its stereo partner
    /// `pair` (its virtual right coordinate at the pair's own `bf`, its focal length times
    /// the baseline).
    #[allow(non_snake_case)]
    pub fn add_observer_pair(
        &mut self,
        camera: CameraModel,
        T_c0_c: Isometry3<f64>,
        pair: UnrectifiedPair,
    ) {
        let bf = camera.fx() * pair.baseline_m();
        self.push_observer(camera, T_c0_c, bf, true, Some(pair));
    }

    #[allow(non_snake_case)]
    fn push_observer(
        &mut self,
        camera: CameraModel,
        T_c0_c: Isometry3<f64>,
        bf: f64,
        has_depth: bool,
        pair: Option<UnrectifiedPair>,
    ) {
        let bounds = image_bounds(&camera);
        let intrinsics = Intrinsics::new(&camera, bf);
        let T_c_c0 = T_c0_c.inverse();
        self.optim_cameras.push(RigCamera::new(intrinsics, T_c_c0));
        self.observers.push(Observer {
            camera,
            bounds,
            intrinsics,
            T_c_c0,
            has_depth,
            pair,
        });
    }

    /// Whether a camera of the rig has a rolling shutter: frames are then estimated with
    /// their velocity, every camera's rows at their own times.
    pub fn has_rolling_shutter(&self) -> bool {
        !self.camera.rolling_shutter().is_global()
            || self
                .observers
                .iter()
                .any(|o| !o.camera.rolling_shutter().is_global())
    }

    /// Number of cameras whose keypoints a frame holds.
    pub fn num_cameras(&self) -> usize {
        1 + self.observers.len()
    }

    /// Camera `k` of the rig (0 = the first); `k` must be below [`Self::num_cameras`].
    pub fn view(&self, k: usize) -> CameraView<'_> {
        match k.checked_sub(1) {
            None => CameraView {
                camera: &self.camera,
                bounds: &self.bounds,
                intrinsics: &self.intrinsics,
                T_c_c0: None,
            },
            Some(o) => {
                let o = &self.observers[o];
                CameraView {
                    camera: &o.camera,
                    bounds: &o.bounds,
                    intrinsics: &o.intrinsics,
                    T_c_c0: Some(&o.T_c_c0),
                }
            }
        }
    }

    /// The sensor and camera, as map files record them.
    pub fn rig(&self) -> Rig {
        let (model, intrinsics, distortion) = camera_record(&self.camera);
        let (width, height) = self.camera.size();
        let pair = self.pair.as_ref().map(pair_record);
        let cameras = self
            .observers
            .iter()
            .map(|o| {
                let (model, intrinsics, distortion) = camera_record(&o.camera);
                let (width, height) = o.camera.size();
                RigMember {
                    model: model.to_owned(),
                    intrinsics,
                    distortion,
                    width,
                    height,
                    T_c0_c: o.T_c_c0.inverse(),
                    has_depth: o.has_depth,
                    pair: o.pair.as_ref().map(pair_record),
                }
            })
            .collect();
        Rig {
            sensor: self.config.sensor.name().to_owned(),
            model: model.to_owned(),
            intrinsics,
            distortion,
            width,
            height,
            pair,
            cameras,
        }
    }

    /// Whether raw keypoints are distorted pinhole pixels (stereo input must not be).
    pub fn is_distorted(&self) -> bool {
        self.camera.as_pinhole().is_some_and(|c| c.is_distorted())
    }

    /// The unit ray of core pixel `(x, y)` (NaN for a pixel outside a fisheye's image circle).
    pub fn ray(&self, x: f32, y: f32) -> Vector3<f64> {
        self.view(0).ray(x, y)
    }

    /// What the further cameras' images must be.
    pub fn observer_shapes(&self) -> Vec<ObserverShape> {
        self.observers
            .iter()
            .map(|o| ObserverShape {
                width: o.camera.size().0,
                height: o.camera.size().1,
                has_depth: o.has_depth,
                paired: o.pair.is_some(),
            })
            .collect()
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

/// A camera's image bounds in core pixels.
fn image_bounds(camera: &CameraModel) -> ImageBounds {
    let b = camera.bounds();
    ImageBounds {
        min_x: b.min_x,
        max_x: b.max_x,
        min_y: b.min_y,
        max_y: b.max_y,
    }
}

/// A camera's model name, `fx fy cx cy` and distortion as map files record them.
/// The second camera of a pair as map files record it.
fn pair_record(pair: &UnrectifiedPair) -> PairCamera {
    let (model, intrinsics, distortion) = camera_record(&pair.right);
    PairCamera {
        model: model.to_owned(),
        intrinsics,
        distortion,
        T_left_right: pair.T_left_right,
    }
}

fn camera_record(camera: &CameraModel) -> (&'static str, [f64; 4], [f64; 5]) {
    match camera {
        CameraModel::Pinhole(c) => {
            let d = &c.distortion;
            let distortion = [d.k1, d.k2, d.p1, d.p2, d.k3];
            (Rig::PINHOLE, [c.fx, c.fy, c.cx, c.cy], distortion)
        }
        CameraModel::KannalaBrandt(c) => {
            let [k1, k2, k3, k4] = c.k;
            (
                KANNALA_BRANDT,
                [c.fx, c.fy, c.cx, c.cy],
                [k1, k2, k3, k4, 0.0],
            )
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

/// What a further camera's images must be: their size and whether depth comes with them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ObserverShape {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Whether its keypoints come with depths (given with its features; from a depth
    /// image or its partner's image with its image).
    pub has_depth: bool,
    /// Whether its stereo partner's image follows its own (depth from the pair, no depth
    /// image).
    pub paired: bool,
}

impl ObserverShape {
    /// The images a frame holds for this camera, in order: `(width, height)` and whether a
    /// depth image comes with it; the partner's after the camera's own.
    pub fn images(&self) -> impl Iterator<Item = ((usize, usize), bool)> {
        let size = (self.width as usize, self.height as usize);
        let own = (size, self.has_depth && !self.paired);
        std::iter::once(own).chain(self.paired.then_some((size, false)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Sensor;
    use crate::frame::point_at_depth;
    use ferroslam_geometry::camera::{test_cameras, test_fisheye_cameras};

    fn rgbd(camera: impl Into<CameraModel>) -> Context {
        let mut config = SlamConfig::for_sensor(Sensor::Rgbd);
        config.depth.bf = 40.0;
        Context::new(camera, config)
    }

    #[test]
    fn pinhole_right_coordinate_is_orb_slams_and_the_fisheye_one_a_second_camera() {
        let (_, pinhole) = test_cameras()[0];
        let ctx = rgbd(pinhole);
        let p_c = Vector3::new(0.3, -0.2, 2.5);
        let u = ctx.camera.project(&p_c).unwrap().x;
        assert_eq!(ctx.view(0).u_right(&p_c, u), u - 40.0 / 2.5);
        assert!(ctx.camera.as_pinhole().is_some() && ctx.rig().model == Rig::PINHOLE);

        let (_, lens) = test_fisheye_cameras()[0];
        let ctx = rgbd(lens);
        let b = 40.0 / lens.fx;
        // 100 degrees off the axis: behind the plane a pinhole would need.
        let p_c = Vector3::new(2.0, 0.5, -0.35);
        let u = ctx.camera.project(&p_c).unwrap().x;
        let right = lens.project(&(p_c - Vector3::new(b, 0.0, 0.0))).unwrap().x;
        assert_eq!(ctx.view(0).u_right(&p_c, u), right);
        // Straight behind the right camera: no projection, no right coordinate.
        assert!(ctx.view(0).u_right(&Vector3::new(b, 0.0, -1.0), u).is_nan());
        assert!(ctx.camera.as_pinhole().is_none() && ctx.rig().model == KANNALA_BRANDT);
        assert_eq!(ctx.rig().distortion[..4], lens.k);
    }

    #[test]
    fn depth_is_z_depth_along_a_fisheye_ray() {
        let (_, lens) = test_fisheye_cameras()[1];
        let ctx = rgbd(lens);
        let p_c = Vector3::new(-1.5, 0.8, 1.2);
        let uv = ctx.camera.project(&p_c).unwrap();
        let ray = ctx.ray(uv.x as f32, uv.y as f32);
        let back = point_at_depth(&ray, p_c.z).unwrap();
        // The f32 pixel: about 1e-4 px of 285 px per radian at 2.1 m.
        assert!((back - p_c).norm() < 1e-5, "{back} vs {p_c}");
        assert!(point_at_depth(&Vector3::new(1.0, 0.0, 0.0), 2.0).is_none());
    }
}
