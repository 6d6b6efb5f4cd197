//! Matcher throughput on seeded random features (640 x 480 image, 8 octaves).

use criterion::{criterion_group, criterion_main, Criterion};
use ferroslam_features::{
    match_brute_force, search_by_projection, Descriptor, ImageBounds, Keypoint, KeypointGrid,
    MatchOptions, ProjectionQuery,
};
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

criterion_group!(benches, bench_matching);
criterion_main!(benches);
