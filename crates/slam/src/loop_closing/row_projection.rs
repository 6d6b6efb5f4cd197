//! Loop closing's projections through a rolling shutter: a keyframe saw each keypoint from
//! its row's pose, `D(dt) * T_c_w` with the keyframe's velocity over the row's time offset
//! ([`readout_motion`], as local BA sees it), not from its reference pose `T_c_w`. Over
//! fr1's 15 ms readout at its 1-1.5 rad/s that is up to 6 px at the top and bottom rows,
//! twice the 3 px of the Sim(3) inlier test. A further camera `k` of a rig moves with the
//! first one: it saw its keypoints from `T_ck_c0 * D(dt) * T_c0_w`, `dt` its own row's.
//!
//! Measured keypoints are moved to where the reference pose sees them, for the Sim(3)
//! solvers that know one pose per keyframe; predicted projections (guided searches) are
//! made from the pose of the row they land on. With a global shutter every function returns
//! its reference-pose input unchanged, so the arithmetic is that of a global shutter.

// Frame-named variables (`T_c_w`, `D`) follow the crate's pose convention.
#![allow(non_snake_case)]

use ferroslam_geometry::rolling_shutter::{
    mounted_motion, pixel_at_reference_line, predicted_readout_motion,
};
use ferroslam_map::{FrameFeatures, Map, MapPointId};
use nalgebra::{Isometry3, Point3, Vector2, Vector3, Vector6};

use crate::context::{CameraView, Context};
use crate::frame::readout_motion;
use crate::frustum::{visible_point, VisiblePoint};

/// Keypoint `i` of `features` (core pixels) where the keyframe's reference pose sees the
/// point it observed, `p_c` being that point's estimate in the frame of `view`, the camera
/// that measured it ([`pixel_at_reference_line`] through that camera's motion on the rig,
/// [`mounted_motion`]); the keypoint itself for a global shutter or the reference line.
pub(super) fn keypoint_at_reference_line(
    view: &CameraView<'_>,
    features: &FrameFeatures,
    i: usize,
    p_c: &Vector3<f64>,
) -> Vector2<f64> {
    let kp = &features.keypoints[i];
    let uv = Vector2::new(kp.x as f64, kp.y as f64);
    readout_motion(features, i)
        .and_then(|D| {
            pixel_at_reference_line(view.camera, &uv, p_c, &mounted_motion(&D, view.T_c_c0))
        })
        .unwrap_or(uv)
}

/// The point `p_c` (the frame of `view`, a camera of a keyframe's rig at its reference line,
/// metres) in the camera frame of the row it projects to, the keyframe moving at `xi_dot`
/// (`FrameFeatures::xi_dot`, its first camera's velocity); `p_c` itself for a global
/// shutter.
pub(super) fn seen_from_row(
    view: &CameraView<'_>,
    xi_dot: &Vector6<f64>,
    p_c: &Vector3<f64>,
) -> Vector3<f64> {
    predicted_readout_motion(view.camera, xi_dot, view.T_c_c0, p_c)
        .map_or(*p_c, |D| (D * Point3::from(*p_c)).coords)
}

/// [`visible_point`] of map point `m` in camera `view` of a rig whose first camera is at
/// `T_c0_w`, from the row it lands on when the keyframe moves at `xi_dot`: pixel and
/// camera-frame point from the row's pose, distance and viewing angle from the camera's
/// centre (the readout moves it millimetres).
pub(super) fn visible_from_row(
    map: &Map,
    m: MapPointId,
    T_c0_w: &Isometry3<f64>,
    xi_dot: &Vector6<f64>,
    view: &CameraView<'_>,
    ctx: &Context,
) -> Option<VisiblePoint> {
    let T_c_w = view.pose(T_c0_w);
    let p_c = T_c_w * Point3::from(map.map_point(m)?.position());
    let T_row = predicted_readout_motion(view.camera, xi_dot, view.T_c_c0, &p_c.coords)
        .map_or(T_c_w, |D| D * T_c_w);
    let rules = &ctx.config.visibility;
    let center = T_c_w.inverse().translation.vector;
    visible_point(map, m, &T_row, &center, view.camera, view.bounds, rules)
}
