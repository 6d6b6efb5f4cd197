//! Refinement of the loop-closing similarity between two keyframes from matched map points
//! (ORB-SLAM2/3 `Optimizer::OptimizeSim3`), as a pure function.
//!
//! The map points stay fixed; only `S_12` (camera 2 to camera 1) moves. Each match gives
//! two monocular reprojection residuals, one in each keyframe:
//! `e_1 = uv1 - proj(S_12 * p2)` and `e_2 = uv2 - proj(S_12^-1 * p1)`, with information
//! `inv_sigma2_k * I` and a Huber kernel of width `sqrt(th2)` on `chi2_k = inv_sigma2_k |e_k|^2`.
//! Increments are LEFT perturbations `S_12 <- exp(zeta) * S_12`, `zeta = [rho; phi; sigma]`.
//!
//! A keyframe of a multi-camera rig is one generalised camera: its points are in the rig's
//! first-camera frame and each keypoint is compared in the camera that measured it,
//! `proj_k(T_ck_c0 * q)` ([`RigCamera`]), so a loop seen by another camera than before
//! refines as any other.

use crate::error::OptimError;
use crate::intrinsics::Intrinsics;
use crate::lm::{damping_diagonal, dense_damped_step, Damping};
use crate::residual::{self, validate_measurement};
use crate::rig_camera::RigCamera;
use crate::robust::Huber;
use ferroslam_geometry::sim3::{Sim3, Vector7, SCALE};
use ferroslam_geometry::so3;
use nalgebra::{Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

/// ORB-SLAM's `th2` for monocular loop closing (`OptimizeSim3(..., th2 = 10, ...)`).
pub const SIM3_TH2_MONO: f64 = 10.0;
/// Levenberg-Marquardt iterations before outliers are removed.
pub const FIRST_ITERATIONS: usize = 5;
/// Iterations after outlier removal when no match was removed.
pub const SECOND_ITERATIONS: usize = 5;
/// Iterations after outlier removal when at least one match was removed.
pub const SECOND_ITERATIONS_AFTER_REJECTION: usize = 10;
/// Initial Marquardt damping (relative to the Hessian diagonal).
const INITIAL_LAMBDA: f64 = 1e-5;
/// Stop a stage once an accepted step lowers the cost by less than this fraction.
const RELATIVE_TOLERANCE: f64 = 1e-12;

type Matrix7<T> = SMatrix<T, 7, 7>;
type Matrix2x7<T> = SMatrix<T, 2, 7>;
type Matrix3x7<T> = SMatrix<T, 3, 7>;

/// A map-point match between keyframe 1 and keyframe 2 (both points fixed).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3Match {
    /// The map point seen by keyframe 1, in keyframe 1's reference (first-camera) frame
    /// (metres).
    pub p1: Vector3<f64>,
    /// Its matched map point seen by keyframe 2, in keyframe 2's reference frame.
    pub p2: Vector3<f64>,
    /// Undistorted keypoint observing `p1` in keyframe 1, pixels of camera `camera1`.
    pub uv1: Vector2<f64>,
    /// Undistorted keypoint observing `p2` in keyframe 2, pixels of camera `camera2`.
    pub uv2: Vector2<f64>,
    /// Index into the rig's cameras of the one that measured `uv1` (0 for a single camera).
    pub camera1: usize,
    /// Index of the camera that measured `uv2`.
    pub camera2: usize,
    /// Information `1 / sigma^2` of `uv1` (ORB-SLAM's per-octave `invSigma2`), 1/pixels^2.
    pub inv_sigma2_1: f64,
    /// Information `1 / sigma^2` of `uv2`, 1/pixels^2.
    pub inv_sigma2_2: f64,
}

/// Result of [`optimize_sim3`].
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct Sim3AlignResult {
    /// Refined similarity mapping camera-2 points to camera 1: `p1 ≈ S_12 * p2`.
    pub S_12: Sim3,
    /// `inliers[i]`: match `i` survived outlier removal and has both `chi2 <= th2`.
    pub inliers: Vec<bool>,
    /// Number of `true` entries in `inliers`.
    pub num_inliers: usize,
}

