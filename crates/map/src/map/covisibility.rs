//! The covisibility graph (ORB-SLAM `KeyFrame::UpdateConnections` and friends).
//!
//! Edge weights are exact at all times (observation changes shift them); which pairs are
//! connected is decided by `update_connections`: an edge exists while at least one endpoint's
//! last update selected it, and disappears when its weight drops to zero.

use super::journal::MapEdit;
use std::collections::{BTreeMap, BTreeSet};

use super::Map;
use crate::{KeyFrame, KeyFrameId, MapError};

/// Minimum shared points for `update_connections` to connect two keyframes (ORB-SLAM: 15).
pub const COVISIBILITY_THRESHOLD: usize = 15;

impl Map {
    /// Recomputes `kf`'s connections from the points it shares with every other keyframe
    /// (ORB-SLAM `UpdateConnections`): it selects the keyframes sharing at least
    /// [`COVISIBILITY_THRESHOLD`] points, or the single best if none does. Edges are set
    /// symmetrically; a previously selected neighbour that is no longer selected is
    /// disconnected unless it selected `kf` itself.
    ///
    /// On the first call that finds a neighbour, a keyframe other than the origin gets its
    /// spanning-tree parent: the most covisible keyframe that is not its own descendant.
    ///
    /// # Errors
    /// [`MapError::UnknownKeyFrame`].
    pub fn update_connections(&mut self, kf: KeyFrameId) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::UpdateConnections { kf },
            |map| map.update_connections_now(kf),
        )
    }

    /// The body of [`Map::update_connections`], run inside its journal entry.
    fn update_connections_now(&mut self, kf: KeyFrameId) -> Result<(), MapError> {
        let frame = self
            .keyframes
            .get(&kf)
            .ok_or(MapError::UnknownKeyFrame(kf))?;
        let counts = self.shared_point_counts(frame);
        let mut selected: BTreeSet<KeyFrameId> = counts
            .iter()
            .filter(|&(_, &n)| n >= COVISIBILITY_THRESHOLD)
            .map(|(&k, _)| k)
            .collect();
        if selected.is_empty() {
            // Lowest id among the maxima, for determinism.
            let best = counts
                .iter()
                .rev()
                .max_by_key(|&(_, &n)| n)
                .map(|(&k, _)| k);
            selected.extend(best);
        }

        let previous = std::mem::take(&mut self.keyframe_mut(kf)?.chosen);
        for &other in previous.difference(&selected) {
            let kept_by_other = self
                .keyframes
                .get(&other)
                .is_some_and(|f| f.chosen.contains(&kf));
            if !kept_by_other {
                self.remove_edge(kf, other);
            }
        }
        for &other in &selected {
            self.set_edge(kf, other, counts.get(&other).copied().unwrap_or(0));
        }
        self.keyframe_mut(kf)?.chosen = selected;

        let frame = self
            .keyframes
            .get(&kf)
            .ok_or(MapError::UnknownKeyFrame(kf))?;
        if frame.parent.is_none() && self.origin != Some(kf) {
            let parent = frame
                .covisibles()
                .into_iter()
                .map(|(k, _)| k)
                .find(|&k| !self.is_descendant(k, kf));
            if let Some(parent) = parent {
                self.set_parent(kf, parent);
            }
        }
        Ok(())
    }

    /// Connected keyframes of `kf` with weights, by decreasing weight (ties: increasing id);
    /// empty for an unknown keyframe.
    pub fn covisibles(&self, kf: KeyFrameId) -> Vec<(KeyFrameId, usize)> {
        self.keyframes
            .get(&kf)
            .map(KeyFrame::covisibles)
            .unwrap_or_default()
    }

    /// The `n` most covisible keyframes of `kf` (ORB-SLAM `GetBestCovisibilityKeyFrames`).
    pub fn best_covisibles(&self, kf: KeyFrameId, n: usize) -> Vec<KeyFrameId> {
        self.keyframes
            .get(&kf)
            .map(|f| f.best_covisibles(n))
            .unwrap_or_default()
    }

    /// Keyframes connected to `kf` by at least `min_weight` shared points, by decreasing
    /// weight (ORB-SLAM `GetCovisiblesByWeight`).
    pub fn covisibles_with_min_weight(&self, kf: KeyFrameId, min_weight: usize) -> Vec<KeyFrameId> {
        self.keyframes
            .get(&kf)
            .map(|f| f.covisibles_with_min_weight(min_weight))
            .unwrap_or_default()
    }

    /// Number of good points `frame` shares with each other keyframe (zero counts omitted).
    pub(super) fn shared_point_counts(&self, frame: &KeyFrame) -> BTreeMap<KeyFrameId, usize> {
        let mut counts = BTreeMap::new();
        for mp in frame.map_points.iter().flatten() {
            let Some(point) = self.map_points.get(mp) else {
                continue;
            };
            for &other in point.observations.keys().filter(|&&k| k != frame.id) {
                *counts.entry(other).or_insert(0) += 1;
            }
        }
        counts
    }

    /// Adds `delta` shared points to the edge `a`-`b` if it exists; removes it at zero.
    pub(super) fn shift_edge(&mut self, a: KeyFrameId, b: KeyFrameId, delta: i64) {
        let Some(&weight) = self.keyframes.get(&a).and_then(|f| f.covisibility.get(&b)) else {
            return;
        };
        match usize::try_from(weight as i64 + delta) {
            Ok(w) if w > 0 => self.set_edge(a, b, w),
            _ => self.remove_edge(a, b),
        }
    }

    /// Creates or reweights the symmetric edge `a`-`b`; a zero weight removes it.
    fn set_edge(&mut self, a: KeyFrameId, b: KeyFrameId, weight: usize) {
        if weight == 0 || a == b {
            self.remove_edge(a, b);
            return;
        }
        for (from, to) in [(a, b), (b, a)] {
            if let Some(frame) = self.keyframes.get_mut(&from) {
                frame.covisibility.insert(to, weight);
            }
        }
    }

    /// Removes the edge `a`-`b` from both endpoints (and from their selections).
    pub(super) fn remove_edge(&mut self, a: KeyFrameId, b: KeyFrameId) {
        for (from, to) in [(a, b), (b, a)] {
            if let Some(frame) = self.keyframes.get_mut(&from) {
                frame.covisibility.remove(&to);
                frame.chosen.remove(&to);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::test_support::{map_with_keyframes, observe_all};

    #[test]
    fn threshold_or_single_best() {
        let (mut map, kfs) = map_with_keyframes(4, 40);
        // kfs[0] shares 20 points with kfs[1], 16 with kfs[2], 3 with kfs[3].
        for i in 0..20 {
            observe_all(&mut map, &kfs[..2], i);
        }
        for i in 20..36 {
            observe_all(&mut map, &[kfs[0], kfs[2]], i);
        }
        for i in 36..39 {
            observe_all(&mut map, &[kfs[0], kfs[3]], i);
        }
        map.update_connections(kfs[0]).unwrap();
        assert_eq!(map.covisibles(kfs[0]), vec![(kfs[1], 20), (kfs[2], 16)]);
        assert_eq!(map.covisibles(kfs[1]), vec![(kfs[0], 20)]);
        assert!(map.covisibles(kfs[3]).is_empty());
        assert_eq!(map.best_covisibles(kfs[0], 1), vec![kfs[1]]);
        assert_eq!(map.covisibles_with_min_weight(kfs[0], 17), vec![kfs[1]]);

        // Below the threshold, kfs[3] keeps its single best neighbour...
        map.update_connections(kfs[3]).unwrap();
        assert_eq!(map.covisibles(kfs[3]), vec![(kfs[0], 3)]);
        assert_eq!(map.keyframe(kfs[3]).unwrap().parent(), Some(kfs[0]));
        // ...even when kfs[0] updates again and does not select it.
        map.update_connections(kfs[0]).unwrap();
        assert_eq!(map.keyframe(kfs[0]).unwrap().weight(kfs[3]), 3);
        map.check_consistency().unwrap();
    }

    #[test]
    fn weights_follow_observation_changes_and_edges_vanish_at_zero() {
        let (mut map, kfs) = map_with_keyframes(2, 40);
        let mps: Vec<_> = (0..20).map(|i| observe_all(&mut map, &kfs, i)).collect();
        map.update_connections(kfs[1]).unwrap();
        assert_eq!(map.keyframe(kfs[0]).unwrap().weight(kfs[1]), 20);
        for &mp in &mps[..5] {
            map.set_map_point_bad(mp);
        }
        assert_eq!(map.keyframe(kfs[1]).unwrap().weight(kfs[0]), 15);
        map.check_consistency().unwrap();
        for &mp in &mps[5..] {
            map.set_map_point_bad(mp);
        }
        assert!(map.covisibles(kfs[0]).is_empty() && map.covisibles(kfs[1]).is_empty());
        map.check_consistency().unwrap();
    }

    #[test]
    fn first_connection_sets_parent_once() {
        let (mut map, kfs) = map_with_keyframes(3, 40);
        for i in 0..20 {
            observe_all(&mut map, &kfs, i);
        }
        map.update_connections(kfs[0]).unwrap();
        assert_eq!(
            map.keyframe(kfs[0]).unwrap().parent(),
            None,
            "origin stays the root"
        );
        map.update_connections(kfs[2]).unwrap();
        assert_eq!(map.keyframe(kfs[2]).unwrap().parent(), Some(kfs[0]));
        // kfs[1] is more covisible with kfs[2] after this, but the parent does not change.
        for i in 20..40 {
            observe_all(&mut map, &kfs[1..], i);
        }
        map.update_connections(kfs[2]).unwrap();
        assert_eq!(map.keyframe(kfs[2]).unwrap().parent(), Some(kfs[0]));
        assert!(map.keyframe(kfs[0]).unwrap().children().contains(&kfs[2]));
        map.check_consistency().unwrap();
    }
}
