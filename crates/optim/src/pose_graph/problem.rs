//! A pose graph: poses `X_w_i`, relative measurements `Z_ij` with information, fixed flags.
//!
//! Edge residual (gtsam's `BetweenFactor` on the full group logarithm):
//! `r_ij = Log(Z_ij^-1 X_i^-1 X_j)`, cost `0.5 * sum r^T Omega r`. With left perturbations
//! `X <- exp(d) X` its Jacobians are `dr/dd_j = J_r^-1(r) Ad(X_j^-1)` and `dr/dd_i = -dr/dd_j`.

use super::group::PoseGroup;
use crate::error::OptimError;
use ferroslam_geometry::sim3::Sim3;
use nalgebra::{Isometry3, SMatrix, SVector};

/// One relative measurement between poses `from = i` and `to = j`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseEdge<G, const D: usize> {
    /// Index `i` of the first pose.
    pub from: usize,
    /// Index `j` of the second pose.
    pub to: usize,
    /// Measured `Z_ij ≈ X_i^-1 X_j` (pose of `j` in frame `i`).
    pub measurement: G,
    /// Information (inverse covariance) of the residual, in the group's tangent order
    /// (se(3): `[translation, rotation]`, as g2o files store it). Symmetric PSD.
    pub information: SMatrix<f64, D, D>,
}

/// A pose graph on the group `G` (`D` degrees of freedom).
///
/// Poses map their own frame into the common one (`T_w_i`; for Sim(3), `S_w_i`, the
/// inverse of ORB-SLAM's `S_i_w`). Fixed poses do not move and fix the gauge; with none
/// fixed the problem is singular (and Levenberg-Marquardt damping alone then holds it).
#[derive(Clone, Debug, PartialEq)]
pub struct PoseGraph<G, const D: usize> {
    /// Pose estimates `X_w_i`.
    pub poses: Vec<G>,
    /// `fixed[i]`: pose `i` is held constant.
    pub fixed: Vec<bool>,
    /// Relative measurements.
    pub edges: Vec<PoseEdge<G, D>>,
}

/// SE(3) pose graph (`T_w_i`, 6x6 information in `[rho; phi]` order).
pub type Se3PoseGraph = PoseGraph<Isometry3<f64>, 6>;
/// Sim(3) pose graph (`S_w_i`, 7x7 information in `[rho; phi; sigma]` order).
pub type Sim3PoseGraph = PoseGraph<Sim3, 7>;

/// Largest asymmetry `|Omega - Omega^T|` tolerated, relative to `max |Omega|`.
const SYMMETRY_TOLERANCE: f64 = 1e-9;

impl<G: PoseGroup<D>, const D: usize> PoseGraph<G, D> {
    /// Checks indices, lengths and finiteness; information must be symmetric.
    ///
    /// # Errors
    /// [`OptimError::InvalidInput`] on mismatched `fixed` length, [`OptimError::NonFinite`]
    /// on a non-finite pose or measurement (or a non-positive Sim(3) scale),
    /// [`OptimError::IndexOutOfRange`] for an edge naming a missing pose.
    pub fn validate(&self) -> Result<(), OptimError> {
        if self.fixed.len() != self.poses.len() {
            return Err(OptimError::InvalidInput(format!(
                "pose graph has {} poses but {} fixed flags",
                self.poses.len(),
                self.fixed.len()
            )));
        }
        if let Some(i) = self.poses.iter().position(|p| !p.is_valid()) {
            return Err(OptimError::NonFinite {
                what: "pose",
                index: i,
            });
        }
        let n = self.poses.len();
        for (e, edge) in self.edges.iter().enumerate() {
            for index in [edge.from, edge.to] {
                if index >= n {
                    return Err(OptimError::IndexOutOfRange {
                        observation: e,
                        what: "pose",
                        index,
                        len: n,
                    });
                }
            }
            let info = &edge.information;
            if !edge.measurement.is_valid() || !info.iter().all(|v| v.is_finite()) {
                return Err(OptimError::NonFinite {
                    what: "edge",
                    index: e,
                });
            }
            let scale = info.amax().max(f64::MIN_POSITIVE);
            if (info - info.transpose()).amax() > SYMMETRY_TOLERANCE * scale {
                return Err(OptimError::InvalidInput(format!(
                    "edge {e} ({} -> {}): information matrix is not symmetric",
                    edge.from, edge.to
                )));
            }
        }
        Ok(())
    }

    /// `0.5 * sum r^T Omega r` over all edges, summed in edge order (deterministic).
    pub fn cost(&self) -> f64 {
        cost_at(&self.edges, &self.poses)
    }
}

