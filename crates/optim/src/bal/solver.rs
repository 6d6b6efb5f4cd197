//! Levenberg-Marquardt for BAL problems: points eliminated by a Schur complement, the
//! reduced camera system (9x9 blocks) factorised with faer's sparse Cholesky.
//!
//! The structure analysis ([`SymbolicBa::from_incidence`]) and the numeric Schur core
//! (`ba::solve::{linearize, solve_damped}`) are those of [`crate::ba`], with 9-parameter
//! cameras, all free; damping and the step search are [`crate::lm`]'s (Marquardt's clamped
//! diagonal, Nielsen's update), as in Ceres' LM.

use super::problem::{cost_at, BalProblem};
use super::snavely::SnavelyCamera;
use super::snavely::CAMERA_PARAMS;
use crate::ba::solve::{linearize, solve_damped, Linearization, ObservationJacobians};
use crate::ba::SymbolicBa;
use crate::error::OptimError;
use crate::lm::Damping;

/// Options of [`solve_bal`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalOptions {
    /// Outer iterations (linearisations); each may try several damping values.
    pub max_iterations: usize,
    /// Initial Marquardt damping, relative to the Hessian diagonal (Ceres' default initial
    /// trust region radius 1e4 is `lambda = 1e-4`).
    pub initial_lambda: f64,
    /// Converged once an accepted step lowers the cost by less than this fraction of it
    /// (Ceres' `function_tolerance`).
    pub function_tolerance: f64,
}

impl Default for BalOptions {
    /// 100 iterations, `lambda = 1e-4`, function tolerance `1e-12`: the settings of the
    /// Ceres reference run in `shared/data/ba/REFERENCE.md`.
    fn default() -> Self {
        Self {
            max_iterations: 100,
            initial_lambda: 1e-4,
            function_tolerance: 1e-12,
        }
    }
}

/// Costs (`0.5 * sum |residual|^2`, pixels^2) before and after, and iterations run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalReport {
    /// Cost at the initial estimate.
    pub initial_cost: f64,
    /// Cost at the returned estimate (never above `initial_cost`).
    pub final_cost: f64,
    /// Linearisations performed.
    pub iterations: usize,
    /// True if the function tolerance was met or no damping could lower the cost further;
    /// false if `max_iterations` ran out first.
    pub converged: bool,
}

