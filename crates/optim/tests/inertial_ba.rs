//! Visual-inertial local bundle adjustment on a seeded synthetic flight: analytic body
//! trajectory, a simulated 200 Hz IMU with EuRoC noise and constant biases, monocular
//! keyframes at 10 Hz looking at a wall of points.
#![allow(non_snake_case)]

mod common;

use common::{gaussian, gaussian3, pose_error, project, K};
use ferroslam_geometry::so3;
use ferroslam_imu::{Bias, BiasWalkFactor, ImuParams, InertialFactor, Preintegrated};
use ferroslam_optim::{
    inertial_bundle_adjust, local_bundle_adjust, BaProblem, InertialBaOptions, InertialBaProblem,
    InertialEdge, Observation, OptimError,
};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);
/// IMU step, seconds (200 Hz).
const IMU_DT: f64 = 0.005;
/// IMU steps between keyframes (10 Hz).
const STEPS_PER_KEYFRAME: usize = 20;

fn true_bias() -> Bias {
    Bias::new(
        Vector3::new(0.01, -0.02, 0.015),
        Vector3::new(0.05, -0.08, 0.1),
    )
}

/// Body position (m) and velocity (m/s) in the world (z up), analytic.
fn body_position(t: f64) -> (Vector3<f64>, Vector3<f64>) {
    (
        Vector3::new(
            0.8 * t + 0.15 * (2.1 * t).sin(),
            0.25 * (1.7 * t).sin(),
            0.1 * (2.9 * t).sin(),
        ),
        Vector3::new(
            0.8 + 0.315 * (2.1 * t).cos(),
            0.425 * (1.7 * t).cos(),
            0.29 * (2.9 * t).cos(),
        ),
    )
}

/// Camera-to-body extrinsic (EuRoC-like: camera axes permuted w.r.t. the IMU, a few cm off).
fn T_b_c() -> Isometry3<f64> {
    let R_b_c = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    Isometry3::from_parts(
        Translation3::new(-0.02, 0.065, 0.01),
        UnitQuaternion::from_matrix(&R_b_c)
            * UnitQuaternion::from_scaled_axis(Vector3::new(0.02, -0.01, 0.03)),
    )
}

/// Body orientation: the camera looks along world +y (image down = world -z), wobbling.
fn body_rotation(t: f64) -> UnitQuaternion<f64> {
    let R_w_c0 = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
    let R0 = UnitQuaternion::from_matrix(&R_w_c0) * T_b_c().rotation.inverse();
    R0 * UnitQuaternion::from_scaled_axis(Vector3::new(
        0.15 * (1.3 * t).sin(),
        0.1 * (1.9 * t + 0.5).sin(),
        0.2 * (0.9 * t).sin(),
    ))
}

fn body_pose(t: f64) -> Isometry3<f64> {
    Isometry3::from_parts(body_position(t).0.into(), body_rotation(t))
}

/// IMU readings over step `[t, t + IMU_DT]` that the preintegration integrates to the true
/// motion (exactly for rotation and velocity, to O(dt^2) for position), plus bias and noise.
fn imu_reading(t: f64, rng: &mut impl Rng, params: &ImuParams) -> (Vector3<f64>, Vector3<f64>) {
    let (R0, R1) = (body_rotation(t), body_rotation(t + IMU_DT));
    let (v0, v1) = (body_position(t).1, body_position(t + IMU_DT).1);
    let gyro = so3::log(&(R0.inverse() * R1)) / IMU_DT
        + true_bias().gyro
        + gaussian3(rng, params.gyro_noise_density / IMU_DT.sqrt());
    let accel = R0.inverse() * ((v1 - v0) / IMU_DT - GRAVITY)
        + true_bias().accel
        + gaussian3(rng, params.accel_noise_density / IMU_DT.sqrt());
    (gyro, accel)
}

struct Truth {
    poses: Vec<Isometry3<f64>>,
    velocities: Vec<Vector3<f64>>,
}

