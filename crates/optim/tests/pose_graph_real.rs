//! Pose-graph optimisation on the g2o benchmarks in `shared/data/posegraph` against the
//! gtsam optima of REFERENCE.md (same cost: 0.5 sum r^T Omega r, r = full SE(3) log).
//!
//! Data: `$FERROSLAM_DATA/posegraph`, else `../../../shared/data/posegraph` relative to this
//! crate. Only the two small graphs run here; the big ones are in `benches/pose_graph.rs`.

use ferroslam_optim::pose_graph::{chordal_initialization, edge_residual, read_g2o};
use ferroslam_optim::{optimize_pose_graph, PoseGraphOptions, Se3PoseGraph, SymbolicPoseGraph};
use nalgebra::Isometry3;
use std::path::PathBuf;
use std::time::Instant;

fn data_dir() -> PathBuf {
    std::env::var_os("FERROSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"))
        .join("posegraph")
}

fn load(name: &str) -> Se3PoseGraph {
    let path = data_dir().join(format!("{name}.g2o"));
    read_g2o(&path).unwrap_or_else(|e| panic!("{e} (set FERROSLAM_DATA to the data folder)"))
}

/// The file's edges with the poses of `optimum/<name>_optimum.g2o`.
fn at_optimum(name: &str) -> Se3PoseGraph {
    let mut graph = load(name);
    let optimum = read_g2o(data_dir().join(format!("optimum/{name}_optimum.g2o"))).unwrap();
    assert_eq!(optimum.poses.len(), graph.poses.len());
    graph.poses = optimum.poses;
    graph
}

/// Largest position and rotation difference after removing the gauge (poses relative to
/// pose 0).
fn pose_difference(a: &[Isometry3<f64>], b: &[Isometry3<f64>]) -> (f64, f64) {
    let (a0, b0) = (a[0].inverse(), b[0].inverse());
    a.iter().zip(b).fold((0.0, 0.0), |(dt, dr), (x, y)| {
        let d = (a0 * x).inverse() * (b0 * y);
        (
            f64::max(dt, d.translation.vector.norm()),
            f64::max(dr, d.rotation.angle()),
        )
    })
}

fn check(name: &str, reference_cost: f64, reference_initial: f64) {
    // Evaluating the cost at gtsam's optimum reproduces gtsam's number: same residual,
    // same information ordering.
    let optimum = at_optimum(name);
    let at_reference = optimum.cost();
    assert!(
        (at_reference / reference_cost - 1.0).abs() < 1e-9,
        "{name}: cost at the gtsam optimum {at_reference} vs {reference_cost}"
    );

    let mut graph = load(name);
    let initial = graph.cost();
    assert!(
        (initial / reference_initial - 1.0).abs() < 1e-6,
        "{name}: initial cost {initial} vs gtsam {reference_initial}"
    );
    let start = Instant::now();
    let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
    let report = optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
    let seconds = start.elapsed().as_secs_f64();
    let rel = report.final_cost / reference_cost - 1.0;
    let (dt, dr) = pose_difference(&graph.poses, &optimum.poses);
    eprintln!(
        "{name}: cost {:.6} -> {:.12} (gtsam {reference_cost}, rel {rel:.2e}), {} iterations, \
         {seconds:.3} s; max pose difference to gtsam {dt:.2e} m, {dr:.2e} rad",
        report.initial_cost, report.final_cost, report.iterations
    );
    assert!(report.converged, "{name}: {report:?}");
    assert!(
        rel.abs() < 1e-6,
        "{name}: final cost {} vs {reference_cost}",
        report.final_cost
    );
    // A per-edge check: no residual is far from its value at the reference optimum.
    let worst = graph
        .edges
        .iter()
        .map(|e| (edge_residual(e, &graph.poses) - edge_residual(e, &optimum.poses)).amax())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-4,
        "{name}: residuals differ from gtsam's by up to {worst}"
    );
}

#[test]
fn small_grid_3d_reaches_gtsam_optimum() {
    check("smallGrid3D", 517.92533236, 83894.33344);
}

#[test]
fn parking_garage_reaches_gtsam_optimum() {
    check("parking-garage", 0.634192399632269, 8363.601948120006);
}

#[test]
fn chordal_start_reaches_the_same_optimum() {
    for (name, reference_cost) in [
        ("smallGrid3D", 517.92533236_f64),
        ("parking-garage", 0.634192399632269),
    ] {
        let mut graph = load(name);
        graph.poses = chordal_initialization(&graph).unwrap();
        // Much closer than the file's estimate (gtsam's chordal start: 1594 and 471).
        let start = graph.cost();
        let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
        let report =
            optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
        eprintln!(
            "{name} chordal: cost {start:.6} -> {:.12}, {} iterations",
            report.final_cost, report.iterations
        );
        let from_file = load(name).cost();
        assert!(
            start < from_file / 100.0,
            "{name}: {start} vs file {from_file}"
        );
        assert!(
            (report.final_cost / reference_cost - 1.0).abs() < 1e-6,
            "{name}: {report:?}"
        );
    }
}