/// Refines `S_12` by minimising both keyframes' robust reprojection errors over `matches`.
///
/// Schedule (ORB-SLAM `OptimizeSim3`): [`FIRST_ITERATIONS`] Levenberg-Marquardt iterations
/// over every match (matches whose points fall behind a camera at the start are outliers
/// from the outset); then a match is an outlier if either `chi2 > th2` (or a point is
/// behind its camera); then [`SECOND_ITERATIONS`] more iterations over the remaining
/// matches, [`SECOND_ITERATIONS_AFTER_REJECTION`] if any match was removed. Removed matches
/// stay outliers; the final inliers are the remaining ones with both `chi2 <= th2`. The
/// Huber kernel (width `sqrt(th2)`) is on in both stages, as in ORB-SLAM. Use
/// [`SIM3_TH2_MONO`] (10) for monocular keyframes as ORB-SLAM does. Unlike ORB-SLAM, which
/// reports 0 inliers when fewer than 10 matches survive the first stage, the count is
/// returned as is: callers apply their own minimum (ORB-SLAM's loop closer wants 20).
///
/// With `fix_scale` the scale is not optimised (6 dof) and stays exactly `S_12.scale`.
/// `cameras` are the rig's (one for a single camera), the same for both keyframes; each
/// side is projected through its match's camera (the stereo `bf` is not used).
///
/// # Errors
/// [`OptimError::InvalidInput`] for no matches, no camera or invalid intrinsics, a match
/// naming a camera the rig does not have, `th2` not positive,
/// `S_12.scale <= 0` or an `inv_sigma2` not positive; [`OptimError::NonFinite`] for a
/// non-finite value in `S_12` (`what = "sim3"`) or in a match (`what = "observation"`,
/// `index` = the match). The underlying LM cannot fail otherwise (its 7x7 system is
/// damped positive definite), but its error is passed through if it does.
///
/// ```
/// use ferroslam_geometry::sim3::{Sim3, Vector7};
/// use ferroslam_optim::sim3_align::{optimize_sim3, Sim3Match, SIM3_TH2_MONO};
/// use ferroslam_optim::{Intrinsics, RigCamera};
/// use nalgebra::{Vector2, Vector3};
/// let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, bf: 0.0, fisheye: None };
/// let proj = |p: Vector3<f64>| Vector2::new(500.0 * p.x / p.z + 320.0, 500.0 * p.y / p.z + 240.0);
/// let truth = Sim3::exp(&Vector7::from([0.1, 0.0, -0.05, 0.0, 0.05, 0.0, 0.3]));
/// let matches: Vec<_> = (0..30)
///     .map(|i| {
///         let p1 = Vector3::new((i % 6) as f64 * 0.3 - 0.8, (i / 6) as f64 * 0.3 - 0.6, 3.0 + (i % 4) as f64 * 0.4);
///         let p2 = truth.inverse().transform_point(&p1);
///         Sim3Match { p1, p2, uv1: proj(p1), uv2: proj(p2), camera1: 0, camera2: 0, inv_sigma2_1: 1.0, inv_sigma2_2: 1.0 }
///     })
///     .collect();
/// let start = Sim3::exp(&Vector7::from([0.02, 0.01, 0.0, 0.01, 0.0, 0.0, 0.05])) * truth;
/// let out = optimize_sim3(&start, &matches, &[RigCamera::first(k)], SIM3_TH2_MONO, false).unwrap();
/// assert_eq!(out.num_inliers, 30);
/// assert!((out.S_12.scale - truth.scale).abs() < 1e-8);
/// ```
#[allow(non_snake_case)]
pub fn optimize_sim3(
    S_12: &Sim3,
    matches: &[Sim3Match],
    cameras: &[RigCamera],
    th2: f64,
    fix_scale: bool,
) -> Result<Sim3AlignResult, OptimError> {
    validate(S_12, matches, cameras, th2)?;
    let problem = Problem {
        k: cameras,
        matches,
        huber: Huber { delta: th2.sqrt() },
        fix_scale,
    };
    let within =
        |s: &Sim3, m: &Sim3Match| chi2s(cameras, s, m).is_some_and(|c| c[0] <= th2 && c[1] <= th2);
    let first: Vec<usize> = (0..matches.len())
        .filter(|&i| chi2s(cameras, S_12, &matches[i]).is_some())
        .collect();
    let s = problem.refine(S_12, &first, FIRST_ITERATIONS)?;
    let second: Vec<usize> = first
        .iter()
        .copied()
        .filter(|&i| within(&s, &matches[i]))
        .collect();
    let iterations = if second.len() < matches.len() {
        SECOND_ITERATIONS_AFTER_REJECTION
    } else {
        SECOND_ITERATIONS
    };
    let s = problem.refine(&s, &second, iterations)?;
    let mut inliers = vec![false; matches.len()];
    for &i in &second {
        inliers[i] = within(&s, &matches[i]);
    }
    let num_inliers = inliers.iter().filter(|&&f| f).count();
    Ok(Sim3AlignResult {
        S_12: s,
        inliers,
        num_inliers,
    })
}

