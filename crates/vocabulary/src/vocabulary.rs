//! The vocabulary tree: nodes, words, descent and the BoW transform.

use ferroslam_features::{hamming, Descriptor};

use crate::bow::{BowVector, FeatureVector, NodeId, WordId};
use crate::error::{Result, VocabularyError};
use crate::weighting::Weighting;

/// Marks a node that is not a word (an inner node or the root).
const NOT_A_WORD: WordId = WordId::MAX;

/// Deepest tree the crate accepts (DBoW2/ORB-SLAM accept `L <= 10`).
pub const MAX_LEVELS: u32 = 16;

/// Largest branching factor accepted (DBoW2 vocabularies use 10): a corrupt header's `k`
/// of billions would make node counts overflow and every word lookup scan billions.
pub const MAX_BRANCHING: u32 = 4096;

/// A hierarchical vocabulary of 256-bit ORB descriptors, as DBoW2's `TemplatedVocabulary`.
///
/// Node 0 is the root (depth 0, no descriptor); every other node has a parent with a smaller
/// id, a centroid descriptor and a weight. Leaves are the words, numbered in increasing node
/// order; a word's weight is its IDF `ln(N / n_i)` for IDF weightings, 1 otherwise, and inner
/// nodes weigh 0. A descriptor is quantised by descending from the root to the child with the
/// smallest Hamming distance (the lowest id on ties) until a leaf is reached.
#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    k: u32,
    levels: u32,
    weighting: Weighting,
    parents: Vec<NodeId>,
    descriptors: Vec<Descriptor>,
    weights: Vec<f64>,
    depths: Vec<u8>,
    /// Children of node `n` are `children[child_start[n]..child_start[n + 1]]`.
    child_start: Vec<u32>,
    children: Vec<NodeId>,
    word_of_node: Vec<WordId>,
    node_of_word: Vec<NodeId>,
}

impl Vocabulary {
    /// Builds a vocabulary from its node arrays, indexed by node id (entry 0 is the root,
    /// whose parent, descriptor and weight are ignored). This is how files are loaded and how
    /// custom vocabularies are brought in.
    ///
    /// `k` and `levels` are the branching factor and depth the tree was built with; they are
    /// recorded, and every node must lie at depth `<= levels`.
    ///
    /// # Errors
    /// [`VocabularyError::InvalidParameter`] for `k` outside `2..=MAX_BRANCHING` or `levels`
    /// outside `1..=MAX_LEVELS`;
    /// [`VocabularyError::Malformed`] for arrays of different lengths, a tree without any
    /// word, a parent id not smaller than its child's, a node deeper than `levels`, or a
    /// non-finite weight.
    pub fn from_raw_parts(
        k: u32,
        levels: u32,
        weighting: Weighting,
        parents: Vec<NodeId>,
        descriptors: Vec<Descriptor>,
        mut weights: Vec<f64>,
    ) -> Result<Self> {
        check_shape(k, levels)?;
        let n = parents.len();
        if descriptors.len() != n || weights.len() != n {
            return Err(VocabularyError::Malformed(format!(
                "node arrays differ in length: {n} parents, {} descriptors, {} weights",
                descriptors.len(),
                weights.len()
            )));
        }
        if n < 2 {
            return Err(VocabularyError::Malformed("the tree has no word".into()));
        }
        if n > NOT_A_WORD as usize {
            return Err(VocabularyError::Malformed(format!("{n} nodes is too many")));
        }
        weights[0] = 0.0;
        let mut depths = vec![0u8; n];
        let mut child_count = vec![0u32; n + 1];
        for i in 1..n {
            let p = parents[i] as usize;
            if p >= i {
                return Err(VocabularyError::Malformed(format!(
                    "node {i} has parent {p}; parents must precede their children"
                )));
            }
            depths[i] = depths[p] + 1;
            if u32::from(depths[i]) > levels {
                return Err(VocabularyError::Malformed(format!(
                    "node {i} lies at depth {} > levels {levels}",
                    depths[i]
                )));
            }
            if !weights[i].is_finite() {
                return Err(VocabularyError::Malformed(format!(
                    "node {i} has weight {}",
                    weights[i]
                )));
            }
            child_count[p + 1] += 1;
        }
        // Prefix sums turn counts into the start offsets of each node's children.
        for i in 0..n {
            child_count[i + 1] += child_count[i];
        }
        let child_start = child_count;
        let mut fill = child_start.clone();
        let mut children = vec![0; n - 1];
        for (i, &p) in parents.iter().enumerate().skip(1) {
            children[fill[p as usize] as usize] = i as NodeId;
            fill[p as usize] += 1;
        }
        let mut word_of_node = vec![NOT_A_WORD; n];
        let mut node_of_word = Vec::new();
        for i in 1..n {
            if child_start[i] == child_start[i + 1] {
                word_of_node[i] = node_of_word.len() as WordId;
                node_of_word.push(i as NodeId);
            }
        }
        Ok(Vocabulary {
            k,
            levels,
            weighting,
            parents,
            descriptors,
            weights,
            depths,
            child_start,
            children,
            word_of_node,
            node_of_word,
        })
    }

