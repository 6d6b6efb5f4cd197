//! Keyframes: a frame's features and pose, its map-point slots and its graph links.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};

use crate::{FrameFeatures, KeyFrameId, MapPointId};

/// A keyframe of the map (ORB-SLAM `KeyFrame`).
///
/// Read-only outside the crate: poses and links change only through [`crate::Map`], which
/// keeps them consistent. A `&KeyFrame` obtained from the map is always good (bad keyframes
/// are removed from the arena).
#[derive(Clone, Debug)]
#[allow(non_snake_case)]
pub struct KeyFrame {
    pub(crate) id: KeyFrameId,
    pub(crate) timestamp: f64,
    pub(crate) frame_index: usize,
    pub(crate) T_c_w: Isometry3<f64>,
    /// Shared, never edited: cloning a map (for the mapping thread) does not copy it.
    pub(crate) features: Arc<FrameFeatures>,
    /// Slot `i` holds the map point keypoint `i` observes.
    pub(crate) map_points: Vec<Option<MapPointId>>,
    /// Covisibility edges: neighbour -> number of good points both observe (symmetric).
    pub(crate) covisibility: BTreeMap<KeyFrameId, usize>,
    /// The neighbours this keyframe's last `update_connections` selected; an edge exists while
    /// either endpoint selects it (or until its weight drops to zero).
    pub(crate) chosen: BTreeSet<KeyFrameId>,
    pub(crate) parent: Option<KeyFrameId>,
    pub(crate) children: BTreeSet<KeyFrameId>,
    /// Keyframes this one closed a loop with (symmetric); such keyframes are never culled.
    pub(crate) loop_edges: BTreeSet<KeyFrameId>,
}

#[allow(non_snake_case)]
impl KeyFrame {
    pub(crate) fn new(
        id: KeyFrameId,
        timestamp: f64,
        frame_index: usize,
        T_c_w: Isometry3<f64>,
        features: FrameFeatures,
    ) -> Self {
        Self {
            id,
            timestamp,
            frame_index,
            T_c_w,
            map_points: vec![None; features.len()],
            features: Arc::new(features),
            covisibility: BTreeMap::new(),
            chosen: BTreeSet::new(),
            parent: None,
            children: BTreeSet::new(),
            loop_edges: BTreeSet::new(),
        }
    }

    /// The keyframe's id.
    pub fn id(&self) -> KeyFrameId {
        self.id
    }

    /// Timestamp of the source frame (s).
    pub fn timestamp(&self) -> f64 {
        self.timestamp
    }

    /// Index of the source frame in the input sequence.
    pub fn frame_index(&self) -> usize {
        self.frame_index
    }

    /// World-to-camera pose: `p_c = T_c_w * p_w`.
    pub fn T_c_w(&self) -> &Isometry3<f64> {
        &self.T_c_w
    }

    /// Camera-to-world pose (the camera's pose in the world).
    pub fn T_w_c(&self) -> Isometry3<f64> {
        self.T_c_w.inverse()
    }

    /// Camera centre in world coordinates (m).
    pub fn camera_center(&self) -> Vector3<f64> {
        self.T_c_w
            .inverse_transform_point(&nalgebra::Point3::origin())
            .coords
    }

    /// The keyframe's features.
    pub fn features(&self) -> &FrameFeatures {
        &self.features
    }

    /// The map point observed by keypoint `i`; `None` if none or `i` out of range.
    pub fn map_point(&self, i: usize) -> Option<MapPointId> {
        self.map_points.get(i).copied().flatten()
    }

    /// Map-point slots, one per keypoint.
    pub fn map_points(&self) -> &[Option<MapPointId>] {
        &self.map_points
    }

    /// Parent in the spanning tree; `None` for the root and before the first connection.
    pub fn parent(&self) -> Option<KeyFrameId> {
        self.parent
    }

    /// Children in the spanning tree.
    pub fn children(&self) -> &BTreeSet<KeyFrameId> {
        &self.children
    }

    /// Keyframes this one closed a loop with (ORB-SLAM `GetLoopEdges`).
    pub fn loop_edges(&self) -> &BTreeSet<KeyFrameId> {
        &self.loop_edges
    }

    /// Always `false`: bad keyframes are removed from the map, so a reference obtained from
    /// it is good. For an id, use [`crate::Map::is_keyframe_bad`].
    pub fn is_bad(&self) -> bool {
        false
    }

    /// Covisibility weight with `other` (shared good points); 0 if not connected.
    pub fn weight(&self, other: KeyFrameId) -> usize {
        self.covisibility.get(&other).copied().unwrap_or(0)
    }

    /// Connected keyframes with their weights, by decreasing weight (ties: increasing id) —
    /// ORB-SLAM `GetVectorCovisibleKeyFrames` with weights.
    pub fn covisibles(&self) -> Vec<(KeyFrameId, usize)> {
        let mut out: Vec<_> = self.covisibility.iter().map(|(&k, &w)| (k, w)).collect();
        out.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        out
    }

    /// The `n` most covisible keyframes (ORB-SLAM `GetBestCovisibilityKeyFrames`).
    pub fn best_covisibles(&self, n: usize) -> Vec<KeyFrameId> {
        self.covisibles()
            .into_iter()
            .take(n)
            .map(|(k, _)| k)
            .collect()
    }

    /// Connected keyframes sharing at least `min_weight` points, by decreasing weight
    /// (ORB-SLAM `GetCovisiblesByWeight`).
    pub fn covisibles_with_min_weight(&self, min_weight: usize) -> Vec<KeyFrameId> {
        self.covisibles()
            .into_iter()
            .take_while(|&(_, w)| w >= min_weight)
            .map(|(k, _)| k)
            .collect()
    }
}
