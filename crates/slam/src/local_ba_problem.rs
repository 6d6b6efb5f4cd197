//! The map-to-bundle-adjustment adapter: which keyframes, points and observations of the
//! map a local (or global) BA problem holds, and writing the solution back (ORB-SLAM
//! `Optimizer::LocalBundleAdjustment` around the solver of `ferroslam_optim`).
//!
//! Rolling shutter: a keyframe observation is projected from the pose of its row,
//! `D(dt) * T_c_w` ([`readout_motion`]), with the keyframe's velocity as tracking estimated it,
//! held fixed. Why not a variable: over one readout the velocity moves a row by at most half
//! a readout times the rate (a few pixels), which the frame's own reprojections already
//! pinned down against the motion-model prior in tracking; in local BA the same
//! observations would only constrain it again, while adding 6 unknowns per keyframe that no
//! other factor ties to its neighbours' poses (no IMU), a gauge-like freedom the Schur
//! solver would need a prior for anyway. Fixed, the problem keeps its structure and its
//! global-shutter arithmetic (`readout_motion` is `None` there).

use std::collections::{HashMap, HashSet};

use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_optim::{local_bundle_adjust, BaProblem, Observation};
use nalgebra::Vector2;

use crate::context::Context;
use crate::error::SlamError;
use crate::frame::readout_motion;

/// Bundle adjustment of the keyframes `local` (the map's origin stays fixed) and every point
/// they see, with the other keyframes observing those points held fixed; ORB-SLAM's robust
/// then plain schedule. Rejected observations are erased from the map; returns their number.
/// Local BA passes a keyframe and its covisible keyframes, global BA every keyframe. The
/// problem, before solving, is pushed to `record` if given.
pub(crate) fn adjust_keyframes(
    local: &[KeyFrameId],
    map: &mut Map,
    ctx: &Context,
    record: Option<&mut Vec<BaProblem>>,
) -> Result<usize, SlamError> {
    let (mut problem, index) = LocalProblem::build(local, &[], map, ctx);
    if let Some(record) = record {
        record.push(problem.clone());
    }
    let Ok(result) = local_bundle_adjust(&mut problem) else {
        // A numerically failed BA leaves the map as it was; the next keyframe retries.
        return Ok(0);
    };
    index.apply(&problem, &result.outlier, map)
}

/// Local BA over `kf` and its covisible keyframes (see [`adjust_keyframes`]).
pub(crate) fn adjust_around(
    kf: KeyFrameId,
    map: &mut Map,
    ctx: &Context,
    record: Option<&mut Vec<BaProblem>>,
) -> Result<usize, SlamError> {
    let mut local: Vec<KeyFrameId> = vec![kf];
    local.extend(map.covisibles(kf).into_iter().map(|(k, _)| k));
    adjust_keyframes(&local, map, ctx, record)
}

/// Which keyframes, points and observations of the map a local BA problem holds.
pub(crate) struct LocalProblem {
    /// Keyframe of each pose of the problem.
    pub pose_ids: Vec<KeyFrameId>,
    points: Vec<MapPointId>,
    /// `(point, keyframe)` of each observation.
    obs_keys: Vec<(MapPointId, KeyFrameId)>,
    /// `mapping.max_scene_depth_ratio` of the configuration.
    max_scene_depth_ratio: f64,
}

