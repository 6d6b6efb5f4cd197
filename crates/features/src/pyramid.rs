//! The ORB image pyramid's scale factors (ORB-SLAM `Frame::mvScaleFactors` and friends).

use crate::FeaturesError;

/// Per-level scale factors of an ORB pyramid.
///
/// Level `i` is downsampled by `scale[i] = scale_factor^i`; `sigma2[i] = scale[i]^2` is the
/// variance (px^2 at level 0) of a keypoint detected at that level, used to weight residuals
/// and epipolar/chi-square tests. The `inv_*` vectors are the element-wise reciprocals.
#[derive(Clone, Debug, PartialEq)]
pub struct ScalePyramid {
    /// Scale ratio between consecutive levels (> 1; ORB-SLAM: 1.2).
    pub scale_factor: f64,
    /// Number of levels (>= 1; ORB-SLAM: 8).
    pub n_levels: usize,
    /// `scale_factor^i`.
    pub scale: Vec<f64>,
    /// `1 / scale[i]`.
    pub inv_scale: Vec<f64>,
    /// `scale[i]^2` (px^2).
    pub sigma2: Vec<f64>,
    /// `1 / sigma2[i]`.
    pub inv_sigma2: Vec<f64>,
}

impl ScalePyramid {
    /// Builds the pyramid tables.
    ///
    /// # Errors
    /// [`FeaturesError::InvalidPyramid`] if `scale_factor` is not finite and > 1, or
    /// `n_levels == 0`.
    pub fn new(scale_factor: f64, n_levels: usize) -> Result<Self, FeaturesError> {
        if !(scale_factor.is_finite() && scale_factor > 1.0) || n_levels == 0 {
            return Err(FeaturesError::InvalidPyramid {
                scale_factor,
                n_levels,
            });
        }
        let scale: Vec<f64> = (0..n_levels).map(|i| scale_factor.powi(i as i32)).collect();
        let sigma2: Vec<f64> = scale.iter().map(|s| s * s).collect();
        Ok(Self {
            scale_factor,
            n_levels,
            inv_scale: scale.iter().map(|s| 1.0 / s).collect(),
            inv_sigma2: sigma2.iter().map(|s| 1.0 / s).collect(),
            scale,
            sigma2,
        })
    }

    /// Predicts the pyramid level at which a map point seen at `distance` (m) should be
    /// detected, given its `max_distance` (m) — ORB-SLAM `MapPoint::PredictScale`:
    /// `ceil(ln(max_distance / distance) / ln(scale_factor))` clamped to `[0, n_levels - 1]`.
    ///
    /// A non-positive `distance` yields the coarsest level; NaN inputs yield level 0.
    ///
    /// ```
    /// use ferroslam_features::ScalePyramid;
    /// let p = ScalePyramid::new(1.2, 8).unwrap();
    /// assert_eq!(p.predict_level(2.0, 2.0), 0);
    /// assert_eq!(p.predict_level(1.01 * 2.0 / 1.2_f64.powi(3), 2.0), 3);
    /// assert_eq!(p.predict_level(1e-3, 2.0), 7);
    /// assert_eq!(p.predict_level(10.0, 2.0), 0);
    /// ```
    pub fn predict_level(&self, distance: f64, max_distance: f64) -> usize {
        let top = self.n_levels - 1;
        if distance <= 0.0 && max_distance > 0.0 {
            return top;
        }
        let level = ((max_distance / distance).ln() / self.scale_factor.ln()).ceil();
        // `as usize` saturates: NaN and negatives map to 0.
        (level.max(0.0) as usize).min(top)
    }

    /// The distance range `(min, max)` (m) over which a map point observed at `distance`
    /// (m) by a keypoint of level `octave` stays detectable — ORB-SLAM
    /// `MapPoint::UpdateNormalAndDepth`: `max = distance * scale[octave]`,
    /// `min = max / scale[n_levels - 1]`. Octaves beyond the pyramid are clamped to its top.
    pub fn distance_bounds(&self, distance: f64, octave: u8) -> (f64, f64) {
        let top = self.n_levels - 1;
        let max = distance * self.scale[usize::from(octave).min(top)];
        (max / self.scale[top], max)
    }
}

impl Default for ScalePyramid {
    /// ORB-SLAM's default pyramid: 8 levels, scale factor 1.2.
    fn default() -> Self {
        Self::new(1.2, 8).unwrap_or_else(|_| unreachable!("1.2 / 8 is a valid pyramid"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables() {
        let p = ScalePyramid::default();
        assert_eq!(p.scale.len(), 8);
        for i in 0..8 {
            let s = 1.2f64.powi(i as i32);
            assert!((p.scale[i] - s).abs() < 1e-12);
            assert!((p.sigma2[i] - s * s).abs() < 1e-12);
            assert!((p.inv_scale[i] * s - 1.0).abs() < 1e-12);
            assert!((p.inv_sigma2[i] * s * s - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(ScalePyramid::new(1.0, 8).is_err());
        assert!(ScalePyramid::new(f64::NAN, 8).is_err());
        assert!(ScalePyramid::new(1.2, 0).is_err());
    }

    #[test]
    fn predict_level_inverts_distance_bounds() {
        let p = ScalePyramid::default();
        for octave in 0..8u8 {
            let (min, max) = p.distance_bounds(3.0, octave);
            // At the observation distance the predicted level is the observed octave.
            assert_eq!(p.predict_level(3.0 * 1.000_001, max), octave as usize);
            assert_eq!(p.predict_level(max, max), 0);
            assert_eq!(p.predict_level(min * 1.000_001, max), 7);
        }
        assert_eq!(p.predict_level(f64::NAN, 1.0), 0);
        assert_eq!(p.predict_level(0.0, 1.0), 7);
    }
}
