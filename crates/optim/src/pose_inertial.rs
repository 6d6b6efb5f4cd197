//! Visual-inertial motion-only optimisation for tracking once the IMU is initialised
//! (ORB-SLAM3 `Optimizer::PoseInertialOptimizationLastKeyFrame`).
//!
//! # Problem
//!
//! The current frame's state `j` = (camera pose `T_c_w`, body velocity `v_w_b`, IMU bias) is
//! refined against
//! - reprojections of FIXED map points ([`PoseObservation`], as in [`crate::optimize_pose`]),
//! - the preintegrated IMU measurement from a FIXED previous state `i` (the last keyframe or
//!   frame, an [`ImuState`]) to `j` ([`InertialFactor`]),
//! - the bias random walk from the fixed bias of `i` to the bias of `j` ([`BiasWalkFactor`]).
//!
//! The body pose follows from the camera pose by the constant extrinsic `T_b_c`:
//! `T_w_b = T_c_w^-1 * T_c_b`. As in ORB-SLAM3, the preintegration is corrected with the
//! (fixed) bias of `i`, so the bias of `j` is tied to it by the random walk alone and comes
//! out equal to `previous.bias`; it is kept in the state so that [`InertialPoseEstimate::information`]
//! covers all 15 dimensions and can serve as the prior of the next frame
//! (`PoseInertialOptimizationLastFrame`).
//!
//! # Tangent space
//!
//! 15 dimensions: `[xi (6); dv (3); db_g (3); db_a (3)]` at [`POSE`], [`VEL`], [`BIAS_GYRO`],
//! [`BIAS_ACCEL`], with `xi = [rho; phi]` a LEFT perturbation of the camera pose,
//! `T_c_w <- exp(xi) * T_c_w`, and additive velocity and biases. The inertial residual's
//! Jacobians are for a left WORLD-frame perturbation `delta` of `T_w_b`; since
//! `(exp(xi) T_c_w)^-1 T_c_b = exp(-Ad(T_w_c) xi) T_w_b`, the chain rule is
//! `d r / d xi = d r / d delta * (-Ad(T_w_c))`.
//!
//! # Schedule (ORB-SLAM3)
//!
//! [`ROUNDS`] rounds of up to [`ITERATIONS_PER_ROUND`] Levenberg-Marquardt iterations. Unlike
//! `optimize_pose`, a round continues from the previous round's estimate (ORB-SLAM3 does not
//! reset the inertial vertices). Visual residuals use the Huber kernel in the first
//! [`ROBUST_ROUNDS`] rounds; the inertial and bias residuals are always active and never
//! robustified. After each round every visual observation is re-classified with the round's
//! threshold ([`CHI2_MONO_SCHEDULE`], [`CHI2_STEREO_SCHEDULE`]; the last two rounds use
//! `optimize_pose`'s 5.991 / 7.815), monocular points closer than [`CLOSE_DEPTH`] getting
//! [`CLOSE_FACTOR`] times the threshold; a point behind the camera is an outlier. A problem
//! with fewer than [`MIN_EDGES`] edges (visual observations plus the three inertial ones)
//! stops after the first round. If fewer than [`FEW_INLIERS`] inliers remain, outliers with
//! `chi2` below [`RECOVER_CHI2_MONO`] / [`RECOVER_CHI2_STEREO`] are re-admitted (flags only).
//!
//! With no visual inlier the optimum is the IMU prediction from `i` (zero inertial residual).

use std::ops::Range;

use crate::error::OptimError;
use crate::lm::{damping_diagonal, dense_damped_step, Damping};
use crate::pose::{self, PoseObservation, ITERATIONS_PER_ROUND, ROBUST_ROUNDS, ROUNDS};
use crate::rig_camera::RigCamera;
use crate::robust::{CHI2_MONO, CHI2_STEREO};
use ferroslam_geometry::se3;
use ferroslam_imu::residual::Vector9;
use ferroslam_imu::{Bias, BiasWalkFactor, ImuState, InertialFactor};
use nalgebra::{Isometry3, Point3, SMatrix, SVector, Vector3};

/// Pose increment `xi = [rho; phi]` (left perturbation of `T_c_w`) in the 15-dim tangent.
pub const POSE: Range<usize> = 0..6;
/// Velocity increment (m/s, world frame).
pub const VEL: Range<usize> = 6..9;
/// Gyro bias increment (rad/s).
pub const BIAS_GYRO: Range<usize> = 9..12;
/// Accelerometer bias increment (m/s^2).
pub const BIAS_ACCEL: Range<usize> = 12..15;

