//! What the solver examples share: one solve per file named on the command line.

use std::fmt::Display;
use std::process::ExitCode;

/// Calls `solve` on each command-line argument in turn; the first error goes to stderr, with
/// exit status 1, as does a missing argument (with `usage`).
pub fn solve_each_file<E: Display>(usage: &str, solve: impl Fn(&str) -> Result<(), E>) -> ExitCode {
    let files: Vec<String> = std::env::args().skip(1).collect();
    if files.is_empty() {
        eprintln!("usage: {usage}");
        return ExitCode::FAILURE;
    }
    for file in &files {
        if let Err(e) = solve(file) {
            eprintln!("{file}: {e}");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}
