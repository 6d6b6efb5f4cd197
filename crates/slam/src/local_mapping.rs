//! Local mapping: what happens to the map when a keyframe is inserted (ORB-SLAM `LocalMapping`):
//! new points from depth, culling of recent points, triangulation with covisible keyframes,
//! fusion of duplicates, local bundle adjustment and culling of redundant keyframes.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use ferroslam_features::matcher::TH_LOW;
use ferroslam_features::{
    search_for_triangulation, search_for_triangulation_rays, Keypoint, MatchOptions,
};
use ferroslam_geometry::camera::{CameraModel, PinholeCamera};
use ferroslam_geometry::triangulation::{essential_matrix, triangulate_dlt, triangulate_rays};
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_optim::robust::{CHI2_MONO, CHI2_STEREO};
#[cfg(feature = "bench")]
use ferroslam_optim::BaProblem;
use nalgebra::{Isometry3, Matrix3, Point3, Vector2, Vector3};

use crate::context::Context;
use crate::error::SlamError;
use crate::frame::unproject_depth;
use crate::local_ba_problem::adjust_around;
use crate::local_inertial_ba::{local_inertial_bundle_adjust, InertialWindow};
use crate::point_fusion::fuse_with_neighbours;

/// What one keyframe's local mapping did, for logs and tests.
#[derive(Clone, Debug, Default)]
pub struct MappingReport {
    /// Points created from depth when the keyframe was inserted.
    pub depth_points: usize,
    /// Points triangulated with covisible keyframes.
    pub triangulated_points: usize,
    /// Recent points removed for failing the culling tests.
    pub culled_points: usize,
    /// Duplicate points fused.
    pub fused_points: usize,
    /// Observations rejected by local BA.
    pub ba_outliers: usize,
    /// Keyframes removed as redundant.
    pub culled_keyframes: usize,
    /// Wall time of local BA (visual or visual-inertial), milliseconds.
    pub local_ba_ms: f64,
    /// Tracking waited for this keyframe's mapping, which stopped after triangulation (see
    /// `Interrupt`).
    pub interrupted: bool,
}

/// What tells local mapping to finish a keyframe sooner (concurrent mapping).
///
/// Tracking waits to insert a keyframe ([`Self::requested`]): local mapping then skips the
/// rest of the current keyframe's optional work (triangulation with further neighbours,
/// fusion, local BA, keyframe culling), as ORB-SLAM's `LocalMapping` does when
/// `CheckNewKeyFrames()` finds a keyframe queued. Without it, tracking would wait for the
/// whole of it (on KITTI stereo, with a keyframe almost every frame, that is most frames).
///
/// Frames come faster than local mapping processed the last keyframe (`hurried`):
/// triangulation searches fewer neighbours (`mapping.hurried_triangulation_neighbours` of
/// the configuration).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Interrupt<'a> {
    waiting: Option<&'a AtomicBool>,
    hurried: bool,
}

impl<'a> Interrupt<'a> {
    /// Never requested (inline mapping: nothing waits).
    pub(crate) const NEVER: Self = Self {
        waiting: None,
        hurried: false,
    };

    /// Requested once `waiting` is set.
    pub(crate) fn on(waiting: &'a AtomicBool, hurried: bool) -> Self {
        Self {
            waiting: Some(waiting),
            hurried,
        }
    }

    fn requested(self) -> bool {
        self.waiting.is_some_and(|f| f.load(Ordering::Relaxed))
    }
}

/// State of local mapping between keyframes.
#[derive(Debug, Default)]
pub struct LocalMapper {
    /// Points created recently and not yet proven (ORB-SLAM `mlpRecentAddedMapPoints`).
    recent_points: Vec<MapPointId>,
    /// While recording, every local BA problem as built, before it is solved.
    #[cfg(feature = "bench")]
    recorded_problems: Option<Vec<BaProblem>>,
}

impl LocalMapper {
    /// Forgets the map's points (after a map reset); a recording goes on.
    pub fn reset(&mut self) {
        self.recent_points.clear();
    }

    /// Starts (`true`) or stops recording each local BA problem before it is solved; stopping
    /// drops what was recorded.
    #[cfg(feature = "bench")]
    pub(crate) fn record_problems(&mut self, on: bool) {
        if on != self.recorded_problems.is_some() {
            self.recorded_problems = on.then(Vec::new);
        }
    }

