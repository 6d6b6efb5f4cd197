//! Loop correction (ORB-SLAM `LoopClosing::CorrectLoop`): the verified Sim(3) of the current
//! keyframe is propagated to its covisible keyframes and their map points, the loop's map
//! points are fused into that neighbourhood, and the new links the fusion creates become
//! loop edges of the essential graph, which is then optimised.

use std::collections::{HashMap, HashSet};

use ferroslam_geometry::sim3::Sim3;
use ferroslam_map::{KeyFrameId, Map, MapPointId};

use super::essential_graph::{move_point, optimize_essential_graph, EssentialGraphInput};
use super::verification::{pose_of, LoopMatch};
use crate::context::Context;
use crate::error::SlamError;
use crate::point_fusion::fuse_points_into;

/// Corrects the loop `found` detected at `current`; returns the essential graph's cost
/// before and after optimisation.
pub(super) fn correct_loop(
    current: KeyFrameId,
    found: &LoopMatch,
    map: &mut Map,
    ctx: &Context,
) -> Result<(f64, f64), SlamError> {
    map.update_connections(current)?;
    let connected: Vec<KeyFrameId> = std::iter::once(current)
        .chain(map.covisibles(current).into_iter().map(|(k, _)| k))
        .collect();
    let T_wc = map.keyframe(current).expect("current keyframe").T_w_c();
    // S_iw before (rigid) and after correction, through the relative pose to the current one.
    let mut before: HashMap<KeyFrameId, Sim3> = HashMap::new();
    let mut corrected: HashMap<KeyFrameId, Sim3> = HashMap::new();
    for &k in &connected {
        let T_iw = *map.keyframe(k).expect("connected keyframe").T_c_w();
        let S_iw = if k == current {
            found.S_cw
        } else {
            Sim3::from_isometry(&(T_iw * T_wc)) * found.S_cw
        };
        before.insert(k, Sim3::from_isometry(&T_iw));
        corrected.insert(k, S_iw);
    }
    // Each point moves with the first connected keyframe that sees it.
    let mut corrected_by: HashMap<MapPointId, KeyFrameId> = HashMap::new();
    for &k in &connected {
        let points: Vec<MapPointId> = map
            .keyframe(k)
            .map(|kf| kf.map_points().iter().flatten().copied().collect())
            .unwrap_or_default();
        for m in points {
            if corrected_by.contains_key(&m) {
                continue;
            }
            let Some(p) = map.map_point(m) else { continue };
            let p_w = move_point(&p.position(), &before[&k], &corrected[&k]);
            map.set_map_point_position(m, p_w)?;
            corrected_by.insert(m, k);
        }
        map.set_keyframe_pose(k, pose_of(&corrected[&k]))?;
    }
    for &m in corrected_by.keys() {
        if map.map_point(m).is_some() {
            map.update_normal_and_depth(m)?;
        }
    }

    // The loop's points replace the current keyframe's duplicates of them.
    for (i, loop_point) in found.matched.iter().enumerate() {
        let Some(loop_point) = loop_point.and_then(|m| map.resolve_map_point(m)) else {
            continue;
        };
        let own = map
            .keyframe(current)
            .and_then(|k| k.map_point(i))
            .and_then(|m| map.resolve_map_point(m));
        match own {
            Some(own) if own != loop_point => map.replace_map_point(own, loop_point)?,
            Some(_) => {}
            None if map
                .map_point(loop_point)
                .is_some_and(|p| p.observation(current).is_none()) =>
            {
                map.add_observation(loop_point, current, i)?;
                map.compute_distinctive_descriptor(loop_point)?;
            }
            None => {}
        }
    }
    let loop_points: Vec<MapPointId> = found
        .loop_points
        .iter()
        .filter_map(|&m| map.resolve_map_point(m))
        .collect::<HashSet<_>>()
        .into_iter()
        .collect();
    let mut loop_points = loop_points;
    loop_points.sort_unstable();
    let radius_px = ctx.config.loop_closing.fuse_radius_px;
    for &k in &connected {
        fuse_points_into(map, k, &loop_points, ctx, radius_px)?;
    }

    // Links that appear only through the fused points join the two sides of the loop.
    let connected_set: HashSet<KeyFrameId> = connected.iter().copied().collect();
    let mut loop_links: Vec<(KeyFrameId, Vec<KeyFrameId>)> = Vec::new();
    for &k in &connected {
        let previous: HashSet<KeyFrameId> = map.covisibles(k).into_iter().map(|(n, _)| n).collect();
        map.update_connections(k)?;
        let new: Vec<KeyFrameId> = map
            .covisibles(k)
            .into_iter()
            .map(|(n, _)| n)
            .filter(|n| !previous.contains(n) && !connected_set.contains(n))
            .collect();
        loop_links.push((k, new));
    }

    // Only points still alive under their own id were moved by the correction. A point
    // fused into another must not lend its keyframe to the survivor: several may resolve
    // to one survivor, and which of them a hash map kept depended on its random order.
    let corrected_points: HashMap<MapPointId, KeyFrameId> = corrected_by
        .into_iter()
        .filter(|(m, _)| map.map_point(*m).is_some())
        .collect();
    let costs = optimize_essential_graph(
        map,
        &EssentialGraphInput {
            current,
            loop_kf: found.loop_kf,
            before: &before,
            corrected: &corrected,
            loop_links: &loop_links,
            corrected_points: &corrected_points,
        },
        &ctx.config.loop_closing,
    )?;
    map.add_loop_edge(current, found.loop_kf)?;
    Ok(costs)
}
