//! [`SparseModel`]: the map as a photogrammetry tool sees it (COLMAP's images, 2-D points and
//! tracks), read through the map's public API only.
//!
//! Such tools keep every keypoint of an image, the ones without a 3-D point too, in the
//! pixels of the image file they are given: the raw (distorted) image. The map keeps its
//! keypoints in the core's pixels (undistorted for a pinhole camera), so the export moves
//! them back through the camera ([`CameraModel::raw_pixel`]).
//!
//! A keyframe of a multi-camera rig is one image per camera, camera `k`'s keypoints
//! ([`crate::FrameFeatures::camera_range`]) seen from `T_w_ck = T_w_c0 * T_c0_ck`
//! ([`crate::RigMember::T_c0_c`]): a point seen by several cameras then has one track across
//! them, which is what lets a tool's BA tie the cameras together.
//!
//! # Rolling shutter
//! Such tools model a global shutter: one pose per image. A rolling-shutter keyframe saw
//! keypoint `i` from the pose of its row, `D(dt_i) * T_c_w` (`dt_i` its row's time offset,
//! `D` the motion at the keyframe's velocity, [`ferroslam_geometry::rolling_shutter`]), so
//! its keypoints are written where the camera would have seen them at the keyframe's
//! reference time, and the keyframe's pose `T_c_w` is the image's:
//! - a keypoint observing map point `p_w` is moved by `pi(T_c_w p_w) - pi(D T_c_w p_w)`.
//!   The exported keypoint's residual through the reference pose is then the core's own
//!   rolling-shutter residual `pi(D T_c_w p_w) - keypoint` (local BA's): the measurement's
//!   noise is kept, only the row's motion is taken out, and a tool's BA refines the same
//!   error the core minimised.
//! - a keypoint without a point has no depth to move it by: its ray is rotated back by
//!   `D`'s rotation alone. Over half a readout (7.5 ms for TUM fr1) a hand-held camera turns
//!   by up to ~0.01 rad (~6 px at 517 px focal length), but moves by about a millimetre,
//!   well under a pixel at a metre or more.
//!
//! A global shutter (every offset 0) leaves keypoints exactly where they were detected.

// Frame-named variables (`T_c_w`, `D`) follow the workspace's pose convention.
#![allow(non_snake_case)]

use ferroslam_geometry::camera::CameraModel;
use ferroslam_geometry::rolling_shutter::motion_over;
use nalgebra::{Isometry3, Point3, Vector2, Vector3};

use crate::{KeyFrame, KeyFrameId, Map, MapPointId, Rgb};

/// One camera's image of a keyframe: its pose and every keypoint with the point it observes.
#[derive(Clone, Debug)]
pub struct SparseImage {
    /// The keyframe.
    pub id: KeyFrameId,
    /// The rig camera that took it (0 = the first).
    pub camera: usize,
    /// Timestamp of the source frame, seconds.
    pub timestamp_s: f64,
    /// Pose of the image's camera at the frame's reference time (`p_w = T_w_c * p_c`,
    /// metres).
    pub T_w_c: Isometry3<f64>,
    /// Every keypoint in raw image pixels (centre of the top-left pixel at (0, 0)), as seen
    /// from `T_w_c` (rolling-shutter compensated, see the module docs).
    pub keypoints_raw_px: Vec<Vector2<f64>>,
    /// Per keypoint, the index in [`SparseModel::points`] of the point it observes.
    pub point_index: Vec<Option<usize>>,
}

/// One live map point.
#[derive(Clone, Debug)]
pub struct SparsePoint {
    /// The map point.
    pub id: MapPointId,
    /// World position, metres.
    pub position: Vector3<f64>,
    /// Colour of its first observation ([`crate::MapPoint::color`]).
    pub color: Option<Rgb>,
}

/// The keyframes (by increasing id) and live map points (by increasing id) of a map, linked
/// by keypoint: the track of a point is every `(image, keypoint)` whose `point_index` is it.
#[derive(Clone, Debug, Default)]
pub struct SparseModel {
    /// One image per keyframe and camera, by keyframe then camera.
    pub images: Vec<SparseImage>,
    /// The map points, in the order of [`Map::map_point_ids`].
    pub points: Vec<SparsePoint>,
}

