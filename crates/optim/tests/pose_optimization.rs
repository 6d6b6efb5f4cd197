//! Motion-only BA on synthetic scenes with planted gross outliers.
#![allow(non_snake_case)]

mod common;

use common::{gaussian, perturb, pose_error, project, random_point, K};
use ferroslam_geometry::se3;
use ferroslam_optim::residual::linearize;
use ferroslam_optim::{optimize_pose, OptimError, PoseObservation, RigCamera};
use nalgebra::{Isometry3, Matrix6, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const PIXEL_SIGMA: f64 = 0.5;
const OUTLIER_FRACTION: f64 = 0.2;
/// 99.9% quantile of chi-square with 6 dof.
const CHI2_6_999: f64 = 22.458;

struct PoseScene {
    T_true: Isometry3<f64>,
    T_init: Isometry3<f64>,
    obs: Vec<PoseObservation>,
    planted: Vec<bool>,
}

fn pose_scene(seed: u64, n: usize, stereo_fraction: f64) -> PoseScene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let T_true = common::true_poses(&mut rng, 1)[0];
    let mut obs = Vec::new();
    let mut planted = Vec::new();
    while obs.len() < n {
        let p_w = random_point(&mut rng);
        let Some((uv, z)) = project(&T_true, &p_w) else {
            continue;
        };
        let is_outlier = rng.random_bool(OUTLIER_FRACTION);
        let noise = Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * PIXEL_SIGMA;
        let uv_obs = if is_outlier {
            // A wrong match: anywhere in the image at least 20 px away from the truth.
            loop {
                let c = Vector2::new(
                    rng.random_range(0.0..common::WIDTH),
                    rng.random_range(0.0..common::HEIGHT),
                );
                if (c - uv).norm() > 20.0 {
                    break c;
                }
            }
        } else {
            uv + noise
        };
        let u_right = rng
            .random_bool(stereo_fraction)
            .then(|| uv_obs.x - K.bf / z + PIXEL_SIGMA * gaussian(&mut rng));
        obs.push(PoseObservation {
            camera: 0,
            p_w,
            uv: uv_obs,
            u_right,
            inv_sigma2: 1.0 / (PIXEL_SIGMA * PIXEL_SIGMA),
        });
        planted.push(is_outlier);
    }
    let T_init = perturb(&mut rng, &T_true, 0.05, 0.035);
    PoseScene {
        T_true,
        T_init,
        obs,
        planted,
    }
}

/// Gauss-Newton information of the pose from the true inliers, at the true pose.
fn information(s: &PoseScene) -> Matrix6<f64> {
    let mut h = Matrix6::zeros();
    for (o, &bad) in s.obs.iter().zip(&s.planted) {
        if !bad {
            let l = linearize(&K, &s.T_true, &o.p_w, &o.uv, o.u_right).unwrap();
            h += o.inv_sigma2 * l.d_e_d_xi.transpose() * l.d_e_d_xi;
        }
    }
    h
}

fn check_recovery(seed: u64, stereo_fraction: f64) {
    let s = pose_scene(seed, 200, stereo_fraction);
    let mut outlier = vec![false; s.obs.len()];
    let est = optimize_pose(&s.T_init, &s.obs, &[RigCamera::first(K)], &mut outlier).unwrap();

    // Accuracy judged against the estimator's own uncertainty: the error twist in the
    // information metric of the true inliers is chi-square(6) distributed, so the 99.9%
    // quantile is a bound that fails by chance once in a thousand seeds.
    let xi = se3::log(&(est.T_c_w * s.T_true.inverse()));
    let mahalanobis = xi.dot(&(information(&s) * xi));
    let (dt, dr) = pose_error(&est.T_c_w, &s.T_true);
    let (dt0, dr0) = pose_error(&s.T_init, &s.T_true);
    println!(
        "seed {seed} stereo {stereo_fraction}: error {:.3} mm {:.4} deg (initial {:.1} mm {:.2} deg), mahalanobis^2 {mahalanobis:.2}, inliers {}",
        dt * 1e3,
        dr.to_degrees(),
        dt0 * 1e3,
        dr0.to_degrees(),
        est.num_inliers
    );
    assert!(
        mahalanobis < CHI2_6_999,
        "seed {seed}: pose error outside the 99.9% confidence region"
    );
    // Absolute sanity bound (several sigma for this geometry: 160 inliers at 0.5 px, 5-12 m).
    assert!(
        dt < 0.01 && dr.to_degrees() < 0.05,
        "seed {seed}: {dt} m, {dr} rad"
    );

    // Every planted gross outlier is flagged; true inliers are flagged at about the test's
    // 5% false-alarm rate (bound 12%: > 3 binomial sigmas above 5% for 160 inliers).
    for (i, (&flag, &bad)) in outlier.iter().zip(&s.planted).enumerate() {
        assert!(!bad || flag, "seed {seed}: planted outlier {i} not flagged");
    }
    let inliers = s.planted.iter().filter(|&&b| !b).count();
    let false_alarms = outlier
        .iter()
        .zip(&s.planted)
        .filter(|(&f, &b)| f && !b)
        .count();
    assert!(
        (false_alarms as f64) < 0.12 * inliers as f64,
        "seed {seed}: {false_alarms} false alarms"
    );
    assert_eq!(est.num_inliers, outlier.iter().filter(|&&o| !o).count());
}