/// Runs Levenberg-Marquardt on `problem` in place: every camera (9 parameters, updated
/// additively) and every observed point move; nothing is held constant, so the 7-dof
/// similarity gauge is left to the damping, as in the Ceres and gtsam references.
///
/// # Errors
/// Any [`BalProblem::validate`] error; [`OptimError::InvalidInput`] if the initial cost is
/// not finite (a point on a camera plane); [`OptimError::NotPositiveDefinite`] if the damped
/// reduced system could not be factorised at any damping; [`OptimError::Solver`] on solver
/// failure. On error the problem is left at the last accepted estimate.
pub fn solve_bal(problem: &mut BalProblem, options: &BalOptions) -> Result<BalReport, OptimError> {
    problem.validate()?;
    let incidence = problem
        .observations
        .iter()
        .map(|o| (o.camera, o.point))
        .collect();
    let all_free = vec![false; problem.cameras.len()];
    let symbolic =
        SymbolicBa::from_incidence(&all_free, problem.points.len(), incidence, CAMERA_PARAMS)?;
    let mut cost = problem.cost();
    if !cost.is_finite() {
        return Err(OptimError::InvalidInput(
            "initial BAL cost is not finite: a point lies on a camera plane".into(),
        ));
    }
    let mut report = BalReport {
        initial_cost: cost,
        final_cost: cost,
        iterations: 0,
        converged: true,
    };
    let Some(llt) = &symbolic.llt else {
        return Ok(report);
    };
    let mut damping = Damping::new(options.initial_lambda);
    let mut lin = Linearization::<CAMERA_PARAMS>::default();
    let mut v_inv = Vec::new();
    let mut trial_cameras = problem.cameras.clone();
    let mut trial_points = problem.points.clone();
    report.converged = false;
    while report.iterations < options.max_iterations {
        report.iterations += 1;
        let cameras: Vec<SnavelyCamera> = problem.cameras.iter().map(SnavelyCamera::new).collect();
        let observation = |i: usize| {
            let o = &problem.observations[i];
            // None is unreachable at an accepted estimate (its cost is finite).
            let l = cameras[o.camera].linearize(&problem.points[o.point], &o.uv)?;
            Some(ObservationJacobians {
                weight: 1.0,
                e: l.residual,
                d_e_d_camera: l.d_r_d_camera,
                d_e_d_point: l.d_r_d_point,
            })
        };
        linearize(&symbolic, &mut lin, observation);
        let accepted = damping.find_step(
            |lambda| solve_damped(&symbolic, &lin, llt, lambda, &mut v_inv),
            |step| {
                for (f, &c) in symbolic.free_poses.iter().enumerate() {
                    trial_cameras[c] = problem.cameras[c] + step.d_pose[f];
                }
                for (p, &j) in symbolic.opt_points.iter().enumerate() {
                    trial_points[j] = problem.points[j] + step.d_point[p];
                }
                let new_cost = cost_at(&problem.observations, &trial_cameras, &trial_points);
                // lm's model decrease is for sum |r|^2; this cost is half of it.
                (cost - new_cost, 0.5 * step.predicted_decrease, new_cost)
            },
        )?;
        // None: no damping lowers the cost any more.
        report.converged = accepted.is_none_or(|new_cost| {
            std::mem::swap(&mut problem.cameras, &mut trial_cameras);
            std::mem::swap(&mut problem.points, &mut trial_points);
            let small = cost - new_cost <= options.function_tolerance * new_cost;
            cost = new_cost;
            small
        });
        if report.converged {
            break;
        }
    }
    report.final_cost = cost;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bal::{fixtures, read_bal};

    /// Ceres' final cost on problem-21-11315-pre (shared/data/ba/reference.json).
    const CERES_FINAL_COST: f64 = 30378.635796500304;

    #[test]
    fn trafalgar_converges_to_the_ceres_cost_deterministically() {
        let start = read_bal(fixtures::path("problem-21-11315-pre.txt.bz2")).unwrap();
        let mut problem = start.clone();
        let report = solve_bal(&mut problem, &BalOptions::default()).unwrap();
        eprintln!(
            "{report:?}, rel. diff {:e}",
            report.final_cost / CERES_FINAL_COST - 1.0
        );
        assert!(report.converged);
        assert!((report.initial_cost / 4413239.314432217 - 1.0).abs() < 1e-12);
        assert!((report.final_cost / CERES_FINAL_COST - 1.0).abs() < 1e-8);
        assert_eq!(report.final_cost, problem.cost());
        let mut again = start.clone();
        assert_eq!(
            solve_bal(&mut again, &BalOptions::default()).unwrap(),
            report
        );
        assert_eq!(again, problem);
    }

    #[test]
    fn dubrovnik_cost_falls_and_bad_input_is_rejected() {
        let mut problem = read_bal(fixtures::path("dubrovnik-3-7-pre.txt")).unwrap();
        let report = solve_bal(&mut problem, &BalOptions::default()).unwrap();
        // Under-determined (38 residuals, 48 parameters): the optimum is 0; Ceres reaches
        // 1.7e-25 px^2 in 90 iterations (REFERENCE.md).
        assert!(report.converged && report.final_cost < 1e-9, "{report:?}");
        problem.observations[0].point = 7;
        assert!(matches!(
            solve_bal(&mut problem, &BalOptions::default()),
            Err(OptimError::IndexOutOfRange { .. })
        ));
    }
}
