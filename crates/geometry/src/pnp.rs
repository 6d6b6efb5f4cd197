//! Camera pose from 3D-2D matches with outliers: RANSAC over 5-point [`crate::epnp`]
//! samples, then Gauss-Newton refinement on the inliers (the role of ORB-SLAM's
//! `PnPsolver` in relocalisation).

use nalgebra::{Isometry3, Matrix6, Vector2, Vector3, Vector6};
use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::camera::CameraModel;
use crate::epnp::epnp;
use crate::se3::{self, ROT, TRANS};
use crate::so3::hat;

/// Points per RANSAC sample: EPnP is not reliable on 4 (see [`crate::epnp::epnp`]), and
/// one extra point costs few iterations (30% outliers at 0.99 confidence: 26 instead of 17).
const SAMPLE_SIZE: usize = 5;

/// Largest angle (degrees) off a fisheye's axis of the rays EPnP samples: their `(x/z, y/z)`
/// is an ordinary pinhole point, whose plane grows without bound towards 90 degrees.
pub const FRONT_RAY_MAX_DEG: f64 = 70.0;

/// RANSAC parameters for [`pnp_ransac`].
#[derive(Debug, Clone, PartialEq)]
pub struct PnpRansacOptions {
    /// Upper bound on RANSAC hypotheses.
    pub max_iterations: usize,
    /// Inlier threshold (pixels) for a point with `sigma2 = 1`; point `i` is an inlier when
    /// its squared reprojection error is below `reprojection_threshold_px^2 * sigma2[i]`.
    pub reprojection_threshold_px: f64,
    /// Fewest inliers for a pose to be returned.
    pub min_inliers: usize,
    /// Probability of drawing at least one all-inlier sample; stops RANSAC early.
    pub confidence: f64,
    /// Seed of the sampling RNG (ChaCha8).
    pub seed: u64,
}

impl Default for PnpRansacOptions {
    /// ORB-SLAM's relocalisation settings: 300 iterations, chi-square 95% threshold for 2
    /// DoF (`sqrt(5.991) ≈ 2.45 px` at unit sigma), 10 inliers, 0.99 confidence, seed 0.
    fn default() -> Self {
        Self {
            max_iterations: 300,
            reprojection_threshold_px: 5.991f64.sqrt(),
            min_inliers: 10,
            confidence: 0.99,
            seed: 0,
        }
    }
}

/// A pose found by [`pnp_ransac`].
#[derive(Debug, Clone, PartialEq)]
#[allow(non_snake_case)]
pub struct PnpSolution {
    /// Pose of the world in the camera: `p_c = T_c_w * p_w`.
    pub T_c_w: Isometry3<f64>,
    /// `inliers[i]` tells whether match `i` agrees with `T_c_w`.
    pub inliers: Vec<bool>,
}

