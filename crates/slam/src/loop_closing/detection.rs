//! Loop candidates and their covisibility consistency (ORB-SLAM `LoopClosing::DetectLoop`).

use std::collections::BTreeSet;

use ferroslam_map::{KeyFrameId, Map};

use crate::place_recognition::PlaceRecognition;

/// The candidate groups of the previous keyframe with their consistency counts.
#[derive(Debug, Default)]
pub(crate) struct LoopDetector {
    groups: Vec<(BTreeSet<KeyFrameId>, usize)>,
    had_candidates: bool,
}

impl LoopDetector {
    /// Forgets the groups (after a loop is closed).
    pub(crate) fn clear(&mut self) {
        self.groups.clear();
    }

    /// Whether the last query retrieved any bag-of-words candidate.
    pub(super) fn had_candidates(&self) -> bool {
        self.had_candidates
    }

    /// Candidates of `kf` consistent with the previous keyframes' candidates.
    ///
    /// The minimum score is the lowest bag-of-words similarity between `kf` and the
    /// keyframes it is connected to, so a candidate must look more like `kf` than its own
    /// neighbours do. Each candidate's group is itself plus its connected keyframes; a group
    /// sharing a keyframe with a group of the previous keyframe inherits its count plus one,
    /// and its candidate is returned once the count reaches `consistency`
    /// (`loop_closing.consistency` of the configuration).
    pub(super) fn consistent_candidates(
        &mut self,
        kf: KeyFrameId,
        map: &Map,
        place: &PlaceRecognition,
        consistency: usize,
    ) -> Vec<KeyFrameId> {
        self.had_candidates = false;
        let Some(min_score) = min_neighbour_score(kf, map, place) else {
            // An unconnected keyframe has nothing to compare against.
            self.groups.clear();
            return Vec::new();
        };
        let candidates = place.loop_candidates(kf, map, min_score);
        self.consistent(candidates, map, consistency)
    }

    /// The `candidates` (keyframes of `map`) whose covisibility groups are consistent with
    /// the previous query's groups, counted as in [`Self::consistent_candidates`]; the
    /// groups become this query's. Loops and merges (candidates in another map) alike.
    pub(crate) fn consistent(
        &mut self,
        candidates: Vec<KeyFrameId>,
        map: &Map,
        consistency: usize,
    ) -> Vec<KeyFrameId> {
        self.had_candidates = !candidates.is_empty();
        let mut next: Vec<(BTreeSet<KeyFrameId>, usize)> = Vec::new();
        let mut inherited = vec![false; self.groups.len()];
        let mut enough = Vec::new();
        for candidate in candidates {
            let group: BTreeSet<KeyFrameId> = std::iter::once(candidate)
                .chain(map.covisibles(candidate).into_iter().map(|(k, _)| k))
                .collect();
            let mut consistent_with_any = false;
            for (g, (previous, count)) in self.groups.iter().enumerate() {
                if previous.is_disjoint(&group) {
                    continue;
                }
                consistent_with_any = true;
                let count = count + 1;
                if !inherited[g] {
                    next.push((group.clone(), count));
                    inherited[g] = true;
                }
                if count >= consistency && !enough.contains(&candidate) {
                    enough.push(candidate);
                }
            }
            if !consistent_with_any {
                next.push((group, 0));
            }
        }
        self.groups = next;
        enough
    }
}

/// The lowest bag-of-words similarity between `kf` and the keyframes it is connected to: a
/// loop or merge candidate must look more like `kf` than its own neighbours do. `None` for an
/// unconnected keyframe.
pub(crate) fn min_neighbour_score(
    kf: KeyFrameId,
    map: &Map,
    place: &PlaceRecognition,
) -> Option<f64> {
    map.covisibles(kf)
        .into_iter()
        .filter_map(|(k, _)| place.score(kf, k))
        .reduce(f64::min)
}
