//! Keypoint masks: a grey image of the extracted image's size whose zero pixels hold no
//! keypoint (a robot's body, a logo, the dark ring outside a fisheye's image circle).
//!
//! The extractor applies a mask to every pyramid level's corners BEFORE the even spread
//! ([`crate::extractor::quadtree`]), so a level's budget goes to the open part of the image.
//! A corner at `(x, y)` of level `l` is tested at its level-0 keypoint position rounded
//! half to even, `(x * s_l, y * s_l)` with `s_l = scale_factor^l` in `f32`: the pixel the
//! returned keypoint rounds to (numpy's `rint`), so no keypoint ever lies on a zero pixel.

use crate::{FeaturesError, GrayImage, OwnedGrayImage};

/// A level-0 mask seen from one pyramid level.
#[derive(Clone, Copy, Debug)]
pub struct LevelMask<'a> {
    mask: GrayImage<'a>,
    /// Level pixels to level-0 pixels (`scale_factor^l` as `f32`, as the keypoints use).
    scale: f32,
}

impl<'a> LevelMask<'a> {
    /// `mask` (level-0 pixels) for the level whose pixels are `scale` level-0 pixels.
    pub fn new(mask: GrayImage<'a>, scale: f32) -> Self {
        Self { mask, scale }
    }

    /// Whether a corner at level pixel `(x, y)` may be a keypoint: its rounded level-0
    /// position lies on a non-zero mask pixel. Positions beyond the mask (a coarse level's
    /// last pixel can round one past level 0's) take the nearest edge pixel.
    pub fn allows(&self, x: u32, y: u32) -> bool {
        let at =
            |v: u32, len: usize| ((v as f32 * self.scale).round_ties_even() as usize).min(len - 1);
        let (w, h) = (self.mask.width(), self.mask.height());
        self.mask.pixels()[at(y, h) * w + at(x, w)] != 0
    }
}

/// Checks that `mask` is `image`'s size.
///
/// # Errors
/// [`FeaturesError::MaskSizeMismatch`] naming both sizes.
pub fn check_mask_size(image: &GrayImage<'_>, mask: &GrayImage<'_>) -> Result<(), FeaturesError> {
    if (mask.width(), mask.height()) == (image.width(), image.height()) {
        return Ok(());
    }
    Err(FeaturesError::MaskSizeMismatch {
        mask_width: mask.width(),
        mask_height: mask.height(),
        image_width: image.width(),
        image_height: image.height(),
    })
}

/// A `width x height` mask open (255) inside a fisheye's image circle and closed (0) outside,
/// `margin_px` inside its edge: pixel `(x, y)` (integer coordinates at pixel centres, as
/// keypoints use) is open when `(x - centre_x_px)^2 + (y - centre_y_px)^2 <=
/// (radius_px - margin_px)^2`.
///
/// Why a margin: FAST fires on the circle's hard edge, and a corner `d` px inside it still
/// sees the edge on a level of scale `s` when `d < 3 s` (FAST's ring); its descriptor patch
/// reaches `18 s`. A few pixels keep the finest levels' corners off the edge; coarse levels
/// need more.
///
/// # Errors
/// [`FeaturesError::InvalidMask`] for an empty size or a centre, radius or margin that is not
/// finite, a radius <= 0 or a margin < 0.
pub fn image_circle_mask(
    width: usize,
    height: usize,
    centre_x_px: f64,
    centre_y_px: f64,
    radius_px: f64,
    margin_px: f64,
) -> Result<OwnedGrayImage, FeaturesError> {
    let bad = |what: String| Err(FeaturesError::InvalidMask(what));
    if width == 0 || height == 0 {
        return bad(format!(
            "the image circle mask needs a size, got {width}x{height}"
        ));
    }
    if !(centre_x_px.is_finite() && centre_y_px.is_finite()) {
        return bad(format!(
            "the image circle's centre must be finite, got ({centre_x_px}, {centre_y_px}) px"
        ));
    }
    if !(radius_px.is_finite() && radius_px > 0.0) {
        return bad(format!(
            "the image circle's radius must be finite and > 0, got {radius_px} px"
        ));
    }
    if !(margin_px.is_finite() && margin_px >= 0.0) {
        return bad(format!(
            "the image circle's margin must be finite and >= 0, got {margin_px} px"
        ));
    }
    let open_r = (radius_px - margin_px).max(0.0);
    let pixels = (0..width * height)
        .map(|i| {
            let (dx, dy) = (
                (i % width) as f64 - centre_x_px,
                (i / width) as f64 - centre_y_px,
            );
            if dx * dx + dy * dy <= open_r * open_r {
                255
            } else {
                0
            }
        })
        .collect();
    OwnedGrayImage::new(width, height, pixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_circle_is_open_inside_its_margin_and_closed_outside() {
        let mask = image_circle_mask(21, 11, 10.0, 5.0, 6.0, 1.0).unwrap();
        let view = mask.view();
        let at = |x: usize, y: usize| view.pixels()[y * 21 + x];
        assert_eq!(at(10, 5), 255);
        assert_eq!(at(15, 5), 255); // 5 px from the centre: on the open radius 6 - 1
        assert_eq!(at(16, 5), 0); // 6 px: inside the circle, but in the margin
        assert_eq!(at(13, 9), 255); // 3^2 + 4^2 = 5^2
        assert_eq!(at(0, 0), 0);
        let open = view.pixels().iter().filter(|&&p| p == 255).count();
        // 81 lattice points within radius 5 (Gauss's circle problem, r = 5)
        assert_eq!(open, 81);
        assert!(view.pixels().iter().all(|&p| p == 0 || p == 255));
    }

    #[test]
    fn bad_circles_are_named() {
        let cases = [
            (image_circle_mask(0, 5, 1.0, 1.0, 2.0, 0.0), "size"),
            (image_circle_mask(5, 5, f64::NAN, 1.0, 2.0, 0.0), "centre"),
            (image_circle_mask(5, 5, 1.0, 1.0, 0.0, 0.0), "radius"),
            (image_circle_mask(5, 5, 1.0, 1.0, 2.0, -1.0), "margin"),
        ];
        for (result, name) in cases {
            let message = result.unwrap_err().to_string();
            assert!(message.contains(name), "{message}");
        }
    }

    #[test]
    fn a_mask_of_another_size_names_both_sizes() {
        let (a, b) = (vec![0u8; 12], vec![0u8; 10]);
        let image = GrayImage::new(4, 3, &a).unwrap();
        let mask = GrayImage::new(5, 2, &b).unwrap();
        assert_eq!(
            check_mask_size(&image, &mask).unwrap_err().to_string(),
            "the mask is 5x2 (width x height) but the image is 4x3: give a mask of the \
             image's size (0 = no keypoint there)"
        );
        assert!(check_mask_size(&image, &image).is_ok());
    }

    #[test]
    fn a_level_corner_is_tested_where_its_keypoint_rounds_and_clamped_to_the_mask() {
        // Open only at column 3 of row 0 (3x1 pixels at level 0): a level corner at x = 2
        // with scale 1.44 lands on 2.88 -> 3.
        let data = [0, 0, 0, 255];
        let mask = LevelMask::new(GrayImage::new(4, 1, &data).unwrap(), 1.44);
        assert!(mask.allows(2, 0));
        assert!(!mask.allows(1, 0)); // 1.44 -> 1
        assert!(mask.allows(3, 0)); // 4.32 -> 4, past the edge: column 3
    }
}
