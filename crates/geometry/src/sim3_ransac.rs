//! RANSAC for the similarity between two keyframes from matched map points (ORB-SLAM2/3
//! `Sim3Solver`), as a pure function.
//!
//! Loop closing matches map points seen in keyframe 1 with map points seen in keyframe 2,
//! each expressed in its keyframe's reference frame (the camera's, or a rig's first
//! camera's). Three matches fix a similarity `S_12` (Horn / Umeyama); a match is an inlier
//! when both of its points reproject onto the other keyframe's keypoint, in the camera that
//! measured it: `S_12 * p2` near `uv1` and `S_21 * p1` near `uv2`. A keyframe of a rig is
//! one generalised camera: the camera indices route each reprojection, so a place seen
//! earlier by one camera and now by another verifies as any loop.

use nalgebra::{Vector2, Vector3};
use rand::Rng;

use crate::sim3::Sim3;
use crate::umeyama::umeyama;

/// One map-point match between keyframe 1 and keyframe 2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3Correspondence {
    /// The map point seen by keyframe 1, in keyframe 1's reference frame (metres).
    pub p1: Vector3<f64>,
    /// Its matched map point seen by keyframe 2, in keyframe 2's reference frame (metres of
    /// map 2).
    pub p2: Vector3<f64>,
    /// Undistorted keypoint observing `p1` in keyframe 1, pixels of camera `camera1`.
    pub uv1: Vector2<f64>,
    /// Undistorted keypoint observing `p2` in keyframe 2, pixels of camera `camera2`.
    pub uv2: Vector2<f64>,
    /// The camera of keyframe 1 that measured `uv1` (0 for a single camera).
    pub camera1: usize,
    /// The camera of keyframe 2 that measured `uv2`.
    pub camera2: usize,
    /// Squared reprojection threshold in keyframe 1, pixels^2 (ORB-SLAM:
    /// `9.21 * sigma2` of the keypoint's octave).
    pub max_err2_1: f64,
    /// Squared reprojection threshold in keyframe 2, pixels^2.
    pub max_err2_2: f64,
}

/// Parameters of [`sim3_ransac`]; `Default` gives ORB-SLAM's loop-closing values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3RansacParams {
    /// Probability of drawing at least one all-inlier sample, in `(0, 1)` (default 0.99).
    pub probability: f64,
    /// Fewest inliers accepted (default 20); values below 3 act as 3.
    pub min_inliers: usize,
    /// Upper bound on the number of hypotheses (default 300).
    pub max_iterations: usize,
    /// Fix the scale to 1 (stereo / RGB-D, where both maps have metric scale).
    pub fix_scale: bool,
}

impl Default for Sim3RansacParams {
    fn default() -> Self {
        Self {
            probability: 0.99,
            min_inliers: 20,
            max_iterations: 300,
            fix_scale: false,
        }
    }
}

/// Outcome of [`sim3_ransac`].
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct Sim3RansacResult {
    /// Similarity mapping camera-2 points to camera 1: `p1 ≈ S_12 * p2`. Its scale is exactly
    /// 1 with `fix_scale`.
    pub S_12: Sim3,
    /// `inliers[i]` is true when match `i` is consistent with `S_12` in both keyframes.
    pub inliers: Vec<bool>,
    /// Number of `true` entries in `inliers`, at least `min_inliers`.
    pub num_inliers: usize,
}

/// Minimal sample size: three non-collinear points fix a similarity.
const SAMPLE_SIZE: usize = 3;
/// Refits on the inlier set (each followed by a recount) while the inlier count grows.
const MAX_REFITS: usize = 3;

