//! Cross-module tests on synthetic descriptors: clusters of noisy copies of random centres.

use ferroslam_features::Descriptor;
use ferroslam_vocabulary::{Database, TrainParams, Vocabulary, VocabularyError, Weighting};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_descriptor(rng: &mut ChaCha8Rng) -> Descriptor {
    core::array::from_fn(|_| rng.random())
}

/// Copy of `d` with `flips` distinct random bits flipped.
fn noisy(d: &Descriptor, flips: usize, rng: &mut ChaCha8Rng) -> Descriptor {
    let mut out = *d;
    let mut flipped = [false; 256];
    let mut done = 0;
    while done < flips {
        let bit = rng.random_range(0..256);
        if !flipped[bit] {
            flipped[bit] = true;
            out[bit / 8] ^= 1 << (bit % 8);
            done += 1;
        }
    }
    out
}

/// `n_images` images of `per_image` noisy observations of their own landmarks (disjoint
/// between images), plus the landmark table.
fn scene(
    n_images: usize,
    per_image: usize,
    flips: usize,
    seed: u64,
) -> (Vec<Vec<Descriptor>>, Vec<Vec<Descriptor>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let landmarks: Vec<Vec<Descriptor>> = (0..n_images)
        .map(|_| {
            (0..per_image)
                .map(|_| random_descriptor(&mut rng))
                .collect()
        })
        .collect();
    let images = landmarks
        .iter()
        .map(|l| l.iter().map(|d| noisy(d, flips, &mut rng)).collect())
        .collect();
    (images, landmarks)
}

fn temp_path(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!(
        "ferroslam-vocabulary-{}-{name}",
        std::process::id()
    ))
}

#[test]
fn words_never_mix_clusters() {
    // 40 centres, 50 samples each at 12 flipped bits (centres are ~128 bits apart).
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let centres: Vec<Descriptor> = (0..40).map(|_| random_descriptor(&mut rng)).collect();
    let images: Vec<Vec<Descriptor>> = centres
        .iter()
        .map(|c| (0..50).map(|_| noisy(c, 12, &mut rng)).collect())
        .collect();
    let params = TrainParams {
        k: 10,
        levels: 2,
        ..TrainParams::default()
    };
    let voc = Vocabulary::train(&images, &params).unwrap();
    assert!(
        voc.word_count() >= 40 && voc.word_count() <= 100,
        "{} words",
        voc.word_count()
    );
    let mut owner = vec![None; voc.word_count()];
    for (c, image) in images.iter().enumerate() {
        for d in image {
            let w = voc.quantize(d) as usize;
            assert!(
                owner[w].is_none() || owner[w] == Some(c),
                "word {w} holds clusters {:?} and {c}",
                owner[w]
            );
            owner[w] = Some(c);
        }
    }
    // Fresh noisy samples land in a word of their own cluster.
    for (c, centre) in centres.iter().enumerate() {
        for _ in 0..10 {
            assert_eq!(
                owner[voc.quantize(&noisy(centre, 12, &mut rng)) as usize],
                Some(c)
            );
        }
    }
    // Each word is seen in exactly one of the 40 images: IDF ln(40).
    for w in 0..voc.word_count() as u32 {
        assert!((voc.word_weight(w).unwrap() - 40f64.ln()).abs() < 1e-12);
    }
}

#[test]
fn noisy_copy_scores_far_higher_against_its_image() {
    let (images, landmarks) = scene(30, 300, 10, 2);
    let params = TrainParams {
        k: 10,
        levels: 3,
        ..TrainParams::default()
    };
    let voc = Vocabulary::train(&images, &params).unwrap();
    let bows: Vec<_> = images.iter().map(|im| voc.transform(im, 1).0).collect();
    let mut db = Database::new();
    for (i, b) in bows.iter().enumerate() {
        db.add(i as u32, b);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    // Random (unclustered) landmarks make word boundaries fall everywhere, so 10 flipped bits
    // move about half the weight to other words (own ~0.5), and 1000 words shared by 30
    // images of 300 features give unrelated images ~0.26: measured min ratio 1.81.
    let mut worst_ratio = f64::INFINITY;
    for (i, l) in landmarks.iter().enumerate() {
        let copy: Vec<Descriptor> = l.iter().map(|d| noisy(d, 10, &mut rng)).collect();
        let (bow, _) = voc.transform(&copy, 1);
        let own = bow.l1_score(&bows[i]);
        let best_other = bows
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, b)| bow.l1_score(b))
            .fold(0.0, f64::max);
        assert!(own > 0.4, "image {i}: own score {own}");
        worst_ratio = worst_ratio.min(own / best_other);
        let top = db.query(&bow, 3, |_| true);
        assert_eq!(top[0].0, i as u32);
        assert!((top[0].1 - own).abs() < 1e-9);
    }
    assert!(
        worst_ratio > 1.5,
        "worst own / best other ratio {worst_ratio}"
    );
}

