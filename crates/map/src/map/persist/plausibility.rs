//! Content checks of a decoded map file beyond its encoding: a file with a valid checksum
//! can still hold values no map could have (written by another tool, or edited and
//! resealed). Every number must be finite and within [`MAX_COORDINATE_M`], every rotation a
//! unit quaternion (a rotation matrix orthonormal with determinant +1), every keyframe's
//! cameras those of the map's rig, every keypoint near its camera's image.

use ferroslam_features::ImageBounds;
use nalgebra::{Isometry3, Vector3};

use super::super::Map;
use crate::frame_features::cameras::check_camera_starts;
use crate::{FrameFeatures, MapError, Rig};

/// Largest |coordinate| (m) of a pose translation or a map point: 1000 km, beyond any
/// camera trajectory (KITTI's longest drive spans ~4 km) by orders of magnitude, yet far
/// below where f64 loses millimetres (~1e13 m). 1e300 is finite but no place.
pub const MAX_COORDINATE_M: f64 = 1e6;
/// Largest | |q| - 1 | of a stored rotation quaternion. Poses are saved bit-exact from
/// unit quaternions (rounding error ~1e-16 per operation); a quaternion off by 1e-6 gives
/// a rotation matrix whose columns are off unit length by ~2e-6: no longer rigid.
pub const UNIT_QUATERNION_TOLERANCE: f64 = 1e-6;
/// How far (as a fraction of the bounds' width / height, on each side) a keypoint may lie
/// outside its camera's image bounds. The bounds of a distorted pinhole are its undistorted
/// corners (ORB-SLAM's `ComputeImageBounds`): with pincushion distortion the middles of the
/// image edges undistort beyond them, so real keypoints do lie a little outside; a keypoint
/// a quarter of an image away is not of that camera.
pub const KEYPOINT_BOUNDS_MARGIN: f64 = 0.25;

/// The first implausible value of `map`, named by its owner (keyframe / map point id) and
/// field, as a [`MapError::CorruptMapFile`].
pub(super) fn check_plausible(map: &Map) -> Result<(), MapError> {
    let refuse = |what: String| Err(super::codec::corrupt(what));
    for (id, kf) in map.keyframes.iter() {
        if !kf.timestamp.is_finite() {
            return refuse(format!("keyframe {id}: timestamp {} (s)", kf.timestamp));
        }
        if let Some(problem) = pose_problem(&kf.T_c_w) {
            return refuse(format!("keyframe {id}: pose T_c_w {problem}"));
        }
        let features = &kf.features;
        if let Some(i) = features.keypoints.iter().position(|k| {
            ![k.x, k.y, k.angle_deg, k.response]
                .iter()
                .all(|v| v.is_finite())
        }) {
            let k = &features.keypoints[i];
            return refuse(format!(
                "keyframe {id}: keypoint {i} (x {}, y {}, angle {}, response {}) not finite",
                k.x, k.y, k.angle_deg, k.response
            ));
        }
        // NaN means "no depth" / "monocular" (documented on FrameFeatures); infinity does not.
        for (field, values) in [("depth", &features.depth), ("u_right", &features.u_right)] {
            if let Some(i) = values.iter().position(|v| v.is_infinite()) {
                return refuse(format!(
                    "keyframe {id}: {field} of keypoint {i} is {}",
                    values[i]
                ));
            }
        }
        if let Some(i) = features.time_offsets_s.iter().position(|t| !t.is_finite()) {
            return refuse(format!(
                "keyframe {id}: row time offset of keypoint {i} is {} (s)",
                features.time_offsets_s[i]
            ));
        }
        if !features.xi_dot.iter().all(|v| v.is_finite()) {
            return refuse(format!(
                "keyframe {id}: readout velocity {:?} not finite",
                features.xi_dot.as_slice()
            ));
        }
        if let Some(problem) = cameras_problem(features, map.rig.as_ref()) {
            return refuse(format!("keyframe {id}: {problem}"));
        }
    }
    for (id, p) in map.map_points.iter() {
        if let Some(problem) = coordinates_problem(&p.position) {
            return refuse(format!("map point {id}: position {problem}"));
        }
        if !p.normal.iter().all(|v| v.is_finite()) {
            return refuse(format!(
                "map point {id}: normal {:?} not finite",
                p.normal.as_slice()
            ));
        }
        if !(p.min_distance.is_finite() && p.max_distance.is_finite()) {
            return refuse(format!(
                "map point {id}: distance range [{}, {}] (m) not finite",
                p.min_distance, p.max_distance
            ));
        }
    }
    for (id, culled) in map.culled_keyframes.iter() {
        if let Some(problem) = pose_problem(&culled.T_c_a) {
            return refuse(format!("culled keyframe {id}: pose T_c_a {problem}"));
        }
    }
    if let Some(rig) = &map.rig {
        let values = rig.intrinsics.iter().chain(&rig.distortion);
        if !values.clone().all(|v| v.is_finite()) {
            return refuse(format!(
                "the camera record: intrinsics {:?} / distortion {:?} not finite",
                rig.intrinsics, rig.distortion
            ));
        }
        for (k, camera) in (1..).zip(&rig.cameras) {
            let values = camera.intrinsics.iter().chain(&camera.distortion);
            if !values.clone().all(|v| v.is_finite()) {
                return refuse(format!(
                    "the camera record: camera {k}'s intrinsics {:?} / distortion {:?} not finite",
                    camera.intrinsics, camera.distortion
                ));
            }
            if let Some(problem) = pose_problem(&camera.T_c0_c) {
                return refuse(format!(
                    "the camera record: camera {k}'s pose T_c0_c {problem}"
                ));
            }
        }
    }
    Ok(())
}

