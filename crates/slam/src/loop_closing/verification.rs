//! Geometric verification of a loop candidate (ORB-SLAM `LoopClosing::ComputeSim3`):
//! bag-of-words matches, Sim(3) RANSAC (scale fixed to 1 with depth sensors), Sim(3)-guided
//! matching, Sim(3) refinement, then the loop's map points projected into the current
//! keyframe; accepted with at least `loop_closure_threshold` matched points. Through a
//! rolling shutter, each keypoint is compared with its row's projection ([`row_projection`]).
//!
//! [`row_projection`]: super::row_projection

use std::collections::HashSet;

use ferroslam_features::matcher::{ProjectionQuery, TH_LOW};
use ferroslam_features::MatchOptions;
use ferroslam_geometry::sim3::Sim3;
use ferroslam_geometry::sim3_ransac::{sim3_ransac, Sim3Correspondence, Sim3RansacParams};
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_optim::sim3_align::{optimize_sim3, Sim3Match};
use ferroslam_vocabulary::FeatureVector;
use nalgebra::{Isometry3, Point3, Translation3};
use rand_chacha::ChaCha8Rng;

use super::keyframe_matching::{match_by_bow, match_by_sim3};
use super::row_projection::{keypoint_at_reference_line, visible_from_row};
use crate::context::Context;
use crate::frame::search_camera;

/// chi2 threshold of a reprojection at 2 degrees of freedom, 99 % (RANSAC inliers).
const CHI2_2DOF: f64 = 9.21;

/// A verified loop between the current keyframe and `loop_kf`.
#[derive(Clone, Debug)]
pub(crate) struct LoopMatch {
    /// The matched earlier keyframe.
    pub loop_kf: KeyFrameId,
    /// Corrected pose of the current keyframe, world to camera (scale 1 with depth sensors).
    pub S_cw: Sim3,
    /// Per keypoint of the current keyframe, the loop map point it matched.
    pub matched: Vec<Option<MapPointId>>,
    /// The map points of the loop keyframe and its covisible keyframes.
    pub loop_points: Vec<MapPointId>,
    /// Number of `Some` in `matched`.
    pub num_matches: usize,
}

/// A rigid pose from a world-to-camera similarity: the same projections, depth divided by
/// the scale (ORB-SLAM converts corrected Sim(3) poses to SE(3) this way).
pub(crate) fn pose_of(S_cw: &Sim3) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(S_cw.translation / S_cw.scale),
        S_cw.rotation,
    )
}

