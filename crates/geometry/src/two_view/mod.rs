//! Monocular map initialisation: the relative pose of two views and the 3-D points of
//! their matches, from pixel matches alone (ORB-SLAM's `Initializer` /
//! `TwoViewReconstruction`).
//!
//! [`reconstruct_two_view`] fits a homography and a fundamental matrix by RANSAC on the
//! same 8-point samples (then refits the winners on their inliers), picks the model that
//! explains the matches better, decomposes it into candidate poses (a fundamental-matrix
//! pose is first refined on the robust Sampson error), and keeps the candidate that
//! triangulates the most inliers in front of both cameras. It refuses, with a [`TwoViewRefusal`] saying why, whenever the
//! answer is not trustworthy: too few matches, no model, an ambiguous choice of pose, too
//! few triangulated points, or too little parallax (e.g. pure rotation).
//!
//! # Frames and units
//!
//! Camera 1 is the origin. The result is `T_c2_c1` (`p_c2 = T_c2_c1 * p_c1`) with a
//! translation of unit norm: monocular scale is unobservable, so lengths (translation,
//! points) are in units of the baseline. Keypoints are UNDISTORTED pixels of one ideal
//! pinhole camera (both views share it).

mod correspondences;
mod essential_refinement;
mod from_fundamental;
mod from_homography;
mod fundamental;
mod homography;
mod linalg;
mod normalization;
mod pose_check;
mod ransac;
mod scoring;

use std::fmt;

use nalgebra::{Isometry3, Vector2, Vector3};
use thiserror::Error;

use crate::camera::PinholeCamera;
use crate::GeometryError;
use correspondences::Correspondences;
use from_fundamental::poses_from_fundamental;
use from_homography::poses_from_homography;
use fundamental::fit_fundamental;
use homography::fit_homography;
use normalization::normalize;
use pose_check::{check_pose, select_pose, Acceptance};
use ransac::{best_model, draw_samples, SAMPLE_SIZE};
use scoring::{score_fundamental, score_homography};

/// A fundamental-matrix pose needs its runner-up below this fraction of its good points
/// (ORB-SLAM: 0.7).
const FUNDAMENTAL_AMBIGUITY_RATIO: f64 = 0.7;
/// The same for the eight homography candidates, of which two often come close (0.75).
const HOMOGRAPHY_AMBIGUITY_RATIO: f64 = 0.75;
/// Fraction of the model's inliers that the pose must triangulate (ORB-SLAM: 0.9).
const MIN_GOOD_FRACTION: f64 = 0.9;

/// Parameters of [`reconstruct_two_view`].
#[derive(Debug, Clone, PartialEq)]
pub struct TwoViewOptions {
    /// Standard deviation of keypoint positions (pixels); scales every threshold.
    pub sigma_px: f64,
    /// RANSAC samples, shared by the homography and the fundamental matrix.
    pub ransac_iterations: usize,
    /// Smallest accepted parallax (degrees) of the reconstruction (see
    /// [`TwoViewReconstruction::parallax_deg`]).
    pub min_parallax_deg: f64,
    /// Fewest triangulated points for a reconstruction to be accepted.
    pub min_triangulated: usize,
    /// The homography is used when `S_H / (S_H + S_F)` exceeds this, else the fundamental
    /// matrix (`S` are the model scores).
    pub homography_ratio_threshold: f64,
    /// Seed of the RANSAC sampling RNG (ChaCha8).
    pub seed: u64,
}

impl Default for TwoViewOptions {
    /// ORB-SLAM's settings: sigma 1 px, 200 iterations, 1 degree, 50 points; a homography
    /// threshold of 0.45 (ORB-SLAM2 uses 0.40, ORB-SLAM3 0.50); seed 0.
    fn default() -> Self {
        Self {
            sigma_px: 1.0,
            ransac_iterations: 200,
            min_parallax_deg: 1.0,
            min_triangulated: 50,
            homography_ratio_threshold: 0.45,
            seed: 0,
        }
    }
}

/// The model a reconstruction came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwoViewModel {
    /// A homography: a planar (or very distant) scene.
    Homography,
    /// A fundamental matrix: a general 3-D scene.
    Fundamental,
}

impl fmt::Display for TwoViewModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Homography => "homography",
            Self::Fundamental => "fundamental-matrix",
        })
    }
}

