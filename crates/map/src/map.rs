//! The map arena: storage, id allocation, lookups and the simple setters.
//!
//! The link-changing operations live in the submodules, one concept each: observations
//! (point <-> keyframe), covisibility, spanning tree (keyframe culling), point geometry and
//! descriptor, the consistency check, whole-map atlas operations (moving, renumbering,
//! merging) and map files ([`persist`]).

use ferroslam_features::ScalePyramid;
use nalgebra::{Isometry3, Vector3};

use crate::{FrameFeatures, KeyFrame, KeyFrameId, MapError, MapPoint, MapPointId, Rig};

mod arena;
mod atlas_ops;
mod consistency;
mod covisibility;
mod journal;
mod observations;
pub mod persist;
mod point_geometry;
mod spanning_tree;

use arena::Arena;
pub use covisibility::COVISIBILITY_THRESHOLD;
use journal::Recorder;
pub use journal::{MapEdit, MapJournal};

/// What is kept of a culled keyframe: its pose relative to the keyframe that adopted its
/// children (its parent, ORB-SLAM `mTcp`).
#[derive(Clone, Debug)]
#[allow(non_snake_case)]
struct CulledKeyFrame {
    anchor: KeyFrameId,
    T_c_a: Isometry3<f64>,
}

/// The SLAM map: arena of keyframes and map points plus their graphs. See the crate docs
/// for the removal policy and the invariants every public method preserves.
///
/// Iteration orders (ids, covisibility ties, observations) are by increasing id, so every
/// operation is deterministic. A clone costs O(1): the copies share their keyframes and
/// points until either writes one (see `arena`).
#[derive(Clone, Debug)]
pub struct Map {
    pyramid: ScalePyramid,
    keyframes: Arena<KeyFrameId, KeyFrame>,
    map_points: Arena<MapPointId, MapPoint>,
    next_keyframe: u32,
    next_map_point: u32,
    /// The first keyframe inserted since creation / `clear`: spanning-tree root, never culled.
    origin: Option<KeyFrameId>,
    culled_keyframes: Arena<KeyFrameId, CulledKeyFrame>,
    replaced_points: Arena<MapPointId, MapPointId>,
    /// Edits being recorded (a copy handed to concurrent mapping), see [`MapJournal`].
    recorder: Option<Recorder>,
    /// The sensor and camera the map is built with (kept by `clear`), stored in map files.
    rig: Option<Rig>,
}

#[allow(non_snake_case)]
impl Map {
    /// An empty map whose keyframes share the ORB scale `pyramid`.
    pub fn new(pyramid: ScalePyramid) -> Self {
        Self {
            pyramid,
            keyframes: Arena::default(),
            map_points: Arena::default(),
            next_keyframe: 0,
            next_map_point: 0,
            origin: None,
            culled_keyframes: Arena::default(),
            replaced_points: Arena::default(),
            recorder: None,
            rig: None,
        }
    }

    /// Records the sensor and camera the map is built with (written to map files).
    pub fn set_rig(&mut self, rig: Rig) {
        self.rig = Some(rig);
    }

    /// The sensor and camera the map is built with, if recorded.
    pub fn rig(&self) -> Option<&Rig> {
        self.rig.as_ref()
    }

    /// The ORB scale pyramid of every keyframe.
    pub fn pyramid(&self) -> &ScalePyramid {
        &self.pyramid
    }

    /// Adds a keyframe with no observations and no links; the first one becomes the
    /// spanning-tree root ([`Map::origin`]).
    pub fn insert_keyframe(
        &mut self,
        timestamp: f64,
        frame_index: usize,
        T_c_w: Isometry3<f64>,
        features: FrameFeatures,
    ) -> KeyFrameId {
        let id = KeyFrameId(self.next_keyframe);
        self.next_keyframe += 1;
        self.keyframes.insert(
            id,
            KeyFrame::new(id, timestamp, frame_index, T_c_w, features),
        );
        self.origin.get_or_insert(id);
        id
    }

    /// Creates a point at `position` (world, m) with no observations. Add the reference
    /// keyframe's observation with [`Map::add_observation`], then call
    /// [`Map::update_normal_and_depth`] and [`Map::compute_distinctive_descriptor`].
    ///
    /// # Errors
    /// [`MapError::UnknownKeyFrame`] if `reference` is not in the map.
    pub fn create_map_point(
        &mut self,
        position: Vector3<f64>,
        reference: KeyFrameId,
    ) -> Result<MapPointId, MapError> {
        if !self.keyframes.contains_key(&reference) {
            return Err(MapError::UnknownKeyFrame(reference));
        }
        let id = MapPointId(self.next_map_point);
        self.next_map_point += 1;
        let point = MapPoint::new(id, position, reference);
        self.record_created_point(id, &point);
        self.map_points.insert(id, point);
        Ok(id)
    }

    /// The keyframe, `None` if unknown or culled.
    pub fn keyframe(&self, id: KeyFrameId) -> Option<&KeyFrame> {
        self.keyframes.get(&id)
    }

