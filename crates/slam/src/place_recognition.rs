//! Place recognition over the map's keyframes (ORB-SLAM `KeyFrameDatabase`): each keyframe's
//! bag of words lives in an inverted-index database, queried to find the keyframes a lost
//! frame may be relocalised against and the keyframes a new keyframe may close a loop with.
//! Each keyframe's feature vector (features grouped by vocabulary node) is kept too, for
//! bag-of-words matching.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use ferroslam_features::Descriptor;
use ferroslam_map::{KeyFrameId, Map};
use ferroslam_vocabulary::{BowVector, Database, FeatureVector, Vocabulary};

use crate::config::PlaceRecognitionConfig;

/// Bag-of-words index of the live keyframes.
pub struct PlaceRecognition {
    vocabulary: Arc<Vocabulary>,
    config: PlaceRecognitionConfig,
    database: Database,
    bows: HashMap<KeyFrameId, (BowVector, FeatureVector)>,
}

impl std::fmt::Debug for PlaceRecognition {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlaceRecognition")
            .field("keyframes", &self.bows.len())
            .finish()
    }
}

impl PlaceRecognition {
    /// An empty index over `vocabulary`, with the feature-vector level, group size and
    /// retrieval count of `config`.
    pub fn new(vocabulary: Arc<Vocabulary>, config: PlaceRecognitionConfig) -> Self {
        Self {
            vocabulary,
            config,
            database: Database::new(),
            bows: HashMap::new(),
        }
    }

    /// The vocabulary words come from.
    pub fn vocabulary(&self) -> &Arc<Vocabulary> {
        &self.vocabulary
    }

    /// Bag of words of a set of descriptors.
    pub fn bow(&self, descriptors: &[Descriptor]) -> BowVector {
        self.vocabulary
            .transform(descriptors, self.config.feature_levels_up)
            .0
    }

    /// Indexes keyframe `kf` of `map` (no-op if it is gone or already indexed); whether it
    /// was indexed now.
    pub fn add_keyframe(&mut self, kf: KeyFrameId, map: &Map) -> bool {
        if self.bows.contains_key(&kf) {
            return false;
        }
        let Some(k) = map.keyframe(kf) else {
            return false;
        };
        let entry = self
            .vocabulary
            .transform(&k.features().descriptors, self.config.feature_levels_up);
        self.insert(kf, entry);
        true
    }

    /// Indexes keyframe `kf` with its bag of words and feature vector computed elsewhere (the
    /// mapping thread's index, so that tracking does not compute them again); no-op if it is
    /// indexed already.
    pub fn insert(&mut self, kf: KeyFrameId, entry: (BowVector, FeatureVector)) {
        if let std::collections::hash_map::Entry::Vacant(slot) = self.bows.entry(kf) {
            self.database.add(kf.0, &entry.0);
            slot.insert(entry);
        }
    }

    /// The bag of words and feature vector of an indexed keyframe.
    pub fn entry(&self, kf: KeyFrameId) -> Option<&(BowVector, FeatureVector)> {
        self.bows.get(&kf)
    }

    /// Forgets the keyframes no longer live in `map` (culled).
    pub fn forget_culled(&mut self, map: &Map) {
        let gone: Vec<KeyFrameId> = self
            .bows
            .keys()
            .filter(|k| map.keyframe(**k).is_none())
            .copied()
            .collect();
        for kf in gone {
            self.database.remove(kf.0);
            self.bows.remove(&kf);
        }
    }

    /// Forgets the keyframes no longer live in `map` (culled) and indexes the new ones,
    /// which it returns.
    pub fn sync(&mut self, map: &Map) -> Vec<KeyFrameId> {
        self.forget_culled(map);
        map.keyframe_ids()
            .into_iter()
            .filter(|&kf| self.add_keyframe(kf, map))
            .collect()
    }

    /// Forgets every keyframe.
    pub fn clear(&mut self) {
        self.database = Database::new();
        self.bows.clear();
    }

    /// Number of indexed keyframes.
    pub fn len(&self) -> usize {
        self.bows.len()
    }

    /// Whether no keyframe is indexed.
    pub fn is_empty(&self) -> bool {
        self.bows.is_empty()
    }

    /// The bag-of-words feature vector of an indexed keyframe.
    pub fn feature_vector(&self, kf: KeyFrameId) -> Option<&FeatureVector> {
        self.bows.get(&kf).map(|(_, f)| f)
    }

    /// DBoW2 L1 similarity of two indexed keyframes, in `[0, 1]`.
    pub fn score(&self, a: KeyFrameId, b: KeyFrameId) -> Option<f64> {
        Some(self.bows.get(&a)?.0.l1_score(&self.bows.get(&b)?.0))
    }

