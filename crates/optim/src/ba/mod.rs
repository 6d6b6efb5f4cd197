//! Sparse bundle adjustment over keyframe poses and map points.
//!
//! [`SymbolicBa`] analyses a [`BaProblem`]'s structure once (which poses are free, which
//! points are optimised, the block sparsity of the reduced camera system and its symbolic
//! Cholesky factorisation); [`bundle_adjust`] runs Levenberg-Marquardt iterations that reuse
//! it; [`local_bundle_adjust`] wraps both in ORB-SLAM's local BA schedule.

mod csr;
mod local;
mod problem;
pub(crate) mod solve;
mod symbolic;
mod text;

pub use local::{
    local_bundle_adjust, LocalBaResult, LOCAL_BA_PLAIN_ITERATIONS, LOCAL_BA_ROBUST_ITERATIONS,
};
pub use problem::{BaProblem, Observation};
pub use solve::{bundle_adjust, BaOptions, BaReport};
pub use symbolic::SymbolicBa;
