//! Levenberg-Marquardt bundle adjustment with the points eliminated by a Schur complement.
//!
//! Each iteration linearises every active observation (in parallel), then for each damping
//! value tried: inverts the damped 3x3 point blocks, assembles the reduced camera system
//! `S = U - W V^-1 W^T` and its right-hand side block column by block column (in parallel),
//! factorises `S` numerically on the reused symbolic Cholesky, back-substitutes the point
//! steps and accepts the step iff the cost decreases (Nielsen's lambda update).

use super::problem::{BaProblem, Observation};
use super::symbolic::SymbolicBa;
use crate::error::OptimError;
use crate::intrinsics::Intrinsics;
use crate::lm::{damping_diagonal, predicted_decrease, Damping};
use crate::residual;
use crate::robust::cost_and_weight;
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::linalg::LltError;
use faer::sparse::SparseColMatRef;
use faer::{Mat, Side};
use ferroslam_geometry::se3;
use nalgebra::{Isometry3, Matrix3, Matrix3x6, Matrix6, Matrix6x3, Vector3, Vector6};
use rayon::prelude::*;

/// Options of [`bundle_adjust`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaOptions {
    /// Outer iterations (linearisations); each may try several damping values.
    pub max_iterations: usize,
    /// Huber kernel (ORB-SLAM widths) on every observation.
    pub robust: bool,
    /// Initial Marquardt damping, relative to the Hessian diagonal.
    pub initial_lambda: f64,
    /// Stop once an accepted step lowers the cost by less than this fraction of it.
    pub function_tolerance: f64,
}

impl Default for BaOptions {
    /// 10 robust iterations, `lambda = 1e-4`, relative tolerance `1e-6` (the cost of `N`
    /// residuals fluctuates by `sqrt(2 N)` between noise draws, so smaller relative gains
    /// carry no information for any realistic `N`).
    fn default() -> Self {
        Self {
            max_iterations: 10,
            robust: true,
            initial_lambda: 1e-4,
            function_tolerance: 1e-6,
        }
    }
}

/// Costs (`sum rho(chi2)` over the active observations) before and after, and iterations run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaReport {
    /// Cost at the initial estimate.
    pub initial_cost: f64,
    /// Cost at the returned estimate (never above `initial_cost`).
    pub final_cost: f64,
    /// Linearisations performed.
    pub iterations: usize,
}

/// Runs Levenberg-Marquardt on `problem` in place, reusing `symbolic`.
///
/// Observations whose point is not in front of their camera at the start are left out of
/// the cost; a step that would push a used observation behind its camera is rejected.
/// Fixed poses and points not seen by any free pose do not move. With no free pose or no
/// usable observation the problem is returned unchanged (`iterations == 0`).
///
/// # Errors
/// [`OptimError::StructureMismatch`] if `symbolic` was built for another structure; any
/// [`BaProblem::validate`] error; [`OptimError::NotPositiveDefinite`] if the damped reduced
/// system could not be factorised at any damping; [`OptimError::Solver`] on solver failure.
/// On error the problem is left at the last accepted estimate.
pub fn bundle_adjust(
    problem: &mut BaProblem,
    symbolic: &SymbolicBa,
    options: &BaOptions,
) -> Result<BaReport, OptimError> {
    let all = vec![true; problem.observations.len()];
    bundle_adjust_masked(problem, symbolic, options, &all)
}

