//! Structure of a pose graph's normal equations, analysed once and reused by every iteration.
//!
//! Unknowns are the free poses, `D` each, in pose order. Block `(a, b)` of the Hessian is
//! non-zero iff `a == b` or an edge joins free poses `a` and `b`. Only the upper triangle is
//! stored (faer reads it as self-adjoint), in CSC with sorted rows: in block column `b` the
//! off-diagonal blocks come first (`D` rows each, in block-row order), then the upper part of
//! the diagonal block (`c + 1` rows in column `c`), so each column's last entry is its
//! diagonal.

use super::group::PoseGroup;
use super::problem::PoseGraph;
use crate::block_pattern::{block_upper_pattern, factorize_upper, number_free_poses};
use crate::error::OptimError;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::SymbolicSparseColMat;
use nalgebra::SMatrix;

/// Where an edge's blocks land: the free indices of its ends and, if both are free and
/// distinct, the slot of the off-diagonal block in block column `max(fi, fj)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct EdgeSlots {
    pub(crate) free_from: Option<usize>,
    pub(crate) free_to: Option<usize>,
    pub(crate) cross_slot: Option<usize>,
}

/// Pattern, ordering and symbolic Cholesky of a pose graph's Hessian. Build it once per
/// structure (same number of poses, fixed flags and edge `(from, to)` pairs) with
/// [`SymbolicPoseGraph::new`] and pass it to every [`super::optimize_pose_graph`] call.
#[derive(Clone, Debug)]
pub struct SymbolicPoseGraph {
    pub(crate) fixed: Vec<bool>,
    pub(crate) incidence: Vec<(usize, usize)>,
    /// Per free pose: the pose index.
    pub(crate) free_poses: Vec<usize>,
    pub(crate) edge_slots: Vec<EdgeSlots>,
    /// Tangent dimension the pattern was built for.
    pub(crate) dim: usize,
    /// Upper-triangular CSC pattern (`dim * free` square).
    pub(crate) pattern: SymbolicSparseColMat<usize>,
    /// Symbolic Cholesky (fill-reducing ordering included), `None` without free poses.
    pub(crate) llt: Option<SymbolicLlt<usize>>,
}

impl SymbolicPoseGraph {
    /// Analyses `graph`'s structure (values are only validated, not used).
    ///
    /// # Errors
    /// Any [`PoseGraph::validate`] error; [`OptimError::Solver`] if faer's symbolic analysis
    /// fails (out of memory).
    pub fn new<G: PoseGroup<D>, const D: usize>(
        graph: &PoseGraph<G, D>,
    ) -> Result<Self, OptimError> {
        graph.validate()?;
        let incidence: Vec<(usize, usize)> = graph.edges.iter().map(|e| (e.from, e.to)).collect();
        Self::from_structure(&graph.fixed, &incidence, D)
    }

    /// The analysis for `dim` unknowns per pose, fixed flags `fixed` and edges `(from, to)`
    /// (indices already checked against `fixed.len()`).
    pub(crate) fn from_structure(
        fixed: &[bool],
        incidence: &[(usize, usize)],
        dim: usize,
    ) -> Result<Self, OptimError> {
        let (free_poses, free_index) = number_free_poses(fixed);
        let nfree = free_poses.len();
        let free_pair = |&(i, j): &(usize, usize)| match (free_index[i], free_index[j]) {
            (Some(a), Some(b)) if a != b => Some((a.min(b), a.max(b))),
            _ => None,
        };
        let mut block_rows: Vec<Vec<usize>> = vec![Vec::new(); nfree];
        for (a, b) in incidence.iter().filter_map(free_pair) {
            block_rows[b].push(a);
        }
        for rows in &mut block_rows {
            rows.sort_unstable();
            rows.dedup();
        }
        let edge_slots = incidence
            .iter()
            .map(|e| EdgeSlots {
                free_from: free_index[e.0],
                free_to: free_index[e.1],
                // Present by construction of block_rows.
                cross_slot: free_pair(e).map(|(a, b)| block_rows[b].binary_search(&a).unwrap_or(0)),
            })
            .collect();

        let above: Vec<&[usize]> = block_rows.iter().map(Vec::as_slice).collect();
        let (pattern, llt) = block_upper_pattern(dim, &above)?;
        Ok(Self {
            fixed: fixed.to_vec(),
            incidence: incidence.to_vec(),
            free_poses,
            edge_slots,
            dim,
            pattern,
            llt,
        })
    }

    /// Number of optimised poses.
    pub fn num_free_poses(&self) -> usize {
        self.free_poses.len()
    }

    /// Stored (upper-triangular) non-zeros of the Hessian.
    pub fn hessian_nnz(&self) -> usize {
        self.pattern.row_idx().len()
    }

    /// True if `graph` has exactly the structure this analysis was built for.
    pub fn matches<G: PoseGroup<D>, const D: usize>(&self, graph: &PoseGraph<G, D>) -> bool {
        self.dim == D
            && graph.fixed == self.fixed
            && graph.poses.len() == self.fixed.len()
            && graph.edges.len() == self.incidence.len()
            && graph
                .edges
                .iter()
                .zip(&self.incidence)
                .all(|(e, &(i, j))| e.from == i && e.to == j)
    }

    /// Index in the CSC values of entry `(r, c)` of block `slot` in block column `b`
    /// (`slot == None`: the diagonal block, `r <= c`).
    pub(crate) fn value_index(&self, b: usize, slot: Option<usize>, r: usize, c: usize) -> usize {
        let col = self.dim * b + c;
        let start = self.pattern.col_ptr()[col];
        match slot {
            Some(s) => start + self.dim * s + r,
            None => self.pattern.col_ptr()[col + 1] - 1 - (c - r),
        }
    }

    /// Adds `m` to block `slot` of block column `col` (`None`: the diagonal block, of which
    /// only the upper triangle is stored). `R` must be the dimension the pattern was built for.
    pub(crate) fn add_block<const R: usize>(
        &self,
        values: &mut [f64],
        col: usize,
        slot: Option<usize>,
        m: &SMatrix<f64, R, R>,
    ) {
        debug_assert_eq!(R, self.dim);
        for c in 0..R {
            let rows = if slot.is_some() { R } else { c + 1 };
            for r in 0..rows {
                values[self.value_index(col, slot, r, c)] += m[(r, c)];
            }
        }
    }

    /// Numeric Cholesky of the matrix with this pattern and `values` (`None` without free
    /// poses).
    ///
    /// # Errors
    /// [`OptimError::NotPositiveDefinite`] on a non-positive pivot, [`OptimError::Solver`]
    /// on any other solver failure.
    pub(crate) fn factorize(&self, values: &[f64]) -> Result<Option<Llt<usize, f64>>, OptimError> {
        let Some(llt) = &self.llt else {
            return Ok(None);
        };
        factorize_upper(&self.pattern, llt, values).map(Some)
    }
}
