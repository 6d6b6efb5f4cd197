//! IMU-only poses for frames vision cannot localise, once the camera and the IMU are
//! aligned (ORB-SLAM3's `RECENTLY_LOST` state with `PredictStateIMU`).
//!
//! While vision tracks, the body poses of the recent frames are kept. When a frame fails,
//! the body state at the last tracked frame `j` is fixed once (the anchor): its velocity
//! follows from the tracked pose `k` about `inertial.velocity_baseline_s` (of the
//! configuration, [`crate::SlamConfig`]) earlier and the IMU
//! preintegrated between them, exactly (no finite difference of noisy positions):
//!
//! ```text
//! v_k = (p_j - p_k - g dt^2 / 2 - R_k dp) / dt,    v_j = v_k + g dt + R_k dv
//! ```
//!
//! Every later frame up to `inertial.imu_only_max_s` after the anchor is predicted from it with the
//! IMU preintegrated since (the newest keyframe's biases). The prediction is where tracking
//! looks for the local map again, and the prior that the few matches it may find are fused
//! with ([`ImuPrediction`]); with none, it is the frame's pose.
//!
//! Frames and units as [`crate::inertial`]: `T_b_c` camera in body, gravity in the map's
//! world, metres, seconds.

use std::collections::VecDeque;

use ferroslam_imu::preintegration::{Matrix9, POS, ROT, VEL};
use ferroslam_imu::{BiasWalkFactor, ImuState, InertialFactor, NavState};
use nalgebra::{Isometry3, Translation3};

use crate::config::InertialTuning;
use crate::inertial::Inertial;

/// Shortest tracked baseline an anchor's velocity is measured over, as a share of
/// `velocity_baseline_s`: right after a start or a relocalisation fewer frames are recorded,
/// and over a shorter stretch the pose noise divided by it would dominate the velocity.
const MIN_BASELINE_SHARE: f64 = 0.5;

/// The IMU's prediction for a frame: its pose and the inertial constraint from the anchor.
#[allow(non_snake_case)]
#[derive(Clone, Debug)]
pub(crate) struct ImuPrediction {
    /// Predicted camera pose.
    pub T_c_w: Isometry3<f64>,
    /// Predicted body state of the frame.
    pub predicted: ImuState,
    /// Body state at the anchor (the last tracked frame), held fixed.
    pub previous: ImuState,
    /// IMU preintegrated from the anchor to the frame.
    pub factor: InertialFactor,
    /// Bias random walk over the same interval.
    pub bias_walk: BiasWalkFactor,
}

/// Recent tracked body poses and the anchor of the current IMU-only stretch.
#[derive(Clone, Debug, Default)]
pub(crate) struct ImuPredictor {
    /// `(timestamp, T_w_b)` of the frames tracked by vision in the last
    /// `velocity_baseline_s` and one more, oldest first.
    tracked: VecDeque<(f64, Isometry3<f64>)>,
    /// Timestamp and state of the last tracked frame once a frame failed.
    anchor: Option<(f64, NavState)>,
}

impl ImuPredictor {
    /// Records a frame tracked by vision (ends any IMU-only stretch).
    #[allow(non_snake_case)]
    pub(crate) fn record(&mut self, timestamp: f64, T_w_c: &Isometry3<f64>, inertial: &Inertial) {
        self.anchor = None;
        let T_b_c = &inertial.config().T_b_c;
        self.tracked.push_back((timestamp, T_w_c * T_b_c.inverse()));
        let baseline_s = inertial.tuning().velocity_baseline_s;
        while self
            .tracked
            .get(1)
            .is_some_and(|&(t, _)| timestamp - t >= baseline_s)
        {
            self.tracked.pop_front();
        }
    }

    /// Forgets everything (map reset or rescaled: the recorded poses are stale).
    pub(crate) fn clear(&mut self) {
        *self = Self::default();
    }

