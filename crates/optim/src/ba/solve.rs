//! Levenberg-Marquardt bundle adjustment with the points eliminated by a Schur complement.
//!
//! Work is split into fixed chunks of points, processed in parallel, with per-observation
//! data stored point by point so each point's data is contiguous. Each iteration linearises
//! every active observation (accumulating the point blocks directly and per-chunk partial
//! pose blocks), then for each damping value tried: inverts the damped 3x3 point blocks and
//! accumulates each chunk's partial reduced camera system `S = U - W V^-1 W^T` and
//! right-hand side, sums the partials in chunk order (deterministic whatever the thread
//! count), factorises `S` numerically on the reused symbolic Cholesky, back-substitutes the
//! point steps and accepts the step iff the cost decreases (Nielsen's lambda update). A
//! rejected step reuses the linearisation; only the damped parts are recomputed.

use super::problem::{BaProblem, Observation};
use super::symbolic::SymbolicBa;
use crate::block_pattern::factorize_upper;
use crate::error::OptimError;
use crate::lm::{damping_diagonal, predicted_decrease, Damping};
use crate::rig_camera::RigCamera;
use crate::robust::cost_and_weight;
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::SymbolicLlt;
use faer::Mat;
use ferroslam_geometry::se3;
use nalgebra::{Isometry3, Matrix3, SMatrix, SVector, Vector3};
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
///
/// Runs inside a rayon pool, the caller's or else the global one: an iteration makes several
/// small parallel loops, and each one started from outside a pool is handed to its threads
/// and waited for.
pub fn bundle_adjust(
    problem: &mut BaProblem,
    symbolic: &SymbolicBa,
    options: &BaOptions,
) -> Result<BaReport, OptimError> {
    let all = vec![true; problem.observations.len()];
    rayon::scope(|_| bundle_adjust_masked(problem, symbolic, options, &all))
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
        cameras: &problem.cameras,
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
    let mut v_inv = Vec::new();
    while iterations < options.max_iterations {
        iterations += 1;
        linearize(symbolic, &mut lin, |i| ctx.linearize_one(problem, i));
        let accepted = damping.find_step(
            |lambda| solve_damped(symbolic, &lin, llt, lambda, &mut v_inv),
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

/// `block -= y w^T` for one DxD block of a block column of the CSC values; `start[c]` is where
/// column `c` begins, `offset` the block's first row within it; only the upper triangle of a
/// diagonal block is stored. This is the solver's hot loop: fixed-size rows so it vectorises.
pub(crate) fn subtract_outer<const D: usize>(
    column: &mut [f64],
    start: &[usize; D],
    offset: usize,
    diagonal: bool,
    y: &SMatrix<f64, D, 3>,
    w: &SMatrix<f64, D, 3>,
) {
    // Column-major: y's three columns are contiguous runs of D.
    let (y0, rest) = y.as_slice().split_at(D);
    let (y1, y2) = rest.split_at(D);
    for c in 0..D {
        let (w0, w1, w2) = (w[(c, 0)], w[(c, 1)], w[(c, 2)]);
        let s = start[c] + offset;
        let rows = if diagonal { c + 1 } else { D };
        let dst = &mut column[s..s + rows];
        for (r, v) in dst.iter_mut().enumerate() {
            *v -= y0[r] * w0 + y1[r] * w1 + y2[r] * w2;
        }
    }
}

/// Gauss-Newton blocks at the current estimate for cameras of `D` parameters:
/// `H = [U W; W^T V]`, gradient `[b_c; b_p]` (half the cost gradient). Storage is reused
/// across iterations (the per-observation buffer is megabytes: reallocating it every
/// iteration costs page faults).
#[derive(Default)]
pub(crate) struct Linearization<const D: usize> {
    /// Per entry of [`SymbolicBa::point_obs`]: `W = w J_c^T J_p`, the camera-point coupling
    /// block (zero for inactive observations and those of fixed cameras).
    w_cp: Vec<SMatrix<f64, D, 3>>,
    u: Vec<SMatrix<f64, D, D>>,
    b_c: Vec<SVector<f64, D>>,
    v: Vec<Matrix3<f64>>,
    b_p: Vec<Vector3<f64>>,
}

/// A damped step: per free camera (additive or tangent, as the caller retracts it), per
/// optimised point, and the decrease the quadratic model predicts for it.
pub(crate) struct Step<const D: usize> {
    pub(crate) d_pose: Vec<SVector<f64, D>>,
    pub(crate) d_point: Vec<Vector3<f64>>,
    pub(crate) predicted_decrease: f64,
}

/// One observation's contribution to the normal equations: residual `e` (`R` rows), its
/// Jacobians with respect to the camera's `D` parameters and the point's 3 coordinates, and
/// the weight `w` of `w |e|^2` (information times robust IRLS factor).
pub(crate) struct ObservationJacobians<const R: usize, const D: usize> {
    pub(crate) weight: f64,
    pub(crate) e: SVector<f64, R>,
    pub(crate) d_e_d_camera: SMatrix<f64, R, D>,
    pub(crate) d_e_d_point: SMatrix<f64, R, 3>,
}

/// Splits `items` into consecutive mutable parts of the given lengths.
pub(crate) fn split_parts<T>(
    mut items: &mut [T],
    lens: impl Iterator<Item = usize>,
) -> Vec<&mut [T]> {
    lens.map(|len| {
        let (head, tail) = std::mem::take(&mut items).split_at_mut(len);
        items = tail;
        head
    })
    .collect()
}

/// One chunk's partial `U` and `b_c`, per free camera.
type PoseBlocks<const D: usize> = (Vec<SMatrix<f64, D, D>>, Vec<SVector<f64, D>>);

/// Observations per chunk of the cost sum (fixed, so the sum's order is too).
const COST_CHUNK: usize = 1024;

/// `sum rho(chi2)` over the `active` observations at the given poses and points; infinite
/// if one of them is no longer in front of its camera. Summed over fixed chunks in a fixed
/// order: a parallel float sum varies run to run, and LM's accept/reject on it would make
/// the whole SLAM run non-deterministic.
pub(crate) fn visual_cost(
    cameras: &[RigCamera],
    observations: &[Observation],
    active: &[bool],
    poses: &[Isometry3<f64>],
    points: &[Vector3<f64>],
    robust: bool,
) -> f64 {
    observations
        .par_chunks(COST_CHUNK)
        .zip(active.par_chunks(COST_CHUNK))
        .map(|(obs, active)| {
            obs.iter()
                .zip(active)
                .filter(|(_, &a)| a)
                .map(|(o, _)| {
                    o.chi2(cameras, &poses[o.pose], &points[o.point])
                        .map_or(f64::INFINITY, |c| {
                            cost_and_weight(c, o.is_stereo(), robust).0
                        })
                })
                .sum::<f64>()
        })
        .collect::<Vec<f64>>()
        .iter()
        .sum()
}

struct Context<'a> {
    cameras: &'a [RigCamera],
    active: &'a [bool],
    robust: bool,
}

impl Context<'_> {
    /// See [`visual_cost`].
    fn cost(&self, problem: &BaProblem, poses: &[Isometry3<f64>], points: &[Vector3<f64>]) -> f64 {
        visual_cost(
            self.cameras,
            &problem.observations,
            self.active,
            poses,
            points,
            self.robust,
        )
    }

    /// Weight (`inv_sigma2` times the kernel's IRLS factor) and linearisation of observation
    /// `i`, `None` if it is inactive.
    fn linearize_one(&self, problem: &BaProblem, i: usize) -> Option<ObservationJacobians<3, 6>> {
        if !self.active[i] {
            return None;
        }
        let o = &problem.observations[i];
        // None is unreachable for an accepted estimate (its cost is finite).
        let l = o.linearize(
            self.cameras,
            &problem.poses[o.pose],
            &problem.points[o.point],
        )?;
        let chi2 = o.inv_sigma2 * l.e.norm_squared();
        let w = o.inv_sigma2 * cost_and_weight(chi2, o.is_stereo(), self.robust).1;
        Some(ObservationJacobians {
            weight: w,
            e: l.e,
            d_e_d_camera: l.d_e_d_xi,
            d_e_d_point: l.d_e_d_p_w,
        })
    }
}

/// Linearises at the current estimate into `lin`, point by point (`observation(i)` gives
/// observation `i`'s terms, `None` to leave it out): each chunk of points fills its points'
/// `V`, `b_p`, `W` and its own partial `U`, `b_c`, which are then summed in chunk order.
pub(crate) fn linearize<const R: usize, const D: usize>(
    sym: &SymbolicBa,
    lin: &mut Linearization<D>,
    observation: impl Fn(usize) -> Option<ObservationJacobians<R, D>> + Sync,
) {
    let nfree = sym.free_poses.len();
    lin.w_cp.resize(sym.point_obs.len(), SMatrix::zeros());
    lin.v.resize(sym.opt_points.len(), Matrix3::zeros());
    lin.b_p.resize(sym.opt_points.len(), Vector3::zeros());
    let chunks: Vec<_> = sym.point_chunks().collect();
    let w_parts = split_parts(&mut lin.w_cp, chunks.iter().map(|(_, e)| *e));
    let v_parts = split_parts(&mut lin.v, chunks.iter().map(|(c, _)| c.len()));
    let b_parts = split_parts(&mut lin.b_p, chunks.iter().map(|(c, _)| c.len()));
    let partial: Vec<PoseBlocks<D>> = chunks
        .into_par_iter()
        .zip(w_parts)
        .zip(v_parts)
        .zip(b_parts)
        .map(|((((points, _), w_out), v_out), b_out)| {
            let mut u = vec![SMatrix::zeros(); nfree];
            let mut b_c = vec![SVector::zeros(); nfree];
            let first_entry = sym.point_obs.range(points.start).start;
            for (j, p) in points.enumerate() {
                let mut v = Matrix3::zeros();
                let mut b = Vector3::zeros();
                for e in sym.point_obs.range(p) {
                    let w_cp = &mut w_out[e - first_entry];
                    *w_cp = SMatrix::zeros();
                    let i = sym.point_obs.items()[e];
                    let Some(o) = observation(i) else {
                        continue;
                    };
                    let jpt = o.weight * o.d_e_d_point.transpose();
                    v += jpt * o.d_e_d_point;
                    b += jpt * o.e;
                    if let Some(f) = sym.entry_free[e] {
                        let jxt = o.weight * o.d_e_d_camera.transpose();
                        u[f] += jxt * o.d_e_d_camera;
                        b_c[f] += jxt * o.e;
                        *w_cp = jxt * o.d_e_d_point;
                    }
                }
                (v_out[j], b_out[j]) = (v, b);
            }
            (u, b_c)
        })
        .collect();
    lin.u = vec![SMatrix::zeros(); nfree];
    lin.b_c = vec![SVector::zeros(); nfree];
    for (u, b_c) in partial {
        for f in 0..nfree {
            lin.u[f] += u[f];
            lin.b_c[f] += b_c[f];
        }
    }
}

/// Solves the damped normal equations `(H + lambda D) dx = -b` by eliminating points
/// (`llt` is `sym.llt`). `v_inv` is scratch for the inverted damped point blocks.
pub(crate) fn solve_damped<const D: usize>(
    sym: &SymbolicBa,
    lin: &Linearization<D>,
    llt: &SymbolicLlt<usize>,
    lambda: f64,
    v_inv: &mut Vec<Matrix3<f64>>,
) -> Result<Step<D>, OptimError> {
    let nfree = sym.free_poses.len();
    let damp3 = |m: &Matrix3<f64>| m.diagonal().map(damping_diagonal);
    let damp_c = |m: &SMatrix<f64, D, D>| m.diagonal().map(damping_diagonal);
    let col_ptr = sym.pattern.col_ptr();
    let col_start: Vec<[usize; D]> = (0..nfree)
        .map(|b| std::array::from_fn(|c| col_ptr[D * b + c]))
        .collect();
    let nnz = sym.pattern.row_idx().len();

    // Per chunk of points: invert the damped point blocks, then accumulate the upper
    // triangle of -W V^-1 W^T and W V^-1 b_p into the chunk's own partial system.
    v_inv.resize(sym.opt_points.len(), Matrix3::zeros());
    let chunks: Vec<_> = sym.point_chunks().collect();
    let v_parts = split_parts(v_inv, chunks.iter().map(|(c, _)| c.len()));
    let partial: Vec<(Vec<f64>, Vec<SVector<f64, D>>)> = chunks
        .into_par_iter()
        .zip(v_parts)
        .map(|((points, _), v_out)| {
            let mut values = vec![0.0; nnz];
            let mut r = vec![SVector::zeros(); nfree];
            let mut y: Vec<SMatrix<f64, D, 3>> = Vec::new();
            for (j, p) in points.enumerate() {
                let v = &lin.v[p];
                // Damped point blocks are positive definite: V is PSD and the damping
                // diagonal > 0.
                let vd = v + Matrix3::from_diagonal(&(lambda * damp3(v)));
                let vi = vd.cholesky().map_or(Matrix3::zeros(), |c| c.inverse());
                v_out[j] = vi;
                let entries = sym.point_obs.range(p);
                let w = &lin.w_cp[entries.clone()];
                // Y = W V^-1 per observation (zero for fixed poses: W is).
                y.clear();
                y.extend(w.iter().map(|w| w * vi));
                for (k, e) in entries.enumerate() {
                    if let Some(f) = sym.entry_free[e] {
                        r[f] += y[k] * lin.b_p[p];
                    }
                }
                for t in sym.point_terms.row(p) {
                    subtract_outer(
                        &mut values,
                        &col_start[t.column as usize],
                        D * t.slot as usize,
                        t.diagonal,
                        &y[t.a as usize],
                        &w[t.b as usize],
                    );
                }
            }
            (values, r)
        })
        .collect();
    let mut values = vec![0.0; nnz];
    let mut rhs: Vec<SVector<f64, D>> = lin.b_c.iter().map(|b| -b).collect();
    for (part_values, part_r) in &partial {
        for (v, p) in values.iter_mut().zip(part_values) {
            *v += p;
        }
        for (r, p) in rhs.iter_mut().zip(part_r) {
            *r += p;
        }
    }
    // Upper triangle of the damped diagonal blocks U_b + lambda D.
    for (b, u) in lin.u.iter().enumerate() {
        let diag_slot = sym.blocks_in_column[b] - 1;
        for c in 0..D {
            let s = col_start[b][c] + D * diag_slot;
            for r in 0..=c {
                values[s + r] += u[(r, c)];
            }
            values[s + c] += lambda * damping_diagonal(u[(c, c)]);
        }
    }

    let factor = factorize_upper(&sym.pattern, llt, &values)?;
    let mut x = Mat::<f64>::from_fn(D * nfree, 1, |i, _| rhs[i / D][i % D]);
    factor.solve_in_place(x.as_mut());
    let d_pose: Vec<SVector<f64, D>> = (0..nfree)
        .map(|b| SVector::from_fn(|r, _| x[(D * b + r, 0)]))
        .collect();
    if d_pose.iter().any(|d| !d.iter().all(|v| v.is_finite())) {
        return Err(OptimError::NotPositiveDefinite { column: 0 });
    }

    // Back-substitution: dp = V^-1 (-b_p - W^T dc).
    let v_inv = &*v_inv;
    let d_point: Vec<Vector3<f64>> = (0..sym.opt_points.len())
        .into_par_iter()
        .with_min_len(MIN_BACK_SUBSTITUTION_POINTS)
        .map(|p| {
            let mut r = -lin.b_p[p];
            for e in sym.point_obs.range(p) {
                if let Some(f) = sym.entry_free[e] {
                    r -= lin.w_cp[e].transpose() * d_pose[f];
                }
            }
            v_inv[p] * r
        })
        .collect();

    let mut g_dot_dx = 0.0;
    let mut dx_d_dx = 0.0;
    for (f, d) in d_pose.iter().enumerate() {
        g_dot_dx += lin.b_c[f].dot(d);
        dx_d_dx += d.component_mul(&damp_c(&lin.u[f])).dot(d);
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

/// Points per parallel task of the back-substitution (a few hundred flops each).
const MIN_BACK_SUBSTITUTION_POINTS: usize = 256;
