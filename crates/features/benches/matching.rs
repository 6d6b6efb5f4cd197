//! Matcher throughput on seeded random features (640 x 480 image, 8 octaves).

use criterion::{criterion_group, criterion_main, Criterion};
use ferroslam_features::matcher::TH_LOW;
use ferroslam_features::{
    match_brute_force, search_by_projection, search_for_triangulation, Descriptor, ImageBounds,
    Keypoint, KeypointGrid, MatchOptions, ProjectionQuery, ScalePyramid,
};
use nalgebra::Matrix3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const N: usize = 1000;

fn features(rng: &mut ChaCha8Rng, n: usize) -> (Vec<Keypoint>, Vec<Descriptor>) {
    (0..n)
        .map(|_| {
            let kp = Keypoint {
                x: rng.random_range(0.0..640.0),
                y: rng.random_range(0.0..480.0),
                octave: rng.random_range(0..8),
                angle_deg: rng.random_range(0.0..360.0),
                response: 1.0,
            };
            (kp, rng.random::<Descriptor>())
        })
        .unzip()
}

/// `d` with `n` random bits flipped (may repeat bits: only used to make near matches).
fn perturb(rng: &mut ChaCha8Rng, d: &Descriptor, n: usize) -> Descriptor {
    let mut out = *d;
    for _ in 0..n {
        let b = rng.random_range(0..256);
        out[b / 8] ^= 1 << (b % 8);
    }
    out
}

fn bench_matching(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let (train_kps, train) = features(&mut rng, N);
    // Half the queries are noisy copies of train features, half are noise.
    let (mut query_kps, mut query) = features(&mut rng, N);
    for i in (0..N).step_by(2) {
        query_kps[i] = train_kps[i];
        query[i] = perturb(&mut rng, &train[i], 10);
    }
    c.bench_function("brute_force_1000x1000", |b| {
        b.iter(|| {
            match_brute_force(
                black_box(&query_kps),
                black_box(&query),
                &train_kps,
                &train,
                &MatchOptions::strict(),
            )
        })
    });

    let bounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };
    let grid = KeypointGrid::new(&train_kps, bounds);
    let queries: Vec<ProjectionQuery> = (0..N)
        .map(|i| {
            let kp = query_kps[i];
            ProjectionQuery {
                u: f64::from(kp.x) + rng.random_range(-2.0..2.0),
                v: f64::from(kp.y) + rng.random_range(-2.0..2.0),
                radius: 15.0,
                min_level: kp.octave.saturating_sub(1),
                max_level: kp.octave,
                descriptor: query[i],
                angle_deg: Some(kp.angle_deg),
            }
        })
        .collect();
    let taken = vec![false; N];
    c.bench_function("grid_build_1000", |b| {
        b.iter(|| KeypointGrid::new(black_box(&train_kps), bounds))
    });
    c.bench_function("search_by_projection_1000", |b| {
        b.iter(|| {
            search_by_projection(
                black_box(&queries),
                &train_kps,
                &train,
                &grid,
                &taken,
                &MatchOptions::motion_model(),
            )
        })
    });
}

/// Local mapping's epipolar search between two keyframes of 2000 free features each (KITTI's
/// extractor setting; seeded random features over 640 x 480, a third of them with a noisy
/// twin in the other view), for a sideways baseline (horizontal epipolar lines) and a
/// forward one (monocular driving: lines radiate from the epipole at the image centre).
fn bench_triangulation_search(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (kps1, desc1) = features(&mut rng, 2000);
    let (kps2, mut desc2) = features(&mut rng, 2000);
    for i in (0..2000).step_by(3) {
        desc2[i] = perturb(&mut rng, &desc1[i], 8);
    }
    let free = vec![true; 2000];
    // F21 of a pure translation t between identical pinhole cameras: K^-T [t]x K^-1, in
    // pixels through K = [500 0 320; 0 500 240; 0 0 1].
    let k_inv = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0)
        .try_inverse()
        .unwrap();
    let sideways = Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0);
    let forward = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let sigma2 = ScalePyramid::new(1.2, 8).unwrap().sigma2;
    let opts = MatchOptions {
        max_distance: TH_LOW,
        nn_ratio: None,
        check_orientation: true,
    };
    for (name, t, epipole) in [
        ("sideways", sideways, None),
        ("forward", forward, Some((320.0, 240.0))),
    ] {
        let f21 = k_inv.transpose() * t * k_inv;
        c.bench_function(&format!("search_for_triangulation_2000x2000 {name}"), |b| {
            b.iter(|| {
                search_for_triangulation(
                    black_box(&kps1),
                    &desc1,
                    &free,
                    &kps2,
                    &desc2,
                    &free,
                    &f21,
                    &sigma2,
                    epipole,
                    &opts,
                )
            })
        });
    }
}

criterion_group!(benches, bench_matching, bench_triangulation_search);
criterion_main!(benches);