    /// Whether local BA problems are being recorded.
    #[cfg(feature = "bench")]
    pub(crate) fn is_recording(&self) -> bool {
        self.recorded_problems.is_some()
    }

    /// Whether local BA problems are being recorded (never without the `bench` feature).
    #[cfg(not(feature = "bench"))]
    pub(crate) fn is_recording(&self) -> bool {
        false
    }

    /// The problems recorded since the last call.
    #[cfg(feature = "bench")]
    pub(crate) fn take_recorded_problems(&mut self) -> Vec<BaProblem> {
        self.recorded_problems
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Registers a point created outside local mapping (by tracking) for culling.
    pub(crate) fn add_recent_point(&mut self, m: MapPointId) {
        self.recent_points.push(m);
    }

    /// Follows the renaming of points created in a map copy and replayed on the original
    /// (see `ferroslam_map::MapJournal`).
    pub(crate) fn rename_recent_points(&mut self, renamed: &HashMap<MapPointId, MapPointId>) {
        for m in &mut self.recent_points {
            if let Some(new) = renamed.get(m) {
                *m = *new;
            }
        }
    }

    /// The stages that change which points the keyframe's neighbourhood has: culling of
    /// recent points, triangulation, fusion with the neighbours. Stops after triangulation
    /// (and sets `report.interrupted`) when `interrupt` is requested; then [`Self::refine`]
    /// is skipped too. `points_added` is called after each neighbour that brought points, so
    /// the mapping thread can send them ahead (see [`Self::create_new_points`]).
    pub(crate) fn grow(
        &mut self,
        kf: KeyFrameId,
        map: &mut Map,
        ctx: &Context,
        report: &mut MappingReport,
        interrupt: Interrupt<'_>,
        points_added: &mut dyn FnMut(&mut Map),
    ) -> Result<(), SlamError> {
        report.culled_points += self.cull_recent_points(kf, map, ctx);
        report.triangulated_points +=
            self.create_new_points(kf, map, ctx, interrupt, points_added)?;
        if interrupt.requested() {
            report.interrupted = true;
            return Ok(());
        }
        report.fused_points +=
            fuse_with_neighbours(kf, map, ctx, ctx.config.mapping.triangulation_neighbours)?;
        Ok(())
    }

    /// The stages that refine the local map after [`Self::grow`]: local BA (inertial over
    /// `inertial` when given: an aligned visual-inertial map; its states are updated), then
    /// keyframe culling.
    pub(crate) fn refine(
        &mut self,
        kf: KeyFrameId,
        map: &mut Map,
        ctx: &Context,
        report: &mut MappingReport,
        inertial: Option<&mut InertialWindow>,
    ) -> Result<(), SlamError> {
        let start = Instant::now();
        report.ba_outliers += match inertial {
            Some(window) => local_inertial_bundle_adjust(kf, window, map, ctx)?,
            None => self.local_bundle_adjust(kf, map, ctx)?,
        };
        report.local_ba_ms += start.elapsed().as_secs_f64() * 1e3;
        report.culled_keyframes += self.cull_keyframes(kf, map, ctx);
        Ok(())
    }

    /// ORB-SLAM `MapPointCulling`: a recent point dies if found in less than
    /// `mapping.min_found_ratio` of the frames that should have seen it, or if
    /// `mapping.recent_point_check_age` keyframes later it has too few observations; after
    /// `mapping.recent_point_proven_age` keyframes it is proven.
    fn cull_recent_points(&mut self, current: KeyFrameId, map: &mut Map, ctx: &Context) -> usize {
        let config = &ctx.config.mapping;
        let (min_obs, min_found) = (config.min_point_observations, config.min_found_ratio);
        let mut culled = 0;
        let mut kept = Vec::with_capacity(self.recent_points.len());
        for &m in &self.recent_points {
            let Some(p) = map.map_point(m) else { continue };
            let age = current.0.saturating_sub(p.first_keyframe().0);
            if p.found_ratio() < min_found
                || (age >= config.recent_point_check_age && p.num_observations() <= min_obs)
            {
                map.set_map_point_bad(m);
                culled += 1;
            } else if age < config.recent_point_proven_age {
                kept.push(m);
            }
        }
        self.recent_points = kept;
        culled
    }

    /// Triangulates unmatched features of `kf` with those of its best covisible keyframes
    /// (ORB-SLAM `CreateNewMapPoints`): epipolar matching, parallax, positive depth,
    /// reprojection and scale-consistency checks. Close features with depth use it directly
    /// when their stereo parallax beats the ray parallax. After the best neighbour, stops
    /// when `interrupt` is requested; searches fewer neighbours when it is hurried; with
    /// depth, stops after a neighbour that brought few points (see
    /// `mapping.always_searched_with_depth`). Calls
    /// `points_added` after each neighbour that brought points, so the best neighbours'
    /// points, most of them, can be used before the search ends.
    fn create_new_points(
        &mut self,
        kf: KeyFrameId,
        map: &mut Map,
        ctx: &Context,
        interrupt: Interrupt<'_>,
        points_added: &mut dyn FnMut(&mut Map),
    ) -> Result<usize, SlamError> {
        let (sensor, config) = (ctx.config.sensor, &ctx.config.mapping);
        let n_neighbours = if interrupt.hurried {
            config.hurried_triangulation_neighbours
        } else {
            config.triangulation_neighbours
        };
        let neighbours = map.best_covisibles(kf, n_neighbours);
        let median_depth = map.scene_median_depth(kf);
        let pyramid = map.pyramid().clone();
        let ratio_factor = config.scale_consistency_factor * pyramid.scale_factor;
        let mut created = 0;
        let n_cameras = ctx.num_cameras();
        for (n, kf2) in neighbours.into_iter().enumerate() {
            if n > 0 && interrupt.requested() {
                break;
            }
            if map.keyframe(kf).is_none() || map.keyframe(kf2).is_none() {
                continue;
            }
            let (mut searched, mut brought) = (false, 0);
            for (a, b) in (0..n_cameras).flat_map(|a| (0..n_cameras).map(move |b| (a, b))) {
                let pair = CameraPair {
                    kf1: kf,
                    kf2,
                    cameras: [a, b],
                };
                let Some(new_points) = pair.triangulate(map, ctx, median_depth, ratio_factor)
                else {
                    continue;
                };
                searched = true;
                for (p_w, i1, i2) in new_points {
                    let m = map.create_map_point(p_w, kf)?;
                    map.add_observation(m, kf, i1)?;
                    map.add_observation(m, kf2, i2)?;
                    map.compute_distinctive_descriptor(m)?;
                    map.update_normal_and_depth(m)?;
                    self.recent_points.push(m);
                    brought += 1;
                }
            }
            if !searched {
                continue;
            }
            created += brought;
            if brought > 0 {
                points_added(map);
            }
            if sensor.has_depth()
                && n >= config.always_searched_with_depth
                && brought < config.min_points_to_search_on
            {
                break;
            }
        }
        Ok(created)
    }

    /// Local BA over `kf` and its covisible keyframes, with the other keyframes that see
    /// their points held fixed; rejected observations are erased from the map.
    pub(crate) fn local_bundle_adjust(
        &mut self,
        kf: KeyFrameId,
        map: &mut Map,
        ctx: &Context,
    ) -> Result<usize, SlamError> {
        #[cfg(feature = "bench")]
        let record = self.recorded_problems.as_mut();
        #[cfg(not(feature = "bench"))]
        let record = None;
        adjust_around(kf, map, ctx, record)
    }

    /// ORB-SLAM `KeyFrameCulling`: a covisible keyframe is redundant when more than
    /// `mapping.redundant_keyframe_share` of its close points are seen, at the same, a finer or
    /// at most `mapping.redundant_level_margin` coarser levels, by at least `mapping.redundant_observations` other keyframes.
    fn cull_keyframes(&self, kf: KeyFrameId, map: &mut Map, ctx: &Context) -> usize {
        let redundant = ctx.config.mapping.redundant_observations;
        let share = ctx.config.mapping.redundant_keyframe_share;
        let mut culled = 0;
        for (candidate, _) in map.covisibles(kf) {
            if Some(candidate) == map.origin() {
                continue;
            }
            let Some(k) = map.keyframe(candidate) else {
                continue;
            };
            let f = k.features();
            let (mut n_points, mut n_redundant) = (0usize, 0usize);
            for (i, m) in k.map_points().iter().enumerate() {
                let Some(p) = m.and_then(|m| map.map_point(m)) else {
                    continue;
                };
                let z = f.depth[i] as f64;
                if ctx.config.sensor.has_depth() && (z < 0.0 || z > ctx.close_depth_m) {
                    continue;
                }
                n_points += 1;
                if p.num_observations() <= redundant {
                    continue;
                }
                let level = f.keypoints[i].octave;
                let coarsest = level.saturating_add(ctx.config.mapping.redundant_level_margin);
                let n_finer = p
                    .observations()
                    .iter()
                    .filter(|(k2, _)| **k2 != candidate)
                    .filter(|(k2, i2)| {
                        map.keyframe(**k2)
                            .is_some_and(|k2| k2.features().keypoints[**i2].octave <= coarsest)
                    })
                    .take(redundant)
                    .count();
                if n_finer >= redundant {
                    n_redundant += 1;
                }
            }
            if n_points > 0
                && n_redundant as f64 > share * n_points as f64
                && map.set_keyframe_bad(candidate)
            {
                culled += 1;
            }
        }
        culled
    }
}

/// One camera of one keyframe and one of another (or the same) keyframe, whose unmatched
/// keypoints are searched along epipolar lines and triangulated.
struct CameraPair {
    kf1: KeyFrameId,
    kf2: KeyFrameId,
    cameras: [usize; 2],
}

impl CameraPair {
    /// New points `(p_w, keypoint of kf1, keypoint of kf2)`; `None` when the pair is not
    /// searched: a baseline too short for its depth (or the stereo baseline), or two cameras
    /// of the rig facing apart.
    fn triangulate(
        &self,
        map: &Map,
        ctx: &Context,
        median_depth: Option<f64>,
        ratio_factor: f64,
    ) -> Option<Vec<(Vector3<f64>, usize, usize)>> {
        let (k1, k2) = (map.keyframe(self.kf1)?, map.keyframe(self.kf2)?);
        let views = [
            View::new(map, self.kf1, ctx, self.cameras[0]),
            View::new(map, self.kf2, ctx, self.cameras[1]),
        ];
        let (T_c1_w, T_c2_w) = (views[0].T_c_w, views[1].T_c_w);
        let (o1, o2) = (views[0].center, views[1].center);
        if self.cameras[0] != self.cameras[1] {
            // Optical axes more than 90 degrees apart: no shared view to search.
            let axis = |v: &View<'_>| v.T_w_c.rotation * Vector3::z();
            if axis(&views[0]).dot(&axis(&views[1])) <= 0.0 {
                return None;
            }
        }
        let config = &ctx.config.mapping;
        let baseline = (o2 - o1).norm();
        let too_short = if ctx.config.sensor.has_depth() {
            baseline < ctx.baseline_m
        } else {
            median_depth.is_none_or(|d| baseline / d < config.min_baseline_depth_ratio())
        };
        if too_short {
            return None;
        }
        let pyramid = map.pyramid();
        let epipole2 = views[1]
            .camera
            .project(&(T_c2_w * Point3::from(o1)).coords)
            .map(|e| (e.x, e.y));
        let (r1, r2) = (views[0].range.clone(), views[1].range.clone());
        let (f1, f2) = (k1.features(), k2.features());
        let free = |k: &ferroslam_map::KeyFrame, r: std::ops::Range<usize>| -> Vec<bool> {
            k.map_points()[r].iter().map(Option::is_none).collect()
        };
        let (free1, free2) = (free(k1, r1.clone()), free(k2, r2.clone()));
        let opts = MatchOptions {
            max_distance: TH_LOW,
            nn_ratio: None,
            check_orientation: true,
        };
        let (kps1, kps2) = (&f1.keypoints[r1.clone()], &f2.keypoints[r2.clone()]);
        let (desc1, desc2) = (&f1.descriptors[r1.clone()], &f2.descriptors[r2.clone()]);
        let pinholes = (views[0].camera.as_pinhole(), views[1].camera.as_pinhole());
        let pairs = if let (Some(c1), Some(c2)) = pinholes {
            let f21 = fundamental_matrix(&T_c1_w, &T_c2_w, c1, c2);
            search_for_triangulation(
                kps1,
                desc1,
                &free1,
                kps2,
                desc2,
                &free2,
                &f21,
                &pyramid.sigma2,
                epipole2,
                &opts,
            )
        } else {
            let rays = |camera: usize, kps: &[Keypoint]| -> Vec<Vector3<f64>> {
                let view = ctx.view(camera);
                kps.iter().map(|k| view.ray(k.x, k.y)).collect()
            };
            search_for_triangulation_rays(
                (kps1, desc1, &free1, &rays(self.cameras[0], kps1)),
                (kps2, desc2, &free2, &rays(self.cameras[1], kps2)),
                &essential_matrix(&T_c1_w, &T_c2_w),
                &pyramid.sigma2,
                1.0 / views[1].camera.fx(),
                epipole2,
                &opts,
            )
        };
        let mut new_points = Vec::new();
        for (l1, l2) in pairs {
            let (i1, i2) = (r1.start + l1, r2.start + l2);
            let Some(p_w) = triangulate_pair(&views, [i1, i2], ctx) else {
                continue;
            };
            let ok = views
                .iter()
                .zip([i1, i2])
                .all(|(v, i)| v.reprojection_ok(&p_w, i, &pyramid.sigma2));
            if !ok {
                continue;
            }
            let (d1, d2) = ((p_w - o1).norm(), (p_w - o2).norm());
            if d1 == 0.0 || d2 == 0.0 {
                continue;
            }
            let ratio_dist = d2 / d1;
            let ratio_octave =
                pyramid.scale[views[0].octave(i1)] / pyramid.scale[views[1].octave(i2)];
            if ratio_dist * ratio_factor < ratio_octave || ratio_dist > ratio_octave * ratio_factor
            {
                continue;
            }
            new_points.push((p_w, i1, i2));
        }
        Some(new_points)
    }
}

/// Fundamental matrix `F21` with `x2^T F21 x1 = 0` for undistorted pixels of pinhole
/// cameras `c1` (at `T_c1_w`) and `c2` (at `T_c2_w`).
fn fundamental_matrix(
    T_c1_w: &Isometry3<f64>,
    T_c2_w: &Isometry3<f64>,
    c1: &PinholeCamera,
    c2: &PinholeCamera,
) -> Matrix3<f64> {
    let e21 = essential_matrix(T_c1_w, T_c2_w);
    let k_inv = |c: &PinholeCamera| {
        Matrix3::new(
            1.0 / c.fx,
            0.0,
            -c.cx / c.fx,
            0.0,
            1.0 / c.fy,
            -c.cy / c.fy,
            0.0,
            0.0,
            1.0,
        )
    };
    k_inv(c2).transpose() * e21 * k_inv(c1)
}

/// One camera of one keyframe's view of a feature, for triangulation checks.
struct View<'a> {
    T_c_w: Isometry3<f64>,
    T_w_c: Isometry3<f64>,
    /// The keyframe's first camera pose, to which depth points are referred.
    T_w_c0: Isometry3<f64>,
    /// Camera centre in the world frame, metres.
    center: Vector3<f64>,
    features: &'a ferroslam_map::FrameFeatures,
    /// This camera's keypoints in `features`.
    range: std::ops::Range<usize>,
    camera: &'a CameraModel,
    ctx: &'a Context,
}

