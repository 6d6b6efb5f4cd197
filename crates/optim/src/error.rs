//! Errors of the optimisers: bad input is kept apart from numerical failure.

/// Everything that can go wrong in `ferroslam-optim`. Nothing in this crate panics on bad
/// input; it returns one of these instead.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OptimError {
    /// An observation names a pose or point that does not exist.
    #[error("observation {observation} refers to {what} {index}, but there are only {len}; fix the observation indices")]
    IndexOutOfRange {
        /// Index of the offending observation.
        observation: usize,
        /// `"pose"` or `"point"`.
        what: &'static str,
        /// The out-of-range index.
        index: usize,
        /// Number of poses or points in the problem.
        len: usize,
    },
    /// A NaN or infinite value where a finite one is required.
    #[error("non-finite value in {what} {index}; remove NaN/inf from the inputs")]
    NonFinite {
        /// What holds the value (`"pose"`, `"point"`, `"observation"`, `"intrinsics"`).
        what: &'static str,
        /// Its index (0 for intrinsics).
        index: usize,
    },
    /// Input that is finite but meaningless (negative information, mismatched lengths, ...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The problem handed to `bundle_adjust` does not have the structure the `SymbolicBa`
    /// was analysed for.
    #[error("problem structure (poses, fixed flags, points or observation incidence) differs from the one the SymbolicBa was built for; rebuild it with SymbolicBa::new")]
    StructureMismatch,
    /// The damped reduced camera system stayed indefinite however large the damping grew:
    /// the problem is degenerate (e.g. a free pose without usable observations) or corrupt.
    #[error("reduced camera system is not positive definite (pivot {column}); check for free poses without observations or degenerate geometry")]
    NotPositiveDefinite {
        /// Column of the failing pivot in the reduced camera system (6 per free pose).
        column: usize,
    },
    /// The sparse solver failed for a non-numerical reason (out of memory, index overflow).
    #[error("sparse solver failure: {0}")]
    Solver(String),
}

impl OptimError {
    /// `Ok` if `index < len`, else [`OptimError::IndexOutOfRange`] for observation
    /// `observation` referring to `what` (`"pose"`, `"camera"`, `"point"`) `index`.
    pub(crate) fn check_index(
        observation: usize,
        what: &'static str,
        index: usize,
        len: usize,
    ) -> Result<(), Self> {
        if index < len {
            return Ok(());
        }
        Err(Self::IndexOutOfRange {
            observation,
            what,
            index,
            len,
        })
    }
}
