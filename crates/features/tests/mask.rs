//! The extractor honours keypoint masks: no keypoint on a zero pixel, the budget spent on the
//! open part, an all-open mask changing nothing.

use ferroslam_features::{
    image_circle_mask, FeaturesError, GrayImage, Keypoint, OrbConfig, OrbExtractor,
};
use proptest::prelude::*;

const W: usize = 240;
const H: usize = 180;

/// A `W x H` image of bright and dark blocks on a ramp, corners everywhere.
fn textured() -> Vec<u8> {
    (0..W * H)
        .map(|i| {
            let (x, y) = (i % W, i / W);
            let block = ((x / 7) * 5 + (y / 9) * 3 + (x / 23) * (y / 17)) % 6;
            (30 + block * 35 + (x * 3 + y) % 5) as u8
        })
        .collect()
}

fn extractor() -> OrbExtractor {
    OrbExtractor::new(OrbConfig {
        n_features: 400,
        n_levels: 4,
        ..OrbConfig::default()
    })
    .unwrap()
}

/// The mask pixel a keypoint lies on (its position rounded half to even, as numpy's `rint`).
fn mask_at(mask: &[u8], k: &Keypoint) -> u8 {
    let (x, y) = (
        k.x.round_ties_even() as usize,
        k.y.round_ties_even() as usize,
    );
    mask[y.min(H - 1) * W + x.min(W - 1)]
}

#[test]
fn an_all_open_mask_gives_exactly_the_unmasked_features() {
    let data = textured();
    let image = GrayImage::new(W, H, &data).unwrap();
    let unmasked = extractor().extract(&image, None).unwrap();
    assert!(
        unmasked.keypoints.len() > 300,
        "{}",
        unmasked.keypoints.len()
    );
    for open in [1u8, 255] {
        let ones = vec![open; W * H];
        let mask = GrayImage::new(W, H, &ones).unwrap();
        assert_eq!(extractor().extract(&image, Some(&mask)).unwrap(), unmasked);
    }
}

#[test]
fn the_budget_goes_to_the_open_half() {
    let data = textured();
    let image = GrayImage::new(W, H, &data).unwrap();
    let left_open: Vec<u8> = (0..W * H).map(|i| u8::from(i % W < W / 2)).collect();
    let mask = GrayImage::new(W, H, &left_open).unwrap();
    let e = extractor();
    let masked = e.extract(&image, Some(&mask)).unwrap();
    let unmasked = e.extract(&image, None).unwrap();
    assert!(masked.keypoints.iter().all(|k| mask_at(&left_open, k) != 0));
    let in_left = |ks: &[Keypoint]| ks.iter().filter(|k| mask_at(&left_open, k) != 0).count();
    // Filtered before the spread: the left half gets (nearly) the whole budget, not the
    // share it had when the spread also covered the right half.
    let (masked_n, unmasked_n) = (masked.keypoints.len(), in_left(&unmasked.keypoints));
    assert!(
        masked_n as f64 > 1.5 * unmasked_n as f64,
        "{masked_n} vs {unmasked_n}"
    );
    assert_eq!(masked.descriptors.len(), masked_n);
}

#[test]
fn stereo_masks_apply_to_their_own_image() {
    let data = textured();
    let image = GrayImage::new(W, H, &data).unwrap();
    let circle = image_circle_mask(W, H, 120.0, 90.0, 80.0, 5.0).unwrap();
    let e = extractor();
    let (left, right) = e
        .extract_stereo(&image, &image, Some(&circle.view()), None)
        .unwrap();
    assert_eq!(left, e.extract(&image, Some(&circle.view())).unwrap());
    assert_eq!(right, e.extract(&image, None).unwrap());
    assert!(left
        .keypoints
        .iter()
        .all(|k| mask_at(circle.view().pixels(), k) == 255));
    let small = vec![255u8; 10 * 10];
    let small = GrayImage::new(10, 10, &small).unwrap();
    let err = e
        .extract_stereo(&image, &image, None, Some(&small))
        .unwrap_err();
    assert_eq!(
        err,
        FeaturesError::MaskSizeMismatch {
            mask_width: 10,
            mask_height: 10,
            image_width: W,
            image_height: H
        }
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random masks of 12 x 12 px blocks (each closed with probability `p`, at a random
    /// offset): no keypoint ever lies on a closed pixel.
    #[test]
    fn no_keypoint_falls_on_a_masked_pixel(
        closed in proptest::collection::vec(any::<bool>(), 21 * 16),
        dx in 0usize..12,
        dy in 0usize..12,
    ) {
        let data = textured();
        let image = GrayImage::new(W, H, &data).unwrap();
        let mask: Vec<u8> = (0..W * H)
            .map(|i| {
                let (bx, by) = ((i % W + dx) / 12, (i / W + dy) / 12);
                if closed[(by * 21 + bx) % closed.len()] { 0 } else { 200 }
            })
            .collect();
        let view = GrayImage::new(W, H, &mask).unwrap();
        let features = extractor().extract(&image, Some(&view)).unwrap();
        for k in &features.keypoints {
            prop_assert!(mask_at(&mask, k) != 0, "keypoint {k:?} on a masked pixel");
        }
    }
}
