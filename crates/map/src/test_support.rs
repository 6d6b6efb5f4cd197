//! Small deterministic maps for the unit tests.
//!
//! Keyframe `k` sits at camera centre `(k, 0, 0)` looking down +z. Its keypoint `i` has
//! octave `i % 8`, descriptor with the lowest `8 * k + i` bits set (capped at 256), and is
//! stereo (u_right >= 0, counting twice in nObs) iff `i` is odd. In the coloured maps it has
//! colour [`test_color`]`(k, i)`.

use ferroslam_features::{ImageBounds, Keypoint, ScalePyramid};
use nalgebra::{Isometry3, Vector3};

use crate::{FrameFeatures, KeyFrameId, Map, MapPointId, Rgb};

fn descriptor_with_bits(n: usize) -> [u8; 32] {
    let mut d = [0u8; 32];
    for bit in 0..n.min(256) {
        d[bit / 8] |= 1 << (bit % 8);
    }
    d
}

fn features(k: usize, n: usize) -> FrameFeatures {
    let keypoints = (0..n)
        .map(|i| Keypoint {
            x: i as f32,
            y: 10.0,
            octave: (i % 8) as u8,
            angle_deg: 0.0,
            response: 1.0,
        })
        .collect();
    let descriptors = (0..n).map(|i| descriptor_with_bits(8 * k + i)).collect();
    let stereo = |i: usize| i % 2 == 1;
    let depth = (0..n).map(|i| if stereo(i) { 3.0 } else { -1.0 }).collect();
    let u_right = (0..n)
        .map(|i| if stereo(i) { i as f32 } else { -1.0 })
        .collect();
    let bounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };
    FrameFeatures::new(keypoints, descriptors, depth, u_right, bounds).expect("consistent lengths")
}

/// Colour of keypoint `i` of keyframe `k` in the coloured maps (distinct for `k, i < 256`).
pub(crate) fn test_color(k: usize, i: usize) -> Rgb {
    [k as u8, i as u8, 200]
}

/// A map with `k` keyframes of `n` keypoints each and no points.
pub(crate) fn map_with_keyframes(k: usize, n: usize) -> (Map, Vec<KeyFrameId>) {
    map_of(k, n, false)
}

/// As [`map_with_keyframes`], with coloured keypoints.
pub(crate) fn map_with_colored_keyframes(k: usize, n: usize) -> (Map, Vec<KeyFrameId>) {
    map_of(k, n, true)
}

fn map_of(k: usize, n: usize, colored: bool) -> (Map, Vec<KeyFrameId>) {
    let mut map = Map::new(ScalePyramid::default());
    let ids = (0..k)
        .map(|i| {
            let t_w_c = Isometry3::translation(i as f64, 0.0, 0.0);
            let mut features = features(i, n);
            if colored {
                let colors = (0..n).map(|j| test_color(i, j)).collect();
                features = features.with_colors(colors).expect("one per keypoint");
            }
            map.insert_keyframe(i as f64, i, t_w_c.inverse(), features)
        })
        .collect();
    (map, ids)
}

/// A point at (0, 0, 5) created by `kfs[0]` and observed by keypoint `index` of every `kfs`.
pub(crate) fn observe_all(map: &mut Map, kfs: &[KeyFrameId], index: usize) -> MapPointId {
    let mp = map
        .create_map_point(Vector3::new(0.0, 0.0, 5.0), kfs[0])
        .expect("live keyframe");
    for &kf in kfs {
        map.add_observation(mp, kf, index).expect("free slot");
    }
    mp
}
