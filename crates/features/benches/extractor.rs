//! The ORB extractor, whole and by stage, with ORB-SLAM's settings (1000 features, 8 levels of
//! scale 1.2): the image pyramid, the smoothing of its levels for BRIEF (each called from
//! outside rayon's pool, and both inside it as `OrbExtractor::extract` runs them), keypoint
//! detection (FAST, fallback, spread, orientation) on level 0 alone and on the pyramid, rotated
//! BRIEF of the pyramid's corners, and `OrbExtractor::extract`; on the first TUM fr1/rpy frame
//! (640 x 480, from `FERROSLAM_DATA`, default `../shared/data` beside the repository) and on a
//! seeded synthetic image of random blobs (corners everywhere, the hard case).

use criterion::{criterion_group, criterion_main, Criterion};
use ferroslam_features::extractor::smoothing::smooth_for_brief;
use ferroslam_features::extractor::{brief::BriefPattern, ImagePyramid};
use ferroslam_features::extractor::{detect_level, detect_pyramid, fast::fast_corners};
use ferroslam_features::{GrayImage, OrbConfig, OrbExtractor};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::hint::black_box;

/// Random blobs on a smooth gradient: corners everywhere, like a cluttered room.
fn textured(w: usize, h: usize, rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut img: Vec<f32> = (0..w * h)
        .map(|i| ((i % w) as f32 * 0.1 + (i / w) as f32 * 0.2) % 255.0)
        .collect();
    for _ in 0..3000 {
        let (cx, cy, r) = (
            rng.random_range(0..w),
            rng.random_range(0..h),
            rng.random_range(2..8),
        );
        let value: f32 = rng.random_range(0.0..255.0);
        for y in cy.saturating_sub(r)..(cy + r).min(h) {
            for x in cx.saturating_sub(r)..(cx + r).min(w) {
                img[y * w + x] = value;
            }
        }
    }
    img.into_iter().map(|v| v as u8).collect()
}

/// The first TUM fr1/rpy frame in grey, when the data folder is there.
fn tum_frame() -> Option<(usize, usize, Vec<u8>)> {
    let data = std::env::var_os("FERROSLAM_DATA").map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
        Into::into,
    );
    let rgb = data.join("tum/rgbd_dataset_freiburg1_rpy/rgb");
    let mut files: Vec<_> = std::fs::read_dir(rgb)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .collect();
    files.sort();
    let mut decoder = jpeg_decoder::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(files.first()?).ok()?,
    ));
    let pixels = decoder.decode().ok()?;
    let info = decoder.info()?;
    let gray = pixels
        .chunks_exact(3)
        .map(|p| {
            (0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2])).round()
                as u8
        })
        .collect();
    Some((usize::from(info.width), usize::from(info.height), gray))
}

fn bench_image(c: &mut Criterion, name: &str, (w, h, base): (usize, usize, Vec<u8>)) {
    let config = OrbConfig::default();
    let (fast, budgets) = (config.fast, config.level_budgets());
    let image = GrayImage::new(w, h, &base).expect("w x h pixels");
    c.bench_function(&format!("{name}: ImagePyramid::build 8 levels"), |b| {
        b.iter(|| black_box(ImagePyramid::build(&image, config.scale_factor, 8)))
    });
    c.bench_function(&format!("{name}: pyramid + smoothing, in the pool"), |b| {
        // as OrbExtractor::extract runs them: one entry into rayon's pool
        b.iter(|| {
            rayon::scope(|_| {
                let pyramid = ImagePyramid::build(&image, config.scale_factor, 8);
                let levels = pyramid
                    .as_ref()
                    .map(ImagePyramid::views)
                    .unwrap_or_default();
                black_box(levels.par_iter().map(smooth_for_brief).collect::<Vec<_>>())
            })
        })
    });
    let pyramid = ImagePyramid::build(&image, config.scale_factor, 8).expect("640 x 480");
    let views = pyramid.views();
    c.bench_function(&format!("{name}: smooth_for_brief 8 levels"), |b| {
        b.iter(|| black_box(views.par_iter().map(smooth_for_brief).collect::<Vec<_>>()))
    });
    c.bench_function(&format!("{name}: fast_corners level 0 (t = 7)"), |b| {
        b.iter(|| black_box(fast_corners(&views[0], 7, 19)))
    });
    c.bench_function(&format!("{name}: fast_corners level 0 (t = 20)"), |b| {
        b.iter(|| black_box(fast_corners(&views[0], 20, 19)))
    });
    c.bench_function(&format!("{name}: detect_level level 0"), |b| {
        b.iter(|| black_box(detect_level(&views[0], budgets[0], fast, None)))
    });
    c.bench_function(&format!("{name}: detect_pyramid 8 levels"), |b| {
        b.iter(|| black_box(detect_pyramid(&views, &budgets, fast, &[])))
    });
    let corners: Vec<(usize, usize, usize, f32)> = detect_pyramid(&views, &budgets, fast, &[])
        .iter()
        .enumerate()
        .flat_map(|(l, level)| {
            level
                .iter()
                .map(move |c| (l, c.corner.x as usize, c.corner.y as usize, c.angle_deg))
        })
        .collect();
    let smoothed: Vec<_> = views.iter().map(smooth_for_brief).collect();
    let smoothed: Vec<GrayImage<'_>> = smoothed.iter().map(|l| l.view()).collect();
    let brief = BriefPattern::opencv();
    let n = corners.len();
    c.bench_function(&format!("{name}: BRIEF describe_all ({n} corners)"), |b| {
        b.iter(|| black_box(brief.describe_all(&smoothed, &corners)))
    });
    let extractor = OrbExtractor::new(config).expect("ORB-SLAM's settings");
    c.bench_function(&format!("{name}: OrbExtractor::extract"), |b| {
        b.iter(|| black_box(extractor.extract(&image, None)))
    });
}

fn bench_extractor(c: &mut Criterion) {
    match tum_frame() {
        Some(frame) => bench_image(c, "tum", frame),
        None => eprintln!("TUM fr1/rpy not found (set FERROSLAM_DATA): synthetic image only"),
    }
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    bench_image(c, "synthetic", (640, 480, textured(640, 480, &mut rng)));
}

criterion_group!(benches, bench_extractor);
criterion_main!(benches);
