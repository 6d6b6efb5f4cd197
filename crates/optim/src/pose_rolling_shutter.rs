//! Motion-only bundle adjustment of a rolling-shutter camera (or rig): the frame's pose
//! `T_c_w` (at its reference line) together with its velocity `xi_dot = [v; w]`, the motion
//! model's velocity as a prior.
//!
//! Observation `i` was read `dt_i` seconds after the frame's timestamp
//! (`ferroslam_geometry::rolling_shutter::RollingShutter::time_offset_s` of its raw pixel),
//! so it is predicted from `D(dt_i) * T_c_w` (see
//! [`ferroslam_geometry::rolling_shutter`]). One frame's reprojections constrain the
//! velocity only through the spread of `dt` (half a readout), so the velocity needs the
//! prior: `(xi_dot - xi_dot_prior)^T Lambda (xi_dot - xi_dot_prior)` is added to the cost.
//! Outlier rejection follows [`crate::optimize_pose`]: the same rounds, kernel schedule and
//! chi-square thresholds; with every `dt_i = 0` the pose part is that problem's.

use crate::error::OptimError;
use crate::lm::{
    add_normal_equations, damping_diagonal, dense_damped_step, mirror_lower_triangle, Damping,
};
use crate::pose::{self, PoseObservation, ITERATIONS_PER_ROUND, ROBUST_ROUNDS, ROUNDS};
use crate::residual;
use crate::rig_camera::RigCamera;
use crate::robust::{chi2_threshold, cost_and_weight};
use ferroslam_geometry::rolling_shutter::{point_at_offset, position_at_offset};
use ferroslam_geometry::se3;
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, SMatrix, SVector, Vector3, Vector6};

type Matrix12 = SMatrix<f64, 12, 12>;
type Vector12 = SVector<f64, 12>;

/// Initial Marquardt damping, as in [`crate::optimize_pose`].
const INITIAL_LAMBDA: f64 = 1e-5;
/// A round stops once an accepted step gains less than this (chi-square units), as in
/// [`crate::optimize_pose`].
const DECREASE_TOLERANCE: f64 = 1e-3;

/// The motion model's velocity of `T_c_w` and its information.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityPrior {
    /// `[v; w]`, metres per second and radians per second (the velocity of `T_c_w`, see
    /// `ferroslam_geometry::rolling_shutter`).
    pub xi_dot: Vector6<f64>,
    /// Information of the prior, `(s^2/m^2)` on the `v` block and `(s^2/rad^2)` on `w`:
    /// the inverse covariance of how far the velocity may change from the motion model's.
    pub information: Matrix6<f64>,
}

impl VelocityPrior {
    /// A prior with independent standard deviations `sigma_v` (m/s) and `sigma_w` (rad/s).
    pub fn isotropic(xi_dot: Vector6<f64>, sigma_v: f64, sigma_w: f64) -> Self {
        let mut information = Matrix6::zeros();
        for j in 0..3 {
            information[(j, j)] = 1.0 / (sigma_v * sigma_v);
            information[(j + 3, j + 3)] = 1.0 / (sigma_w * sigma_w);
        }
        Self {
            xi_dot,
            information,
        }
    }
}

/// Result of [`optimize_pose_and_velocity`].
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseVelocityEstimate {
    /// Refined world-to-camera pose at the frame's reference line.
    pub T_c_w: Isometry3<f64>,
    /// Refined velocity `[v; w]` of `T_c_w`.
    pub xi_dot: Vector6<f64>,
    /// Observations classified as inliers by the final round.
    pub num_inliers: usize,
}

