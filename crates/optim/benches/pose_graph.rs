//! Time to converge on the g2o benchmarks (sphere2500, torus3D, parking-garage), from the
//! file's initial estimate and from the chordal initialisation (included in the timing).
//! torus3D from the file converges to a local minimum (as gtsam's LM does, REFERENCE.md),
//! so it is only timed from the chordal start. Final costs are printed to stderr.
//!
//! Data: `$FERROSLAM_DATA/posegraph`, else `../../../shared/data/posegraph`.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use ferroslam_optim::pose_graph::chordal_initialization;
use ferroslam_optim::{
    optimize_pose_graph, read_g2o, PoseGraphOptions, Se3PoseGraph, SymbolicPoseGraph,
};
use std::path::PathBuf;

fn load(name: &str) -> Se3PoseGraph {
    let dir = std::env::var_os("FERROSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let path = dir.join("posegraph").join(format!("{name}.g2o"));
    read_g2o(&path).unwrap_or_else(|e| panic!("{e} (set FERROSLAM_DATA)"))
}

/// Chordal start (optional) + symbolic analysis + LM; returns (final cost, iterations).
fn solve(mut graph: Se3PoseGraph, chordal: bool) -> (f64, usize) {
    if chordal {
        graph.poses = chordal_initialization(&graph).unwrap();
    }
    let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
    let report = optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
    (report.final_cost, report.iterations)
}

fn pose_graph(c: &mut Criterion) {
    let mut group = c.benchmark_group("pose_graph");
    group.sample_size(10);
    for (name, inits) in [
        ("sphere2500", &[false, true][..]),
        ("parking-garage", &[false, true][..]),
        ("torus3D", &[true][..]),
    ] {
        let graph = load(name);
        for &chordal in inits {
            let label = format!("{name}/{}", if chordal { "chordal" } else { "file" });
            let (cost, iterations) = solve(graph.clone(), chordal);
            eprintln!("{label}: final cost {cost:.10}, {iterations} iterations");
            group.bench_function(&label, |b| {
                b.iter_batched(
                    || graph.clone(),
                    |g| solve(g, chordal),
                    BatchSize::LargeInput,
                )
            });
        }
    }
    group.finish();
}

criterion_group!(benches, pose_graph);
criterion_main!(benches);
