//! Local visual-inertial bundle adjustment of a new keyframe once the camera and the IMU
//! are aligned (ORB-SLAM3 `Optimizer::LocalInertialBA`).
//!
//! The window is the newest keyframes (`inertial.window_keyframes` of the configuration) in
//! time order joined by their preintegrated IMU ([`InertialWindow`], built by tracking from
//! the inertial state); its oldest keyframe is held fixed, pose and IMU state, as ORB-SLAM3
//! holds the keyframe before its window. The
//! other window keyframes and the new keyframe's covisible keyframes are optimised with every
//! point they see (the covisible ones without IMU terms), the remaining observers held
//! fixed. Velocities and biases come back in the window.

use std::collections::HashMap;

use ferroslam_imu::{Bias, BiasWalkFactor, InertialFactor};
use ferroslam_map::{KeyFrameId, Map};
use ferroslam_optim::{inertial_bundle_adjust, InertialBaOptions, InertialBaProblem, InertialEdge};
use nalgebra::{Isometry3, Vector3};

use crate::context::Context;
use crate::error::SlamError;
use crate::local_ba_problem::LocalProblem;

/// The IMU side of a local inertial BA: keyframes oldest first, their states and the
/// factors between consecutive ones. `keyframes[0]` is held fixed.
#[allow(non_snake_case)]
#[derive(Clone, Debug)]
pub(crate) struct InertialWindow {
    /// Camera pose in the body (IMU) frame, metres.
    pub T_b_c: Isometry3<f64>,
    pub keyframes: Vec<KeyFrameId>,
    /// Body velocity in the world at each keyframe, m/s.
    pub velocities: Vec<Vector3<f64>>,
    pub biases: Vec<Bias>,
    /// `edges[k]` joins `keyframes[k]` and `keyframes[k + 1]`.
    pub edges: Vec<(InertialFactor, BiasWalkFactor)>,
}

/// Local inertial BA around the new keyframe `kf` (the newest of `window`); rejected
/// observations are erased from the map and their number returned. A numerically failed BA
/// leaves the map and the window as they were.
pub(crate) fn local_inertial_bundle_adjust(
    kf: KeyFrameId,
    window: &mut InertialWindow,
    map: &mut Map,
    ctx: &Context,
) -> Result<usize, SlamError> {
    let Some((&anchor, free)) = window.keyframes.split_first() else {
        return Ok(0);
    };
    let mut local: Vec<KeyFrameId> = free.to_vec();
    local.extend(
        map.covisibles(kf)
            .into_iter()
            .map(|(k, _)| k)
            .filter(|k| *k != anchor && !free.contains(k)),
    );
    let (visual, index) = LocalProblem::build(&local, &[anchor], map, ctx);
    let slot: HashMap<KeyFrameId, usize> = index
        .pose_ids
        .iter()
        .enumerate()
        .map(|(i, k)| (*k, i))
        .collect();
    if !window.keyframes.iter().all(|k| slot.contains_key(k)) {
        return Ok(0); // a window keyframe is gone from the map
    }
    let n = index.pose_ids.len();
    let mut problem = InertialBaProblem {
        visual,
        T_b_c: window.T_b_c,
        velocities: vec![Vector3::zeros(); n],
        biases: vec![Bias::default(); n],
        inertial_fixed: vec![true; n],
        inertial_edges: Vec::with_capacity(window.edges.len()),
    };
    for (k, id) in window.keyframes.iter().enumerate() {
        let s = slot[id];
        problem.velocities[s] = window.velocities[k];
        problem.biases[s] = window.biases[k];
        problem.inertial_fixed[s] = k == 0;
    }
    for (k, (factor, bias_walk)) in window.edges.iter().enumerate() {
        problem.inertial_edges.push(InertialEdge {
            i: slot[&window.keyframes[k]],
            j: slot[&window.keyframes[k + 1]],
            factor: factor.clone(),
            bias_walk: *bias_walk,
        });
    }
    let Ok(result) = inertial_bundle_adjust(&mut problem, &InertialBaOptions::default()) else {
        return Ok(0);
    };
    for (k, id) in window.keyframes.iter().enumerate() {
        window.velocities[k] = problem.velocities[slot[id]];
        window.biases[k] = problem.biases[slot[id]];
    }
    index.apply(&problem.visual, &result.outlier, map)
}
