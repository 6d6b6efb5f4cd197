//! Levenberg-Marquardt over keyframe states and points, points eliminated by a Schur
//! complement into a DENSE reduced system over the free keyframe parameters (local windows
//! hold tens of keyframes, a few hundred parameters: dense Cholesky is cheaper than sparse
//! bookkeeping, and the inertial chain couples neighbours anyway).

use super::problem::{body_pose, InertialBaProblem};
use super::state::{
    linearize_inertial, StateJacobian, ACCEL_BIAS, GYRO_BIAS, POSE, STATE_DIM, VEL,
};
use super::HUBER_DELTA_INERTIAL;
use crate::ba::solve::visual_cost;
use crate::error::OptimError;
use crate::lm::{damping_diagonal, predicted_decrease, Damping};
use crate::robust::{cost_and_weight, Huber};
use faer::linalg::solvers::Solve;
use faer::{Mat, Side};
use ferroslam_geometry::se3;
use ferroslam_imu::{Bias, ImuState};
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, SMatrix, SVector, Vector3, Vector6};
use rayon::prelude::*;
use std::cmp::Ordering;
use std::ops::AddAssign;

/// Which parameters are free and where they sit in the reduced system; which points are
/// optimised and by which observations. Built once per call, shared by the stages.
pub(crate) struct Layout {
    /// Column of keyframe `k`'s pose tangent, if the pose is free.
    pose_col: Vec<Option<usize>>,
    /// Column of keyframe `k`'s `[v; b_g; b_a]`, if they are free.
    inertial_col: Vec<Option<usize>>,
    /// Size of the reduced system.
    dim: usize,
    /// Optimised points (seen by a free pose) and their observations.
    opt_points: Vec<(usize, Vec<usize>)>,
}

impl Layout {
    /// Requires a validated problem.
    pub(crate) fn new(problem: &InertialBaProblem) -> Self {
        let n = problem.visual.poses.len();
        let mut touched = vec![false; n];
        for e in &problem.inertial_edges {
            touched[e.i] = true;
            touched[e.j] = true;
        }
        let mut dim = 0;
        let mut pose_col = vec![None; n];
        let mut inertial_col = vec![None; n];
        for k in 0..n {
            if !problem.visual.pose_fixed[k] {
                pose_col[k] = Some(dim);
                dim += POSE.len();
            }
            if touched[k] && !problem.inertial_fixed[k] {
                inertial_col[k] = Some(dim);
                dim += STATE_DIM - POSE.len();
            }
        }
        let mut obs_of_point = vec![Vec::new(); problem.visual.points.len()];
        for (i, o) in problem.visual.observations.iter().enumerate() {
            obs_of_point[o.point].push(i);
        }
        let opt_points = obs_of_point
            .into_iter()
            .enumerate()
            .filter(|(_, obs)| {
                obs.iter()
                    .any(|&i| pose_col[problem.visual.observations[i].pose].is_some())
            })
            .collect();
        Self {
            pose_col,
            inertial_col,
            dim,
            opt_points,
        }
    }

    /// Column in the reduced system of parameter `c` (0..15, see [`super::state`]) of
    /// keyframe `k`, if free.
    fn column(&self, k: usize, c: usize) -> Option<usize> {
        if POSE.contains(&c) {
            self.pose_col[k].map(|s| s + c)
        } else {
            self.inertial_col[k].map(|s| s + c - POSE.len())
        }
    }
}

/// One stage of the schedule.
pub(crate) struct Stage {
    pub(crate) max_iterations: usize,
    /// Huber kernels on visual (ORB-SLAM widths) and inertial ([`HUBER_DELTA_INERTIAL`])
    /// residuals; the bias random walk never has one (as in ORB-SLAM3).
    pub(crate) robust: bool,
    pub(crate) initial_lambda: f64,
    pub(crate) function_tolerance: f64,
}