/// Estimates `S_12` from map-point matches by RANSAC on 3-point Horn/Umeyama hypotheses.
///
/// `project(camera, p)` is the projection of a reference-frame point (metres) into camera
/// `camera`'s undistorted pixels, `None` behind it; it is used for both keyframes. Match `i`
/// is an inlier of a hypothesis `S_12` when `|uv1 - project(camera1, S_12 p2)|^2 <=
/// max_err2_1` AND `|uv2 - project(camera2, S_12^-1 p1)|^2 <= max_err2_2`.
///
/// Iterations: like ORB-SLAM, the hypothesis budget starts at
/// `ceil(ln(1 - probability) / ln(1 - w^3))` with the inlier ratio `w = min_inliers / n`,
/// clamped to `[1, max_iterations]`, and shrinks as better hypotheses raise the observed
/// ratio. Samples whose points are collinear (or coincide) are skipped. The best hypothesis
/// is then refitted with Umeyama on all its inliers and the inliers recounted, repeated
/// while the count grows (ORB-SLAM keeps the 3-point estimate; the refit lowers its noise).
///
/// Returns `None` when there are fewer than `max(min_inliers, 3)` matches, any input value
/// is not finite or a threshold negative, `probability` is outside `(0, 1)`,
/// `max_iterations` is 0, every sample is degenerate, or the best hypothesis has fewer than
/// `min_inliers` inliers. Deterministic for a given `rng` state.
///
/// ```
/// use ferroslam_geometry::sim3::{Sim3, Vector7};
/// use ferroslam_geometry::sim3_ransac::{sim3_ransac, Sim3Correspondence, Sim3RansacParams};
/// use nalgebra::{Vector2, Vector3};
/// use rand::SeedableRng;
/// let project = |_camera: usize, p: &Vector3<f64>| {
///     (p.z > 0.0).then(|| Vector2::new(500.0 * p.x / p.z + 320.0, 500.0 * p.y / p.z + 240.0))
/// };
/// let s_12 = Sim3::exp(&Vector7::from([0.1, 0.0, -0.05, 0.0, 0.05, 0.0, 0.3]));
/// let matches: Vec<_> = (0..30)
///     .map(|i| {
///         let p1 = Vector3::new((i % 6) as f64 * 0.3 - 0.8, (i / 6) as f64 * 0.3 - 0.6, 3.0 + (i % 4) as f64 * 0.4);
///         let p2 = s_12.inverse().transform_point(&p1);
///         let (uv1, uv2) = (project(0, &p1).unwrap(), project(0, &p2).unwrap());
///         Sim3Correspondence { p1, p2, uv1, uv2, camera1: 0, camera2: 0, max_err2_1: 9.21, max_err2_2: 9.21 }
///     })
///     .collect();
/// let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
/// let found = sim3_ransac(&matches, project, &Sim3RansacParams::default(), &mut rng).unwrap();
/// assert_eq!(found.num_inliers, 30);
/// assert!((found.S_12.scale - s_12.scale).abs() < 1e-9);
/// ```
pub fn sim3_ransac(
    matches: &[Sim3Correspondence],
    project: impl Fn(usize, &Vector3<f64>) -> Option<Vector2<f64>>,
    params: &Sim3RansacParams,
    rng: &mut impl Rng,
) -> Option<Sim3RansacResult> {
    let n = matches.len();
    let min_inliers = params.min_inliers.max(SAMPLE_SIZE);
    if n < min_inliers
        || !(params.probability > 0.0 && params.probability < 1.0)
        || params.max_iterations == 0
        || !matches.iter().all(is_valid)
    {
        return None;
    }
    let with_scale = !params.fix_scale;
    let consistent = |s_12: &Sim3| inliers_of(matches, &project, s_12);
    let mut budget = iterations_for(min_inliers as f64 / n as f64, params);
    let mut best: Option<(Sim3, Vec<bool>, usize)> = None;
    let mut iteration = 0;
    while iteration < budget {
        iteration += 1;
        let sample = rand::seq::index::sample(rng, n, SAMPLE_SIZE);
        let p1: Vec<_> = sample.iter().map(|i| matches[i].p1).collect();
        let p2: Vec<_> = sample.iter().map(|i| matches[i].p2).collect();
        let Some(s_12) = umeyama(&p2, &p1, with_scale).filter(is_finite) else {
            continue;
        };
        let (flags, count) = consistent(&s_12);
        if best.as_ref().is_none_or(|b| count > b.2) {
            budget = budget.min(iterations_for(count as f64 / n as f64, params));
            best = Some((s_12, flags, count));
        }
    }
    let (mut s_12, mut flags, mut count) = best?;
    for _ in 0..MAX_REFITS {
        let (p1, p2): (Vec<_>, Vec<_>) = matches
            .iter()
            .zip(&flags)
            .filter(|(_, &inlier)| inlier)
            .map(|(m, _)| (m.p1, m.p2))
            .unzip();
        let Some(refit) = umeyama(&p2, &p1, with_scale).filter(is_finite) else {
            break;
        };
        let (refit_flags, refit_count) = consistent(&refit);
        if refit_count < count {
            break;
        }
        let grew = refit_count > count;
        (s_12, flags, count) = (refit, refit_flags, refit_count);
        if !grew {
            break;
        }
    }
    (count >= min_inliers).then_some(Sim3RansacResult {
        S_12: s_12,
        inliers: flags,
        num_inliers: count,
    })
}

