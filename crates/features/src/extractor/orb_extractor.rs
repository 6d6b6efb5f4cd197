//! The extractor's entry point: one grey image (and an optional keypoint mask, see
//! [`crate::mask`]) in, ORB keypoints, descriptors and the pyramid out
//! ([`OrbExtractor::extract`]); both images of a stereo pair at once
//! ([`OrbExtractor::extract_stereo`]).

use rayon::prelude::*;

use super::brief::BriefPattern;
use super::image_pyramid::ImagePyramid;
use super::smoothing::smooth_for_brief;
use super::{detect_pyramid, FastThresholds, OrientedCorner};
use crate::mask::{check_mask_size, LevelMask};
use crate::{Descriptor, FeaturesError, GrayImage, Keypoint};

/// Most pyramid levels an extractor builds.
pub const MAX_LEVELS: usize = 32;

/// ORB-SLAM's extractor settings (its `ORBextractor` arguments). [`OrbConfig::default`] is
/// the one place their defaults are written: the SLAM configuration's extractor section
/// and the Python `OrbExtractor` take theirs from it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbConfig {
    /// Keypoints wanted per image (>= 1; fewer on textureless images). ORB-SLAM: 1000 at
    /// 640 px wide, 2000 at KITTI's 1241.
    pub n_features: usize,
    /// Scale between neighbouring pyramid levels (finite, > 1). ORB-SLAM: 1.2.
    pub scale_factor: f64,
    /// Pyramid levels, `1..=MAX_LEVELS`. ORB-SLAM: 8.
    pub n_levels: usize,
    /// FAST thresholds, `0 < min <= initial < 255`. ORB-SLAM: 20 and 7.
    pub fast: FastThresholds,
}

impl Default for OrbConfig {
    /// ORB-SLAM's settings for 640 x 480 images (its TUM settings).
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            fast: FastThresholds {
                initial: 20,
                min: 7,
            },
        }
    }
}

impl OrbConfig {
    /// Checks every setting, naming the first invalid one.
    ///
    /// # Errors
    /// [`FeaturesError::InvalidOrbConfig`].
    pub fn validate(&self) -> Result<(), FeaturesError> {
        let bad = |what: String| Err(FeaturesError::InvalidOrbConfig(what));
        if self.n_features == 0 {
            return bad("n_features must be >= 1, got 0".into());
        }
        if !(self.scale_factor.is_finite() && self.scale_factor > 1.0) {
            return bad(format!(
                "scale_factor must be finite and > 1, got {}",
                self.scale_factor
            ));
        }
        if !(1..=MAX_LEVELS).contains(&self.n_levels) {
            return bad(format!(
                "n_levels must be in [1, {MAX_LEVELS}], got {}",
                self.n_levels
            ));
        }
        let FastThresholds { initial, min } = self.fast;
        if !(0 < min && min <= initial && initial < 255) {
            return bad(format!(
                "need 0 < min_fast <= ini_fast < 255, got min_fast = {min}, ini_fast = {initial}"
            ));
        }
        Ok(())
    }

    /// Keypoints wanted per level, a geometric series summing to `n_features`:
    /// `n (1 - f) / (1 - f^L) f^l` with `f = 1 / scale_factor`, rounded half to even; the
    /// coarsest level takes the remainder (never negative). Finer levels have more area, so
    /// they get more.
    pub fn level_budgets(&self) -> Vec<usize> {
        let (n, levels) = (self.n_features as f64, self.n_levels);
        let f = 1.0 / self.scale_factor;
        let per_unit = if levels > 1 {
            n * (1.0 - f) / (1.0 - f.powf(levels as f64))
        } else {
            n
        };
        let mut budgets: Vec<usize> = (0..levels.saturating_sub(1))
            .map(|l| (per_unit * f.powf(l as f64)).round_ties_even() as usize)
            .collect();
        let given: usize = budgets.iter().sum();
        budgets.push(self.n_features.saturating_sub(given));
        budgets
    }
}

/// What [`OrbExtractor::extract`] finds in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct Features {
    /// Keypoints in RAW (distorted) level-0 pixels, grouped by octave (finest first), each
    /// octave in the order of the even spread; `angle_deg` in `[0, 360)`, `response` the FAST
    /// score. A keypoint of octave `l` lies on integer pixels of level `l`, scaled by
    /// `scale_factor^l` (in `f32`).
    pub keypoints: Vec<Keypoint>,
    /// The descriptor of each keypoint.
    pub descriptors: Vec<Descriptor>,
    /// The pyramid the keypoints were found on (stereo matching refines on its levels).
    pub pyramid: ImagePyramid,
}

