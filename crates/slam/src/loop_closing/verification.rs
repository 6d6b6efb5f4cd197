//! Geometric verification of a loop candidate (ORB-SLAM `LoopClosing::ComputeSim3`):
//! bag-of-words matches, Sim(3) RANSAC (scale fixed to 1 with depth sensors), Sim(3)-guided
//! matching, Sim(3) refinement, then the loop's map points projected into the current
//! keyframe; accepted with at least `loop_closure_threshold` matched points. A merge candidate
//! (another map of the atlas) is verified over its window of covisible keyframes
//! ([`verify_window`]). Through a rolling shutter, each keypoint is compared with its row's projection ([`row_projection`]).
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

/// Per keypoint of the current keyframe, the map point of the other map part it matched.
type Matches = Vec<Option<MapPointId>>;

/// The fewest matches each stage of a verification passes on.
#[derive(Clone, Copy)]
struct Gates {
    /// Sim(3) RANSAC inliers.
    ransac: usize,
    /// Inliers of the refined Sim(3).
    refined: usize,
    /// Matched points after the final projection.
    accepted: usize,
}

/// Verifies `candidate` as a loop for `current`, given their bag-of-words feature vectors
/// `fv`; `None` when any stage falls short.
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
    let gates = Gates {
        ransac: config.min_stage_matches,
        refined: config.min_stage_matches,
        accepted: config.loop_closure_threshold,
    };
    let S_12 = ransac_sim3(map, ctx, (current, candidate), &matches, gates.ransac, rng)?;
    match_by_sim3(
        map,
        ctx,
        current,
        candidate,
        &S_12,
        config.guided_radius_px,
        &mut matches,
    );
    let (S_12, matched) = refine_sim3(map, ctx, (current, candidate), &S_12, &matches, gates)?;
    accept(map, ctx, current, candidate, &S_12, matched, gates)
}

/// Verifies a place of another map part for `current` (ORB-SLAM3
/// `DetectCommonRegionsFromBoW`): `current` (bag-of-words `fv1`) is matched against every
/// keyframe of `window` (the candidate first, then its best covisible keyframes, each with its
/// feature vector), each keypoint and each map point taken once; the keyframe with the most
/// matches is the reference of the Sim(3) RANSAC over the pooled matches. The RANSAC's
/// similarity then guides a fresh search by projection of the reference's neighbourhood (a
/// handful of bag-of-words matches finds a pose that projection completes), which is refined
/// and completed by projection as a loop is, with the merge's gates (`loop_closing.merge_*`:
/// lower for the RANSAC and the refinement, higher for the final count). A keyframe seen
/// from another map shares few words with any one keyframe there, enough with its
/// neighbourhood.
pub(crate) fn verify_window(
    (current, fv1): (KeyFrameId, &FeatureVector),
    window: &[(KeyFrameId, &FeatureVector)],
    map: &Map,
    ctx: &Context,
    rng: &mut ChaCha8Rng,
) -> Option<LoopMatch> {
    let config = &ctx.config.loop_closing;
    let mut matches: Matches = vec![None; map.keyframe(current)?.features().len()];
    let mut pooled: HashSet<MapPointId> = HashSet::new();
    let mut reference = (0, window.first()?.0);
    for &(k, fv) in window {
        let found = match_by_bow(map, (current, fv1), (k, fv), config.bow_nn_ratio);
        let count = found.iter().flatten().count();
        if count > reference.0 {
            reference = (count, k);
        }
        for (slot, m) in matches.iter_mut().zip(found) {
            if let Some(m) = m.filter(|m| slot.is_none() && pooled.insert(*m)) {
                *slot = Some(m);
            }
        }
    }
    if pooled.len() < config.min_stage_matches {
        return None;
    }
    let reference = reference.1;
    let gates = Gates {
        ransac: config.merge_ransac_inliers,
        refined: config.merge_refined_inliers,
        accepted: config.merge_threshold,
    };
    let S_12 = ransac_sim3(map, ctx, (current, reference), &matches, gates.ransac, rng)?;
    let T_2w = *map.keyframe(reference)?.T_c_w();
    let mut guided: Matches = vec![None; matches.len()];
    let points = neighbourhood_points(map, reference);
    let S_cw = S_12 * Sim3::from_isometry(&T_2w);
    let radius = config.guided_radius_px;
    match_by_projection(
        map,
        ctx,
        current,
        &pose_of(&S_cw),
        &points,
        radius,
        &mut guided,
    );
    if guided.iter().flatten().count() < config.min_stage_matches {
        return None;
    }
    let (S_12, matched) = refine_sim3(map, ctx, (current, reference), &S_12, &guided, gates)?;

    accept(map, ctx, current, reference, &S_12, matched, gates)
}

