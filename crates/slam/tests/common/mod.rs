//! What the synthetic-scene tests share.

use ferroslam_features::Keypoint;
use nalgebra::Vector2;

/// A synthetic keypoint at pixel `uv` of pyramid level `octave`, upright, unit response.
pub fn keypoint(uv: &Vector2<f64>, octave: u8) -> Keypoint {
    Keypoint {
        x: uv.x as f32,
        y: uv.y as f32,
        octave,
        angle_deg: 0.0,
        response: 1.0,
    }
}
