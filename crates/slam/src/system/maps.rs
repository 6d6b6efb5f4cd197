//! The system's maps: the current one and the atlas's (see `crate::atlas`). A lost map goes
//! to the atlas; a lost or new map's frames are relocalised in the atlas's maps, and the one
//! found becomes current again; a keyframe that recognises a place of a stored map merges
//! the current map into it (`crate::loop_closing`'s merging).

use std::sync::Arc;

use ferroslam_map::{KeyFrameId, Map, MapPointId};
use nalgebra::{Isometry3, Vector3};

use super::SlamSystem;
use crate::atlas::{MapSummary, StoredMap};
use crate::error::SlamError;
use crate::frame::Frame;
use crate::inertial::{Inertial, InertialMapState};
use crate::loop_closing::{
    join_maps, min_neighbour_score, seam_keyframes, verify_merge, LoopDetector, MapMerge,
    MergeMatch,
};
use crate::mapping::MappingRequest;
use crate::place_recognition::PlaceRecognition;
use crate::tracking::{Tracker, TrackingState};
use crate::trajectory::Trajectory;

impl SlamSystem {
    /// The ids after every keyframe and point id any map of this run has used.
    pub(super) fn used_ids(&self) -> (KeyFrameId, MapPointId) {
        std::iter::once(&self.map)
            .chain(self.atlas.iter().map(|s| &s.map))
            .map(Map::next_ids)
            .fold((KeyFrameId(0), MapPointId(0)), |(k, m), (nk, nm)| {
                (k.max(nk), m.max(nm))
            })
    }

    /// A new map id.
    pub(super) fn new_map_id(&mut self) -> usize {
        self.next_map_id += 1;
        self.next_map_id - 1
    }

    /// An empty map like the current one (pyramid, rig), its ids after every used one.
    fn fresh_map(&self) -> Map {
        let mut map = Map::new(self.map.pyramid().clone());
        map.set_rig(self.ctx.rig());
        map.reserve_ids(self.used_ids());
        map
    }

    /// An empty keyframe index over the current one's vocabulary.
    pub(super) fn fresh_place(&self) -> Option<PlaceRecognition> {
        let config = self.ctx.config.place_recognition;
        self.place
            .as_ref()
            .map(|p| PlaceRecognition::new(std::sync::Arc::clone(p.vocabulary()), config))
    }

    /// Moves the current map, its frames and its index to the atlas and starts a new map.
    pub(super) fn store_current_map(&mut self) {
        // The mapping thread's copy is dropped with its next job (reset below).
        let (map, place) = (self.fresh_map(), self.fresh_place());
        let stored = StoredMap {
            id: self.map_id,
            map: std::mem::replace(&mut self.map, map),
            trajectory: std::mem::take(&mut self.trajectory),
            place: std::mem::replace(&mut self.place, place),
            detector: LoopDetector::default(),
            inertial: self.inertial.as_mut().map(Inertial::take_map_state),
        };
        self.atlas.push(stored);
        self.map_id = self.new_map_id();
        self.clear_map();
    }

    /// Whether stored maps can be found again: a vocabulary and a map being built.
    fn atlas_searchable(&self) -> bool {
        !self.atlas.is_empty() && self.place.is_some() && !self.localization_only
    }

    /// Whether tracking can resume in `stored`: any map of a visual system; with an IMU, a
    /// map aligned with it (its gravity and keyframe states kept with it: a loaded map or
    /// one lost before its alignment would be re-aligned, its world turned).
    fn relocalisable(&self, stored: &StoredMap) -> bool {
        self.inertial.is_none()
            || stored
                .inertial
                .as_ref()
                .is_some_and(InertialMapState::is_aligned)
    }