    /// The map point, `None` if unknown, culled or fused.
    pub fn map_point(&self, id: MapPointId) -> Option<&MapPoint> {
        self.map_points.get(&id)
    }

    /// All keyframes by increasing id.
    pub fn keyframes(&self) -> impl Iterator<Item = &KeyFrame> {
        self.keyframes.values()
    }

    /// All map points by increasing id.
    pub fn map_points(&self) -> impl Iterator<Item = &MapPoint> {
        self.map_points.values()
    }

    /// Ids of all keyframes, increasing.
    pub fn keyframe_ids(&self) -> Vec<KeyFrameId> {
        self.keyframes.keys().copied().collect()
    }

    /// Ids of all map points, increasing.
    pub fn map_point_ids(&self) -> Vec<MapPointId> {
        self.map_points.keys().copied().collect()
    }

    /// Number of keyframes.
    pub fn num_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// Number of map points.
    pub fn num_map_points(&self) -> usize {
        self.map_points.len()
    }

    /// The spanning-tree root: the first keyframe inserted (since the last [`Map::clear`]).
    pub fn origin(&self) -> Option<KeyFrameId> {
        self.origin
    }

    /// True if `id` is not (or no longer) a keyframe of the map.
    pub fn is_keyframe_bad(&self, id: KeyFrameId) -> bool {
        !self.keyframes.contains_key(&id)
    }

    /// True if `id` is not (or no longer) a point of the map.
    pub fn is_map_point_bad(&self, id: MapPointId) -> bool {
        !self.map_points.contains_key(&id)
    }

