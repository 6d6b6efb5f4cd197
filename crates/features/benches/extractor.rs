//! ORB-SLAM keypoint detection (FAST, fallback, spread, orientation): level 0 alone and the
//! 8-level pyramid (budgets of 1000 features), then rotated BRIEF of the pyramid's corners
//! (seeded random tests: OpenCV's come from `cv2.ORB` at run time), on the first TUM fr1/rpy
//! frame (640 x 480, from `FERROSLAM_DATA`, default `../shared/data` beside the repository)
//! and on a seeded synthetic image of random blobs (corners everywhere, the hard case).

use criterion::{criterion_group, criterion_main, Criterion};
use ferroslam_features::extractor::brief::{BriefPattern, BriefTest};
use ferroslam_features::extractor::{
    detect_level, detect_pyramid, fast::fast_corners, FastThresholds,
};
use ferroslam_features::GrayImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const FAST: FastThresholds = FastThresholds {
    initial: 20,
    min: 7,
};
const BUDGETS: [usize; 8] = [217, 181, 151, 126, 105, 87, 73, 60];

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

/// Bilinear halving by `scale` (enough for a benchmark pyramid).
fn downscale(src: &[u8], w: usize, h: usize, scale: f64) -> (usize, usize, Vec<u8>) {
    let (nw, nh) = (
        (w as f64 / scale).round() as usize,
        (h as f64 / scale).round() as usize,
    );
    let data = (0..nh)
        .flat_map(|y| (0..nw).map(move |x| (x, y)))
        .map(|(x, y)| {
            src[((y as f64 * scale) as usize).min(h - 1) * w
                + ((x as f64 * scale) as usize).min(w - 1)]
        })
        .collect();
    (nw, nh, data)
}

fn bench_image(c: &mut Criterion, name: &str, (w, h, base): (usize, usize, Vec<u8>)) {
    let levels: Vec<(usize, usize, Vec<u8>)> = (0..8)
        .map(|l| downscale(&base, w, h, 1.2f64.powi(l)))
        .collect();
    let views: Vec<GrayImage<'_>> = levels
        .iter()
        .map(|(w, h, d)| GrayImage::new(*w, *h, d).unwrap())
        .collect();
    c.bench_function(&format!("{name}: fast_corners level 0 (t = 7)"), |b| {
        b.iter(|| black_box(fast_corners(&views[0], 7, 19)))
    });
    c.bench_function(&format!("{name}: fast_corners level 0 (t = 20)"), |b| {
        b.iter(|| black_box(fast_corners(&views[0], 20, 19)))
    });
    c.bench_function(&format!("{name}: detect_level level 0"), |b| {
        b.iter(|| black_box(detect_level(&views[0], BUDGETS[0], FAST)))
    });
    c.bench_function(&format!("{name}: detect_pyramid 8 levels"), |b| {
        b.iter(|| black_box(detect_pyramid(&views, &BUDGETS, FAST)))
    });
    let corners: Vec<(usize, usize, usize, f32)> = detect_pyramid(&views, &BUDGETS, FAST)
        .iter()
        .enumerate()
        .flat_map(|(l, level)| {
            level
                .iter()
                .map(move |c| (l, c.corner.x as usize, c.corner.y as usize, c.angle_deg))
        })
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut offset = || [rng.random_range(-13..=13), rng.random_range(-13..=13)];
    let tests = std::array::from_fn(|_| BriefTest {
        first: offset(),
        second: offset(),
    });
    let brief = BriefPattern::new(&tests);
    let n = corners.len();
    c.bench_function(&format!("{name}: BRIEF describe_all ({n} corners)"), |b| {
        b.iter(|| black_box(brief.describe_all(&views, &corners)))
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
