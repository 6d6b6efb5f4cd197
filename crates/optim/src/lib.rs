//! Nonlinear least squares for ferroslam: motion-only bundle adjustment and sparse local
//! bundle adjustment, following ORB-SLAM2/3 `Optimizer::PoseOptimization` and
//! `Optimizer::LocalBundleAdjustment`.
//!
//! Conventions (shared with `ferroslam_geometry`):
//! - poses are `T_c_w` (world to camera), `p_c = T_c_w * p_w`, metres;
//! - observations are undistorted pixel coordinates of an ideal pinhole ([`Intrinsics`]);
//!   stereo / RGB-D observations add ORB-SLAM's virtual right coordinate `u_r = u - bf / z`;
//! - an observation names the camera of a multi-camera rig that made it ([`RigCamera`]): a
//!   pose is the rig's first camera's `T_c0_w`, camera `k` sees from `T_ck_c0 * T_c0_w`;
//! - pose increments are LEFT perturbations `T_c_w <- exp(xi) * T_c_w` with
//!   `xi = [rho (0..3); phi (3..6)]` (`ferroslam_geometry::se3::{TRANS, ROT}`);
//! - residuals are `e = observed - predicted`, weighted by `inv_sigma2` (information
//!   `inv_sigma2 * I`), and the cost is `sum rho(chi2)` with `chi2 = inv_sigma2 * |e|^2`
//!   and `rho` the identity or g2o's Huber kernel ([`robust`]).
//!
//! Entry points: [`optimize_pose`] (one pose, fixed points, outlier rejection;
//! [`pose_rolling_shutter::optimize_pose_and_velocity`] for a rolling-shutter frame, its
//! velocity estimated with the pose),
//! [`SymbolicBa`] + [`bundle_adjust`] (Levenberg-Marquardt with a Schur complement on the
//! points, the reduced camera system factorised with faer's sparse Cholesky on a symbolic
//! analysis built once per problem structure) and [`local_bundle_adjust`] (ORB-SLAM's
//! robust-then-plain schedule with outlier classification). [`pose_graph`] holds the SE(3) /
//! Sim(3) pose-graph optimiser ([`SymbolicPoseGraph`] + [`optimize_pose_graph`], same
//! Levenberg-Marquardt and sparse Cholesky pattern) and a g2o reader ([`read_g2o`]).
//! `bal` (cargo feature `bal`, benchmarks only) solves Bundle Adjustment in the Large
//! problems (Snavely cameras, reader for the published `.txt` / `.txt.bz2` files) with the
//! same Schur-complement core as [`ba`].
//! [`optimize_sim3`] refines the loop-closing similarity `S_12` between two keyframes from
//! matched map points (ORB-SLAM's `OptimizeSim3`: both reprojection errors, Huber, outlier
//! removal between two rounds), after `ferroslam_geometry::sim3_ransac` found it.
#![warn(missing_docs)]

pub mod ba;
#[cfg(feature = "bal")]
pub mod bal;
mod block_pattern;
pub mod error;
pub mod inertial_ba;
pub mod intrinsics;
mod lm;
pub mod pose;
pub mod pose_graph;
pub mod pose_inertial;
pub mod pose_rolling_shutter;
pub mod residual;
pub mod rig_camera;
pub mod robust;
pub mod sim3_align;

pub use ba::{
    bundle_adjust, local_bundle_adjust, BaOptions, BaProblem, BaReport, LocalBaResult, Observation,
    SymbolicBa,
};
pub use error::OptimError;
pub use inertial_ba::{
    inertial_bundle_adjust, InertialBaOptions, InertialBaProblem, InertialBaResult, InertialEdge,
};
pub use intrinsics::Intrinsics;
pub use pose::{optimize_pose, PoseEstimate, PoseObservation};
pub use pose_graph::{
    optimize_pose_graph, read_g2o, PoseEdge, PoseGraph, PoseGraphOptions, PoseGraphReport,
    Se3PoseGraph, Sim3PoseGraph, SymbolicPoseGraph,
};
pub use pose_inertial::{optimize_pose_inertial, InertialLink, InertialPoseEstimate};
pub use rig_camera::RigCamera;
pub use sim3_align::{optimize_sim3, Sim3AlignResult, Sim3Match, SIM3_TH2_MONO};
