//! The map journal: a record of the edits made to a map copy, replayed on the original.
//!
//! Concurrent local mapping works on a snapshot of the map while tracking keeps using (and
//! inserting keyframes into) the original; nothing is locked. When the mapping thread is
//! done, the edits it made are sent back as a [`MapJournal`] and replayed by the owner of the
//! original ([`Map::apply_journal`]). Replaying re-executes the same operations, so their
//! effects combine with what tracking did in the meantime (e.g. covisibility recomputed
//! with the keyframe tracking inserted); positions and poses set by bundle adjustment are
//! copied as they are. Only the outermost call of an operation is recorded: the operations
//! it calls itself happen again when it is replayed.
//!
//! Points created in the copy get the original's next free ids when replayed; the renaming
//! is returned so whoever holds ids of them (local mapping's recent points) can follow.
//!
//! A journal can also be sent in parts ([`Map::drain_journal`]), so that the original gets
//! the points triangulated for a keyframe before local BA on the copy is done; the parts are
//! replayed in order with one renaming ([`Map::apply_journal_part`]).

use std::collections::HashMap;

use nalgebra::{Isometry3, Vector3};

use super::Map;
use crate::{KeyFrameId, MapError, MapPoint, MapPointId};

/// One recorded map operation, with its arguments.
#[derive(Clone, Debug, PartialEq)]
#[allow(missing_docs, non_snake_case)]
pub enum MapEdit {
    CreateMapPoint {
        id: MapPointId,
        position: Vector3<f64>,
        reference: KeyFrameId,
    },
    SetKeyFramePose {
        kf: KeyFrameId,
        T_c_w: Isometry3<f64>,
    },
    SetMapPointPosition {
        mp: MapPointId,
        p_w: Vector3<f64>,
    },
    IncreaseVisible {
        mp: MapPointId,
        n: u32,
    },
    IncreaseFound {
        mp: MapPointId,
        n: u32,
    },
    IncreaseVisibleMany {
        mps: Vec<MapPointId>,
    },
    IncreaseFoundMany {
        mps: Vec<MapPointId>,
    },
    AddObservation {
        mp: MapPointId,
        kf: KeyFrameId,
        index: usize,
    },
    EraseObservation {
        mp: MapPointId,
        kf: KeyFrameId,
    },
    SetMapPointBad {
        mp: MapPointId,
    },
    ReplaceMapPoint {
        old: MapPointId,
        new: MapPointId,
    },
    UpdateNormalAndDepth {
        mp: MapPointId,
    },
    ComputeDistinctiveDescriptor {
        mp: MapPointId,
    },
    UpdateConnections {
        kf: KeyFrameId,
    },
    AddLoopEdge {
        a: KeyFrameId,
        b: KeyFrameId,
    },
    SetKeyFrameBad {
        kf: KeyFrameId,
    },
}

/// The edits made to a map copy since [`Map::begin_journal`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MapJournal {
    /// Point ids from this one on were created in the copy.
    first_new_point: u32,
    /// The recorded operations, in order.
    edits: Vec<MapEdit>,
}

impl MapJournal {
    /// Number of recorded operations.
    pub fn len(&self) -> usize {
        self.edits.len()
    }

    /// Whether nothing was recorded.
    pub fn is_empty(&self) -> bool {
        self.edits.is_empty()
    }
}

/// Recording state: the journal and how deep inside a recorded operation we are.
#[derive(Clone, Debug, Default)]
pub(super) struct Recorder {
    journal: MapJournal,
    depth: u32,
}

impl Map {
    /// Starts recording this map's edits (on a copy made for concurrent mapping).
    /// Keyframe insertion and [`Map::clear`] are not recorded: they belong to tracking.
    pub fn begin_journal(&mut self) {
        self.recorder = Some(Recorder {
            journal: MapJournal {
                first_new_point: self.next_map_point,
                edits: Vec::new(),
            },
            depth: 0,
        });
    }

    /// Stops recording and returns the edits since [`Map::begin_journal`] (empty if it was
    /// not called).
    pub fn take_journal(&mut self) -> MapJournal {
        self.recorder.take().map(|r| r.journal).unwrap_or_default()
    }

