//! A seeded synthetic flight for visual-inertial BA, shared by the tests and the benchmark:
//! analytic body trajectory, a simulated 200 Hz IMU with EuRoC noise and constant biases,
//! monocular keyframes at 10 Hz looking at a wall of points.

use ferroslam_geometry::so3;
use ferroslam_imu::{Bias, BiasWalkFactor, ImuParams, InertialFactor, Preintegrated};
use ferroslam_optim::{BaProblem, InertialBaProblem, InertialEdge, Observation, RigCamera};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{gaussian, gaussian3, project, K};

pub const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);
/// IMU step, seconds (200 Hz).
pub const IMU_DT: f64 = 0.005;
/// IMU steps between keyframes (10 Hz).
pub const STEPS_PER_KEYFRAME: usize = 20;

pub fn true_bias() -> Bias {
    Bias::new(
        Vector3::new(0.01, -0.02, 0.015),
        Vector3::new(0.05, -0.08, 0.1),
    )
}

/// Body position (m) and velocity (m/s) in the world (z up), analytic.
pub fn body_position(t: f64) -> (Vector3<f64>, Vector3<f64>) {
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
pub fn T_b_c() -> Isometry3<f64> {
    let R_b_c = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    Isometry3::from_parts(
        Translation3::new(-0.02, 0.065, 0.01),
        UnitQuaternion::from_matrix(&R_b_c)
            * UnitQuaternion::from_scaled_axis(Vector3::new(0.02, -0.01, 0.03)),
    )
}

/// Body orientation: the camera looks along world +y (image down = world -z), wobbling.
pub fn body_rotation(t: f64) -> UnitQuaternion<f64> {
    let R_w_c0 = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
    let R0 = UnitQuaternion::from_matrix(&R_w_c0) * T_b_c().rotation.inverse();
    R0 * UnitQuaternion::from_scaled_axis(Vector3::new(
        0.15 * (1.3 * t).sin(),
        0.1 * (1.9 * t + 0.5).sin(),
        0.2 * (0.9 * t).sin(),
    ))
}

pub fn body_pose(t: f64) -> Isometry3<f64> {
    Isometry3::from_parts(body_position(t).0.into(), body_rotation(t))
}

/// IMU readings over step `[t, t + IMU_DT]` that the preintegration integrates to the true
/// motion (exactly for rotation and velocity, to O(dt^2) for position), plus bias and noise.
pub fn imu_reading(t: f64, rng: &mut impl Rng, params: &ImuParams) -> (Vector3<f64>, Vector3<f64>) {
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

/// The true keyframe poses `T_c_w` and velocities (world, m/s) of a [`flight`].
pub struct Truth {
    pub poses: Vec<Isometry3<f64>>,
    pub velocities: Vec<Vector3<f64>>,
}

/// The problem AT THE TRUE STATE except for the biases (zero, their initial guess) with noisy
/// measurements. Keyframe 0's pose is fixed (the gauge), every velocity and bias is free.
/// Preintegrations are linearised at zero bias.
pub fn flight(seed: u64, keyframes: usize, points: usize) -> (InertialBaProblem, Truth) {
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
                camera: 0,
                pose,
                point: true_points.len(),
                uv: uv + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)),
                u_right: None,
                inv_sigma2: 1.0,
                readout_motion: None,
            });
        }
        true_points.push(p);
    }
    let mut pose_fixed = vec![false; keyframes];
    pose_fixed[0] = true;
    let problem = InertialBaProblem {
        visual: BaProblem {
            cameras: vec![RigCamera::first(K)],
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