/// RANSAC hypothesis count for inlier ratio `w`, clamped to `[1, max_iterations]`.
fn iterations_for(w: f64, params: &Sim3RansacParams) -> usize {
    let all_inlier = w.min(1.0).powi(SAMPLE_SIZE as i32);
    if all_inlier >= 1.0 {
        return 1;
    }
    let k = ((1.0 - params.probability).ln() / (1.0 - all_inlier).ln()).ceil();
    // w = 0 divides by ln(1) = 0; no sample can succeed then, so use the whole budget.
    if k.is_finite() {
        (k.max(1.0) as usize).min(params.max_iterations)
    } else {
        params.max_iterations
    }
}

/// Inlier flags of every match under `s_12`, and their count.
fn inliers_of(
    matches: &[Sim3Correspondence],
    project: &impl Fn(usize, &Vector3<f64>) -> Option<Vector2<f64>>,
    s_12: &Sim3,
) -> (Vec<bool>, usize) {
    let s_21 = s_12.inverse();
    let within = |camera: usize, p: Vector3<f64>, uv: &Vector2<f64>, max_err2: f64| {
        project(camera, &p).is_some_and(|pred| (pred - uv).norm_squared() <= max_err2)
    };
    let flags: Vec<bool> = matches
        .iter()
        .map(|m| {
            within(m.camera1, s_12.transform_point(&m.p2), &m.uv1, m.max_err2_1)
                && within(m.camera2, s_21.transform_point(&m.p1), &m.uv2, m.max_err2_2)
        })
        .collect();
    let count = flags.iter().filter(|&&f| f).count();
    (flags, count)
}

fn is_valid(m: &Sim3Correspondence) -> bool {
    let mut values = m.p1.iter().chain(&m.p2).chain(&m.uv1).chain(&m.uv2);
    values.all(|v| v.is_finite())
        && m.max_err2_1 >= 0.0
        && m.max_err2_2 >= 0.0
        && m.max_err2_1.is_finite()
        && m.max_err2_2.is_finite()
}

