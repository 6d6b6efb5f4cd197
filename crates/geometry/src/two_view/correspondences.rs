//! The matches two-view reconstruction can use: both pixels finite, with their rays.

use nalgebra::{Vector2, Vector3};

use crate::camera::PinholeCamera;
use crate::GeometryError;

/// Usable matches, in the order of the caller's `matches` (skipping unusable ones).
pub(super) struct Correspondences {
    /// Index of each usable match in the caller's `matches`.
    pub match_index: Vec<usize>,
    /// Undistorted pixel in view 1.
    pub pixels1: Vec<Vector2<f64>>,
    /// Undistorted pixel in view 2.
    pub pixels2: Vec<Vector2<f64>>,
    /// Ray `(x, y, 1)` in camera 1 through `pixels1`.
    pub rays1: Vec<Vector3<f64>>,
    /// Ray `(x, y, 1)` in camera 2 through `pixels2`.
    pub rays2: Vec<Vector3<f64>>,
}

impl Correspondences {
    /// Collects the matches whose two pixels are finite; the others are left out (they can
    /// never be inliers). Fails if a match refers to a keypoint that does not exist.
    pub fn new(
        keypoints1: &[Vector2<f64>],
        keypoints2: &[Vector2<f64>],
        matches: &[(usize, usize)],
        camera: &PinholeCamera,
    ) -> Result<Self, GeometryError> {
        let mut c = Self {
            match_index: Vec::new(),
            pixels1: Vec::new(),
            pixels2: Vec::new(),
            rays1: Vec::new(),
            rays2: Vec::new(),
        };
        for (k, &(i1, i2)) in matches.iter().enumerate() {
            let (Some(p1), Some(p2)) = (keypoints1.get(i1), keypoints2.get(i2)) else {
                let index = if i1 >= keypoints1.len() { i1 } else { i2 };
                return Err(GeometryError::InvalidParameter {
                    name: "matches",
                    value: index as f64,
                    reason: "match refers to a keypoint index out of range",
                });
            };
            if !(p1.iter().chain(p2.iter()).all(|v| v.is_finite())) {
                continue;
            }
            c.match_index.push(k);
            c.pixels1.push(*p1);
            c.pixels2.push(*p2);
            c.rays1.push(camera.unproject(p1));
            c.rays2.push(camera.unproject(p2));
        }
        Ok(c)
    }

    /// Number of usable matches.
    pub fn len(&self) -> usize {
        self.match_index.len()
    }
}
