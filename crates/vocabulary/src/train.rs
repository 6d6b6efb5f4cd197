//! Vocabulary training: hierarchical k-majority clustering and IDF word weights.

use ferroslam_features::Descriptor;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::bow::NodeId;
use crate::cluster::k_majority;
use crate::error::{Result, VocabularyError};
use crate::vocabulary::{check_shape, Vocabulary};
use crate::weighting::Weighting;

/// Training parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainParams {
    /// Branching factor `k` (>= 2). DBoW2 and ORB-SLAM use 10.
    pub k: u32,
    /// Tree depth `L` (1..=16); at most `k^L` words. ORB-SLAM uses 6.
    pub levels: u32,
    /// Word weighting; IDF weightings learn `ln(N / n_i)` from the training images.
    pub weighting: Weighting,
    /// Cap on centroid updates per clustering step (DBoW2 iterates to convergence; k-majority
    /// can oscillate, so a cap keeps training time bounded).
    pub max_iterations: u32,
    /// Seed of every random choice (k-means++ seeding); equal inputs and seeds give equal trees.
    pub seed: u64,
}

impl Default for TrainParams {
    /// `k = 10`, `levels = 6`, TF-IDF, 10 iterations, seed 0.
    fn default() -> Self {
        TrainParams {
            k: 10,
            levels: 6,
            weighting: Weighting::TfIdf,
            max_iterations: 10,
            seed: 0,
        }
    }
}

/// A trained subtree before it is numbered.
struct Subtree {
    centroid: Descriptor,
    children: Vec<Subtree>,
}

impl Vocabulary {
    /// Trains a vocabulary on the descriptors of a set of images (one slice per image).
    ///
    /// Clusters all descriptors into `k` groups by k-majority (k-means++ seeding on Hamming
    /// distance, bitwise-majority centroids), then each group recursively down to depth
    /// `levels`; a group with a single distinct descriptor becomes a leaf early. Nodes are
    /// numbered breadth first. Word weights: for IDF weightings `ln(N / n_i)` with `N` the
    /// number of images and `n_i` the number of images with a descriptor quantised into word
    /// `i` (0 if none); 1 otherwise. Subtrees are trained in parallel with rayon; each uses
    /// its own RNG derived from `params.seed` and its position, so the result does not depend
    /// on thread scheduling.
    ///
    /// # Errors
    /// [`VocabularyError::InvalidParameter`] for `k` outside `2..=MAX_BRANCHING` or `levels`
    /// outside `1..=16`;
    /// [`VocabularyError::NoTrainingData`] when there is no descriptor at all.
    pub fn train(images: &[Vec<Descriptor>], params: &TrainParams) -> Result<Self> {
        check_shape(params.k, params.levels)?;
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.is_empty() {
            return Err(VocabularyError::NoTrainingData);
        }
        if all.len() > u32::MAX as usize {
            return Err(VocabularyError::InvalidParameter(format!(
                "{} descriptors is too many",
                all.len()
            )));
        }
        let members: Vec<u32> = (0..all.len() as u32).collect();
        let top = grow(&all, &members, 1, params, params.seed);

        let (parents, descriptors) = number_breadth_first(&top);
        let n = parents.len();
        let weights = vec![0.0; n];
        let mut vocabulary = Vocabulary::from_raw_parts(
            params.k,
            params.levels,
            params.weighting,
            parents,
            descriptors,
            weights,
        )?;
        vocabulary.set_word_weights(images);
        Ok(vocabulary)
    }

    /// IDF weights on words (or 1 for non-IDF weightings), 0 on inner nodes.
    fn set_word_weights(&mut self, images: &[Vec<Descriptor>]) {
        let words = self.word_count();
        let document_frequency = images
            .par_iter()
            .map(|image| {
                let mut seen: Vec<u32> = image.iter().map(|d| self.quantize(d)).collect();
                seen.sort_unstable();
                seen.dedup();
                seen
            })
            .fold(
                || vec![0u32; words],
                |mut counts, seen| {
                    seen.into_iter().for_each(|w| counts[w as usize] += 1);
                    counts
                },
            )
            .reduce(
                || vec![0u32; words],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let n_images = images.len() as f64;
        let uses_idf = self.weighting().uses_idf();
        let new_weights: Vec<(NodeId, f64)> = document_frequency
            .iter()
            .enumerate()
            .filter_map(|(w, &n_i)| {
                let node = self.word_node(w as u32)?;
                let weight = match (uses_idf, n_i) {
                    (false, _) => 1.0,
                    (true, 0) => 0.0,
                    (true, n_i) => (n_images / f64::from(n_i)).ln(),
                };
                Some((node, weight))
            })
            .collect();
        self.set_weights(&new_weights);
    }
}

/// Clusters `members` into the children of one node at depth `depth - 1`, recursing below.
fn grow(
    all: &[Descriptor],
    members: &[u32],
    depth: u32,
    params: &TrainParams,
    seed: u64,
) -> Vec<Subtree> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let clusters = k_majority(
        all,
        members,
        params.k as usize,
        params.max_iterations,
        &mut rng,
    );
    clusters
        .into_par_iter()
        .enumerate()
        .map(|(i, cluster)| {
            let first = all[cluster.members[0] as usize];
            let varied = cluster.members.iter().any(|&m| all[m as usize] != first);
            let children = if depth < params.levels && varied {
                grow(
                    all,
                    &cluster.members,
                    depth + 1,
                    params,
                    child_seed(seed, i as u64),
                )
            } else {
                Vec::new()
            };
            Subtree {
                centroid: cluster.centroid,
                children,
            }
        })
        .collect()
}

/// Decorrelated seed of child `i` (SplitMix64 finaliser over the parent seed and index).
fn child_seed(seed: u64, i: u64) -> u64 {
    let mut z = seed ^ (i + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Node arrays (root first, then level by level), so parents precede children and siblings
/// are contiguous.
fn number_breadth_first(top: &[Subtree]) -> (Vec<NodeId>, Vec<Descriptor>) {
    let mut parents = vec![0];
    let mut descriptors = vec![[0u8; 32]];
    let mut queue: std::collections::VecDeque<(&[Subtree], NodeId)> = [(top, 0)].into();
    while let Some((siblings, parent)) = queue.pop_front() {
        for s in siblings {
            let id = parents.len() as NodeId;
            parents.push(parent);
            descriptors.push(s.centroid);
            queue.push_back((&s.children, id));
        }
    }
    (parents, descriptors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_empty_and_bad_params() {
        let p = TrainParams::default();
        assert!(matches!(
            Vocabulary::train(&[], &p),
            Err(VocabularyError::NoTrainingData)
        ));
        assert!(matches!(
            Vocabulary::train(&[vec![]], &p),
            Err(VocabularyError::NoTrainingData)
        ));
        let bad = TrainParams { k: 1, ..p.clone() };
        assert!(Vocabulary::train(&[vec![[0; 32]]], &bad).is_err());
        let bad = TrainParams { levels: 0, ..p };
        assert!(Vocabulary::train(&[vec![[0; 32]]], &bad).is_err());
    }

    #[test]
    fn single_descriptor_gives_one_word() {
        let v = Vocabulary::train(&[vec![[7; 32]], vec![]], &TrainParams::default()).unwrap();
        assert_eq!(v.word_count(), 1);
        // Seen in 1 of 2 images.
        assert!((v.word_weight(0).unwrap() - 2f64.ln()).abs() < 1e-12);
    }
}
