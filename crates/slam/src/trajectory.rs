//! The per-frame trajectory, stored relative to reference keyframes so that later map
//! corrections (local BA, culling) move every frame with its keyframe (as ORB-SLAM saves it).

use ferroslam_map::{KeyFrameId, Map};
use nalgebra::Isometry3;

use crate::inertial::scale_translation;

/// One tracked frame: its reference keyframe and its pose relative to it.
#[derive(Clone, Copy, Debug)]
struct FrameRecord {
    timestamp: f64,
    reference: KeyFrameId,
    T_c_r: Isometry3<f64>,
}

/// Tracked frames, each anchored to a keyframe.
#[derive(Debug, Default)]
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
        // Culled keyframes are placed relative to their anchors by unscaled offsets (inside
        // the map), so the frames are re-anchored rather than their offsets scaled.
        let scaled: Vec<_> = self
            .frames
            .iter()
            .map(|f| {
                let T_r_w = map.resolve_keyframe_pose(f.reference)?;
                Some(scale_translation(&(f.T_c_r * T_r_w), s))
            })
            .collect();
        rescale_map(map)?;
        for (f, T_c_w) in self.frames.iter_mut().zip(scaled) {
            if let (Some(T_c_w), Some(T_r_w)) = (T_c_w, map.resolve_keyframe_pose(f.reference)) {
                f.T_c_r = T_c_w * T_r_w.inverse();
            }
        }
        Ok(())
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
