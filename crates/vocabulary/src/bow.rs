//! Bag-of-words vectors, feature vectors and DBoW2's L1 score.

use std::collections::BTreeMap;

/// Index of a word (a leaf of the vocabulary tree), `0..word_count`.
pub type WordId = u32;
/// Index of a node of the vocabulary tree; the root is node 0.
pub type NodeId = u32;

/// Sparse bag-of-words vector: word id -> weight, sorted by word id, one entry per word.
///
/// Vectors produced by [`Vocabulary::transform`](crate::Vocabulary::transform) are
/// L1-normalised (weights sum to 1), as DBoW2 does for L1 scoring.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BowVector {
    entries: Vec<(WordId, f64)>,
}

impl BowVector {
    /// Builds a vector from (word, weight) pairs in any order; weights of repeated words add up.
    pub fn from_weights(mut pairs: Vec<(WordId, f64)>) -> Self {
        pairs.sort_unstable_by_key(|&(w, _)| w);
        let mut entries: Vec<(WordId, f64)> = Vec::with_capacity(pairs.len());
        for (w, v) in pairs {
            match entries.last_mut() {
                Some(last) if last.0 == w => last.1 += v,
                _ => entries.push((w, v)),
            }
        }
        BowVector { entries }
    }

    /// (word, weight) entries in increasing word order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = (WordId, f64)> + '_ {
        self.entries.iter().copied()
    }

    /// Number of distinct words.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when no word is present.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Weight of `word`, if present.
    pub fn get(&self, word: WordId) -> Option<f64> {
        self.entries
            .binary_search_by_key(&word, |&(w, _)| w)
            .ok()
            .map(|i| self.entries[i].1)
    }

    /// Sum of absolute weights.
    pub fn l1_norm(&self) -> f64 {
        self.entries.iter().map(|&(_, v)| v.abs()).sum()
    }

    /// Scales the weights so that their absolute values sum to 1 (no-op on a zero vector).
    pub fn normalize_l1(&mut self) {
        let norm = self.l1_norm();
        if norm > 0.0 {
            for e in &mut self.entries {
                e.1 /= norm;
            }
        }
    }

    /// DBoW2's L1 score `s = 1 - 0.5 * | a/|a| - b/|b| |_1`, in `[0, 1]`
    /// (1 for vectors with the same direction, 0 for vectors sharing no word).
    /// A zero vector scores 0 against anything.
    pub fn l1_score(&self, other: &BowVector) -> f64 {
        let (na, nb) = (self.l1_norm(), other.l1_norm());
        if na <= 0.0 || nb <= 0.0 {
            return 0.0;
        }
        let (mut i, mut j, mut dist) = (0, 0, 0.0);
        let (a, b) = (&self.entries, &other.entries);
        while i < a.len() || j < b.len() {
            let wa = a.get(i).map_or(WordId::MAX, |e| e.0);
            let wb = b.get(j).map_or(WordId::MAX, |e| e.0);
            let (va, vb) = match wa.cmp(&wb) {
                std::cmp::Ordering::Less => {
                    i += 1;
                    (a[i - 1].1 / na, 0.0)
                }
                std::cmp::Ordering::Greater => {
                    j += 1;
                    (0.0, b[j - 1].1 / nb)
                }
                std::cmp::Ordering::Equal => {
                    i += 1;
                    j += 1;
                    (a[i - 1].1 / na, b[j - 1].1 / nb)
                }
            };
            dist += (va - vb).abs();
        }
        (1.0 - 0.5 * dist).clamp(0.0, 1.0)
    }
}

/// Feature indices grouped by the vocabulary node they fall under at a chosen tree level
/// (ORB-SLAM's `FeatureVector`): two images' features need only be matched within the same
/// node. Feature indices are positions in the descriptor slice given to
/// [`Vocabulary::transform`](crate::Vocabulary::transform), in increasing order per node.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FeatureVector {
    nodes: BTreeMap<NodeId, Vec<u32>>,
}

impl FeatureVector {
    pub(crate) fn push(&mut self, node: NodeId, feature: u32) {
        self.nodes.entry(node).or_default().push(feature);
    }

    /// (node, feature indices) in increasing node order.
    pub fn iter(&self) -> impl Iterator<Item = (NodeId, &[u32])> + '_ {
        self.nodes.iter().map(|(&n, f)| (n, f.as_slice()))
    }

    /// Feature indices under `node`, if any.
    pub fn get(&self, node: NodeId) -> Option<&[u32]> {
        self.nodes.get(&node).map(Vec::as_slice)
    }

    /// Number of distinct nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True when no feature was recorded.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Nodes present in both vectors, with each side's features, in increasing node order:
    /// the candidate groups of ORB-SLAM's `SearchByBoW`.
    pub fn common_nodes<'a>(
        &'a self,
        other: &'a FeatureVector,
    ) -> impl Iterator<Item = (NodeId, &'a [u32], &'a [u32])> + 'a {
        self.nodes
            .iter()
            .filter_map(move |(&n, a)| other.nodes.get(&n).map(|b| (n, a.as_slice(), b.as_slice())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_weights_sorts_and_merges() {
        let v = BowVector::from_weights(vec![(5, 1.0), (2, 0.5), (5, 2.0)]);
        assert_eq!(v.iter().collect::<Vec<_>>(), vec![(2, 0.5), (5, 3.0)]);
        assert_eq!(v.get(5), Some(3.0));
        assert_eq!(v.get(3), None);
    }

    #[test]
    fn l1_score_limits_and_scale_invariance() {
        let a = BowVector::from_weights(vec![(1, 1.0), (2, 3.0)]);
        let scaled = BowVector::from_weights(vec![(1, 2.0), (2, 6.0)]);
        let disjoint = BowVector::from_weights(vec![(7, 1.0)]);
        assert!((a.l1_score(&scaled) - 1.0).abs() < 1e-12);
        assert_eq!(a.l1_score(&disjoint), 0.0);
        assert_eq!(a.l1_score(&BowVector::default()), 0.0);
        // a/|a| = (0.25, 0.75), b/|b| = (0.5, 0.5) on words 1, 2: distance 0.5 -> score 0.75.
        let b = BowVector::from_weights(vec![(1, 1.0), (2, 1.0)]);
        assert!((a.l1_score(&b) - 0.75).abs() < 1e-12);
        assert!((b.l1_score(&a) - 0.75).abs() < 1e-12);
    }

    #[test]
    fn common_nodes_intersects() {
        let mut a = FeatureVector::default();
        let mut b = FeatureVector::default();
        for (n, f) in [(1, 0), (3, 1), (3, 2), (9, 3)] {
            a.push(n, f);
        }
        for (n, f) in [(3, 0), (4, 1), (9, 2)] {
            b.push(n, f);
        }
        let common: Vec<_> = a.common_nodes(&b).collect();
        assert_eq!(
            common,
            vec![(3, &[1, 2][..], &[0][..]), (9, &[3][..], &[2][..])]
        );
    }
}
