//! Exhaustive descriptor matching between two feature sets.

use super::{best_two::BestTwo, finalize, MatchOptions};
use crate::{hamming, Descriptor, Keypoint};
use rayon::prelude::*;

/// Matches every query feature against every train feature (used for reference-keyframe
/// tracking until a BoW vocabulary exists; same acceptance rules as ORB-SLAM `SearchByBoW`).
///
/// For each query: the nearest train descriptor is accepted if its distance is
/// `<= opts.max_distance` and, with `opts.nn_ratio = Some(r)`, `best < r * second_best`.
/// A train feature matched by several queries keeps only the closest (ties: lowest query
/// index). With `opts.check_orientation`, matches whose `query.angle_deg - train.angle_deg`
/// falls outside the three dominant rotation bins are dropped.
///
/// Returns one entry per query descriptor: the matched train index or `None`. Keypoint and
/// descriptor slices of unequal length are truncated to the shorter (no panic): features
/// beyond it are neither matched nor matchable. Parallel over queries; deterministic.
pub fn match_brute_force(
    query_kps: &[Keypoint],
    query: &[Descriptor],
    train_kps: &[Keypoint],
    train: &[Descriptor],
    opts: &MatchOptions,
) -> Vec<Option<usize>> {
    let n_query = query_kps.len().min(query.len());
    let n_train = train_kps.len().min(train.len());
    let mut matches: Vec<_> = (0..query.len())
        .into_par_iter()
        .map(|q| {
            if q >= n_query {
                return None;
            }
            let mut best = BestTwo::default();
            for (t, (d, kp)) in train[..n_train].iter().zip(train_kps).enumerate() {
                best.push(hamming(&query[q], d), t, kp.octave);
            }
            best.accept(opts.max_distance, opts.nn_ratio)
        })
        .collect();
    finalize(&mut matches, n_train, opts.check_orientation, |q, t| {
        Some(query_kps[q].angle_deg - train_kps[t].angle_deg)
    });
    matches.into_iter().map(|m| m.map(|(t, _)| t)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matcher::test_support::*;
    use crate::matcher::TH_LOW;
    use rand::seq::SliceRandom;
    use rand::Rng;

    #[test]
    fn finds_planted_matches_among_noise() {
        let seed = 11;
        let mut rng = rng(seed);
        let n_train = 500;
        let train: Vec<Descriptor> = (0..n_train).map(|_| random_descriptor(&mut rng)).collect();
        let train_kps: Vec<Keypoint> = (0..n_train).map(|_| random_keypoint(&mut rng)).collect();
        // 200 planted queries (a few bits flipped, rotated by 20 deg) in shuffled order,
        // plus 100 pure-noise queries.
        let mut planted: Vec<usize> = (0..n_train).collect();
        planted.shuffle(&mut rng);
        planted.truncate(200);
        let mut query = Vec::new();
        let mut query_kps = Vec::new();
        let mut expected = Vec::new();
        for &t in &planted {
            let n_bits = rng.random_range(0..=20);
            query.push(flip_bits(&mut rng, &train[t], n_bits));
            let angle = (train_kps[t].angle_deg + 20.0 + rng.random_range(-3.0..3.0)) % 360.0;
            query_kps.push(Keypoint {
                angle_deg: angle,
                ..train_kps[t]
            });
            expected.push(Some(t));
        }
        for _ in 0..100 {
            query.push(random_descriptor(&mut rng));
            query_kps.push(random_keypoint(&mut rng));
            expected.push(None);
        }
        let got = match_brute_force(
            &query_kps,
            &query,
            &train_kps,
            &train,
            &MatchOptions::strict(),
        );
        assert_eq!(got, expected, "seed {seed}");
    }

    #[test]
    fn rejects_ambiguous_and_keeps_one_to_one() {
        let mut rng = rng(12);
        let base = random_descriptor(&mut rng);
        let far = flip_bits(&mut rng, &base, 128);
        // Train 0 and 1 are both 10 bits from query 0: ambiguous under any ratio < 1.
        let train = [
            flip_bits(&mut rng, &base, 10),
            flip_bits(&mut rng, &base, 10),
            far,
        ];
        let kp = random_keypoint(&mut rng);
        let kps = [kp; 3];
        let opts = MatchOptions {
            nn_ratio: Some(0.9),
            check_orientation: false,
            ..MatchOptions::strict()
        };
        assert_eq!(
            match_brute_force(&[kp], &[base], &kps, &train, &opts),
            vec![None]
        );
        let no_ratio = MatchOptions {
            nn_ratio: None,
            ..opts
        };
        assert_eq!(
            match_brute_force(&[kp], &[base], &kps, &train, &no_ratio),
            vec![Some(0)]
        );

        // Two queries want train 0: the closer one (query 1) keeps it.
        let queries = [
            flip_bits(&mut rng, &train[0], 8),
            flip_bits(&mut rng, &train[0], 3),
        ];
        let got = match_brute_force(&[kp; 2], &queries, &kps[..1], &train[..1], &no_ratio);
        assert_eq!(got, vec![None, Some(0)]);
        // Beyond TH_LOW nothing matches.
        let q = [flip_bits(&mut rng, &train[2], TH_LOW as usize + 1)];
        assert_eq!(
            match_brute_force(&[kp], &q, &kps[2..], &train[2..], &no_ratio),
            vec![None]
        );
    }

    #[test]
    fn orientation_check_drops_rotated_minority_and_bad_lengths_do_not_panic() {
        let mut rng = rng(13);
        let n = 60;
        let train: Vec<Descriptor> = (0..n).map(|_| random_descriptor(&mut rng)).collect();
        let train_kps: Vec<Keypoint> = (0..n).map(|_| random_keypoint(&mut rng)).collect();
        let query: Vec<Descriptor> = train.iter().map(|d| flip_bits(&mut rng, d, 5)).collect();
        let query_kps: Vec<Keypoint> = train_kps
            .iter()
            .enumerate()
            .map(|(i, kp)| {
                // Queries 0..4 are rotated by 180 deg relative to the rest.
                let rot = if i < 4 { 180.0 } else { 0.0 };
                Keypoint {
                    angle_deg: (kp.angle_deg + rot) % 360.0,
                    ..*kp
                }
            })
            .collect();
        let got = match_brute_force(
            &query_kps,
            &query,
            &train_kps,
            &train,
            &MatchOptions::strict(),
        );
        for (i, m) in got.iter().enumerate() {
            assert_eq!(*m, (i >= 4).then_some(i), "query {i}");
        }
        // Fewer keypoints than descriptors: extra queries are unmatched, no panic.
        let opts = MatchOptions {
            check_orientation: false,
            ..MatchOptions::strict()
        };
        let got = match_brute_force(&query_kps[..10], &query, &train_kps, &train[..30], &opts);
        assert_eq!(got.len(), n);
        assert!(got[10..].iter().all(Option::is_none));
        assert!(got[..10].iter().enumerate().all(|(i, m)| *m == Some(i)));
    }
}
