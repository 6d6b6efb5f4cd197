//! Motion-only bundle adjustment: refine one camera pose (the first camera's of a rig, the
//! others seen through their [`RigCamera::T_c_c0`]) against fixed world points with
//! ORB-SLAM's outlier rejection schedule (`Optimizer::PoseOptimization`).

use crate::error::OptimError;
use crate::lm::{
    add_normal_equations, damping_diagonal, dense_damped_step, mirror_lower_triangle, Damping,
};
use crate::residual;
use crate::rig_camera::{carry_jacobian, seen_from, RigCamera};
use crate::robust::{chi2_threshold, cost_and_weight};
use ferroslam_geometry::se3;
use nalgebra::{Isometry3, Matrix6, Vector2, Vector3, Vector6};

/// Rounds of optimisation followed by re-classification of every observation.
pub const ROUNDS: usize = 4;
/// Levenberg-Marquardt iterations per round (ORB-SLAM uses 10 in each).
pub const ITERATIONS_PER_ROUND: usize = 10;
/// The first `ROBUST_ROUNDS` rounds use the Huber kernel; later ones plain least squares.
pub const ROBUST_ROUNDS: usize = 3;
/// Initial Marquardt damping (relative to the Hessian diagonal).
const INITIAL_LAMBDA: f64 = 1e-5;
/// Stop a round once an accepted step lowers the cost (a sum of chi-square values) by less
/// than this: the pose is then within a few hundredths of its standard deviation of the
/// round's optimum (what is left is at most that gain, far less once LM converges
/// quadratically), and further iterations would only polish roundoff. ORB-SLAM's g2o
/// always runs all 10 (time saved: docs/benchmarks.md).
const DECREASE_TOLERANCE: f64 = 1e-3;

/// A fixed world point observed by one camera of the rig whose pose is optimised.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseObservation {
    /// Index into the rig's cameras (0 for a single camera).
    pub camera: usize,
    /// Point in the world frame, metres.
    pub p_w: Vector3<f64>,
    /// Observed undistorted keypoint, pixels.
    pub uv: Vector2<f64>,
    /// Virtual right coordinate `u - bf / depth` (pixels) for stereo / RGB-D, else `None`.
    pub u_right: Option<f64>,
    /// Information weight `1 / sigma^2` (1/pixels^2), ORB-SLAM's per-octave `invSigma2`.
    pub inv_sigma2: f64,
}

/// Result of [`optimize_pose`].
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseEstimate {
    /// Refined world-to-camera pose.
    pub T_c_w: Isometry3<f64>,
    /// Observations classified as inliers by the final round.
    pub num_inliers: usize,
}

/// Refines `T_c_w` from fixed 3D-2D (or 3D-stereo) correspondences, classifying outliers.
///
/// `T_c_w` is the pose of the rig's first camera; an observation of camera `k` is seen from
/// `cameras[k].T_c_c0 * T_c_w` with `cameras[k].intrinsics` (see [`RigCamera`]); a single
/// camera is `&[RigCamera::first(k)]`.
///
/// Schedule (ORB-SLAM2/3 `PoseOptimization`): [`ROUNDS`] rounds, each restarting from the
/// initial `T_c_w` and running up to [`ITERATIONS_PER_ROUND`] Levenberg-Marquardt iterations
/// over the observations currently flagged inlier, with the Huber kernel in the first
/// [`ROBUST_ROUNDS`] rounds. After each round ALL observations are re-classified:
/// outlier iff `chi2 > CHI2_MONO` (mono) / `> CHI2_STEREO` (stereo), or the point is not in
/// front of the camera (or its prediction is non-finite).
///
/// `outlier` holds the initial flags on input and the final classification on output.
/// With no usable observation the initial pose is returned unchanged.
///
/// # Errors
/// [`OptimError::InvalidInput`] if `outlier.len() != obs.len()`, `cameras` is empty, an
/// observation's camera is not in it, intrinsics are invalid or an `inv_sigma2` is not
/// positive; [`OptimError::NonFinite`] for a non-finite pose, camera extrinsics or
/// observation value.
#[allow(non_snake_case)]
pub fn optimize_pose(
    T_c_w: &Isometry3<f64>,
    obs: &[PoseObservation],
    cameras: &[RigCamera],
    outlier: &mut [bool],
) -> Result<PoseEstimate, OptimError> {
    validate(T_c_w, obs, cameras, outlier)?;
    let mut pose = *T_c_w;
    // Like ORB-SLAM, every round restarts from the initial guess so that a round spoiled by
    // outliers does not bias the next; which points it projects is decided once.
    let projects_at_start: Vec<bool> = obs
        .iter()
        .map(|o| chi2_of(cameras, T_c_w, o).is_some())
        .collect();
    for round in 0..ROUNDS {
        let active: Vec<usize> = (0..obs.len())
            .filter(|&i| !outlier[i] && projects_at_start[i])
            .collect();
        pose = refine(T_c_w, obs, &active, cameras, round < ROBUST_ROUNDS);
        for (flag, o) in outlier.iter_mut().zip(obs) {
            *flag =
                chi2_of(cameras, &pose, o).is_none_or(|c| c > chi2_threshold(o.u_right.is_some()));
        }
    }
    let num_inliers = outlier.iter().filter(|&&o| !o).count();
    Ok(PoseEstimate {
        T_c_w: pose,
        num_inliers,
    })
}

