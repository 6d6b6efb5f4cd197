//! Matching the map points of two keyframes: by bag-of-words node (ORB-SLAM
//! `SearchByBoW(KeyFrame, KeyFrame)`) and guided by a Sim(3) (`SearchBySim3`).

use ferroslam_features::matcher::finalize;
use ferroslam_features::matcher::{ProjectionQuery, TH_HIGH, TH_LOW};
use ferroslam_features::{hamming, MatchOptions};
use ferroslam_geometry::sim3::Sim3;
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_vocabulary::FeatureVector;
use nalgebra::{Point3, Vector3};

use super::row_projection::seen_from_row;
use crate::context::Context;
use crate::frame::search_camera;

/// For each keypoint of `kf1` carrying a map point, the map point of `kf2` whose keypoint
/// shares its vocabulary node and has the closest descriptor: within [`TH_LOW`], below `ratio`
/// times the second closest, one-to-one (the closer match wins) and consistent with the
/// dominant keypoint rotations (the matchers' common `finalize`). Indexed by `kf1`'s
/// keypoints.
pub(super) fn match_by_bow(
    map: &Map,
    (kf1, fv1): (KeyFrameId, &FeatureVector),
    (kf2, fv2): (KeyFrameId, &FeatureVector),
    ratio: f32,
) -> Vec<Option<MapPointId>> {
    let (Some(k1), Some(k2)) = (map.keyframe(kf1), map.keyframe(kf2)) else {
        return Vec::new();
    };
    let (f1, f2) = (k1.features(), k2.features());
    let good = |k: &ferroslam_map::KeyFrame, i: usize| {
        k.map_point(i).filter(|m| map.map_point(*m).is_some())
    };
    // best[i1] = (i2, distance)
    let mut best: Vec<Option<(usize, u32)>> = vec![None; f1.len()];
    for (_, idx1, idx2) in fv1.common_nodes(fv2) {
        for &i1 in idx1 {
            let i1 = i1 as usize;
            if good(k1, i1).is_none() {
                continue;
            }
            let (mut d1, mut d2, mut arg) = (u32::MAX, u32::MAX, 0);
            for &i2 in idx2 {
                let i2 = i2 as usize;
                if good(k2, i2).is_none() {
                    continue;
                }
                let d = hamming(&f1.descriptors[i1], &f2.descriptors[i2]);
                if d < d1 {
                    (d2, d1, arg) = (d1, d, i2);
                } else if d < d2 {
                    d2 = d;
                }
            }
            if d1 <= TH_LOW && (d1 as f32) < ratio * d2 as f32 {
                best[i1] = Some((arg, d1));
            }
        }
    }
    finalize(&mut best, f2.len(), true, |i1, i2| {
        Some(f1.keypoints[i1].angle_deg - f2.keypoints[i2].angle_deg)
    });
    best.iter()
        .map(|m| m.and_then(|(i2, _)| good(k2, i2)))
        .collect()
}

/// Completes `matches` (indexed by `kf1`'s keypoints, map points of `kf2`) with matches
/// found by projecting each keyframe's unmatched map points into every camera of the other
/// through `S_12` (keyframe-2 to keyframe-1 reference frames) within `th` pixels times the predicted level's
/// scale (each projection from the row it lands on, [`seen_from_row`]); a pair is added
/// only when both directions agree. Returns the number added.
pub(super) fn match_by_sim3(
    map: &Map,
    ctx: &Context,
    kf1: KeyFrameId,
    kf2: KeyFrameId,
    S_12: &Sim3,
    th: f64,
    matches: &mut [Option<MapPointId>],
) -> usize {
    let (Some(k1), Some(k2)) = (map.keyframe(kf1), map.keyframe(kf2)) else {
        return 0;
    };
    let already: std::collections::HashSet<MapPointId> =
        matches.iter().flatten().copied().collect();
    let S_21 = S_12.inverse();
    // Reference-frame points of kf1's unmatched map points, projected into every camera of
    // kf2, and vice versa.
    let side = |from: &ferroslam_map::KeyFrame,
                to: &ferroslam_map::KeyFrame,
                S_to_from: &Sim3,
                skip: &dyn Fn(usize, MapPointId) -> bool| {
        let f = to.features();
        let cameras = f.num_cameras();
        let mut queries: Vec<Vec<ProjectionQuery>> = vec![Vec::new(); cameras];
        let mut sources: Vec<Vec<usize>> = vec![Vec::new(); cameras];
        for (i, m) in from.map_points().iter().enumerate() {
            let Some(m) = m.filter(|m| map.map_point(*m).is_some()) else {
                continue;
            };
            if skip(i, m) {
                continue;
            }
            let p = map.map_point(m).unwrap();
            let p_from = (from.T_c_w() * Point3::from(p.position())).coords;
            let p_to: Vector3<f64> = S_to_from.transform_point(&p_from);
            for k in 0..cameras {
                let view = ctx.view(k);
                let p_k = view.point_in_camera(&p_to);
                let p_row = seen_from_row(&view, &f.xi_dot, &p_k);
                let Some(uv) = view.camera.project(&p_row).filter(|uv| view.contains(uv)) else {
                    continue;
                };
                let dist = p_k.norm();
                let range = (p.min_distance(), p.max_distance());
                if !ctx.config.visibility.in_scale_range(dist, range) {
                    continue;
                }
                let level = p.predict_level(dist, map.pyramid()) as u8;
                queries[k].push(ProjectionQuery {
                    u: uv.x,
                    v: uv.y,
                    radius: th * map.pyramid().scale[level as usize],
                    min_level: level.saturating_sub(1),
                    max_level: level + 1,
                    descriptor: *p.descriptor(),
                    angle_deg: None,
                });
                sources[k].push(i);
            }
        }
        let opts = MatchOptions {
            max_distance: TH_HIGH,
            nn_ratio: None,
            check_orientation: false,
        };
        // A point in the view of two cameras keeps the first camera's match.
        let mut out = vec![None; from.map_points().len()];
        for (k, (queries, sources)) in queries.iter().zip(&sources).enumerate() {
            let found = search_camera(queries, f, k, &[], &opts);
            for (q, hit) in found.into_iter().enumerate() {
                if let Some((t, _)) = hit {
                    out[sources[q]].get_or_insert(t);
                }
            }
        }
        out
    };
    let skip1 = |i: usize, _m: MapPointId| matches[i].is_some();
    let skip2 = |_i: usize, m: MapPointId| already.contains(&m);
    let from1 = side(k1, k2, &S_21, &skip1);
    let from2 = side(k2, k1, S_12, &skip2);
    let mut added = 0;
    for (i1, hit) in from1.iter().enumerate() {
        let Some(i2) = *hit else { continue };
        if from2.get(i2).copied().flatten() != Some(i1) {
            continue;
        }
        if let Some(m2) = k2.map_point(i2).filter(|m| map.map_point(*m).is_some()) {
            matches[i1] = Some(m2);
            added += 1;
        }
    }
    added
}