/// An accepted two-view reconstruction.
#[derive(Debug, Clone, PartialEq)]
#[allow(non_snake_case)]
pub struct TwoViewReconstruction {
    /// Pose of camera 1 in camera 2: `p_c2 = T_c2_c1 * p_c1`, translation of unit norm.
    pub T_c2_c1: Isometry3<f64>,
    /// Per match (same order as `matches`): its point in camera 1 (units of the
    /// baseline) when it is an inlier that triangulates in front of both cameras with
    /// reprojection error below `2 sigma` and parallax above about 0.36 degrees.
    pub points_c1: Vec<Option<Vector3<f64>>>,
    /// Per match: inlier of the chosen model, or consistent with the accepted pose.
    pub inliers: Vec<bool>,
    /// The model the pose came from.
    pub model: TwoViewModel,
    /// `S_H / (S_H + S_F)`, in `[0, 1]`: near 0.5 or above for planar scenes.
    pub homography_ratio: f64,
    /// Parallax (degrees) of the triangulated points: the 51st largest, or the smallest
    /// if there are fewer (ORB-SLAM's statistic; a few well-spread points suffice).
    pub parallax_deg: f64,
}

/// Why [`reconstruct_two_view`] returned no reconstruction. Messages are meant for users.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TwoViewRefusal {
    /// An argument is invalid: an option outside its domain, intrinsics not finite or
    /// focal lengths not positive, or a match index out of range.
    #[error(transparent)]
    InvalidInput(#[from] GeometryError),
    /// Fewer usable matches (both pixels finite) than the 8 the solvers need.
    #[error("only {usable} usable matches, at least {needed} needed; track more features")]
    TooFewMatches {
        /// Matches with finite pixels in both views.
        usable: usize,
        /// The minimum.
        needed: usize,
    },
    /// Neither model could be fitted: the points have no spread (e.g. all identical or
    /// all on one image row/column) or every sample was degenerate.
    #[error("no homography or fundamental matrix fits: the matched points are degenerate")]
    NoModel,
    /// The chosen model has no usable decomposition: a homography whose singular values
    /// repeat (pure rotation, or motion along the plane normal) or an essential matrix
    /// that does not decompose.
    #[error("the {model} has no unique pose (pure rotation?); translate the camera sideways")]
    DegenerateModel {
        /// The model that was chosen.
        model: TwoViewModel,
    },
    /// Two candidate poses explain the matches about equally well.
    #[error(
        "ambiguous {model} pose: best candidate explains {best} matches, another {second}; \
         translate the camera more"
    )]
    Ambiguous {
        /// The model that was chosen.
        model: TwoViewModel,
        /// Good points of the best candidate.
        best: usize,
        /// Good points of the runner-up.
        second: usize,
    },
    /// The best pose triangulates too few matches.
    #[error("only {good} matches triangulate with the {model} pose, {needed} needed")]
    TooFewTriangulated {
        /// The model that was chosen.
        model: TwoViewModel,
        /// Good points of the best candidate.
        good: usize,
        /// `max(0.9 * model inliers, min_triangulated)`.
        needed: usize,
    },
    /// The points are seen from too similar directions to fix their depth.
    #[error(
        "parallax {parallax_deg:.2} deg is below {min_parallax_deg} deg; translate the camera \
         further"
    )]
    LowParallax {
        /// The model that was chosen.
        model: TwoViewModel,
        /// Parallax of the best candidate (degrees).
        parallax_deg: f64,
        /// The minimum asked for.
        min_parallax_deg: f64,
    },
}