/// Why the keyframe's cameras cannot be: starts that do not split its keypoints, a count
/// other than the rig's (when the map records one), bounds not finite, a keypoint beyond
/// its camera's bounds ([`KEYPOINT_BOUNDS_MARGIN`]); `None` if they can.
fn cameras_problem(features: &FrameFeatures, rig: Option<&Rig>) -> Option<String> {
    if let Err(e) = check_camera_starts(&features.camera_starts, features.len()) {
        return Some(e.to_string());
    }
    if let Some(rig) = rig.filter(|r| r.num_cameras() != features.num_cameras()) {
        return Some(format!(
            "{} cameras (camera_starts {:?}), but the map's rig has {}",
            features.num_cameras(),
            features.camera_starts,
            rig.num_cameras()
        ));
    }
    for (k, grid) in features.grids.iter().enumerate() {
        let ImageBounds {
            min_x,
            max_x,
            min_y,
            max_y,
        } = grid.bounds();
        if ![min_x, max_x, min_y, max_y].iter().all(|v| v.is_finite()) {
            return Some(format!(
                "camera {k}'s image bounds x [{min_x}, {max_x}], y [{min_y}, {max_y}] not finite"
            ));
        }
        let (dx, dy) = (
            KEYPOINT_BOUNDS_MARGIN * (max_x - min_x).abs(),
            KEYPOINT_BOUNDS_MARGIN * (max_y - min_y).abs(),
        );
        let range = features.camera_range(k);
        let start = range.start;
        let outside = features.keypoints[range].iter().position(|kp| {
            let (x, y) = (f64::from(kp.x), f64::from(kp.y));
            !(min_x - dx..=max_x + dx).contains(&x) || !(min_y - dy..=max_y + dy).contains(&y)
        });
        if let Some(j) = outside {
            let kp = &features.keypoints[start + j];
            return Some(format!(
                "keypoint {} at ({}, {}) px is outside camera {k}'s image bounds x [{min_x}, \
                 {max_x}], y [{min_y}, {max_y}] (by more than {KEYPOINT_BOUNDS_MARGIN} of them)",
                start + j,
                kp.x,
                kp.y
            ));
        }
    }
    None
}

/// Why the pose is not a plausible rigid transform, or `None`.
fn pose_problem(pose: &Isometry3<f64>) -> Option<String> {
    if let Some(problem) = coordinates_problem(&pose.translation.vector) {
        return Some(format!("translation {problem}"));
    }
    let q = pose.rotation.coords;
    if !q.iter().all(|v| v.is_finite()) {
        return Some(format!("rotation quaternion {:?} not finite", q.as_slice()));
    }
    let norm_error = (q.norm() - 1.0).abs();
    (norm_error > UNIT_QUATERNION_TOLERANCE).then(|| {
        format!(
            "rotation quaternion {:?} has norm {} (not a rotation: | |q| - 1 | > \
             {UNIT_QUATERNION_TOLERANCE})",
            q.as_slice(),
            q.norm()
        )
    })
}

/// Why the point (m) is not finite and within [`MAX_COORDINATE_M`], or `None`.
fn coordinates_problem(p: &Vector3<f64>) -> Option<String> {
    if !p.iter().all(|v| v.is_finite()) {
        return Some(format!("{:?} not finite", p.as_slice()));
    }
    (p.amax() > MAX_COORDINATE_M)
        .then(|| format!("{:?} beyond {MAX_COORDINATE_M:e} m", p.as_slice()))
}