#[allow(non_snake_case)]
fn validate(
    S_12: &Sim3,
    matches: &[Sim3Match],
    cameras: &[RigCamera],
    th2: f64,
) -> Result<(), OptimError> {
    RigCamera::validate_all(cameras)?;
    if matches.is_empty() {
        return Err(OptimError::InvalidInput(
            "optimize_sim3 needs at least one match".into(),
        ));
    }
    if !(th2.is_finite() && th2 > 0.0) {
        return Err(OptimError::InvalidInput(format!(
            "th2 = {th2} (must be finite and > 0)"
        )));
    }
    let finite = S_12.scale.is_finite()
        && S_12.translation.iter().all(|v| v.is_finite())
        && S_12.rotation.coords.iter().all(|v| v.is_finite());
    if !finite {
        return Err(OptimError::NonFinite {
            what: "sim3",
            index: 0,
        });
    }
    if S_12.scale <= 0.0 {
        return Err(OptimError::InvalidInput(format!(
            "S_12.scale = {} (must be > 0)",
            S_12.scale
        )));
    }
    for (i, m) in matches.iter().enumerate() {
        if !m.p1.iter().chain(&m.p2).all(|v| v.is_finite()) {
            return Err(OptimError::NonFinite {
                what: "observation",
                index: i,
            });
        }
        if m.camera1.max(m.camera2) >= cameras.len() {
            return Err(OptimError::InvalidInput(format!(
                "match {i} names cameras {} and {} of a rig of {}",
                m.camera1,
                m.camera2,
                cameras.len()
            )));
        }
        validate_measurement(i, &m.uv1, None, m.inv_sigma2_1)?;
        validate_measurement(i, &m.uv2, None, m.inv_sigma2_2)?;
    }
    Ok(())
}

/// Both residuals of one match and their Jacobians at the current `S_12`.
#[derive(Clone, Copy, Debug)]
struct Linearization {
    /// `[uv1 - proj(S_12 p2), uv2 - proj(S_12^-1 p1)]`, pixels.
    e: [Vector2<f64>; 2],
    /// `d e_k / d zeta` for the left perturbation `S_12 <- exp(zeta) * S_12`.
    d_e_d_zeta: [Matrix2x7<f64>; 2],
}

/// `d (exp(zeta) x) / d zeta` at `zeta = 0`: `[I, -hat(x), x]`.
fn d_exp_x_d_zeta(x: &Vector3<f64>) -> Matrix3x7<f64> {
    let mut d = Matrix3x7::zeros();
    d.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    d.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-so3::hat(x)));
    d.set_column(SCALE, x);
    d
}

/// Pixel of a camera point and its Jacobian, `None` behind the camera or non-finite.
fn project(k: &Intrinsics, p_c: &Vector3<f64>) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
    let (pred, d_pred_d_p_c) = residual::predict(k, p_c)?;
    Some((
        pred.fixed_rows::<2>(0).into_owned(),
        d_pred_d_p_c.fixed_view::<2, 3>(0, 0).into_owned(),
    ))
}