/// Refines `T_c_w` and its velocity from fixed world points observed at the time offsets
/// `time_offsets_s` (seconds after the frame's timestamp, one per observation), classifying
/// outliers as [`crate::optimize_pose`] does (`outlier` in: initial flags, out: final).
///
/// `cameras` is the rig of [`crate::optimize_pose`]: `T_c_w` and `xi_dot` are its first
/// camera's (the body's), and camera `k` sees observation `i` from `T_ck_c0 * D(dt_i) *
/// T_c_w`: the rig moves rigidly over a readout, each camera's rows timed by its own shutter
/// (`dt_i` is the offset of the row in the camera that saw it).
///
/// # Errors
/// As [`crate::optimize_pose`], and [`OptimError::InvalidInput`] when `time_offsets_s` does
/// not have one finite entry per observation or the prior is not finite with a positive
/// semi-definite information (its diagonal >= 0); [`OptimError::NotPositiveDefinite`] when
/// no damping makes a round's system factorisable.
#[allow(non_snake_case)]
pub fn optimize_pose_and_velocity(
    T_c_w: &Isometry3<f64>,
    prior: &VelocityPrior,
    obs: &[PoseObservation],
    time_offsets_s: &[f64],
    cameras: &[RigCamera],
    outlier: &mut [bool],
) -> Result<PoseVelocityEstimate, OptimError> {
    pose::validate(T_c_w, obs, cameras, outlier)?;
    validate(prior, obs, time_offsets_s)?;
    let problem = Problem {
        obs,
        dt: time_offsets_s,
        cameras,
        rotations: cameras
            .iter()
            .map(|c| {
                c.T_c_c0
                    .map(|T| T.rotation.to_rotation_matrix().into_inner())
            })
            .collect(),
        prior,
    };
    let start = (*T_c_w, prior.xi_dot);
    let mut state = start;
    // Every round restarts from the initial guess, as in optimize_pose.
    let projects_at_start: Vec<bool> = (0..obs.len())
        .map(|i| problem.chi2(&start, i).is_some())
        .collect();
    for round in 0..ROUNDS {
        let active: Vec<usize> = (0..obs.len())
            .filter(|&i| !outlier[i] && projects_at_start[i])
            .collect();
        state = problem.refine(start, &active, round < ROBUST_ROUNDS)?;
        for (i, flag) in outlier.iter_mut().enumerate() {
            let stereo = obs[i].u_right.is_some();
            *flag = problem
                .chi2(&state, i)
                .is_none_or(|c| c > chi2_threshold(stereo));
        }
    }
    Ok(PoseVelocityEstimate {
        T_c_w: state.0,
        xi_dot: state.1,
        num_inliers: outlier.iter().filter(|&&o| !o).count(),
    })
}

fn validate(
    prior: &VelocityPrior,
    obs: &[PoseObservation],
    time_offsets_s: &[f64],
) -> Result<(), OptimError> {
    if time_offsets_s.len() != obs.len() {
        return Err(OptimError::InvalidInput(format!(
            "time_offsets_s has {} entries for {} observations",
            time_offsets_s.len(),
            obs.len()
        )));
    }
    if let Some(i) = time_offsets_s.iter().position(|t| !t.is_finite()) {
        return Err(OptimError::InvalidInput(format!(
            "time offset {i} is {} (must be finite seconds)",
            time_offsets_s[i]
        )));
    }
    let finite = prior
        .xi_dot
        .iter()
        .chain(prior.information.iter())
        .all(|v| v.is_finite());
    if !finite || prior.information.diagonal().iter().any(|&d| d < 0.0) {
        return Err(OptimError::InvalidInput(
            "the velocity prior must be finite with a non-negative information diagonal".into(),
        ));
    }
    Ok(())
}

/// Pose and velocity.
type State = (Isometry3<f64>, Vector6<f64>);

struct Problem<'a> {
    obs: &'a [PoseObservation],
    dt: &'a [f64],
    cameras: &'a [RigCamera],
    /// Each camera's `R_c_c0` (the Jacobians' rotation into it), once per problem.
    rotations: Vec<Option<Matrix3<f64>>>,
    prior: &'a VelocityPrior,
}

/// Cost and Gauss-Newton system over `[delta (pose, left); d xi_dot]`.
struct Evaluation {
    cost: f64,
    h: Matrix12,
    g: Vector12,
}