/// Residual `Log(Z^-1 X_i^-1 X_j)` of `edge` at `poses`.
pub fn edge_residual<G: PoseGroup<D>, const D: usize>(
    edge: &PoseEdge<G, D>,
    poses: &[G],
) -> SVector<f64, D> {
    let xi = &poses[edge.from];
    let xj = &poses[edge.to];
    edge.measurement
        .inverse()
        .compose(&xi.inverse())
        .compose(xj)
        .log()
}

/// Residual and the Jacobian `dr/dd_j` for a left perturbation `X_j <- exp(d_j) X_j`;
/// the Jacobian for `X_i` is its negative.
pub(crate) fn linearize_edge<G: PoseGroup<D>, const D: usize>(
    edge: &PoseEdge<G, D>,
    poses: &[G],
) -> (SVector<f64, D>, SMatrix<f64, D, D>) {
    let r = edge_residual(edge, poses);
    let j = G::right_jacobian_inverse(&r) * poses[edge.to].inverse().adjoint();
    (r, j)
}

pub(crate) fn cost_at<G: PoseGroup<D>, const D: usize>(
    edges: &[PoseEdge<G, D>],
    poses: &[G],
) -> f64 {
    edges
        .iter()
        .map(|e| {
            let r = edge_residual(e, poses);
            0.5 * r.dot(&(e.information * r))
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use ferroslam_geometry::sim3::Vector7;
    use nalgebra::Vector6;

    /// Central differences of the residual under left perturbations of both poses.
    fn check_jacobian<G: PoseGroup<D>, const D: usize>(poses: [G; 2], z: G) {
        let edge = PoseEdge {
            from: 0,
            to: 1,
            measurement: z,
            information: SMatrix::<f64, D, D>::identity(),
        };
        let (_, j) = linearize_edge(&edge, &poses);
        let h = 1e-6;
        for (pose, sign) in [(0usize, -1.0), (1, 1.0)] {
            for k in 0..D {
                let mut d = SVector::<f64, D>::zeros();
                d[k] = h;
                let mut plus = poses;
                plus[pose] = G::exp(&d).compose(&poses[pose]);
                let mut minus = poses;
                minus[pose] = G::exp(&-d).compose(&poses[pose]);
                let numeric =
                    (edge_residual(&edge, &plus) - edge_residual(&edge, &minus)) / (2.0 * h);
                let analytic = j.column(k) * sign;
                assert!(
                    (numeric - analytic).amax() < 1e-7,
                    "pose {pose} column {k}: numeric {numeric} analytic {analytic}"
                );
            }
        }
    }

    #[test]
    fn se3_edge_jacobians_match_central_differences() {
        let a = Vector6::new(1.0, -2.0, 0.5, 0.3, -0.4, 1.2);
        let b = Vector6::new(-0.5, 0.7, 2.0, -1.1, 0.6, 0.2);
        let z = Vector6::new(0.4, 0.3, -0.2, 0.5, 0.1, -0.3);
        check_jacobian::<Isometry3<f64>, 6>(
            [Isometry3::exp(&a), Isometry3::exp(&b)],
            Isometry3::exp(&z),
        );
    }

    #[test]
    fn sim3_edge_jacobians_match_central_differences() {
        let a = Vector7::from([1.0, -2.0, 0.5, 0.3, -0.4, 1.2, 0.3]);
        let b = Vector7::from([-0.5, 0.7, 2.0, -1.1, 0.6, 0.2, -0.4]);
        // A residual of 0.3 rad, 0.5 m, 20 % scale: the truncated series is exact to ~1e-10.
        let z = Vector7::from([0.4, 0.3, -0.2, 0.2, 0.1, -0.2, 0.2]);
        let (a, b) = (Sim3::exp(&a), Sim3::exp(&b));
        check_jacobian::<Sim3, 7>([a, b], a.inverse() * b * Sim3::exp(&z));
    }

    #[test]
    fn validate_rejects_bad_indices_and_asymmetric_information() {
        let mut g = Se3PoseGraph {
            poses: vec![Isometry3::identity(); 2],
            fixed: vec![true, false],
            edges: vec![PoseEdge {
                from: 0,
                to: 2,
                measurement: Isometry3::identity(),
                information: SMatrix::identity(),
            }],
        };
        assert!(matches!(
            g.validate(),
            Err(OptimError::IndexOutOfRange { index: 2, .. })
        ));
        g.edges[0].to = 1;
        g.edges[0].information[(0, 1)] = 1.0;
        assert!(matches!(g.validate(), Err(OptimError::InvalidInput(_))));
        g.edges[0].information[(1, 0)] = 1.0;
        assert!(g.validate().is_ok());
        g.fixed.pop();
        assert!(matches!(g.validate(), Err(OptimError::InvalidInput(_))));
    }
}
