//! Scoring a relative-pose hypothesis by triangulating the inliers (ORB-SLAM's CheckRT),
//! and choosing among hypotheses only when the choice is unambiguous.

use nalgebra::{Isometry3, Vector3};

use super::correspondences::Correspondences;
use super::{TwoViewModel, TwoViewRefusal};
use crate::camera::PinholeCamera;
use crate::triangulation::{parallax_cos, triangulate_dlt};

/// Points whose rays meet at a smaller angle than this (cosine; about 0.36 degrees) are too
/// far away for their depth sign to mean anything: they count as consistent with any
/// hypothesis but are not kept as map points.
const MAX_POINT_PARALLAX_COS: f64 = 0.99998;

/// Which parallax stands for the whole reconstruction: the one of rank 50 (0-based) from
/// the largest, so a few well-spread points are enough (ORB-SLAM).
const PARALLAX_RANK: usize = 50;

/// How well one pose explains the matches.
#[derive(Debug, Clone)]
pub(super) struct PoseCheck {
    /// Inliers that triangulate consistently (in front of both cameras, reprojection error
    /// below `2 sigma` in both views), including those with negligible parallax.
    pub good: usize,
    /// Parallax of rank [`PARALLAX_RANK`] among the good points (degrees), 0 if none.
    pub parallax_deg: f64,
    /// Per usable match: the triangulated point in camera 1 (units of the baseline) if it
    /// is good and has more than negligible parallax.
    pub points_c1: Vec<Option<Vector3<f64>>>,
}

/// Triangulates every inlier with camera 1 at the origin and camera 2 at `T_c2_c1`.
#[allow(non_snake_case)]
pub(super) fn check_pose(
    c: &Correspondences,
    inliers: &[bool],
    camera: &PinholeCamera,
    T_c2_c1: &Isometry3<f64>,
    sigma: f64,
) -> PoseCheck {
    let max_error2 = 4.0 * sigma * sigma;
    let center2_c1 = T_c2_c1.inverse().translation.vector;
    // Pixel of a camera point, also for points behind the camera (negative depth is
    // tolerated for far points, so `PinholeCamera::project` is too strict here).
    let reprojection_error2 = |p: &Vector3<f64>, uv: &nalgebra::Vector2<f64>| {
        let u = camera.fx * p.x / p.z + camera.cx;
        let v = camera.fy * p.y / p.z + camera.cy;
        (u - uv.x).powi(2) + (v - uv.y).powi(2)
    };
    let mut parallax_cosines = Vec::new();
    let mut points_c1 = vec![None; c.len()];
    for i in (0..c.len()).filter(|&i| inliers[i]) {
        let Some(p1) = triangulate_dlt(&Isometry3::identity(), T_c2_c1, &c.rays1[i], &c.rays2[i])
        else {
            continue;
        };
        let p2 = T_c2_c1 * nalgebra::Point3::from(p1);
        let cos = parallax_cos(&p1, &Vector3::zeros(), &center2_c1);
        let significant = cos < MAX_POINT_PARALLAX_COS;
        if significant && (p1.z <= 0.0 || p2.z <= 0.0) {
            continue;
        }
        // `!(e < max)` also rejects NaN (a point on a camera plane).
        if !(reprojection_error2(&p1, &c.pixels1[i]) < max_error2
            && reprojection_error2(&p2.coords, &c.pixels2[i]) < max_error2)
        {
            continue;
        }
        parallax_cosines.push(cos);
        if significant {
            points_c1[i] = Some(p1);
        }
    }
    parallax_cosines.sort_unstable_by(f64::total_cmp);
    let parallax_deg = parallax_cosines
        .get(PARALLAX_RANK.min(parallax_cosines.len().saturating_sub(1)))
        .map_or(0.0, |cos| cos.acos().to_degrees());
    PoseCheck {
        good: parallax_cosines.len(),
        parallax_deg,
        points_c1,
    }
}

/// What a pose must achieve to be accepted.
pub(super) struct Acceptance {
    /// Which model the hypotheses come from (for the refusal reason).
    pub model: TwoViewModel,
    /// The runner-up must explain at most this fraction of the winner's good points.
    pub ambiguity_ratio: f64,
    /// Fewest good points.
    pub min_good: usize,
    /// Smallest reconstruction parallax (degrees).
    pub min_parallax_deg: f64,
}

/// Checks every hypothesis and returns the best one with its check, or why none is
/// acceptable: the best must have enough good points, clearly beat the runner-up and have
/// enough parallax (tested in that order).
#[allow(non_snake_case)]
pub(super) fn select_pose(
    hypotheses: &[Isometry3<f64>],
    c: &Correspondences,
    inliers: &[bool],
    camera: &PinholeCamera,
    sigma: f64,
    acceptance: &Acceptance,
) -> Result<(Isometry3<f64>, PoseCheck), TwoViewRefusal> {
    let model = acceptance.model;
    let mut checks: Vec<(Isometry3<f64>, PoseCheck)> = hypotheses
        .iter()
        .map(|T_c2_c1| (*T_c2_c1, check_pose(c, inliers, camera, T_c2_c1, sigma)))
        .collect();
    // Stable sort: among equals the first hypothesis wins, deterministically.
    checks.sort_by_key(|(_, check)| std::cmp::Reverse(check.good));
    let second = checks.get(1).map_or(0, |(_, check)| check.good);
    let Some((pose, best)) = checks.into_iter().next() else {
        return Err(TwoViewRefusal::DegenerateModel { model });
    };
    if best.good < acceptance.min_good {
        // Too few points explained whatever else happens; say so before ambiguity.
        return Err(TwoViewRefusal::TooFewTriangulated {
            model,
            good: best.good,
            needed: acceptance.min_good,
        });
    }
    if second as f64 >= acceptance.ambiguity_ratio * best.good as f64 {
        return Err(TwoViewRefusal::Ambiguous {
            model,
            best: best.good,
            second,
        });
    }
    // `parallax_deg` is never NaN (acos of a clamped cosine, or 0).
    if best.parallax_deg < acceptance.min_parallax_deg {
        return Err(TwoViewRefusal::LowParallax {
            model,
            parallax_deg: best.parallax_deg,
            min_parallax_deg: acceptance.min_parallax_deg,
        });
    }
    Ok((pose, best))
}
