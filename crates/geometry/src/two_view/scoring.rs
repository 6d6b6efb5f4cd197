//! ORB-SLAM's model scores: truncated chi-square scores of symmetric transfer errors.
//!
//! Each match contributes, per direction, `threshold_2dof - chi2` when `chi2` (squared
//! pixel error over `sigma^2`) is within the direction's inlier threshold, and nothing
//! otherwise. Using the 2-DoF threshold as the reward for both models keeps the scores
//! of the homography (point-to-point errors, 2 DoF) and the fundamental matrix
//! (point-to-line errors, 1 DoF) comparable.

use nalgebra::{Matrix3, Vector2};

/// Chi-square 95% quantile, 1 degree of freedom (point-to-epipolar-line distance).
const CHI2_1DOF_95: f64 = 3.841;
/// Chi-square 95% quantile, 2 degrees of freedom (point-to-point transfer error).
const CHI2_2DOF_95: f64 = 5.991;

/// How well a model explains all matches.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Score {
    /// Sum of per-direction rewards (dimensionless, larger is better).
    pub score: f64,
    /// `inliers[i]`: match `i` is within the threshold in both directions.
    pub inliers: Vec<bool>,
}

/// Scores `h21` (`x2 ∝ H21 x1`, pixels) by transferring each point into the other view
/// with `h21` and its inverse. `None` if `h21` is not invertible.
pub(super) fn score_homography(
    h21: &Matrix3<f64>,
    pixels1: &[Vector2<f64>],
    pixels2: &[Vector2<f64>],
    sigma: f64,
) -> Option<Score> {
    let h12 = h21.try_inverse()?;
    let inv_sigma2 = 1.0 / (sigma * sigma);
    let transfer_chi2 = |h: &Matrix3<f64>, from: &Vector2<f64>, to: &Vector2<f64>| {
        let q = h * from.push(1.0);
        (to - q.xy() / q.z).norm_squared() * inv_sigma2
    };
    Some(score_directions(
        pixels1,
        pixels2,
        CHI2_2DOF_95,
        |p1, p2| [transfer_chi2(&h12, p2, p1), transfer_chi2(h21, p1, p2)],
    ))
}

/// Scores `f21` (`x2^T F21 x1 = 0`, pixels) by each point's distance to the epipolar line
/// of its match, in both views.
pub(super) fn score_fundamental(
    f21: &Matrix3<f64>,
    pixels1: &[Vector2<f64>],
    pixels2: &[Vector2<f64>],
    sigma: f64,
) -> Score {
    let inv_sigma2 = 1.0 / (sigma * sigma);
    let line_chi2 = |line: nalgebra::Vector3<f64>, p: &Vector2<f64>| {
        line.dot(&p.push(1.0)).powi(2) / line.xy().norm_squared() * inv_sigma2
    };
    score_directions(pixels1, pixels2, CHI2_1DOF_95, |p1, p2| {
        [
            line_chi2(f21.transpose() * p2.push(1.0), p1),
            line_chi2(f21 * p1.push(1.0), p2),
        ]
    })
}

/// Applies the truncated reward to the two directional chi-squares of every match. A
/// non-finite chi-square (point mapped to infinity) is an outlier.
fn score_directions(
    pixels1: &[Vector2<f64>],
    pixels2: &[Vector2<f64>],
    inlier_threshold: f64,
    chi2: impl Fn(&Vector2<f64>, &Vector2<f64>) -> [f64; 2],
) -> Score {
    let mut score = 0.0;
    let inliers = pixels1
        .iter()
        .zip(pixels2)
        .map(|(p1, p2)| {
            let mut inlier = true;
            for c in chi2(p1, p2) {
                if c <= inlier_threshold {
                    score += CHI2_2DOF_95 - c;
                } else {
                    // Also catches NaN.
                    inlier = false;
                }
            }
            inlier
        })
        .collect();
    Score { score, inliers }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_matches_get_full_reward_and_outliers_none() {
        let h = Matrix3::new(1.0, 0.0, 5.0, 0.0, 1.0, -3.0, 0.0, 0.0, 1.0);
        let p1 = [Vector2::new(10.0, 10.0), Vector2::new(100.0, 50.0)];
        let p2 = [Vector2::new(15.0, 7.0), Vector2::new(300.0, 50.0)];
        let s = score_homography(&h, &p1, &p2, 1.0).unwrap();
        assert_eq!(s.inliers, vec![true, false]);
        assert!((s.score - 2.0 * CHI2_2DOF_95).abs() < 1e-9);
        // A 1-px error along x at sigma 1 costs chi2 = 1 in each direction.
        let s = score_homography(&h, &p1[..1], &[Vector2::new(16.0, 7.0)], 1.0).unwrap();
        assert!((s.score - 2.0 * (CHI2_2DOF_95 - 1.0)).abs() < 1e-9);
        assert!(score_homography(&Matrix3::zeros(), &p1, &p2, 1.0).is_none());
    }

    #[test]
    fn fundamental_uses_line_distances() {
        // Pure x-translation, identity intrinsics: epipolar lines are the rows y = v.
        let f = Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
        let p1 = [Vector2::new(10.0, 20.0), Vector2::new(10.0, 20.0)];
        let p2 = [Vector2::new(50.0, 21.0), Vector2::new(50.0, 23.0)];
        let s = score_fundamental(&f, &p1, &p2, 1.0);
        assert_eq!(s.inliers, vec![true, false]);
        assert!((s.score - 2.0 * (CHI2_2DOF_95 - 1.0)).abs() < 1e-9);
    }
}