/// ORB-SLAM's `ORBextractor`, descriptors bit for bit OpenCV's ORB.
///
/// Per image: the [`ImagePyramid`]; on every level in parallel, FAST with the per-cell
/// threshold fallback, the even spread to the level's budget and the intensity-centroid
/// orientation ([`detect_pyramid`]), while the levels are smoothed for BRIEF
/// ([`smooth_for_brief`]); then rotated BRIEF with OpenCV's tests
/// ([`BriefPattern::opencv`]) for all keypoints in parallel.
#[derive(Clone, Debug)]
pub struct OrbExtractor {
    config: OrbConfig,
    budgets: Vec<usize>,
    /// `scale_factor^l` rounded to `f32`, level pixels to level-0 pixels.
    scales: Vec<f32>,
    brief: BriefPattern,
}

impl OrbExtractor {
    /// An extractor with `config`.
    ///
    /// # Errors
    /// [`FeaturesError::InvalidOrbConfig`] naming the first invalid setting.
    pub fn new(config: OrbConfig) -> Result<Self, FeaturesError> {
        config.validate()?;
        Ok(Self {
            budgets: config.level_budgets(),
            scales: (0..config.n_levels)
                .map(|l| config.scale_factor.powf(l as f64) as f32)
                .collect(),
            brief: BriefPattern::opencv(),
            config,
        })
    }

    /// The settings.
    pub fn config(&self) -> &OrbConfig {
        &self.config
    }

    /// Keypoints wanted per level ([`OrbConfig::level_budgets`]).
    pub fn level_budgets(&self) -> &[usize] {
        &self.budgets
    }

    /// The features of a grey image (see [`Features`]); none on a textureless image or on
    /// levels too small to hold a keypoint. With a `mask` (the image's size), no keypoint
    /// lies on a zero mask pixel, and each level's budget goes to the open pixels (see
    /// [`crate::mask`]); a mask with no zero pixel gives exactly the unmasked features.
    ///
    /// # Errors
    /// [`FeaturesError::MaskSizeMismatch`] when `mask` is not the image's size;
    /// [`FeaturesError::ImageTooSmall`] when a pyramid level would have no pixels.
    pub fn extract(
        &self,
        image: &GrayImage<'_>,
        mask: Option<&GrayImage<'_>>,
    ) -> Result<Features, FeaturesError> {
        if let Some(mask) = mask {
            check_mask_size(image, mask)?;
        }
        // Called from outside rayon's pool, each parallel loop below would wake its threads
        // and wait for them; inside it (one entry per image) they just share the work.
        rayon::scope(|_| self.extract_in_pool(image, mask))
    }

    /// [`OrbExtractor::extract`], on a thread of rayon's pool, `mask` of the image's size.
    fn extract_in_pool(
        &self,
        image: &GrayImage<'_>,
        mask: Option<&GrayImage<'_>>,
    ) -> Result<Features, FeaturesError> {
        let pyramid = ImagePyramid::build(image, self.config.scale_factor, self.config.n_levels)?;
        let levels = pyramid.views();
        let masks: Vec<LevelMask<'_>> = mask
            .map(|m| self.scales.iter().map(|&s| LevelMask::new(*m, s)).collect())
            .unwrap_or_default();
        let (per_level, smoothed) = rayon::join(
            || detect_pyramid(&levels, &self.budgets, self.config.fast, &masks),
            || levels.par_iter().map(smooth_for_brief).collect::<Vec<_>>(),
        );
        let smoothed: Vec<GrayImage<'_>> = smoothed.iter().map(|l| l.view()).collect();
        let found: Vec<(usize, OrientedCorner)> = per_level
            .into_iter()
            .enumerate()
            .flat_map(|(l, level)| level.into_iter().map(move |c| (l, c)))
            .collect();
        let corners: Vec<(usize, usize, usize, f32)> = found
            .iter()
            .map(|&(l, c)| (l, c.corner.x as usize, c.corner.y as usize, c.angle_deg))
            .collect();
        let described = self.brief.describe_all(&smoothed, &corners);
        // Corners keep EDGE_PX > the tests' reach from the border: all are described.
        let (keypoints, descriptors): (Vec<Keypoint>, Vec<Descriptor>) = found
            .into_iter()
            .zip(described)
            .filter_map(|((l, c), d)| {
                let keypoint = Keypoint {
                    x: c.corner.x as f32 * self.scales[l],
                    y: c.corner.y as f32 * self.scales[l],
                    octave: l as u8,
                    angle_deg: c.angle_deg,
                    response: c.corner.score,
                };
                Some((keypoint, d?))
            })
            .unzip();
        Ok(Features {
            keypoints,
            descriptors,
            pyramid,
        })
    }