impl Map {
    /// The map as images, points and tracks, keypoints in the raw pixels of `camera` (the
    /// first camera of every keyframe) at each keyframe's reference time: one image per
    /// keyframe, a rig's further cameras left out ([`Self::rig_sparse_model`] has them).
    pub fn sparse_model(&self, camera: &CameraModel) -> SparseModel {
        self.rig_sparse_model(std::slice::from_ref(camera))
    }

    /// As [`Self::sparse_model`], with one image per keyframe for each of `cameras` (camera
    /// `k` of the rig is `cameras[k]`, placed by [`Map::rig`]'s `T_c0_c`): what a rig's
    /// model holds. A camera the rig record does not place is left out.
    pub fn rig_sparse_model(&self, cameras: &[CameraModel]) -> SparseModel {
        let points: Vec<SparsePoint> = self
            .map_point_ids()
            .into_iter()
            .filter_map(|id| self.map_point(id))
            .map(|p| SparsePoint {
                id: p.id(),
                position: p.position(),
                color: p.color(),
            })
            .collect();
        let index_of: std::collections::HashMap<MapPointId, usize> =
            points.iter().enumerate().map(|(i, p)| (p.id, i)).collect();
        // Per camera, its pose in the first camera's frame (`None`: the first camera itself,
        // whose keyframe pose is used as it is).
        let mounts: Vec<(&CameraModel, Option<Isometry3<f64>>)> = cameras
            .iter()
            .enumerate()
            .map_while(|(k, camera)| match k.checked_sub(1) {
                None => Some((camera, None)),
                Some(m) => Some((camera, Some(self.rig()?.cameras.get(m)?.T_c0_c))),
            })
            .collect();
        let mut images = Vec::new();
        for kf in self
            .keyframe_ids()
            .into_iter()
            .filter_map(|id| self.keyframe(id))
        {
            for (k, &(camera, T_c0_ck)) in mounts.iter().enumerate() {
                let view = View {
                    camera,
                    T_c_w: T_c0_ck.map_or(*kf.T_c_w(), |T| T.inverse() * kf.T_c_w()),
                    T_c0_c: T_c0_ck,
                };
                let point_index: Vec<Option<usize>> = kf
                    .features()
                    .camera_range(k)
                    .map(|i| kf.map_point(i).and_then(|m| index_of.get(&m).copied()))
                    .collect();
                let keypoints_raw_px = kf
                    .features()
                    .camera_range(k)
                    .zip(&point_index)
                    .map(|(i, point)| {
                        let p_w = point.map(|j| &points[j].position);
                        camera.raw_pixel(&view.at_reference_time(kf, i, p_w))
                    })
                    .collect();
                images.push(SparseImage {
                    id: kf.id(),
                    camera: k,
                    timestamp_s: kf.timestamp(),
                    T_w_c: view.T_c_w.inverse(),
                    keypoints_raw_px,
                    point_index,
                });
            }
        }
        SparseModel { images, points }
    }
}

/// One camera of a keyframe: how its keypoints are moved to the keyframe's reference time.
struct View<'a> {
    camera: &'a CameraModel,
    /// The camera's pose at the reference time (world to camera, metres).
    T_c_w: Isometry3<f64>,
    /// Its pose in the first camera's frame, whose motion the keyframe's velocity is;
    /// `None` for the first camera.
    T_c0_c: Option<Isometry3<f64>>,
}

impl View<'_> {
    /// Keypoint `i` of `kf` (core pixels) where the camera would have seen it from the
    /// keyframe's reference pose (see the module docs; `p_w` the point it observes, if any).
    /// Unchanged for a keypoint read at the reference time, and where a projection fails (a
    /// point or ray turned behind a pinhole): no better place is known.
    fn at_reference_time(
        &self,
        kf: &KeyFrame,
        i: usize,
        p_w: Option<&Vector3<f64>>,
    ) -> Vector2<f64> {
        let features = kf.features();
        let kp = &features.keypoints[i];
        let uv = Vector2::new(f64::from(kp.x), f64::from(kp.y));
        let dt = features.time_offset_s(i);
        if dt == 0.0 {
            return uv;
        }
        // The first camera's motion over `dt`, seen in this camera's frame.
        let D_c0 = motion_over(&features.xi_dot, dt);
        let D = self.T_c0_c.map_or(D_c0, |T| T.inverse() * D_c0 * T);
        let camera = self.camera;
        let moved = match p_w {
            Some(p_w) => {
                let p_c = self.T_c_w * Point3::from(*p_w);
                let at_reference = camera.project(&p_c.coords);
                let at_row = camera.project(&(D * p_c).coords);
                at_reference.zip(at_row).map(|(r, s)| uv + (r - s))
            }
            None => camera
                .unproject(&uv)
                .and_then(|ray_row| camera.project(&(D.rotation.inverse() * ray_row))),
        };
        moved.unwrap_or(uv)
    }
}