/// One free pose's share of a point's linearisation: column, `w J_c^T J_c`, `w J_c^T e`.
type PoseTerm = (usize, SMatrix<f64, 6, 6>, Vector6<f64>);

/// Costs before and after a stage and its iterations.
pub(crate) struct StageReport {
    pub(crate) initial_cost: f64,
    pub(crate) final_cost: f64,
    pub(crate) iterations: usize,
}

/// The variables being estimated (copied out of the problem, written back at the end).
#[derive(Clone)]
struct Estimate {
    poses: Vec<Isometry3<f64>>,
    velocities: Vec<Vector3<f64>>,
    biases: Vec<Bias>,
    points: Vec<Vector3<f64>>,
}

impl Estimate {
    #[allow(non_snake_case)]
    fn imu_state(&self, k: usize, T_b_c: &Isometry3<f64>) -> ImuState {
        ImuState {
            T_w_b: body_pose(&self.poses[k], T_b_c),
            v_w_b: self.velocities[k],
            bias: self.biases[k],
        }
    }
}

struct Context<'a> {
    problem: &'a InertialBaProblem,
    layout: &'a Layout,
    active: Vec<bool>,
    robust: bool,
}

/// Gauss-Newton blocks at the current estimate (`H = [U W; W^T V]`, half-gradient `[g; b_p]`).
struct Linearization {
    u: DMatrix<f64>,
    g: DVector<f64>,
    /// Per optimised point: `V`, `b_p` and `(column of the pose, W = w J_c^T J_p)` per
    /// observation by a free pose.
    points: Vec<PointBlocks>,
}

struct PointBlocks {
    v: Matrix3<f64>,
    b: Vector3<f64>,
    w: Vec<(usize, SMatrix<f64, 6, 3>)>,
}

/// A damped step over the reduced system's columns and the optimised points.
struct Step {
    dx: DVector<f64>,
    d_point: Vec<Vector3<f64>>,
    predicted_decrease: f64,
}

/// Runs one LM stage on `problem` in place over the observations with `use_obs[i]` (those
/// whose point is not in front of its camera at the start are left out as well). Requires a
/// validated problem and its `layout`. On error the problem keeps its last accepted estimate.
pub(crate) fn optimize(
    problem: &mut InertialBaProblem,
    layout: &Layout,
    stage: &Stage,
    use_obs: &[bool],
) -> Result<StageReport, OptimError> {
    let active = (0..problem.visual.observations.len())
        .into_par_iter()
        .map(|i| use_obs[i] && problem.visual.chi2(i).is_some())
        .collect();
    let mut current = Estimate {
        poses: problem.visual.poses.clone(),
        velocities: problem.velocities.clone(),
        biases: problem.biases.clone(),
        points: problem.visual.points.clone(),
    };
    let ctx = Context {
        problem,
        layout,
        active,
        robust: stage.robust,
    };
    let mut cost = ctx.cost(&current);
    let initial_cost = cost;
    let mut iterations = 0;
    let mut failure = None;
    if layout.dim > 0 {
        let mut trial = current.clone();
        let mut damping = Damping::new(stage.initial_lambda);
        while iterations < stage.max_iterations {
            iterations += 1;
            let lin = ctx.linearize(&current);
            let accepted = damping.find_step(
                |lambda| solve_damped(&lin, lambda),
                |step| {
                    ctx.apply(&current, step, &mut trial);
                    let new_cost = ctx.cost(&trial);
                    (cost - new_cost, step.predicted_decrease, new_cost)
                },
            );
            let new_cost = match accepted {
                Ok(Some(c)) => c,
                Ok(None) => break,
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            };
            std::mem::swap(&mut current, &mut trial);
            let decrease = cost - new_cost;
            cost = new_cost;
            if decrease <= stage.function_tolerance * cost {
                break;
            }
        }
    }
    drop(ctx);
    problem.visual.poses = current.poses;
    problem.velocities = current.velocities;
    problem.biases = current.biases;
    problem.visual.points = current.points;
    match failure {
        Some(e) => Err(e),
        None => Ok(StageReport {
            initial_cost,
            final_cost: cost,
            iterations,
        }),
    }
}

