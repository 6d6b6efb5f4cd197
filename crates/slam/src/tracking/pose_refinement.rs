//! Motion-only BA of a tracked frame: its pose, and with a rolling-shutter camera its
//! velocity too, against the map points and temporary points it matched.

use ferroslam_map::Map;
use ferroslam_optim::pose_rolling_shutter::{optimize_pose_and_velocity, VelocityPrior};
use ferroslam_optim::{optimize_pose, PoseObservation};
use nalgebra::{Vector2, Vector6};

use crate::context::Context;
use crate::error::SlamError;
use crate::frame::Frame;

/// Motion-only BA of `frame` on its map point and temporary point matches; sets the pose and
/// the outlier flags.
///
/// The frame of a rig with a rolling-shutter camera is estimated with its velocity (the
/// velocity of the first camera's `T_c_w`, kept in `frame.features.xi_dot` for the depth
/// points and the keyframe it may become), each match seen at its row's time in its camera,
/// `prior_xi_dot` the velocity it is drawn to (`tracking.velocity_prior_sigma_*` of the
/// configuration). Global shutters keep ORB-SLAM's pose-only problem and arithmetic.
pub fn optimize_frame_pose(
    frame: &mut Frame,
    map: &Map,
    ctx: &Context,
    prior_xi_dot: &Vector6<f64>,
) -> Result<usize, SlamError> {
    let (obs, index) = frame_observations(frame, map);
    if obs.len() < 3 {
        return Ok(0);
    }
    let mut outlier = vec![false; obs.len()];
    let num_inliers = if !ctx.has_rolling_shutter() {
        let estimate = optimize_pose(&frame.T_c_w, &obs, &ctx.optim_cameras, &mut outlier)?;
        frame.T_c_w = estimate.T_c_w;
        estimate.num_inliers
    } else {
        let tracking = &ctx.config.tracking;
        let prior = VelocityPrior::isotropic(
            *prior_xi_dot,
            tracking.velocity_prior_sigma_m_s,
            tracking.velocity_prior_sigma_rad_s,
        );
        let offsets: Vec<f64> = index
            .iter()
            .map(|&i| frame.features.time_offset_s(i))
            .collect();
        let estimate = optimize_pose_and_velocity(
            &frame.T_c_w,
            &prior,
            &obs,
            &offsets,
            &ctx.optim_cameras,
            &mut outlier,
        )?;
        frame.T_c_w = estimate.T_c_w;
        frame.features.xi_dot = estimate.xi_dot;
        estimate.num_inliers
    };
    for (k, &i) in index.iter().enumerate() {
        frame.outlier[i] = outlier[k];
    }
    Ok(num_inliers)
}

/// The frame's map point and temporary point matches as pose observations, with the
/// keypoint index of each.
pub(super) fn frame_observations(frame: &Frame, map: &Map) -> (Vec<PoseObservation>, Vec<usize>) {
    let pyramid = map.pyramid();
    let mut obs = Vec::new();
    let mut index = Vec::new();
    for i in 0..frame.len() {
        let p_w = match (frame.map_points[i], frame.vo_points[i]) {
            (Some(m), _) => match map.map_point(m) {
                Some(p) => p.position(),
                None => continue,
            },
            (None, Some(p)) => p,
            (None, None) => continue,
        };
        let kp = &frame.features.keypoints[i];
        let ur = frame.features.u_right[i];
        obs.push(PoseObservation {
            p_w,
            uv: Vector2::new(kp.x as f64, kp.y as f64),
            u_right: (ur >= 0.0).then_some(ur as f64),
            inv_sigma2: pyramid.inv_sigma2[kp.octave as usize],
            camera: frame.features.camera_of(i),
        });
        index.push(i);
    }
    (obs, index)
}

/// Drops the associations flagged as outliers; returns the remaining map point matches.
pub(super) fn discard_outliers(frame: &mut Frame) -> usize {
    let mut n = 0;
    for i in 0..frame.len() {
        if frame.outlier[i] {
            frame.map_points[i] = None;
            frame.vo_points[i] = None;
            frame.outlier[i] = false;
        } else if frame.map_points[i].is_some() {
            n += 1;
        }
    }
    n
}
