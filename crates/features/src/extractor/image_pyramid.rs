//! The image pyramid ORB detects and describes on, built as OpenCV's ORB builds it.
//!
//! Level 0 is the image; level `l` is `round(width / s^l) x round(height / s^l)` pixels
//! (`s` the scale factor, `s^l` by `f64::powf`, rounding half to even), resized from level
//! `l - 1` by [`resize_linear_exact`] (OpenCV's `INTER_LINEAR_EXACT`). The levels are bit
//! for bit those OpenCV's ORB describes on, which keeps the descriptors equal to `cv2.ORB`'s.

use super::resize::resize_linear_exact;
use crate::image::{GrayImage, OwnedGrayImage};
use crate::FeaturesError;

/// An image and its downscaled copies, finest first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImagePyramid {
    levels: Vec<OwnedGrayImage>,
}

impl ImagePyramid {
    /// `(width, height)` (pixels) of the `n_levels` levels of a `width x height` image.
    ///
    /// # Errors
    /// [`FeaturesError::ImageTooSmall`] when a level would have no pixels.
    pub fn level_sizes(
        width: usize,
        height: usize,
        scale_factor: f64,
        n_levels: usize,
    ) -> Result<Vec<(usize, usize)>, FeaturesError> {
        (0..n_levels)
            .map(|level| {
                let scale = scale_factor.powf(level as f64);
                let shrink = |side: usize| (side as f64 / scale).round_ties_even() as usize;
                let (level_width, level_height) = (shrink(width), shrink(height));
                if level_width == 0 || level_height == 0 {
                    return Err(FeaturesError::ImageTooSmall {
                        width,
                        height,
                        n_levels,
                        scale_factor,
                        level,
                        level_width,
                        level_height,
                    });
                }
                Ok((level_width, level_height))
            })
            .collect()
    }

    /// The `n_levels` levels of `image` with `scale_factor` between neighbours.
    ///
    /// # Errors
    /// [`FeaturesError::ImageTooSmall`] when a level would have no pixels. The caller checks
    /// `scale_factor` and `n_levels` (see [`ScalePyramid::new`](crate::ScalePyramid::new)).
    pub fn build(
        image: &GrayImage<'_>,
        scale_factor: f64,
        n_levels: usize,
    ) -> Result<Self, FeaturesError> {
        let sizes = Self::level_sizes(image.width(), image.height(), scale_factor, n_levels)?;
        let mut levels = Vec::with_capacity(n_levels);
        levels.push(OwnedGrayImage::new(
            image.width(),
            image.height(),
            image.pixels().to_vec(),
        )?);
        // One entry into rayon's pool for all levels: from outside it, each level's parallel
        // resize would wake its threads and wait for them.
        rayon::scope(|_| {
            for &(w, h) in &sizes[1..] {
                let previous = levels[levels.len() - 1].view();
                let level = resize_linear_exact(&previous, w, h)
                    .unwrap_or_else(|| unreachable!("level_sizes gives no empty level"));
                levels.push(level);
            }
        });
        Ok(Self { levels })
    }

    /// The levels, finest (the image) first.
    pub fn levels(&self) -> &[OwnedGrayImage] {
        &self.levels
    }

    /// The levels, borrowed.
    pub fn views(&self) -> Vec<GrayImage<'_>> {
        self.levels.iter().map(OwnedGrayImage::view).collect()
    }

    /// The levels, finest first.
    pub fn into_levels(self) -> Vec<OwnedGrayImage> {
        self.levels
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_sizes_round_half_to_even() {
        let sizes = ImagePyramid::level_sizes(640, 480, 1.2, 8).unwrap();
        assert_eq!(
            sizes,
            [
                (640, 480),
                (533, 400),
                (444, 333),
                (370, 278),
                (309, 231),
                (257, 193),
                (214, 161),
                (179, 134)
            ]
        );
        // 5 / 2 = 2.5 and 7 / 2 = 3.5: ties to even
        assert_eq!(
            ImagePyramid::level_sizes(5, 7, 2.0, 2).unwrap(),
            [(5, 7), (2, 4)]
        );
    }

    #[test]
    fn too_deep_a_pyramid_is_refused() {
        let err = ImagePyramid::level_sizes(20, 10, 2.0, 6).unwrap_err();
        assert_eq!(
            err,
            FeaturesError::ImageTooSmall {
                width: 20,
                height: 10,
                n_levels: 6,
                scale_factor: 2.0,
                level: 5,
                level_width: 1,
                level_height: 0
            }
        );
        let data = [0u8; 200];
        assert!(ImagePyramid::build(&GrayImage::new(20, 10, &data).unwrap(), 2.0, 6).is_err());
    }

    #[test]
    fn levels_have_their_sizes_and_a_constant_image_stays_constant() {
        let (w, h) = (101, 77);
        let data = vec![93u8; w * h];
        let image = GrayImage::new(w, h, &data).unwrap();
        let pyramid = ImagePyramid::build(&image, 1.3, 5).unwrap();
        let sizes: Vec<(usize, usize)> = pyramid
            .levels()
            .iter()
            .map(|l| (l.view().width(), l.view().height()))
            .collect();
        assert_eq!(sizes, ImagePyramid::level_sizes(w, h, 1.3, 5).unwrap());
        assert_eq!(pyramid.views()[0].pixels(), &data[..]);
        assert!(pyramid
            .levels()
            .iter()
            .all(|l| l.view().pixels().iter().all(|&v| v == 93)));
    }

    #[test]
    fn each_level_is_resized_from_the_previous_one() {
        let (w, h) = (64, 48);
        let data: Vec<u8> = (0..w * h).map(|i| (i * 7 % 251) as u8).collect();
        let pyramid = ImagePyramid::build(&GrayImage::new(w, h, &data).unwrap(), 1.2, 3).unwrap();
        let views = pyramid.views();
        let again = resize_linear_exact(&views[1], views[2].width(), views[2].height()).unwrap();
        assert_eq!(again.view().pixels(), views[2].pixels());
    }
}
