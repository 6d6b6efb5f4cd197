//! Content checks of a decoded map file beyond its encoding: a file with a valid checksum
//! can still hold values no map could have (written by another tool, or edited and
//! resealed). Every number must be finite and within [`MAX_COORDINATE_M`], every rotation a
//! unit quaternion (a rotation matrix orthonormal with determinant +1).

use ferroslam_features::ImageBounds;
use nalgebra::{Isometry3, Vector3};

use super::super::Map;
use crate::MapError;

/// Largest |coordinate| (m) of a pose translation or a map point: 1000 km, beyond any
/// camera trajectory (KITTI's longest drive spans ~4 km) by orders of magnitude, yet far
/// below where f64 loses millimetres (~1e13 m). 1e300 is finite but no place.
pub const MAX_COORDINATE_M: f64 = 1e6;
/// Largest | |q| - 1 | of a stored rotation quaternion. Poses are saved bit-exact from
/// unit quaternions (rounding error ~1e-16 per operation); a quaternion off by 1e-6 gives
/// a rotation matrix whose columns are off unit length by ~2e-6: no longer rigid.
pub const UNIT_QUATERNION_TOLERANCE: f64 = 1e-6;

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
        let ImageBounds {
            min_x,
            max_x,
            min_y,
            max_y,
        } = features.grid.bounds();
        if ![min_x, max_x, min_y, max_y].iter().all(|v| v.is_finite()) {
            return refuse(format!(
                "keyframe {id}: image bounds x [{min_x}, {max_x}], y [{min_y}, {max_y}] not finite"
            ));
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
    }
    Ok(())
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