/// A 15x15 matrix over `[xi; dv; db_g; db_a]`.
pub type Matrix15 = SMatrix<f64, 15, 15>;
type Vector15 = SVector<f64, 15>;

/// Monocular outlier threshold per round (ORB-SLAM3 `chi2Mono`).
pub const CHI2_MONO_SCHEDULE: [f64; ROUNDS] = [12.0, 7.5, CHI2_MONO, CHI2_MONO];
/// Stereo outlier threshold per round (ORB-SLAM3 `chi2Stereo`).
pub const CHI2_STEREO_SCHEDULE: [f64; ROUNDS] = [15.6, 9.8, CHI2_STEREO, CHI2_STEREO];
/// Monocular points closer than this (metres, camera z; range for a fisheye) get a looser
/// threshold.
pub const CLOSE_DEPTH: f64 = 10.0;
/// Threshold multiplier for close monocular points.
pub const CLOSE_FACTOR: f64 = 1.5;
/// Fewer edges than this (visual + 3 inertial) run a single round.
pub const MIN_EDGES: usize = 10;
/// Below this many inliers, mildly bad observations are re-admitted after the last round.
pub const FEW_INLIERS: usize = 30;
/// Re-admission threshold for monocular observations.
pub const RECOVER_CHI2_MONO: f64 = 18.0;
/// Re-admission threshold for stereo observations.
pub const RECOVER_CHI2_STEREO: f64 = 24.0;

/// Edges of the inertial factor graph besides the visual ones: inertial, gyro and accel walk.
const INERTIAL_EDGES: usize = 3;
/// Initial Marquardt damping (relative to the Hessian diagonal), as in `optimize_pose`.
const INITIAL_LAMBDA: f64 = 1e-5;
/// Stop a round once an accepted step lowers the cost by less than this fraction.
const RELATIVE_TOLERANCE: f64 = 1e-12;

/// The inertial constraint on the current frame: the fixed previous state and the factors
/// from it to the current one.
#[derive(Clone, Copy, Debug)]
pub struct InertialLink<'a> {
    /// State `i` (last keyframe or frame), held fixed.
    pub previous: &'a ImuState,
    /// Preintegrated IMU from `i` to the current frame.
    pub factor: &'a InertialFactor,
    /// Bias random walk over the same interval.
    pub bias_walk: &'a BiasWalkFactor,
}

/// Result of [`optimize_pose_inertial`].
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InertialPoseEstimate {
    /// Refined world-to-camera pose.
    pub T_c_w: Isometry3<f64>,
    /// The same estimate as body state: `T_w_b = T_c_w^-1 * T_c_b`, velocity, bias.
    pub state: ImuState,
    /// Observations classified as inliers at the end.
    pub num_inliers: usize,
    /// Gauss-Newton information (Hessian of the non-robust cost, final inliers, final
    /// state) over `[xi; dv; db_g; db_a]` ([`POSE`], [`VEL`], [`BIAS_GYRO`], [`BIAS_ACCEL`]):
    /// ORB-SLAM3's marginal for the next frame's prior. Symmetric positive definite.
    pub information: Matrix15,
}