impl<'a> View<'a> {
    fn new(map: &'a Map, kf: KeyFrameId, ctx: &'a Context, camera: usize) -> Self {
        let k = map.keyframe(kf).expect("view of a live keyframe");
        let view = ctx.view(camera);
        let T_c_w = view.pose(k.T_c_w());
        let features = k.features();
        Self {
            T_c_w,
            T_w_c: if camera == 0 {
                k.T_w_c()
            } else {
                T_c_w.inverse()
            },
            T_w_c0: k.T_w_c(),
            center: view.center(k.T_c_w()),
            features,
            range: features.camera_range(camera),
            camera: view.camera,
            ctx,
        }
    }

    fn octave(&self, i: usize) -> usize {
        self.features.keypoints[i].octave as usize
    }

    fn pixel(&self, i: usize) -> Vector2<f64> {
        let kp = &self.features.keypoints[i];
        Vector2::new(kp.x as f64, kp.y as f64)
    }

    /// ORB-SLAM's chi2 test (5.991 for (u, v), 7.8 with the right coordinate), positive depth.
    fn reprojection_ok(&self, p_w: &Vector3<f64>, i: usize, sigma2: &[f64]) -> bool {
        let p_c = self.T_c_w * Point3::from(*p_w);
        let Some(uv) = self.camera.project(&p_c.coords) else {
            return false;
        };
        let e = uv - self.pixel(i);
        let s2 = sigma2[self.octave(i)];
        let ur = self.features.u_right[i] as f64;
        if ur >= 0.0 {
            let view = self.ctx.view(self.features.camera_of(i));
            let er = view.u_right(&p_c.coords, uv.x) - ur;
            e.norm_squared() + er * er <= CHI2_STEREO * s2
        } else {
            e.norm_squared() <= CHI2_MONO * s2
        }
    }
}

