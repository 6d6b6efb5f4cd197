//! Runs ORB-SLAM's local BA schedule ([`local_bundle_adjust`]) on problems in the text form of
//! [`BaProblem::to_text`] and prints one JSON object per file on stdout (used by
//! `benches/solvers_compare.py`).
//!
//! `cargo run --release -p ferroslam-optim --example local_ba_solve -- FILE...`
//!
//! Fields: `file` (as given), `poses`, `free_poses`, `points`, `observations`,
//! `stereo_observations`, `initial_cost` (robust stage start, Huber) and `final_cost` (plain
//! stage end, its inliers, no kernel), both `0.5 sum inv_sigma2 |e|^2` as gtsam's `error()`,
//! `outliers` (the final classification: ORB-SLAM's chi-square test or behind the camera),
//! `iterations` (both stages), `solve_s` (symbolic analysis plus both stages) and
//! `ms_per_iteration`. Errors go to stderr with exit status 1.

use ferroslam_optim::{local_bundle_adjust, BaProblem, OptimError};
use std::process::ExitCode;
use std::time::Instant;

mod common;

fn main() -> ExitCode {
    common::solve_each_file("local_ba_solve FILE...", solve)
}

fn solve(file: &str) -> Result<(), OptimError> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| OptimError::InvalidInput(format!("cannot read {file}: {e}")))?;
    let mut problem = BaProblem::from_text(&text, file)?;
    let free_poses = problem.pose_fixed.iter().filter(|&&fixed| !fixed).count();
    let (poses, points) = (problem.poses.len(), problem.points.len());
    let observations = problem.observations.len();
    let stereo = problem
        .observations
        .iter()
        .filter(|o| o.is_stereo())
        .count();
    let start = Instant::now();
    let result = local_bundle_adjust(&mut problem)?;
    let solve_s = start.elapsed().as_secs_f64();
    let report = result.report;
    let outliers = result.outlier.iter().filter(|&&o| o).count();
    println!(
        "{{\"file\": {file:?}, \"poses\": {poses}, \"free_poses\": {free_poses}, \
         \"points\": {points}, \"observations\": {observations}, \
         \"stereo_observations\": {stereo}, \
         \"initial_cost\": {:e}, \"final_cost\": {:e}, \"outliers\": {outliers}, \
         \"iterations\": {}, \"solve_s\": {solve_s:.6}, \"ms_per_iteration\": {:.4}}}",
        0.5 * report.initial_cost,
        0.5 * report.final_cost,
        report.iterations,
        1e3 * solve_s / report.iterations.max(1) as f64,
    );
    Ok(())
}