    /// [`OrbExtractor::extract`] on both images of a stereo pair, in parallel, each with its
    /// own optional mask.
    ///
    /// # Errors
    /// As [`OrbExtractor::extract`], the left image's error first.
    pub fn extract_stereo(
        &self,
        left: &GrayImage<'_>,
        right: &GrayImage<'_>,
        left_mask: Option<&GrayImage<'_>>,
        right_mask: Option<&GrayImage<'_>>,
    ) -> Result<(Features, Features), FeaturesError> {
        let (left, right) = rayon::join(
            || self.extract(left, left_mask),
            || self.extract(right, right_mask),
        );
        Ok((left?, right?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::extractor::EDGE_PX;

    /// A `w x h` image of bright and dark squares on a grey ramp, corners everywhere.
    fn checkered(w: usize, h: usize) -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let square = ((x / 9) * 7 + (y / 11) * 3) % 5;
                (40 + square * 40 + (x + y) % 7) as u8
            })
            .collect()
    }

    #[test]
    fn budgets_follow_the_geometric_series() {
        let budgets = OrbConfig::default().level_budgets();
        assert_eq!(budgets, [217, 181, 151, 126, 105, 87, 73, 60]);
        let one_level = OrbConfig {
            n_features: 500,
            scale_factor: 2.0,
            n_levels: 1,
            ..OrbConfig::default()
        };
        assert_eq!(one_level.level_budgets(), [500]);
    }

    #[test]
    fn invalid_settings_are_named() {
        let base = OrbConfig::default();
        let cases = [
            (
                OrbConfig {
                    n_features: 0,
                    ..base
                },
                "n_features",
            ),
            (
                OrbConfig {
                    scale_factor: 1.0,
                    ..base
                },
                "scale_factor",
            ),
            (
                OrbConfig {
                    scale_factor: f64::NAN,
                    ..base
                },
                "scale_factor",
            ),
            (
                OrbConfig {
                    n_levels: 0,
                    ..base
                },
                "n_levels",
            ),
            (
                OrbConfig {
                    n_levels: 33,
                    ..base
                },
                "n_levels",
            ),
            (
                OrbConfig {
                    fast: FastThresholds { initial: 5, min: 7 },
                    ..base
                },
                "min_fast",
            ),
        ];
        for (config, name) in cases {
            let message = OrbExtractor::new(config).unwrap_err().to_string();
            assert!(message.contains(name), "{message}");
        }
    }

    #[test]
    fn keypoints_are_level_pixels_scaled_to_level_0_with_their_descriptors() {
        let (w, h) = (320, 240);
        let data = checkered(w, h);
        let extractor = OrbExtractor::new(OrbConfig {
            n_features: 300,
            n_levels: 4,
            ..OrbConfig::default()
        })
        .unwrap();
        let features = extractor
            .extract(&GrayImage::new(w, h, &data).unwrap(), None)
            .unwrap();
        let n = features.keypoints.len();
        assert!(n > 200, "{n} keypoints");
        assert_eq!(features.descriptors.len(), n);
        assert_eq!(features.pyramid.levels().len(), 4);
        let octaves: Vec<u8> = features.keypoints.iter().map(|k| k.octave).collect();
        assert!(
            octaves.windows(2).all(|o| o[0] <= o[1]),
            "grouped by octave"
        );
        for k in &features.keypoints {
            let s = 1.2f64.powf(f64::from(k.octave)) as f32;
            let (lx, ly) = (k.x / s, k.y / s);
            assert!((lx - lx.round()).abs() < 1e-3 && (ly - ly.round()).abs() < 1e-3);
            assert!(lx.round() as usize >= EDGE_PX && ly.round() as usize >= EDGE_PX);
            assert!((0.0..360.0).contains(&k.angle_deg) && k.response >= 7.0);
        }
    }

    #[test]
    fn stereo_equals_two_extractions_and_blank_images_have_none() {
        let (w, h) = (200, 150);
        let (a, b) = (
            checkered(w, h),
            checkered(w, h).into_iter().rev().collect::<Vec<_>>(),
        );
        let (a, b) = (
            GrayImage::new(w, h, &a).unwrap(),
            GrayImage::new(w, h, &b).unwrap(),
        );
        let extractor = OrbExtractor::new(OrbConfig::default()).unwrap();
        let (left, right) = extractor.extract_stereo(&a, &b, None, None).unwrap();
        assert_eq!(left, extractor.extract(&a, None).unwrap());
        assert_eq!(right, extractor.extract(&b, None).unwrap());
        let blank = vec![128u8; w * h];
        let none = extractor
            .extract(&GrayImage::new(w, h, &blank).unwrap(), None)
            .unwrap();
        assert!(none.keypoints.is_empty() && none.descriptors.is_empty());
        // 1 / 1.2^4 < 0.5: level 4 has no pixel
        let too_small = extractor.extract(&GrayImage::new(1, 1, &[0]).unwrap(), None);
        assert!(matches!(
            too_small,
            Err(FeaturesError::ImageTooSmall { .. })
        ));
    }
}