    /// Sets a keyframe's world-to-camera pose.
    ///
    /// # Errors
    /// [`MapError::UnknownKeyFrame`].
    pub fn set_keyframe_pose(
        &mut self,
        kf: KeyFrameId,
        T_c_w: Isometry3<f64>,
    ) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::SetKeyFramePose { kf, T_c_w },
            |map| map.set_keyframe_pose_now(kf, T_c_w),
        )
    }

    /// The body of [`Map::set_keyframe_pose`], run inside its journal entry.
    fn set_keyframe_pose_now(
        &mut self,
        kf: KeyFrameId,
        T_c_w: Isometry3<f64>,
    ) -> Result<(), MapError> {
        self.keyframe_mut(kf)?.T_c_w = T_c_w;
        Ok(())
    }

    /// Sets a point's world position (m). Normal and distances are not refreshed: call
    /// [`Map::update_normal_and_depth`] when they matter.
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`].
    pub fn set_map_point_position(
        &mut self,
        mp: MapPointId,
        p_w: Vector3<f64>,
    ) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::SetMapPointPosition { mp, p_w },
            |map| map.set_map_point_position_now(mp, p_w),
        )
    }

    /// The body of [`Map::set_map_point_position`], run inside its journal entry.
    fn set_map_point_position_now(
        &mut self,
        mp: MapPointId,
        p_w: Vector3<f64>,
    ) -> Result<(), MapError> {
        self.map_point_mut(mp)?.position = p_w;
        Ok(())
    }

    /// Adds `n` to the point's visible counter (ORB-SLAM `IncreaseVisible`).
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`].
    pub fn increase_visible(&mut self, mp: MapPointId, n: u32) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::IncreaseVisible { mp, n },
            |map| map.increase_visible_now(mp, n),
        )
    }

    /// The body of [`Map::increase_visible`], run inside its journal entry.
    fn increase_visible_now(&mut self, mp: MapPointId, n: u32) -> Result<(), MapError> {
        let point = self.map_point_mut(mp)?;
        point.visible = point.visible.saturating_add(n);
        Ok(())
    }

    /// Adds `n` to the point's found counter (ORB-SLAM `IncreaseFound`).
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`].
    pub fn increase_found(&mut self, mp: MapPointId, n: u32) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::IncreaseFound { mp, n },
            |map| map.increase_found_now(mp, n),
        )
    }

    /// The body of [`Map::increase_found`], run inside its journal entry.
    fn increase_found_now(&mut self, mp: MapPointId, n: u32) -> Result<(), MapError> {
        let point = self.map_point_mut(mp)?;
        point.found = point.found.saturating_add(n);
        Ok(())
    }

    /// Adds 1 to the visible counter of each point of `mps` (ORB-SLAM `IncreaseVisible`, once
    /// per point and frame), recorded as one journal entry for the whole list: tracking counts
    /// every local point it projects, every frame. A point listed twice counts twice.
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`] for the first unknown point; the known ones are counted
    /// all the same, as a replay of the journal entry does.
    pub fn increase_visible_many(&mut self, mps: &[MapPointId]) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::IncreaseVisibleMany { mps: mps.to_vec() },
            |map| map.increase_many_now(mps, |p| &mut p.visible),
        )
    }

    /// Adds 1 to the found counter of each point of `mps` (ORB-SLAM `IncreaseFound`), as one
    /// journal entry; see [`Map::increase_visible_many`].
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`] for the first unknown point, the others counted.
    pub fn increase_found_many(&mut self, mps: &[MapPointId]) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::IncreaseFoundMany { mps: mps.to_vec() },
            |map| map.increase_many_now(mps, |p| &mut p.found),
        )
    }

    /// The body of the batched counters: the counter `counter` picks, plus one per listing.
    fn increase_many_now(
        &mut self,
        mps: &[MapPointId],
        counter: impl Fn(&mut MapPoint) -> &mut u32,
    ) -> Result<(), MapError> {
        let mut first_unknown = None;
        for &mp in mps {
            match self.map_points.get_mut(&mp) {
                Some(point) => {
                    let c = counter(point);
                    *c = c.saturating_add(1);
                }
                None => {
                    first_unknown.get_or_insert(MapError::UnknownMapPoint(mp));
                }
            }
        }
        first_unknown.map_or(Ok(()), Err)
    }

    /// Number of points of `kf` with at least `min_obs` observations (ORB-SLAM
    /// `TrackedMapPoints`, `nObs` counting stereo twice); 0 for an unknown keyframe.
    pub fn tracked_points(&self, kf: KeyFrameId, min_obs: usize) -> usize {
        self.keyframes.get(&kf).map_or(0, |frame| {
            frame
                .map_points
                .iter()
                .flatten()
                .filter(|mp| self.map_points.get(mp).is_some_and(|p| p.n_obs >= min_obs))
                .count()
        })
    }

    /// The live points observed by `keyframes`, each once, in order of first sight (keyframe
    /// order, then keypoint order); unknown keyframes contribute nothing.
    ///
    /// Runs for every tracked frame over the whole local map (tens of thousands of slots), so
    /// "seen" is a bitset over point ids rather than a hash set; keyframe slots only hold live
    /// points (see the crate invariants).
    pub fn points_seen_by(
        &self,
        keyframes: impl IntoIterator<Item = KeyFrameId>,
    ) -> Vec<MapPointId> {
        let mut out = Vec::new();
        self.points_seen_by_into(keyframes, &mut Vec::new(), &mut out);
        out
    }

    /// [`Map::points_seen_by`] into `out` (cleared first), with `seen` as the bitset: buffers
    /// kept by the caller so that tracking allocates nothing per frame once they have grown.
    /// `seen` must be all zeros (or empty) and is left so.
    pub fn points_seen_by_into(
        &self,
        keyframes: impl IntoIterator<Item = KeyFrameId>,
        seen: &mut Vec<u64>,
        out: &mut Vec<MapPointId>,
    ) {
        out.clear();
        let words = (self.next_map_point as usize).div_ceil(64);
        if seen.len() < words {
            seen.resize(words, 0);
        }
        out.extend(
            keyframes
                .into_iter()
                .filter_map(|kf| self.keyframes.get(&kf))
                .flat_map(|frame| frame.map_points.iter().flatten().copied())
                .filter(|mp| {
                    debug_assert!(self.map_points.contains_key(mp), "slot holds dead {mp:?}");
                    let (word, bit) = (mp.0 as usize / 64, mp.0 % 64);
                    let first = seen[word] & (1 << bit) == 0;
                    seen[word] |= 1 << bit;
                    first
                }),
        );
        for mp in out.iter() {
            seen[mp.0 as usize / 64] = 0;
        }
    }

    /// The live point `id` stands for: itself if in the map, else the point it was fused
    /// into (following chains of fusions, ORB-SLAM `GetReplaced`); `None` if it was culled.
    pub fn resolve_map_point(&self, id: MapPointId) -> Option<MapPointId> {
        let mut current = id;
        for _ in 0..=self.replaced_points.len() {
            if self.map_points.contains_key(&current) {
                return Some(current);
            }
            current = *self.replaced_points.get(&current)?;
        }
        None
    }

    /// World-to-camera pose of a keyframe, live or culled: a culled keyframe is placed
    /// relative to the keyframe that adopted it, as when it was culled (ORB-SLAM trajectory
    /// saving through `mTcp`). `None` if the id was never a keyframe (or after `clear`).
    pub fn resolve_keyframe_pose(&self, id: KeyFrameId) -> Option<Isometry3<f64>> {
        let mut T_c_a = Isometry3::identity();
        let mut current = id;
        for _ in 0..=self.culled_keyframes.len() {
            if let Some(frame) = self.keyframes.get(&current) {
                return Some(T_c_a * frame.T_c_w);
            }
            let culled = self.culled_keyframes.get(&current)?;
            T_c_a *= culled.T_c_a;
            current = culled.anchor;
        }
        None
    }

    /// Removes everything; ids keep increasing (never reused).
    pub fn clear(&mut self) {
        self.keyframes.clear();
        self.map_points.clear();
        self.origin = None;
        self.culled_keyframes.clear();
        self.replaced_points.clear();
    }

    fn keyframe_mut(&mut self, id: KeyFrameId) -> Result<&mut KeyFrame, MapError> {
        self.keyframes
            .get_mut(&id)
            .ok_or(MapError::UnknownKeyFrame(id))
    }

    fn map_point_mut(&mut self, id: MapPointId) -> Result<&mut MapPoint, MapError> {
        self.map_points
            .get_mut(&id)
            .ok_or(MapError::UnknownMapPoint(id))
    }
}