/// Refines the current frame's camera pose, velocity and bias from fixed map points and the
/// IMU link from a fixed previous state (see the module docs for the schedule).
///
/// `initial` is the starting body state (typically the IMU prediction); `T_b_c` the pose of
/// the rig's first camera in the body frame, the other cameras' observations being seen
/// through their `T_c_c0` as in [`crate::optimize_pose`]. `outlier` holds the initial flags on input (flagged observations
/// sit out the first round) and the final classification on output.
///
/// # Errors
/// [`OptimError::InvalidInput`] if `outlier.len() != obs.len()`, `cameras` is empty, an
/// observation's camera is not in it, intrinsics are invalid or an `inv_sigma2` is not
/// positive; [`OptimError::NonFinite`] for a non-finite value in an observation or a
/// camera's extrinsics, `initial` (`"initial state"`), `link.previous` (`"previous state"`) or
/// `T_b_c` (`"extrinsics"`); [`OptimError::NotPositiveDefinite`] if no damping makes the
/// system factorisable (not expected: the inertial factors constrain every dimension).
#[allow(non_snake_case)]
pub fn optimize_pose_inertial(
    initial: &ImuState,
    link: &InertialLink<'_>,
    T_b_c: &Isometry3<f64>,
    obs: &[PoseObservation],
    cameras: &[RigCamera],
    outlier: &mut [bool],
) -> Result<InertialPoseEstimate, OptimError> {
    for (state, what) in [
        (initial, "initial state"),
        (link.previous, "previous state"),
    ] {
        if !state_finite(state) {
            return Err(OptimError::NonFinite { what, index: 0 });
        }
    }
    if !isometry_finite(T_b_c) {
        return Err(OptimError::NonFinite {
            what: "extrinsics",
            index: 0,
        });
    }
    let problem = Problem {
        link,
        T_c_b: T_b_c.inverse(),
        obs,
        cameras,
    };
    let mut x = State {
        T_c_w: (initial.T_w_b * T_b_c).inverse(),
        v_w_b: initial.v_w_b,
        bias: initial.bias,
    };
    pose::validate(&x.T_c_w, obs, cameras, outlier)?;

    for round in 0..ROUNDS {
        let active: Vec<usize> = (0..obs.len())
            .filter(|&i| !outlier[i] && pose::chi2_of(cameras, &x.T_c_w, &obs[i]).is_some())
            .collect();
        x = problem.refine(x, &active, round < ROBUST_ROUNDS)?;
        for (flag, o) in outlier.iter_mut().zip(obs) {
            *flag = !is_inlier(cameras, &x.T_c_w, o, round);
        }
        if obs.len() + INERTIAL_EDGES < MIN_EDGES {
            break;
        }
    }
    if outlier.iter().filter(|&&o| !o).count() < FEW_INLIERS {
        for (flag, o) in outlier.iter_mut().zip(obs) {
            let limit = if o.u_right.is_some() {
                RECOVER_CHI2_STEREO
            } else {
                RECOVER_CHI2_MONO
            };
            if pose::chi2_of(cameras, &x.T_c_w, o).is_some_and(|c| c < limit) {
                *flag = false;
            }
        }
    }
    let inliers: Vec<usize> = (0..obs.len()).filter(|&i| !outlier[i]).collect();
    let (_, visual) = problem.evaluate(&x, &inliers, false);
    let (information, _) = problem.normal_equations(&x, &visual);
    Ok(InertialPoseEstimate {
        T_c_w: x.T_c_w,
        state: problem.body_state(&x),
        num_inliers: inliers.len(),
        information: 0.5 * (information + information.transpose()),
    })
}

fn isometry_finite(t: &Isometry3<f64>) -> bool {
    t.translation.vector.iter().all(|v| v.is_finite())
        && t.rotation.coords.iter().all(|v| v.is_finite())
}

fn state_finite(s: &ImuState) -> bool {
    isometry_finite(&s.T_w_b)
        && s.v_w_b
            .iter()
            .chain(s.bias.gyro.iter())
            .chain(s.bias.accel.iter())
            .all(|v| v.is_finite())
}

/// ORB-SLAM3's per-round classification of one visual observation at `T_c_w`.
#[allow(non_snake_case)]
fn is_inlier(
    cameras: &[RigCamera],
    T_c_w: &Isometry3<f64>,
    o: &PoseObservation,
    round: usize,
) -> bool {
    let Some(chi2) = pose::chi2_of(cameras, T_c_w, o) else {
        return false;
    };
    let threshold = if o.u_right.is_some() {
        CHI2_STEREO_SCHEDULE[round]
    } else {
        let (camera, T_ck_w) = pose::camera_pose(cameras, T_c_w, o);
        let p_c = T_ck_w * Point3::from(o.p_w);
        // A fisheye sees points beside and behind its axis: their range, not z, is the depth.
        let depth = if camera.intrinsics.fisheye.is_some() {
            p_c.coords.norm()
        } else {
            p_c.z
        };
        let close = if depth < CLOSE_DEPTH {
            CLOSE_FACTOR
        } else {
            1.0
        };
        close * CHI2_MONO_SCHEDULE[round]
    };
    chi2 <= threshold
}

/// The variables of the current frame.
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug)]
struct State {
    T_c_w: Isometry3<f64>,
    v_w_b: Vector3<f64>,
    bias: Bias,
}

impl State {
    /// `x [+] dx` in the tangent layout of the module docs.
    fn retract(&self, dx: &Vector15) -> Self {
        let xi = dx.fixed_rows::<6>(POSE.start).into_owned();
        Self {
            T_c_w: se3::retract(&xi, &self.T_c_w),
            v_w_b: self.v_w_b + dx.fixed_rows::<3>(VEL.start),
            bias: Bias::new(
                self.bias.gyro + dx.fixed_rows::<3>(BIAS_GYRO.start),
                self.bias.accel + dx.fixed_rows::<3>(BIAS_ACCEL.start),
            ),
        }
    }
}

