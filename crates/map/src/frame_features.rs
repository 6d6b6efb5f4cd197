//! The per-keypoint arrays a keyframe is built from.

use ferroslam_features::{Descriptor, ImageBounds, Keypoint, KeypointGrid};
use nalgebra::Vector6;

use crate::MapError;

/// An 8-bit colour: red, green, blue.
pub type Rgb = [u8; 3];

/// Keypoints of one frame with their descriptors, depths, virtual-right coordinates and
/// (optionally) colours, plus the grid for radius search. Index `i` refers to the same
/// feature in every array.
///
/// Build it with [`FrameFeatures::new`] (and [`FrameFeatures::with_colors`]), which check
/// the lengths; the fields are public for reading, and every accessor of this crate
/// tolerates inconsistent lengths (missing entries read as "no depth", "monocular", "no
/// colour").
#[derive(Clone, Debug)]
pub struct FrameFeatures {
    /// UNDISTORTED keypoints (px).
    pub keypoints: Vec<Keypoint>,
    /// ORB descriptors, one per keypoint.
    pub descriptors: Vec<Descriptor>,
    /// Depth (m) along the camera z axis; `<= 0` (or NaN) means no depth.
    pub depth: Vec<f32>,
    /// Virtual right coordinate `u - bf / depth` (px); `< 0` means monocular.
    pub u_right: Vec<f32>,
    /// Colour of the image at each keypoint, if the frame came with colours: a map point
    /// takes the colour of its first observation ([`crate::MapPoint::color`]).
    pub colors: Option<Vec<Rgb>>,
    /// Grid over `keypoints` for [`KeypointGrid::features_in_area`].
    pub grid: KeypointGrid,
    /// Rolling shutter: seconds from the frame's timestamp to the readout of each keypoint's
    /// row in its camera (from the raw pixel it was detected at); empty for a global shutter
    /// (every offset 0). Set by [`FrameFeatures::with_time_offsets`].
    pub time_offsets_s: Vec<f64>,
    /// Velocity `[v; w]` (metres and radians per second) of the frame's `T_c_w` over its
    /// readout, as tracking estimated it (zero for a global shutter): keypoint `i` was seen
    /// from `D(time_offsets_s[i]) * T_c_w` (`ferroslam_geometry::rolling_shutter`).
    pub xi_dot: Vector6<f64>,
}

impl FrameFeatures {
    /// Bundles the arrays and builds the keypoint grid over `bounds`.
    ///
    /// `depth` and `u_right` may be empty (monocular frame): they are then filled with `-1`.
    ///
    /// # Errors
    /// [`MapError::LengthMismatch`] if `descriptors` does not have one entry per keypoint, or
    /// `depth` / `u_right` are neither empty nor one per keypoint.
    pub fn new(
        keypoints: Vec<Keypoint>,
        descriptors: Vec<Descriptor>,
        depth: Vec<f32>,
        u_right: Vec<f32>,
        bounds: ImageBounds,
    ) -> Result<Self, MapError> {
        let expected = keypoints.len();
        let per_keypoint = |values: Vec<f32>, field| match values.len() {
            0 => Ok(vec![-1.0; expected]),
            got if got == expected => Ok(values),
            got => Err(MapError::LengthMismatch {
                field,
                expected,
                got,
            }),
        };
        if descriptors.len() != expected {
            return Err(MapError::LengthMismatch {
                field: "descriptors",
                expected,
                got: descriptors.len(),
            });
        }
        let depth = per_keypoint(depth, "depth")?;
        let u_right = per_keypoint(u_right, "u_right")?;
        let grid = KeypointGrid::new(&keypoints, bounds);
        Ok(Self {
            keypoints,
            descriptors,
            depth,
            u_right,
            colors: None,
            grid,
            time_offsets_s: Vec::new(),
            xi_dot: Vector6::zeros(),
        })
    }

    /// The same features with each keypoint's row time offset (seconds, see
    /// [`Self::time_offsets_s`]).
    ///
    /// # Errors
    /// [`MapError::LengthMismatch`] unless there is one offset per keypoint.
    pub fn with_time_offsets(self, time_offsets_s: Vec<f64>) -> Result<Self, MapError> {
        if time_offsets_s.len() != self.len() {
            return Err(MapError::LengthMismatch {
                field: "time_offsets_s",
                expected: self.len(),
                got: time_offsets_s.len(),
            });
        }
        Ok(Self {
            time_offsets_s,
            ..self
        })
    }

