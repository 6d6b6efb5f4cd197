//! Visibility of a map point from a camera pose (ORB-SLAM `Frame::isInFrustum`).

use ferroslam_features::{ImageBounds, ScalePyramid};
use ferroslam_geometry::camera::CameraModel;
use ferroslam_map::{Map, MapPoint, MapPointId};
use nalgebra::{Isometry3, Point3, Vector3};

use crate::config::VisibilityConfig;

/// Where and at which pyramid level a map point should appear in an image.
#[derive(Clone, Copy, Debug)]
pub struct VisiblePoint {
    /// Predicted pixel column (core pixels).
    pub u: f64,
    /// Predicted pixel row (core pixels).
    pub v: f64,
    /// The point in the camera frame, metres (`z < 0` for a fisheye's points beyond 90
    /// degrees from the axis).
    pub p_c: Vector3<f64>,
    /// Predicted pyramid level from the viewing distance.
    pub level: u8,
    /// Cosine between the viewing ray and the point's mean viewing direction.
    pub view_cos: f64,
}

/// What the visibility test reads of a map point: copied out of the map once per frame by
/// tracking's local-map cache, read in place by [`visible_point`], so that both go through
/// the one rule of [`PointShape::visible_from`].
#[derive(Clone, Copy, Debug)]
pub struct PointShape {
    /// World position (m).
    pub position: Vector3<f64>,
    /// Mean viewing direction, unit length.
    pub normal: Vector3<f64>,
    /// Scale-invariance distance range (m), ORB-SLAM `mfMinDistance` / `mfMaxDistance`.
    pub min_distance: f64,
    /// See `min_distance`.
    pub max_distance: f64,
}

impl From<&MapPoint> for PointShape {
    fn from(point: &MapPoint) -> Self {
        Self {
            position: point.position(),
            normal: point.normal(),
            min_distance: point.min_distance(),
            max_distance: point.max_distance(),
        }
    }
}

impl PointShape {
    /// Projects the point into a camera at `T_c_w` and checks ORB-SLAM's visibility
    /// conditions: projected by the model (positive depth for the pinhole), inside the image
    /// bounds, distance within the scale-invariance range widened by `rules` and viewing angle
    /// with `cos >= rules.min_view_cos` to the mean direction.
    pub fn visible_from(
        &self,
        T_c_w: &Isometry3<f64>,
        center_w: &Vector3<f64>,
        camera: &CameraModel,
        bounds: &ImageBounds,
        rules: &VisibilityConfig,
        pyramid: &ScalePyramid,
    ) -> Option<VisiblePoint> {
        let p_w = self.position;
        let p_c = T_c_w * Point3::from(p_w);
        let uv = camera.project(&p_c.coords)?;
        if uv.x < bounds.min_x
            || uv.x >= bounds.max_x
            || uv.y < bounds.min_y
            || uv.y >= bounds.max_y
        {
            return None;
        }
        let ray = p_w - center_w;
        let dist = ray.norm();
        if !rules.in_scale_range(dist, (self.min_distance, self.max_distance)) {
            return None;
        }
        let view_cos = ray.dot(&self.normal) / dist;
        if view_cos < rules.min_view_cos {
            return None;
        }
        let level = pyramid.predict_level(dist, self.max_distance) as u8;
        Some(VisiblePoint {
            u: uv.x,
            v: uv.y,
            p_c: p_c.coords,
            level,
            view_cos,
        })
    }
}

/// [`PointShape::visible_from`] of map point `mp` as the map holds it now; `None` for a
/// point no longer in the map.
pub fn visible_point(
    map: &Map,
    mp: MapPointId,
    T_c_w: &Isometry3<f64>,
    center_w: &Vector3<f64>,
    camera: &CameraModel,
    bounds: &ImageBounds,
    rules: &VisibilityConfig,
) -> Option<VisiblePoint> {
    PointShape::from(map.map_point(mp)?).visible_from(
        T_c_w,
        center_w,
        camera,
        bounds,
        rules,
        map.pyramid(),
    )
}