/// Robust pose `T_c_w` from world points `points_w` (metres) and their core pixels `pixels`
/// in `camera` (undistorted for the pinhole, raw for a fisheye).
///
/// EPnP needs rays in front of one image plane: with a fisheye the hypotheses are drawn
/// only from matches whose ray lies within [`FRONT_RAY_MAX_DEG`] of the optical axis, and the
/// inlier test and refinement then use every match through the model.
///
/// `sigma2[i]` is the pixel variance of match `i` (ORB-SLAM: the squared scale factor of
/// the keypoint's pyramid level); it scales the inlier threshold and weighs the
/// refinement by `1 / sigma2`. An empty slice means 1 for every point; a match whose
/// variance is not positive and finite is never an inlier.
///
/// Deterministic for a given `options.seed`. Returns `None` if the slices differ in length,
/// if there are fewer matches than `max(5, min_inliers)`, or if the best pose has fewer
/// than `min_inliers` inliers after refinement. Matches with non-finite values are never
/// inliers.
pub fn pnp_ransac(
    points_w: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    sigma2: &[f64],
    camera: &CameraModel,
    options: &PnpRansacOptions,
) -> Option<PnpSolution> {
    let n = points_w.len();
    if pixels.len() != n
        || !(sigma2.is_empty() || sigma2.len() == n)
        || n < SAMPLE_SIZE.max(options.min_inliers)
    {
        return None;
    }
    let problem = Problem {
        points_w,
        pixels,
        camera,
        // An empty slice means unit variance; `residual` skips unusable (<= 0, non-finite)
        // variances rather than let them poison the solve.
        sigma2: (0..n)
            .map(|i| sigma2.get(i).copied().unwrap_or(1.0))
            .collect(),
        threshold2: options.reprojection_threshold_px.powi(2),
    };
    // (x, y, 1) rays; the matches EPnP may sample.
    let (rays, eligible): (Vec<Vector3<f64>>, Vec<usize>) = match camera {
        CameraModel::Pinhole(c) => (
            pixels.iter().map(|uv| c.unproject(uv)).collect(),
            (0..n).collect(),
        ),
        CameraModel::KannalaBrandt(_) => {
            let min_z = FRONT_RAY_MAX_DEG.to_radians().cos();
            let rays: Vec<_> = pixels
                .iter()
                .map(|uv| match camera.unproject(uv) {
                    Some(r) if r.z > min_z => r / r.z,
                    _ => Vector3::repeat(f64::NAN),
                })
                .collect();
            let eligible = (0..n).filter(|&i| rays[i].x.is_finite()).collect();
            (rays, eligible)
        }
    };
    if eligible.len() < SAMPLE_SIZE {
        return None;
    }

    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut best: Option<(usize, Isometry3<f64>)> = None;
    let mut needed = options.max_iterations;
    let mut iteration = 0;
    while iteration < needed.min(options.max_iterations) {
        iteration += 1;
        let idx = sample(&mut rng, eligible.len(), SAMPLE_SIZE);
        let sample_w: Vec<_> = idx.iter().map(|i| points_w[eligible[i]]).collect();
        let sample_rays: Vec<_> = idx.iter().map(|i| rays[eligible[i]]).collect();
        let Some(hypothesis) = epnp(&sample_w, &sample_rays) else {
            continue;
        };
        let count = problem.inliers(&hypothesis).iter().filter(|&&b| b).count();
        if best.as_ref().is_some_and(|(c, _)| *c >= count) {
            continue;
        }
        best = Some((count, hypothesis));
        needed = iterations_needed(count as f64 / n as f64, options.confidence);
    }

    let (count, mut pose) = best?;
    if count < options.min_inliers {
        return None;
    }
    // Refine, re-classify, repeat until the inlier set is stable (ORB-SLAM's Refine()).
    let mut inliers = problem.inliers(&pose);
    for _ in 0..5 {
        pose = problem.refine(&pose, &inliers);
        let next = problem.inliers(&pose);
        let stable = next == inliers;
        inliers = next;
        if stable {
            break;
        }
    }
    (inliers.iter().filter(|&&b| b).count() >= options.min_inliers).then_some(PnpSolution {
        T_c_w: pose,
        inliers,
    })
}

/// RANSAC iterations for `confidence` given an inlier ratio.
fn iterations_needed(inlier_ratio: f64, confidence: f64) -> usize {
    let all_inliers = inlier_ratio.powi(SAMPLE_SIZE as i32);
    if all_inliers >= 1.0 {
        return 1;
    }
    let k = (1.0 - confidence).ln() / (1.0 - all_inliers).ln();
    if k.is_finite() && k >= 0.0 {
        k.ceil() as usize
    } else {
        usize::MAX
    }
}

/// The matches and how to score a pose against them.
struct Problem<'a> {
    points_w: &'a [Vector3<f64>],
    pixels: &'a [Vector2<f64>],
    camera: &'a CameraModel,
    sigma2: Vec<f64>,
    threshold2: f64,
}