    /// Seconds from the frame's timestamp to the readout of keypoint `i`'s row; 0 for a
    /// global shutter or an out-of-range `i`.
    pub fn time_offset_s(&self, i: usize) -> f64 {
        self.time_offsets_s.get(i).copied().unwrap_or(0.0)
    }

    /// The same features with a colour per keypoint.
    ///
    /// # Errors
    /// [`MapError::LengthMismatch`] unless there is one colour per keypoint.
    pub fn with_colors(self, colors: Vec<Rgb>) -> Result<Self, MapError> {
        if colors.len() != self.len() {
            return Err(MapError::LengthMismatch {
                field: "colors",
                expected: self.len(),
                got: colors.len(),
            });
        }
        Ok(Self {
            colors: Some(colors),
            ..self
        })
    }

    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// True if there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// True if keypoint `i` has a valid (positive) depth; false for out-of-range `i`.
    pub fn has_depth(&self, i: usize) -> bool {
        self.depth.get(i).is_some_and(|&d| d > 0.0)
    }

    /// True if keypoint `i` has a virtual right coordinate (stereo/RGB-D observation, counted
    /// twice in ORB-SLAM's `nObs`); false for out-of-range `i`.
    pub fn is_stereo(&self, i: usize) -> bool {
        self.u_right.get(i).is_some_and(|&u| u >= 0.0)
    }

    /// Colour of keypoint `i`; `None` for a frame without colours or an out-of-range `i`.
    pub fn color(&self, i: usize) -> Option<Rgb> {
        self.colors.as_ref()?.get(i).copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keypoint(x: f32) -> Keypoint {
        Keypoint {
            x,
            y: 10.0,
            octave: 0,
            angle_deg: 0.0,
            response: 1.0,
        }
    }

    const BOUNDS: ImageBounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };

    #[test]
    fn monocular_arrays_may_be_empty() {
        let f = FrameFeatures::new(
            vec![keypoint(1.0); 3],
            vec![[0; 32]; 3],
            vec![],
            vec![],
            BOUNDS,
        )
        .unwrap();
        assert_eq!(f.len(), 3);
        assert!(!f.has_depth(0) && !f.is_stereo(0));
        assert!(!f.has_depth(7) && !f.is_stereo(7));
    }

    #[test]
    fn depth_and_right_coordinate() {
        let f = FrameFeatures::new(
            vec![keypoint(1.0), keypoint(2.0)],
            vec![[0; 32]; 2],
            vec![2.0, 0.0],
            vec![0.5, -1.0],
            BOUNDS,
        )
        .unwrap();
        assert!(f.has_depth(0) && f.is_stereo(0));
        assert!(!f.has_depth(1) && !f.is_stereo(1));
        assert_eq!(
            f.grid
                .features_in_area(&f.keypoints, 2.0, 10.0, 0.5, None, None),
            vec![1]
        );
    }

    #[test]
    fn rejects_mismatched_lengths() {
        let kps = vec![keypoint(1.0); 2];
        let err = FrameFeatures::new(kps.clone(), vec![[0; 32]; 1], vec![], vec![], BOUNDS);
        assert!(matches!(
            err,
            Err(MapError::LengthMismatch {
                field: "descriptors",
                ..
            })
        ));
        let err = FrameFeatures::new(kps, vec![[0; 32]; 2], vec![1.0], vec![], BOUNDS);
        assert!(matches!(
            err,
            Err(MapError::LengthMismatch { field: "depth", .. })
        ));
    }

    #[test]
    fn colors_are_optional_and_one_per_keypoint() {
        let f = FrameFeatures::new(
            vec![keypoint(1.0); 2],
            vec![[0; 32]; 2],
            vec![],
            vec![],
            BOUNDS,
        )
        .unwrap();
        assert_eq!(f.color(0), None);
        let err = f.clone().with_colors(vec![[1, 2, 3]]);
        assert!(matches!(
            err,
            Err(MapError::LengthMismatch {
                field: "colors",
                expected: 2,
                got: 1
            })
        ));
        let f = f.with_colors(vec![[1, 2, 3], [4, 5, 6]]).unwrap();
        assert_eq!((f.color(1), f.color(2)), (Some([4, 5, 6]), None));
    }
}