    /// `(timestamp, body state)` of the last tracked frame, its velocity measured over the
    /// tracked baseline with the IMU (see the module doc); `None` before the alignment,
    /// without a baseline of [`MIN_BASELINE_SHARE`] of `velocity_baseline_s` or without IMU
    /// samples over it.
    #[allow(non_snake_case)]
    pub(crate) fn last_tracked_state(&self, inertial: &Inertial) -> Option<(f64, NavState)> {
        let gravity_w = inertial.gravity_w()?;
        let &(t_k, T_w_bk) = self.tracked.front()?;
        let &(t_j, T_w_bj) = self.tracked.back()?;
        let dt = t_j - t_k;
        if dt < MIN_BASELINE_SHARE * inertial.tuning().velocity_baseline_s {
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
        Some((t_j, state))
    }

    /// The IMU's prediction for a frame at `timestamp` that vision could not localise;
    /// `None` before the alignment, without a tracked baseline of at least
    /// [`MIN_BASELINE_SHARE`] of `velocity_baseline_s`, beyond `imu_only_max_s` or without
    /// IMU samples up to `timestamp`.
    #[allow(non_snake_case)]
    pub(crate) fn predict(&mut self, timestamp: f64, inertial: &Inertial) -> Option<ImuPrediction> {
        let gravity_w = inertial.gravity_w()?;
        let tuning = inertial.tuning();
        let (t_j, state_j) = match self.anchor {
            Some(anchor) => anchor,
            None => *self.anchor.insert(self.last_tracked_state(inertial)?),
        };
        if timestamp - t_j > tuning.imu_only_max_s {
            return None;
        }
        let pre = inertial.preintegrate(t_j, timestamp)?;
        let predicted = pre.predict(&state_j, &gravity_w);
        let body_state = |s: &NavState| ImuState {
            T_w_b: Isometry3::from_parts(Translation3::from(s.p_w_b), s.R_w_b),
            v_w_b: s.v_w_b,
            bias: *pre.bias(),
        };
        let predicted = body_state(&predicted);
        Some(ImuPrediction {
            T_c_w: (predicted.T_w_b * inertial.config().T_b_c).inverse(),
            previous: body_state(&state_j),
            predicted,
            bias_walk: BiasWalkFactor::new(&inertial.config().params, pre.dt()).ok()?,
            factor: InertialFactor::new(pre, gravity_w)
                .and_then(|f| f.with_added_covariance(&anchor_covariance(timestamp - t_j, tuning)))
                .ok()?,
        })
    }
}

/// The uncertainty of the anchor state a prediction starts from, which the
/// preintegration's own covariance does not hold (`anchor_sigma_*` of the tuning),
/// propagated over `dt` seconds into the inertial residual `[r_R; r_v; r_p]`: a velocity
/// error moves `r_v` by itself and `r_p` by `dt` times it, an acceleration error `r_v` by
/// `dt` and `r_p` by `dt^2 / 2` times it, a gyro bias error `r_R` by `dt` times it
/// (isotropic, so the anchor's orientation drops out).
fn anchor_covariance(dt: f64, tuning: &InertialTuning) -> Matrix9 {
    let (sv, sa, sg) = (
        tuning.anchor_sigma_velocity_m_s,
        tuning.anchor_sigma_accel_m_s2,
        tuning.anchor_sigma_gyro_rad_s,
    );
    let (var_v, var_a) = (sv * sv, sa * sa);
    let mut c = Matrix9::zeros();
    let mut block = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>, value: f64| {
        for (r, k) in rows.zip(cols) {
            c[(r, k)] = value;
        }
    };
    block(ROT, ROT, (sg * dt).powi(2));
    block(VEL, VEL, var_v + var_a * dt * dt);
    block(POS, POS, var_v * dt * dt + var_a * dt.powi(4) / 4.0);
    block(VEL, POS, var_v * dt + var_a * dt.powi(3) / 2.0);
    block(POS, VEL, var_v * dt + var_a * dt.powi(3) / 2.0);
    c
}
