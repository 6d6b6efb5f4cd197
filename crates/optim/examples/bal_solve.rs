//! Solves BAL problems and prints one JSON object per file on stdout (used by
//! `benches/solvers_compare.py`).
//!
//! `cargo run --release -p ferroslam-optim --example bal_solve -- FILE[.bz2]...`
//!
//! Fields: `file` (as given), `cameras`, `points`, `observations`, `initial_cost` and
//! `final_cost` (`0.5 sum |r|^2`, pixels^2), `iterations`, `converged`, `read_s` (reading
//! and decompressing), `solve_s` (symbolic analysis plus Levenberg-Marquardt with
//! [`BalOptions::default`]). Errors go to stderr with exit status 1.

use ferroslam_optim::bal::{read_bal, solve_bal, BalOptions, BalReport};
use ferroslam_optim::OptimError;
use std::process::ExitCode;
use std::time::Instant;

mod common;

fn main() -> ExitCode {
    common::solve_each_file("bal_solve FILE[.bz2]...", solve)
}

fn solve(file: &str) -> Result<(), OptimError> {
    let start = Instant::now();
    let mut problem = read_bal(file)?;
    let read_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let report = solve_bal(&mut problem, &BalOptions::default())?;
    let solve_s = start.elapsed().as_secs_f64();
    let (cameras, points) = (problem.cameras.len(), problem.points.len());
    let observations = problem.observations.len();
    let BalReport {
        initial_cost,
        final_cost,
        iterations,
        converged,
    } = report;
    println!(
        "{{\"file\": {file:?}, \"cameras\": {cameras}, \"points\": {points}, \
         \"observations\": {observations}, \"initial_cost\": {initial_cost:e}, \
         \"final_cost\": {final_cost:e}, \"iterations\": {iterations}, \
         \"converged\": {converged}, \"read_s\": {read_s:.6}, \"solve_s\": {solve_s:.6}}}"
    );
    Ok(())
}