/// Relative pose and points of two views of a static scene, from matched keypoints.
///
/// `keypoints1`, `keypoints2`: UNDISTORTED pixels in views 1 and 2 of `camera` (only its
/// pinhole intrinsics are used). `matches[k] = (i1, i2)` pairs `keypoints1[i1]` with
/// `keypoints2[i2]`. Matches with a non-finite pixel are ignored (never inliers, no point).
///
/// Deterministic for a given `options.seed`. Never panics; returns why it refused (see
/// [`TwoViewRefusal`]). In particular a rotation without translation, or a translation
/// too small for the scene depth, is refused rather than given an arbitrary direction.
pub fn reconstruct_two_view(
    keypoints1: &[Vector2<f64>],
    keypoints2: &[Vector2<f64>],
    matches: &[(usize, usize)],
    camera: &PinholeCamera,
    options: &TwoViewOptions,
) -> Result<TwoViewReconstruction, TwoViewRefusal> {
    validate(camera, options)?;
    let c = Correspondences::new(keypoints1, keypoints2, matches, camera)?;
    if c.len() < SAMPLE_SIZE {
        return Err(TwoViewRefusal::TooFewMatches {
            usable: c.len(),
            needed: SAMPLE_SIZE,
        });
    }
    let (Some(n1), Some(n2)) = (normalize(&c.pixels1), normalize(&c.pixels2)) else {
        return Err(TwoViewRefusal::NoModel);
    };
    let samples = draw_samples(c.len(), options.ransac_iterations, options.seed);
    let sigma = options.sigma_px;
    let homography = best_model(
        &samples,
        |indices, _| fit_homography(&n1, &n2, indices),
        |h| score_homography(h, &c.pixels1, &c.pixels2, sigma),
    );
    let fundamental = best_model(
        &samples,
        |indices, previous| fit_fundamental(&n1, &n2, indices, previous),
        |f| Some(score_fundamental(f, &c.pixels1, &c.pixels2, sigma)),
    );
    let score_of = |m: &Option<(_, scoring::Score)>| m.as_ref().map_or(0.0, |(_, s)| s.score);
    let (s_h, s_f) = (score_of(&homography), score_of(&fundamental));
    // Scores are finite and non-negative (`best_model` drops non-finite ones).
    if s_h + s_f <= 0.0 {
        return Err(TwoViewRefusal::NoModel);
    }
    let homography_ratio = s_h / (s_h + s_f);
    let (model, (_, score), poses) = if homography_ratio > options.homography_ratio_threshold {
        let h = homography.ok_or(TwoViewRefusal::NoModel)?;
        let poses = poses_from_homography(&h.0, camera);
        (TwoViewModel::Homography, h, poses)
    } else {
        let f = fundamental.ok_or(TwoViewRefusal::NoModel)?;
        let poses =
            poses_from_fundamental(&f.0, camera, &c.pixels1, &c.pixels2, &f.1.inliers, sigma);
        (TwoViewModel::Fundamental, f, poses)
    };
    let poses = poses.ok_or(TwoViewRefusal::DegenerateModel { model })?;
    let inlier_count = score.inliers.iter().filter(|&&b| b).count();
    let acceptance = Acceptance {
        model,
        ambiguity_ratio: match model {
            TwoViewModel::Homography => HOMOGRAPHY_AMBIGUITY_RATIO,
            TwoViewModel::Fundamental => FUNDAMENTAL_AMBIGUITY_RATIO,
        },
        min_good: options
            .min_triangulated
            .max((MIN_GOOD_FRACTION * inlier_count as f64).ceil() as usize),
        min_parallax_deg: options.min_parallax_deg,
    };
    let (pose, check) = select_pose(&poses, &c, &score.inliers, camera, sigma, &acceptance)?;
    // The model's inliers come from the RANSAC estimate; the accepted (refined) pose explains
    // more matches, so every match is re-checked against it for the returned points.
    let final_check = check_pose(&c, &vec![true; c.len()], camera, &pose, sigma);
    let mut points_c1 = vec![None; matches.len()];
    let mut inliers = vec![false; matches.len()];
    for (i, &k) in c.match_index.iter().enumerate() {
        points_c1[k] = final_check.points_c1[i];
        inliers[k] = final_check.points_c1[i].is_some() || score.inliers[i];
    }
    Ok(TwoViewReconstruction {
        T_c2_c1: pose,
        points_c1,
        inliers,
        model,
        homography_ratio,
        parallax_deg: check.parallax_deg,
    })
}

/// Rejects options and intrinsics outside their domain.
fn validate(camera: &PinholeCamera, options: &TwoViewOptions) -> Result<(), GeometryError> {
    let invalid = |name, value, reason| {
        Err(GeometryError::InvalidParameter {
            name,
            value,
            reason,
        })
    };
    for (name, value) in [("fx", camera.fx), ("fy", camera.fy)] {
        if !(value.is_finite() && value > 0.0) {
            return invalid(name, value, "focal length must be finite and positive");
        }
    }
    for (name, value) in [("cx", camera.cx), ("cy", camera.cy)] {
        if !value.is_finite() {
            return invalid(name, value, "principal point must be finite");
        }
    }
    if !(options.sigma_px.is_finite() && options.sigma_px > 0.0) {
        return invalid("sigma_px", options.sigma_px, "must be finite and positive");
    }
    if options.ransac_iterations == 0 {
        return invalid("ransac_iterations", 0.0, "must be at least 1");
    }
    if !(options.min_parallax_deg.is_finite() && options.min_parallax_deg >= 0.0) {
        return invalid(
            "min_parallax_deg",
            options.min_parallax_deg,
            "must be finite and non-negative",
        );
    }
    let ratio = options.homography_ratio_threshold;
    if !(0.0..=1.0).contains(&ratio) {
        return invalid("homography_ratio_threshold", ratio, "must be in [0, 1]");
    }
    Ok(())
}
