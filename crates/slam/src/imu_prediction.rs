//! IMU-only poses for frames vision cannot localise, once the camera and the IMU are
//! aligned (ORB-SLAM3's `RECENTLY_LOST` state with `PredictStateIMU`).
//!
//! While vision tracks, the body poses of the recent frames are kept. When a frame fails,
//! the body state at the last tracked frame `j` is fixed once (the anchor): its velocity
//! follows from the tracked pose `k` about [`VELOCITY_BASELINE_S`] earlier and the IMU
//! preintegrated between them, exactly (no finite difference of noisy positions):
//!
//! ```text
//! v_k = (p_j - p_k - g dt^2 / 2 - R_k dp) / dt,    v_j = v_k + g dt + R_k dv
//! ```
//!
//! Every later frame up to [`IMU_ONLY_MAX_S`] after the anchor is predicted from it with the
//! IMU preintegrated since (biases of the alignment). The prediction is the pose reported
//! for the frame and the starting point from which tracking looks for the local map again.
//!
//! Frames and units as [`crate::inertial`]: `T_b_c` camera in body, gravity in the map's
//! world, metres, seconds.

use std::collections::VecDeque;

use ferroslam_imu::NavState;
use nalgebra::{Isometry3, Translation3};

use crate::inertial::Inertial;

/// Time over which the anchor's velocity is measured, seconds: long enough that millimetre
/// pose noise gives millimetres per second, short enough that the bias error stays small.
pub const VELOCITY_BASELINE_S: f64 = 0.5;
/// Longest IMU-only stretch, seconds, after which the frame is lost (ORB-SLAM3's
/// `time_recently_lost`).
pub const IMU_ONLY_MAX_S: f64 = 5.0;

/// Recent tracked body poses and the anchor of the current IMU-only stretch.
#[derive(Clone, Debug, Default)]
pub(crate) struct ImuPredictor {
    /// `(timestamp, T_w_b)` of the frames tracked by vision in the last
    /// [`VELOCITY_BASELINE_S`] and one more, oldest first.
    tracked: VecDeque<(f64, Isometry3<f64>)>,
    /// Timestamp and state of the last tracked frame once a frame failed.
    anchor: Option<(f64, NavState)>,
}

impl ImuPredictor {
    /// Records a frame tracked by vision (ends any IMU-only stretch).
    #[allow(non_snake_case)]
    pub(crate) fn record(
        &mut self,
        timestamp: f64,
        T_w_c: &Isometry3<f64>,
        T_b_c: &Isometry3<f64>,
    ) {
        self.anchor = None;
        self.tracked.push_back((timestamp, T_w_c * T_b_c.inverse()));
        while self
            .tracked
            .get(1)
            .is_some_and(|&(t, _)| timestamp - t >= VELOCITY_BASELINE_S)
        {
            self.tracked.pop_front();
        }
    }

    /// Forgets everything (map reset or rescaled: the recorded poses are stale).
    pub(crate) fn clear(&mut self) {
        *self = Self::default();
    }

    /// The IMU-predicted `T_c_w` of a frame at `timestamp` that vision could not localise;
    /// `None` before the alignment, without a tracked baseline of at least half
    /// [`VELOCITY_BASELINE_S`], beyond [`IMU_ONLY_MAX_S`] or without IMU samples up to
    /// `timestamp`.
    #[allow(non_snake_case)]
    pub(crate) fn predict(
        &mut self,
        timestamp: f64,
        inertial: &Inertial,
    ) -> Option<Isometry3<f64>> {
        let gravity_w = inertial.gravity_w()?;
        let (t_j, state_j) = match self.anchor {
            Some(anchor) => anchor,
            None => {
                let &(t_k, T_w_bk) = self.tracked.front()?;
                let &(t_j, T_w_bj) = self.tracked.back()?;
                let dt = t_j - t_k;
                if dt < 0.5 * VELOCITY_BASELINE_S {
                    return None;
                }
                let delta = inertial.preintegrate(t_k, t_j)?.delta();
                let R_k = T_w_bk.rotation;
                let p_k = T_w_bk.translation.vector;
                let p_j = T_w_bj.translation.vector;
                let v_k = (p_j - p_k - gravity_w * (0.5 * dt * dt) - R_k * delta.delta_p) / dt;
                let state = NavState {
                    R_w_b: T_w_bj.rotation,
                    v_w_b: v_k + gravity_w * dt + R_k * delta.delta_v,
                    p_w_b: p_j,
                };
                *self.anchor.insert((t_j, state))
            }
        };
        if timestamp - t_j > IMU_ONLY_MAX_S {
            return None;
        }
        let predicted = inertial
            .preintegrate(t_j, timestamp)?
            .predict(&state_j, &gravity_w);
        let T_w_b = Isometry3::from_parts(Translation3::from(predicted.p_w_b), predicted.R_w_b);
        Some((T_w_b * inertial.config().T_b_c).inverse())
    }
}
