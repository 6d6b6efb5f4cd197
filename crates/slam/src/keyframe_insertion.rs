//! Keyframe insertion, tracking's side of a new keyframe (ORB-SLAM `CreateNewKeyFrame`):
//! the frame enters the map with its matched points, and, with depth, its closest unmatched
//! features become points. The rest is the mapping pipeline's ([`crate::mapping`]).

use ferroslam_map::{KeyFrameId, Map, MapPointId};

use crate::context::Context;
use crate::error::SlamError;
use crate::frame::{unproject_depth, Frame};

/// Turns a tracked frame into a keyframe: links its matched points (outliers and points the
/// keyframe already sees are dropped from the frame), and creates points from measured depth
/// for the closest unmatched features (at least 100 points, all those closer than
/// `close_depth_m`; the first keyframe passes infinity to keep every feature with depth).
/// Returns the keyframe and the points created, oldest first.
pub(crate) fn insert_keyframe(
    frame: &mut Frame,
    map: &mut Map,
    ctx: &Context,
    close_depth_m: f64,
) -> Result<(KeyFrameId, Vec<MapPointId>), SlamError> {
    let kf = map.insert_keyframe(
        frame.timestamp,
        frame.index,
        frame.T_c_w,
        frame.features.clone(),
    );
    for i in 0..frame.len() {
        let Some(m) = frame.map_points[i] else {
            continue;
        };
        if frame.outlier[i]
            || map
                .map_point(m)
                .is_none_or(|p| p.observations().contains_key(&kf))
        {
            frame.map_points[i] = None;
            continue;
        }
        map.add_observation(m, kf, i)?;
        map.update_normal_and_depth(m)?;
        map.compute_distinctive_descriptor(m)?;
    }
    let T_w_c = frame.T_c_w.inverse();
    let mut created = Vec::new();
    for i in frame.closest_depth_features(close_depth_m) {
        if frame.map_points[i].is_some() {
            continue;
        }
        let Some(p_w) = unproject_depth(&frame.features, i, ctx, &T_w_c) else {
            continue;
        };
        let m = map.create_map_point(p_w, kf)?;
        map.add_observation(m, kf, i)?;
        map.compute_distinctive_descriptor(m)?;
        map.update_normal_and_depth(m)?;
        frame.map_points[i] = Some(m);
        created.push(m);
    }
    map.update_connections(kf)?;
    Ok((kf, created))
}