/// [`bundle_adjust`] over the observations with `use_obs[i] == true` only (ORB-SLAM's edge
/// levels: outliers leave the cost but the structure, and so `symbolic`, stays the same).
pub(crate) fn bundle_adjust_masked(
    problem: &mut BaProblem,
    symbolic: &SymbolicBa,
    options: &BaOptions,
    use_obs: &[bool],
) -> Result<BaReport, OptimError> {
    if !symbolic.matches(problem) {
        return Err(OptimError::StructureMismatch);
    }
    problem.validate()?;
    let active: Vec<bool> = (0..problem.observations.len())
        .into_par_iter()
        .map(|i| use_obs[i] && problem.chi2(i).is_some())
        .collect();
    let ctx = Context {
        k: problem.intrinsics,
        symbolic,
        active: &active,
        robust: options.robust,
    };
    let mut cost = ctx.cost(problem, &problem.poses, &problem.points);
    let initial_cost = cost;
    let Some(llt) = &symbolic.llt else {
        return Ok(BaReport {
            initial_cost,
            final_cost: cost,
            iterations: 0,
        });
    };
    if !active.iter().any(|&a| a) {
        return Ok(BaReport {
            initial_cost,
            final_cost: cost,
            iterations: 0,
        });
    }
    let mut damping = Damping::new(options.initial_lambda);
    let mut iterations = 0;
    let mut trial_poses = problem.poses.clone();
    let mut trial_points = problem.points.clone();
    let mut lin = Linearization::default();
    let mut y_scratch = Vec::new();
    while iterations < options.max_iterations {
        iterations += 1;
        ctx.linearize(problem, &mut lin);
        let accepted = damping.find_step(
            |lambda| ctx.step(&lin, llt, lambda, &mut y_scratch),
            |step| {
                for (f, &pose) in symbolic.free_poses.iter().enumerate() {
                    trial_poses[pose] = se3::retract(&step.d_pose[f], &problem.poses[pose]);
                }
                for (p, &point) in symbolic.opt_points.iter().enumerate() {
                    trial_points[point] = problem.points[point] + step.d_point[p];
                }
                let new_cost = ctx.cost(problem, &trial_poses, &trial_points);
                (cost - new_cost, step.predicted_decrease, new_cost)
            },
        )?;
        let Some(new_cost) = accepted else {
            break;
        };
        std::mem::swap(&mut problem.poses, &mut trial_poses);
        std::mem::swap(&mut problem.points, &mut trial_points);
        let decrease = cost - new_cost;
        cost = new_cost;
        if decrease <= options.function_tolerance * cost {
            break;
        }
    }
    Ok(BaReport {
        initial_cost,
        final_cost: cost,
        iterations,
    })
}

/// `block -= y w^T` for one 6x6 block of a block column of the CSC values; `start[c]` is where
/// column `c` begins, `offset` the block's first row within it; only the upper triangle of a
/// diagonal block is stored. This is the solver's hot loop: fixed-size rows so it vectorises.
fn subtract_outer(
    column: &mut [f64],
    start: &[usize; 6],
    offset: usize,
    diagonal: bool,
    y: &Matrix6x3<f64>,
    w: &Matrix6x3<f64>,
) {
    // Column-major: y's three columns are contiguous runs of 6.
    let (y0, rest) = y.as_slice().split_at(6);
    let (y1, y2) = rest.split_at(6);
    for c in 0..6 {
        let (w0, w1, w2) = (w[(c, 0)], w[(c, 1)], w[(c, 2)]);
        let s = start[c] + offset;
        let rows = if diagonal { c + 1 } else { 6 };
        let dst = &mut column[s..s + rows];
        for (r, v) in dst.iter_mut().enumerate() {
            *v -= y0[r] * w0 + y1[r] * w1 + y2[r] * w2;
        }
    }
}

/// Per-observation linearisation (weights include `inv_sigma2` and the kernel's IRLS factor;
/// zero weight for inactive observations).
#[derive(Clone, Copy)]
struct ObsLin {
    w: f64,
    e: Vector3<f64>,
    d_e_d_xi: Matrix3x6<f64>,
    d_e_d_p_w: Matrix3<f64>,
    /// `W = w J_xi^T J_p`, the pose-point coupling block.
    w_cp: Matrix6x3<f64>,
}

impl ObsLin {
    const INACTIVE: Self = Self {
        w: 0.0,
        e: Vector3::new(0.0, 0.0, 0.0),
        d_e_d_xi: Matrix3x6::new(
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0,
        ),
        d_e_d_p_w: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        w_cp: Matrix6x3::new(
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0,
        ),
    };
}

/// Gauss-Newton blocks at the current estimate: `H = [U W; W^T V]`, gradient `[b_c; b_p]`
/// (half the cost gradient).
#[derive(Default)]
struct Linearization {
    obs: Vec<ObsLin>,
    u: Vec<Matrix6<f64>>,
    b_c: Vec<Vector6<f64>>,
    v: Vec<Matrix3<f64>>,
    b_p: Vec<Vector3<f64>>,
}

struct Step {
    d_pose: Vec<Vector6<f64>>,
    d_point: Vec<Vector3<f64>>,
    predicted_decrease: f64,
}

struct Context<'a> {
    k: Intrinsics,
    symbolic: &'a SymbolicBa,
    active: &'a [bool],
    robust: bool,
}