/// Verifies `candidate` as a loop for `current`, given their bag-of-words feature vectors
/// `fv`; `None` when any stage falls short. A merge candidate is verified the same way, both
/// maps in one (each keyframe's pose in its own map's world).
pub(crate) fn verify_loop(
    current: KeyFrameId,
    candidate: KeyFrameId,
    map: &Map,
    ctx: &Context,
    fv: (&FeatureVector, &FeatureVector),
    rng: &mut ChaCha8Rng,
) -> Option<LoopMatch> {
    let (fv1, fv2) = fv;
    let config = &ctx.config.loop_closing;
    let mut matches = match_by_bow(map, (current, fv1), (candidate, fv2), config.bow_nn_ratio);
    if matches.iter().flatten().count() < config.min_stage_matches {
        return None;
    }
    let fix_scale = ctx.config.sensor.has_depth();
    let (_, pairs) = correspondences(map, ctx, current, candidate, &matches);
    let params = Sim3RansacParams {
        probability: config.sim3_ransac_probability,
        min_inliers: config.min_stage_matches,
        max_iterations: config.sim3_ransac_iterations,
        fix_scale,
    };
    let corr: Vec<Sim3Correspondence> = pairs
        .iter()
        .map(|p| Sim3Correspondence {
            p1: p.p1,
            p2: p.p2,
            uv1: p.uv1,
            uv2: p.uv2,
            camera1: p.camera1,
            camera2: p.camera2,
            max_err2_1: CHI2_2DOF / p.inv_sigma2_1,
            max_err2_2: CHI2_2DOF / p.inv_sigma2_2,
        })
        .collect();
    let project = |k: usize, p: &nalgebra::Vector3<f64>| {
        let view = ctx.view(k);
        view.camera.project(&view.point_in_camera(p))
    };
    let ransac = sim3_ransac(&corr, project, &params, rng)?;
    match_by_sim3(
        map,
        ctx,
        current,
        candidate,
        &ransac.S_12,
        config.guided_radius_px,
        &mut matches,
    );
    let (ids, pairs) = correspondences(map, ctx, current, candidate, &matches);
    let refined = optimize_sim3(
        &ransac.S_12,
        &pairs,
        &ctx.optim_cameras,
        config.sim3_huber_chi2,
        fix_scale,
    )
    .ok()?;
    if refined.num_inliers < config.min_stage_matches {
        return None;
    }
    let S_12 = refined.S_12;
    let T_2w = *map.keyframe(candidate)?.T_c_w();
    let S_cw = S_12 * Sim3::from_isometry(&T_2w);

    // The loop's neighbourhood, projected into the current keyframe.
    let mut matched: Vec<Option<MapPointId>> = vec![None; matches.len()];
    let k1 = map.keyframe(current)?;
    for (&(i1, m2), inlier) in ids.iter().zip(&refined.inliers) {
        if *inlier {
            matched[i1] = Some(m2);
        }
    }
    let loop_points = map.points_seen_by(
        std::iter::once(candidate).chain(map.covisibles(candidate).into_iter().map(|(k, _)| k)),
    );
    let already: HashSet<MapPointId> = matched.iter().flatten().copied().collect();
    let T_cw = pose_of(&S_cw);
    let f = k1.features();
    let opts = MatchOptions {
        max_distance: TH_LOW,
        nn_ratio: None,
        check_orientation: false,
    };
    // Camera by camera; a point found by one camera is not searched for by the next.
    let mut found_points: HashSet<MapPointId> = already;
    for k in 0..f.num_cameras() {
        let view = ctx.view(k);
        let mut queries = Vec::new();
        let mut sources = Vec::new();
        for &m in loop_points.iter().filter(|m| !found_points.contains(m)) {
            let Some(vis) = visible_from_row(map, m, &T_cw, &f.xi_dot, &view, ctx) else {
                continue;
            };
            queries.push(ProjectionQuery {
                u: vis.u,
                v: vis.v,
                radius: config.projection_radius_px * map.pyramid().scale[vis.level as usize],
                min_level: vis.level.saturating_sub(1),
                max_level: vis.level,
                descriptor: *map.map_point(m)?.descriptor(),
                angle_deg: None,
            });
            sources.push(m);
        }
        let taken: Vec<bool> = matched.iter().map(Option::is_some).collect();
        let found = search_camera(&queries, f, k, &taken, &opts);
        for (q, hit) in found.into_iter().enumerate() {
            if let Some((i, _)) = hit {
                matched[i] = Some(sources[q]);
                found_points.insert(sources[q]);
            }
        }
    }
    let num_matches = matched.iter().flatten().count();
    (num_matches >= config.loop_closure_threshold).then_some(LoopMatch {
        loop_kf: candidate,
        S_cw,
        matched,
        loop_points,
        num_matches,
    })
}

/// The matches whose two map points both exist, as `(keypoint of kf1, map point of kf2)` and
/// as Sim(3) correspondences (points in each keyframe's reference frame, its first camera's;
/// keypoint pixels of the camera that measured them, moved to the reference line; octave
/// weights).
fn correspondences(
    map: &Map,
    ctx: &Context,
    kf1: KeyFrameId,
    kf2: KeyFrameId,
    matches: &[Option<MapPointId>],
) -> (Vec<(usize, MapPointId)>, Vec<Sim3Match>) {
    let (Some(k1), Some(k2)) = (map.keyframe(kf1), map.keyframe(kf2)) else {
        return (Vec::new(), Vec::new());
    };
    let inv_sigma2 = &map.pyramid().inv_sigma2;
    let mut ids = Vec::new();
    let mut out = Vec::new();
    for (i1, m2) in matches.iter().enumerate() {
        let Some(m2) = *m2 else { continue };
        let Some(m1) = k1.map_point(i1) else { continue };
        let (Some(p1), Some(p2)) = (map.map_point(m1), map.map_point(m2)) else {
            continue;
        };
        let Some(i2) = p2.observation(kf2) else {
            continue;
        };
        // Each keyframe is one generalised camera: points in its reference frame, each
        // keypoint in the camera that measured it.
        let (c1, c2) = (k1.features().camera_of(i1), k2.features().camera_of(i2));
        let (view1, view2) = (ctx.view(c1), ctx.view(c2));
        let (kp1, kp2) = (&k1.features().keypoints[i1], &k2.features().keypoints[i2]);
        let p1 = (k1.T_c_w() * Point3::from(p1.position())).coords;
        let p2 = (k2.T_c_w() * Point3::from(p2.position())).coords;
        let (p1_c, p2_c) = (view1.point_in_camera(&p1), view2.point_in_camera(&p2));
        ids.push((i1, m2));
        out.push(Sim3Match {
            p1,
            p2,
            uv1: keypoint_at_reference_line(view1.camera, k1.features(), i1, &p1_c),
            uv2: keypoint_at_reference_line(view2.camera, k2.features(), i2, &p2_c),
            camera1: c1,
            camera2: c2,
            inv_sigma2_1: inv_sigma2[kp1.octave as usize],
            inv_sigma2_2: inv_sigma2[kp2.octave as usize],
        });
    }
    (ids, out)
}
