//! [`SparseModel`]: the map as a photogrammetry tool sees it (COLMAP's images, 2-D points and
//! tracks), read through the map's public API only.
//!
//! Such tools keep every keypoint of an image, the ones without a 3-D point too, in the
//! pixels of the image file they are given: the raw (distorted) image. The map keeps its
//! keypoints in the core's pixels (undistorted for a pinhole camera), so the caller passes
//! the camera's way back (`CameraModel::raw_pixel` of `ferroslam_geometry`). A keyframe of a
//! multi-camera rig will add one image per camera here; points and tracks do not change.

use nalgebra::{Isometry3, Vector2, Vector3};

use crate::{KeyFrameId, Map, MapPointId, Rgb};

/// One keyframe's image: its pose and every keypoint with the point it observes.
#[derive(Clone, Debug)]
#[allow(non_snake_case)]
pub struct SparseImage {
    /// The keyframe.
    pub id: KeyFrameId,
    /// Timestamp of the source frame, seconds.
    pub timestamp_s: f64,
    /// Camera-to-world pose (`p_w = T_w_c * p_c`, metres).
    pub T_w_c: Isometry3<f64>,
    /// Every keypoint in raw image pixels (centre of the top-left pixel at (0, 0)).
    pub keypoints_raw_px: Vec<Vector2<f64>>,
    /// Per keypoint, the index in [`SparseModel::points`] of the point it observes.
    pub point_index: Vec<Option<usize>>,
}

/// One live map point.
#[derive(Clone, Debug)]
pub struct SparsePoint {
    /// The map point.
    pub id: MapPointId,
    /// World position, metres.
    pub position: Vector3<f64>,
    /// Colour of its first observation ([`crate::MapPoint::color`]).
    pub color: Option<Rgb>,
}

/// The keyframes (by increasing id) and live map points (by increasing id) of a map, linked
/// by keypoint: the track of a point is every `(image, keypoint)` whose `point_index` is it.
#[derive(Clone, Debug, Default)]
pub struct SparseModel {
    /// One image per keyframe.
    pub images: Vec<SparseImage>,
    /// The map points, in the order of [`Map::map_point_ids`].
    pub points: Vec<SparsePoint>,
}

impl Map {
    /// The map as images, points and tracks; `raw_px` moves a keypoint from the map's
    /// pixels to the raw image's (the camera of every keyframe).
    pub fn sparse_model(&self, raw_px: impl Fn(&Vector2<f64>) -> Vector2<f64>) -> SparseModel {
        let points: Vec<SparsePoint> = self
            .map_point_ids()
            .into_iter()
            .filter_map(|id| self.map_point(id))
            .map(|p| SparsePoint {
                id: p.id(),
                position: p.position(),
                color: p.color(),
            })
            .collect();
        let index_of: std::collections::HashMap<MapPointId, usize> =
            points.iter().enumerate().map(|(i, p)| (p.id, i)).collect();
        let images = self
            .keyframe_ids()
            .into_iter()
            .filter_map(|id| self.keyframe(id))
            .map(|kf| {
                let keypoints = &kf.features().keypoints;
                SparseImage {
                    id: kf.id(),
                    timestamp_s: kf.timestamp(),
                    T_w_c: kf.T_w_c(),
                    keypoints_raw_px: keypoints
                        .iter()
                        .map(|k| raw_px(&Vector2::new(f64::from(k.x), f64::from(k.y))))
                        .collect(),
                    point_index: (0..keypoints.len())
                        .map(|i| kf.map_point(i).and_then(|m| index_of.get(&m).copied()))
                        .collect(),
                }
            })
            .collect();
        SparseModel { images, points }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use crate::test_support::{map_with_keyframes, observe_all};

    #[test]
    fn every_keypoint_is_listed_with_its_point_in_raw_pixels() {
        let (mut map, kfs) = map_with_keyframes(3, 4);
        let shared = observe_all(&mut map, &kfs, 2);
        let shift = Vector2::new(0.5, -0.25);
        let model = map.sparse_model(|uv| uv + shift);
        assert_eq!(model.points.len(), 1);
        assert_eq!(model.points[0].id, shared);
        assert_eq!(model.images.len(), 3);
        for (image, &kf) in model.images.iter().zip(&kfs) {
            assert_eq!(image.id, kf);
            assert_eq!(image.point_index, vec![None, None, Some(0), None]);
            let keyframe = map.keyframe(kf).unwrap();
            assert_eq!(image.T_w_c, keyframe.T_w_c());
            let keypoints = &keyframe.features().keypoints;
            assert_eq!(image.keypoints_raw_px.len(), keypoints.len());
            for (raw, k) in image.keypoints_raw_px.iter().zip(keypoints) {
                assert_eq!(*raw, Vector2::new(f64::from(k.x), f64::from(k.y)) + shift);
            }
        }
    }
}
