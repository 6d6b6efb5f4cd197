//! Umeyama, triangulation and PnP on synthetic scenes.

mod common;

use approx::assert_relative_eq;
use common::*;
use ferroslam_geometry::camera::{test_cameras, PinholeCamera};
use ferroslam_geometry::pnp::{pnp_ransac, PnpRansacOptions};
use ferroslam_geometry::se3;
use ferroslam_geometry::sim3::Sim3;
use ferroslam_geometry::triangulation::{parallax_cos, triangulate_dlt};
use ferroslam_geometry::umeyama::umeyama;
use nalgebra::{Isometry3, Point3, Vector2, Vector3, Vector6};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn umeyama_recovers_sim3(s in sim3(), src in prop::collection::vec(point(), 6..30)) {
        let dst: Vec<_> = src.iter().map(|p| s.transform_point(p)).collect();
        let est = umeyama(&src, &dst, true).unwrap();
        assert_relative_eq!(est.scale, s.scale, max_relative = 1e-9);
        assert_relative_eq!(est.translation, s.translation, epsilon = 1e-8);
        prop_assert!(rotation_error(&est.rotation, &s.rotation) < 1e-9);
    }

    #[test]
    fn umeyama_recovers_se3(t in isometry(), src in prop::collection::vec(point(), 6..30)) {
        let dst: Vec<_> = src.iter().map(|p| (t * Point3::from(*p)).coords).collect();
        let est = umeyama(&src, &dst, false).unwrap();
        assert_relative_eq!(est.scale, 1.0);
        assert_relative_eq!(est.translation, t.translation.vector, epsilon = 1e-8);
        prop_assert!(rotation_error(&est.rotation, &t.rotation) < 1e-9);
    }

    #[test]
    fn unproject_is_parallel_to_projected_point(p in prop::array::uniform3(-5.0..5.0f64), z in 0.1..50.0f64) {
        for (_, c) in test_cameras() {
            let p_c = Vector3::new(p[0], p[1], z);
            let ray = c.unproject(&c.project(&p_c).unwrap());
            assert_relative_eq!(ray * z, p_c, epsilon = 1e-9 * p_c.norm());
        }
    }
}

