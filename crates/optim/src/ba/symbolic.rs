//! Structure of a bundle adjustment, analysed once and reused by every iteration.
//!
//! Unknowns are ordered free poses first (6 each, in pose order) and optimised points
//! (3 each). Eliminating the points leaves the reduced camera system
//! `S = Hcc - Hcp Hpp^-1 Hpc` over the free poses, whose block `(a, b)` is non-zero iff
//! `a == b` or poses `a` and `b` co-observe an optimised point. Only the upper triangle is
//! stored (faer reads it as self-adjoint), in CSC with sorted rows: in block column `b` the
//! off-diagonal blocks come first (6 rows each, in block-row order), then the upper part of
//! the diagonal block (`c + 1` rows in column `c`).

use super::csr::Csr;
use super::problem::BaProblem;
use crate::block_pattern::block_upper_pattern;
use crate::error::OptimError;
use faer::sparse::linalg::solvers::SymbolicLlt;
use faer::sparse::SymbolicSparseColMat;

/// One term `-Y_a W_b^T` of the Schur complement, added to block `slot` of its block
/// column: `obs_a` and `obs_b` see the same point from free poses `a <= b`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SchurTerm {
    pub(crate) slot: usize,
    pub(crate) obs_a: usize,
    pub(crate) obs_b: usize,
}

/// Pattern, ordering and symbolic Cholesky of a problem's reduced camera system, plus the
/// incidence lists the numeric phase walks. Build it once per structure (same poses, fixed
/// flags, points and observation `(pose, point)` pairs) with [`SymbolicBa::new`] and pass it
/// to every [`super::bundle_adjust`] call; values may change freely in between.
#[derive(Clone, Debug)]
pub struct SymbolicBa {
    pub(crate) pose_fixed: Vec<bool>,
    pub(crate) num_points: usize,
    pub(crate) incidence: Vec<(usize, usize)>,
    /// Per pose: its index among the free poses.
    pub(crate) free_index: Vec<Option<usize>>,
    /// Per free pose: the pose index.
    pub(crate) free_poses: Vec<usize>,
    /// Per point: its index among the optimised points.
    pub(crate) point_index: Vec<Option<usize>>,
    /// Per optimised point: the point index.
    pub(crate) opt_points: Vec<usize>,
    /// Per optimised point: all its observations.
    pub(crate) point_obs: Csr<usize>,
    /// Per free pose: all its observations.
    pub(crate) pose_obs: Csr<usize>,
    /// Per free pose (block column): Schur terms landing in it.
    pub(crate) schur_terms: Csr<SchurTerm>,
    /// Per block column: number of blocks (off-diagonal ones + the diagonal).
    pub(crate) blocks_in_column: Vec<usize>,
    /// Upper-triangular CSC pattern of the reduced camera system (`6 * free` square).
    pub(crate) pattern: SymbolicSparseColMat<usize>,
    /// Symbolic Cholesky (fill-reducing ordering included), `None` without free poses.
    pub(crate) llt: Option<SymbolicLlt<usize>>,
}

impl SymbolicBa {
    /// Analyses `problem`'s structure (values are only validated, not used).
    ///
    /// # Errors
    /// Any [`BaProblem::validate`] error; [`OptimError::Solver`] if faer's symbolic analysis
    /// fails (out of memory).
    pub fn new(problem: &BaProblem) -> Result<Self, OptimError> {
        problem.validate()?;
        let obs = &problem.observations;
        let mut free_poses = Vec::new();
        let free_index: Vec<Option<usize>> = problem
            .pose_fixed
            .iter()
            .enumerate()
            .map(|(i, &fixed)| {
                (!fixed).then(|| {
                    free_poses.push(i);
                    free_poses.len() - 1
                })
            })
            .collect();
        let mut seen_by_free = vec![false; problem.points.len()];
        for o in obs {
            if free_index[o.pose].is_some() {
                seen_by_free[o.point] = true;
            }
        }
        let mut opt_points = Vec::new();
        let point_index: Vec<Option<usize>> = seen_by_free
            .iter()
            .enumerate()
            .map(|(j, &seen)| {
                seen.then(|| {
                    opt_points.push(j);
                    opt_points.len() - 1
                })
            })
            .collect();
        let point_obs = Csr::from_pairs(
            opt_points.len(),
            obs.iter()
                .enumerate()
                .filter_map(|(i, o)| point_index[o.point].map(|p| (p, i))),
        );
        let pose_obs = Csr::from_pairs(
            free_poses.len(),
            obs.iter()
                .enumerate()
                .filter_map(|(i, o)| free_index[o.pose].map(|f| (f, i))),
        );

        // Block pattern: per block column b, the sorted block rows a <= b.
        let nfree = free_poses.len();
        let mut block_rows: Vec<Vec<usize>> = (0..nfree).map(|b| vec![b]).collect();
        let free_obs_of_point = |p: usize| {
            point_obs
                .row(p)
                .iter()
                .filter_map(|&i| free_index[obs[i].pose].map(|f| (f, i)))
        };
        for p in 0..opt_points.len() {
            for (fa, _) in free_obs_of_point(p) {
                for (fb, _) in free_obs_of_point(p) {
                    if fa < fb {
                        block_rows[fb].push(fa);
                    }
                }
            }
        }
        for rows in &mut block_rows {
            rows.sort_unstable();
            rows.dedup();
        }
        let mut terms = Vec::new();
        for p in 0..opt_points.len() {
            for (fa, obs_a) in free_obs_of_point(p) {
                for (fb, obs_b) in free_obs_of_point(p) {
                    if fa <= fb {
                        // Present by construction of block_rows.
                        let slot = block_rows[fb].binary_search(&fa).unwrap_or(0);
                        terms.push((fb, SchurTerm { slot, obs_a, obs_b }));
                    }
                }
            }
        }
        let schur_terms = Csr::from_pairs(nfree, terms);

        // block_rows[b] ends with b itself: the diagonal block.
        let above: Vec<&[usize]> = block_rows.iter().map(|r| &r[..r.len() - 1]).collect();
        let (pattern, llt) = block_upper_pattern(6, &above)?;
        Ok(Self {
            pose_fixed: problem.pose_fixed.clone(),
            num_points: problem.points.len(),
            incidence: obs.iter().map(|o| (o.pose, o.point)).collect(),
            free_index,
            free_poses,
            point_index,
            opt_points,
            point_obs,
            pose_obs,
            schur_terms,
            blocks_in_column: block_rows.iter().map(Vec::len).collect(),
            pattern,
            llt,
        })
    }

    /// Number of optimised poses.
    pub fn num_free_poses(&self) -> usize {
        self.free_poses.len()
    }

    /// Number of optimised points (those observed by at least one free pose).
    pub fn num_optimized_points(&self) -> usize {
        self.opt_points.len()
    }

    /// Stored (upper-triangular) non-zeros of the reduced camera system.
    pub fn reduced_system_nnz(&self) -> usize {
        self.pattern.row_idx().len()
    }

    /// True if `problem` has exactly the structure this analysis was built for.
    pub fn matches(&self, problem: &BaProblem) -> bool {
        problem.pose_fixed == self.pose_fixed
            && problem.poses.len() == self.pose_fixed.len()
            && problem.points.len() == self.num_points
            && problem.observations.len() == self.incidence.len()
            && problem
                .observations
                .iter()
                .zip(&self.incidence)
                .all(|(o, &(c, p))| o.pose == c && o.point == p)
    }
}