/// The problem AT THE TRUE STATE except for the biases (zero, their initial guess) with noisy
/// measurements. Keyframe 0's pose is fixed (the gauge), every velocity and bias is free.
/// Preintegrations are linearised at zero bias.
fn flight(seed: u64, keyframes: usize, points: usize) -> (InertialBaProblem, Truth) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let params = ImuParams::euroc();
    let kf_time = |k: usize| (k * STEPS_PER_KEYFRAME) as f64 * IMU_DT;
    let poses: Vec<Isometry3<f64>> = (0..keyframes)
        .map(|k| (body_pose(kf_time(k)) * T_b_c()).inverse())
        .collect();
    let velocities: Vec<Vector3<f64>> = (0..keyframes)
        .map(|k| body_position(kf_time(k)).1)
        .collect();
    let inertial_edges = (1..keyframes)
        .map(|j| {
            let mut pre = Preintegrated::new(Bias::default(), &params).unwrap();
            for s in 0..STEPS_PER_KEYFRAME {
                let t = kf_time(j - 1) + s as f64 * IMU_DT;
                let (gyro, accel) = imu_reading(t, &mut rng, &params);
                pre.integrate(IMU_DT, &gyro, &accel).unwrap();
            }
            InertialEdge {
                i: j - 1,
                j,
                factor: InertialFactor::new(pre, GRAVITY).unwrap(),
                bias_walk: BiasWalkFactor::new(&params, kf_time(1)).unwrap(),
            }
        })
        .collect();
    let mut true_points = Vec::new();
    let mut observations = Vec::new();
    while true_points.len() < points {
        let p = Vector3::new(
            rng.random_range(-2.5..4.5),
            rng.random_range(3.0..7.0),
            rng.random_range(-1.5..1.5),
        );
        let seen: Vec<(usize, Vector2<f64>)> = poses
            .iter()
            .enumerate()
            .filter_map(|(k, T)| project(T, &p).map(|(uv, _)| (k, uv)))
            .collect();
        if seen.len() < 2 {
            continue;
        }
        for (pose, uv) in seen {
            observations.push(Observation {
                pose,
                point: true_points.len(),
                uv: uv + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)),
                u_right: None,
                inv_sigma2: 1.0,
            });
        }
        true_points.push(p);
    }
    let mut pose_fixed = vec![false; keyframes];
    pose_fixed[0] = true;
    let problem = InertialBaProblem {
        visual: BaProblem {
            intrinsics: K,
            poses: poses.clone(),
            pose_fixed,
            points: true_points,
            observations,
        },
        T_b_c: T_b_c(),
        velocities: velocities.clone(),
        biases: vec![Bias::default(); keyframes],
        inertial_fixed: vec![false; keyframes],
        inertial_edges,
    };
    let truth = Truth { poses, velocities };
    (problem, truth)
}

/// Largest errors over the keyframes: camera position (m), rotation (rad),
/// velocity (m/s), gyro bias (rad/s), accelerometer bias (m/s^2).
#[derive(Debug)]
struct Errors {
    position: f64,
    rotation: f64,
    velocity: f64,
    gyro_bias: f64,
    accel_bias: f64,
}

fn errors(p: &InertialBaProblem, truth: &Truth) -> Errors {
    let mut e = Errors {
        position: 0.0,
        rotation: 0.0,
        velocity: 0.0,
        gyro_bias: 0.0,
        accel_bias: 0.0,
    };
    for k in 0..truth.poses.len() {
        let c = p.visual.poses[k].inverse().translation.vector;
        let c_true = truth.poses[k].inverse().translation.vector;
        e.position = e.position.max((c - c_true).norm());
        e.rotation = e
            .rotation
            .max(pose_error(&p.visual.poses[k], &truth.poses[k]).1);
        e.velocity = e
            .velocity
            .max((p.velocities[k] - truth.velocities[k]).norm());
        e.gyro_bias = e
            .gyro_bias
            .max((p.biases[k].gyro - true_bias().gyro).norm());
        e.accel_bias = e
            .accel_bias
            .max((p.biases[k].accel - true_bias().accel).norm());
    }
    e
}

