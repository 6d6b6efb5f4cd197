//! Whole-map operations for an atlas of several maps: moving a map into another world frame
//! by a similarity, renumbering its ids, and moving all of it into another map.
//!
//! Map merging (loop closing, outside this crate) aligns one map to another with a Sim(3),
//! moves it in, and then fuses duplicates and adds links. Ids are unique within a run, but
//! maps loaded from files may collide, hence [`Map::shift_ids`]. None of these is recorded in
//! the journal (a concurrent copy could not replay them), so they refuse while recording.

use ferroslam_geometry::sim3::Sim3;

use super::{CulledKeyFrame, Map};
use crate::{KeyFrameId, MapError, MapPointId};

#[allow(non_snake_case)]
impl Map {
    /// Moves the whole map into another world frame: every point `p -> S_new_old p`, and
    /// every keyframe gets the rigid pose with the same projections (its centre moves as a
    /// point, camera-frame coordinates scale by `s`). Culled keyframes' relative poses scale
    /// alike; normals and distance ranges are recomputed.
    ///
    /// # Errors
    /// [`MapError::Recording`] while recording a journal, [`MapError::InvalidArgument`] for a
    /// scale not positive and finite or a non-finite rotation / translation. The map is
    /// unchanged on error.
    pub fn transform_world(&mut self, S_new_old: &Sim3) -> Result<(), MapError> {
        self.refuse_while_recording("transform_world")?;
        let s = S_new_old.scale;
        if !(s.is_finite() && s > 0.0) {
            return Err(MapError::InvalidArgument(format!(
                "transform_world: similarity scale {s} must be positive and finite"
            )));
        }
        let finite = S_new_old.translation.iter().all(|v| v.is_finite())
            && S_new_old.rotation.coords.iter().all(|v| v.is_finite());
        if !finite {
            return Err(MapError::InvalidArgument(format!(
                "transform_world: similarity {S_new_old:?} is not finite"
            )));
        }

        let S_old_new = S_new_old.inverse();
        let ids: Vec<KeyFrameId> = self.keyframes.keys().copied().collect();
        for kf in ids {
            let frame = self.keyframe_mut(kf)?;
            // S_c_new p_new = p_c_old; dividing out its scale 1/s gives s * p_c_old.
            frame.T_c_w = (Sim3::from_isometry(&frame.T_c_w) * S_old_new).to_isometry_unscaled();
        }
        let culled: Vec<KeyFrameId> = self.culled_keyframes.keys().copied().collect();
        for kf in culled {
            if let Some(c) = self.culled_keyframes.get_mut(&kf) {
                c.T_c_a.translation.vector *= s;
            }
        }
        let points = self.map_point_ids();
        for &mp in &points {
            let point = self.map_point_mut(mp)?;
            point.position = S_new_old.transform_point(&point.position);
        }
        for mp in points {
            self.update_normal_and_depth(mp)?;
        }
        Ok(())
    }

    /// The ids the next [`Map::insert_keyframe`] / [`Map::create_map_point`] would get.
    pub fn next_ids(&self) -> (KeyFrameId, MapPointId) {
        (
            KeyFrameId(self.next_keyframe),
            MapPointId(self.next_map_point),
        )
    }

    /// Raises the id counters to at least `next` (never lowers them), so that a map started
    /// after a loaded one allocates ids disjoint from it.
    pub fn reserve_ids(&mut self, next: (KeyFrameId, MapPointId)) {
        self.next_keyframe = self.next_keyframe.max(next.0 .0);
        self.next_map_point = self.next_map_point.max(next.1 .0);
    }