    /// Returns the edits recorded since the last part and goes on recording: a part of a
    /// journal sent in parts, the last one coming from [`Map::take_journal`] (empty if not
    /// recording).
    pub fn drain_journal(&mut self) -> MapJournal {
        self.recorder
            .as_mut()
            .map(|r| MapJournal {
                first_new_point: r.journal.first_new_point,
                edits: std::mem::take(&mut r.journal.edits),
            })
            .unwrap_or_default()
    }

    /// Runs `body`, recording `edit` if this is the outermost recorded call.
    pub(super) fn journaled<R>(
        &mut self,
        edit: impl FnOnce() -> MapEdit,
        body: impl FnOnce(&mut Self) -> R,
    ) -> R {
        if let Some(r) = self.recorder.as_mut() {
            if r.depth == 0 {
                r.journal.edits.push(edit());
            }
            r.depth += 1;
        }
        let out = body(self);
        if let Some(r) = self.recorder.as_mut() {
            r.depth -= 1;
        }
        out
    }

    /// Records the creation of point `id` (called by [`Map::create_map_point`]).
    pub(super) fn record_created_point(&mut self, id: MapPointId, point: &MapPoint) {
        if let Some(r) = self.recorder.as_mut().filter(|r| r.depth == 0) {
            r.journal.edits.push(MapEdit::CreateMapPoint {
                id,
                position: point.position,
                reference: point.reference,
            });
        }
    }

    /// Replays `journal` (recorded on a copy of this map) on this map. Edits whose
    /// keyframes or points no longer exist here are skipped. Returns the new ids of the
    /// points the copy created, `copy id -> id here`.
    pub fn apply_journal(&mut self, journal: &MapJournal) -> HashMap<MapPointId, MapPointId> {
        let mut renamed = HashMap::new();
        self.apply_journal_part(journal, &mut renamed);
        renamed
    }

