//! ORB-SLAM's local bundle adjustment schedule (`Optimizer::LocalBundleAdjustment`).

use super::problem::BaProblem;
use super::solve::{bundle_adjust_masked, BaOptions, BaReport};
use super::symbolic::SymbolicBa;
use crate::error::OptimError;

/// Iterations of the first, robust (Huber) stage: ORB-SLAM's 5, enough for the kernel to
/// tell outliers apart before they are dropped (not an option: every recorded result of the
/// real-data matrix rests on this schedule).
pub const LOCAL_BA_ROBUST_ITERATIONS: usize = 5;
/// Iterations of the second stage, plain least squares over the inliers of the first:
/// ORB-SLAM's 10, cut short by [`LOCAL_BA_FUNCTION_TOLERANCE`] once the cost settles.
pub const LOCAL_BA_PLAIN_ITERATIONS: usize = 10;

/// Relative cost decrease below which a stage stops early (g2o stops once no iteration
/// improves; ORB-SLAM's fixed counts otherwise spend half the plain stage sliding
/// low-parallax points along their rays, shifting poses by a fraction of a millimetre).
const LOCAL_BA_FUNCTION_TOLERANCE: f64 = 1e-5;

/// Result of [`local_bundle_adjust`].
#[derive(Clone, Debug, PartialEq)]
pub struct LocalBaResult {
    /// `initial_cost` of the robust stage (all observations, Huber), `final_cost` of the plain
    /// stage (first-stage inliers, no kernel), iterations of both stages.
    pub report: BaReport,
    /// Final classification per observation: `chi2` above the ORB-SLAM threshold or point not
    /// in front of the camera. The caller erases these links from the map, as ORB-SLAM does.
    pub outlier: Vec<bool>,
}

/// Local BA in place: [`LOCAL_BA_ROBUST_ITERATIONS`] Huber iterations over all observations,
/// then observations with `chi2` above threshold or behind their camera are dropped and
/// [`LOCAL_BA_PLAIN_ITERATIONS`] iterations run without kernel; finally every observation is
/// classified. Either stage stops early once an iteration lowers the cost by less than a
/// relative `1e-5`. The symbolic analysis is built once and shared by both stages. Runs inside
/// a rayon pool (see [`super::bundle_adjust`]).
///
/// With zero free poses or zero observations nothing moves (the classification is still
/// returned). Points with no observation by a free pose are not optimised.
///
/// # Errors
/// As [`SymbolicBa::new`] and [`super::bundle_adjust`].
pub fn local_bundle_adjust(problem: &mut BaProblem) -> Result<LocalBaResult, OptimError> {
    rayon::scope(|_| local_bundle_adjust_in_pool(problem))
}

fn local_bundle_adjust_in_pool(problem: &mut BaProblem) -> Result<LocalBaResult, OptimError> {
    let symbolic = SymbolicBa::new(problem)?;
    let robust = BaOptions {
        max_iterations: LOCAL_BA_ROBUST_ITERATIONS,
        robust: true,
        function_tolerance: LOCAL_BA_FUNCTION_TOLERANCE,
        ..BaOptions::default()
    };
    let all = vec![true; problem.observations.len()];
    let first = bundle_adjust_masked(problem, &symbolic, &robust, &all)?;
    let inlier: Vec<bool> = problem.classify_outliers().iter().map(|&o| !o).collect();
    let plain = BaOptions {
        max_iterations: LOCAL_BA_PLAIN_ITERATIONS,
        robust: false,
        function_tolerance: LOCAL_BA_FUNCTION_TOLERANCE,
        ..BaOptions::default()
    };
    let second = bundle_adjust_masked(problem, &symbolic, &plain, &inlier)?;
    Ok(LocalBaResult {
        report: BaReport {
            initial_cost: first.initial_cost,
            final_cost: second.final_cost,
            iterations: first.iterations + second.iterations,
        },
        outlier: problem.classify_outliers(),
    })
}
