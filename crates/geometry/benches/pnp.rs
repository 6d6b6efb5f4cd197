//! Relocalisation's pose solvers: EPnP on a 5-point inlier sample, and PnP-RANSAC on 300
//! matches of which 40 % are outliers (TUM-like camera, 1 px noise), seeded.

use criterion::{criterion_group, criterion_main, Criterion};
use ferroslam_geometry::camera::{PinholeCamera, RadTan};
use ferroslam_geometry::epnp::epnp;
use ferroslam_geometry::pnp::{pnp_ransac, PnpRansacOptions};
use ferroslam_geometry::se3;
use nalgebra::{Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const MATCHES: usize = 300;
const OUTLIER_SHARE: f64 = 0.4;

#[allow(non_snake_case)]
fn pnp(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let camera = PinholeCamera::new(517.3, 516.5, 318.6, 255.3, RadTan::default(), 640, 480)
        .expect("valid camera");
    let T_c_w = se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-0.5..0.5)));
    let mut points_w = Vec::with_capacity(MATCHES);
    let mut pixels = Vec::with_capacity(MATCHES);
    let mut inliers = Vec::new();
    while points_w.len() < MATCHES {
        let p_c = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-1.5..1.5),
            rng.random_range(1.0..5.0),
        );
        let Some(uv) = camera.project(&p_c) else {
            continue;
        };
        let noise = Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let outlier = rng.random_bool(OUTLIER_SHARE);
        if !outlier {
            inliers.push(points_w.len());
        }
        let uv = if outlier {
            Vector2::new(rng.random_range(0.0..640.0), rng.random_range(0.0..480.0))
        } else {
            uv + noise
        };
        points_w.push(T_c_w.inverse_transform_point(&p_c.into()).coords);
        pixels.push(uv);
    }
    let sample_w: Vec<Vector3<f64>> = inliers[..5].iter().map(|&i| points_w[i]).collect();
    let sample_rays: Vec<Vector3<f64>> = inliers[..5]
        .iter()
        .map(|&i| camera.unproject(&pixels[i]))
        .collect();
    let solution = pnp_ransac(
        &points_w,
        &pixels,
        &[],
        &camera.into(),
        &PnpRansacOptions::default(),
    )
    .expect("a pose");
    eprintln!(
        "pnp scene: {MATCHES} matches, {} inliers found, translation error {:.2e} m",
        solution.inliers.iter().filter(|&&i| i).count(),
        (solution.T_c_w.translation.vector - T_c_w.translation.vector).norm()
    );
    let mut group = c.benchmark_group("pnp");
    group.bench_function("epnp_5_points", |b| {
        b.iter(|| epnp(&sample_w, &sample_rays))
    });
    group.bench_function("pnp_ransac_300_matches_40pct_outliers", |b| {
        b.iter(|| {
            pnp_ransac(
                &points_w,
                &pixels,
                &[],
                &camera.into(),
                &PnpRansacOptions::default(),
            )
        })
    });
    group.finish();
}

criterion_group!(benches, pnp);
criterion_main!(benches);
