//! RANSAC over a fixed list of minimal samples, shared by the homography and the
//! fundamental-matrix searches so that both models see the same data (as in ORB-SLAM,
//! which makes their scores comparable).

use nalgebra::Matrix3;
use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::scoring::Score;

/// Matches per RANSAC sample: 8 for the 8-point algorithm; the homography uses the same
/// 8 (over-determined) so both models are fitted to identical subsets.
pub(super) const SAMPLE_SIZE: usize = 8;

/// `iterations` samples of `SAMPLE_SIZE` distinct indices in `0..n`, drawn from a
/// ChaCha8 RNG seeded with `seed`. Empty if `n < SAMPLE_SIZE`.
pub(super) fn draw_samples(n: usize, iterations: usize, seed: u64) -> Vec<[usize; SAMPLE_SIZE]> {
    if n < SAMPLE_SIZE {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..iterations)
        .map(|_| {
            let mut s = [0; SAMPLE_SIZE];
            for (slot, i) in s.iter_mut().zip(sample(&mut rng, n, SAMPLE_SIZE).iter()) {
                *slot = i;
            }
            s
        })
        .collect()
}

/// Local optimisation rounds: refits on the inliers of the best model while that raises
/// the score (the best minimal sample is too noisy for an accurate pose at 1 px noise).
const MAX_REFITS: usize = 20;

/// The best-scoring model over `samples`, then refitted on its inliers: `fit(indices,
/// previous)` turns a set of match indices into a model (or `None` when degenerate),
/// `previous` being the model being refined (`None` for samples); `score` rates a model on
/// all matches. Ties keep the earlier sample. `None` if no sample gave a scorable model.
pub(super) fn best_model(
    samples: &[[usize; SAMPLE_SIZE]],
    fit: impl Fn(&[usize], Option<&Matrix3<f64>>) -> Option<Matrix3<f64>>,
    score: impl Fn(&Matrix3<f64>) -> Option<Score>,
) -> Option<(Matrix3<f64>, Score)> {
    let scored = |indices: &[usize], previous: Option<&Matrix3<f64>>| {
        let model = fit(indices, previous)?;
        let s = score(&model)?;
        s.score.is_finite().then_some((model, s))
    };
    let mut best: Option<(Matrix3<f64>, Score)> = None;
    for s in samples {
        let Some(candidate) = scored(s, None) else {
            continue;
        };
        if best
            .as_ref()
            .is_none_or(|(_, b)| candidate.1.score > b.score)
        {
            best = Some(candidate);
        }
    }
    let mut best = best?;
    for _ in 0..MAX_REFITS {
        let inliers: Vec<usize> = (0..best.1.inliers.len())
            .filter(|&i| best.1.inliers[i])
            .collect();
        match scored(&inliers, Some(&best.0)) {
            Some(refit) if refit.1.score > best.1.score => best = refit,
            _ => break,
        }
    }
    Some(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_distinct_in_range_and_seeded() {
        let a = draw_samples(20, 50, 7);
        assert_eq!(a.len(), 50);
        for s in &a {
            let mut sorted = s.to_vec();
            sorted.sort_unstable();
            sorted.dedup();
            assert_eq!(sorted.len(), SAMPLE_SIZE);
            assert!(sorted.iter().all(|&i| i < 20));
        }
        assert_eq!(a, draw_samples(20, 50, 7));
        assert_ne!(a, draw_samples(20, 50, 8));
        assert!(draw_samples(7, 50, 7).is_empty());
    }
}