    /// Renumbers every keyframe id `k -> k + keyframe_offset` and point id
    /// `m -> m + point_offset`, everywhere they appear (tables, slots, graphs, tombstones,
    /// origin, counters).
    ///
    /// # Errors
    /// [`MapError::Recording`] while recording, [`MapError::IdOverflow`] if an id (or the
    /// counter) would pass `u32::MAX`. The map is unchanged on error.
    pub fn shift_ids(&mut self, keyframe_offset: u32, point_offset: u32) -> Result<(), MapError> {
        self.refuse_while_recording("shift_ids")?;
        // Every id is below its counter, so checking the counters covers all of them.
        let overflow = |what, next: u32, offset| MapError::IdOverflow { what, next, offset };
        let next_keyframe = self
            .next_keyframe
            .checked_add(keyframe_offset)
            .ok_or(overflow("keyframe", self.next_keyframe, keyframe_offset))?;
        let next_map_point = self
            .next_map_point
            .checked_add(point_offset)
            .ok_or(overflow("map point", self.next_map_point, point_offset))?;
        if (keyframe_offset, point_offset) == (0, 0) {
            return Ok(());
        }
        let k = |id: KeyFrameId| KeyFrameId(id.0 + keyframe_offset);
        let m = |id: MapPointId| MapPointId(id.0 + point_offset);

        let keyframes = std::mem::take(&mut self.keyframes);
        self.keyframes = keyframes
            .into_entries()
            .map(|(id, mut f)| {
                f.id = k(id);
                f.map_points
                    .iter_mut()
                    .flatten()
                    .for_each(|mp| *mp = m(*mp));
                f.covisibility = f.covisibility.into_iter().map(|(o, w)| (k(o), w)).collect();
                f.chosen = f.chosen.into_iter().map(k).collect();
                f.parent = f.parent.map(k);
                f.children = f.children.into_iter().map(k).collect();
                f.loop_edges = f.loop_edges.into_iter().map(k).collect();
                (f.id, f)
            })
            .collect();
        let points = std::mem::take(&mut self.map_points);
        self.map_points = points
            .into_entries()
            .map(|(id, mut p)| {
                p.id = m(id);
                p.observations = p.observations.into_iter().map(|(o, i)| (k(o), i)).collect();
                p.reference = k(p.reference);
                p.first_keyframe = k(p.first_keyframe);
                (p.id, p)
            })
            .collect();
        let culled = std::mem::take(&mut self.culled_keyframes);
        self.culled_keyframes = culled
            .into_entries()
            .map(|(id, c)| {
                let anchor = k(c.anchor);
                (k(id), CulledKeyFrame { anchor, ..c })
            })
            .collect();
        let replaced = std::mem::take(&mut self.replaced_points);
        self.replaced_points = replaced
            .into_entries()
            .map(|(old, new)| (m(old), m(new)))
            .collect();
        self.origin = self.origin.map(k);
        self.next_keyframe = next_keyframe;
        self.next_map_point = next_map_point;
        Ok(())
    }

