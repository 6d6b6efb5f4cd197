//! Visual-inertial local bundle adjustment (ORB-SLAM3 `Optimizer::LocalInertialBA`).
//!
//! Jointly over keyframe states (camera pose `T_c_w`, body velocity `v_w_b`, IMU biases) and
//! map points, [`inertial_bundle_adjust`] minimises
//!
//! ```text
//! sum_obs rho(chi2_reprojection) + sum_edges rho_I(r_I^T Info_I r_I) + sum_edges r_B^T Info_B r_B
//! ```
//!
//! with the reprojection residuals of [`crate::residual`], the preintegrated inertial residual
//! [`ferroslam_imu::InertialFactor`] and the bias random walk [`ferroslam_imu::BiasWalkFactor`]
//! of every [`InertialEdge`]. The body pose of a keyframe is `T_w_b = T_c_w^-1 T_b_c^-1` with
//! the constant camera-to-body extrinsic `T_b_c`.
//!
//! Perturbations: camera poses on the LEFT (`T_c_w <- exp(xi) T_c_w`, `xi = [rho; phi]`, as
//! in visual BA), velocities, biases and points additively.
//!
//! The solver is Levenberg-Marquardt with the points eliminated by a Schur complement and
//! the reduced system over the free keyframe parameters (6 per free pose, 9 per free
//! velocity + biases) solved densely; steps that push an observation behind its camera are
//! rejected.

mod problem;
mod solve;
mod state;

pub use problem::{InertialBaProblem, InertialEdge};

use crate::ba::BaReport;
use crate::error::OptimError;
use solve::{optimize, Layout, Stage};

/// Huber width for the 9-dof inertial residual, `sqrt(16.92)` (ORB-SLAM3's
/// `LocalInertialBA`; 16.92 is the 95% chi-square quantile with 9 degrees of freedom).
pub const HUBER_DELTA_INERTIAL: f64 = 4.113_392_760_240_627;

/// Options of [`inertial_bundle_adjust`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InertialBaOptions {
    /// Iterations of the robust stage: Huber on every visual observation (ORB-SLAM widths)
    /// and on every inertial residual ([`HUBER_DELTA_INERTIAL`]); ORB-SLAM3 runs 10.
    pub robust_iterations: usize,
    /// Iterations of a second stage without kernels over the first stage's visual inliers
    /// (ORB-SLAM2's local BA schedule). ORB-SLAM3's `LocalInertialBA` has none: 0.
    pub plain_iterations: usize,
    /// Initial Marquardt damping, relative to the Hessian diagonal (> 0).
    pub initial_lambda: f64,
    /// A stage stops once an accepted step lowers the cost by less than this fraction (>= 0).
    pub function_tolerance: f64,
}

impl Default for InertialBaOptions {
    /// ORB-SLAM3's schedule: 10 robust iterations, no plain stage; `lambda = 1e-4`,
    /// relative tolerance `1e-5` (as the visual local BA).
    fn default() -> Self {
        Self {
            robust_iterations: 10,
            plain_iterations: 0,
            initial_lambda: 1e-4,
            function_tolerance: 1e-5,
        }
    }
}

/// Result of [`inertial_bundle_adjust`].
#[derive(Clone, Debug, PartialEq)]
pub struct InertialBaResult {
    /// Total cost (visual + inertial + bias walk) at the start of the robust stage (with the
    /// kernels) and at the end of the last stage run (with that stage's kernels, over its
    /// observations); iterations of all stages.
    pub report: BaReport,
    /// Final classification per visual observation: `chi2` above ORB-SLAM's threshold
    /// ([`crate::robust::CHI2_MONO`] / [`crate::robust::CHI2_STEREO`]) or point not in front
    /// of the camera. The caller erases these links from the map, as ORB-SLAM3 does.
    pub outlier: Vec<bool>,
}

/// Visual-inertial local BA in place: `options.robust_iterations` LM iterations with Huber
/// kernels, then (if `options.plain_iterations > 0`) visual observations classified as
/// outliers are dropped and the rest is refined without kernels; finally every visual
/// observation is classified. Poses, velocities, biases and points of `problem` are updated.
///
/// Observations whose point is behind its camera at the start of a stage are left out of
/// it. With nothing free the problem is returned unchanged (the classification still is).
///
/// # Errors
/// [`InertialBaProblem::validate`] errors and [`OptimError::InvalidInput`] for invalid
/// options (nothing is changed); [`OptimError::NotPositiveDefinite`] if the damped reduced
/// system cannot be factorised at any damping (e.g. a free velocity with no inertial edge
/// information, degenerate geometry), in which case the problem keeps the last accepted
/// estimate.
pub fn inertial_bundle_adjust(
    problem: &mut InertialBaProblem,
    options: &InertialBaOptions,
) -> Result<InertialBaResult, OptimError> {
    problem.validate()?;
    let lambda_ok = options.initial_lambda.is_finite() && options.initial_lambda > 0.0;
    let tolerance_ok = options.function_tolerance.is_finite() && options.function_tolerance >= 0.0;
    if !(lambda_ok && tolerance_ok) {
        return Err(OptimError::InvalidInput(format!(
            "initial_lambda = {} must be finite and > 0, function_tolerance = {} finite and >= 0",
            options.initial_lambda, options.function_tolerance
        )));
    }
    let layout = Layout::new(problem);
    let stage = |max_iterations, robust| Stage {
        max_iterations,
        robust,
        initial_lambda: options.initial_lambda,
        function_tolerance: options.function_tolerance,
    };
    let all = vec![true; problem.visual.observations.len()];
    let first = optimize(
        problem,
        &layout,
        &stage(options.robust_iterations, true),
        &all,
    )?;
    let mut report = BaReport {
        initial_cost: first.initial_cost,
        final_cost: first.final_cost,
        iterations: first.iterations,
    };
    if options.plain_iterations > 0 {
        let inlier: Vec<bool> = problem
            .visual
            .classify_outliers()
            .iter()
            .map(|&o| !o)
            .collect();
        let second = optimize(
            problem,
            &layout,
            &stage(options.plain_iterations, false),
            &inlier,
        )?;
        report.final_cost = second.final_cost;
        report.iterations += second.iterations;
    }
    Ok(InertialBaResult {
        report,
        outlier: problem.visual.classify_outliers(),
    })
}
