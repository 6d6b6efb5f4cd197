//! What the synthetic-scene tests share. Not every test binary uses every helper.
#![allow(dead_code)]

use ferroslam_features::Keypoint;
use ferroslam_geometry::umeyama::umeyama;
use nalgebra::{Isometry3, Vector2, Vector3};
use rand::Rng;

/// A synthetic keypoint at pixel `uv` of pyramid level `octave`, upright, unit response.
pub fn keypoint(uv: &Vector2<f64>, octave: u8) -> Keypoint {
    Keypoint {
        x: uv.x as f32,
        y: uv.y as f32,
        octave,
        angle_deg: 0.0,
        response: 1.0,
    }
}

/// A normally distributed sample of standard deviation `sigma` (Box-Muller): sensor noise is
/// closer to a Gaussian than to the uniform `random_range` gives.
pub fn gaussian(rng: &mut impl Rng, sigma: f64) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    sigma * (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Absolute trajectory error, metres: the RMS distance between the estimated camera centres
/// and the true ones after the rigid (SE(3), no scale) alignment that minimises it, as the
/// TUM benchmark's `evaluate_ate` computes it. `estimated[i]` and `truth[i]` are `T_w_c` of
/// one frame (each in its own world frame).
pub fn ate_rmse_m(estimated: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    let centres = |poses: &[Isometry3<f64>]| -> Vec<Vector3<f64>> {
        poses.iter().map(|T_w_c| T_w_c.translation.vector).collect()
    };
    let (est, gt) = (centres(estimated), centres(truth));
    let S_gt_est = umeyama(&est, &gt, false).expect("trajectories to align");
    let sum2: f64 = est
        .iter()
        .zip(&gt)
        .map(|(e, g)| (S_gt_est.transform_point(e) - g).norm_squared())
        .sum();
    (sum2 / est.len() as f64).sqrt()
}
