//! The data of a visual-inertial bundle adjustment: a visual [`BaProblem`] plus, per
//! keyframe, a velocity and IMU biases, and the inertial factors between keyframes.

use crate::ba::BaProblem;
use crate::error::OptimError;
use ferroslam_imu::Bias;
use ferroslam_imu::{BiasWalkFactor, ImuState, InertialFactor};
use nalgebra::{Isometry3, Vector3};

/// The IMU measurement between keyframes `i` and `j` (indices into
/// [`BaProblem::poses`] of [`InertialBaProblem::visual`]): the preintegrated motion and the
/// bias random walk over the same interval.
#[derive(Clone, Debug, PartialEq)]
pub struct InertialEdge {
    /// Earlier keyframe (the preintegration starts here and is corrected to its bias).
    pub i: usize,
    /// Later keyframe.
    pub j: usize,
    /// Preintegrated IMU residual from `i` to `j`; it carries gravity in the world frame.
    pub factor: InertialFactor,
    /// Random walk tying the biases of `i` and `j`.
    pub bias_walk: BiasWalkFactor,
}

/// A visual-inertial bundle adjustment (ORB-SLAM3 `LocalInertialBA`).
///
/// Keyframe `k` is the camera pose `visual.poses[k]` (`T_c_w`), the velocity
/// `velocities[k]` of the body (IMU) frame in the world and the IMU biases `biases[k]`. The
/// body pose is `T_w_b = T_c_w^-1 * T_b_c^-1` (see [`Self::imu_state`]).
///
/// What is optimised: the poses with `visual.pose_fixed[k] == false`; the velocity and biases
/// of every keyframe with `inertial_fixed[k] == false` that some edge touches (a keyframe
/// without inertial edge, such as one of ORB-SLAM's fixed covisible keyframes, has nothing to
/// constrain them, so they stay as given); the points observed by at least one free pose.
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct InertialBaProblem {
    /// Camera poses `T_c_w`, their fixed flags, points and observations (as for visual BA).
    pub visual: BaProblem,
    /// Camera-to-body extrinsic: `p_b = T_b_c * p_c` (EuRoC's `T_BS` is `T_b_c` with the
    /// camera as sensor), metres. Constant. For a rig, that of its first camera, whose pose
    /// `visual.poses` holds (the others follow through their `RigCamera::T_c_c0`).
    pub T_b_c: Isometry3<f64>,
    /// Velocity of the body frame in the world, m/s, one per pose.
    pub velocities: Vec<Vector3<f64>>,
    /// IMU biases (gyro rad/s, accelerometer m/s^2), one per pose.
    pub biases: Vec<Bias>,
    /// `true` holds the velocity and biases of that keyframe constant (e.g. ORB-SLAM3's
    /// keyframe just before the window, whose pose is fixed as well), one per pose.
    pub inertial_fixed: Vec<bool>,
    /// Inertial edges, normally one per pair of consecutive keyframes.
    pub inertial_edges: Vec<InertialEdge>,
}

impl InertialBaProblem {
    /// The body state of keyframe `k` at the current estimate: `T_w_b = T_c_w^-1 T_b_c^-1`,
    /// its velocity and biases. `None` if `k` is out of range.
    #[allow(non_snake_case)]
    pub fn imu_state(&self, k: usize) -> Option<ImuState> {
        Some(ImuState {
            T_w_b: body_pose(self.visual.poses.get(k)?, &self.T_b_c),
            v_w_b: *self.velocities.get(k)?,
            bias: *self.biases.get(k)?,
        })
    }

    /// Checks the visual part ([`BaProblem::validate`]), one velocity / bias / flag per pose,
    /// finite values and edge indices (in range, `i != j`).
    pub fn validate(&self) -> Result<(), OptimError> {
        self.visual.validate()?;
        let n = self.visual.poses.len();
        for (what, len) in [
            ("velocities", self.velocities.len()),
            ("biases", self.biases.len()),
            ("inertial_fixed", self.inertial_fixed.len()),
        ] {
            if len != n {
                return Err(OptimError::InvalidInput(format!(
                    "{what} has {len} entries for {n} poses"
                )));
            }
        }
        let t = &self.T_b_c;
        if !t
            .translation
            .vector
            .iter()
            .chain(t.rotation.coords.iter())
            .all(|v| v.is_finite())
        {
            return Err(OptimError::NonFinite {
                what: "T_b_c",
                index: 0,
            });
        }
        if let Some(k) = self.velocities.iter().position(|v| !finite(v)) {
            return Err(OptimError::NonFinite {
                what: "velocity",
                index: k,
            });
        }
        if let Some(k) = self
            .biases
            .iter()
            .position(|b| !(finite(&b.gyro) && finite(&b.accel)))
        {
            return Err(OptimError::NonFinite {
                what: "bias",
                index: k,
            });
        }
        for (e, edge) in self.inertial_edges.iter().enumerate() {
            if edge.i >= n || edge.j >= n || edge.i == edge.j {
                return Err(OptimError::InvalidInput(format!(
                    "inertial edge {e} joins keyframes {} and {} of {n} (need two distinct keyframes in range)",
                    edge.i, edge.j
                )));
            }
        }
        Ok(())
    }
}

fn finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// `T_w_b = T_c_w^-1 * T_b_c^-1`.
#[allow(non_snake_case)]
pub(crate) fn body_pose(T_c_w: &Isometry3<f64>, T_b_c: &Isometry3<f64>) -> Isometry3<f64> {
    T_c_w.inverse() * T_b_c.inverse()
}
