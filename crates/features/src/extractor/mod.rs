//! ORB-SLAM's `ORBextractor`, whole: [`OrbExtractor`] takes a grey image and gives keypoints,
//! descriptors and the pyramid. Its stages:
//!
//! - the image pyramid ([`image_pyramid`], resized by [`resize`]), as OpenCV's ORB builds it;
//! - per level, FAST ([`fast`]) at the initial threshold with the per-cell fallback to the
//!   low one ([`threshold_fallback`]), the even spread to the level's budget ([`quadtree`])
//!   and the intensity-centroid orientation ([`orientation`]): [`detect_level`];
//! - the rotated BRIEF descriptors ([`brief`], OpenCV's tests in [`opencv_brief_tests`]) on
//!   the levels smoothed as OpenCV's ORB smooths them ([`smoothing`]).
//!
//! The pyramid and the smoothing equal OpenCV's bit for bit, so the descriptors equal
//! `cv2.ORB`'s on the same keypoints. Below [`OrbExtractor`], coordinates are integer pixels
//! of the level the corner was found on (x right, y down).

pub mod brief;
pub mod fast;
pub mod image_pyramid;
pub mod opencv_brief_tests;
pub mod orb_extractor;
pub mod orientation;
pub mod quadtree;
pub mod resize;
mod rounding;
pub mod smoothing;
pub mod threshold_fallback;

pub use image_pyramid::ImagePyramid;
pub use orb_extractor::{Features, OrbConfig, OrbExtractor};

use rayon::prelude::*;

use crate::mask::LevelMask;
use crate::GrayImage;
use orientation::CentroidPatch;

/// Keypoints keep this distance (level pixels) from the border: the rotated BRIEF pattern
/// reaches about 18 px from its centre (ORB's `edgeThreshold`, ORB-SLAM's `EDGE_THRESHOLD`).
pub const EDGE_PX: usize = 19;

/// Margin (level pixels) of the region the fallback grid and the spread cover: FAST needs
/// 3 px around a corner, so corners `EDGE_PX` inside lie 3 px inside this region.
const GRID_MARGIN_PX: usize = EDGE_PX - 3;

/// A FAST corner on one level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Corner {
    /// Column (level pixels).
    pub x: u32,
    /// Row (level pixels).
    pub y: u32,
    /// FAST score (see [`fast`]).
    pub score: f32,
}

/// A selected corner with its orientation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrientedCorner {
    /// The corner.
    pub corner: Corner,
    /// Intensity-centroid orientation, degrees in `[0, 360)`.
    pub angle_deg: f32,
}

/// FAST thresholds: every grid cell first tries `initial`, cells with no such corner fall back
/// to `min` (ORB-SLAM's `iniThFAST` = 20 and `minThFAST` = 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FastThresholds {
    /// Threshold tried first.
    pub initial: u8,
    /// Threshold in cells where `initial` finds nothing.
    pub min: u8,
}

/// Up to `budget` spread, oriented corners of one pyramid level, at least [`EDGE_PX`] from
/// its border and, with a `mask`, where it [allows](LevelMask::allows) them (tested before
/// the spread, so the budget goes to the open part). Levels too small to hold one give none.
pub fn detect_level(
    level: &GrayImage<'_>,
    budget: usize,
    fast: FastThresholds,
    mask: Option<&LevelMask<'_>>,
) -> Vec<OrientedCorner> {
    let (w, h) = (level.width(), level.height());
    if budget == 0 || w <= 2 * EDGE_PX + 1 || h <= 2 * EDGE_PX + 1 {
        return Vec::new();
    }
    let mut corners = threshold_fallback::fallback_corners(level, fast, EDGE_PX, GRID_MARGIN_PX);
    if let Some(mask) = mask {
        corners.retain(|c| mask.allows(c.x, c.y));
    }
    let extent = w.max(h) - 2 * GRID_MARGIN_PX;
    let patch = CentroidPatch::default();
    quadtree::spread(&corners, extent, GRID_MARGIN_PX, budget)
        .into_iter()
        .map(|i| {
            let corner = corners[i];
            let angle_deg = patch
                .angle_deg(level, corner.x as usize, corner.y as usize)
                .expect("corners lie EDGE_PX > PATCH_RADIUS inside the level");
            OrientedCorner { corner, angle_deg }
        })
        .collect()
}

/// [`detect_level`] on every level of a pyramid (in parallel), `budgets[l]` and `masks[l]`
/// for level `l` (no masks: `&[]`); levels without a budget get none.
pub fn detect_pyramid(
    levels: &[GrayImage<'_>],
    budgets: &[usize],
    fast: FastThresholds,
    masks: &[LevelMask<'_>],
) -> Vec<Vec<OrientedCorner>> {
    levels
        .par_iter()
        .enumerate()
        .map(|(l, level)| {
            let budget = budgets.get(l).copied().unwrap_or(0);
            detect_level(level, budget, fast, masks.get(l))
        })
        .collect()
}
