//! Bundle Adjustment in the Large (BAL): Snavely's 9-parameter cameras, batch
//! Levenberg-Marquardt with the points eliminated by a Schur complement.
//!
//! The BAL data sets (Agarwal, Snavely, Seitz, Szeliski, "Bundle Adjustment in the Large",
//! ECCV 2010) use their own camera model, not ferroslam's pinhole `T_c_w`:
//!
//! ```text
//! camera = [w (Rodrigues angle-axis, rad), t, f (px), k1, k2]      point = X (world)
//! P = R(w) X + t,   p = -P.xy / P.z,   d = 1 + k1 |p|^2 + k2 |p|^4
//! residual = f d p - (u, v)            (pixels; the camera looks down -z)
//! cost = 0.5 * sum of |residual|^2     (no robust loss, no parameter held constant)
//! ```
//!
//! This is Ceres' `SnavelyReprojectionError`, so costs compare directly with Ceres' and
//! gtsam's (`GeneralSFMFactor<Cal3Bundler>`, sigma 1) reports.
//!
//! Entry points: [`read_bal`] (plain text or `.bz2`), [`BalProblem`] (data, validation,
//! cost), [`SnavelyCamera`] (projection with analytic Jacobians) and [`solve_bal`] (LM on
//! the reduced camera system of 9x9 blocks, factorised with faer's sparse Cholesky, reusing
//! the numeric core of [`crate::ba`]). Camera parameters are updated additively, as in Ceres
//! (angle-axis included), points too.

mod problem;
mod reader;
mod snavely;
mod solver;

pub use problem::{BalObservation, BalProblem};
pub use reader::{parse_bal, read_bal};
pub use snavely::{CameraParams, CAMERA_PARAMS};
pub use snavely::{SnavelyCamera, SnavelyLinearization};
pub use solver::{solve_bal, BalOptions, BalReport};

/// Fixtures shared by the unit tests of this module.
#[cfg(test)]
pub(crate) mod fixtures {
    use std::path::PathBuf;

    /// `$FERROSLAM_DATA/ba/<name>`, else `shared/data/ba/<name>` beside the repository.
    pub(crate) fn path(name: &str) -> PathBuf {
        std::env::var_os("FERROSLAM_DATA")
            .map(PathBuf::from)
            .unwrap_or_else(|| {
                PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
            })
            .join("ba")
            .join(name)
    }
}