fn is_finite(s: &Sim3) -> bool {
    s.scale.is_finite()
        && s.scale > 0.0
        && s.translation.iter().all(|v| v.is_finite())
        && s.rotation.coords.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim3::Vector7;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    const FX: f64 = 520.0;

    fn project(p: &Vector3<f64>) -> Option<Vector2<f64>> {
        (p.z > 1e-6).then(|| Vector2::new(FX * p.x / p.z + 320.0, FX * p.y / p.z + 240.0))
    }

    /// One camera: every index is the reference camera.
    fn project_any(_camera: usize, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        project(p)
    }

    /// A point in front of a camera, inside a 640x480 image, 2-6 m deep.
    fn random_point(rng: &mut ChaCha8Rng) -> Vector3<f64> {
        let z = rng.random_range(2.0..6.0);
        let u = rng.random_range(20.0..620.0);
        let v = rng.random_range(20.0..460.0);
        Vector3::new((u - 320.0) / FX * z, (v - 240.0) / FX * z, z)
    }

    fn pixel_noise(rng: &mut ChaCha8Rng, sigma: f64) -> Vector2<f64> {
        // Uniform with standard deviation sigma per axis: enough for threshold tests.
        let a = sigma * 3f64.sqrt();
        Vector2::new(rng.random_range(-a..a), rng.random_range(-a..a))
    }

    /// `n` matches under `s_12`, the first `n_out` of them wrong (points on both sides drawn
    /// independently), with pixel noise (sigma 0.7 px) and 3D noise (sigma ~3 mm).
    fn scene(s_12: &Sim3, n: usize, n_out: usize, seed: u64) -> Vec<Sim3Correspondence> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s_21 = s_12.inverse();
        (0..n)
            .map(|i| {
                let p1 = random_point(&mut rng);
                let p2 = if i < n_out {
                    random_point(&mut rng)
                } else {
                    s_21.transform_point(&p1)
                };
                let uv1 = project(&p1).unwrap() + pixel_noise(&mut rng, 0.7);
                let uv2 = project(&p2).unwrap() + pixel_noise(&mut rng, 0.7);
                let jitter =
                    |rng: &mut ChaCha8Rng| Vector3::from_fn(|_, _| rng.random_range(-0.005..0.005));
                Sim3Correspondence {
                    p1: p1 + jitter(&mut rng),
                    p2: p2 + jitter(&mut rng) * s_21.scale,
                    uv1,
                    uv2,
                    camera1: 0,
                    camera2: 0,
                    max_err2_1: 9.21,
                    max_err2_2: 9.21,
                }
            })
            .collect()
    }

    fn truth(scale: f64) -> Sim3 {
        let mut zeta = Vector7::from([0.15, -0.05, 0.1, 0.03, -0.08, 0.02, 0.0]);
        zeta[crate::sim3::SCALE] = scale.ln();
        Sim3::exp(&zeta)
    }

    fn assert_close(found: &Sim3, want: &Sim3) {
        let err = (found.inverse() * *want).log();
        let rot_deg = err.fixed_rows::<3>(3).norm().to_degrees();
        let trans = (found.translation - want.translation).norm();
        assert!(rot_deg < 0.15, "rotation error {rot_deg} deg");
        assert!(trans < 0.01, "translation error {trans} m");
        assert!(
            (found.scale / want.scale - 1.0).abs() < 0.002,
            "scale {} vs {}",
            found.scale,
            want.scale
        );
    }

    fn run(matches: &[Sim3Correspondence], fix_scale: bool, seed: u64) -> Option<Sim3RansacResult> {
        let params = Sim3RansacParams {
            fix_scale,
            ..Default::default()
        };
        sim3_ransac(
            matches,
            project_any,
            &params,
            &mut ChaCha8Rng::seed_from_u64(seed),
        )
    }

    #[test]
    fn recovers_scaled_similarity_with_half_outliers() {
        let s = truth(1.7);
        for (n, n_out, seed) in [(100, 40, 1), (100, 50, 2), (80, 48, 3)] {
            let matches = scene(&s, n, n_out, seed);
            let found = run(&matches, false, seed).expect("a similarity");
            assert_close(&found.S_12, &s);
            // Every true match is found; wrong ones only survive by chance agreement.
            assert!(found.inliers[n_out..].iter().all(|&f| f), "seed {seed}");
            let false_positives = found.inliers[..n_out].iter().filter(|&&f| f).count();
            assert!(false_positives <= 1, "seed {seed}: {false_positives}");
            assert_eq!(
                found.num_inliers,
                found.inliers.iter().filter(|&&f| f).count()
            );
        }
    }

    #[test]
    fn fixed_scale_is_exactly_one() {
        let s = truth(1.0);
        let matches = scene(&s, 90, 45, 4);
        let found = run(&matches, true, 4).expect("a rigid transform");
        assert_eq!(found.S_12.scale, 1.0);
        assert_close(&found.S_12, &s);
        assert!(found.inliers[45..].iter().all(|&f| f));
    }

    #[test]
    fn deterministic_for_a_seed() {
        let matches = scene(&truth(1.7), 60, 30, 5);
        assert_eq!(run(&matches, false, 9), run(&matches, false, 9));
    }

    #[test]
    fn too_few_matches_or_inliers_give_none() {
        let s = truth(1.7);
        assert!(run(&scene(&s, 19, 0, 6), false, 6).is_none());
        assert!(run(&[], false, 6).is_none());
        // 100 matches of which only 15 agree: below min_inliers = 20.
        assert!(run(&scene(&s, 100, 85, 7), false, 7).is_none());
    }

    #[test]
    fn non_finite_or_invalid_input_gives_none() {
        let mut matches = scene(&truth(1.7), 40, 0, 8);
        assert!(run(&matches, false, 8).is_some());
        let bad_params = Sim3RansacParams {
            probability: f64::NAN,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        assert!(sim3_ransac(&matches, project_any, &bad_params, &mut rng).is_none());
        matches[3].p2.y = f64::NAN;
        assert!(run(&matches, false, 8).is_none());
        matches[3].p2.y = 1.0;
        matches[5].uv1.x = f64::INFINITY;
        assert!(run(&matches, false, 8).is_none());
    }

    #[test]
    fn collinear_points_give_none() {
        let s = truth(1.7);
        let s_21 = s.inverse();
        let matches: Vec<_> = (0..30)
            .map(|i| {
                let p1 = Vector3::new(0.1 * i as f64 - 1.0, 0.0, 4.0);
                let p2 = s_21.transform_point(&p1);
                Sim3Correspondence {
                    p1,
                    p2,
                    uv1: project(&p1).unwrap(),
                    uv2: project(&p2).unwrap(),
                    camera1: 0,
                    camera2: 0,
                    max_err2_1: 9.21,
                    max_err2_2: 9.21,
                }
            })
            .collect();
        assert!(run(&matches, false, 10).is_none());
    }

    /// A two-camera rig, camera 1 turned 90 degrees about the vertical axis and 0.1 m out:
    /// keyframe 1 saw the place through camera 1, keyframe 2 through camera 0. Each match is
    /// measured in its own camera, its points in the reference (camera-0) frames.
    #[test]
    #[allow(non_snake_case)]
    fn matches_measured_by_different_cameras_of_a_rig_verify() {
        let T_c1_c0 = nalgebra::Isometry3::new(
            Vector3::new(0.1, 0.0, 0.0),
            Vector3::new(0.0, std::f64::consts::FRAC_PI_2, 0.0),
        );
        let T_c0_c1 = T_c1_c0.inverse();
        let rig = |camera: usize, p: &Vector3<f64>| match camera {
            0 => project(p),
            _ => project(&(T_c1_c0 * nalgebra::Point3::from(*p)).coords),
        };
        // Keyframe 2's camera 0 faces where keyframe 1's camera 1 did.
        let s = Sim3::from_isometry(&T_c0_c1) * truth(1.0);
        let s_21 = s.inverse();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let matches: Vec<_> = (0..60)
            .map(|i| {
                // In front of camera 1 of keyframe 1, and of camera 0 of keyframe 2 for the
                // true matches; the first 20 are wrong.
                let p1 = (T_c0_c1 * nalgebra::Point3::from(random_point(&mut rng))).coords;
                let p2 = if i < 20 {
                    random_point(&mut rng)
                } else {
                    s_21.transform_point(&p1)
                };
                Sim3Correspondence {
                    p1,
                    p2,
                    uv1: rig(1, &p1).unwrap() + pixel_noise(&mut rng, 0.7),
                    uv2: rig(0, &p2).unwrap() + pixel_noise(&mut rng, 0.7),
                    camera1: 1,
                    camera2: 0,
                    max_err2_1: 9.21,
                    max_err2_2: 9.21,
                }
            })
            .collect();
        let params = Sim3RansacParams {
            fix_scale: true,
            ..Default::default()
        };
        let found = sim3_ransac(&matches, rig, &params, &mut ChaCha8Rng::seed_from_u64(11))
            .expect("a rigid transform");
        assert_close(&found.S_12, &s);
        assert!(found.inliers[20..].iter().all(|&f| f));
        // Through the wrong camera nothing reprojects: keyframe 1's points are beside
        // camera 0, not in front of it.
        let wrong = |_camera: usize, p: &Vector3<f64>| project(p);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        assert!(sim3_ransac(&matches, wrong, &params, &mut rng).is_none());
    }

    #[test]
    fn iteration_budget_follows_inlier_ratio() {
        let p = Sim3RansacParams::default();
        // ORB-SLAM: ln(0.01) / ln(1 - 0.2^3) = 573.3 -> capped at 300.
        assert_eq!(iterations_for(0.2, &p), 300);
        assert_eq!(iterations_for(0.5, &p), 35);
        assert_eq!(iterations_for(1.0, &p), 1);
        assert_eq!(iterations_for(0.0, &p), 300);
    }
}
