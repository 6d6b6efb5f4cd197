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
use crate::block_pattern::{block_upper_pattern, number_free_poses};
use crate::error::OptimError;
use faer::sparse::linalg::solvers::SymbolicLlt;
use faer::sparse::SymbolicSparseColMat;

/// One term `-Y_a W_b^T` of the Schur complement of a point: its observations at positions
/// `a` and `b` of its [`SymbolicBa::point_obs`] row come from free poses `fa <= fb`; the
/// term lands in block `slot` of block column `column = fb` (`diagonal` iff `fa == fb`).
/// 32-bit fields (poses and a point's observations number far fewer than 2^32) halve the
/// list the numeric phase walks every iteration.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SchurTerm {
    pub(crate) column: u32,
    pub(crate) slot: u32,
    pub(crate) diagonal: bool,
    pub(crate) a: u32,
    pub(crate) b: u32,
}

/// Most point chunks the numeric phase splits the points into (each chunk accumulates its
/// own copy of the pose blocks, summed in chunk order so results do not depend on threads).
const MAX_CHUNKS: usize = 16;
/// Fewest points per chunk (smaller chunks cost more in partial sums than they gain).
const MIN_CHUNK_POINTS: usize = 64;
/// Most `f64`s all chunks' partial reduced systems may take together (32 MiB).
const PARTIAL_BUDGET: usize = 1 << 22;

/// Pattern, ordering and symbolic Cholesky of a problem's reduced camera system, plus the
/// incidence lists the numeric phase walks. Build it once per structure (same poses, fixed
/// flags, points and observation `(pose, point)` pairs) with [`SymbolicBa::new`] and pass it
/// to every [`super::bundle_adjust`] call; values may change freely in between.
#[derive(Clone, Debug)]
pub struct SymbolicBa {
    pub(crate) pose_fixed: Vec<bool>,
    pub(crate) num_points: usize,
    pub(crate) incidence: Vec<(usize, usize)>,
    /// Per free pose: the pose index.
    pub(crate) free_poses: Vec<usize>,
    /// Per optimised point: the point index.
    pub(crate) opt_points: Vec<usize>,
    /// Per optimised point: all its observations. Per-observation numeric data is stored
    /// in this order ("entries"), so a point's data is contiguous.
    pub(crate) point_obs: Csr<usize>,
    /// Per entry of `point_obs`: the free index of the observing pose.
    pub(crate) entry_free: Vec<Option<usize>>,
    /// Per optimised point: its Schur terms.
    pub(crate) point_terms: Csr<SchurTerm>,
    /// Points per chunk of the numeric phase (the last chunk may be shorter); depends on
    /// the structure only, never on the thread count.
    pub(crate) chunk_points: usize,
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
        let incidence = problem.observations.iter().map(|o| (o.pose, o.point));
        Self::from_incidence(
            &problem.pose_fixed,
            problem.points.len(),
            incidence.collect(),
            6,
        )
    }

    /// The analysis for `dim`-parameter camera blocks from the structure alone: fixed flags
    /// per camera, the number of points and each observation's `(camera, point)`, all
    /// indices in range (the caller validated them).
    pub(crate) fn from_incidence(
        pose_fixed: &[bool],
        num_points: usize,
        incidence: Vec<(usize, usize)>,
        dim: usize,
    ) -> Result<Self, OptimError> {
        let (free_poses, free_index) = number_free_poses(pose_fixed);
        let mut seen_by_free = vec![false; num_points];
        for &(pose, point) in &incidence {
            if free_index[pose].is_some() {
                seen_by_free[point] = true;
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
            incidence
                .iter()
                .enumerate()
                .filter_map(|(i, &(_, point))| point_index[point].map(|p| (p, i))),
        );
        let entry_free: Vec<Option<usize>> = point_obs
            .items()
            .iter()
            .map(|&i| free_index[incidence[i].0])
            .collect();

        // Per point: (position in its row, free index) of its observations by free poses.
        let free_entries = Csr::from_rows((0..opt_points.len()).map(|p| {
            let (entry_free, start) = (&entry_free, point_obs.range(p).start);
            point_obs
                .range(p)
                .filter_map(move |e| entry_free[e].map(|f| (e - start, f)))
        }));
        // Block pattern: per block column b, the sorted block rows a <= b.
        let nfree = free_poses.len();
        let mut block_rows: Vec<Vec<usize>> = (0..nfree).map(|b| vec![b]).collect();
        for p in 0..opt_points.len() {
            for &(_, fa) in free_entries.row(p) {
                for &(_, fb) in free_entries.row(p) {
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
        let point_terms = Csr::from_rows((0..opt_points.len()).map(|p| {
            let entries = free_entries.row(p);
            let block_rows = &block_rows;
            entries.iter().flat_map(move |&(a, fa)| {
                entries
                    .iter()
                    .filter(move |&&(_, fb)| fa <= fb)
                    .map(move |&(b, fb)| SchurTerm {
                        column: fb as u32,
                        // Present by construction of block_rows.
                        slot: block_rows[fb].binary_search(&fa).unwrap_or(0) as u32,
                        diagonal: fa == fb,
                        a: a as u32,
                        b: b as u32,
                    })
            })
        }));

        // block_rows[b] ends with b itself: the diagonal block.
        let above: Vec<&[usize]> = block_rows.iter().map(|r| &r[..r.len() - 1]).collect();
        let (pattern, llt) = block_upper_pattern(dim, &above)?;
        let partial_len = pattern.row_idx().len() + dim * nfree;
        let chunks = (opt_points.len() / MIN_CHUNK_POINTS)
            .clamp(1, MAX_CHUNKS)
            .min((PARTIAL_BUDGET / partial_len.max(1)).max(1));
        let chunk_points = opt_points.len().div_ceil(chunks).max(1);
        Ok(Self {
            pose_fixed: pose_fixed.to_vec(),
            num_points,
            incidence,
            free_poses,
            opt_points,
            point_obs,
            entry_free,
            point_terms,
            chunk_points,
            blocks_in_column: block_rows.iter().map(Vec::len).collect(),
            pattern,
            llt,
        })
    }

    /// Point chunks of the numeric phase and the number of `point_obs` entries in each.
    pub(crate) fn point_chunks(
        &self,
    ) -> impl Iterator<Item = (std::ops::Range<usize>, usize)> + '_ {
        let n = self.opt_points.len();
        (0..n).step_by(self.chunk_points).map(move |p0| {
            let p1 = (p0 + self.chunk_points).min(n);
            let entries = self.point_obs.range(p1 - 1).end - self.point_obs.range(p0).start;
            (p0..p1, entries)
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
