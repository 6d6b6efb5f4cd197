//! ORB keypoints as seen by the core.

/// One ORB keypoint.
///
/// `x`, `y` are pixel coordinates at level 0 (x right, y down), raw (distorted) as extracted,
/// UNDISTORTED once a frame has undistorted them (see the crate conventions); `octave` is the
/// pyramid level the feature was detected at; `angle_deg` is the orientation in degrees,
/// `[0, 360)` (OpenCV convention); `response` is the detector score (larger is stronger).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keypoint {
    /// Pixel column (px).
    pub x: f32,
    /// Pixel row (px).
    pub y: f32,
    /// Pyramid level (0 = full resolution).
    pub octave: u8,
    /// Orientation in degrees, `[0, 360)`.
    pub angle_deg: f32,
    /// Detector response.
    pub response: f32,
}
