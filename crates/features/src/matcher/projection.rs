//! Guided matching of projected map points against a frame's keypoints.

use super::{best_two::BestTwo, finalize, MatchOptions};
use crate::{hamming, Descriptor, Keypoint, KeypointGrid};
use rayon::prelude::*;

/// A map point projected into the target image, to be matched within a square window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectionQuery {
    /// Projected column (undistorted px).
    pub u: f64,
    /// Projected row (undistorted px).
    pub v: f64,
    /// Half-side of the square search window (px), typically `th * scale[predicted level]`.
    pub radius: f64,
    /// Lowest accepted keypoint octave (ORB-SLAM: predicted level - 1).
    pub min_level: u8,
    /// Highest accepted keypoint octave (ORB-SLAM: predicted level).
    pub max_level: u8,
    /// The map point's representative descriptor.
    pub descriptor: Descriptor,
    /// Orientation (deg) of the feature the query comes from, for the rotation check; `None`
    /// exempts this query from it (e.g. local-map points).
    pub angle_deg: Option<f32>,
}

/// Matches each query to the closest target keypoint in its window — ORB-SLAM
/// `SearchByProjection(Frame, vector<MapPoint*>)`, plus the rotation check of
/// `SearchByProjection(Frame, Frame)`.
///
/// Candidates are the keypoints returned by `grid.features_in_area(target_kps, u, v, radius,
/// min_level, max_level)` that are not `taken` (`taken[i] == true`, e.g. already bound to a
/// map point; a `taken` slice shorter than the targets means "not taken"). The best candidate
/// is accepted if its distance is `<= opts.max_distance`; with `opts.nn_ratio = Some(r)` it is
/// rejected when the second best lies on the same octave and `best > r * second`. Each target
/// goes to at most one query (smallest distance, ties: lowest query index). With
/// `opts.check_orientation`, queries with `angle_deg = Some(a)` whose `a - target.angle_deg`
/// falls outside the three dominant rotation bins are dropped.
///
/// Returns, per query, `Some((target index, Hamming distance))` or `None`. `grid` must be
/// built from `target_kps`; targets beyond `target.len()` are ignored. Deterministic.
pub fn search_by_projection(
    queries: &[ProjectionQuery],
    target_kps: &[Keypoint],
    target: &[Descriptor],
    grid: &KeypointGrid,
    taken: &[bool],
    opts: &MatchOptions,
) -> Vec<Option<(usize, u32)>> {
    search_by_projection_with(queries, target_kps, target, grid, taken, opts, |_, _| true)
}