#[test]
fn training_is_deterministic_and_feature_vectors_cover_features() {
    let (images, _) = scene(12, 200, 8, 3);
    let params = TrainParams {
        k: 6,
        levels: 4,
        seed: 7,
        ..TrainParams::default()
    };
    let a = Vocabulary::train(&images, &params).unwrap();
    let b = Vocabulary::train(&images, &params).unwrap();
    assert_eq!(a, b);
    assert_eq!(
        (a.branching(), a.levels(), a.weighting()),
        (6, 4, Weighting::TfIdf)
    );
    let (bow, fv) = a.transform(&images[0], 2);
    assert!((bow.l1_norm() - 1.0).abs() < 1e-12);
    let mut seen: Vec<u32> = Vec::new();
    for (node, features) in fv.iter() {
        // Grouping depth is levels - 2 = 2, shallower only for a word above it.
        let depth = a.depth(node).unwrap();
        assert!(
            depth == 2 || (depth < 2 && a.node_word(node).is_some()),
            "node {node} depth {depth}"
        );
        for &f in features {
            let word_node = a.word_node(a.quantize(&images[0][f as usize])).unwrap();
            let mut n = word_node;
            while a.depth(n).unwrap() > depth {
                n = a.parent(n).unwrap();
            }
            assert_eq!(n, node);
        }
        seen.extend_from_slice(features);
    }
    seen.sort_unstable();
    // Words of these images are seen in one image each, so every weight is positive.
    assert_eq!(seen, (0..images[0].len() as u32).collect::<Vec<_>>());
}

#[test]
fn files_round_trip_and_damaged_files_fail_cleanly() {
    let (images, _) = scene(8, 150, 8, 4);
    let voc = Vocabulary::train(
        &images,
        &TrainParams {
            k: 5,
            levels: 3,
            ..TrainParams::default()
        },
    )
    .unwrap();
    let (bin, txt) = (temp_path("v.bin"), temp_path("v.txt"));
    voc.save(&bin).unwrap();
    let loaded = Vocabulary::load(&bin).unwrap();
    assert_eq!(loaded, voc);
    assert_eq!(
        loaded.transform(&images[3], 1),
        voc.transform(&images[3], 1)
    );
    voc.save_dbow2_text(&txt).unwrap();
    assert_eq!(Vocabulary::load_dbow2_text(&txt).unwrap(), voc);

    let bytes = std::fs::read(&bin).unwrap();
    std::fs::write(&bin, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(
        Vocabulary::load(&bin),
        Err(VocabularyError::Truncated { .. })
    ));
    let mut corrupt = bytes.clone();
    corrupt[bytes.len() / 2] ^= 0xFF;
    std::fs::write(&bin, &corrupt).unwrap();
    assert!(matches!(
        Vocabulary::load(&bin),
        Err(VocabularyError::ChecksumMismatch)
    ));
    let text = std::fs::read_to_string(&txt).unwrap();
    std::fs::write(&txt, &text[..text.len() - 40]).unwrap();
    assert!(matches!(
        Vocabulary::load_dbow2_text(&txt),
        Err(VocabularyError::Parse { .. })
    ));
    // A text file is not a binary vocabulary and vice versa.
    assert!(matches!(
        Vocabulary::load(&txt),
        Err(VocabularyError::BadMagic)
    ));
    assert!(Vocabulary::load_dbow2_text(&bin).is_err());
    assert!(matches!(
        Vocabulary::load(temp_path("missing")),
        Err(VocabularyError::Io(_))
    ));
    let _ = std::fs::remove_file(&bin);
    let _ = std::fs::remove_file(&txt);
}