#[test]
fn recovers_mono_pose_with_20_percent_outliers() {
    for seed in [1, 2, 3] {
        check_recovery(seed, 0.0);
    }
}

#[test]
fn recovers_stereo_pose_with_20_percent_outliers() {
    for seed in [4, 5] {
        check_recovery(seed, 0.6);
    }
}

#[test]
fn initially_flagged_outliers_are_reclassified() {
    let s = pose_scene(9, 100, 0.0);
    // Start with every true inlier flagged too: round 0 only uses the unflagged ones
    // (the planted outliers), so the schedule must recover through re-classification.
    let mut outlier: Vec<bool> = s
        .planted
        .iter()
        .enumerate()
        .map(|(i, &b)| b || i % 2 == 0)
        .collect();
    let est = optimize_pose(&s.T_init, &s.obs, &[RigCamera::first(K)], &mut outlier).unwrap();
    let (dt, _) = pose_error(&est.T_c_w, &s.T_true);
    assert!(dt < 0.01, "{dt}");
}

#[test]
fn behind_camera_points_are_outliers() {
    let mut s = pose_scene(10, 50, 0.0);
    s.obs[0].p_w = s.T_true.inverse() * Vector3::new(0.0, 0.0, -3.0);
    let mut outlier = vec![false; s.obs.len()];
    optimize_pose(&s.T_init, &s.obs, &[RigCamera::first(K)], &mut outlier).unwrap();
    assert!(outlier[0]);
}

#[test]
fn degenerate_and_bad_input() {
    let T = Isometry3::identity();
    let est = optimize_pose(&T, &[], &[RigCamera::first(K)], &mut []).unwrap();
    assert_eq!(est.num_inliers, 0);
    assert_eq!(est.T_c_w, T);

    let s = pose_scene(11, 10, 0.0);
    assert!(matches!(
        optimize_pose(&T, &s.obs, &[RigCamera::first(K)], &mut [false; 3]),
        Err(OptimError::InvalidInput(_))
    ));
    let mut bad = s.obs.clone();
    bad[2].uv.x = f64::NAN;
    assert_eq!(
        optimize_pose(&T, &bad, &[RigCamera::first(K)], &mut [false; 10]).unwrap_err(),
        OptimError::NonFinite {
            what: "observation",
            index: 2
        }
    );
    let mut bad = s.obs.clone();
    bad[1].inv_sigma2 = 0.0;
    assert!(matches!(
        optimize_pose(&T, &bad, &[RigCamera::first(K)], &mut [false; 10]),
        Err(OptimError::InvalidInput(_))
    ));
}

/// Rounds stop early once a step gains little (see `pose.rs`): the last round must still end
/// at the least-squares optimum of its inliers, well inside the pose's own uncertainty. The
/// Newton decrement `g^T H^-1 g` is the squared Mahalanobis distance from there to the
/// optimum of the local quadratic model.
#[test]
fn rounds_end_at_the_optimum_of_their_inliers() {
    for (seed, stereo_fraction) in [(1, 0.0), (2, 0.0), (4, 0.6), (5, 0.6)] {
        let s = pose_scene(seed, 200, stereo_fraction);
        let mut outlier = vec![false; s.obs.len()];
        let est = optimize_pose(&s.T_init, &s.obs, &[RigCamera::first(K)], &mut outlier).unwrap();
        let (mut h, mut g) = (Matrix6::zeros(), Vector6::zeros());
        for (o, _) in s.obs.iter().zip(&outlier).filter(|(_, &bad)| !bad) {
            let l = linearize(&K, &est.T_c_w, &o.p_w, &o.uv, o.u_right).unwrap();
            h += o.inv_sigma2 * l.d_e_d_xi.transpose() * l.d_e_d_xi;
            g += o.inv_sigma2 * l.d_e_d_xi.transpose() * l.e;
        }
        let decrement = g.dot(&h.cholesky().unwrap().solve(&g));
        println!("seed {seed}: Newton decrement {decrement:.3e}");
        assert!(decrement < 1e-3, "seed {seed}: {decrement}");
    }
}