/// [`project`] of a reference-frame point through rig camera `camera`: the pixel and its
/// Jacobian with respect to the reference-frame point (`d uv / d p_c * R_c_c0`).
fn project_in(camera: &RigCamera, p: &Vector3<f64>) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
    let k = &camera.intrinsics;
    match &camera.T_c_c0 {
        None => project(k, p),
        Some(t_c_c0) => {
            let p_c = t_c_c0.rotation * p + t_c_c0.translation.vector;
            let (uv, d_uv_d_p_c) = project(k, &p_c)?;
            Some((
                uv,
                d_uv_d_p_c * t_c_c0.rotation.to_rotation_matrix().into_inner(),
            ))
        }
    }
}

fn linearize(cameras: &[RigCamera], s_12: &Sim3, m: &Sim3Match) -> Option<Linearization> {
    // Keyframe 1 sees q = S_12 p2; perturbed, exp(zeta) q.
    let q = s_12.transform_point(&m.p2);
    let (pred_1, d_uv_d_q) = project_in(&cameras[m.camera1], &q)?;
    // Keyframe 2 sees r = S_12^-1 p1; perturbed, S_12^-1 exp(-zeta) p1, and the linear part
    // of S_12^-1 is R^T / s.
    let r = s_12.inverse().transform_point(&m.p1);
    let (pred_2, d_uv_d_r) = project_in(&cameras[m.camera2], &r)?;
    let r_t_over_s = s_12.rotation.inverse().to_rotation_matrix().into_inner() / s_12.scale;
    let lin = Linearization {
        e: [m.uv1 - pred_1, m.uv2 - pred_2],
        d_e_d_zeta: [
            -d_uv_d_q * d_exp_x_d_zeta(&q),
            d_uv_d_r * r_t_over_s * d_exp_x_d_zeta(&m.p1),
        ],
    };
    let finite = lin.e.iter().all(|e| e.iter().all(|v| v.is_finite()));
    finite.then_some(lin)
}

/// `[chi2_1, chi2_2]` of a match, `None` where [`linearize`] is `None`.
fn chi2s(k: &[RigCamera], s_12: &Sim3, m: &Sim3Match) -> Option<[f64; 2]> {
    linearize(k, s_12, m).map(|lin| {
        [
            m.inv_sigma2_1 * lin.e[0].norm_squared(),
            m.inv_sigma2_2 * lin.e[1].norm_squared(),
        ]
    })
}

/// Everything fixed during the optimisation.
struct Problem<'a> {
    k: &'a [RigCamera],
    matches: &'a [Sim3Match],
    huber: Huber,
    fix_scale: bool,
}

impl Problem<'_> {
    /// Robust cost over `active`, infinite if any of them leaves a camera's domain (so such
    /// steps are rejected).
    fn cost(&self, s_12: &Sim3, active: &[usize]) -> f64 {
        active
            .iter()
            .map(|&i| {
                chi2s(self.k, s_12, &self.matches[i]).map_or(f64::INFINITY, |c| {
                    self.huber.rho(c[0]) + self.huber.rho(c[1])
                })
            })
            .sum()
    }

    /// IRLS normal equations `H = sum J^T W J`, `g = sum J^T W e` over `active`; with a fixed
    /// scale the `sigma` row and column are replaced by the identity so its step is 0.
    fn normal_equations(&self, s_12: &Sim3, active: &[usize]) -> (Matrix7<f64>, Vector7<f64>) {
        let mut h = Matrix7::zeros();
        let mut g = Vector7::zeros();
        for &i in active {
            let m = &self.matches[i];
            // Valid by construction: the current estimate was accepted with a finite cost.
            let Some(lin) = linearize(self.k, s_12, m) else {
                continue;
            };
            for (side, inv_sigma2) in [m.inv_sigma2_1, m.inv_sigma2_2].into_iter().enumerate() {
                let (e, j) = (&lin.e[side], &lin.d_e_d_zeta[side]);
                let w = inv_sigma2 * self.huber.weight(inv_sigma2 * e.norm_squared());
                h += w * j.transpose() * j;
                g += w * j.transpose() * e;
            }
        }
        if self.fix_scale {
            h.row_mut(SCALE).fill(0.0);
            h.column_mut(SCALE).fill(0.0);
            h[(SCALE, SCALE)] = 1.0;
            g[SCALE] = 0.0;
        }
        (h, g)
    }

    /// Up to `iterations` Levenberg-Marquardt iterations on `S_12` over the `active` matches.
    fn refine(
        &self,
        start: &Sim3,
        active: &[usize],
        iterations: usize,
    ) -> Result<Sim3, OptimError> {
        let mut s_12 = *start;
        if active.is_empty() {
            return Ok(s_12);
        }
        let mut current = self.cost(&s_12, active);
        let mut damping = Damping::new(INITIAL_LAMBDA);
        for _ in 0..iterations {
            let (h, g) = self.normal_equations(&s_12, active);
            let d = h.diagonal().map(damping_diagonal);
            let mut candidate = s_12;
            let accepted = damping.find_step(
                |lambda| dense_damped_step(&h, &g, &d, lambda),
                |(dx, predicted)| {
                    candidate = Sim3::exp(dx) * s_12;
                    let new_cost = self.cost(&candidate, active);
                    (current - new_cost, *predicted, new_cost)
                },
            )?;
            let Some(new_cost) = accepted else {
                break;
            };
            let decrease = current - new_cost;
            s_12 = candidate;
            current = new_cost;
            if decrease <= RELATIVE_TOLERANCE * new_cost.max(f64::MIN_POSITIVE) {
                break;
            }
        }
        Ok(s_12)
    }
}

