//! Solves g2o pose graphs and prints one JSON object per (file, initialisation) on stdout
//! (used by `benches/pose_graph_compare.py`).
//!
//! `cargo run --release -p ferroslam-optim --example pose_graph_solve -- [--init file|chordal|both] FILE.g2o...`
//!
//! `file` starts from the VERTEX lines, `chordal` from [`chordal_initialization`] (default:
//! both). Fields: `name` (file stem), `init`, `poses`, `edges`, `initial_cost` (at the
//! start of LM), `final_cost` (`0.5 sum r^T Omega r`, gtsam's), `iterations`, `converged`,
//! `read_s` (parsing), `init_s` (chordal initialisation, 0 for `file`), `solve_s` (symbolic
//! analysis plus Levenberg-Marquardt). Errors go to stderr with exit status 1.

use ferroslam_optim::pose_graph::chordal_initialization;
use ferroslam_optim::{
    optimize_pose_graph, read_g2o, OptimError, PoseGraphOptions, SymbolicPoseGraph,
};
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

fn main() -> ExitCode {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut inits = vec!["file", "chordal"];
    if let Some(k) = args.iter().position(|a| a == "--init") {
        let choice = args.get(k + 1).cloned().unwrap_or_default();
        inits = match choice.as_str() {
            "file" => vec!["file"],
            "chordal" => vec!["chordal"],
            "both" => vec!["file", "chordal"],
            _ => {
                eprintln!("--init takes file, chordal or both");
                return ExitCode::FAILURE;
            }
        };
        args.drain(k..k + 2);
    }
    if args.is_empty() {
        eprintln!("usage: pose_graph_solve [--init file|chordal|both] FILE.g2o...");
        return ExitCode::FAILURE;
    }
    for file in &args {
        for init in &inits {
            if let Err(e) = solve(file, init == &"chordal") {
                eprintln!("{file}: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    ExitCode::SUCCESS
}

fn solve(file: &str, chordal: bool) -> Result<(), OptimError> {
    let start = Instant::now();
    let mut graph = read_g2o(file)?;
    let read_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    if chordal {
        graph.poses = chordal_initialization(&graph)?;
    }
    let init_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let symbolic = SymbolicPoseGraph::new(&graph)?;
    let report = optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default())?;
    let solve_s = start.elapsed().as_secs_f64();
    let name = Path::new(file)
        .file_stem()
        .map_or_else(|| file.to_string(), |s| s.to_string_lossy().into_owned());
    println!(
        "{{\"name\": \"{name}\", \"init\": \"{}\", \"poses\": {}, \"edges\": {}, \
         \"initial_cost\": {:e}, \"final_cost\": {:e}, \"iterations\": {}, \"converged\": {}, \
         \"read_s\": {read_s:.6}, \"init_s\": {init_s:.6}, \"solve_s\": {solve_s:.6}}}",
        if chordal { "chordal" } else { "file" },
        graph.poses.len(),
        graph.edges.len(),
        report.initial_cost,
        report.final_cost,
        report.iterations,
        report.converged
    );
    Ok(())
}