/// The map points of `kf` and its covisible keyframes: a loop's neighbourhood.
fn neighbourhood_points(map: &Map, kf: KeyFrameId) -> Vec<MapPointId> {
    map.points_seen_by(std::iter::once(kf).chain(map.covisibles(kf).into_iter().map(|(k, _)| k)))
}

/// The Sim(3) RANSAC over `matches` between keyframes `kf1` and `kf2` with at least
/// `min_inliers`: `S_12`.
fn ransac_sim3(
    map: &Map,
    ctx: &Context,
    (kf1, kf2): (KeyFrameId, KeyFrameId),
    matches: &[Option<MapPointId>],
    min_inliers: usize,
    rng: &mut ChaCha8Rng,
) -> Option<Sim3> {
    let config = &ctx.config.loop_closing;
    let (_, pairs) = correspondences(map, ctx, kf1, kf2, matches);
    let params = Sim3RansacParams {
        probability: config.sim3_ransac_probability,
        min_inliers,
        max_iterations: config.sim3_ransac_iterations,
        fix_scale: ctx.config.sensor.has_depth(),
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
    sim3_ransac(&corr, project, &params, rng).map(|r| r.S_12)
}

/// `S_12` refined over `matches` between `kf1` and `kf2`, with the matches it keeps as
/// inliers; `None` below `gates.refined` inliers.
fn refine_sim3(
    map: &Map,
    ctx: &Context,
    (kf1, kf2): (KeyFrameId, KeyFrameId),
    S_12: &Sim3,
    matches: &[Option<MapPointId>],
    gates: Gates,
) -> Option<(Sim3, Matches)> {
    let config = &ctx.config.loop_closing;
    let (ids, pairs) = correspondences(map, ctx, kf1, kf2, matches);

    let refined = optimize_sim3(
        S_12,
        &pairs,
        &ctx.optim_cameras,
        config.sim3_huber_chi2,
        ctx.config.sensor.has_depth(),
    )
    .ok()?;
    if refined.num_inliers < gates.refined {
        return None;
    }
    let mut matched: Matches = vec![None; matches.len()];
    for (&(i1, m2), inlier) in ids.iter().zip(&refined.inliers) {
        if *inlier {
            matched[i1] = Some(m2);
        }
    }
    Some((refined.S_12, matched))
}

/// The last stage: the neighbourhood of `loop_kf` projected into `current` posed by `S_12`
/// (from `loop_kf`'s frame) completes the refined `matched`; accepted with at least
/// `gates.accepted` matched points.
fn accept(
    map: &Map,
    ctx: &Context,
    current: KeyFrameId,
    loop_kf: KeyFrameId,
    S_12: &Sim3,
    mut matched: Matches,
    gates: Gates,
) -> Option<LoopMatch> {
    let config = &ctx.config.loop_closing;
    let S_cw = *S_12 * Sim3::from_isometry(map.keyframe(loop_kf)?.T_c_w());
    let loop_points = neighbourhood_points(map, loop_kf);
    let radius = config.projection_radius_px;
    match_by_projection(
        map,
        ctx,
        current,
        &pose_of(&S_cw),
        &loop_points,
        radius,
        &mut matched,
    );
    let num_matches = matched.iter().flatten().count();
    (num_matches >= gates.accepted).then_some(LoopMatch {
        loop_kf,
        S_cw,
        matched,
        loop_points,
        num_matches,
    })
}

/// Completes `matched` (per keypoint of `current`) with the `points` not matched yet,
/// projected into `current` posed at `T_cw` within `radius` pixels times the predicted
/// level's scale.
fn match_by_projection(
    map: &Map,
    ctx: &Context,
    current: KeyFrameId,
    T_cw: &Isometry3<f64>,
    points: &[MapPointId],
    radius: f64,
    matched: &mut [Option<MapPointId>],
) {
    let Some(k1) = map.keyframe(current) else {
        return;
    };
    let f = k1.features();
    let opts = MatchOptions {
        max_distance: TH_LOW,
        nn_ratio: None,
        check_orientation: false,
    };
    // Camera by camera; a point found by one camera is not searched for by the next.
    let mut found_points: HashSet<MapPointId> = matched.iter().flatten().copied().collect();
    for k in 0..f.num_cameras() {
        let view = ctx.view(k);
        let mut queries = Vec::new();
        let mut sources = Vec::new();
        for &m in points.iter().filter(|m| !found_points.contains(m)) {
            let (Some(vis), Some(point)) = (
                visible_from_row(map, m, T_cw, &f.xi_dot, &view, ctx),
                map.map_point(m),
            ) else {
                continue;
            };
            queries.push(ProjectionQuery {
                u: vis.u,
                v: vis.v,
                radius: radius * map.pyramid().scale[vis.level as usize],
                min_level: vis.level.saturating_sub(1),
                max_level: vis.level,
                descriptor: *point.descriptor(),
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
}

/// The matches whose two map points both exist, as `(keypoint of kf1, map point of kf2)` and
/// as Sim(3) correspondences (points in each keyframe's reference frame, its first camera's;
/// keypoint pixels of the camera that measured them, moved to the reference line; octave
/// weights). A point `kf2` does not observe (matched in a keyframe of its window) is measured
/// where `kf2`'s first camera projects it, with `kf1`'s keypoint weight (ORB-SLAM3's
/// `Sim3Solver` and `OptimizeSim3` over a window do the same).
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
        let i2 = p2.observation(kf2);
        // Each keyframe is one generalised camera: points in its reference frame, each
        // keypoint in the camera that measured it.
        let c1 = k1.features().camera_of(i1);
        let c2 = i2.map_or(0, |i2| k2.features().camera_of(i2));
        let (view1, view2) = (ctx.view(c1), ctx.view(c2));
        let kp1 = &k1.features().keypoints[i1];
        let p1 = (k1.T_c_w() * Point3::from(p1.position())).coords;
        let p2 = (k2.T_c_w() * Point3::from(p2.position())).coords;
        let (p1_c, p2_c) = (view1.point_in_camera(&p1), view2.point_in_camera(&p2));
        let (uv2, octave2) = match i2 {
            Some(i2) => (
                keypoint_at_reference_line(&view2, k2.features(), i2, &p2_c),
                k2.features().keypoints[i2].octave,
            ),
            None => match view2.camera.project(&p2_c) {
                Some(uv) => (uv, kp1.octave),
                None => continue,
            },
        };
        ids.push((i1, m2));
        out.push(Sim3Match {
            p1,
            p2,
            uv1: keypoint_at_reference_line(&view1, k1.features(), i1, &p1_c),
            uv2,
            camera1: c1,
            camera2: c2,
            inv_sigma2_1: inv_sigma2[kp1.octave as usize],
            inv_sigma2_2: inv_sigma2[octave2 as usize],
        });
    }
    (ids, out)
}