impl Problem<'_> {
    /// Residual `pixel - project(T_c_w p_w)` and `p_c`, or `None` if the point does not
    /// project or its variance is unusable.
    #[allow(non_snake_case)]
    fn residual(&self, T_c_w: &Isometry3<f64>, i: usize) -> Option<(Vector2<f64>, Vector3<f64>)> {
        if !(self.sigma2[i] > 0.0 && self.sigma2[i].is_finite()) {
            return None;
        }
        let p_c = T_c_w.rotation * self.points_w[i] + T_c_w.translation.vector;
        let r = self.pixels[i] - self.camera.project(&p_c)?;
        r.iter().all(|v| v.is_finite()).then_some((r, p_c))
    }

    #[allow(non_snake_case)]
    fn inliers(&self, T_c_w: &Isometry3<f64>) -> Vec<bool> {
        (0..self.points_w.len())
            .map(|i| {
                self.residual(T_c_w, i)
                    .is_some_and(|(r, _)| r.norm_squared() < self.threshold2 * self.sigma2[i])
            })
            .collect()
    }

    /// Gauss-Newton on the inliers' weighted reprojection error, left perturbation
    /// `T_c_w <- exp(delta) T_c_w` with `delta` in the camera frame.
    #[allow(non_snake_case)]
    fn refine(&self, T_c_w: &Isometry3<f64>, inliers: &[bool]) -> Isometry3<f64> {
        let mut pose = *T_c_w;
        for _ in 0..10 {
            let mut h = Matrix6::zeros();
            let mut g = Vector6::zeros();
            for i in (0..inliers.len()).filter(|&i| inliers[i]) {
                let Some((r, p_c)) = self.residual(&pose, i) else {
                    continue;
                };
                let Some((_, d_uv_d_p_c)) = self.camera.project_with_jacobian(&p_c) else {
                    continue;
                };
                // d p_c / d delta = [I, -hat(p_c)]; the residual is pixel - uv.
                let mut d_p_c_d_delta = nalgebra::Matrix3x6::zeros();
                d_p_c_d_delta
                    .fixed_view_mut::<3, 3>(0, TRANS.start)
                    .fill_with_identity();
                d_p_c_d_delta
                    .fixed_view_mut::<3, 3>(0, ROT.start)
                    .copy_from(&-hat(&p_c));
                let j = -(d_uv_d_p_c * d_p_c_d_delta);
                let w = 1.0 / self.sigma2[i];
                h += j.transpose() * j * w;
                g += j.transpose() * r * w;
            }
            let Some(delta) = h.cholesky().map(|c| c.solve(&-g)) else {
                break;
            };
            if !delta.iter().all(|v| v.is_finite()) {
                break;
            }
            pose = se3::exp(&delta) * pose;
            if delta.norm() < 1e-10 {
                break;
            }
        }
        pose
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::test_cameras;

    #[test]
    fn iterations_needed_matches_formula() {
        assert_eq!(iterations_needed(1.0, 0.99), 1);
        assert_eq!(iterations_needed(0.0, 0.99), usize::MAX);
        // (1 - 0.5^5)^k <= 0.01  ->  k = 146.
        assert_eq!(iterations_needed(0.5, 0.99), 146);
    }

    #[test]
    #[allow(non_snake_case)]
    fn fisheye_pose_from_points_all_around_with_outliers() {
        use crate::camera::test_fisheye_cameras;
        use rand::Rng;
        let (_, lens) = test_fisheye_cameras()[0];
        let camera = CameraModel::from(lens);
        let T_c_w = se3::exp(&Vector6::new(0.2, -0.1, 0.3, 0.1, -0.2, 0.05));
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut points_w, mut pixels, mut beyond_90) = (Vec::new(), Vec::new(), 0);
        while points_w.len() < 150 {
            // Half near the axis, half 80-97 degrees off it.
            let theta: f64 = if points_w.len() % 2 == 0 {
                rng.random_range(0.0..1.2)
            } else {
                rng.random_range(1.4..1.7)
            };
            let phi: f64 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
            let dir = Vector3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            let p_c = dir * rng.random_range(1.0..6.0);
            let mut uv = camera.project(&p_c).unwrap();
            if points_w.len() % 5 == 0 {
                uv += Vector2::new(rng.random_range(-60.0..60.0), rng.random_range(-60.0..60.0));
            } else {
                uv += Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
                beyond_90 += usize::from(p_c.z < 0.0);
            }
            points_w.push((T_c_w.inverse() * nalgebra::Point3::from(p_c)).coords);
            pixels.push(uv);
        }
        let sol = pnp_ransac(
            &points_w,
            &pixels,
            &[],
            &camera,
            &PnpRansacOptions::default(),
        )
        .expect("a pose");
        let err = se3::log(&(sol.T_c_w * T_c_w.inverse()));
        assert!(err.norm() < 5e-3, "pose error {err}");
        // Matches beyond 90 degrees never enter EPnP, but the refined pose keeps them.
        let kept = (0..150)
            .filter(|&i| sol.inliers[i] && (T_c_w * nalgebra::Point3::from(points_w[i])).z < 0.0)
            .count();
        assert!(beyond_90 > 5 && kept == beyond_90, "{kept} of {beyond_90}");
        assert!((0..150).step_by(5).all(|i| !sol.inliers[i]));
    }

    #[test]
    fn rejects_mismatched_or_too_few() {
        let (_, camera) = test_cameras()[0];
        let p = vec![Vector3::new(0.0, 0.0, 1.0); 20];
        let uv = vec![Vector2::new(300.0, 200.0); 20];
        let opts = PnpRansacOptions::default();
        assert!(pnp_ransac(&p, &uv[..19], &[], &camera.into(), &opts).is_none());
        assert!(pnp_ransac(&p, &uv, &[1.0; 3], &camera.into(), &opts).is_none());
        assert!(pnp_ransac(&p[..5], &uv[..5], &[], &camera.into(), &opts).is_none());
    }
}
