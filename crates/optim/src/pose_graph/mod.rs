//! Pose-graph optimisation on SE(3) and Sim(3): g2o benchmarks and ORB-SLAM's essential
//! graph after a loop closure.
//!
//! A [`PoseGraph`] holds poses `X_w_i` (frame `i` into the common frame `w`), relative
//! measurements `Z_ij ≈ X_i^-1 X_j` with information matrices, and fixed flags (the gauge).
//! The cost is gtsam's `BetweenFactor` cost `0.5 * sum r^T Omega r` with
//! `r = Log(Z_ij^-1 X_i^-1 X_j)`, the full group logarithm. [`SymbolicPoseGraph`] analyses
//! the sparsity once (faer's symbolic Cholesky with its fill-reducing ordering) and
//! [`optimize_pose_graph`] runs Levenberg-Marquardt with analytic Jacobians on it. Both are
//! generic over the group through [`PoseGroup`], implemented for `Isometry3<f64>` (6 dof)
//! and [`ferroslam_geometry::sim3::Sim3`] (7 dof). [`chordal_initialization`] gives SE(3)
//! graphs a starting point in the global basin when odometry alone would not. For ORB-SLAM's `S_i_w` keyframe poses,
//! store `X_i = S_i_w^-1` and `Z_ij = S_i_w S_j_w^-1`.

mod chordal;
mod g2o;
mod group;
mod problem;
mod solve;
mod symbolic;