impl Context<'_> {
    /// `sum rho(chi2)` over active observations at the given estimate; infinite if one of
    /// them is no longer in front of its camera.
    fn cost(&self, problem: &BaProblem, poses: &[Isometry3<f64>], points: &[Vector3<f64>]) -> f64 {
        problem
            .observations
            .par_iter()
            .zip(self.active.par_iter())
            .filter(|(_, &a)| a)
            .map(|(o, _)| {
                residual::chi2(
                    &self.k,
                    &poses[o.pose],
                    &points[o.point],
                    &o.uv,
                    o.u_right,
                    o.inv_sigma2,
                )
                .map_or(f64::INFINITY, |c| {
                    cost_and_weight(c, o.is_stereo(), self.robust).0
                })
            })
            .collect::<Vec<f64>>()
            // Summed in a fixed order: a parallel float sum varies run to run, and LM's
            // accept/reject on it would make the whole SLAM run non-deterministic.
            .iter()
            .sum()
    }

    /// Linearises at the current estimate into `lin`, reusing its storage (the per-observation
    /// buffer is megabytes: reallocating it every iteration costs page faults).
    fn linearize(&self, problem: &BaProblem, lin: &mut Linearization) {
        let sym = self.symbolic;
        lin.obs.resize(problem.observations.len(), ObsLin::INACTIVE);
        lin.obs
            .par_iter_mut()
            .zip(problem.observations.par_iter().zip(self.active.par_iter()))
            .for_each(|(out, (o, &active))| *out = self.linearize_one(problem, o, active));
        let obs = &lin.obs;
        let (u, b_c) = (0..sym.free_poses.len())
            .into_par_iter()
            .map(|f| {
                let mut u = Matrix6::zeros();
                let mut b = Vector6::zeros();
                for &i in sym.pose_obs.row(f) {
                    let l = &obs[i];
                    let jt = l.d_e_d_xi.transpose();
                    u += l.w * jt * l.d_e_d_xi;
                    b += l.w * jt * l.e;
                }
                (u, b)
            })
            .unzip();
        let (v, b_p) = (0..sym.opt_points.len())
            .into_par_iter()
            .map(|p| {
                let mut v = Matrix3::zeros();
                let mut b = Vector3::zeros();
                for &i in sym.point_obs.row(p) {
                    let l = &obs[i];
                    let jt = l.d_e_d_p_w.transpose();
                    v += l.w * jt * l.d_e_d_p_w;
                    b += l.w * jt * l.e;
                }
                (v, b)
            })
            .unzip();
        (lin.u, lin.b_c, lin.v, lin.b_p) = (u, b_c, v, b_p);
    }

    fn linearize_one(&self, problem: &BaProblem, o: &Observation, active: bool) -> ObsLin {
        if !active {
            return ObsLin::INACTIVE;
        }
        let pose = &problem.poses[o.pose];
        let Some(l) =
            residual::linearize(&self.k, pose, &problem.points[o.point], &o.uv, o.u_right)
        else {
            // Unreachable for an accepted estimate (its cost is finite).
            return ObsLin::INACTIVE;
        };
        let chi2 = o.inv_sigma2 * l.e.norm_squared();
        let w = o.inv_sigma2 * cost_and_weight(chi2, o.is_stereo(), self.robust).1;
        ObsLin {
            w,
            e: l.e,
            d_e_d_xi: l.d_e_d_xi,
            d_e_d_p_w: l.d_e_d_p_w,
            w_cp: w * l.d_e_d_xi.transpose() * l.d_e_d_p_w,
        }
    }

    /// Solves the damped normal equations `(H + lambda D) dx = -b` by eliminating points.
    fn step(
        &self,
        lin: &Linearization,
        llt: &SymbolicLlt<usize>,
        lambda: f64,
        y: &mut Vec<Matrix6x3<f64>>,
    ) -> Result<Step, OptimError> {
        let sym = self.symbolic;
        let damp3 = |m: &Matrix3<f64>| m.diagonal().map(damping_diagonal);
        let damp6 = |m: &Matrix6<f64>| m.diagonal().map(damping_diagonal);
        // Damped point blocks are positive definite: V is PSD and the damping diagonal > 0.
        let v_inv: Vec<Matrix3<f64>> = lin
            .v
            .par_iter()
            .map(|v| {
                let vd = v + Matrix3::from_diagonal(&(lambda * damp3(v)));
                vd.cholesky().map_or(Matrix3::zeros(), |c| c.inverse())
            })
            .collect();
        let problem_obs_point = |i: usize| sym.point_index[self.observation_point(i)];
        // Y = W V^-1 per observation of a free pose and an optimised point.
        y.resize(lin.obs.len(), Matrix6x3::zeros());
        y.par_iter_mut().enumerate().for_each(|(i, y)| {
            *y = match problem_obs_point(i) {
                Some(p) if lin.obs[i].w > 0.0 => lin.obs[i].w_cp * v_inv[p],
                _ => Matrix6x3::zeros(),
            }
        });
        let y = &*y;

        // Assemble the upper triangle of S and r = -b_c + W V^-1 b_p per block column.
        let col_ptr = sym.pattern.col_ptr();
        let mut values = vec![0.0; sym.pattern.row_idx().len()];
        let mut columns: Vec<&mut [f64]> = Vec::with_capacity(sym.free_poses.len());
        let mut rest = values.as_mut_slice();
        for b in 0..sym.free_poses.len() {
            let (head, tail) = rest.split_at_mut(col_ptr[6 * b + 6] - col_ptr[6 * b]);
            columns.push(head);
            rest = tail;
        }
        let rhs: Vec<Vector6<f64>> = columns
            .into_par_iter()
            .enumerate()
            .map(|(b, column)| {
                let start: [usize; 6] =
                    std::array::from_fn(|c| col_ptr[6 * b + c] - col_ptr[6 * b]);
                let diag_slot = sym.blocks_in_column[b] - 1;
                // Upper triangle of the damped diagonal block U_b + lambda D.
                let u = &lin.u[b];
                for c in 0..6 {
                    let s = start[c] + 6 * diag_slot;
                    for r in 0..=c {
                        column[s + r] += u[(r, c)];
                    }
                    column[s + c] += lambda * damping_diagonal(u[(c, c)]);
                }
                // -Y_a W_b^T, written column by column straight into the CSC values (the
                // hot loop of the whole solver: no temporaries, rows contiguous).
                for t in sym.schur_terms.row(b) {
                    subtract_outer(
                        column,
                        &start,
                        6 * t.slot,
                        t.slot == diag_slot,
                        &y[t.obs_a],
                        &lin.obs[t.obs_b].w_cp,
                    );
                }
                let mut r = -lin.b_c[b];
                for &i in sym.pose_obs.row(b) {
                    if let Some(p) = problem_obs_point(i) {
                        r += y[i] * lin.b_p[p];
                    }
                }
                r
            })
            .collect();

        let matrix = SparseColMatRef::new(sym.pattern.as_ref(), &values);
        let factor =
            Llt::try_new_with_symbolic(llt.clone(), matrix, Side::Upper).map_err(|e| match e {
                LltError::Numeric(
                    faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index },
                ) => OptimError::NotPositiveDefinite { column: index },
                LltError::Generic(e) => OptimError::Solver(format!("{e:?}")),
            })?;
        let n = 6 * sym.free_poses.len();
        let mut x = Mat::<f64>::from_fn(n, 1, |i, _| rhs[i / 6][i % 6]);
        factor.solve_in_place(x.as_mut());
        let d_pose: Vec<Vector6<f64>> = (0..sym.free_poses.len())
            .map(|b| Vector6::from_fn(|r, _| x[(6 * b + r, 0)]))
            .collect();
        if d_pose.iter().any(|d| !d.iter().all(|v| v.is_finite())) {
            return Err(OptimError::NotPositiveDefinite { column: 0 });
        }

        // Back-substitution: dp = V^-1 (-b_p - W^T dc).
        let d_point: Vec<Vector3<f64>> = (0..sym.opt_points.len())
            .into_par_iter()
            .map(|p| {
                let mut r = -lin.b_p[p];
                for &i in sym.point_obs.row(p) {
                    if let Some(f) = sym.free_index[self.observation_pose(i)] {
                        r -= lin.obs[i].w_cp.transpose() * d_pose[f];
                    }
                }
                v_inv[p] * r
            })
            .collect();

        let mut g_dot_dx = 0.0;
        let mut dx_d_dx = 0.0;
        for (f, d) in d_pose.iter().enumerate() {
            g_dot_dx += lin.b_c[f].dot(d);
            dx_d_dx += d.component_mul(&damp6(&lin.u[f])).dot(d);
        }
        for (p, d) in d_point.iter().enumerate() {
            g_dot_dx += lin.b_p[p].dot(d);
            dx_d_dx += d.component_mul(&damp3(&lin.v[p])).dot(d);
        }
        Ok(Step {
            d_pose,
            d_point,
            predicted_decrease: predicted_decrease(g_dot_dx, lambda, dx_d_dx),
        })
    }

    fn observation_point(&self, i: usize) -> usize {
        self.symbolic.incidence[i].1
    }

    fn observation_pose(&self, i: usize) -> usize {
        self.symbolic.incidence[i].0
    }
}