#[cfg(test)]
#[allow(non_snake_case)]
mod tests {
    use super::*;
    use ferroslam_geometry::testing::check_jacobian;
    use nalgebra::{DMatrix, DVector};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const K: Intrinsics = Intrinsics {
        fx: 517.3,
        fy: 516.5,
        cx: 318.6,
        cy: 255.3,
        bf: 0.0,
        fisheye: None,
    };

    /// The single camera as a rig of one.
    fn one() -> [RigCamera; 1] {
        [RigCamera::first(K)]
    }

    /// A two-camera rig: camera 1 turned 90 degrees about its y axis, 0.1 m out.
    fn two() -> [RigCamera; 2] {
        let T_c1_c0 = nalgebra::Isometry3::new(
            Vector3::new(0.1, 0.0, 0.0),
            Vector3::new(0.0, std::f64::consts::FRAC_PI_2, 0.0),
        );
        [RigCamera::first(K), RigCamera::new(K, T_c1_c0)]
    }

    /// `scene`'s matches with keyframe 1's side seen through camera 1 of [`two`]: its
    /// points moved into the reference frame as that camera sees them, `S_12` turned to
    /// match, `uv1` kept.
    fn rig_scene(s_12: &Sim3, n: usize, seed: u64) -> (Sim3, Vec<Sim3Match>) {
        let T_c0_c1 = two()[1].T_c_c0.unwrap().inverse();
        let s_rig = Sim3::from_isometry(&T_c0_c1) * *s_12;
        let matches = scene(s_12, n, 0, seed)
            .into_iter()
            .map(|m| Sim3Match {
                p1: (T_c0_c1 * nalgebra::Point3::from(m.p1)).coords,
                camera1: 1,
                ..m
            })
            .collect();
        (s_rig, matches)
    }

    fn pixel(p: &Vector3<f64>) -> Vector2<f64> {
        project(&K, p).expect("point in front").0
    }

    fn truth(scale: f64) -> Sim3 {
        let mut zeta = Vector7::from([0.2, -0.1, 0.15, 0.04, -0.1, 0.03, 0.0]);
        zeta[SCALE] = scale.ln();
        Sim3::exp(&zeta)
    }