/// The accuracy the optimum reaches on these flights, about twice the largest errors measured
/// over the seeds below (0.0098 m, 0.0013 rad, 0.0094 m/s, 6.3e-4 rad/s, 0.0052 m/s^2; the
/// true biases have norms 0.027 rad/s and 0.137 m/s^2 and start at zero). Without noise the
/// solver lands on the truth to 2e-5 m (the simulation's position integration error): these
/// errors are the statistical ones of 1-pixel monocular noise and EuRoC's IMU noise.
fn assert_accurate(what: &str, e: &Errors) {
    let ok = e.position < 0.02
        && e.rotation < 0.003
        && e.velocity < 0.02
        && e.gyro_bias < 1.5e-3
        && e.accel_bias < 0.015;
    assert!(ok, "{what}: {e:?}");
}

/// Least-squares scale of the camera centres relative to keyframe 0, estimate vs truth.
fn trajectory_scale(poses: &[Isometry3<f64>], truth: &Truth) -> f64 {
    let centre = |T: &Isometry3<f64>| T.inverse().translation.vector;
    let (c0, t0) = (centre(&poses[0]), centre(&truth.poses[0]));
    let (mut num, mut den) = (0.0, 0.0);
    for (T, T_true) in poses.iter().zip(&truth.poses) {
        let d_true = centre(T_true) - t0;
        num += (centre(T) - c0).dot(&d_true);
        den += d_true.norm_squared();
    }
    num / den
}

#[test]
fn recovers_perturbed_poses_velocities_and_biases() {
    let (mut p, truth) = flight(1, 21, 250);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for k in 1..p.visual.poses.len() {
        p.visual.poses[k] = common::perturb(&mut rng, &p.visual.poses[k], 0.05, 0.02);
        p.velocities[k] += gaussian3(&mut rng, 0.2);
    }
    for x in &mut p.visual.points {
        *x += gaussian3(&mut rng, 0.05);
    }
    let before = errors(&p, &truth);
    let result = inertial_bundle_adjust(&mut p, &InertialBaOptions::default()).unwrap();
    let after = errors(&p, &truth);
    println!(
        "before: {:.4} m {:.4} rad {:.4} m/s; after: {:.5} m {:.5} rad {:.5} m/s, b_g {:.5} rad/s, b_a {:.4} m/s^2; cost {:.1} -> {:.1} in {} iterations",
        before.position, before.rotation, before.velocity, after.position, after.rotation,
        after.velocity, after.gyro_bias, after.accel_bias, result.report.initial_cost,
        result.report.final_cost, result.report.iterations
    );
    assert!(result.report.final_cost < 0.01 * result.report.initial_cost);
    assert_accurate("perturbed start", &after);
    // Noise-only residuals: about 5% of monocular observations exceed chi2 = 5.991.
    let outliers = result.outlier.iter().filter(|&&o| o).count() as f64;
    assert!(outliers / (result.outlier.len() as f64) < 0.08);
}

/// The flight blown up by `s` about camera 0's centre (cameras, points, velocities): every
/// image observation is unchanged, so monocular vision cannot tell it from the truth.
fn scaled(p: &InertialBaProblem, s: f64) -> InertialBaProblem {
    let mut out = p.clone();
    let c0 = p.visual.poses[0].inverse().translation.vector;
    let scale = |x: &Vector3<f64>| c0 + s * (x - c0);
    for T in out.visual.poses.iter_mut().skip(1) {
        let T_w_c = T.inverse();
        *T = Isometry3::from_parts(scale(&T_w_c.translation.vector).into(), T_w_c.rotation)
            .inverse();
    }
    for x in &mut out.visual.points {
        *x = scale(x);
    }
    for v in out.velocities.iter_mut().skip(1) {
        *v *= s;
    }
    out
}

