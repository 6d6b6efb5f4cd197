//! Chordal initialisation of an SE(3) pose graph (Carlone et al., "Initialization
//! techniques for 3D SLAM", ICRA 2015).
//!
//! Rotations first: minimise `sum w_ij |R_j - R_i Z_ij|_F^2` over unconstrained 3x3
//! matrices (fixed poses keep theirs), a linear least-squares problem whose three rows
//! decouple into one sparse system with three right-hand sides, then project each result
//! onto SO(3). Translations next, with those rotations: minimise
//! `sum w_ij |t_j - t_i - R_i t_ij|^2`, linear again. Weights are isotropic approximations
//! of the information: `w = trace(block) / 3` of its rotation or translation block.
//! Levenberg-Marquardt from this estimate avoids the local minima that odometry-style
//! initial estimates can lead into (torus3D).

use super::problem::Se3PoseGraph;
use super::symbolic::SymbolicPoseGraph;
use crate::error::OptimError;
use faer::linalg::solvers::Solve;
use faer::Mat;
use ferroslam_geometry::se3::{ROT, TRANS};
use nalgebra::{Isometry3, Matrix3, Rotation3, SMatrix, Translation3, UnitQuaternion};

/// One linear block equation `a_i x_i + a_j x_j ≈ c` with weight `w`; `x` are 3 x `M`.
struct BlockEquation<const M: usize> {
    w: f64,
    a_from: Matrix3<f64>,
    a_to: Matrix3<f64>,
    c: SMatrix<f64, 3, M>,
}

/// Chordal estimate of all poses of `graph` (fixed poses keep their values).
///
/// # Errors
/// Any [`Se3PoseGraph::validate`] error; [`OptimError::InvalidInput`] if no pose is fixed
/// (the linear systems would be singular); [`OptimError::NotPositiveDefinite`] if a free
/// pose is not connected to a fixed one; [`OptimError::Solver`] on solver failure.
pub fn chordal_initialization(graph: &Se3PoseGraph) -> Result<Vec<Isometry3<f64>>, OptimError> {
    graph.validate()?;
    if !graph.fixed.iter().any(|&f| f) {
        return Err(OptimError::InvalidInput(
            "chordal initialisation needs at least one fixed pose (the gauge)".into(),
        ));
    }
    let incidence: Vec<(usize, usize)> = graph.edges.iter().map(|e| (e.from, e.to)).collect();
    let sym = SymbolicPoseGraph::from_structure(&graph.fixed, &incidence, 3)?;
    let trace3 = |m: nalgebra::Matrix3<f64>| m.trace() / 3.0;

    // Unknown R_i^T: residual R_j^T - Z^T R_i^T = (R_j - R_i Z)^T.
    let rotation_eqs: Vec<BlockEquation<3>> = graph
        .edges
        .iter()
        .map(|e| BlockEquation {
            w: trace3(
                e.information
                    .fixed_view::<3, 3>(ROT.start, ROT.start)
                    .into_owned(),
            ),
            a_from: -e
                .measurement
                .rotation
                .to_rotation_matrix()
                .into_inner()
                .transpose(),
            a_to: Matrix3::identity(),
            c: Matrix3::zeros(),
        })
        .collect();
    let fixed_rt: Vec<Matrix3<f64>> = graph
        .poses
        .iter()
        .map(|p| p.rotation.to_rotation_matrix().into_inner().transpose())
        .collect();
    let rt = solve_blocks(&sym, &incidence, &rotation_eqs, &fixed_rt)?;
    let rotations: Vec<UnitQuaternion<f64>> = rt
        .iter()
        .zip(&graph.poses)
        .zip(&graph.fixed)
        .map(|((m, p), &fixed)| {
            if fixed {
                p.rotation
            } else {
                project_to_so3(&m.transpose())
            }
        })
        .collect();

    // Unknown t_i: residual t_j - t_i - R_i t_ij.
    let translation_eqs: Vec<BlockEquation<1>> = graph
        .edges
        .iter()
        .map(|e| BlockEquation {
            w: trace3(
                e.information
                    .fixed_view::<3, 3>(TRANS.start, TRANS.start)
                    .into_owned(),
            ),
            a_from: -Matrix3::identity(),
            a_to: Matrix3::identity(),
            c: rotations[e.from] * e.measurement.translation.vector,
        })
        .collect();
    let fixed_t: Vec<_> = graph.poses.iter().map(|p| p.translation.vector).collect();
    let t = solve_blocks(&sym, &incidence, &translation_eqs, &fixed_t)?;
    Ok(t.iter()
        .zip(rotations)
        .map(|(t, r)| Isometry3::from_parts(Translation3::from(*t), r))
        .collect())
}