    /// Branching factor `k` the tree was built with.
    pub fn branching(&self) -> u32 {
        self.k
    }

    /// Depth `L` the tree was built with (leaves lie at depth `<= L`).
    pub fn levels(&self) -> u32 {
        self.levels
    }

    /// Word weighting scheme.
    pub fn weighting(&self) -> Weighting {
        self.weighting
    }

    /// Number of nodes, the root included.
    pub fn node_count(&self) -> usize {
        self.parents.len()
    }

    /// Number of words (leaves).
    pub fn word_count(&self) -> usize {
        self.node_of_word.len()
    }

    /// Parent of `node` (`None` for the root or an unknown id).
    pub fn parent(&self, node: NodeId) -> Option<NodeId> {
        (node != 0)
            .then(|| self.parents.get(node as usize).copied())
            .flatten()
    }

    /// Children of `node` in increasing id order (empty for a word or an unknown id).
    pub fn children(&self, node: NodeId) -> &[NodeId] {
        let n = node as usize;
        match (self.child_start.get(n), self.child_start.get(n + 1)) {
            (Some(&a), Some(&b)) => &self.children[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Centroid descriptor of `node` (`None` for an unknown id; the root's is all zeros).
    pub fn descriptor(&self, node: NodeId) -> Option<&Descriptor> {
        self.descriptors.get(node as usize)
    }

    /// Weight of `node`: the word weight for a leaf, 0 for inner nodes.
    pub fn weight(&self, node: NodeId) -> Option<f64> {
        self.weights.get(node as usize).copied()
    }

    /// Depth of `node` (root 0).
    pub fn depth(&self, node: NodeId) -> Option<u32> {
        self.depths.get(node as usize).map(|&d| u32::from(d))
    }

    /// Node of `word`.
    pub fn word_node(&self, word: WordId) -> Option<NodeId> {
        self.node_of_word.get(word as usize).copied()
    }

    /// Word of `node`, if it is a leaf.
    pub fn node_word(&self, node: NodeId) -> Option<WordId> {
        self.word_of_node
            .get(node as usize)
            .copied()
            .filter(|&w| w != NOT_A_WORD)
    }

    /// Weight of `word` (IDF or 1, see [`Weighting`]).
    pub fn word_weight(&self, word: WordId) -> Option<f64> {
        self.word_node(word).map(|n| self.weights[n as usize])
    }

    /// The word a descriptor falls into.
    pub fn quantize(&self, descriptor: &Descriptor) -> WordId {
        self.descend(descriptor, 0).0
    }

    /// Converts an image's descriptors into its L1-normalised BoW vector and its feature
    /// vector (ORB-SLAM's `ComputeBoW`).
    ///
    /// The feature vector groups feature indices by their ancestor at depth
    /// `levels - levels_up` (ORB-SLAM uses `levels_up = 4` with `L = 6`, i.e. depth 2);
    /// when a word lies shallower than that, the word's own node is used, and
    /// `levels_up >= levels` groups everything under the root.
    ///
    /// As in DBoW2, features whose word weighs 0 (an IDF word seen in every training image)
    /// are left out of both vectors.
    pub fn transform(
        &self,
        descriptors: &[Descriptor],
        levels_up: u32,
    ) -> (BowVector, FeatureVector) {
        let group_depth = self.levels.saturating_sub(levels_up);
        let mut pairs = Vec::with_capacity(descriptors.len());
        let mut features = FeatureVector::default();
        for (i, d) in descriptors.iter().enumerate() {
            let (word, group) = self.descend(d, group_depth);
            let weight = self.weights[self.node_of_word[word as usize] as usize];
            if weight <= 0.0 {
                continue;
            }
            pairs.push((word, weight));
            features.push(group, i as u32);
        }
        if self.weighting == Weighting::Binary {
            pairs.sort_unstable_by_key(|&(w, _)| w);
            pairs.dedup_by_key(|&mut (w, _)| w);
        }
        let mut bow = BowVector::from_weights(pairs);
        bow.normalize_l1();
        (bow, features)
    }

    /// Overwrites node weights (training sets the word weights after numbering the tree).
    pub(crate) fn set_weights(&mut self, weights: &[(NodeId, f64)]) {
        for &(node, w) in weights {
            self.weights[node as usize] = w;
        }
    }

    /// Node arrays (parents, descriptors, weights) indexed by node id, for the file writers.
    pub(crate) fn raw_parts(&self) -> (&[NodeId], &[Descriptor], &[f64]) {
        (&self.parents, &self.descriptors, &self.weights)
    }

    /// Descends to a leaf; returns its word and the deepest node on the path at depth
    /// `<= group_depth`.
    fn descend(&self, d: &Descriptor, group_depth: u32) -> (WordId, NodeId) {
        let (mut node, mut group) = (0usize, 0);
        loop {
            let kids = &self.children
                [self.child_start[node] as usize..self.child_start[node + 1] as usize];
            // from_raw_parts guarantees that every non-root leaf is a word and the root has children.
            let Some(&first) = kids.first() else {
                return (self.word_of_node[node], group);
            };
            let mut best = (hamming(d, &self.descriptors[first as usize]), first);
            for &c in &kids[1..] {
                let dist = hamming(d, &self.descriptors[c as usize]);
                if dist < best.0 {
                    best = (dist, c);
                }
            }
            node = best.1 as usize;
            if u32::from(self.depths[node]) <= group_depth {
                group = node as NodeId;
            }
        }
    }
}

/// Validates the recorded branching factor and depth.
pub(crate) fn check_shape(k: u32, levels: u32) -> Result<()> {
    if !(2..=MAX_BRANCHING).contains(&k) {
        return Err(VocabularyError::InvalidParameter(format!(
            "branching factor k = {k} outside 2..={MAX_BRANCHING}"
        )));
    }
    if !(1..=MAX_LEVELS).contains(&levels) {
        return Err(VocabularyError::InvalidParameter(format!(
            "levels = {levels} outside 1..={MAX_LEVELS}"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Root with two children; child 1 has two leaf children (3, 4), child 2 is a leaf.
    fn small() -> Vocabulary {
        let mut d = vec![[0u8; 32]; 5];
        d[1] = [0x00; 32];
        d[2] = [0xFF; 32];
        d[3] = [0x00; 32];
        d[4] = [0x0F; 32];
        Vocabulary::from_raw_parts(
            2,
            2,
            Weighting::TfIdf,
            vec![0, 0, 0, 1, 1],
            d,
            vec![0.0, 0.0, 2.0, 1.0, 0.5],
        )
        .unwrap()
    }

    #[test]
    fn structure_words_and_descent() {
        let v = small();
        assert_eq!(v.node_count(), 5);
        assert_eq!(v.word_count(), 3);
        assert_eq!(v.children(0), &[1, 2]);
        assert_eq!(v.children(1), &[3, 4]);
        assert!(v.children(2).is_empty());
        assert_eq!(v.node_word(2), Some(0));
        assert_eq!(v.node_word(3), Some(1));
        assert_eq!(v.node_word(1), None);
        assert_eq!(v.word_weight(0), Some(2.0));
        assert_eq!(v.depth(4), Some(2));
        assert_eq!(v.parent(4), Some(1));
        assert_eq!(v.parent(0), None);
        assert_eq!(v.quantize(&[0xFF; 32]), 0);
        assert_eq!(v.quantize(&[0x01; 32]), 1);
        assert_eq!(v.quantize(&[0x0F; 32]), 2);
    }

    #[test]
    fn transform_weights_and_groups() {
        let v = small();
        let descs = [[0xFF; 32], [0x01; 32], [0x01; 32], [0x0F; 32]];
        let (bow, fv) = v.transform(&descs, 1);
        // Raw weights: word0 2.0, word1 1.0 + 1.0, word2 0.5; total 4.5.
        let expect = [(0, 2.0 / 4.5), (1, 2.0 / 4.5), (2, 0.5 / 4.5)];
        for ((w, x), (ew, ex)) in bow.iter().zip(expect) {
            assert_eq!(w, ew);
            assert!((x - ex).abs() < 1e-12);
        }
        // Grouped at depth 1: node 2 (a shallow word) and node 1.
        assert_eq!(
            fv.iter().collect::<Vec<_>>(),
            vec![(1, &[1, 2, 3][..]), (2, &[0][..])]
        );
        let (_, at_root) = v.transform(&descs, 5);
        assert_eq!(at_root.get(0), Some(&[0, 1, 2, 3][..]));
    }

    #[test]
    fn rejects_bad_trees() {
        let d = vec![[0u8; 32]; 3];
        let w = vec![0.0; 3];
        assert!(Vocabulary::from_raw_parts(
            2,
            2,
            Weighting::Tf,
            vec![0, 2, 0],
            d.clone(),
            w.clone()
        )
        .is_err());
        assert!(Vocabulary::from_raw_parts(
            2,
            1,
            Weighting::Tf,
            vec![0, 0, 1],
            d.clone(),
            w.clone()
        )
        .is_err());
        assert!(Vocabulary::from_raw_parts(
            1,
            2,
            Weighting::Tf,
            vec![0, 0, 0],
            d.clone(),
            w.clone()
        )
        .is_err());
        assert!(
            Vocabulary::from_raw_parts(2, 2, Weighting::Tf, vec![0], vec![[0; 32]], vec![0.0])
                .is_err()
        );
        assert!(Vocabulary::from_raw_parts(
            2,
            2,
            Weighting::Tf,
            vec![0, 0, 0],
            d,
            vec![0.0, f64::NAN, 1.0]
        )
        .is_err());
    }
}