pub use chordal::chordal_initialization;
pub use g2o::{parse_g2o, read_g2o};
pub use group::{bernoulli_right_jacobian_inverse, PoseGroup};
pub use problem::{edge_residual, PoseEdge, PoseGraph, Se3PoseGraph, Sim3PoseGraph};
pub use solve::{optimize_pose_graph, PoseGraphOptions, PoseGraphReport};
pub use symbolic::SymbolicPoseGraph;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::OptimError;
    use ferroslam_geometry::sim3::{Sim3, Vector7};
    use nalgebra::{Isometry3, SMatrix, Translation3, UnitQuaternion, Vector3};

    const N: usize = 24;

    /// Ground truth of a monocular loop: keyframes on a 5 m circle (heading along it, a
    /// little height wiggle) whose local map scale drifts by 3 % per keyframe, as
    /// `S_w_i = [s_i R_i | p_i]` with `s_i = exp(-0.03 i)`.
    fn truth() -> Vec<Sim3> {
        (0..N)
            .map(|i| {
                let theta = std::f64::consts::TAU * i as f64 / N as f64;
                Sim3 {
                    rotation: UnitQuaternion::from_euler_angles(0.05 * theta.sin(), 0.0, theta),
                    translation: Vector3::new(
                        5.0 * theta.cos(),
                        5.0 * theta.sin(),
                        0.3 * (3.0 * theta).sin(),
                    ),
                    scale: (-0.03 * i as f64).exp(),
                }
            })
            .collect()
    }

    /// Odometry (i, i+1), a few covisibility edges (i, i+2) and the loop edge (N-1, 0),
    /// all measured exactly from the truth; the initial estimate chains the odometry with
    /// the scale dropped, like a monocular tracker that never sees its drift.
    fn drifted_loop() -> (Sim3PoseGraph, Vec<Sim3>) {
        let gt = truth();
        let edge = |i: usize, j: usize| PoseEdge {
            from: i,
            to: j,
            measurement: gt[i].inverse() * gt[j],
            information: SMatrix::<f64, 7, 7>::identity(),
        };
        let mut edges: Vec<_> = (0..N - 1).map(|i| edge(i, i + 1)).collect();
        edges.extend((0..N - 2).step_by(5).map(|i| edge(i, i + 2)));
        edges.push(edge(N - 1, 0));
        let mut poses = vec![gt[0]];
        for i in 0..N - 1 {
            let step = Sim3 {
                scale: 1.0,
                ..edges[i].measurement
            };
            poses.push(poses[i] * step);
        }
        let mut fixed = vec![false; N];
        fixed[0] = true;
        (
            Sim3PoseGraph {
                poses,
                fixed,
                edges,
            },
            gt,
        )
    }

    fn max_position_error(poses: &[Sim3], gt: &[Sim3]) -> f64 {
        poses
            .iter()
            .zip(gt)
            .map(|(p, g)| (p.translation - g.translation).norm())
            .fold(0.0, f64::max)
    }

    #[test]
    fn sim3_loop_closure_corrects_scale_drift() {
        let (mut graph, gt) = drifted_loop();
        let before = max_position_error(&graph.poses, &gt);
        assert!(before > 3.0, "drift too small to test: {before}");
        let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
        let report =
            optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
        assert!(report.converged);
        assert!(report.final_cost < 1e-16, "{report:?}");
        assert!(max_position_error(&graph.poses, &gt) < 1e-7);
        for (p, g) in graph.poses.iter().zip(&gt) {
            assert!((p.scale / g.scale - 1.0).abs() < 1e-8);
            assert!(p.rotation.angle_to(&g.rotation) < 1e-8);
        }
    }

    #[test]
    fn sim3_fixed_vertices_stay_put_and_se3_cannot_fix_scale() {
        // ORB-SLAM fixes the loop keyframe; fix a second vertex at its true value.
        let (mut graph, gt) = drifted_loop();
        graph.fixed[N / 2] = true;
        graph.poses[N / 2] = gt[N / 2];
        let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
        optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
        assert_eq!(graph.poses[N / 2], gt[N / 2]);
        assert!(max_position_error(&graph.poses, &gt) < 1e-7);

        // The same loop as an SE(3) graph (scales dropped) closes, but with a residual
        // error: rigid edges cannot absorb a scale drift.
        let (sim, gt) = drifted_loop();
        let to_iso =
            |s: &Sim3| Isometry3::from_parts(Translation3::from(s.translation), s.rotation);
        let mut se3 = Se3PoseGraph {
            poses: sim.poses.iter().map(to_iso).collect(),
            fixed: sim.fixed.clone(),
            edges: sim
                .edges
                .iter()
                .map(|e| PoseEdge {
                    from: e.from,
                    to: e.to,
                    measurement: to_iso(&e.measurement),
                    information: SMatrix::<f64, 6, 6>::identity(),
                })
                .collect(),
        };
        let symbolic = SymbolicPoseGraph::new(&se3).unwrap();
        let report =
            optimize_pose_graph(&mut se3, &symbolic, &PoseGraphOptions::default()).unwrap();
        assert!(report.final_cost > 1e-3, "{report:?}");
        let err = se3
            .poses
            .iter()
            .zip(&gt)
            .map(|(p, g)| (p.translation.vector - g.translation).norm())
            .fold(0.0, f64::max);
        assert!(err > 0.5, "{err}");
    }

    #[test]
    fn noisy_sim3_loop_converges_from_drift_to_a_stationary_point() {
        // Perturbed measurements: no exact answer, but LM must still converge and lower the
        // cost, and the truth must stay close.
        let (mut graph, gt) = drifted_loop();
        for (k, e) in graph.edges.iter_mut().enumerate() {
            let t = k as f64;
            let noise = Vector7::from_fn(|r, _| 1e-3 * ((t * 7.3 + r as f64 * 1.9).sin()));
            e.measurement = Sim3::exp(&noise) * e.measurement;
        }
        let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
        let report =
            optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
        assert!(report.converged && report.final_cost < 1e-4, "{report:?}");
        assert!(max_position_error(&graph.poses, &gt) < 0.05);
    }

    #[test]
    fn structure_changes_and_fully_fixed_graphs_are_handled() {
        let (mut graph, _) = drifted_loop();
        let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
        graph.edges.pop();
        assert_eq!(
            optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()),
            Err(OptimError::StructureMismatch)
        );
        graph.fixed = vec![true; N];
        let before = graph.clone();
        let symbolic = SymbolicPoseGraph::new(&graph).unwrap();
        let report =
            optimize_pose_graph(&mut graph, &symbolic, &PoseGraphOptions::default()).unwrap();
        assert_eq!(report.iterations, 0);
        assert_eq!(graph, before);
        graph.poses[3].scale = -1.0;
        assert!(matches!(
            SymbolicPoseGraph::new(&graph),
            Err(OptimError::NonFinite {
                what: "pose",
                index: 3
            })
        ));
    }
}