impl Context<'_> {
    fn inertial_kernel(&self, chi2: f64) -> (f64, f64) {
        if self.robust {
            let h = Huber {
                delta: HUBER_DELTA_INERTIAL,
            };
            (h.rho(chi2), h.weight(chi2))
        } else {
            (chi2, 1.0)
        }
    }

    /// Total cost; infinite if an active observation is not in front of its camera.
    fn cost(&self, est: &Estimate) -> f64 {
        let visual = &self.problem.visual;
        let mut cost = visual_cost(
            &visual.cameras,
            &visual.observations,
            &self.active,
            &est.poses,
            &est.points,
            self.robust,
        );
        for e in &self.problem.inertial_edges {
            let (s_i, s_j) = (
                est.imu_state(e.i, &self.problem.T_b_c),
                est.imu_state(e.j, &self.problem.T_b_c),
            );
            cost += self.inertial_kernel(e.factor.chi2(&s_i, &s_j)).0;
            cost += e.bias_walk.chi2(&s_i.bias, &s_j.bias);
        }
        if cost.is_finite() {
            cost
        } else {
            f64::INFINITY
        }
    }

    fn linearize(&self, est: &Estimate) -> Linearization {
        let layout = self.layout;
        let visual = &self.problem.visual;
        let n = layout.dim;
        let mut u = DMatrix::zeros(n, n);
        let mut g = DVector::zeros(n);
        // Per point in parallel: V, b_p, W and the point's share of the pose blocks.
        let per_point: Vec<(PointBlocks, Vec<PoseTerm>)> = layout
            .opt_points
            .par_iter()
            .map(|(p, obs)| {
                let mut blocks = PointBlocks {
                    v: Matrix3::zeros(),
                    b: Vector3::zeros(),
                    w: Vec::new(),
                };
                let mut pose_terms = Vec::new();
                for &i in obs.iter().filter(|&&i| self.active[i]) {
                    let o = &visual.observations[i];
                    // None is unreachable at an accepted estimate (its cost is finite).
                    let Some(l) = o.linearize(&visual.cameras, &est.poses[o.pose], &est.points[*p])
                    else {
                        continue;
                    };
                    let chi2 = o.inv_sigma2 * l.e.norm_squared();
                    let w = o.inv_sigma2 * cost_and_weight(chi2, o.is_stereo(), self.robust).1;
                    let jpt = w * l.d_e_d_p_w.transpose();
                    blocks.v += jpt * l.d_e_d_p_w;
                    blocks.b += jpt * l.e;
                    if let Some(c) = layout.pose_col[o.pose] {
                        let jct = w * l.d_e_d_xi.transpose();
                        blocks.w.push((c, jct * l.d_e_d_p_w));
                        pose_terms.push((c, jct * l.d_e_d_xi, jct * l.e));
                    }
                }
                (blocks, pose_terms)
            })
            .collect();
        let mut points = Vec::with_capacity(per_point.len());
        for (blocks, pose_terms) in per_point {
            for (c, uu, b) in pose_terms {
                let mut block = u.fixed_view_mut::<6, 6>(c, c);
                block += uu;
                let mut gb = g.fixed_rows_mut::<6>(c);
                gb += b;
            }
            points.push(blocks);
        }
        let t_b_c = &self.problem.T_b_c;
        for e in &self.problem.inertial_edges {
            let (s_i, s_j) = (est.imu_state(e.i, t_b_c), est.imu_state(e.j, t_b_c));
            let (r, d_i, d_j) =
                linearize_inertial(&e.factor, &est.poses[e.i], &s_i, &est.poses[e.j], &s_j);
            let info = e.factor.information();
            let w = self.inertial_kernel(r.dot(&(info * r))).1;
            self.accumulate(&mut u, &mut g, (e.i, e.j), (&d_i, &d_j), &(info * w), &r);
            // Bias walk r = [b_g; b_a]_j - [b_g; b_a]_i: -I over i's biases, +I over j's
            // (the gyro and accelerometer columns are contiguous, 9..15).
            let mut b_i = StateJacobian::<6>::zeros();
            let mut b_j = StateJacobian::<6>::zeros();
            for c in 0..6 {
                b_i[(c, GYRO_BIAS.start + c)] = -1.0;
                b_j[(c, GYRO_BIAS.start + c)] = 1.0;
            }
            let rb = e.bias_walk.residual(&s_i.bias, &s_j.bias);
            self.accumulate(
                &mut u,
                &mut g,
                (e.i, e.j),
                (&b_i, &b_j),
                e.bias_walk.information(),
                &rb,
            );
        }
        Linearization { u, g, points }
    }

    /// Adds `J^T info J` and `J^T info r` of a residual over keyframes `i` and `j` (Jacobians
    /// over their 15 parameters each) to the free columns.
    fn accumulate<const R: usize>(
        &self,
        u: &mut DMatrix<f64>,
        g: &mut DVector<f64>,
        (i, j): (usize, usize),
        (d_i, d_j): (&StateJacobian<R>, &StateJacobian<R>),
        info: &SMatrix<f64, R, R>,
        r: &SVector<f64, R>,
    ) {
        let cols: Vec<(usize, SVector<f64, R>)> = (0..STATE_DIM)
            .filter_map(|c| Some((self.layout.column(i, c)?, d_i.column(c).into_owned())))
            .chain(
                (0..STATE_DIM)
                    .filter_map(|c| Some((self.layout.column(j, c)?, d_j.column(c).into_owned()))),
            )
            .collect();
        let weighted: Vec<SVector<f64, R>> = cols.iter().map(|(_, jc)| info * jc).collect();
        for (a, (ca, _)) in cols.iter().enumerate() {
            g[*ca] += weighted[a].dot(r);
            for (cb, jb) in &cols {
                u[(*ca, *cb)] += weighted[a].dot(jb);
            }
        }
    }

    /// `trial = current [+] step`.
    fn apply(&self, current: &Estimate, step: &Step, trial: &mut Estimate) {
        let layout = self.layout;
        for k in 0..current.poses.len() {
            if let Some(c) = layout.pose_col[k] {
                let xi = Vector6::from_fn(|r, _| step.dx[c + r]);
                trial.poses[k] = se3::retract(&xi, &current.poses[k]);
            }
            if let Some(c) = layout.inertial_col[k] {
                let d = |range: std::ops::Range<usize>| {
                    let s = c + range.start - POSE.len();
                    Vector3::new(step.dx[s], step.dx[s + 1], step.dx[s + 2])
                };
                trial.velocities[k] = current.velocities[k] + d(VEL);
                trial.biases[k] = Bias::new(
                    current.biases[k].gyro + d(GYRO_BIAS),
                    current.biases[k].accel + d(ACCEL_BIAS),
                );
            }
        }
        for ((p, _), d) in layout.opt_points.iter().zip(&step.d_point) {
            trial.points[*p] = current.points[*p] + d;
        }
    }
}