impl Problem<'_> {
    /// Residual of observation `i` and its Jacobian over the 12 variables.
    #[allow(non_snake_case)]
    fn linearize(&self, state: &State, i: usize) -> Option<(Vector3<f64>, SMatrix<f64, 3, 12>)> {
        let o = &self.obs[i];
        let at = point_at_offset(&state.0, &state.1, self.dt[i], &Point3::from(o.p_w));
        let p_c = self.cameras[o.camera]
            .T_c_c0
            .map_or(at.p_c, |t| (t * Point3::from(at.p_c)).coords);
        let R_c_c0 = self.rotations[o.camera];
        let (e, mut d_pred_d_p_c) = self.error_at(i, &p_c)?;
        if o.u_right.is_none() {
            d_pred_d_p_c.row_mut(2).fill(0.0);
        }
        // The camera's point moves with the first camera's: d p_ck = R_ck_c0 d p_c0.
        let d_pred_d_p_c0 = R_c_c0.map_or(d_pred_d_p_c, |R| d_pred_d_p_c * R);
        let mut j = SMatrix::<f64, 3, 12>::zeros();
        j.fixed_view_mut::<3, 6>(0, 0)
            .copy_from(&(-d_pred_d_p_c0 * at.d_p_c_d_pose));
        j.fixed_view_mut::<3, 6>(0, 6)
            .copy_from(&(-d_pred_d_p_c0 * at.d_p_c_d_velocity));
        Some((e, j))
    }

    /// Residual of observation `i` seen at `p_c`, and the prediction's Jacobian; `None` where
    /// it does not project or the residual is not finite.
    fn error_at(&self, i: usize, p_c: &Vector3<f64>) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        let o = &self.obs[i];
        let (pred, d_pred_d_p_c) = residual::predict(&self.cameras[o.camera].intrinsics, p_c)?;
        let e = Vector3::new(
            o.uv.x - pred.x,
            o.uv.y - pred.y,
            o.u_right.map_or(0.0, |ur| ur - pred.z),
        );
        e.iter().all(|v| v.is_finite()).then_some((e, d_pred_d_p_c))
    }

    /// `inv_sigma2 * |e|^2` of observation `i`, without the Jacobians [`Problem::linearize`]
    /// computes (the classification of every observation each round).
    fn chi2(&self, state: &State, i: usize) -> Option<f64> {
        let o = &self.obs[i];
        let p_c0 = position_at_offset(&state.0, &state.1, self.dt[i], &Point3::from(o.p_w));
        let p_c = self.cameras[o.camera]
            .T_c_c0
            .map_or(p_c0, |t| (t * Point3::from(p_c0)).coords);
        let (e, _) = self.error_at(i, &p_c)?;
        Some(o.inv_sigma2 * e.norm_squared())
    }

    fn evaluate(&self, state: &State, active: &[usize], robust: bool) -> Evaluation {
        let mut at = Evaluation {
            cost: 0.0,
            h: Matrix12::zeros(),
            g: Vector12::zeros(),
        };
        for &i in active {
            let o = &self.obs[i];
            let Some((e, j)) = self.linearize(state, i) else {
                at.cost = f64::INFINITY;
                continue;
            };
            let (rho, weight) =
                cost_and_weight(o.inv_sigma2 * e.norm_squared(), o.u_right.is_some(), robust);
            at.cost += rho;
            let rows = if o.u_right.is_some() { 3 } else { 2 };
            add_normal_equations(&mut at.h, &mut at.g, o.inv_sigma2 * weight, &j, &e, rows);
        }
        mirror_lower_triangle(&mut at.h);
        // The prior's residual r = xi_dot - prior, d r / d xi_dot = I.
        let r = state.1 - self.prior.xi_dot;
        let lambda = &self.prior.information;
        at.cost += r.dot(&(lambda * r));
        let mut h_vv = at.h.fixed_view_mut::<6, 6>(6, 6);
        h_vv += lambda;
        let mut g_v = at.g.fixed_rows_mut::<6>(6);
        g_v += lambda * r;
        at
    }

    /// Levenberg-Marquardt on pose and velocity over the `active` observations.
    fn refine(&self, start: State, active: &[usize], robust: bool) -> Result<State, OptimError> {
        let mut state = start;
        if active.is_empty() {
            return Ok(state);
        }
        let mut current = self.evaluate(&state, active, robust);
        let mut damping = Damping::new(INITIAL_LAMBDA);
        for _ in 0..ITERATIONS_PER_ROUND {
            let (h, g) = (current.h, current.g);
            let d = h.diagonal().map(damping_diagonal);
            let mut tried = None;
            let accepted = damping.find_step(
                |lambda| dense_damped_step(&h, &g, &d, lambda),
                |(dx, predicted)| {
                    let moved = (
                        se3::retract(&dx.fixed_rows::<6>(0).into_owned(), &state.0),
                        state.1 + dx.fixed_rows::<6>(6),
                    );
                    let at = self.evaluate(&moved, active, robust);
                    let new_cost = at.cost;
                    tried = Some((moved, at));
                    (current.cost - new_cost, *predicted, new_cost)
                },
            )?;
            // The last step tried is the accepted one: its system is the next iteration's.
            let (Some(new_cost), Some((moved, at))) = (accepted, tried) else {
                break;
            };
            let gain = current.cost - new_cost;
            state = moved;
            current = at;
            if gain <= DECREASE_TOLERANCE {
                break;
            }
        }
        Ok(state)
    }
}