#[test]
fn inertial_terms_recover_the_metric_scale_that_monocular_vision_cannot() {
    let (p, truth) = flight(2, 21, 250);
    let start = scaled(&p, 1.25);
    assert!((trajectory_scale(&start.visual.poses, &truth) - 1.25).abs() < 1e-12);

    // Vision alone (same fixed keyframe, same observations): the scale does not move.
    let mut visual = start.visual.clone();
    local_bundle_adjust(&mut visual).unwrap();
    let visual_scale = trajectory_scale(&visual.poses, &truth);

    let mut inertial = start.clone();
    let result = inertial_bundle_adjust(&mut inertial, &InertialBaOptions::default()).unwrap();
    let inertial_scale = trajectory_scale(&inertial.visual.poses, &truth);
    let e = errors(&inertial, &truth);
    println!(
        "scale: start 1.25, visual BA {visual_scale:.5}, inertial BA {inertial_scale:.5} \
         ({} iterations); after: {:.5} m, {:.5} m/s, b_g {:.6}, b_a {:.4}",
        result.report.iterations, e.position, e.velocity, e.gyro_bias, e.accel_bias
    );
    assert!(
        (visual_scale - 1.25).abs() < 0.01,
        "visual scale {visual_scale}"
    );
    assert!(
        (inertial_scale - 1.0).abs() < 0.01,
        "inertial scale {inertial_scale}"
    );
    assert_accurate("scaled start", &e);
}

#[test]
fn gross_outliers_are_classified_and_do_not_bias_the_estimate() {
    let (mut p, truth) = flight(3, 16, 200);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    // Every 40th observation moved by 40 pixels (chi2 = 1600 >> 5.991).
    let corrupted: Vec<usize> = (0..p.visual.observations.len()).step_by(40).collect();
    for &i in &corrupted {
        let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        p.visual.observations[i].uv += 40.0 * Vector2::new(angle.cos(), angle.sin());
    }
    for k in 1..p.visual.poses.len() {
        p.visual.poses[k] = common::perturb(&mut rng, &p.visual.poses[k], 0.03, 0.01);
        p.velocities[k] += gaussian3(&mut rng, 0.1);
    }
    // Keyframe 0 as ORB-SLAM3's keyframe before the window: velocity and biases held.
    p.inertial_fixed[0] = true;
    p.biases[0] = true_bias();
    let options = InertialBaOptions {
        plain_iterations: 10,
        ..InertialBaOptions::default()
    };
    let result = inertial_bundle_adjust(&mut p, &options).unwrap();
    assert_eq!(p.velocities[0], truth.velocities[0]);
    assert_eq!(p.biases[0], true_bias());
    let e = errors(&p, &truth);
    let clean_flagged = (0..result.outlier.len())
        .filter(|i| result.outlier[*i] && !corrupted.contains(i))
        .count();
    println!(
        "{} corrupted, all flagged: {}; clean flagged {clean_flagged} of {}; {:.5} m {:.5} m/s",
        corrupted.len(),
        corrupted.iter().all(|&i| result.outlier[i]),
        result.outlier.len() - corrupted.len(),
        e.position,
        e.velocity
    );
    assert!(corrupted.iter().all(|&i| result.outlier[i]));
    assert!((clean_flagged as f64) < 0.08 * (result.outlier.len() - corrupted.len()) as f64);
    assert_accurate("with outliers", &e);
}

#[test]
fn nothing_free_leaves_the_problem_unchanged() {
    let (mut p, _) = flight(4, 4, 30);
    p.visual.pose_fixed = vec![true; 4];
    p.inertial_fixed = vec![true; 4];
    p.velocities[2] += Vector3::new(0.5, 0.0, 0.0);
    let before = p.clone();
    let result = inertial_bundle_adjust(&mut p, &InertialBaOptions::default()).unwrap();
    assert_eq!(result.report.iterations, 0);
    assert_eq!(result.outlier.len(), p.visual.observations.len());
    assert_eq!(p, before);
}