    /// Relocalises `frame` in the atlas's maps, the most recently stored first. The map it
    /// is found in becomes the current one (with `frame` tracked in it); the current map
    /// goes to the atlas, or is dropped when it has too few keyframes to keep. Whether it
    /// was found.
    pub(super) fn relocalise_in_atlas(&mut self, frame: &mut Frame) -> Result<bool, SlamError> {
        if !self.atlas_searchable() {
            return Ok(false);
        }
        for i in (0..self.atlas.len()).rev() {
            if !self.relocalisable(&self.atlas[i]) {
                continue;
            }
            let stored = &mut self.atlas[i];
            let mut tracker = Tracker::default();
            tracker.state = TrackingState::Lost;
            let mut trial = frame.clone();
            if tracker.track(
                &mut trial,
                &mut stored.map,
                &self.ctx,
                stored.place.as_ref(),
            )? {
                *frame = trial;
                self.finish_mapping()?;
                let stored = self.atlas.remove(i);
                self.make_current(stored);
                if let Some(inertial) = self.inertial.as_mut() {
                    inertial.resume_at(frame.timestamp);
                }
                self.tracker = tracker;
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Makes `stored` the current map; the current one goes to the atlas when it is worth
    /// keeping: loaded (no frames tracked in it), or with more keyframes than
    /// `tracking.min_keyframes_to_keep`.
    pub(super) fn make_current(&mut self, stored: StoredMap) {
        let keyframes = self.map.num_keyframes();
        let young = keyframes <= self.ctx.config.tracking.min_keyframes_to_keep
            && !self.trajectory.is_empty();
        let keep = keyframes > 0 && !young;
        let previous = StoredMap {
            id: self.map_id,
            map: std::mem::replace(&mut self.map, stored.map),
            trajectory: std::mem::replace(&mut self.trajectory, stored.trajectory),
            place: std::mem::replace(&mut self.place, stored.place),
            detector: LoopDetector::default(),
            inertial: self.inertial.as_mut().map(Inertial::take_map_state),
        };
        if let (Some(inertial), Some(state)) = (self.inertial.as_mut(), stored.inertial) {
            inertial.restore_map_state(state);
        }
        if keep {
            self.atlas.push(previous);
        } else {
            self.unpose_young_frames();
        }
        self.map_id = stored.id;
        // A map brought back continues after every id used meanwhile.
        self.map.reserve_ids(self.used_ids());
        self.forget_map_work();
        self.atlas.iter_mut().for_each(|s| s.detector.clear());
    }

    /// Looks for a place of a stored map in each keyframe mapped since the last frame and
    /// merges the current map into the first one verified (see `crate::loop_closing`'s
    /// merging); with `loop_closing.loop_closure` only.
    pub(super) fn check_merges(&mut self) -> Result<(), SlamError> {
        let checks = std::mem::take(&mut self.merge_checks);
        // Merging online is part of loop closing (as in ORB-SLAM3).
        if self.tracker.state != TrackingState::Ok || !self.ctx.config.loop_closing.loop_closure {
            return Ok(());
        }
        self.check_merges_at(&checks)
    }

    /// [`Self::check_merges`] for keyframes `checks` of the current map, in order.
    pub(super) fn check_merges_at(&mut self, checks: &[KeyFrameId]) -> Result<(), SlamError> {
        // Visual-inertial maps are not merged: their gravity and keyframe states would have
        // to be joined too (relocalisation does resume in them).
        if !self.atlas_searchable() || self.inertial.is_some() {
            return Ok(());
        }
        let consistency = self.ctx.config.loop_closing.consistency;
        for &kf in checks {
            let Some(place) = self.place.as_ref() else {
                return Ok(());
            };
            let (Some((bow, _)), Some(min_score)) =
                (place.entry(kf), min_neighbour_score(kf, &self.map, place))
            else {
                continue;
            };
            let mut consistent: Vec<(usize, KeyFrameId)> = Vec::new();
            for (i, stored) in self.atlas.iter_mut().enumerate() {
                let Some(theirs) = stored.place.as_ref() else {
                    continue;
                };
                let candidates = theirs.merge_candidates(bow, &stored.map, min_score);
                let found = stored
                    .detector
                    .consistent(candidates, &stored.map, consistency);
                consistent.extend(found.into_iter().map(|c| (i, c)));
            }
            for (i, candidate) in consistent {
                if self.map.keyframe(kf).is_none() {
                    break;
                }
                if self.try_merge(kf, i, candidate)? {
                    return Ok(());
                }
            }
        }
        Ok(())
    }

    /// Verifies `candidate` of stored map `i` as the place keyframe `kf` of the current map
    /// shows, on the maps as they are (see `verify_merge`).
    fn verify_place(
        &self,
        kf: KeyFrameId,
        i: usize,
        candidate: KeyFrameId,
    ) -> Result<Option<MergeMatch>, SlamError> {
        let stored = &self.atlas[i];
        let fv = self.place.as_ref().and_then(|p| p.feature_vector(kf));
        match (fv, stored.place.as_ref()) {
            (Some(fv), Some(place)) if self.map.keyframe(kf).is_some() => verify_merge(
                (&self.map, kf, fv),
                (&stored.map, candidate, place),
                &self.ctx,
            ),
            _ => Ok(None),
        }
    }

    /// Verifies and, if verified, performs the merge of the current map into stored map `i`
    /// at `(kf, candidate)`. Nothing changes unless it is done (whether it is).
    fn try_merge(
        &mut self,
        kf: KeyFrameId,
        i: usize,
        candidate: KeyFrameId,
    ) -> Result<bool, SlamError> {
        // The merge joins the maps as tracking holds them: mapping finishes first (verified
        // before the thread's last edits are in, young monocular maps never merged).
        self.finish_mapping()?;
        let Some(merge) = self.verify_place(kf, i, candidate)? else {
            return Ok(false);
        };
        let stored = &self.atlas[i];
        // The maps are joined where they share the most: the window's reference keyframe.
        let matched = merge.matched();
        let S = merge.S_older_current;
        // On copies (sharing their entries): an error leaves every map as it was.
        let mut current = self.map.clone();
        let mut trajectory = self.trajectory.clone();
        let (merged, graph_cost) = trajectory
            .transform_world(&S, &mut current, |m| m.transform_world(&S))
            .map_err(SlamError::from)
            .and_then(|()| {
                join_maps(
                    stored.map.clone(),
                    current,
                    (kf, matched),
                    &merge,
                    &self.ctx,
                )
            })?;
        let seam = seam_keyframes((kf, matched), &merged);
        let mut stored = self.atlas.remove(i);
        self.record_merge(&merge, &stored, (kf, matched), (graph_cost, seam.len()));
        stored.trajectory.append(trajectory);
        if let (Some(theirs), Some(ours)) = (stored.place.as_mut(), self.place.take()) {
            theirs.absorb(ours);
        }
        self.map = merged;
        self.map.reserve_ids(self.used_ids());
        self.trajectory = std::mem::take(&mut stored.trajectory);
        self.place = stored.place.take();
        self.map_id = stored.id;
        self.tracker.transform_world(&S);
        self.forget_map_work();
        self.atlas.iter_mut().for_each(|s| s.detector.clear());
        if let Some(place) = self.place.as_mut() {
            place.forget_culled(&self.map);
        }
        // The weld and global BA run where loop closing's BA runs: in the mapping thread, with
        // tracking going on in the merged map meanwhile (inline: here, within this call).
        let vocabulary = self.place.as_ref().map(|p| Arc::clone(p.vocabulary()));
        let adjusted = self.mapping.submit(
            MappingRequest::AdjustMerged { seam },
            &mut self.map,
            &self.ctx,
            vocabulary.as_ref(),
        );
        self.absorb(adjusted.into_iter().collect())?;
        Ok(true)
    }

    fn record_merge(
        &mut self,
        merge: &MergeMatch,
        into: &StoredMap,
        (kf, candidate): (KeyFrameId, KeyFrameId),
        (graph_cost, welded_keyframes): ((f64, f64), usize),
    ) {
        let time = |map: &Map, k| map.keyframe(k).map_or(f64::NAN, |k| k.timestamp());
        self.merges.push(MapMerge {
            merged_map: self.map_id,
            into_map: into.id,
            current: kf,
            matched: candidate,
            timestamps: (time(&self.map, kf), time(&into.map, candidate)),
            num_matches: merge.num_matches(),
            scale: merge.S_older_current.scale,
            graph_cost,
            welded_keyframes,
            similarity: merge.S_older_current,
        });
    }

    /// Maps merged so far, oldest first.
    pub fn merges(&self) -> &[MapMerge] {
        &self.merges
    }

    /// Id of the map tracking runs in.
    pub fn current_map_id(&self) -> usize {
        self.map_id
    }

    /// Every map of the run with keyframes (the atlas's, oldest first, then the current
    /// one), in the order `save_map` writes them.
    pub fn maps(&self) -> Vec<MapSummary> {
        let current = MapSummary {
            id: self.map_id,
            frames: self.trajectory.poses(&self.map).len(),
            keyframes: self.map.num_keyframes(),
            points: self.map.num_map_points(),
            current: true,
        };
        self.atlas
            .iter()
            .map(StoredMap::summary)
            .chain(std::iter::once(current))
            .filter(|m| m.keyframes > 0)
            .collect()
    }

    /// The map with id `id` (current or stored).
    ///
    /// # Errors
    /// `InvalidInput` naming the run's map ids when `id` is none of them.
    pub fn map_by_id(&self, id: usize) -> Result<&Map, SlamError> {
        if id == self.map_id {
            return Ok(&self.map);
        }
        self.atlas
            .iter()
            .find(|s| s.id == id)
            .map(|s| &s.map)
            .ok_or_else(|| {
                let ids: Vec<String> = self.maps().iter().map(|m| m.id.to_string()).collect();
                SlamError::InvalidInput(format!(
                    "map_id {id} is not a map of this run (its maps: {})",
                    if ids.is_empty() {
                        "none yet".to_owned()
                    } else {
                        ids.join(", ")
                    }
                ))
            })
    }

    /// [`Self::keyframe_trajectory`] of map `id`.
    ///
    /// # Errors
    /// As [`Self::map_by_id`].
    pub fn keyframe_trajectory_of(
        &self,
        id: usize,
    ) -> Result<Vec<(KeyFrameId, f64, Isometry3<f64>)>, SlamError> {
        self.map_by_id(id).map(super::keyframes_of)
    }

    /// [`Self::map_points`] of map `id`.
    ///
    /// # Errors
    /// As [`Self::map_by_id`].
    pub fn map_points_of(&self, id: usize) -> Result<Vec<Vector3<f64>>, SlamError> {
        self.map_by_id(id).map(super::points_of)
    }

    /// [`Self::map_point_colors`] of map `id`.
    ///
    /// # Errors
    /// As [`Self::map_by_id`].
    pub fn map_point_colors_of(
        &self,
        id: usize,
    ) -> Result<Vec<Option<ferroslam_map::Rgb>>, SlamError> {
        self.map_by_id(id).map(super::colors_of)
    }

    /// `(timestamp, T_w_c, map id)` of every tracked frame in time order, with all map
    /// corrections applied; each pose is in its map's world (and, monocular, scale).
    fn frames_with_maps(&self) -> Vec<(f64, Isometry3<f64>, usize)> {
        let of = |id: usize, map: &Map, trajectory: &Trajectory| {
            trajectory
                .poses(map)
                .into_iter()
                .map(move |(t, T)| (t, T, id))
                .collect::<Vec<_>>()
        };
        let mut frames: Vec<_> = self
            .atlas
            .iter()
            .flat_map(|s| of(s.id, &s.map, &s.trajectory))
            .chain(of(self.map_id, &self.map, &self.trajectory))
            .collect();
        frames.sort_by(|a, b| a.0.total_cmp(&b.0));
        frames
    }

    /// `(timestamp, T_w_c)` of every tracked frame in time order, with all map corrections
    /// applied; see [`Self::frame_map_ids`] for the map of each.
    pub fn frame_trajectory(&self) -> Vec<(f64, Isometry3<f64>)> {
        self.frames_with_maps()
            .into_iter()
            .map(|(t, T, _)| (t, T))
            .collect()
    }

    /// Map id of each entry of [`Self::frame_trajectory`]. Poses of different maps live in
    /// different worlds (and, monocular, scales).
    pub fn frame_map_ids(&self) -> Vec<usize> {
        self.frames_with_maps()
            .into_iter()
            .map(|(_, _, id)| id)
            .collect()
    }
}