/// Points per parallel task of the Schur complement (each task owns a dense `S`).
const SCHUR_CHUNK: usize = 128;

/// Solves `(H + lambda D) dx = -[g; b_p]` by eliminating the points.
fn solve_damped(lin: &Linearization, lambda: f64) -> Result<Step, OptimError> {
    let n = lin.g.len();
    let damp_u: DVector<f64> = lin.u.diagonal().map(damping_diagonal);
    let mut s = lin.u.clone();
    for c in 0..n {
        s[(c, c)] += lambda * damp_u[c];
    }
    let mut rhs = -&lin.g;
    let damp3 = |m: &Matrix3<f64>| m.diagonal().map(damping_diagonal);
    // Damped point blocks are positive definite (V is PSD, the damping diagonal > 0).
    let v_inv: Vec<Matrix3<f64>> = lin
        .points
        .iter()
        .map(|pt| {
            let vd = pt.v + Matrix3::from_diagonal(&(lambda * damp3(&pt.v)));
            vd.cholesky().map_or(Matrix3::zeros(), |c| c.inverse())
        })
        .collect();
    // S = U - W V^-1 W^T, rhs = -g + W V^-1 b_p, per fixed chunk of points in parallel (only
    // the upper block triangle), the chunks then summed in order (deterministic).
    let partial: Vec<(DMatrix<f64>, DVector<f64>)> = lin
        .points
        .par_chunks(SCHUR_CHUNK)
        .zip(v_inv.par_chunks(SCHUR_CHUNK))
        .map(|(points, v_inv)| {
            let mut s = DMatrix::zeros(n, n);
            let mut r = DVector::zeros(n);
            for (pt, vi) in points.iter().zip(v_inv) {
                for (a, (ca, wa)) in pt.w.iter().enumerate() {
                    let y = wa * vi;
                    let mut ra = r.fixed_rows_mut::<6>(*ca);
                    ra += y * pt.b;
                    let mut diag = s.fixed_view_mut::<6, 6>(*ca, *ca);
                    diag += y * wa.transpose();
                    for (cb, wb) in &pt.w[a + 1..] {
                        // The pair's blocks are m at (ca, cb) and m^T at (cb, ca).
                        let m = y * wb.transpose();
                        match ca.cmp(cb) {
                            Ordering::Less => s.fixed_view_mut::<6, 6>(*ca, *cb).add_assign(&m),
                            Ordering::Greater => s
                                .fixed_view_mut::<6, 6>(*cb, *ca)
                                .add_assign(&m.transpose()),
                            Ordering::Equal => s
                                .fixed_view_mut::<6, 6>(*ca, *ca)
                                .add_assign(&(m + m.transpose())),
                        }
                    }
                }
            }
            (s, r)
        })
        .collect();
    for (part_s, part_r) in &partial {
        s -= part_s;
        rhs += part_r;
    }
    let s_faer = Mat::<f64>::from_fn(n, n, |r, c| s[(r.min(c), r.max(c))]);
    let llt = s_faer.llt(Side::Lower).map_err(|e| match e {
        faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
            OptimError::NotPositiveDefinite { column: index }
        }
    })?;
    let mut x = Mat::<f64>::from_fn(n, 1, |r, _| rhs[r]);
    llt.solve_in_place(x.as_mut());
    let dx = DVector::from_fn(n, |r, _| x[(r, 0)]);
    if !dx.iter().all(|v| v.is_finite()) {
        return Err(OptimError::NotPositiveDefinite { column: 0 });
    }
    // Back-substitution: dp = V^-1 (-b_p - W^T dx).
    let d_point: Vec<Vector3<f64>> = lin
        .points
        .iter()
        .zip(&v_inv)
        .map(|(pt, vi)| {
            let mut r = -pt.b;
            for (c, w) in &pt.w {
                r -= w.transpose() * dx.fixed_rows::<6>(*c);
            }
            vi * r
        })
        .collect();
    let mut g_dot_dx = lin.g.dot(&dx);
    let mut dx_d_dx = dx.component_mul(&damp_u).dot(&dx);
    for (pt, d) in lin.points.iter().zip(&d_point) {
        g_dot_dx += pt.b.dot(d);
        dx_d_dx += d.component_mul(&damp3(&pt.v)).dot(d);
    }
    Ok(Step {
        dx,
        d_point,
        predicted_decrease: predicted_decrease(g_dot_dx, lambda, dx_d_dx),
    })
}
