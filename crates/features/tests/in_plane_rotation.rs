//! Cross-module check: a frame rotated in-plane by 30 degrees about the image centre is
//! matched identically by brute force and by projection search (grid + pyramid radius).

use ferroslam_features::{
    hamming, match_brute_force, search_by_projection, Descriptor, ImageBounds, Keypoint,
    KeypointGrid, MatchOptions, ProjectionQuery, ScalePyramid,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SEED: u64 = 2024;
const ROT_DEG: f32 = 30.0;

/// Rotates a keypoint about (320, 240) by `ROT_DEG`, adding its angle.
fn rotate(kp: &Keypoint) -> Keypoint {
    let (s, c) = ROT_DEG.to_radians().sin_cos();
    let (dx, dy) = (kp.x - 320.0, kp.y - 240.0);
    Keypoint {
        x: 320.0 + c * dx - s * dy,
        y: 240.0 + s * dx + c * dy,
        angle_deg: (kp.angle_deg + ROT_DEG) % 360.0,
        ..*kp
    }
}

#[test]
fn brute_force_and_projection_agree_on_a_rotated_frame() {
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let pyramid = ScalePyramid::default();
    let n = 800;
    let kps1: Vec<Keypoint> = (0..n)
        .map(|_| Keypoint {
            x: rng.random_range(120.0..520.0),
            y: rng.random_range(80.0..400.0),
            octave: rng.random_range(0..8),
            angle_deg: rng.random_range(0.0..360.0),
            response: 1.0,
        })
        .collect();
    let desc1: Vec<Descriptor> = (0..n).map(|_| rng.random()).collect();
    // Frame 2: every feature rotated, descriptors with up to 12 flipped bits.
    let kps2: Vec<Keypoint> = kps1.iter().map(rotate).collect();
    let desc2: Vec<Descriptor> = desc1
        .iter()
        .map(|d| {
            let mut d = *d;
            for _ in 0..rng.random_range(0..12) {
                let b = rng.random_range(0..256usize);
                d[b / 8] ^= 1 << (b % 8);
            }
            d
        })
        .collect();

    let brute = match_brute_force(&kps1, &desc1, &kps2, &desc2, &MatchOptions::strict());
    let expected: Vec<Option<usize>> = (0..n).map(Some).collect();
    assert_eq!(brute, expected, "seed {SEED}");

    let bounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };
    let grid = KeypointGrid::new(&kps2, bounds);
    let queries: Vec<ProjectionQuery> = kps1
        .iter()
        .zip(&desc1)
        .map(|(kp, d)| {
            let predicted = rotate(kp);
            ProjectionQuery {
                u: f64::from(predicted.x) + rng.random_range(-1.0..1.0),
                v: f64::from(predicted.y) + rng.random_range(-1.0..1.0),
                radius: 4.0 * pyramid.scale[usize::from(kp.octave)],
                min_level: kp.octave.saturating_sub(1),
                max_level: kp.octave,
                descriptor: *d,
                angle_deg: Some(kp.angle_deg),
            }
        })
        .collect();
    let projected = search_by_projection(
        &queries,
        &kps2,
        &desc2,
        &grid,
        &[],
        &MatchOptions::motion_model(),
    );
    for (i, m) in projected.iter().enumerate() {
        assert_eq!(
            *m,
            Some((i, hamming(&desc1[i], &desc2[i]))),
            "seed {SEED}, query {i}"
        );
    }
}