/// The world point of a matched pair, trusting measured depth only where it is precise.
///
/// A feature with close depth (below `close_depth_m`) in either view is mapped from that depth
/// (the closer view wins). Far depth is unreliable from one view (the ORB-SLAM2 paper's
/// close/far rule), so far and depthless features are triangulated from the two rays, and only
/// with enough parallax; the reprojection check that follows
/// still holds a triangulated point to any disparity measured for it. See
/// `mapping.min_ray_parallax_deg` of the configuration.
///
/// ORB-SLAM2's code also back-projects far depth here and ray-triangulates from 1.15 deg of
/// parallax; on KITTI stereo that inflated the path (the metric scale drifted), and TUM
/// RGB-D gained nothing from it.
fn triangulate_pair(views: &[View<'_>; 2], idx: [usize; 2], ctx: &Context) -> Option<Vector3<f64>> {
    let depth = [0, 1].map(|k| views[k].features.depth[idx[k]] as f64);
    let closest = (0..2)
        .filter(|&k| depth[k] > 0.0 && depth[k] < ctx.close_depth_m)
        .min_by(|&a, &b| depth[a].total_cmp(&depth[b]));
    if let Some(k) = closest {
        return unproject_depth(views[k].features, idx[k], ctx, &views[k].T_w_c0);
    }
    // (x, y, 1) rays for the pinhole (ORB-SLAM's arithmetic), unit rays otherwise.
    let xn = [0, 1].map(|k| {
        let (camera, uv) = (views[k].camera, views[k].pixel(idx[k]));
        camera
            .as_pinhole()
            .map_or_else(|| camera.unproject(&uv), |c| Some(c.unproject(&uv)))
    });
    let [Some(x1), Some(x2)] = xn else {
        return None;
    };
    let rays = [(0, x1), (1, x2)].map(|(k, x)| views[k].T_w_c.rotation * x);
    let cos_rays = rays[0].dot(&rays[1]) / (rays[0].norm() * rays[1].norm());
    if cos_rays > ctx.config.mapping.min_ray_parallax_deg.to_radians().cos() {
        return None;
    }
    let pinholes = views[0].camera.as_pinhole().is_some() && views[1].camera.as_pinhole().is_some();
    if pinholes {
        triangulate_dlt(&views[0].T_c_w, &views[1].T_c_w, &x1, &x2)
    } else {
        triangulate_rays(&views[0].T_c_w, &views[1].T_c_w, &x1, &x2)
    }
}

#[cfg(test)]
mod tests {
    use ferroslam_features::{Descriptor, Keypoint, ScalePyramid};
    use ferroslam_geometry::camera::{PinholeCamera, RadTan};
    use ferroslam_map::FrameFeatures;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::config::{Sensor, SlamConfig};

    /// [`scene_sharing`] with 50 points shared with each of `n_others` other keyframes.
    fn scene(n_others: usize, sensor: Sensor) -> (Context, Map, KeyFrameId) {
        scene_sharing(&vec![50; n_others], sensor)
    }

    /// [`scene_spaced`] with keyframes 0.2 m apart.
    fn scene_sharing(shared: &[usize], sensor: Sensor) -> (Context, Map, KeyFrameId) {
        scene_spaced(shared, sensor, 0.2)
    }

    /// Keyframes `others` (`shared.len()` of them, `spacing_m` apart along x), `best`
    /// `spacing_m` further and `newest` as far further still, looking along z at points 3-6 m
    /// away (median about 4.5 m), each
    /// point with its own random descriptor. 60 points are mapped in every keyframe and 20
    /// more in `best` and `newest`, so `best` is the newest's best covisible; 50 unmapped
    /// points are seen by `newest` and `best`, and `shared[j]` more by `newest` and other
    /// keyframe `j`. With a depth `sensor`, every feature has its depth (all close). Returns
    /// the context, the map and `newest`.
    fn scene_spaced(
        shared: &[usize],
        sensor: Sensor,
        spacing_m: f64,
    ) -> (Context, Map, KeyFrameId) {
        let n_others = shared.len();
        let camera =
            PinholeCamera::new(500.0, 500.0, 320.0, 240.0, RadTan::default(), 640, 480).unwrap();
        let mut config = SlamConfig::for_sensor(sensor);
        config.depth.depth_threshold = 100.0;
        let ctx = Context::new(camera, config);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut point = || {
            let z = rng.random_range(3.0..6.0);
            let p = Vector3::new(
                rng.random_range(-0.4..0.4) * z,
                rng.random_range(-0.3..0.3) * z,
                z,
            );
            let descriptor: Descriptor = std::array::from_fn(|_| rng.random());
            (p, descriptor)
        };
        let all: Vec<_> = (0..60).map(|_| point()).collect();
        let pair: Vec<_> = (0..20).map(|_| point()).collect();
        let with_best: Vec<_> = (0..50).map(|_| point()).collect();
        let with_others: Vec<Vec<_>> = shared
            .iter()
            .map(|&n| (0..n).map(|_| point()).collect())
            .collect();
        // (centre x in metres, points seen)
        let mut views: Vec<(f64, Vec<_>)> = with_others
            .iter()
            .enumerate()
            .map(|(j, with)| (spacing_m * j as f64, [&all[..], &with[..]].concat()))
            .collect();
        let x_best = spacing_m * n_others as f64;
        views.push((x_best, [&all[..], &pair[..], &with_best[..]].concat()));
        let newest_sees = [&all[..], &pair[..], &with_best[..]]
            .into_iter()
            .chain(with_others.iter().map(Vec::as_slice));
        views.push((x_best + spacing_m, newest_sees.collect::<Vec<_>>().concat()));
        let mut map = Map::new(ScalePyramid::new(1.2, 8).unwrap());
        let mut keyframes = Vec::new();
        for (n, (x, seen)) in views.iter().enumerate() {
            let T_c_w = Isometry3::translation(-x, 0.0, 0.0);
            let (mut keypoints, mut depth, mut u_right) = (Vec::new(), Vec::new(), Vec::new());
            for (p, _) in seen {
                let p_c = T_c_w * Point3::from(*p);
                let uv = ctx.camera.project(&p_c.coords).unwrap();
                keypoints.push(Keypoint {
                    x: uv.x as f32,
                    y: uv.y as f32,
                    octave: 0,
                    angle_deg: 0.0,
                    response: 1.0,
                });
                if sensor.has_depth() {
                    depth.push(p_c.z as f32);
                    u_right.push((uv.x - ctx.intrinsics.bf / p_c.z) as f32);
                }
            }
            let descriptors = seen.iter().map(|(_, d)| *d).collect();
            let features =
                FrameFeatures::new(keypoints, descriptors, depth, u_right, ctx.bounds).unwrap();
            keyframes.push(map.insert_keyframe(n as f64, n, T_c_w, features));
        }
        // Map points: `all` in every view at the same index; `pair` at 60.. in the last two.
        for (i, (p, _)) in all.iter().chain(&pair).enumerate() {
            let seen_by = if i < 60 {
                &keyframes[..]
            } else {
                &keyframes[n_others..]
            };
            let m = map.create_map_point(*p, seen_by[0]).unwrap();
            for &kf in seen_by {
                map.add_observation(m, kf, i).unwrap();
            }
            map.compute_distinctive_descriptor(m).unwrap();
            map.update_normal_and_depth(m).unwrap();
        }
        for &kf in &keyframes {
            map.update_connections(kf).unwrap();
        }
        let newest = keyframes[n_others + 1];
        assert_eq!(map.best_covisibles(newest, 1), vec![keyframes[n_others]]);
        (ctx, map, newest)
    }

    /// Maps the newest keyframe of a scene ([`scene_spaced`]) and checks the map stays
    /// consistent.
    fn map_newest(
        (ctx, mut map, newest): (Context, Map, KeyFrameId),
        interrupt: Interrupt<'_>,
    ) -> MappingReport {
        let mut report = MappingReport::default();
        let mut mapper = LocalMapper::default();
        mapper
            .grow(newest, &mut map, &ctx, &mut report, interrupt, &mut |_| {})
            .unwrap();
        if !report.interrupted {
            mapper
                .refine(newest, &mut map, &ctx, &mut report, None)
                .unwrap();
        }
        map.check_consistency().unwrap();
        report
    }

    #[test]
    fn interrupted_mapping_triangulates_with_the_best_neighbour_only_and_skips_the_rest() {
        let full = map_newest(scene(1, Sensor::Monocular), Interrupt::NEVER);
        assert_eq!(full.triangulated_points, 100);
        assert!(!full.interrupted && full.local_ba_ms > 0.0);
        let waiting = AtomicBool::new(true);
        let waited_for = map_newest(scene(1, Sensor::Monocular), Interrupt::on(&waiting, false));
        assert_eq!(waited_for.triangulated_points, 50);
        assert!(waited_for.interrupted);
        assert_eq!((waited_for.local_ba_ms, waited_for.fused_points), (0.0, 0));
    }

    /// The points triangulated with each neighbour are handed on as soon as they exist (the
    /// mapping thread sends them ahead to tracking), each hand-over with its own edits.
    #[test]
    fn grow_hands_on_each_neighbours_points_as_they_are_made() {
        let (ctx, mut map, newest) = scene(1, Sensor::Monocular);
        let before = map.num_map_points();
        map.begin_journal();
        let mut handed = Vec::new();
        let mut report = MappingReport::default();
        LocalMapper::default()
            .grow(
                newest,
                &mut map,
                &ctx,
                &mut report,
                Interrupt::NEVER,
                &mut |map| handed.push((map.num_map_points() - before, map.drain_journal().len())),
            )
            .unwrap();
        let created: Vec<usize> = handed.iter().map(|h| h.0).collect();
        assert_eq!(created, vec![50, 100]);
        // A point's creation and its two observations at least, per point.
        assert!(handed.iter().all(|h| h.1 >= 3 * 50), "{handed:?}");
    }

    /// Hurried, a keyframe with depth triangulates with its best 3 neighbours only, but its
    /// mapping goes on (fusion, local BA); a monocular one still searches them all. A
    /// keyframe waited for stops after the best.
    #[test]
    fn hurried_mapping_with_depth_triangulates_with_the_best_neighbours_only() {
        let n_others = 4;
        let run = |sensor, interrupt| map_newest(scene(n_others, sensor), interrupt);
        let (not_waiting, waiting) = (AtomicBool::new(false), AtomicBool::new(true));
        let every_neighbour = 50 * (n_others + 1);
        for sensor in [Sensor::Rgbd, Sensor::Monocular] {
            let full = run(sensor, Interrupt::on(&not_waiting, false));
            assert_eq!(full.triangulated_points, every_neighbour, "{sensor:?}");
        }
        let hurried = run(Sensor::Rgbd, Interrupt::on(&not_waiting, true));
        assert_eq!(hurried.triangulated_points, 50 * 3);
        assert!(!hurried.interrupted && hurried.local_ba_ms > 0.0);
        let mono = run(Sensor::Monocular, Interrupt::on(&not_waiting, true));
        assert_eq!(mono.triangulated_points, every_neighbour);
        let waited_for = run(Sensor::Rgbd, Interrupt::on(&waiting, true));
        assert_eq!(waited_for.triangulated_points, 50);
        assert!(waited_for.interrupted);
    }

    /// With depth, the search for new points goes past the best two neighbours only while
    /// each brings enough; a monocular keyframe searches them all. The other keyframes tie in
    /// covisibility and come in the order they were made, after `best`.
    #[test]
    fn with_depth_the_search_stops_at_a_neighbour_that_brings_few_points() {
        let shared = [50, 3, 50, 50];
        let all: usize = 50 + shared.iter().sum::<usize>();
        for (sensor, expected) in [(Sensor::Rgbd, 50 + 50 + 3), (Sensor::Monocular, all)] {
            let report = map_newest(scene_sharing(&shared, sensor), Interrupt::NEVER);
            assert_eq!(report.triangulated_points, expected, "{sensor:?}");
        }
    }

    /// Monocular, a keyframe pair triangulates only from the baseline that gives a point at
    /// the scene's median depth the least parallax: 7 cm against about 4.5 m (1.6 %) makes
    /// nothing, though its closest points (under 3.5 m) would pass the parallax check and
    /// ORB-SLAM's 1 %.
    #[test]
    fn monocular_pairs_under_the_median_depths_parallax_baseline_triangulate_nothing() {
        for (spacing_m, expected) in [(0.07, 0), (0.2, 50)] {
            let scene = scene_spaced(&[], Sensor::Monocular, spacing_m);
            let report = map_newest(scene, Interrupt::NEVER);
            assert_eq!(report.triangulated_points, expected, "{spacing_m} m");
        }
    }
}