#[allow(non_snake_case)]
pub(crate) fn validate(
    T_c_w: &Isometry3<f64>,
    obs: &[PoseObservation],
    cameras: &[RigCamera],
    outlier: &[bool],
) -> Result<(), OptimError> {
    RigCamera::validate_all(cameras)?;
    if outlier.len() != obs.len() {
        return Err(OptimError::InvalidInput(format!(
            "outlier has {} flags for {} observations",
            outlier.len(),
            obs.len()
        )));
    }
    let pose_finite = T_c_w.translation.vector.iter().all(|v| v.is_finite())
        && T_c_w.rotation.coords.iter().all(|v| v.is_finite());
    if !pose_finite {
        return Err(OptimError::NonFinite {
            what: "pose",
            index: 0,
        });
    }
    for (i, o) in obs.iter().enumerate() {
        if o.camera >= cameras.len() {
            return Err(OptimError::InvalidInput(format!(
                "observation {i} is of camera {}, but the rig has {} cameras",
                o.camera,
                cameras.len()
            )));
        }
        if !o.p_w.iter().all(|v| v.is_finite()) {
            return Err(OptimError::NonFinite {
                what: "observation",
                index: i,
            });
        }
        residual::validate_measurement(i, &o.uv, o.u_right, o.inv_sigma2)?;
    }
    Ok(())
}

/// The observation's camera and the pose it sees from, `T_c_c0 * T_c_w` (`T_c_w` itself for
/// the first camera).
#[allow(non_snake_case)]
pub(crate) fn camera_pose<'a>(
    cameras: &'a [RigCamera],
    T_c_w: &Isometry3<f64>,
    o: &PoseObservation,
) -> (&'a RigCamera, Isometry3<f64>) {
    let camera = &cameras[o.camera];
    (camera, seen_from(camera.T_c_c0.as_ref(), T_c_w))
}

#[allow(non_snake_case)]
pub(crate) fn chi2_of(
    cameras: &[RigCamera],
    T_c_w: &Isometry3<f64>,
    o: &PoseObservation,
) -> Option<f64> {
    let (camera, T) = camera_pose(cameras, T_c_w, o);
    residual::chi2(
        &camera.intrinsics,
        &T,
        &o.p_w,
        &o.uv,
        o.u_right,
        o.inv_sigma2,
    )
}

/// Cost and Gauss-Newton system of the `active` observations at one pose.
pub(crate) struct Evaluation {
    /// `sum rho(chi2)`, infinite if any of them leaves the camera's domain (so such steps are
    /// rejected and the objective stays well defined).
    pub(crate) cost: f64,
    /// `H = sum w J^T J` over the observations in the domain, with `w = inv_sigma2 *
    /// rho'(chi2)` and `J = d e / d xi` (left perturbation of `T_c_w`).
    pub(crate) h: Matrix6<f64>,
    /// `g = sum w J^T e`.
    pub(crate) g: Vector6<f64>,
}

/// [`Evaluation`] at `pose`, in one pass: Levenberg-Marquardt needs each candidate's cost,
/// and the accepted candidate's system is the next iteration's (separate passes for the two
/// projected every point twice per iteration).
pub(crate) fn evaluate(
    cameras: &[RigCamera],
    pose: &Isometry3<f64>,
    obs: &[PoseObservation],
    active: &[usize],
    robust: bool,
) -> Evaluation {
    let mut at = Evaluation {
        cost: 0.0,
        h: Matrix6::zeros(),
        g: Vector6::zeros(),
    };
    for &i in active {
        let o = &obs[i];
        let (camera, seen) = camera_pose(cameras, pose, o);
        let Some((e, mut j)) =
            residual::linearize_pose(&camera.intrinsics, &seen, &o.p_w, &o.uv, o.u_right)
        else {
            at.cost = f64::INFINITY;
            continue;
        };
        carry_jacobian(camera.T_c_c0.as_ref(), &mut j);
        let chi2 = o.inv_sigma2 * e.norm_squared();
        let (rho, weight) = cost_and_weight(chi2, o.u_right.is_some(), robust);
        at.cost += rho;
        let rows = if o.u_right.is_some() { 3 } else { 2 };
        add_normal_equations(&mut at.h, &mut at.g, o.inv_sigma2 * weight, &j, &e, rows);
    }
    mirror_lower_triangle(&mut at.h);
    at
}

/// Levenberg-Marquardt on the 6-dof pose over the `active` observations.
fn refine(
    start: &Isometry3<f64>,
    obs: &[PoseObservation],
    active: &[usize],
    cameras: &[RigCamera],
    robust: bool,
) -> Isometry3<f64> {
    let mut pose = *start;
    if active.is_empty() {
        return pose;
    }
    let mut current = evaluate(cameras, &pose, obs, active, robust);
    let mut damping = Damping::new(INITIAL_LAMBDA);
    for _ in 0..ITERATIONS_PER_ROUND {
        let (h, g) = (current.h, current.g);
        let d = h.diagonal().map(damping_diagonal);
        let accepted = loop {
            if damping.exhausted() {
                break None;
            }
            let Ok((dx, predicted)) = dense_damped_step(&h, &g, &d, damping.lambda()) else {
                damping.reject();
                continue;
            };
            let candidate = se3::retract(&dx, &pose);
            let at = evaluate(cameras, &candidate, obs, active, robust);
            let actual = current.cost - at.cost;
            if actual > 0.0 && predicted > 0.0 {
                damping.accept(actual / predicted);
                break Some((candidate, at, actual));
            }
            damping.reject();
        };
        let Some((candidate, at, actual)) = accepted else {
            break;
        };
        pose = candidate;
        current = at;
        if actual <= DECREASE_TOLERANCE {
            break;
        }
    }
    pose
}
