//! Sparsity pattern of a symmetric block matrix (the reduced camera system of bundle
//! adjustment, the pose-graph Hessian), stored as faer wants it for a sparse Cholesky.

use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::linalg::LltError;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::Side;

use crate::error::OptimError;

/// The free poses among `fixed` flags: their indices, increasing, and per pose its rank
/// among them (`None` for a fixed pose). Free poses are the block rows and columns of the
/// reduced system.
pub(crate) fn number_free_poses(fixed: &[bool]) -> (Vec<usize>, Vec<Option<usize>>) {
    let mut free_poses = Vec::new();
    let free_index = fixed
        .iter()
        .enumerate()
        .map(|(i, &fixed)| {
            (!fixed).then(|| {
                free_poses.push(i);
                free_poses.len() - 1
            })
        })
        .collect();
    (free_poses, free_index)
}

/// Upper-triangular CSC pattern of a symmetric matrix of `dim` x `dim` blocks, and its
/// symbolic Cholesky factorisation (`None` for an empty matrix).
///
/// Block column `b` holds the blocks at block rows `above[b]` (strictly above the diagonal,
/// increasing) and the upper triangle of its diagonal block; within a column, rows appear in
/// that order, so numeric values can be written block by block.
pub(crate) fn block_upper_pattern(
    dim: usize,
    above: &[&[usize]],
) -> Result<(SymbolicSparseColMat<usize>, Option<SymbolicLlt<usize>>), OptimError> {
    let n = dim * above.len();
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0usize);
    for (b, rows) in above.iter().enumerate() {
        for c in 0..dim {
            for &a in *rows {
                row_idx.extend(dim * a..dim * a + dim);
            }
            row_idx.extend(dim * b..=dim * b + c);
            col_ptr.push(row_idx.len());
        }
    }
    let pattern = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
    let llt = if n == 0 {
        None
    } else {
        Some(
            SymbolicLlt::try_new(pattern.as_ref(), Side::Upper)
                .map_err(|e| OptimError::Solver(format!("{e:?}")))?,
        )
    };
    Ok((pattern, llt))
}

/// Numeric Cholesky of the symmetric matrix whose upper triangle has `pattern` and `values`,
/// reusing the symbolic factorisation `llt` of that pattern.
///
/// # Errors
/// [`OptimError::NotPositiveDefinite`] on a non-positive pivot, [`OptimError::Solver`] on any
/// other solver failure.
pub(crate) fn factorize_upper(
    pattern: &SymbolicSparseColMat<usize>,
    llt: &SymbolicLlt<usize>,
    values: &[f64],
) -> Result<Llt<usize, f64>, OptimError> {
    let matrix = SparseColMatRef::new(pattern.as_ref(), values);
    Llt::try_new_with_symbolic(llt.clone(), matrix, Side::Upper).map_err(|e| match e {
        LltError::Numeric(faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot {
            index,
        }) => OptimError::NotPositiveDefinite { column: index },
        LltError::Generic(e) => OptimError::Solver(format!("{e:?}")),
    })
}
