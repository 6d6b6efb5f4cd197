//! The spanning tree and keyframe culling (ORB-SLAM `KeyFrame::SetBadFlag`).

use super::journal::MapEdit;
use std::collections::BTreeSet;

use super::{CulledKeyFrame, Map};
use crate::{KeyFrameId, MapError};

impl Map {
    /// Records that `a` and `b` closed a loop (ORB-SLAM `AddLoopEdge`, both ways). Both keep
    /// the edge for the essential graph and are never culled afterwards.
    ///
    /// # Errors
    /// [`MapError::UnknownKeyFrame`] if either is not in the map.
    pub fn add_loop_edge(&mut self, a: KeyFrameId, b: KeyFrameId) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::AddLoopEdge { a, b },
            |map| map.add_loop_edge_now(a, b),
        )
    }

    /// The body of [`Map::add_loop_edge`], run inside its journal entry.
    fn add_loop_edge_now(&mut self, a: KeyFrameId, b: KeyFrameId) -> Result<(), MapError> {
        self.keyframe_mut(b)?;
        self.keyframe_mut(a)?.loop_edges.insert(b);
        self.keyframe_mut(b)?.loop_edges.insert(a);
        Ok(())
    }

    /// Culls a keyframe (ORB-SLAM `KeyFrame::SetBadFlag`): erases its observations (points
    /// whose `nObs` falls to 2 or less are culled too), removes its covisibility edges, and
    /// re-parents its children in the spanning tree. Children are adopted greedily, one at a
    /// time, by the candidate they are most covisible with, candidates being the culled
    /// keyframe's parent and the children already adopted; children covisible with no
    /// candidate go to the culled keyframe's parent (the origin if it had none).
    ///
    /// The keyframe's pose relative to its adopter stays available through
    /// [`Map::resolve_keyframe_pose`]. Returns `false`, doing nothing, for an unknown keyframe,
    /// for the origin and for keyframes with loop edges, which are never culled (ORB-SLAM
    /// `mbNotErase`: the essential graph needs both ends of every loop).
    pub fn set_keyframe_bad(&mut self, kf: KeyFrameId) -> bool {
        self.journaled(
            || MapEdit::SetKeyFrameBad { kf },
            |map| map.set_keyframe_bad_now(kf),
        )
    }

    /// The body of [`Map::set_keyframe_bad`], run inside its journal entry.
    fn set_keyframe_bad_now(&mut self, kf: KeyFrameId) -> bool {
        if self.origin == Some(kf) {
            return false;
        }
        let Some(frame) = self.keyframes.get(&kf) else {
            return false;
        };
        if !frame.loop_edges.is_empty() {
            return false;
        }
        let points: Vec<_> = frame.map_points.iter().flatten().copied().collect();
        for mp in points {
            self.erase_observation(mp, kf);
        }
        // Weights are exact, so no edge should survive the erasures; clear any anyway.
        let neighbours: Vec<_> = self.covisibles(kf).into_iter().map(|(k, _)| k).collect();
        for other in neighbours {
            self.remove_edge(kf, other);
        }

        let Some(frame) = self.keyframes.get(&kf) else {
            return false;
        };
        let parent = frame.parent;
        let mut orphans = frame.children.clone();
        self.adopt_children(parent, &mut orphans);
        let Some(adopter) = parent.or(self.origin) else {
            return false;
        };
        for child in orphans {
            self.set_parent(child, adopter);
        }
        if let Some(p) = parent.and_then(|p| self.keyframes.get_mut(&p)) {
            p.children.remove(&kf);
        }

        if let (Some(frame), Some(anchor)) =
            (self.keyframes.remove(&kf), self.keyframes.get(&adopter))
        {
            let t_c_a = frame.T_c_w * anchor.T_c_w.inverse();
            self.culled_keyframes.insert(
                kf,
                CulledKeyFrame {
                    anchor: adopter,
                    T_c_a: t_c_a,
                },
            );
        }
        true
    }

    /// ORB-SLAM's greedy re-parenting loop: repeatedly moves the (child, candidate) pair with
    /// the highest covisibility weight; adopted children become candidates themselves.
    /// Children left in `orphans` share no edge with any candidate.
    fn adopt_children(&mut self, parent: Option<KeyFrameId>, orphans: &mut BTreeSet<KeyFrameId>) {
        let mut candidates: BTreeSet<KeyFrameId> = parent.into_iter().collect();
        loop {
            let mut best: Option<(usize, KeyFrameId, KeyFrameId)> = None;
            for &child in orphans.iter() {
                for (other, weight) in self.covisibles(child) {
                    // Edge weights are positive, so 0 stands for "no best yet".
                    if candidates.contains(&other) && weight > best.map_or(0, |(w, _, _)| w) {
                        best = Some((weight, child, other));
                    }
                }
            }
            let Some((_, child, adopter)) = best else {
                return;
            };
            self.set_parent(child, adopter);
            candidates.insert(child);
            orphans.remove(&child);
        }
    }

    /// Makes `parent` the spanning-tree parent of `child`, detaching it from its old parent.
    pub(super) fn set_parent(&mut self, child: KeyFrameId, parent: KeyFrameId) {
        let old = self.keyframes.get(&child).and_then(|f| f.parent);
        if let Some(old) = old.and_then(|p| self.keyframes.get_mut(&p)) {
            old.children.remove(&child);
        }
        if let Some(frame) = self.keyframes.get_mut(&parent) {
            frame.children.insert(child);
        }
        if let Some(frame) = self.keyframes.get_mut(&child) {
            frame.parent = Some(parent);
        }
    }

    /// True if `ancestor` is `kf` or lies on `kf`'s parent chain.
    pub(super) fn is_descendant(&self, kf: KeyFrameId, ancestor: KeyFrameId) -> bool {
        let mut current = Some(kf);
        // The step bound only guards against a (never expected) cycle.
        for _ in 0..=self.keyframes.len() {
            match current {
                Some(k) if k == ancestor => return true,
                Some(k) => current = self.keyframes.get(&k).and_then(|f| f.parent),
                None => return false,
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use approx::assert_relative_eq;

    use crate::test_support::{map_with_keyframes, observe_all};

    #[test]
    fn children_are_adopted_by_the_most_covisible_candidate() {
        // Grown in time order, giving the tree 0 <- 1 <- {2, 3}. Culling 1 hands 2 to 0 (its
        // parent, shared points 50..70) and then 3 to 2 (shared stereo points, which survive).
        let (mut map, kfs) = map_with_keyframes(4, 120);
        for i in 0..20 {
            observe_all(&mut map, &kfs[..2], i);
        }
        map.update_connections(kfs[1]).unwrap();
        for i in 20..50 {
            observe_all(&mut map, &kfs[1..3], i);
        }
        for i in 50..70 {
            observe_all(&mut map, &[kfs[0], kfs[2]], i);
        }
        map.update_connections(kfs[2]).unwrap();
        for i in (71..111).step_by(2) {
            observe_all(&mut map, &kfs[1..4], i);
        }
        map.update_connections(kfs[3]).unwrap();
        assert_eq!(map.keyframe(kfs[2]).unwrap().parent(), Some(kfs[1]));
        assert_eq!(map.keyframe(kfs[3]).unwrap().parent(), Some(kfs[1]));
        map.check_consistency().unwrap();

        let pose_before = *map.keyframe(kfs[1]).unwrap().T_c_w();
        assert!(map.set_keyframe_bad(kfs[1]));
        assert!(map.keyframe(kfs[1]).is_none());
        assert_eq!(map.keyframe(kfs[2]).unwrap().parent(), Some(kfs[0]));
        assert_eq!(map.keyframe(kfs[3]).unwrap().parent(), Some(kfs[2]));
        map.check_consistency().unwrap();

        // The culled pose follows its adopter.
        let resolved = map.resolve_keyframe_pose(kfs[1]).unwrap();
        assert_relative_eq!(
            resolved.to_homogeneous(),
            pose_before.to_homogeneous(),
            epsilon = 1e-12
        );
    }

    #[test]
    fn origin_is_never_culled() {
        let (mut map, kfs) = map_with_keyframes(2, 10);
        assert!(!map.set_keyframe_bad(kfs[0]));
        assert!(map.keyframe(kfs[0]).is_some());
    }
}
