//! Sim(3) pose-graph optimisation over the essential graph (ORB-SLAM
//! `Optimizer::OptimizeEssentialGraph`): every keyframe is a vertex; edges are the spanning
//! tree, the loop edges (old and new) and the covisibility edges of at least
//! `loop_closing.strong_covisibility` shared points ([`LoopClosingConfig`]). Measurements are the relative poses before the loop
//! correction (the new loop links: after it), so the graph spreads the loop's error over
//! the trajectory. Map points then follow their reference keyframe.

use std::collections::{BTreeSet, HashMap};

use ferroslam_geometry::sim3::Sim3;
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use ferroslam_optim::{
    optimize_pose_graph, PoseEdge, PoseGraphOptions, Sim3PoseGraph, SymbolicPoseGraph,
};
use nalgebra::{SMatrix, Vector3};

use super::verification::pose_of;
use crate::config::LoopClosingConfig;
use crate::error::SlamError;

/// What the correction step hands to the optimisation.
pub(super) struct EssentialGraphInput<'a> {
    /// The keyframe that detected the loop.
    pub current: KeyFrameId,
    /// The matched keyframe; held fixed.
    pub loop_kf: KeyFrameId,
    /// `S_iw` before correction of the corrected keyframes.
    pub before: &'a HashMap<KeyFrameId, Sim3>,
    /// `S_iw` after correction (with scale) of the corrected keyframes.
    pub corrected: &'a HashMap<KeyFrameId, Sim3>,
    /// New covisibility links created by the fusion, per corrected keyframe.
    pub loop_links: &'a [(KeyFrameId, Vec<KeyFrameId>)],
    /// Points moved by the correction, with the keyframe that moved them.
    pub corrected_points: &'a HashMap<MapPointId, KeyFrameId>,
}

/// Optimises every keyframe pose and moves every map point; returns the graph's cost before
/// and after. `config` gives the strong-covisibility weight and the iterations.
pub(super) fn optimize_essential_graph(
    map: &mut Map,
    input: &EssentialGraphInput<'_>,
    config: &LoopClosingConfig,
) -> Result<(f64, f64), SlamError> {
    let strong = config.strong_covisibility;
    let ids = map.keyframe_ids();
    let index: HashMap<KeyFrameId, usize> = ids.iter().enumerate().map(|(i, k)| (*k, i)).collect();
    let rigid = |k: KeyFrameId| Sim3::from_isometry(map.keyframe(k).expect("keyframe").T_c_w());
    // Initial S_iw (corrected ones keep their scale) and the measurement poses.
    let initial: Vec<Sim3> = ids
        .iter()
        .map(|k| input.corrected.get(k).copied().unwrap_or_else(|| rigid(*k)))
        .collect();
    let measured: Vec<Sim3> = ids
        .iter()
        .map(|k| input.before.get(k).copied().unwrap_or_else(|| rigid(*k)))
        .collect();
    let mut graph = Sim3PoseGraph {
        poses: initial.iter().map(Sim3::inverse).collect(),
        fixed: ids.iter().map(|k| *k == input.loop_kf).collect(),
        edges: Vec::new(),
    };
    let mut added: BTreeSet<(usize, usize)> = BTreeSet::new();
    let mut add = |graph: &mut Sim3PoseGraph, i: usize, j: usize, S_iw: &Sim3, S_jw: &Sim3| {
        if i != j && added.insert((i.min(j), i.max(j))) {
            graph.edges.push(PoseEdge {
                from: i,
                to: j,
                measurement: *S_iw * S_jw.inverse(),
                information: SMatrix::<f64, 7, 7>::identity(),
            });
        }
    };
    for (k, links) in input.loop_links {
        let i = index[k];
        for n in links {
            let Some(&j) = index.get(n) else { continue };
            let weight = map.keyframe(*k).map_or(0, |kf| kf.weight(*n));
            let is_loop_pair = *k == input.current && *n == input.loop_kf;
            if weight < strong && !is_loop_pair {
                continue;
            }
            add(&mut graph, i, j, &initial[i], &initial[j]);
        }
    }
    for (i, &k) in ids.iter().enumerate() {
        let kf = map.keyframe(k).expect("keyframe");
        let neighbours = kf
            .parent()
            .into_iter()
            .chain(kf.loop_edges().iter().copied())
            .chain(kf.covisibles_with_min_weight(strong));
        for n in neighbours {
            if let Some(&j) = index.get(&n) {
                add(&mut graph, i, j, &measured[i], &measured[j]);
            }
        }
    }
    let symbolic = SymbolicPoseGraph::new(&graph)?;
    let options = PoseGraphOptions {
        max_iterations: config.essential_graph_iterations,
        ..PoseGraphOptions::default()
    };
    let report = optimize_pose_graph(&mut graph, &symbolic, &options)?;

    let optimised: Vec<Sim3> = graph.poses.iter().map(Sim3::inverse).collect();
    for (i, &k) in ids.iter().enumerate() {
        map.set_keyframe_pose(k, pose_of(&optimised[i]))?;
    }
    for m in map.map_point_ids() {
        let Some(p) = map.map_point(m) else { continue };
        let reference = input
            .corrected_points
            .get(&m)
            .copied()
            .unwrap_or_else(|| p.reference_keyframe());
        let Some(&r) = index.get(&reference) else {
            continue;
        };
        let p_w = move_point(&p.position(), &initial[r], &optimised[r]);
        map.set_map_point_position(m, p_w)?;
        map.update_normal_and_depth(m)?;
    }
    Ok((report.initial_cost, report.final_cost))
}

/// A world point seen by a keyframe whose pose changes from `S_old` to `S_new` (both
/// world to camera), moved so its camera coordinates do not change: `S_new^-1 * S_old * p`.
pub(super) fn move_point(p: &Vector3<f64>, S_old: &Sim3, S_new: &Sim3) -> Vector3<f64> {
    S_new.inverse().transform_point(&S_old.transform_point(p))
}