#[cfg(test)]
mod tests {
    use approx::assert_relative_eq;
    use ferroslam_geometry::camera::{test_cameras, CameraModel};
    use ferroslam_geometry::rolling_shutter::motion_over;
    use nalgebra::{Isometry3, Point3, Vector2, Vector6};

    use crate::test_support::{map_with_keyframes, observe_all};
    use crate::{KeyFrameId, Map};

    fn tum_fr1() -> CameraModel {
        CameraModel::from(test_cameras()[0].1)
    }

    fn core_px(map: &Map, kf: KeyFrameId, i: usize) -> Vector2<f64> {
        let k = &map.keyframe(kf).unwrap().features().keypoints[i];
        Vector2::new(f64::from(k.x), f64::from(k.y))
    }

    #[test]
    fn every_keypoint_is_listed_with_its_point_in_raw_pixels() {
        let (mut map, kfs) = map_with_keyframes(3, 4);
        let shared = observe_all(&mut map, &kfs, 2);
        let camera = tum_fr1();
        let model = map.sparse_model(&camera);
        assert_eq!(model.points.len(), 1);
        assert_eq!(model.points[0].id, shared);
        assert_eq!(model.images.len(), 3);
        for (image, &kf) in model.images.iter().zip(&kfs) {
            assert_eq!(image.id, kf);
            assert_eq!(image.point_index, vec![None, None, Some(0), None]);
            assert_eq!(image.T_w_c, map.keyframe(kf).unwrap().T_w_c());
            assert_eq!(image.keypoints_raw_px.len(), 4);
            for (i, raw) in image.keypoints_raw_px.iter().enumerate() {
                // A global shutter: the detected keypoint, distorted back.
                assert_eq!(*raw, camera.raw_pixel(&core_px(&map, kf, i)));
            }
        }
    }

    /// Two keyframes of a 2-camera rig (keypoints 0-1 camera 0's, 2-3 camera 1's): one image
    /// per keyframe and camera, camera 1's placed by the rig and in its own pixels, and a
    /// point seen by both cameras (in two keyframes) in one track.
    #[test]
    fn a_rig_keyframe_is_one_image_per_camera() {
        let (template, old) = map_with_keyframes(2, 4);
        let bounds = ferroslam_features::ImageBounds {
            min_x: 0.0,
            max_x: 640.0,
            min_y: 0.0,
            max_y: 480.0,
        };
        let mut map = Map::new(template.pyramid().clone());
        let kfs: Vec<KeyFrameId> = old
            .iter()
            .enumerate()
            .map(|(n, &id)| {
                let kf = template.keyframe(id).unwrap();
                let features = kf.features().clone().with_cameras(vec![0, 2], &[bounds; 2]);
                map.insert_keyframe(n as f64, n, *kf.T_c_w(), features.unwrap())
            })
            .collect();
        // A point observes one keypoint per keyframe: camera 0's in the first, camera 1's
        // in the second.
        let point = observe_all(&mut map, &kfs[..1], 1);
        map.add_observation(point, kfs[1], 3).unwrap();
        let T_c0_c1 = Isometry3::translation(0.1, 0.0, 0.0);
        let member = CameraModel::from(test_cameras()[1].1);
        let mut rig = crate::Rig {
            sensor: "rgbd".into(),
            model: crate::Rig::PINHOLE.into(),
            intrinsics: [0.0; 4],
            distortion: [0.0; 5],
            width: 640,
            height: 480,
            pair: None,
            cameras: Vec::new(),
        };
        rig.cameras.push(crate::RigMember {
            model: crate::Rig::PINHOLE.into(),
            intrinsics: [0.0; 4],
            distortion: [0.0; 5],
            width: 640,
            height: 480,
            T_c0_c: T_c0_c1,
            has_depth: false,
            pair: None,
        });
        map.set_rig(rig);
        let cameras = [tum_fr1(), member];
        let model = map.rig_sparse_model(&cameras);
        assert_eq!(model.images.len(), 4);
        for (n, image) in model.images.iter().enumerate() {
            let (kf, k) = (kfs[n / 2], n % 2);
            assert_eq!((image.id, image.camera), (kf, k));
            let T_w_c0 = map.keyframe(kf).unwrap().T_w_c();
            let expected = if k == 0 { T_w_c0 } else { T_w_c0 * T_c0_c1 };
            assert_relative_eq!(image.T_w_c, expected, epsilon = 1e-12);
            let seen = Some(0).filter(|_| n == 0 || n == 3);
            assert_eq!(image.point_index, vec![None, seen]);
            let raw = cameras[k].raw_pixel(&core_px(&map, kf, 2 * k + 1));
            assert_eq!(image.keypoints_raw_px[1], raw);
        }
        // The first camera alone: the single-camera model.
        let first = map.sparse_model(&cameras[0]);
        assert_eq!(first.images.len(), 2);
        assert!(first
            .images
            .iter()
            .all(|i| i.camera == 0 && i.point_index.len() == 2));
        assert_ne!(
            member.raw_pixel(&Vector2::new(3.0, 10.0)),
            cameras[0].raw_pixel(&Vector2::new(3.0, 10.0))
        );
    }

