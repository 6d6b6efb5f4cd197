//! Inverted-index keyframe database (DBoW2's `Database`, ORB-SLAM's `KeyFrameDatabase`).

use std::collections::HashMap;

use crate::bow::{BowVector, WordId};

/// Keyframe id as used by the caller.
pub type EntryId = u32;

/// BoW vectors of keyframes with an inverted file (word -> keyframes containing it), so a
/// query scores only the keyframes that share at least one word with it.
///
/// Scores are DBoW2's L1 score ([`BowVector::l1_score`]). Entries are stored L1-normalised,
/// for which the score reduces to `sum over shared words of min(a_w, b_w)`, accumulated
/// along the inverted lists.
#[derive(Clone, Debug, Default)]
pub struct Database {
    /// Indexed by word id: (entry, normalised weight) of every entry containing the word.
    inverted: Vec<Vec<(EntryId, f64)>>,
    entries: HashMap<EntryId, BowVector>,
}

impl Database {
    /// An empty database.
    pub fn new() -> Self {
        Database::default()
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when no entry is stored.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Whether `id` is stored.
    pub fn contains(&self, id: EntryId) -> bool {
        self.entries.contains_key(&id)
    }

    /// The stored (L1-normalised) vector of `id`.
    pub fn get(&self, id: EntryId) -> Option<&BowVector> {
        self.entries.get(&id)
    }

    /// Adds keyframe `id`, replacing any entry stored under the same id. Returns true when it
    /// replaced one.
    pub fn add(&mut self, id: EntryId, bow: &BowVector) -> bool {
        let replaced = self.remove(id);
        let mut stored = bow.clone();
        stored.normalize_l1();
        for (w, v) in stored.iter() {
            let w = w as usize;
            if w >= self.inverted.len() {
                self.inverted.resize_with(w + 1, Vec::new);
            }
            self.inverted[w].push((id, v));
        }
        self.entries.insert(id, stored);
        replaced
    }

    /// Removes keyframe `id`. Returns false when it was not stored.
    pub fn remove(&mut self, id: EntryId) -> bool {
        let Some(old) = self.entries.remove(&id) else {
            return false;
        };
        for (w, _) in old.iter() {
            if let Some(list) = self.inverted.get_mut(w as usize) {
                list.retain(|&(e, _)| e != id);
            }
        }
        true
    }

    /// The `max_results` best-scoring entries accepted by `keep` that share at least one word
    /// with `bow`, as (id, L1 score in `(0, 1]`), best first (ties: smaller id first).
    /// `keep` is called once per candidate; pass e.g. `|id| !excluded.contains(&id)`.
    pub fn query(
        &self,
        bow: &BowVector,
        max_results: usize,
        keep: impl Fn(EntryId) -> bool,
    ) -> Vec<(EntryId, f64)> {
        let mut query = bow.clone();
        query.normalize_l1();
        let mut scores: HashMap<EntryId, Option<f64>> = HashMap::new();
        for (w, q) in query.iter() {
            for &(id, v) in self.postings(w) {
                let score = scores.entry(id).or_insert_with(|| keep(id).then_some(0.0));
                if let Some(s) = score {
                    *s += q.min(v);
                }
            }
        }
        let mut ranked: Vec<(EntryId, f64)> = scores
            .into_iter()
            .filter_map(|(id, s)| s.map(|s| (id, s.min(1.0))))
            .collect();
        ranked.sort_unstable_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        ranked.truncate(max_results);
        ranked
    }

    /// Number of distinct words each entry accepted by `keep` shares with `bow` (entries
    /// sharing none are omitted), in increasing id order: the first filter of ORB-SLAM's
    /// `DetectLoopCandidates` / `DetectRelocalizationCandidates`.
    pub fn common_words(
        &self,
        bow: &BowVector,
        keep: impl Fn(EntryId) -> bool,
    ) -> Vec<(EntryId, u32)> {
        let mut counts: HashMap<EntryId, Option<u32>> = HashMap::new();
        for (w, _) in bow.iter() {
            for &(id, _) in self.postings(w) {
                if let Some(c) = counts.entry(id).or_insert_with(|| keep(id).then_some(0)) {
                    *c += 1;
                }
            }
        }
        let mut out: Vec<(EntryId, u32)> = counts
            .into_iter()
            .filter_map(|(id, c)| c.map(|c| (id, c)))
            .collect();
        out.sort_unstable();
        out
    }

    fn postings(&self, word: WordId) -> &[(EntryId, f64)] {
        self.inverted.get(word as usize).map_or(&[], Vec::as_slice)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bow(pairs: &[(WordId, f64)]) -> BowVector {
        BowVector::from_weights(pairs.to_vec())
    }

    #[test]
    fn query_scores_equal_direct_l1_scores() {
        let vectors = [
            bow(&[(0, 1.0), (3, 2.0), (9, 1.0)]),
            bow(&[(3, 1.0), (4, 1.0)]),
            bow(&[(9, 5.0), (0, 0.5), (3, 0.1)]),
            bow(&[(100, 1.0)]),
        ];
        let mut db = Database::new();
        for (i, v) in vectors.iter().enumerate() {
            assert!(!db.add(i as EntryId, v));
        }
        let q = bow(&[(0, 2.0), (3, 1.0), (4, 1.0), (9, 0.5)]);
        let results = db.query(&q, 10, |_| true);
        assert_eq!(results.len(), 3, "entry 3 shares no word");
        for w in results.windows(2) {
            assert!(w[0].1 >= w[1].1);
        }
        for (id, s) in &results {
            assert!((s - q.l1_score(&vectors[*id as usize])).abs() < 1e-12);
        }
        assert_eq!(db.query(&q, 1, |_| true).len(), 1);
        let without_best = db.query(&q, 10, |id| id != results[0].0);
        assert_eq!(without_best, results[1..].to_vec());
    }

    #[test]
    fn remove_replace_and_common_words() {
        let mut db = Database::new();
        db.add(7, &bow(&[(1, 1.0), (2, 1.0)]));
        db.add(8, &bow(&[(2, 1.0), (5, 1.0)]));
        let q = bow(&[(1, 1.0), (2, 1.0), (5, 1.0)]);
        assert_eq!(db.common_words(&q, |_| true), vec![(7, 2), (8, 2)]);
        assert_eq!(db.common_words(&q, |id| id == 8), vec![(8, 2)]);
        assert!(db.add(7, &bow(&[(9, 1.0)])));
        assert_eq!(db.common_words(&q, |_| true), vec![(8, 2)]);
        assert!(db.remove(8));
        assert!(!db.remove(8));
        assert!(db.query(&q, 5, |_| true).is_empty());
        assert_eq!(db.len(), 1);
        assert!(db.contains(7) && !db.contains(8));
    }
}
