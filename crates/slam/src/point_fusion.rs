//! Fusing duplicate map points (ORB-SLAM `SearchInNeighbors` and `ORBmatcher::Fuse`): after
//! local mapping creates points, and when loop correction projects the loop's points.

use std::collections::HashSet;

use ferroslam_features::hamming;
use ferroslam_features::matcher::TH_LOW;
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_optim::robust::{CHI2_MONO, CHI2_STEREO};

use crate::context::Context;
use crate::error::SlamError;
use crate::frustum::visible_point;

/// ORB-SLAM `SearchInNeighbors`: fuses the points of `kf` into its first and second
/// covisibility neighbours (`n_neighbours`, then `mapping.fusion_second_neighbours` of each)
/// and theirs into `kf`, within `mapping.fuse_radius_px`, then refreshes `kf`'s points and
/// links.
pub(crate) fn fuse_with_neighbours(
    kf: KeyFrameId,
    map: &mut Map,
    ctx: &Context,
    n_neighbours: usize,
) -> Result<usize, SlamError> {
    let mut targets = Vec::new();
    let mut seen: HashSet<KeyFrameId> = HashSet::from([kf]);
    for n in map.best_covisibles(kf, n_neighbours) {
        if seen.insert(n) {
            targets.push(n);
        }
        for n2 in map.best_covisibles(n, ctx.config.mapping.fusion_second_neighbours) {
            if seen.insert(n2) {
                targets.push(n2);
            }
        }
    }
    let own: Vec<MapPointId> = map
        .keyframe(kf)
        .map(|k| k.map_points().iter().flatten().copied().collect())
        .unwrap_or_default();
    let radius_px = ctx.config.mapping.fuse_radius_px;
    let mut fused = 0;
    for &t in &targets {
        fused += fuse_points_into(map, t, &own, ctx, radius_px)?;
    }
    let mut theirs = Vec::new();
    let mut seen_points = HashSet::new();
    for &t in &targets {
        for m in map
            .keyframe(t)
            .into_iter()
            .flat_map(|k| k.map_points().iter().flatten())
        {
            if seen_points.insert(*m) {
                theirs.push(*m);
            }
        }
    }
    fused += fuse_points_into(map, kf, &theirs, ctx, radius_px)?;
    let refreshed: Vec<MapPointId> = map
        .keyframe(kf)
        .map(|k| k.map_points().iter().flatten().copied().collect())
        .unwrap_or_default();
    for m in refreshed {
        if map.map_point(m).is_some() {
            map.compute_distinctive_descriptor(m)?;
            map.update_normal_and_depth(m)?;
        }
    }
    map.update_connections(kf)?;
    Ok(fused)
}

/// Projects `points` into keyframe `kf` and, for the best keypoint passing the reprojection
/// test within `th * scale` pixels (`th`: pixels at level 0), either merges duplicates (the
/// point with more observations survives) or adds the observation (ORB-SLAM
/// `ORBmatcher::Fuse`).
pub(crate) fn fuse_points_into(
    map: &mut Map,
    kf: KeyFrameId,
    points: &[MapPointId],
    ctx: &Context,
    th: f64,
) -> Result<usize, SlamError> {
    let Some(k) = map.keyframe(kf) else {
        return Ok(0);
    };
    let (T_c0_w, center0) = (*k.T_c_w(), k.camera_center());
    let pyramid = map.pyramid().clone();
    let rules = &ctx.config.visibility;
    let mut fused = 0;
    for &m in points {
        let Some(p) = map.map_point(m) else { continue };
        if p.observations().contains_key(&kf) {
            continue;
        }
        let descriptor = *p.descriptor();
        let k = map.keyframe(kf).unwrap();
        let f = k.features();
        // The closest descriptor among the cameras that see the point.
        let mut best: Option<(u32, usize)> = None;
        for camera in 0..f.num_cameras().min(ctx.num_cameras()) {
            let view = ctx.view(camera);
            let T_c_w = view.pose(&T_c0_w);
            let center = if camera == 0 {
                center0
            } else {
                view.center(&T_c0_w)
            };
            let Some(vis) = visible_point(map, m, &T_c_w, &center, view.camera, view.bounds, rules)
            else {
                continue;
            };
            let ur_pred = view.u_right(&vis.p_c, vis.u);
            let radius = th * pyramid.scale[vis.level as usize];
            let range = f.camera_range(camera);
            let keypoints = &f.keypoints[range.clone()];
            for local in f
                .grid(camera)
                .features_in_area(keypoints, vis.u, vis.v, radius, None, None)
            {
                let i = range.start + local;
                let kp = &f.keypoints[i];
                if kp.octave + 1 < vis.level || kp.octave > vis.level {
                    continue;
                }
                let (ex, ey) = (vis.u - kp.x as f64, vis.v - kp.y as f64);
                let ur = f.u_right[i] as f64;
                let inv_s2 = pyramid.inv_sigma2[kp.octave as usize];
                let chi2_ok = if ur >= 0.0 {
                    let er = ur_pred - ur;
                    (ex * ex + ey * ey + er * er) * inv_s2 <= CHI2_STEREO
                } else {
                    (ex * ex + ey * ey) * inv_s2 <= CHI2_MONO
                };
                if !chi2_ok {
                    continue;
                }
                let d = hamming(&descriptor, &f.descriptors[i]);
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, i));
                }
            }
        }
        let Some((_, i)) = best.filter(|(d, _)| *d <= TH_LOW) else {
            continue;
        };
        match k
            .map_point(i)
            .filter(|other| map.map_point(*other).is_some())
        {
            Some(other) if other != m => {
                let n_other = map.map_point(other).unwrap().num_observations();
                let n_this = map.map_point(m).unwrap().num_observations();
                if n_other > n_this {
                    map.replace_map_point(m, other)?;
                } else {
                    map.replace_map_point(other, m)?;
                }
                fused += 1;
            }
            Some(_) => {}
            None => {
                map.add_observation(m, kf, i)?;
                fused += 1;
            }
        }
    }
    Ok(fused)
}
