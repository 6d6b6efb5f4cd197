//! Observations: the two-way link between a map point and a keypoint of a keyframe, and the
//! point removals that follow from it (erase, cull, fuse).
//!
//! Every link change also shifts the weights of existing covisibility edges, so edge
//! weights always equal the number of shared good points.

use super::journal::MapEdit;
use std::collections::BTreeMap;

use super::Map;
use crate::{KeyFrameId, MapError, MapPointId};

/// Covisibility weight changes accumulated over a compound operation and applied at its end,
/// so that an edge whose weight only dips transiently is not dropped.
#[derive(Default)]
struct EdgeShifts(BTreeMap<(KeyFrameId, KeyFrameId), i64>);

impl EdgeShifts {
    fn add(&mut self, kf: KeyFrameId, others: &[KeyFrameId], delta: i64) {
        for &other in others {
            *self.0.entry((kf.min(other), kf.max(other))).or_default() += delta;
        }
    }
}

impl Map {
    /// Links keypoint `index` of `kf` with `mp`, both ways (ORB-SLAM `AddObservation` +
    /// `AddMapPoint`); existing covisibility edges between `kf` and the point's other
    /// observers gain one shared point. A stereo/RGB-D keypoint (`u_right >= 0`) adds 2 to
    /// the point's `nObs`. A point without a colour takes the keypoint's
    /// ([`crate::MapPoint::color`]).
    ///
    /// # Errors
    /// Unknown ids, [`MapError::KeypointOutOfRange`], [`MapError::SlotOccupied`] (the keypoint
    /// already holds a point), [`MapError::AlreadyObserved`] (`kf` already sees `mp`).
    pub fn add_observation(
        &mut self,
        mp: MapPointId,
        kf: KeyFrameId,
        index: usize,
    ) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::AddObservation { mp, kf, index },
            |map| map.add_observation_now(mp, kf, index),
        )
    }

    /// The body of [`Map::add_observation`], run inside its journal entry.
    fn add_observation_now(
        &mut self,
        mp: MapPointId,
        kf: KeyFrameId,
        index: usize,
    ) -> Result<(), MapError> {
        let frame = self
            .keyframes
            .get(&kf)
            .ok_or(MapError::UnknownKeyFrame(kf))?;
        let point = self
            .map_points
            .get(&mp)
            .ok_or(MapError::UnknownMapPoint(mp))?;
        match frame.map_points.get(index) {
            None => {
                let len = frame.map_points.len();
                return Err(MapError::KeypointOutOfRange { kf, index, len });
            }
            Some(Some(existing)) => {
                return Err(MapError::SlotOccupied {
                    kf,
                    index,
                    existing: *existing,
                })
            }
            Some(None) => {}
        }
        if let Some(&existing) = point.observations.get(&kf) {
            return Err(MapError::AlreadyObserved {
                mp,
                kf,
                index: existing,
            });
        }
        let mut shifts = EdgeShifts::default();
        self.link(mp, kf, index, &mut shifts);
        self.apply(shifts);
        Ok(())
    }

    /// Unlinks `mp` and `kf` both ways (ORB-SLAM `EraseObservation` + `EraseMapPointMatch`).
    /// If the point's `nObs` falls to 2 or less it is culled everywhere, as ORB-SLAM.
    /// Returns `false` (and does nothing) if `kf` does not observe `mp`.
    pub fn erase_observation(&mut self, mp: MapPointId, kf: KeyFrameId) -> bool {
        self.journaled(
            || MapEdit::EraseObservation { mp, kf },
            |map| map.erase_observation_now(mp, kf),
        )
    }

    /// The body of [`Map::erase_observation`], run inside its journal entry.
    fn erase_observation_now(&mut self, mp: MapPointId, kf: KeyFrameId) -> bool {
        let mut shifts = EdgeShifts::default();
        if !self.unlink(mp, kf, &mut shifts) {
            return false;
        }
        self.apply(shifts);
        if self.map_points.get(&mp).is_some_and(|p| p.n_obs <= 2) {
            self.set_map_point_bad(mp);
        }
        true
    }

    /// Culls a point (ORB-SLAM `MapPoint::SetBadFlag`): erases all its observations and
    /// removes it from the map. Returns `false` if it was not in the map.
    pub fn set_map_point_bad(&mut self, mp: MapPointId) -> bool {
        self.journaled(
            || MapEdit::SetMapPointBad { mp },
            |map| map.set_map_point_bad_now(mp),
        )
    }

    /// The body of [`Map::set_map_point_bad`], run inside its journal entry.
    fn set_map_point_bad_now(&mut self, mp: MapPointId) -> bool {
        let Some(point) = self.map_points.get(&mp) else {
            return false;
        };
        let observers: Vec<KeyFrameId> = point.observations.keys().copied().collect();
        let mut shifts = EdgeShifts::default();
        for kf in observers {
            self.unlink(mp, kf, &mut shifts);
        }
        self.apply(shifts);
        self.map_points.remove(&mp);
        true
    }

    /// Fuses `old` into `new` (ORB-SLAM `MapPoint::Replace`): every keyframe observing `old`
    /// observes `new` through the same keypoint instead (or just drops `old` if it already
    /// sees `new`), the visible/found counters are added to `new`, its descriptor, normal and
    /// distances are recomputed, and `old` is removed ([`Map::resolve_map_point`] maps it to
    /// `new`). `old == new` is a no-op.
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`] for either id.
    pub fn replace_map_point(&mut self, old: MapPointId, new: MapPointId) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::ReplaceMapPoint { old, new },
            |map| map.replace_map_point_now(old, new),
        )
    }

    /// The body of [`Map::replace_map_point`], run inside its journal entry.
    fn replace_map_point_now(&mut self, old: MapPointId, new: MapPointId) -> Result<(), MapError> {
        if old == new {
            return Ok(());
        }
        let old_point = self
            .map_points
            .get(&old)
            .ok_or(MapError::UnknownMapPoint(old))?;
        let new_point = self
            .map_points
            .get(&new)
            .ok_or(MapError::UnknownMapPoint(new))?;
        let moved: Vec<(KeyFrameId, usize)> = old_point
            .observations
            .iter()
            .map(|(&k, &i)| (k, i))
            .collect();
        let (visible, found) = (old_point.visible, old_point.found);
        let already_seen: Vec<KeyFrameId> = new_point.observations.keys().copied().collect();

        let mut shifts = EdgeShifts::default();
        for (kf, index) in moved {
            self.unlink(old, kf, &mut shifts);
            if !already_seen.contains(&kf) {
                self.link(new, kf, index, &mut shifts);
            }
        }
        self.apply(shifts);
        self.map_points.remove(&old);
        self.replaced_points.insert(old, new);

        let point = self.map_point_mut(new)?;
        point.visible = point.visible.saturating_add(visible);
        point.found = point.found.saturating_add(found);
        self.compute_distinctive_descriptor(new)?;
        self.update_normal_and_depth(new)
    }

    /// Links without validation (callers checked ids, range and free slot); records the new
    /// shared points with the point's other observers.
    fn link(&mut self, mp: MapPointId, kf: KeyFrameId, index: usize, shifts: &mut EdgeShifts) {
        let weight = self.observation_weight(kf, index);
        let color = self
            .keyframes
            .get(&kf)
            .and_then(|f| f.features.color(index));
        let Some(point) = self.map_points.get_mut(&mp) else {
            return;
        };
        let others: Vec<KeyFrameId> = point.observations.keys().copied().collect();
        point.observations.insert(kf, index);
        point.n_obs += weight;
        point.color = point.color.or(color);
        // The creating keyframe is the preferred reference; otherwise any observer will do.
        if kf == point.first_keyframe || !point.observations.contains_key(&point.reference) {
            point.reference = kf;
        }
        if let Some(slot) = self
            .keyframes
            .get_mut(&kf)
            .and_then(|f| f.map_points.get_mut(index))
        {
            *slot = Some(mp);
        }
        shifts.add(kf, &others, 1);
    }

    /// Removes the observation of `mp` by `kf` both ways; returns whether there was one.
    fn unlink(&mut self, mp: MapPointId, kf: KeyFrameId, shifts: &mut EdgeShifts) -> bool {
        let Some(index) = self.map_points.get(&mp).and_then(|p| p.observation(kf)) else {
            return false;
        };
        let weight = self.observation_weight(kf, index);
        let Some(point) = self.map_points.get_mut(&mp) else {
            return false;
        };
        point.observations.remove(&kf);
        point.n_obs = point.n_obs.saturating_sub(weight);
        if point.reference == kf {
            if let Some(&first) = point.observations.keys().next() {
                point.reference = first;
            }
        }
        let others: Vec<KeyFrameId> = point.observations.keys().copied().collect();
        if let Some(slot) = self
            .keyframes
            .get_mut(&kf)
            .and_then(|f| f.map_points.get_mut(index))
        {
            *slot = None;
        }
        shifts.add(kf, &others, -1);
        true
    }

    /// ORB-SLAM's `nObs` increment of one observation: 2 for stereo/RGB-D keypoints.
    fn observation_weight(&self, kf: KeyFrameId, index: usize) -> usize {
        let stereo = self
            .keyframes
            .get(&kf)
            .is_some_and(|f| f.features.is_stereo(index));
        if stereo {
            2
        } else {
            1
        }
    }

    fn apply(&mut self, shifts: EdgeShifts) {
        for ((a, b), delta) in shifts.0 {
            self.shift_edge(a, b, delta);
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::test_support::{
        map_with_colored_keyframes, map_with_keyframes, observe_all, test_color,
    };
    use crate::{KeyFrameId, MapError, MapPointId};
    use nalgebra::Vector3;

    #[test]
    fn add_observation_links_both_ways_and_counts_stereo_twice() {
        let (mut map, kfs) = map_with_keyframes(2, 10);
        let mp = map
            .create_map_point(Vector3::new(0.0, 0.0, 5.0), kfs[0])
            .unwrap();
        map.add_observation(mp, kfs[0], 3).unwrap(); // stereo keypoint (odd index)
        map.add_observation(mp, kfs[1], 4).unwrap(); // monocular
        let point = map.map_point(mp).unwrap();
        assert_eq!(point.num_observations(), 3);
        assert_eq!(point.observation(kfs[1]), Some(4));
        assert_eq!(map.keyframe(kfs[0]).unwrap().map_point(3), Some(mp));
        map.check_consistency().unwrap();
    }

    #[test]
    fn a_point_takes_the_colour_of_its_first_coloured_observation() {
        let (mut map, kfs) = map_with_colored_keyframes(3, 10);
        let mp = observe_all(&mut map, &kfs, 5);
        assert_eq!(map.map_point(mp).unwrap().color(), Some(test_color(0, 5)));
        // Erasing the creating observation keeps the colour.
        assert!(map.erase_observation(mp, kfs[0]));
        assert_eq!(map.map_point(mp).unwrap().color(), Some(test_color(0, 5)));

        // Keyframes without colours give none, until a coloured one observes the point.
        let (mut plain, plain_kfs) = map_with_keyframes(1, 10);
        let kf = plain.insert_keyframe(
            1.0,
            1,
            nalgebra::Isometry3::identity(),
            map.keyframe(kfs[2]).unwrap().features().clone(),
        );
        let mp = plain
            .create_map_point(Vector3::new(0.0, 0.0, 5.0), plain_kfs[0])
            .unwrap();
        plain.add_observation(mp, plain_kfs[0], 6).unwrap();
        assert_eq!(plain.map_point(mp).unwrap().color(), None);
        plain.add_observation(mp, kf, 7).unwrap();
        assert_eq!(plain.map_point(mp).unwrap().color(), Some(test_color(2, 7)));
        plain.check_consistency().unwrap();
    }

    #[test]
    fn add_observation_rejects_bad_input() {
        let (mut map, kfs) = map_with_keyframes(2, 10);
        let mp = map.create_map_point(Vector3::zeros(), kfs[0]).unwrap();
        let other = map.create_map_point(Vector3::zeros(), kfs[0]).unwrap();
        map.add_observation(mp, kfs[0], 2).unwrap();
        assert!(matches!(
            map.add_observation(mp, kfs[0], 10),
            Err(MapError::KeypointOutOfRange { .. })
        ));
        assert!(matches!(
            map.add_observation(other, kfs[0], 2),
            Err(MapError::SlotOccupied { .. })
        ));
        assert!(matches!(
            map.add_observation(mp, kfs[0], 4),
            Err(MapError::AlreadyObserved { .. })
        ));
        assert_eq!(
            map.add_observation(MapPointId(99), kfs[0], 4),
            Err(MapError::UnknownMapPoint(MapPointId(99)))
        );
        assert_eq!(
            map.add_observation(mp, KeyFrameId(99), 4),
            Err(MapError::UnknownKeyFrame(KeyFrameId(99)))
        );
        map.check_consistency().unwrap();
    }

    #[test]
    fn erase_culls_point_when_nobs_reaches_two() {
        let (mut map, kfs) = map_with_keyframes(3, 10);
        // Monocular keypoints (even indices): nObs = 3.
        let mp = observe_all(&mut map, &kfs, 0);
        assert!(map.erase_observation(mp, kfs[2]));
        assert!(map.map_point(mp).is_none());
        for &kf in &kfs {
            assert_eq!(map.keyframe(kf).unwrap().map_point(0), None);
        }
        assert!(!map.erase_observation(mp, kfs[0]));
        map.check_consistency().unwrap();
    }

    #[test]
    fn erase_keeps_point_with_enough_observations_and_moves_reference() {
        let (mut map, kfs) = map_with_keyframes(4, 10);
        let mp = observe_all(&mut map, &kfs, 0);
        assert_eq!(map.map_point(mp).unwrap().reference_keyframe(), kfs[0]);
        assert!(map.erase_observation(mp, kfs[0]));
        let point = map.map_point(mp).unwrap();
        assert_eq!(point.num_observations(), 3);
        assert_eq!(point.reference_keyframe(), kfs[1]);
        assert_eq!(point.first_keyframe(), kfs[0]);
        map.check_consistency().unwrap();
    }

    #[test]
    fn replace_merges_observations_and_counters() {
        let (mut map, kfs) = map_with_keyframes(4, 10);
        let old = map
            .create_map_point(Vector3::new(0.0, 0.0, 4.0), kfs[0])
            .unwrap();
        let new = map
            .create_map_point(Vector3::new(0.0, 0.0, 4.0), kfs[1])
            .unwrap();
        map.add_observation(old, kfs[0], 0).unwrap();
        map.add_observation(old, kfs[1], 0).unwrap();
        map.add_observation(old, kfs[2], 0).unwrap();
        map.add_observation(new, kfs[1], 2).unwrap();
        map.add_observation(new, kfs[3], 2).unwrap();
        map.increase_visible(old, 4).unwrap();
        map.increase_found(old, 2).unwrap();

        map.replace_map_point(old, new).unwrap();
        assert!(map.map_point(old).is_none());
        assert_eq!(map.resolve_map_point(old), Some(new));
        let point = map.map_point(new).unwrap();
        let obs: Vec<_> = point.observations().iter().map(|(&k, &i)| (k, i)).collect();
        // kfs[1] already saw `new` through keypoint 2: its slot 0 is simply freed.
        assert_eq!(
            obs,
            vec![(kfs[0], 0), (kfs[1], 2), (kfs[2], 0), (kfs[3], 2)]
        );
        assert_eq!(map.keyframe(kfs[1]).unwrap().map_point(0), None);
        assert_eq!(map.keyframe(kfs[2]).unwrap().map_point(0), Some(new));
        assert_eq!((point.visible(), point.found()), (1 + 5, 1 + 3));
        map.check_consistency().unwrap();
    }

    #[test]
    fn replace_keeps_single_point_edges() {
        let (mut map, kfs) = map_with_keyframes(2, 10);
        let old = observe_all(&mut map, &kfs, 0);
        let new = map
            .create_map_point(Vector3::new(0.0, 0.0, 3.0), kfs[0])
            .unwrap();
        map.update_connections(kfs[1]).unwrap();
        assert_eq!(map.keyframe(kfs[0]).unwrap().weight(kfs[1]), 1);
        // The shared point changes identity but the pair still shares one point.
        map.replace_map_point(old, new).unwrap();
        assert_eq!(map.keyframe(kfs[0]).unwrap().weight(kfs[1]), 1);
        map.check_consistency().unwrap();
    }
}