    /// Replays one part of a journal sent in parts ([`Map::drain_journal`]), after the parts
    /// before it. `renamed` holds the renaming of the points those parts created and gains
    /// this part's.
    pub fn apply_journal_part(
        &mut self,
        journal: &MapJournal,
        renamed: &mut HashMap<MapPointId, MapPointId>,
    ) {
        let first_new = journal.first_new_point;
        let id = |m: MapPointId, renamed: &HashMap<MapPointId, MapPointId>| {
            if m.0 >= first_new {
                renamed.get(&m).copied().unwrap_or(MapPointId(u32::MAX))
            } else {
                m
            }
        };
        for edit in &journal.edits {
            // An edit that fails here failed (or was skipped) in the copy as well, or refers
            // to something tracking no longer has: either way there is nothing to apply.
            let _: Result<(), MapError> = match *edit {
                MapEdit::CreateMapPoint {
                    id: copy_id,
                    position,
                    reference,
                } => self.create_map_point(position, reference).map(|new| {
                    renamed.insert(copy_id, new);
                }),
                MapEdit::SetKeyFramePose { kf, T_c_w } => self.set_keyframe_pose(kf, T_c_w),
                MapEdit::SetMapPointPosition { mp, p_w } => {
                    self.set_map_point_position(id(mp, renamed), p_w)
                }
                MapEdit::IncreaseVisible { mp, n } => self.increase_visible(id(mp, renamed), n),
                MapEdit::IncreaseFound { mp, n } => self.increase_found(id(mp, renamed), n),
                MapEdit::IncreaseVisibleMany { ref mps } => {
                    let mps: Vec<MapPointId> = mps.iter().map(|&m| id(m, renamed)).collect();
                    self.increase_visible_many(&mps)
                }
                MapEdit::IncreaseFoundMany { ref mps } => {
                    let mps: Vec<MapPointId> = mps.iter().map(|&m| id(m, renamed)).collect();
                    self.increase_found_many(&mps)
                }
                MapEdit::AddObservation { mp, kf, index } => {
                    self.add_observation(id(mp, renamed), kf, index)
                }
                MapEdit::EraseObservation { mp, kf } => {
                    self.erase_observation(id(mp, renamed), kf);
                    Ok(())
                }
                MapEdit::SetMapPointBad { mp } => {
                    self.set_map_point_bad(id(mp, renamed));
                    Ok(())
                }
                MapEdit::ReplaceMapPoint { old, new } => {
                    self.replace_map_point(id(old, renamed), id(new, renamed))
                }
                MapEdit::UpdateNormalAndDepth { mp } => {
                    self.update_normal_and_depth(id(mp, renamed))
                }
                MapEdit::ComputeDistinctiveDescriptor { mp } => {
                    self.compute_distinctive_descriptor(id(mp, renamed))
                }
                MapEdit::UpdateConnections { kf } => self.update_connections(kf),
                MapEdit::AddLoopEdge { a, b } => self.add_loop_edge(a, b),
                MapEdit::SetKeyFrameBad { kf } => {
                    self.set_keyframe_bad(kf);
                    Ok(())
                }
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{map_with_keyframes, observe_all};
    use nalgebra::Vector3;

    /// Mapping edits a copy while tracking inserts a keyframe into the original; replaying the
    /// journal gives the original the copy's edits on top of its own.
    #[test]
    fn replayed_edits_combine_with_concurrent_insertions() {
        let (mut map, kfs) = map_with_keyframes(5, 20);
        let shared = observe_all(&mut map, &kfs[..3], 1);
        let doomed = observe_all(&mut map, &kfs[..3], 3);
        let fused = observe_all(&mut map, &kfs[3..], 1);
        for &kf in &kfs {
            map.update_connections(kf).unwrap();
        }

        let mut copy = map.clone();
        copy.begin_journal();
        let new = copy
            .create_map_point(Vector3::new(1.0, 2.0, 6.0), kfs[0])
            .unwrap();
        copy.add_observation(new, kfs[0], 5).unwrap();
        copy.add_observation(new, kfs[1], 5).unwrap();
        copy.update_normal_and_depth(new).unwrap();
        copy.set_map_point_position(shared, Vector3::new(0.1, 0.0, 5.0))
            .unwrap();
        let pose = Isometry3::translation(0.5, 0.0, 0.0);
        copy.set_keyframe_pose(kfs[2], pose).unwrap();
        copy.set_map_point_bad(doomed);
        copy.replace_map_point(fused, shared).unwrap();
        copy.update_connections(kfs[0]).unwrap();
        copy.add_loop_edge(kfs[0], kfs[4]).unwrap();
        let journal = copy.take_journal();
        // Nested operations (normal updates inside replace, erasures inside set-bad) are not
        // recorded on their own.
        assert_eq!(journal.len(), 10);

        // Meanwhile tracking adds a keyframe with a new point of its own.
        let tracking_kf = map.insert_keyframe(
            9.0,
            9,
            Isometry3::identity(),
            map.keyframe(kfs[1]).unwrap().features().clone(),
        );
        let tracking_point = map
            .create_map_point(Vector3::new(0.0, 1.0, 4.0), tracking_kf)
            .unwrap();
        map.add_observation(tracking_point, tracking_kf, 2).unwrap();
        map.add_observation(shared, tracking_kf, 7).unwrap();

        let renamed = map.apply_journal(&journal);
        let new_here = renamed[&new];
        assert_ne!(new_here, tracking_point);
        let p = map.map_point(new_here).unwrap();
        assert_eq!(p.position(), Vector3::new(1.0, 2.0, 6.0));
        assert_eq!(p.observations().len(), 2);
        assert_eq!(
            map.map_point(shared).unwrap().position(),
            Vector3::new(0.1, 0.0, 5.0)
        );
        assert_eq!(*map.keyframe(kfs[2]).unwrap().T_c_w(), pose);
        assert!(map.map_point(doomed).is_none());
        assert_eq!(map.resolve_map_point(fused), Some(shared));
        // The fused point keeps tracking's observation as well as the copy's.
        assert!(map
            .map_point(shared)
            .unwrap()
            .observation(tracking_kf)
            .is_some());
        assert!(map.map_point(tracking_point).is_some());
        assert!(map.keyframe(kfs[0]).unwrap().loop_edges().contains(&kfs[4]));
        map.check_consistency().unwrap();
    }

    /// A journal replayed in the parts it was drained in does what the whole journal does,
    /// with points created in one part edited in the next.
    #[test]
    fn parts_replayed_in_order_equal_the_whole_journal() {
        let (mut map, kfs) = map_with_keyframes(3, 10);
        let old = observe_all(&mut map, &kfs[..2], 1);
        let record = |drain: bool| {
            let mut copy = map.clone();
            copy.begin_journal();
            let new = copy
                .create_map_point(Vector3::new(1.0, 2.0, 6.0), kfs[0])
                .unwrap();
            copy.add_observation(new, kfs[0], 5).unwrap();
            let first = drain.then(|| copy.drain_journal());
            copy.add_observation(new, kfs[1], 5).unwrap();
            copy.set_map_point_position(new, Vector3::new(1.0, 2.0, 7.0))
                .unwrap();
            copy.replace_map_point(old, new).unwrap();
            (
                new,
                first
                    .into_iter()
                    .chain([copy.take_journal()])
                    .collect::<Vec<_>>(),
            )
        };
        let (new, whole) = record(false);
        let (_, parts) = record(true);
        assert_eq!((whole.len(), parts.len()), (1, 2));
        assert_eq!((parts[0].len(), parts[1].len()), (2, 3));

        let mut by_parts = map.clone();
        let mut renamed = HashMap::new();
        for part in &parts {
            by_parts.apply_journal_part(part, &mut renamed);
        }
        let renamed_whole = map.apply_journal(&whole[0]);
        assert_eq!(renamed, renamed_whole);
        let (a, b) = (
            map.map_point(renamed[&new]).unwrap(),
            by_parts.map_point(renamed[&new]).unwrap(),
        );
        assert_eq!(a.position(), Vector3::new(1.0, 2.0, 7.0));
        assert_eq!(a.position(), b.position());
        assert_eq!(a.observations(), b.observations());
        assert_eq!(a.observations().len(), 2);
        assert!(by_parts.map_point(old).is_none());
        by_parts.check_consistency().unwrap();
    }

    /// A batched counter is one journal entry per call; replayed on the original it gives the
    /// counters the copy got by applying it, with the copy's new points renamed and points
    /// culled meanwhile skipped without stopping the rest of the list.
    #[test]
    fn batched_counters_replay_as_applied() {
        let (mut map, kfs) = map_with_keyframes(3, 10);
        let a = observe_all(&mut map, &kfs[..2], 1);
        let b = observe_all(&mut map, &kfs[1..], 2);
        let culled = observe_all(&mut map, &kfs[..1], 3);
        let mut copy = map.clone();
        copy.begin_journal();
        let new = copy
            .create_map_point(Vector3::new(1.0, 2.0, 6.0), kfs[0])
            .unwrap();
        copy.add_observation(new, kfs[0], 5).unwrap();
        copy.increase_visible_many(&[a, culled, b, new, a]).unwrap();
        copy.increase_found_many(&[b, new, culled]).unwrap();
        let journal = copy.take_journal();
        assert_eq!(journal.len(), 4);

        map.set_map_point_bad(culled);
        let renamed = map.apply_journal(&journal);
        for (here, there) in [(a, a), (b, b), (renamed[&new], new)] {
            let (p, q) = (map.map_point(here).unwrap(), copy.map_point(there).unwrap());
            assert_eq!((p.visible(), p.found()), (q.visible(), q.found()));
        }
        // Counters start at 1; `a` was listed twice.
        let p = map.map_point(a).unwrap();
        assert_eq!((p.visible(), p.found()), (3, 1));
        map.check_consistency().unwrap();
    }

    /// The batched counters do what one call per point does, and an unknown point is
    /// reported without keeping the others from being counted.
    #[test]
    fn batched_counters_equal_one_call_per_point() {
        let (mut map, kfs) = map_with_keyframes(2, 6);
        let points: Vec<MapPointId> = (0..4).map(|i| observe_all(&mut map, &kfs, i)).collect();
        let mut one_by_one = map.clone();
        let listed = [points[0], points[2], points[2], points[3]];
        for &m in &listed {
            one_by_one.increase_visible(m, 1).unwrap();
            one_by_one.increase_found(m, 1).unwrap();
        }
        map.increase_visible_many(&listed).unwrap();
        map.increase_found_many(&listed).unwrap();
        for &m in &points {
            let (p, q) = (map.map_point(m).unwrap(), one_by_one.map_point(m).unwrap());
            assert_eq!((p.visible(), p.found()), (q.visible(), q.found()));
        }
        let unknown = MapPointId(999);
        assert_eq!(
            map.increase_visible_many(&[unknown, points[1]]),
            Err(MapError::UnknownMapPoint(unknown))
        );
        assert_eq!(map.map_point(points[1]).unwrap().visible(), 2);
    }

    #[test]
    fn without_begin_nothing_is_recorded() {
        let (mut map, kfs) = map_with_keyframes(2, 4);
        observe_all(&mut map, &kfs, 0);
        assert!(map.take_journal().is_empty());
    }
}
