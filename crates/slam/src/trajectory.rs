//! The per-frame trajectory, stored relative to reference keyframes so that later map
//! corrections (local BA, culling) move every frame with its keyframe (as ORB-SLAM saves it).

use ferroslam_map::{KeyFrameId, Map};
use nalgebra::Isometry3;

use ferroslam_geometry::sim3::Sim3;

use crate::inertial::scale_translation;
use crate::loop_closing::pose_of;

/// One tracked frame: its reference keyframe and its pose relative to it.
#[derive(Clone, Copy, Debug)]
struct FrameRecord {
    timestamp: f64,
    reference: KeyFrameId,
    T_c_r: Isometry3<f64>,
}

/// Tracked frames, each anchored to a keyframe.
#[derive(Clone, Debug, Default)]
pub struct Trajectory {
    frames: Vec<FrameRecord>,
}

impl Trajectory {
    /// Records a tracked frame at pose `T_c_w` with reference keyframe `reference`.
    pub fn push(
        &mut self,
        timestamp: f64,
        T_c_w: &Isometry3<f64>,
        reference: KeyFrameId,
        map: &Map,
    ) {
        if let Some(T_r_w) = map.resolve_keyframe_pose(reference) {
            self.frames.push(FrameRecord {
                timestamp,
                reference,
                T_c_r: T_c_w * T_r_w.inverse(),
            });
        }
    }

    /// Records an earlier frame (tracked after the frames around it) in time order; a
    /// timestamp already recorded is left as it is. Whether it was recorded.
    pub fn insert(
        &mut self,
        timestamp: f64,
        T_c_w: &Isometry3<f64>,
        reference: KeyFrameId,
        map: &Map,
    ) -> bool {
        let at = self.frames.partition_point(|f| f.timestamp < timestamp);
        let taken = self
            .frames
            .get(at)
            .is_some_and(|f| f.timestamp == timestamp);
        let Some(T_r_w) = map.resolve_keyframe_pose(reference).filter(|_| !taken) else {
            return false;
        };
        self.frames.insert(
            at,
            FrameRecord {
                timestamp,
                reference,
                T_c_r: T_c_w * T_r_w.inverse(),
            },
        );
        true
    }

    /// `(timestamp, T_w_c)` of every tracked frame with the current map's corrections
    /// (culled reference keyframes are followed to their live ancestors).
    pub fn poses(&self, map: &Map) -> Vec<(f64, Isometry3<f64>)> {
        self.frames
            .iter()
            .filter_map(|f| {
                let T_r_w = map.resolve_keyframe_pose(f.reference)?;
                Some((f.timestamp, (f.T_c_r * T_r_w).inverse()))
            })
            .collect()
    }

    /// Scales the world by `s`: `rescale_map` scales `map`, and every frame keeps its pose
    /// scaled by `s`, re-anchored to its (possibly culled) reference keyframe.
    ///
    /// # Errors
    /// Whatever `rescale_map` returns; the trajectory is unchanged then.
    pub fn rescale<E>(
        &mut self,
        s: f64,
        map: &mut Map,
        rescale_map: impl FnOnce(&mut Map) -> Result<(), E>,
    ) -> Result<(), E> {
        self.reanchor(map, |T_c_w| scale_translation(T_c_w, s), rescale_map)
    }

    /// Moves the world by the similarity `S_new_old` (a map merged into another's frame):
    /// `transform_map` moves `map`, and every frame keeps its projections (`T_c_w S^-1`, as
    /// a rigid pose), re-anchored to its reference keyframe.
    ///
    /// # Errors
    /// Whatever `transform_map` returns; the trajectory is unchanged then.
    pub fn transform_world<E>(
        &mut self,
        S_new_old: &Sim3,
        map: &mut Map,
        transform_map: impl FnOnce(&mut Map) -> Result<(), E>,
    ) -> Result<(), E> {
        let S_old_new = S_new_old.inverse();
        let moved = |T_c_w: &Isometry3<f64>| pose_of(&(Sim3::from_isometry(T_c_w) * S_old_new));
        self.reanchor(map, moved, transform_map)
    }

    /// Each frame's pose through `new_pose`, then `change_map`, then re-anchored.
    fn reanchor<E>(
        &mut self,
        map: &mut Map,
        new_pose: impl Fn(&Isometry3<f64>) -> Isometry3<f64>,
        change_map: impl FnOnce(&mut Map) -> Result<(), E>,
    ) -> Result<(), E> {
        // Culled keyframes are placed relative to their anchors (inside the map), so the
        // frames are re-anchored rather than their offsets changed.
        let moved: Vec<_> = self
            .frames
            .iter()
            .map(|f| {
                let T_r_w = map.resolve_keyframe_pose(f.reference)?;
                Some(new_pose(&(f.T_c_r * T_r_w)))
            })
            .collect();
        change_map(map)?;
        for (f, T_c_w) in self.frames.iter_mut().zip(moved) {
            if let (Some(T_c_w), Some(T_r_w)) = (T_c_w, map.resolve_keyframe_pose(f.reference)) {
                f.T_c_r = T_c_w * T_r_w.inverse();
            }
        }
        Ok(())
    }

    /// Takes in the frames of `other` (the trajectory of a map merged into this one's, its
    /// keyframes now in this map), keeping time order.
    pub fn append(&mut self, other: Trajectory) {
        self.frames.extend(other.frames);
        self.frames
            .sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    }

    /// Whether no frame was tracked.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Forgets everything.
    pub fn clear(&mut self) {
        self.frames.clear();
    }
}