    /// `n` exact matches under `s_12` with 0.5 px pixel noise; `uv1` of the first `n_out`
    /// moved by 25-40 px.
    fn scene(s_12: &Sim3, n: usize, n_out: usize, seed: u64) -> Vec<Sim3Match> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s_21 = s_12.inverse();
        (0..n)
            .map(|i| {
                let z = rng.random_range(2.0..6.0);
                let uv = Vector2::new(rng.random_range(30.0..610.0), rng.random_range(30.0..450.0));
                let p1 = Vector3::new((uv.x - K.cx) / K.fx * z, (uv.y - K.cy) / K.fy * z, z);
                let p2 = s_21.transform_point(&p1);
                let mut noise = || Vector2::from_fn(|_, _| rng.random_range(-0.5..0.5));
                let mut uv1 = pixel(&p1) + noise();
                let uv2 = pixel(&p2) + noise();
                if i < n_out {
                    let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    uv1 += Vector2::new(angle.cos(), angle.sin()) * rng.random_range(25.0..40.0);
                }
                Sim3Match {
                    p1,
                    p2,
                    uv1,
                    uv2,
                    camera1: 0,
                    camera2: 0,
                    inv_sigma2_1: 1.0,
                    inv_sigma2_2: 1.0 / 1.44, // second octave
                }
            })
            .collect()
    }

    fn perturbed(s: &Sim3, with_scale: bool) -> Sim3 {
        let mut delta = Vector7::from([0.08, -0.05, 0.1, 0.03, 0.04, -0.02, 0.0]);
        if with_scale {
            delta[SCALE] = 0.15;
        }
        Sim3::exp(&delta) * *s
    }

    fn error(found: &Sim3, want: &Sim3) -> (f64, f64, f64) {
        let rot_deg = (found.rotation.inverse() * want.rotation)
            .angle()
            .to_degrees();
        let trans = (found.translation - want.translation).norm();
        (rot_deg, trans, (found.scale / want.scale - 1.0).abs())
    }

    #[test]
    fn jacobians_match_numeric_derivatives() {
        let s = truth(1.6);
        for m in scene(&s, 5, 2, 11) {
            let lin = linearize(&one(), &s, &m).unwrap();
            let analytic = DMatrix::from_fn(4, 7, |r, c| lin.d_e_d_zeta[r / 2][(r % 2, c)]);
            let f = |zeta: &DVector<f64>| {
                let moved = Sim3::exp(&Vector7::from_column_slice(zeta.as_slice())) * s;
                let l = linearize(&one(), &moved, &m).unwrap();
                DVector::from_iterator(4, l.e[0].iter().chain(l.e[1].iter()).copied())
            };
            check_jacobian(
                "sim3 reprojection",
                &analytic,
                f,
                &DVector::zeros(7),
                1e-6,
                1e-5,
            );
        }
    }

    #[test]
    fn rig_jacobians_match_numeric_derivatives() {
        let (s, matches) = rig_scene(&truth(1.6), 5, 21);
        let rig = two();
        for m in matches {
            let lin = linearize(&rig, &s, &m).unwrap();
            let analytic = DMatrix::from_fn(4, 7, |r, c| lin.d_e_d_zeta[r / 2][(r % 2, c)]);
            let f = |zeta: &DVector<f64>| {
                let moved = Sim3::exp(&Vector7::from_column_slice(zeta.as_slice())) * s;
                let l = linearize(&rig, &moved, &m).unwrap();
                DVector::from_iterator(4, l.e[0].iter().chain(l.e[1].iter()).copied())
            };
            check_jacobian(
                "rig sim3 reprojection",
                &analytic,
                f,
                &DVector::zeros(7),
                1e-6,
                1e-5,
            );
        }
    }

    #[test]
    fn matches_seen_by_another_camera_converge_to_truth() {
        let (s, matches) = rig_scene(&truth(1.0), 60, 22);
        let out =
            optimize_sim3(&perturbed(&s, false), &matches, &two(), SIM3_TH2_MONO, true).unwrap();
        let (rot, trans, _) = error(&out.S_12, &s);
        assert!(rot < 0.05 && trans < 0.005, "{rot} deg, {trans} m");
        assert_eq!(out.num_inliers, 60);
        // A camera index the rig does not have is refused, naming the match.
        let mut bad = matches.clone();
        bad[7].camera2 = 2;
        let err = optimize_sim3(&s, &bad, &two(), SIM3_TH2_MONO, true).unwrap_err();
        assert_eq!(
            err.to_string(),
            OptimError::InvalidInput("match 7 names cameras 1 and 2 of a rig of 2".into())
                .to_string()
        );
    }

    #[test]
    fn perturbed_start_converges_to_truth() {
        let s = truth(1.6);
        let matches = scene(&s, 60, 0, 12);
        let out =
            optimize_sim3(&perturbed(&s, true), &matches, &one(), SIM3_TH2_MONO, false).unwrap();
        let (rot, trans, scale) = error(&out.S_12, &s);
        assert!(
            rot < 0.05 && trans < 0.005 && scale < 0.002,
            "{rot} deg, {trans} m, {scale}"
        );
        assert_eq!(out.num_inliers, 60);
        assert!(out.inliers.iter().all(|&f| f));
    }

    #[test]
    fn fixed_scale_converges_and_keeps_scale() {
        let s = truth(1.0);
        let matches = scene(&s, 60, 0, 13);
        let out =
            optimize_sim3(&perturbed(&s, false), &matches, &one(), SIM3_TH2_MONO, true).unwrap();
        assert_eq!(out.S_12.scale, 1.0);
        let (rot, trans, _) = error(&out.S_12, &s);
        assert!(rot < 0.05 && trans < 0.005, "{rot} deg, {trans} m");
        // A wrong but fixed scale stays where it was.
        let start = Sim3 {
            scale: 1.3,
            ..perturbed(&s, false)
        };
        let out = optimize_sim3(&start, &matches, &one(), SIM3_TH2_MONO, true).unwrap();
        assert_eq!(out.S_12.scale, 1.3);
    }

    #[test]
    fn outliers_are_flagged() {
        let s = truth(1.6);
        let matches = scene(&s, 80, 16, 14);
        let out =
            optimize_sim3(&perturbed(&s, true), &matches, &one(), SIM3_TH2_MONO, false).unwrap();
        assert!(
            out.inliers[..16].iter().all(|&f| !f),
            "{:?}",
            &out.inliers[..16]
        );
        assert!(out.inliers[16..].iter().all(|&f| f));
        assert_eq!(out.num_inliers, 64);
        let (rot, trans, scale) = error(&out.S_12, &s);
        assert!(
            rot < 0.05 && trans < 0.005 && scale < 0.002,
            "{rot} deg, {trans} m, {scale}"
        );
    }

    #[test]
    fn point_behind_a_camera_is_an_outlier() {
        let s = truth(1.6);
        let mut matches = scene(&s, 30, 0, 15);
        matches[0].p2 = -matches[0].p2 * 3.0;
        let out = optimize_sim3(&s, &matches, &one(), SIM3_TH2_MONO, false).unwrap();
        assert!(!out.inliers[0]);
        assert_eq!(out.num_inliers, 29);
    }

    #[test]
    fn bad_input_is_an_error() {
        let s = truth(1.6);
        let matches = scene(&s, 10, 0, 16);
        let run = |s: &Sim3, m: &[Sim3Match], th2: f64| optimize_sim3(s, m, &one(), th2, false);
        assert!(matches!(
            run(&s, &[], 10.0),
            Err(OptimError::InvalidInput(_))
        ));
        assert!(matches!(
            run(&s, &matches, 0.0),
            Err(OptimError::InvalidInput(_))
        ));
        assert!(matches!(
            run(&s, &matches, f64::NAN),
            Err(OptimError::InvalidInput(_))
        ));
        let zero_scale = Sim3 { scale: 0.0, ..s };
        assert!(matches!(
            run(&zero_scale, &matches, 10.0),
            Err(OptimError::InvalidInput(_))
        ));
        let negative_scale = Sim3 { scale: -1.0, ..s };
        assert!(matches!(
            run(&negative_scale, &matches, 10.0),
            Err(OptimError::InvalidInput(_))
        ));
        let nan_sim3 = Sim3 {
            scale: f64::NAN,
            ..s
        };
        assert!(matches!(
            run(&nan_sim3, &matches, 10.0),
            Err(OptimError::NonFinite { what: "sim3", .. })
        ));
        let mut bad = matches.clone();
        bad[4].p1.z = f64::INFINITY;
        assert_eq!(
            run(&s, &bad, 10.0),
            Err(OptimError::NonFinite {
                what: "observation",
                index: 4
            })
        );
        let mut bad = matches.clone();
        bad[7].uv2.y = f64::NAN;
        assert!(matches!(
            run(&s, &bad, 10.0),
            Err(OptimError::NonFinite { index: 7, .. })
        ));
        let mut bad = matches;
        bad[2].inv_sigma2_1 = 0.0;
        assert!(matches!(
            run(&s, &bad, 10.0),
            Err(OptimError::InvalidInput(_))
        ));
    }
}