type Mutation<'a> = &'a dyn Fn(&mut InertialBaProblem);

#[test]
fn invalid_input_is_an_error_and_changes_nothing() {
    let (p, _) = flight(5, 4, 30);
    let options = InertialBaOptions::default();
    let check = |what: &str, mutate: &dyn Fn(&mut InertialBaProblem), opts: &InertialBaOptions| {
        let mut bad = p.clone();
        mutate(&mut bad);
        let before = bad.clone();
        let err = inertial_bundle_adjust(&mut bad, opts).expect_err(what);
        // Compared as text: NaN inputs are not equal to themselves.
        assert!(
            format!("{bad:?}") == format!("{before:?}"),
            "{what}: problem changed"
        );
        err
    };
    let lengths: [(&str, Mutation); 3] = [
        ("velocities", &|q| {
            q.velocities.pop();
        }),
        ("biases", &|q| q.biases.push(Bias::default())),
        ("inertial_fixed", &|q| q.inertial_fixed.clear()),
    ];
    for (what, mutate) in lengths {
        let err = check(what, mutate, &options);
        assert!(
            matches!(&err, OptimError::InvalidInput(m) if m.starts_with(what)),
            "{what}: {err}"
        );
    }
    for (j, what) in [(4, "index out of range"), (0, "i == j")] {
        let err = check(what, &|q| q.inertial_edges[0].j = j, &options);
        assert!(matches!(err, OptimError::InvalidInput(m) if m.contains("inertial edge 0")));
    }
    let non_finite: [(&str, Mutation); 4] = [
        ("velocity", &|q| q.velocities[2].y = f64::NAN),
        ("bias", &|q| q.biases[3].accel.z = f64::INFINITY),
        ("T_b_c", &|q| q.T_b_c.translation.x = f64::NAN),
        ("pose", &|q| q.visual.poses[1].translation.z = f64::NAN),
    ];
    for (what, mutate) in non_finite {
        let err = check(what, mutate, &options);
        assert!(
            matches!(err, OptimError::NonFinite { what: w, .. } if w == what),
            "{what}: {err:?}"
        );
    }
    let err = check(
        "observation index",
        &|q| q.visual.observations[0].point = 10_000,
        &options,
    );
    assert!(matches!(
        err,
        OptimError::IndexOutOfRange { what: "point", .. }
    ));
    for opts in [
        InertialBaOptions {
            initial_lambda: 0.0,
            ..options
        },
        InertialBaOptions {
            initial_lambda: f64::NAN,
            ..options
        },
        InertialBaOptions {
            function_tolerance: -1.0,
            ..options
        },
    ] {
        let err = check("options", &|_| {}, &opts);
        assert!(matches!(err, OptimError::InvalidInput(_)));
    }
}

/// Release timing of a typical window: `cargo test --release -p ferroslam-optim --test
/// inertial_ba -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing_15_keyframes_1500_points() {
    let (mut p, truth) = flight(6, 16, 1500);
    p.visual.pose_fixed[0] = true;
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    for k in 1..p.visual.poses.len() {
        p.visual.poses[k] = common::perturb(&mut rng, &p.visual.poses[k], 0.02, 0.005);
        p.velocities[k] += gaussian3(&mut rng, 0.05);
    }
    for x in &mut p.visual.points {
        *x += gaussian3(&mut rng, 0.02);
    }
    let t = Instant::now();
    let result = inertial_bundle_adjust(&mut p, &InertialBaOptions::default()).unwrap();
    let elapsed = t.elapsed();
    let e = errors(&p, &truth);
    println!(
        "15 free keyframes + 1 fixed, {} points, {} observations: {:.1} ms, {} iterations, {:.5} m",
        p.visual.points.len(),
        p.visual.observations.len(),
        elapsed.as_secs_f64() * 1e3,
        result.report.iterations,
        e.position
    );
    assert_accurate("timing window", &e);
}
