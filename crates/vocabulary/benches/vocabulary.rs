//! Vocabulary throughput: load of a 10^6-word (k = 10, L = 6) tree, BoW transform of 1000
//! descriptors, database query over 500 keyframes, and a small training run.
//!
//! The large tree is complete and has random centroids (training one needs ~10^7
//! descriptors); load and descent costs depend only on its shape.

use criterion::{criterion_group, criterion_main, Criterion};
use ferroslam_features::Descriptor;
use ferroslam_vocabulary::{Database, TrainParams, Vocabulary, Weighting};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

/// Complete k-ary tree of depth `levels`, numbered breadth first (parent of i is (i-1)/k).
fn complete_tree(k: u32, levels: u32, rng: &mut ChaCha8Rng) -> Vocabulary {
    let n = ((k as usize).pow(levels + 1) - 1) / (k as usize - 1);
    let parents = (0..n as u32).map(|i| i.saturating_sub(1) / k).collect();
    let descriptors = (0..n).map(|_| rng.random::<Descriptor>()).collect();
    let weights = (0..n).map(|_| rng.random_range(0.1..5.0)).collect();
    Vocabulary::from_raw_parts(k, levels, Weighting::TfIdf, parents, descriptors, weights)
        .expect("valid tree")
}

fn perturb(rng: &mut ChaCha8Rng, d: &Descriptor, n: usize) -> Descriptor {
    let mut out = *d;
    for _ in 0..n {
        let b = rng.random_range(0..256);
        out[b / 8] ^= 1 << (b % 8);
    }
    out
}

fn bench_vocabulary(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let voc = complete_tree(10, 6, &mut rng);
    let bytes = voc.to_bytes();
    println!(
        "k=10 L=6 vocabulary: {} nodes, {} words, {} bytes",
        voc.node_count(),
        voc.word_count(),
        bytes.len()
    );
    let path = std::env::temp_dir().join(format!(
        "ferroslam-vocabulary-bench-{}.bin",
        std::process::id()
    ));
    std::fs::write(&path, &bytes).expect("temp file");

    let mut group = c.benchmark_group("vocabulary");
    group.sample_size(10);
    group.bench_function("load_1M_words_from_file", |b| {
        b.iter(|| Vocabulary::load(black_box(&path)).expect("load"))
    });
    group.bench_function("from_bytes_1M_words", |b| {
        b.iter(|| Vocabulary::from_bytes(black_box(&bytes)).expect("parse"))
    });
    group.finish();
    let _ = std::fs::remove_file(&path);

    let image: Vec<Descriptor> = (0..1000).map(|_| rng.random()).collect();
    c.bench_function("transform_1000_descriptors_1M_words", |b| {
        b.iter(|| voc.transform(black_box(&image), 4))
    });

    // 500 keyframes along a path through 20 000 landmarks, each seeing 1000 of them.
    let landmarks: Vec<Descriptor> = (0..20_000).map(|_| rng.random()).collect();
    let keyframe = |j: usize, rng: &mut ChaCha8Rng| -> Vec<Descriptor> {
        (0..1000)
            .map(|i| perturb(rng, &landmarks[(j * 37 + i) % landmarks.len()], 8))
            .collect()
    };
    let mut db = Database::new();
    for j in 0..500 {
        db.add(j as u32, &voc.transform(&keyframe(j, &mut rng), 4).0);
    }
    let query = voc.transform(&keyframe(250, &mut rng), 4).0;
    c.bench_function("query_500_keyframes", |b| {
        b.iter(|| db.query(black_box(&query), 10, |id| id != 250))
    });

    let images: Vec<Vec<Descriptor>> = (0..20).map(|j| keyframe(j * 20, &mut rng)).collect();
    let params = TrainParams {
        k: 10,
        levels: 4,
        ..TrainParams::default()
    };
    let mut group = c.benchmark_group("train");
    group.sample_size(10);
    group.bench_function("train_20k_descriptors_k10_l4", |b| {
        b.iter(|| Vocabulary::train(black_box(&images), &params))
    });
    group.finish();
}

criterion_group!(benches, bench_vocabulary);
criterion_main!(benches);