    /// Keyframes a frame with `descriptors` may be relocalised against, best first (ORB-SLAM
    /// `DetectRelocalizationCandidates`): keyframes sharing words, each scored with its best
    /// covisible keyframes' scores added; the best of every group scoring at least
    /// `group_score_ratio` of the best group is kept.
    pub fn relocalisation_candidates(
        &self,
        descriptors: &[Descriptor],
        map: &Map,
    ) -> Vec<KeyFrameId> {
        let bow = self.bow(descriptors);
        let scores: HashMap<KeyFrameId, f64> = self
            .database
            .query(&bow, self.config.max_retrieved, |id| {
                map.keyframe(KeyFrameId(id)).is_some()
            })
            .into_iter()
            .map(|(id, s)| (KeyFrameId(id), s))
            .collect();
        best_of_groups(&scores, map, &self.config)
    }

    /// Keyframes indexed keyframe `kf` may close a loop with (ORB-SLAM
    /// `DetectLoopCandidates`): keyframes not connected to `kf` in the covisibility graph
    /// that share more than `common_words_share` of the largest number of words any of them shares with `kf`
    /// and score at least `min_score` against it, grouped with their covisible keyframes as
    /// in [`Self::relocalisation_candidates`].
    pub fn loop_candidates(&self, kf: KeyFrameId, map: &Map, min_score: f64) -> Vec<KeyFrameId> {
        let Some((bow, _)) = self.bows.get(&kf) else {
            return Vec::new();
        };
        let mut excluded: HashSet<KeyFrameId> =
            map.covisibles(kf).into_iter().map(|(k, _)| k).collect();
        excluded.insert(kf);
        self.candidates_sharing_words(bow, map, min_score, &excluded)
    }

    /// Keyframes of this index's map (`map`) a keyframe of ANOTHER map, with bag of words
    /// `bow`, may be merged at (ORB-SLAM3 `DetectNBestCandidates` over the other maps): the
    /// selection of [`Self::loop_candidates`], with nothing excluded (no keyframe of `map`
    /// is connected to the other map's).
    pub fn merge_candidates(&self, bow: &BowVector, map: &Map, min_score: f64) -> Vec<KeyFrameId> {
        self.candidates_sharing_words(bow, map, min_score, &HashSet::new())
    }

    fn candidates_sharing_words(
        &self,
        bow: &BowVector,
        map: &Map,
        min_score: f64,
        excluded: &HashSet<KeyFrameId>,
    ) -> Vec<KeyFrameId> {
        let common = self.database.common_words(bow, |id| {
            let id = KeyFrameId(id);
            !excluded.contains(&id) && map.keyframe(id).is_some()
        });
        let Some(max_common) = common.iter().map(|&(_, n)| n).max() else {
            return Vec::new();
        };
        let min_common = self.config.common_words_share * max_common as f64;
        let scores: HashMap<KeyFrameId, f64> = common
            .into_iter()
            .filter(|&(_, n)| n as f64 > min_common)
            .filter_map(|(id, _)| {
                let id = KeyFrameId(id);
                let score = bow.l1_score(&self.bows.get(&id)?.0);
                (score >= min_score).then_some((id, score))
            })
            .collect();
        best_of_groups(&scores, map, &self.config)
    }

    /// Takes in every keyframe `other` indexes (the index of a map merged into this one's),
    /// in id order.
    pub fn absorb(&mut self, other: PlaceRecognition) {
        let mut entries: Vec<_> = other.bows.into_iter().collect();
        entries.sort_unstable_by_key(|(kf, _)| *kf);
        for (kf, entry) in entries {
            self.insert(kf, entry);
        }
    }
}

/// ORB-SLAM's covisibility grouping of retrieved keyframes: each keyframe's score plus its
/// `group_size` best covisible keyframes' scores; the best-scoring keyframe of every group
/// totalling at least `group_score_ratio` of the best total is kept, best group first.
fn best_of_groups(
    scores: &HashMap<KeyFrameId, f64>,
    map: &Map,
    config: &PlaceRecognitionConfig,
) -> Vec<KeyFrameId> {
    let mut groups: Vec<(f64, KeyFrameId)> = scores
        .iter()
        .map(|(&kf, &score)| {
            let (mut total, mut best) = (score, (score, kf));
            for n in map.best_covisibles(kf, config.group_size) {
                if let Some(&s) = scores.get(&n) {
                    total += s;
                    if s > best.0 {
                        best = (s, n);
                    }
                }
            }
            (total, best.1)
        })
        .collect();
    groups.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let Some(&(top, _)) = groups.first() else {
        return Vec::new();
    };
    let mut out: Vec<KeyFrameId> = Vec::new();
    for (total, kf) in groups {
        if total >= config.group_score_ratio * top && !out.contains(&kf) {
            out.push(kf);
        }
    }
    out
}