/// Zero-mean Gaussian sample by Box-Muller.
fn gaussian(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
    sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[allow(non_snake_case)]
struct Scene {
    T_c_w: Isometry3<f64>,
    points_w: Vec<Vector3<f64>>,
    pixels: Vec<Vector2<f64>>,
    is_outlier: Vec<bool>,
}

/// `n` points 1-20 m in front of `camera`, seen with Gaussian pixel noise; a fraction of
/// the matches replaced by random pixels.
fn scene(seed: u64, camera: &PinholeCamera, n: usize, outlier_ratio: f64, noise_px: f64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    #[allow(non_snake_case)]
    let T_c_w = se3::exp(&Vector6::from_fn(|i, _| {
        rng.random_range(-1.0..1.0) * if i < 3 { 3.0 } else { 1.0 }
    }));
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let mut scene = Scene {
        T_c_w,
        points_w: vec![],
        pixels: vec![],
        is_outlier: vec![],
    };
    for _ in 0..n {
        let uv = Vector2::new(rng.random_range(0.0..w), rng.random_range(0.0..h));
        let p_c = camera.unproject(&uv) * rng.random_range(1.0..20.0);
        scene
            .points_w
            .push((T_c_w.inverse() * Point3::from(p_c)).coords);
        let outlier = rng.random::<f64>() < outlier_ratio;
        scene.is_outlier.push(outlier);
        scene.pixels.push(if outlier {
            Vector2::new(rng.random_range(0.0..w), rng.random_range(0.0..h))
        } else {
            uv + Vector2::new(gaussian(&mut rng, noise_px), gaussian(&mut rng, noise_px))
        });
    }
    scene
}

#[test]
fn pnp_ransac_recovers_pose_with_outliers_and_noise() {
    for (name, camera) in test_cameras() {
        for seed in 0..5 {
            let s = scene(seed, &camera, 200, 0.3, 0.5);
            let sol = pnp_ransac(
                &s.points_w,
                &s.pixels,
                &[],
                &camera.into(),
                &PnpRansacOptions {
                    seed,
                    ..Default::default()
                },
            )
            .unwrap_or_else(|| panic!("{name} seed {seed}: no pose"));
            let err = sol.T_c_w.inverse() * s.T_c_w;
            let (dt, dr) = (
                err.translation.vector.norm(),
                err.rotation.angle().to_degrees(),
            );
            assert!(
                dt < 0.01 && dr < 0.1,
                "{name} seed {seed}: error {dt} m, {dr} deg"
            );
            let missed = s
                .is_outlier
                .iter()
                .zip(&sol.inliers)
                .filter(|(o, i)| !**o && !**i)
                .count();
            assert!(
                missed <= 2,
                "{name} seed {seed}: {missed} true inliers rejected"
            );
        }
    }
}

#[test]
fn pnp_ransac_is_deterministic_for_a_seed() {
    let (_, camera) = test_cameras()[1];
    let s = scene(3, &camera, 100, 0.4, 1.0);
    let opts = PnpRansacOptions {
        seed: 42,
        ..Default::default()
    };
    assert_eq!(
        pnp_ransac(&s.points_w, &s.pixels, &[], &camera.into(), &opts),
        pnp_ransac(&s.points_w, &s.pixels, &[], &camera.into(), &opts)
    );
}

#[test]
fn pnp_ransac_uses_sigma2_to_scale_the_threshold() {
    let (_, camera) = test_cameras()[0];
    let s = scene(11, &camera, 100, 0.0, 3.0); // 3 px noise: beyond the unit-sigma threshold
    let opts = PnpRansacOptions::default();
    let tight = pnp_ransac(&s.points_w, &s.pixels, &[], &camera.into(), &opts)
        .map_or(0, |p| p.inliers.iter().filter(|&&b| b).count());
    let loose = pnp_ransac(&s.points_w, &s.pixels, &[9.0; 100], &camera.into(), &opts).unwrap();
    assert!(
        loose.inliers.iter().filter(|&&b| b).count() > tight.max(90),
        "sigma2 = 9 should accept ~all"
    );
}

#[test]
fn pnp_ransac_returns_none_below_min_inliers() {
    let (_, camera) = test_cameras()[0];
    let s = scene(5, &camera, 100, 1.0, 0.5);
    assert!(pnp_ransac(
        &s.points_w,
        &s.pixels,
        &[],
        &camera.into(),
        &PnpRansacOptions::default()
    )
    .is_none());
    let s = scene(6, &camera, 100, 0.8, 0.5);
    let inliers = s.is_outlier.iter().filter(|o| !**o).count();
    let opts = PnpRansacOptions {
        min_inliers: inliers + 10,
        ..Default::default()
    };
    assert!(pnp_ransac(&s.points_w, &s.pixels, &[], &camera.into(), &opts).is_none());
}

#[test]
fn triangulation_two_view_with_noise() {
    let (_, camera) = test_cameras()[0];
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    #[allow(non_snake_case)]
    let (T_c1_w, T_c2_w) = (
        Isometry3::identity(),
        se3::exp(&Vector6::new(-0.5, 0.05, 0.02, 0.01, -0.05, 0.02)),
    );
    let (c1, c2) = (
        T_c1_w.inverse().translation.vector,
        T_c2_w.inverse().translation.vector,
    );
    for _ in 0..100 {
        let p_w = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-1.5..1.5),
            rng.random_range(2.0..6.0),
        );
        let observe = |t: &Isometry3<f64>, rng: &mut ChaCha8Rng| {
            let uv = camera.project(&(t * Point3::from(p_w)).coords).unwrap();
            camera.unproject(&(uv + Vector2::new(gaussian(rng, 0.5), gaussian(rng, 0.5))))
        };
        let (x1, x2) = (observe(&T_c1_w, &mut rng), observe(&T_c2_w, &mut rng));
        let est = triangulate_dlt(&T_c1_w, &T_c2_w, &x1, &x2).unwrap();
        // Depth error grows as z^2 / (f b) per pixel: ~0.07 m per px at 6 m.
        assert!(
            (est - p_w).norm() < 0.05 * p_w.z * p_w.z / 6.0 + 0.05,
            "{est} vs {p_w}"
        );
        assert!(parallax_cos(&est, &c1, &c2) < 0.9999);
    }
}

#[test]
fn sim3_unit_scale_conversion_is_lossless() {
    let t = se3::exp(&Vector6::new(0.3, 0.2, -0.1, 0.5, -0.4, 0.3));
    assert_relative_eq!(
        Sim3::from_isometry(&t).to_isometry_unscaled(),
        t,
        epsilon = 1e-15
    );
}
