//! BAL problem-21-11315 (Trafalgar): a full Levenberg-Marquardt solve from the file's start
//! (symbolic analysis included) and a single iteration, whose time is the per-iteration
//! cost. The full solve's final cost and iteration count are printed to stderr.
//!
//! Data: `$FERROSLAM_DATA/ba`, else `../../../shared/data/ba`.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use ferroslam_optim::bal::{read_bal, solve_bal, BalOptions, BalProblem};
use std::path::PathBuf;

const FILE: &str = "problem-21-11315-pre.txt.bz2";

fn load() -> BalProblem {
    let dir = std::env::var_os("FERROSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    read_bal(dir.join("ba").join(FILE)).unwrap_or_else(|e| panic!("{e} (set FERROSLAM_DATA)"))
}

fn bal(c: &mut Criterion) {
    let problem = load();
    let mut group = c.benchmark_group("bal");
    group.sample_size(10);
    let full = BalOptions::default();
    let report = solve_bal(&mut problem.clone(), &full).unwrap();
    eprintln!(
        "{FILE}: cost {:.6} -> {:.10}, {} iterations, converged {}",
        report.initial_cost, report.final_cost, report.iterations, report.converged
    );
    let one = BalOptions {
        max_iterations: 1,
        ..full
    };
    for (label, options) in [("solve", full), ("one_iteration", one)] {
        group.bench_function(label, |b| {
            b.iter_batched(
                || problem.clone(),
                |mut p| solve_bal(&mut p, &options).unwrap(),
                BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, bal);
criterion_main!(benches);
