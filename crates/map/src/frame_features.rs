//! The per-keypoint arrays a keyframe is built from.

use std::ops::Range;

use ferroslam_features::{Descriptor, ImageBounds, Keypoint, KeypointGrid};
use nalgebra::Vector6;

use crate::MapError;

pub(crate) mod cameras;

/// An 8-bit colour: red, green, blue.
pub type Rgb = [u8; 3];

/// Keypoints of one frame with their descriptors, depths, virtual-right coordinates and
/// (optionally) colours, plus the grids for radius search. Index `i` refers to the same
/// feature in every array.
///
/// A frame of a multi-camera rig is one instant of all its cameras: their keypoints in one
/// list, sorted by camera ([`FrameFeatures::with_cameras`]), each camera with its own image
/// bounds and grid.
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
    /// First keypoint of each camera of the rig (`[0]` for one camera): camera k's keypoints are `camera_range(k)`.
    pub camera_starts: Vec<usize>,
    /// One grid per camera over that camera's keypoints, indexed LOCALLY (0 = the camera's first keypoint) — for `KeypointGrid::features_in_area`.
    pub grids: Vec<KeypointGrid>,
    /// Rolling shutter: seconds from the frame's timestamp to the readout of each keypoint's
    /// row in its camera (from the raw pixel it was detected at); empty for a global shutter
    /// (every offset 0). Set by [`FrameFeatures::with_time_offsets`].
    pub time_offsets_s: Vec<f64>,
    /// Velocity `[v; w]` (metres and radians per second) of the frame's `T_c_w` (its first
    /// camera's) over its readout, as tracking estimated it (zero for a global shutter):
    /// keypoint `i` of camera `k` was seen from `T_ck_c0 * D(time_offsets_s[i]) * T_c0_w`
    /// (`ferroslam_geometry::rolling_shutter`).
    pub xi_dot: Vector6<f64>,
}

impl FrameFeatures {
    /// Bundles the arrays of one camera and builds the keypoint grid over `bounds`.
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
            camera_starts: vec![0],
            grids: vec![grid],
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

    /// The same keypoints as the frame of a multi-camera rig: camera `k` sees the keypoints
    /// `camera_starts[k]..camera_starts[k + 1]` (the last camera's end at [`Self::len`]) within
    /// `bounds[k]` (px). The grids are rebuilt, one per camera over its keypoints.
    ///
    /// # Errors
    /// [`MapError::CameraStartsNotAtZero`], [`MapError::CameraStartsDecreasing`],
    /// [`MapError::CameraStartBeyondKeypoints`] for starts that cannot split the keypoints,
    /// [`MapError::CameraBoundsMismatch`] unless there is one bounds per camera.
    pub fn with_cameras(
        self,
        camera_starts: Vec<usize>,
        bounds: &[ImageBounds],
    ) -> Result<Self, MapError> {
        cameras::check_camera_starts(&camera_starts, self.len())?;
        if bounds.len() != camera_starts.len() {
            return Err(MapError::CameraBoundsMismatch {
                cameras: camera_starts.len(),
                bounds: bounds.len(),
            });
        }
        let grids = cameras::camera_grids(&self.keypoints, &camera_starts, bounds.iter().copied());
        Ok(Self {
            camera_starts,
            grids,
            ..self
        })
    }

    /// Number of cameras of the rig that took the frame (1 for a single camera).
    pub fn num_cameras(&self) -> usize {
        self.camera_starts.len()
    }

    /// Keypoint indices of camera `k` (empty for `k` beyond the cameras).
    pub fn camera_range(&self, k: usize) -> Range<usize> {
        cameras::camera_range(&self.camera_starts, self.len(), k)
    }

    /// The camera that saw keypoint `i` (binary search of the starts); 0 for an
    /// out-of-range `i`.
    pub fn camera_of(&self, i: usize) -> usize {
        cameras::camera_of(&self.camera_starts, self.len(), i)
    }

    /// Camera `k`'s grid, indexed locally: keypoint `j` of the grid is keypoint
    /// `camera_range(k).start + j` of the frame.
    ///
    /// # Panics
    /// If `k >= self.num_cameras()`.
    pub fn grid(&self, k: usize) -> &KeypointGrid {
        &self.grids[k]
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
            f.grid(0)
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

    /// Keypoints at x = 0, 1, .. (px), y = 10.
    fn row_of(n: usize) -> FrameFeatures {
        let kps = (0..n).map(|i| keypoint(i as f32)).collect();
        FrameFeatures::new(kps, vec![[0; 32]; n], vec![], vec![], BOUNDS).unwrap()
    }

    #[test]
    fn one_camera_by_default() {
        let f = row_of(4);
        assert_eq!((f.num_cameras(), f.camera_range(0)), (1, 0..4));
        assert_eq!((f.camera_of(3), f.camera_of(4)), (0, 0));
        assert_eq!(f.grid(0).bounds(), BOUNDS);
    }

    #[test]
    fn cameras_split_the_keypoints_with_local_grids() {
        let small = ImageBounds {
            max_x: 320.0,
            max_y: 240.0,
            ..BOUNDS
        };
        let f = row_of(7)
            .with_cameras(vec![0, 2, 2, 5], &[BOUNDS, small, small, BOUNDS])
            .unwrap();
        assert_eq!(f.num_cameras(), 4);
        let ranges: Vec<_> = (0..5).map(|k| f.camera_range(k)).collect();
        assert_eq!(ranges, [0..2, 2..2, 2..5, 5..7, 7..7]);
        let cameras: Vec<_> = (0..8).map(|i| f.camera_of(i)).collect();
        assert_eq!(cameras, [0, 0, 2, 2, 2, 3, 3, 0]);
        assert_eq!(f.grid(1).bounds(), small);
        // Camera 2's keypoints are x = 2, 3, 4: x = 3 is its local keypoint 1.
        let local = &f.keypoints[f.camera_range(2)];
        assert_eq!(
            f.grid(2)
                .features_in_area(local, 3.0, 10.0, 0.5, None, None),
            [1]
        );
        assert_eq!(
            f.grid(3)
                .features_in_area(&f.keypoints[5..], 6.0, 10.0, 0.5, None, None),
            [1]
        );
    }

    #[test]
    fn bad_camera_starts_are_named() {
        let err = |starts: Vec<usize>, n| row_of(5).with_cameras(starts, &vec![BOUNDS; n]);
        let e = err(vec![1, 3], 2).unwrap_err();
        assert_eq!(e, MapError::CameraStartsNotAtZero { starts: vec![1, 3] });
        assert!(e.to_string().contains("[1, 3] must begin with 0"), "{e}");
        assert!(matches!(
            err(vec![], 0),
            Err(MapError::CameraStartsNotAtZero { .. })
        ));
        let e = err(vec![0, 3, 2], 3).unwrap_err();
        assert_eq!(
            e.to_string(),
            "FrameFeatures: camera_starts [0, 3, 2] decrease at camera 2: keypoints must be \
             sorted by camera"
        );
        let e = err(vec![0, 6], 2).unwrap_err();
        assert_eq!(
            e.to_string(),
            "FrameFeatures: camera_starts [0, 6]: camera 1 starts beyond the 5 keypoints"
        );
        // All keypoints in the first camera, none in the second: fine.
        assert!(err(vec![0, 5], 2).is_ok());
        let e = err(vec![0, 2], 3).unwrap_err();
        assert_eq!(
            e.to_string(),
            "FrameFeatures: 2 cameras but 3 image bounds (one per camera)"
        );
    }
}