/// Least squares `min sum w |a_i x_i + a_j x_j - c|^2` over the free `x` (fixed ones taken
/// from `fixed_values`), by sparse Cholesky on `sym` (built with 3 unknowns per pose).
fn solve_blocks<const M: usize>(
    sym: &SymbolicPoseGraph,
    incidence: &[(usize, usize)],
    equations: &[BlockEquation<M>],
    fixed_values: &[SMatrix<f64, 3, M>],
) -> Result<Vec<SMatrix<f64, 3, M>>, OptimError> {
    let mut values = vec![0.0; sym.pattern.row_idx().len()];
    let mut rhs = vec![SMatrix::<f64, 3, M>::zeros(); sym.free_poses.len()];
    for ((eq, s), &(i, j)) in equations.iter().zip(&sym.edge_slots).zip(incidence) {
        if i == j {
            continue;
        }
        // Fixed ends move to the right-hand side.
        let mut c = eq.c;
        if s.free_from.is_none() {
            c -= eq.a_from * fixed_values[i];
        }
        if s.free_to.is_none() {
            c -= eq.a_to * fixed_values[j];
        }
        for (free, a) in [(s.free_from, &eq.a_from), (s.free_to, &eq.a_to)] {
            if let Some(f) = free {
                sym.add_block(&mut values, f, None, &(a.transpose() * a * eq.w));
                rhs[f] += a.transpose() * c * eq.w;
            }
        }
        if let (Some(slot), Some(fi), Some(fj)) = (s.cross_slot, s.free_from, s.free_to) {
            // Stored block (min, max) of the symmetric matrix.
            let block = if fi < fj {
                eq.a_from.transpose() * eq.a_to
            } else {
                eq.a_to.transpose() * eq.a_from
            };
            sym.add_block(&mut values, fi.max(fj), Some(slot), &(block * eq.w));
        }
    }
    let Some(factor) = sym.factorize(&values)? else {
        return Ok(fixed_values.to_vec());
    };
    let mut x = Mat::<f64>::from_fn(3 * rhs.len(), M, |r, k| rhs[r / 3][(r % 3, k)]);
    factor.solve_in_place(x.as_mut());
    let mut out = fixed_values.to_vec();
    for (f, &pose) in sym.free_poses.iter().enumerate() {
        out[pose] = SMatrix::from_fn(|r, k| x[(3 * f + r, k)]);
        if !out[pose].iter().all(|v| v.is_finite()) {
            return Err(OptimError::NotPositiveDefinite { column: 3 * f });
        }
    }
    Ok(out)
}

/// Nearest rotation in the Frobenius norm (SVD, determinant forced to +1).
fn project_to_so3(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return UnitQuaternion::identity();
    };
    let d = (u * v_t).determinant().signum();
    let r = u * Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, d)) * v_t;
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose_graph::PoseEdge;
    use ferroslam_geometry::se3;
    use nalgebra::Vector6;

    #[test]
    fn recovers_a_consistent_graph_from_a_bad_start() {
        let truth: Vec<Isometry3<f64>> = (0..12)
            .map(|i| {
                let t = i as f64;
                se3::exp(&Vector6::new(
                    t.cos(),
                    0.3 * t,
                    t.sin(),
                    0.4 * t,
                    -0.2 * t,
                    0.7 * t,
                ))
            })
            .collect();
        let mut edges = Vec::new();
        for i in 0..12 {
            for j in [i + 1, i + 5] {
                if j < 12 {
                    edges.push(PoseEdge {
                        from: i,
                        to: j,
                        measurement: truth[i].inverse() * truth[j],
                        information: SMatrix::<f64, 6, 6>::identity() * 4.0,
                    });
                }
            }
        }
        let mut fixed = vec![false; 12];
        fixed[0] = true;
        let mut poses = vec![Isometry3::identity(); 12];
        poses[0] = truth[0];
        let graph = Se3PoseGraph {
            poses,
            fixed,
            edges,
        };
        let est = chordal_initialization(&graph).unwrap();
        for (e, t) in est.iter().zip(&truth) {
            assert!(se3::log(&(e.inverse() * t)).amax() < 1e-9);
        }
        let free = Se3PoseGraph {
            fixed: vec![false; 12],
            ..graph
        };
        assert!(matches!(
            chordal_initialization(&free),
            Err(OptimError::InvalidInput(_))
        ));
    }
}
