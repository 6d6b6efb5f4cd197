//! Visibility of a map point from a camera pose (ORB-SLAM `Frame::isInFrustum`).

use ferroslam_features::ImageBounds;
use ferroslam_geometry::camera::CameraModel;
use ferroslam_map::{Map, MapPointId};
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

/// Projects `mp` into a camera at `T_c_w` and checks ORB-SLAM's visibility conditions:
/// projected by the model (positive depth for the pinhole), inside the image bounds, distance
/// within the scale-invariance range widened by `rules` and viewing angle with
/// `cos >= rules.min_view_cos` to the mean direction.
pub fn visible_point(
    map: &Map,
    mp: MapPointId,
    T_c_w: &Isometry3<f64>,
    center_w: &Vector3<f64>,
    camera: &CameraModel,
    bounds: &ImageBounds,
    rules: &VisibilityConfig,
) -> Option<VisiblePoint> {
    let point = map.map_point(mp)?;
    let p_w = point.position();
    let p_c = T_c_w * Point3::from(p_w);
    let uv = camera.project(&p_c.coords)?;
    if uv.x < bounds.min_x || uv.x >= bounds.max_x || uv.y < bounds.min_y || uv.y >= bounds.max_y {
        return None;
    }
    let ray = p_w - center_w;
    let dist = ray.norm();
    if !rules.in_scale_range(dist, (point.min_distance(), point.max_distance())) {
        return None;
    }
    let view_cos = ray.dot(&point.normal()) / dist;
    if view_cos < rules.min_view_cos {
        return None;
    }
    let level = map.pyramid().predict_level(dist, point.max_distance()) as u8;
    Some(VisiblePoint {
        u: uv.x,
        v: uv.y,
        p_c: p_c.coords,
        level,
        view_cos,
    })
}