/// [`search_by_projection`] with an extra test `accept(query, target)` on every candidate
/// before descriptors are compared, e.g. ORB-SLAM's stereo check that the right-image
/// coordinate predicted for the query agrees with the candidate's measured one.
pub fn search_by_projection_with(
    queries: &[ProjectionQuery],
    target_kps: &[Keypoint],
    target: &[Descriptor],
    grid: &KeypointGrid,
    taken: &[bool],
    opts: &MatchOptions,
    accept: impl Fn(usize, usize) -> bool + Sync,
) -> Vec<Option<(usize, u32)>> {
    let n_target = target_kps.len().min(target.len());
    let mut matches: Vec<_> = queries
        .par_iter()
        .enumerate()
        .map(|(qi, q)| {
            let candidates = grid.features_in_area(
                &target_kps[..n_target],
                q.u,
                q.v,
                q.radius,
                Some(q.min_level),
                Some(q.max_level),
            );
            let mut best = BestTwo::default();
            for t in candidates {
                if !taken.get(t).copied().unwrap_or(false) && accept(qi, t) {
                    best.push(hamming(&q.descriptor, &target[t]), t, target_kps[t].octave);
                }
            }
            best.accept_same_level(opts.max_distance, opts.nn_ratio)
        })
        .collect();
    finalize(&mut matches, n_target, opts.check_orientation, |q, t| {
        queries[q].angle_deg.map(|a| a - target_kps[t].angle_deg)
    });
    matches
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matcher::test_support::*;
    use crate::ImageBounds;
    use rand::Rng;

    const BOUNDS: ImageBounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };

    struct Scene {
        kps: Vec<Keypoint>,
        desc: Vec<Descriptor>,
        grid: KeypointGrid,
    }

    fn scene(seed: u64, n: usize) -> Scene {
        let mut rng = rng(seed);
        let kps: Vec<Keypoint> = (0..n).map(|_| random_keypoint(&mut rng)).collect();
        let desc = (0..n).map(|_| random_descriptor(&mut rng)).collect();
        let grid = KeypointGrid::new(&kps, BOUNDS);
        Scene { kps, desc, grid }
    }

    /// A query planted on target `t`: projected within 2 px, `n_bits` bits flipped.
    fn planted(
        rng: &mut rand_chacha::ChaCha8Rng,
        s: &Scene,
        t: usize,
        n_bits: usize,
    ) -> ProjectionQuery {
        let kp = s.kps[t];
        ProjectionQuery {
            u: f64::from(kp.x) + rng.random_range(-2.0..2.0),
            v: f64::from(kp.y) + rng.random_range(-2.0..2.0),
            radius: 15.0,
            min_level: kp.octave.saturating_sub(1),
            max_level: kp.octave,
            descriptor: flip_bits(rng, &s.desc[t], n_bits),
            angle_deg: Some(kp.angle_deg + 5.0),
        }
    }

    #[test]
    fn finds_planted_matches_and_respects_taken() {
        let seed = 21;
        let s = scene(seed, 1500);
        let mut rng = rng(seed + 1);
        let targets: Vec<usize> = (0..1500).step_by(3).collect();
        let queries: Vec<_> = targets
            .iter()
            .map(|&t| {
                let n_bits = rng.random_range(0..30);
                planted(&mut rng, &s, t, n_bits)
            })
            .collect();
        let mut taken = vec![false; 1500];
        for &t in targets.iter().step_by(10) {
            taken[t] = true;
        }
        let got = search_by_projection(
            &queries,
            &s.kps,
            &s.desc,
            &s.grid,
            &taken,
            &MatchOptions::motion_model(),
        );
        for (q, &t) in targets.iter().enumerate() {
            if taken[t] {
                // The true target is unavailable and random neighbours are ~128 bits away.
                assert_eq!(got[q], None, "seed {seed}, query {q}");
            } else {
                let d = hamming(&queries[q].descriptor, &s.desc[t]);
                assert_eq!(got[q], Some((t, d)), "seed {seed}, query {q}");
            }
        }
    }

    #[test]
    fn one_to_one_and_window_and_levels() {
        let s = scene(22, 800);
        let mut rng = rng(23);
        let t = 17;
        let close = planted(&mut rng, &s, t, 4);
        let closer = ProjectionQuery {
            descriptor: flip_bits(&mut rng, &s.desc[t], 2),
            ..close
        };
        let opts = MatchOptions::local_map();
        let got = search_by_projection(&[close, closer], &s.kps, &s.desc, &s.grid, &[], &opts);
        assert_eq!(got[0], None);
        assert_eq!(got[1], Some((t, hamming(&closer.descriptor, &s.desc[t]))));

        // Outside the window or the level range: no match to t.
        let kp = s.kps[t];
        let far = ProjectionQuery {
            u: f64::from(kp.x) + 20.0,
            ..closer
        };
        let wrong_level = ProjectionQuery {
            min_level: kp.octave + 1,
            max_level: kp.octave + 2,
            ..closer
        };
        let got = search_by_projection(&[far, wrong_level], &s.kps, &s.desc, &s.grid, &[], &opts);
        assert!(got.iter().all(|m| m.is_none_or(|(i, _)| i != t)), "{got:?}");
    }

    #[test]
    fn same_level_ratio_test() {
        // Two targets at the same spot: distances 30 and 33 are ambiguous (30 > 0.8 * 33)
        // on the same octave, accepted when the runner-up is on another octave.
        let mut rng = rng(24);
        let d = random_descriptor(&mut rng);
        let kp = Keypoint {
            x: 100.0,
            y: 100.0,
            octave: 1,
            angle_deg: 0.0,
            response: 1.0,
        };
        let desc = [flip_bits(&mut rng, &d, 30), flip_bits(&mut rng, &d, 33)];
        let q = ProjectionQuery {
            u: 100.0,
            v: 100.0,
            radius: 5.0,
            min_level: 0,
            max_level: 2,
            descriptor: d,
            angle_deg: None,
        };
        let opts = MatchOptions::local_map();
        let same = [kp, kp];
        let grid = KeypointGrid::new(&same, BOUNDS);
        assert_eq!(
            search_by_projection(&[q], &same, &desc, &grid, &[], &opts),
            vec![None]
        );
        let other = [kp, Keypoint { octave: 2, ..kp }];
        let grid = KeypointGrid::new(&other, BOUNDS);
        assert_eq!(
            search_by_projection(&[q], &other, &desc, &grid, &[], &opts),
            vec![Some((0, 30))]
        );
    }

    #[test]
    fn orientation_check_applies_only_to_oriented_queries() {
        let s = scene(25, 400);
        let mut rng = rng(26);
        let mut queries: Vec<_> = (0..40).map(|t| planted(&mut rng, &s, t * 10, 3)).collect();
        // Query 0 disagrees with the common +5 deg rotation; query 1 has no angle.
        queries[0].angle_deg = queries[0].angle_deg.map(|a| a + 150.0);
        queries[1].angle_deg = None;
        let got = search_by_projection(
            &queries,
            &s.kps,
            &s.desc,
            &s.grid,
            &[],
            &MatchOptions::motion_model(),
        );
        assert_eq!(got[0], None);
        for (q, m) in got.iter().enumerate().skip(1) {
            assert_eq!(m.map(|(t, _)| t), Some(q * 10), "query {q}");
        }
    }

    #[test]
    fn accept_filter_skips_candidates_before_choosing_the_best() {
        let s = scene(31, 300);
        let mut rng = rng(32);
        let q = planted(&mut rng, &s, 7, 0);
        let opts = MatchOptions {
            max_distance: 256,
            nn_ratio: None,
            check_orientation: false,
        };
        let all = search_by_projection(&[q], &s.kps, &s.desc, &s.grid, &[], &opts);
        assert_eq!(all[0].map(|m| m.0), Some(7));
        // Refusing target 7 lets the next candidate in the window win (or none if alone).
        let filtered =
            search_by_projection_with(&[q], &s.kps, &s.desc, &s.grid, &[], &opts, |_, t| t != 7);
        assert_ne!(filtered[0].map(|m| m.0), Some(7));
    }
}
