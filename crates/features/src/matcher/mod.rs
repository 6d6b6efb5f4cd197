//! Hamming matchers of ORB-SLAM2/3 (`ORBmatcher.cc`), parallel over queries with rayon.
//!
//! Every matcher follows the same pipeline, which keeps the output deterministic whatever the
//! thread count:
//! 1. per query (in parallel): scan the candidates, keep the best and second-best Hamming
//!    distance, apply `max_distance` and the matcher's ratio test;
//! 2. one-to-one: a target claimed by several queries goes to the smallest distance (ties:
//!    the lowest query index);
//! 3. if `check_orientation`: the [`RotationHistogram`] rejects matches whose keypoint angle
//!    difference is outside the three most populated bins.

mod best_two;
mod brute_force;
mod epipolar;
mod options;
mod pencil;
mod projection;
mod rotation;

pub use brute_force::match_brute_force;
pub use epipolar::{search_for_triangulation, search_for_triangulation_rays};
pub use options::{MatchOptions, TH_HIGH, TH_LOW};
pub use projection::{search_by_projection, search_by_projection_with, ProjectionQuery};
pub use rotation::{RotationHistogram, HISTO_LENGTH};

/// A query's chosen target: `(target index, Hamming distance)`.
pub type Candidate = (usize, u32);

/// Steps 2 and 3 of the pipeline (see the module docs), in place: for matchers written
/// elsewhere (e.g. bag-of-words matching between keyframes) that produce per-query best
/// candidates `(target index, Hamming distance)`.
///
/// `angle_diff(query, target)` gives the orientation difference in degrees, or `None` when
/// the query has no orientation (it is then exempt from the rotation check). Every target
/// index in `matches` must be `< n_targets`.
pub fn finalize(
    matches: &mut [Option<Candidate>],
    n_targets: usize,
    check_orientation: bool,
    angle_diff: impl Fn(usize, usize) -> Option<f32>,
) {
    let mut owner: Vec<Option<usize>> = vec![None; n_targets];
    for q in 0..matches.len() {
        let Some((t, d)) = matches[q] else { continue };
        match owner[t] {
            Some(prev) if matches[prev].is_some_and(|(_, pd)| pd <= d) => matches[q] = None,
            Some(prev) => {
                matches[prev] = None;
                owner[t] = Some(q);
            }
            None => owner[t] = Some(q),
        }
    }
    if !check_orientation {
        return;
    }
    let mut histogram = RotationHistogram::new();
    for (q, m) in matches.iter().enumerate() {
        if let Some(rot) = m.and_then(|(t, _)| angle_diff(q, t)) {
            histogram.add(q, rot);
        }
    }
    for q in histogram.rejected() {
        matches[q] = None;
    }
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Seeded random keypoints and descriptors shared by the matcher tests.
    use crate::{Descriptor, Keypoint};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    pub fn rng(seed: u64) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(seed)
    }

    pub fn random_descriptor(rng: &mut ChaCha8Rng) -> Descriptor {
        rng.random()
    }

    /// `d` with `n_bits` distinct random bits flipped.
    pub fn flip_bits(rng: &mut ChaCha8Rng, d: &Descriptor, n_bits: usize) -> Descriptor {
        let mut out = *d;
        let bits = rand::seq::index::sample(rng, 256, n_bits);
        for b in bits {
            out[b / 8] ^= 1 << (b % 8);
        }
        out
    }

    pub fn random_keypoint(rng: &mut ChaCha8Rng) -> Keypoint {
        Keypoint {
            x: rng.random_range(0.0..640.0),
            y: rng.random_range(0.0..480.0),
            octave: rng.random_range(0..8),
            angle_deg: rng.random_range(0.0..360.0),
            response: 1.0,
        }
    }
}