/// Everything fixed during the optimisation.
#[allow(non_snake_case)]
struct Problem<'a> {
    link: &'a InertialLink<'a>,
    T_c_b: Isometry3<f64>,
    obs: &'a [PoseObservation],
    cameras: &'a [RigCamera],
}

impl Problem<'_> {
    fn body_state(&self, x: &State) -> ImuState {
        ImuState {
            T_w_b: x.T_c_w.inverse() * self.T_c_b,
            v_w_b: x.v_w_b,
            bias: x.bias,
        }
    }

    /// Inertial residual and its Jacobian over the 15-dim tangent (bias columns zero: the
    /// preintegration is corrected with the previous state's bias).
    fn inertial(&self, x: &State) -> (Vector9, SMatrix<f64, 9, 15>) {
        let (r, jac) = self
            .link
            .factor
            .evaluate(self.link.previous, &self.body_state(x));
        let mut j = SMatrix::<f64, 9, 15>::zeros();
        j.fixed_view_mut::<9, 6>(0, POSE.start)
            .copy_from(&(jac.d_res_d_pose_j * -se3::adjoint(&x.T_c_w.inverse())));
        j.fixed_view_mut::<9, 3>(0, VEL.start)
            .copy_from(&jac.d_res_d_vel_j);
        (r, j)
    }

    /// Total cost at `x`: visual `sum rho(chi2)` over `active` plus the inertial and
    /// bias-walk `chi2`; infinite when a term is undefined, so such steps are rejected. With
    /// the visual part's evaluation, whose system [`Self::normal_equations`] takes.
    fn evaluate(&self, x: &State, active: &[usize], robust: bool) -> (f64, pose::Evaluation) {
        let link = self.link;
        let r = link.factor.residual(link.previous, &self.body_state(x));
        let inertial = r.dot(&(link.factor.information() * r));
        let walk = link.bias_walk.chi2(&link.previous.bias, &x.bias);
        let visual = pose::evaluate(self.cameras, &x.T_c_w, self.obs, active, robust);
        let total = visual.cost + inertial + walk;
        (if total.is_nan() { f64::INFINITY } else { total }, visual)
    }

    /// Gauss-Newton system `(H, g)` of the whole cost at `x` (`visual`: [`Self::evaluate`]'s
    /// at `x`), step `(H + lambda D) dx = -g`.
    fn normal_equations(&self, x: &State, visual: &pose::Evaluation) -> (Matrix15, Vector15) {
        let mut h = Matrix15::zeros();
        let mut g = Vector15::zeros();
        h.fixed_view_mut::<6, 6>(POSE.start, POSE.start)
            .copy_from(&visual.h);
        g.fixed_rows_mut::<6>(POSE.start).copy_from(&visual.g);
        let (r, j) = self.inertial(x);
        let omega = self.link.factor.information();
        h += j.transpose() * omega * j;
        g += j.transpose() * (omega * r);
        // Bias walk: r = b_j - b_i, d r / d b_j = I over [db_g; db_a].
        let walk = self.link.bias_walk;
        let rb = walk.residual(&self.link.previous.bias, &x.bias);
        let mut h_bias = h.fixed_view_mut::<6, 6>(BIAS_GYRO.start, BIAS_GYRO.start);
        h_bias += walk.information();
        let mut g_bias = g.fixed_rows_mut::<6>(BIAS_GYRO.start);
        g_bias += walk.information() * rb;
        (h, g)
    }

    /// Levenberg-Marquardt over the 15 dimensions with the visual observations `active`.
    fn refine(&self, start: State, active: &[usize], robust: bool) -> Result<State, OptimError> {
        let mut x = start;
        let (mut current, mut visual) = self.evaluate(&x, active, robust);
        let mut damping = Damping::new(INITIAL_LAMBDA);
        for _ in 0..ITERATIONS_PER_ROUND {
            let (h, g) = self.normal_equations(&x, &visual);
            let d = h.diagonal().map(damping_diagonal);
            let mut candidate = (x, None);
            let accepted = damping.find_step(
                |lambda| dense_damped_step(&h, &g, &d, lambda),
                |(dx, predicted)| {
                    let moved = x.retract(dx);
                    let (new_cost, at) = self.evaluate(&moved, active, robust);
                    candidate = (moved, Some(at));
                    (current - new_cost, *predicted, new_cost)
                },
            )?;
            // The last step tried is the accepted one: its visual system is the next one's.
            let (Some(new_cost), (moved, Some(at))) = (accepted, candidate) else {
                break;
            };
            let actual = current - new_cost;
            x = moved;
            current = new_cost;
            visual = at;
            if actual <= RELATIVE_TOLERANCE * new_cost.max(f64::MIN_POSITIVE) {
                break;
            }
        }
        Ok(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intrinsics::Intrinsics;
    use ferroslam_geometry::testing::check_jacobian;
    use ferroslam_imu::{ImuParams, Preintegrated};
    use nalgebra::{DMatrix, DVector, Translation3, UnitQuaternion, Vector6};

    const K: Intrinsics = Intrinsics {
        fx: 458.0,
        fy: 457.0,
        cx: 367.0,
        cy: 248.0,
        bf: 0.0,
        fisheye: None,
    };

    fn extrinsics() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(-0.02, 0.06, 0.01),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, 1.4, -0.2)),
        )
    }

    fn factors() -> (InertialFactor, BiasWalkFactor) {
        let params = ImuParams::euroc();
        let mut pre = Preintegrated::new(
            Bias::new(Vector3::new(0.01, 0.0, -0.01), Vector3::new(0.05, 0.1, 0.0)),
            &params,
        )
        .unwrap();
        for step in 0..40 {
            let t = step as f64 * 0.005;
            pre.integrate(
                0.005,
                &Vector3::new(0.3, -0.2 + t, 0.5),
                &Vector3::new(0.4, 9.7, 0.2 - t),
            )
            .unwrap();
        }
        (
            InertialFactor::new(pre, Vector3::new(0.0, 0.0, -9.81)).unwrap(),
            BiasWalkFactor::new(&params, 0.2).unwrap(),
        )
    }

    fn previous() -> ImuState {
        ImuState {
            T_w_b: Isometry3::from_parts(
                Translation3::new(1.0, -0.5, 0.8),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.1, 0.7)),
            ),
            v_w_b: Vector3::new(0.6, 0.1, -0.2),
            bias: Bias::new(
                Vector3::new(0.012, 0.0, -0.01),
                Vector3::new(0.05, 0.1, 0.02),
            ),
        }
    }

    #[test]
    #[allow(non_snake_case)]
    fn world_perturbation_of_the_body_is_minus_adjoint_of_the_camera_perturbation() {
        let T_b_c = extrinsics();
        let T_c_w = (previous().T_w_b * T_b_c).inverse();
        let T_w_b = T_c_w.inverse() * T_b_c.inverse();
        let xi = Vector6::new(0.05, -0.1, 0.2, 0.3, -0.2, 0.1);
        let perturbed = (se3::exp(&xi) * T_c_w).inverse() * T_b_c.inverse();
        let predicted = se3::exp(&(-se3::adjoint(&T_c_w.inverse()) * xi)) * T_w_b;
        let diff = perturbed.inverse() * predicted;
        assert!(diff.translation.vector.norm() < 1e-12 && diff.rotation.angle() < 1e-12);
    }

    #[test]
    #[allow(non_snake_case)]
    fn inertial_jacobian_matches_central_differences() {
        let (factor, bias_walk) = factors();
        let prev = previous();
        let link = InertialLink {
            previous: &prev,
            factor: &factor,
            bias_walk: &bias_walk,
        };
        let T_b_c = extrinsics();
        let problem = Problem {
            link: &link,
            T_c_b: T_b_c.inverse(),
            obs: &[],
            cameras: &[RigCamera::first(K)],
        };
        // A state well away from the IMU prediction so that every term matters.
        let x = State {
            T_c_w: (Isometry3::from_parts(
                Translation3::new(1.2, -0.4, 0.7),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.2, 0.9)),
            ) * T_b_c)
                .inverse(),
            v_w_b: Vector3::new(0.9, 0.3, -0.6),
            bias: Bias::new(Vector3::new(0.02, -0.01, 0.0), Vector3::new(0.1, 0.0, -0.1)),
        };
        let (r, j) = problem.inertial(&x);
        assert!(r.norm() > 0.1);
        let analytic = DMatrix::from_column_slice(9, 15, j.as_slice());
        check_jacobian(
            "inertial residual vs [xi; dv; db_g; db_a]",
            &analytic,
            |d| {
                let dx = Vector15::from_column_slice(d.as_slice());
                let (r, _) = problem.inertial(&x.retract(&dx));
                DVector::from_column_slice(r.as_slice())
            },
            &DVector::zeros(15),
            1e-6,
            1e-6,
        );
    }
}