    /// Keyframe 1 read as a rolling shutter turning at 1.5 rad/s (fr1/rpy's peaks): its
    /// keypoint 2 is where its row saw the point at (0, 0, 5), keypoint 0 a ray with no point.
    #[test]
    fn rolling_shutter_keypoints_are_moved_to_the_reference_pose() {
        let (mut map, kfs) = map_with_keyframes(1, 4);
        let camera = tum_fr1();
        let p_w = Point3::new(0.0, 0.0, 5.0);
        let T_c_w = Isometry3::translation(-1.0, 0.0, 0.0);
        let xi_dot = Vector6::new(0.05, 0.0, 0.02, 0.3, 1.5, -0.2);
        let dt = [-0.007, 0.0, 0.006, 0.0];
        let D = motion_over(&xi_dot, dt[2]);
        let seen = camera.project(&(D * T_c_w * p_w).coords).unwrap();
        let mut features = map.keyframe(kfs[0]).unwrap().features().clone();
        features.keypoints[2].x = seen.x as f32;
        features.keypoints[2].y = seen.y as f32;
        features.xi_dot = xi_dot;
        let features = features.with_time_offsets(dt.to_vec()).unwrap();
        let kf1 = map.insert_keyframe(1.0, 1, T_c_w, features);
        let kfs = [kfs[0], kf1];
        observe_all(&mut map, &kfs, 2);

        let image = &map.sparse_model(&camera).images[1];
        let core = |i: usize| camera.core_pixel(&image.keypoints_raw_px[i]);
        // Moved by the row's motion: the residual through the reference pose is the
        // detected keypoint's (f32 rounding) through its row's pose.
        let at_reference = camera.project(&(T_c_w * p_w).coords).unwrap();
        let residual_row = core_px(&map, kfs[1], 2) - seen;
        assert_relative_eq!(core(2) - at_reference, residual_row, epsilon = 1e-6);
        assert!((core(2) - core_px(&map, kfs[1], 2)).norm() > 2.0);
        // Without a point: the ray rotated back by the row's rotation.
        let ray = camera.unproject(&core_px(&map, kfs[1], 0)).unwrap();
        let D0 = motion_over(&xi_dot, dt[0]);
        let expected = camera.project(&(D0.rotation.inverse() * ray)).unwrap();
        assert_relative_eq!(core(0), expected, epsilon = 1e-6);
        assert!((core(0) - core_px(&map, kfs[1], 0)).norm() > 2.0);
        // Keypoints on the reference row are not moved.
        assert_relative_eq!(core(1), core_px(&map, kfs[1], 1), epsilon = 1e-9);
    }
}