impl LocalProblem {
    /// The BA problem over the keyframes `local` (free, except the map's origin), every
    /// point they see, the other keyframes observing those points and `also_fixed` (fixed).
    pub(crate) fn build(
        local: &[KeyFrameId],
        also_fixed: &[KeyFrameId],
        map: &Map,
        ctx: &Context,
    ) -> (BaProblem, Self) {
        let local_set: HashSet<KeyFrameId> = local.iter().copied().collect();
        let points = map.points_seen_by(local.iter().copied());
        let mut fixed = Vec::new();
        let mut fixed_set = HashSet::new();
        let observers = points
            .iter()
            .flat_map(|&m| map.map_point(m).unwrap().observations().keys().copied());
        for k in also_fixed.iter().copied().chain(observers) {
            if !local_set.contains(&k) && map.keyframe(k).is_some() && fixed_set.insert(k) {
                fixed.push(k);
            }
        }
        let pose_ids: Vec<KeyFrameId> = local.iter().chain(fixed.iter()).copied().collect();
        let pose_index: HashMap<KeyFrameId, usize> =
            pose_ids.iter().enumerate().map(|(i, k)| (*k, i)).collect();
        let pyramid = map.pyramid();
        let mut observations = Vec::new();
        let mut obs_keys = Vec::new();
        for (pi, &m) in points.iter().enumerate() {
            for (&k, &i) in map.map_point(m).unwrap().observations() {
                let Some(&pose) = pose_index.get(&k) else {
                    continue;
                };
                let f = map.keyframe(k).unwrap().features();
                let kp = &f.keypoints[i];
                let ur = f.u_right[i];
                observations.push(Observation {
                    pose,
                    point: pi,
                    uv: Vector2::new(kp.x as f64, kp.y as f64),
                    u_right: (ur >= 0.0).then_some(ur as f64),
                    inv_sigma2: pyramid.inv_sigma2[kp.octave as usize],
                    readout_motion: readout_motion(f, i),
                    camera: f.camera_of(i),
                });
                obs_keys.push((m, k));
            }
        }
        // The map's first keyframe fixes the gauge.
        let origin = map.origin();
        let problem = BaProblem {
            cameras: ctx.optim_cameras.clone(),
            poses: pose_ids
                .iter()
                .map(|k| *map.keyframe(*k).unwrap().T_c_w())
                .collect(),
            pose_fixed: pose_ids
                .iter()
                .map(|k| !local_set.contains(k) || Some(*k) == origin)
                .collect(),
            points: points
                .iter()
                .map(|m| map.map_point(*m).unwrap().position())
                .collect(),
            observations,
        };
        let index = Self {
            pose_ids,
            points,
            obs_keys,
            max_scene_depth_ratio: ctx.config.mapping.max_scene_depth_ratio,
        };
        (problem, index)
    }

    /// Writes the solved `problem` back: free poses, points, and the erasure of the
    /// observations flagged in `outlier`; returns how many were erased.
    pub(crate) fn apply(
        &self,
        problem: &BaProblem,
        outlier: &[bool],
        map: &mut Map,
    ) -> Result<usize, SlamError> {
        for (pi, &k) in self.pose_ids.iter().enumerate() {
            if !problem.pose_fixed[pi] {
                map.set_keyframe_pose(k, problem.poses[pi])?;
            }
        }
        for (pi, &m) in self.points.iter().enumerate() {
            map.set_map_point_position(m, problem.points[pi])?;
        }
        let mut n_outliers = 0;
        for (o, &(m, k)) in self.obs_keys.iter().enumerate() {
            if outlier[o] && map.map_point(m).is_some() {
                map.erase_observation(m, k);
                n_outliers += 1;
            }
        }
        self.drop_points_beyond_the_scene(map);
        for &m in &self.points {
            if map.map_point(m).is_some() {
                map.update_normal_and_depth(m)?;
            }
        }
        Ok(n_outliers)
    }

    /// Marks bad the points bundle adjustment left farther from their reference keyframe
    /// than `mapping.max_scene_depth_ratio` times that keyframe's scene median depth (BA
    /// slides points seen along nearly parallel rays out of the scene).
    fn drop_points_beyond_the_scene(&self, map: &mut Map) {
        let mut medians: HashMap<KeyFrameId, Option<f64>> = HashMap::new();
        for &m in &self.points {
            let Some(p) = map.map_point(m) else { continue };
            let (reference, position) = (p.reference_keyframe(), p.position());
            let Some(centre) = map.keyframe(reference).map(|k| k.camera_center()) else {
                continue;
            };
            let median = *medians
                .entry(reference)
                .or_insert_with(|| map.scene_median_depth(reference));
            let too_far = |d: f64| (position - centre).norm() > self.max_scene_depth_ratio * d;
            if median.is_some_and(too_far) {
                map.set_map_point_bad(m);
            }
        }
    }
}