    /// Moves every keyframe, point and tombstone of `other` (already in this map's world
    /// frame, see [`Map::transform_world`]) into this map. `other`'s spanning tree is re-rooted
    /// at `link.0` (one of its keyframes), which becomes a child of `link.1` (one of ours), so
    /// the merged tree keeps our origin as its root. No covisibility is created between the
    /// parts; our origin and rig stay; the id counters become the larger of both. Keyframes of
    /// `other` not yet connected (no parent, not its origin) stay so.
    ///
    /// # Errors
    /// The map is unchanged on error:
    /// - [`MapError::Recording`] if either map is recording a journal;
    /// - [`MapError::PyramidMismatch`] if the scale pyramids differ;
    /// - [`MapError::UnknownKeyFrame`] if `link.0` is not a keyframe of `other` or `link.1`
    ///   not one of ours;
    /// - [`MapError::NotInSpanningTree`] if `link.0` does not reach `other`'s origin;
    /// - [`MapError::KeyFrameIdCollision`] / [`MapError::MapPointIdCollision`] for the lowest
    ///   id (live or tombstone) both maps hold.
    pub fn absorb(
        &mut self,
        mut other: Map,
        link: (KeyFrameId, KeyFrameId),
    ) -> Result<(), MapError> {
        self.refuse_while_recording("absorb")?;
        other.refuse_while_recording("absorb (the absorbed map)")?;
        let (ours, theirs) = (&self.pyramid, &other.pyramid);
        if ours.n_levels != theirs.n_levels || ours.scale_factor != theirs.scale_factor {
            return Err(MapError::PyramidMismatch {
                ours_levels: ours.n_levels,
                ours_factor: ours.scale_factor,
                theirs_levels: theirs.n_levels,
                theirs_factor: theirs.scale_factor,
            });
        }
        if !other.keyframes.contains_key(&link.0) {
            return Err(MapError::UnknownKeyFrame(link.0));
        }
        if !self.keyframes.contains_key(&link.1) {
            return Err(MapError::UnknownKeyFrame(link.1));
        }
        let path = other.path_to_root(link.0);
        if let Some(origin) = other.origin.filter(|o| path.last() != Some(o)) {
            return Err(MapError::NotInSpanningTree { kf: link.0, origin });
        }
        self.check_disjoint(&other)?;

        // Reverse the path: each keyframe on it becomes the parent of its old parent.
        for pair in path.windows(2) {
            let (child, parent) = (pair[0], pair[1]);
            if let Some(p) = other.keyframes.get_mut(&parent) {
                p.children.remove(&child);
                p.parent = Some(child);
            }
            if let Some(c) = other.keyframes.get_mut(&child) {
                c.children.insert(parent);
            }
        }
        if let Some(frame) = other.keyframes.get_mut(&link.0) {
            frame.parent = Some(link.1);
        }
        self.keyframe_mut(link.1)?.children.insert(link.0);

        self.keyframes.append(other.keyframes);
        self.map_points.append(other.map_points);
        self.culled_keyframes.append(other.culled_keyframes);
        self.replaced_points.append(other.replaced_points);
        self.reserve_ids((
            KeyFrameId(other.next_keyframe),
            MapPointId(other.next_map_point),
        ));
        Ok(())
    }

    /// `kf` and its ancestors up to the root of its tree, in that order.
    fn path_to_root(&self, kf: KeyFrameId) -> Vec<KeyFrameId> {
        let mut path = vec![kf];
        let mut current = kf;
        // The length bound only guards against a (never expected) cycle.
        while let Some(parent) = self.keyframes.get(&current).and_then(|f| f.parent) {
            if path.len() > self.keyframes.len() {
                break;
            }
            path.push(parent);
            current = parent;
        }
        path
    }

    /// The lowest keyframe / point id (live or tombstone) held by both maps, as an error.
    fn check_disjoint(&self, other: &Map) -> Result<(), MapError> {
        let ours_kf = |id: &KeyFrameId| {
            self.keyframes.contains_key(id) || self.culled_keyframes.contains_key(id)
        };
        let mut kfs: Vec<KeyFrameId> = other.keyframes.keys().copied().collect();
        kfs.extend(other.culled_keyframes.keys().copied());
        if let Some(id) = kfs.into_iter().filter(ours_kf).min() {
            return Err(MapError::KeyFrameIdCollision(id));
        }
        let ours_mp = |id: &MapPointId| {
            self.map_points.contains_key(id) || self.replaced_points.contains_key(id)
        };
        let mut mps: Vec<MapPointId> = other.map_points.keys().copied().collect();
        mps.extend(other.replaced_points.keys().copied());
        if let Some(id) = mps.into_iter().filter(ours_mp).min() {
            return Err(MapError::MapPointIdCollision(id));
        }
        Ok(())
    }

    fn refuse_while_recording(&self, operation: &'static str) -> Result<(), MapError> {
        match self.recorder {
            Some(_) => Err(MapError::Recording(operation)),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use ferroslam_features::{ImageBounds, Keypoint, ScalePyramid};
    use ferroslam_geometry::sim3::Sim3;
    use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

    use crate::test_support::map_with_keyframes;
    use crate::{FrameFeatures, KeyFrameId, Map, MapError, MapPointId};

    /// Five keyframes, points seen by three consecutive ones, a culled keyframe (2), a fused
    /// point and a loop edge: every table and link `shift_ids` / `absorb` must carry.
    fn fixture() -> (Map, Vec<KeyFrameId>) {
        let (mut map, kfs) = map_with_keyframes(5, 60);
        // Observed keyframe by keyframe, connecting each as it comes (as tracking does), so
        // that every parent is an earlier keyframe and the tree is rooted at the origin.
        let mut points = [None; 60];
        for (j, &kf) in kfs.iter().enumerate() {
            for (i, point) in points.iter_mut().enumerate() {
                let first = i % 3;
                if j == first {
                    let p = Vector3::new(
                        (i % 5) as f64 * 0.7 - 1.0,
                        (i % 3) as f64 * 0.4 - 0.4,
                        4.0 + (i % 7) as f64,
                    );
                    *point = Some(map.create_map_point(p, kf).unwrap());
                }
                if let Some(mp) = point.filter(|_| j < first + 3) {
                    map.add_observation(mp, kf, i).unwrap();
                }
            }
            if j > 0 {
                map.update_connections(kf).unwrap();
            }
        }
        assert!(map.set_keyframe_bad(kfs[2]));
        let live = map.map_point_ids();
        map.replace_map_point(live[0], live[1]).unwrap();
        map.add_loop_edge(kfs[0], kfs[4]).unwrap();
        for mp in map.map_point_ids() {
            map.update_normal_and_depth(mp).unwrap();
        }
        map.check_consistency().unwrap();
        (map, kfs)
    }

    fn pixel(p_c: &Vector3<f64>) -> (f64, f64) {
        (500.0 * p_c.x / p_c.z + 320.0, 500.0 * p_c.y / p_c.z + 240.0)
    }

    /// Camera-frame coordinates of every observation, by (point, keyframe).
    #[allow(non_snake_case)]
    fn observed(map: &Map) -> Vec<(MapPointId, KeyFrameId, Vector3<f64>)> {
        let mut out = Vec::new();
        for p in map.map_points() {
            for &kf in p.observations().keys() {
                let T_c_w = map.keyframe(kf).unwrap().T_c_w();
                out.push((p.id(), kf, (T_c_w * Point3::from(p.position())).coords));
            }
        }
        out
    }

    #[test]
    #[allow(non_snake_case)]
    fn transform_world_keeps_every_projection_and_scales_depth() {
        for s in [1.0, 2.5] {
            let (mut map, kfs) = fixture();
            let S = Sim3 {
                rotation: UnitQuaternion::from_euler_angles(0.3, -0.2, 0.9),
                translation: Vector3::new(1.5, -2.0, 0.25),
                scale: s,
            };
            let before = observed(&map);
            let old_points: Vec<_> = map.map_points().cloned().collect();
            let culled_pose = map.resolve_keyframe_pose(kfs[2]).unwrap();
            map.transform_world(&S).unwrap();
            map.check_consistency().unwrap();

            let after = observed(&map);
            assert_eq!(after.len(), before.len());
            for ((mp, kf, old), (mp2, kf2, new)) in before.iter().zip(&after) {
                assert_eq!((mp, kf), (mp2, kf2));
                assert!((new - old * s).norm() < 1e-9, "{mp} in {kf}");
                assert!((new.normalize() - old.normalize()).norm() < 1e-12);
                let (u0, v0) = pixel(old);
                let (u1, v1) = pixel(new);
                assert!((u0 - u1).abs() < 1e-9 && (v0 - v1).abs() < 1e-9);
            }
            for old in &old_points {
                let new = map.map_point(old.id()).unwrap();
                let moved = S.transform_point(&old.position());
                assert!((new.position() - moved).norm() < 1e-12);
                assert!((new.normal() - S.rotation * old.normal()).norm() < 1e-9);
                assert!((new.max_distance() - s * old.max_distance()).abs() < 1e-9);
                assert!((new.min_distance() - s * old.min_distance()).abs() < 1e-9);
            }
            // The culled keyframe, placed through its anchor, sees points as before.
            let p_old = old_points[0].position();
            let p_new = S.transform_point(&p_old);
            let seen_old = culled_pose * Point3::from(p_old);
            let seen_new = map.resolve_keyframe_pose(kfs[2]).unwrap() * Point3::from(p_new);
            assert!((seen_new.coords - seen_old.coords * s).norm() < 1e-9);
        }
    }

    #[test]
    #[allow(non_snake_case)]
    fn transform_world_refuses_bad_scales_and_recording() {
        let (mut map, _) = fixture();
        for scale in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let S = Sim3 {
                scale,
                ..Sim3::identity()
            };
            assert!(matches!(
                map.transform_world(&S),
                Err(MapError::InvalidArgument(_))
            ));
        }
        let before = map.map_points().next().unwrap().position();
        map.begin_journal();
        assert_eq!(
            map.transform_world(&Sim3::identity()),
            Err(MapError::Recording("transform_world"))
        );
        assert_eq!(map.map_points().next().unwrap().position(), before);
    }

    #[test]
    fn next_and_reserved_ids() {
        let (mut map, _) = fixture();
        let (kf, mp) = map.next_ids();
        assert_eq!(kf, KeyFrameId(5));
        map.reserve_ids((KeyFrameId(2), MapPointId(mp.0 + 10)));
        assert_eq!(map.next_ids(), (kf, MapPointId(mp.0 + 10)));
        let features = one_keypoint();
        let id = map.insert_keyframe(9.0, 9, Isometry3::identity(), features);
        assert_eq!(id, kf);
    }

    #[test]
    fn shifted_ids_are_found_everywhere() {
        let (original, kfs) = fixture();
        let mut map = original.clone();
        map.shift_ids(100, 1000).unwrap();
        map.check_consistency().unwrap();
        let k = |id: KeyFrameId| KeyFrameId(id.0 + 100);
        let m = |id: MapPointId| MapPointId(id.0 + 1000);
        assert_eq!(map.origin(), original.origin().map(k));
        let (nk, nm) = original.next_ids();
        assert_eq!(map.next_ids(), (k(nk), m(nm)));
        for old in original.keyframes() {
            let new = map.keyframe(k(old.id())).unwrap();
            assert_eq!(new.id(), k(old.id()));
            let slots: Vec<_> = old.map_points().iter().map(|s| s.map(m)).collect();
            assert_eq!(new.map_points(), &slots[..]);
            let covis: Vec<_> = old
                .covisibles()
                .into_iter()
                .map(|(o, w)| (k(o), w))
                .collect();
            assert_eq!(new.covisibles(), covis);
            assert_eq!(new.parent(), old.parent().map(k));
            let shifted = |set: &std::collections::BTreeSet<KeyFrameId>| -> Vec<_> {
                set.iter().map(|&c| k(c)).collect()
            };
            assert!(new.children().iter().copied().eq(shifted(old.children())));
            assert!(new
                .loop_edges()
                .iter()
                .copied()
                .eq(shifted(old.loop_edges())));
        }
        for old in original.map_points() {
            let new = map.map_point(m(old.id())).unwrap();
            assert_eq!(new.id(), m(old.id()));
            assert_eq!(new.reference_keyframe(), k(old.reference_keyframe()));
            assert_eq!(new.first_keyframe(), k(old.first_keyframe()));
            let obs: Vec<_> = old
                .observations()
                .iter()
                .map(|(&o, &i)| (k(o), i))
                .collect();
            assert!(new.observations().iter().map(|(&o, &i)| (o, i)).eq(obs));
        }
        // Tombstones: the culled keyframe and the fused point.
        assert_eq!(
            map.resolve_keyframe_pose(k(kfs[2])),
            original.resolve_keyframe_pose(kfs[2])
        );
        let fused = original.replaced_points.keys().next().copied().unwrap();
        assert_eq!(
            map.resolve_map_point(m(fused)),
            original.resolve_map_point(fused).map(m)
        );
        assert!(map.keyframe(kfs[0]).is_none());
    }

    #[test]
    fn shift_ids_refuses_overflow_and_recording() {
        let (mut map, _) = fixture();
        let ids = (map.keyframe_ids(), map.map_point_ids(), map.next_ids());
        assert!(matches!(
            map.shift_ids(u32::MAX - 2, 0),
            Err(MapError::IdOverflow {
                what: "keyframe",
                ..
            })
        ));
        assert!(matches!(
            map.shift_ids(0, u32::MAX),
            Err(MapError::IdOverflow {
                what: "map point",
                ..
            })
        ));
        map.begin_journal();
        assert_eq!(map.shift_ids(1, 1), Err(MapError::Recording("shift_ids")));
        assert_eq!(
            (map.keyframe_ids(), map.map_point_ids(), map.next_ids()),
            ids
        );
    }

    /// A map of two maps: `b` shifted past `a`, linked b's keyframe 3 -> a's keyframe 1.
    fn merged() -> (Map, Map, Map, (KeyFrameId, KeyFrameId)) {
        let (a, a_kfs) = fixture();
        let (mut b, b_kfs) = fixture();
        let (nk, nm) = a.next_ids();
        b.shift_ids(nk.0, nm.0).unwrap();
        let link = (KeyFrameId(b_kfs[3].0 + nk.0), a_kfs[1]);
        let mut map = a.clone();
        map.absorb(b.clone(), link).unwrap();
        (map, a, b, link)
    }

    #[test]
    fn absorb_makes_one_tree_rooted_at_our_origin() {
        let (map, a, b, link) = merged();
        map.check_consistency().unwrap();
        assert_eq!(map.origin(), a.origin());
        assert_eq!(map.keyframe(link.0).unwrap().parent(), Some(link.1));
        assert!(map.keyframe(link.1).unwrap().children().contains(&link.0));
        // The path to b's old root was reversed: that root now has a parent.
        let b_root = b.origin().unwrap();
        assert_ne!(b_root, link.0);
        assert!(map.keyframe(b_root).unwrap().parent().is_some());
        let origin = map.origin().unwrap();
        for kf in map.keyframe_ids() {
            let mut current = kf;
            let mut steps = 0;
            while let Some(parent) = map.keyframe(current).unwrap().parent() {
                current = parent;
                steps += 1;
                assert!(steps <= map.num_keyframes(), "cycle through {kf}");
            }
            assert_eq!(current, origin, "{kf} does not reach the origin");
        }
        let mut kfs = a.keyframe_ids();
        kfs.extend(b.keyframe_ids());
        assert_eq!(map.keyframe_ids(), kfs);
        let mut mps = a.map_point_ids();
        mps.extend(b.map_point_ids());
        assert_eq!(map.map_point_ids(), mps);
        assert_eq!(map.next_ids(), b.next_ids());
        // Both culled keyframes and fused points survive, no edge joins the parts.
        for id in [KeyFrameId(2), KeyFrameId(2 + a.next_ids().0 .0)] {
            assert!(map.resolve_keyframe_pose(id).is_some());
        }
        assert_eq!(map.replaced_points.len(), 2);
        for f in map.keyframes() {
            let ours = a.keyframe(f.id()).is_some();
            assert!(f
                .covisibles()
                .iter()
                .all(|(o, _)| a.keyframe(*o).is_some() == ours));
        }
    }

    #[test]
    fn an_absorbed_map_round_trips_through_a_file() {
        let (map, _, _, _) = merged();
        let path =
            std::env::temp_dir().join(format!("ferroslam-map-absorb-{}.fslam", std::process::id()));
        map.save_to_path(&path).unwrap();
        let loaded = Map::load_from_path(&path);
        std::fs::remove_file(&path).unwrap();
        let loaded = loaded.unwrap();
        loaded.check_consistency().unwrap();
        assert_eq!(loaded.keyframe_ids(), map.keyframe_ids());
        assert_eq!(loaded.map_point_ids(), map.map_point_ids());
        assert_eq!(loaded.next_ids(), map.next_ids());
        assert_eq!(loaded.origin(), map.origin());
    }

    fn one_keypoint() -> FrameFeatures {
        let kp = Keypoint {
            x: 320.0,
            y: 240.0,
            octave: 0,
            angle_deg: 0.0,
            response: 1.0,
        };
        let bounds = ImageBounds {
            min_x: 0.0,
            max_x: 640.0,
            min_y: 0.0,
            max_y: 480.0,
        };
        FrameFeatures::new(vec![kp], vec![[0; 32]], vec![], vec![], bounds).unwrap()
    }

    #[test]
    fn failed_absorbs_leave_the_map_unchanged() {
        let (a, a_kfs) = fixture();
        let snapshot = |m: &Map| (m.keyframe_ids(), m.map_point_ids(), m.next_ids());
        let expect = snapshot(&a);
        let children = a.keyframe(a_kfs[1]).unwrap().children().clone();
        let (nk, nm) = a.next_ids();
        let shifted = || {
            let (mut b, _) = fixture();
            b.shift_ids(nk.0, nm.0).unwrap();
            b
        };
        let b_kf = KeyFrameId(nk.0 + 1);

        let mut map = a.clone();
        let (b, _) = fixture();
        assert_eq!(
            map.absorb(b, (KeyFrameId(1), a_kfs[1])),
            Err(MapError::KeyFrameIdCollision(KeyFrameId(0)))
        );
        // Point 0 was culled (no tombstone), the lowest id held is live or fused.
        let replaced = a.replaced_points.keys().copied();
        let first_point = a.map_point_ids().into_iter().chain(replaced).min();
        let first_point = first_point.unwrap();
        let (mut b, _) = fixture();
        b.shift_ids(nk.0, 0).unwrap();
        assert_eq!(
            map.absorb(b, (b_kf, a_kfs[1])),
            Err(MapError::MapPointIdCollision(first_point))
        );
        assert_eq!(
            map.absorb(shifted(), (KeyFrameId(999), a_kfs[1])),
            Err(MapError::UnknownKeyFrame(KeyFrameId(999)))
        );
        assert_eq!(
            map.absorb(shifted(), (b_kf, a_kfs[2])),
            Err(MapError::UnknownKeyFrame(a_kfs[2]))
        );
        // A keyframe of the other map not yet connected to its tree.
        let mut b = shifted();
        let features = one_keypoint();
        let loose = b.insert_keyframe(9.0, 9, Isometry3::identity(), features);
        assert!(matches!(
            map.absorb(b, (loose, a_kfs[1])),
            Err(MapError::NotInSpanningTree { kf, .. }) if kf == loose
        ));
        // Another pyramid.
        let mut c = Map::new(ScalePyramid::new(1.3, 8).unwrap());
        c.reserve_ids((KeyFrameId(1000), MapPointId(1000)));
        let features = one_keypoint();
        let c_kf = c.insert_keyframe(0.0, 0, Isometry3::identity(), features);
        assert!(matches!(
            map.absorb(c, (c_kf, a_kfs[1])),
            Err(MapError::PyramidMismatch { .. })
        ));
        let mut recording = shifted();
        recording.begin_journal();
        assert_eq!(
            map.absorb(recording, (b_kf, a_kfs[1])),
            Err(MapError::Recording("absorb (the absorbed map)"))
        );
        map.begin_journal();
        assert_eq!(
            map.absorb(shifted(), (b_kf, a_kfs[1])),
            Err(MapError::Recording("absorb"))
        );
        assert!(map.take_journal().is_empty());

        assert_eq!(snapshot(&map), expect);
        assert_eq!(map.keyframe(a_kfs[1]).unwrap().children(), &children);
        map.check_consistency().unwrap();
        // And the same map absorbs the shifted one once asked properly.
        map.absorb(shifted(), (b_kf, a_kfs[1])).unwrap();
        map.check_consistency().unwrap();
    }
}
