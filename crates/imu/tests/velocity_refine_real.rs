//! Velocities and bias from fixed vicon2gt poses and the REAL V1_01 IMU, against vicon2gt's
//! velocities and biases.
//!
//! Data: see `common` (missing data fails the test loudly).

mod common;

use common::{data_dir, fitted_gravity, load, median_max};
use ferroslam_imu::{
    inertial_velocity_refine, Bias, ImuParams, InertialFactor, Preintegrated, VelocityRefineConfig,
};
use nalgebra::Vector3;

/// Keyframes every 0.5 s (10 vicon2gt samples), 20 of them: a 9.5 s window.
const STRIDE: usize = 10;
const KEYFRAMES: usize = 20;

#[test]
fn velocities_and_bias_from_ground_truth_poses() {
    let (imu, gt) = load();
    let params = ImuParams::from_euroc_file(data_dir().join("imu0/sensor.yaml")).unwrap();
    let pre = |a: usize| {
        Preintegrated::between(
            &imu,
            gt[a].t_s,
            gt[a + STRIDE].t_s,
            Bias::default(),
            &params,
        )
        .unwrap()
    };
    let all: Vec<Preintegrated> = (0..gt.len() - STRIDE).map(pre).collect();
    let gravity = fitted_gravity((0..all.len()).map(|k| (&gt[k], &gt[k + STRIDE], &all[k])));

    let (mut vel_err, mut bg_err, mut ba_err) = (Vec::new(), Vec::new(), Vec::new());
    // Disjoint windows over the whole flight.
    for start in (0..gt.len() - STRIDE * KEYFRAMES).step_by(STRIDE * KEYFRAMES) {
        let picks: Vec<usize> = (0..KEYFRAMES).map(|k| start + k * STRIDE).collect();
        let poses: Vec<_> = picks.iter().map(|&i| gt[i].state.T_w_b).collect();
        let factors: Vec<_> = picks[..KEYFRAMES - 1]
            .iter()
            .map(|&i| InertialFactor::new(all[i].clone(), gravity).unwrap())
            .collect();
        let out = inertial_velocity_refine(
            &poses,
            &factors,
            &vec![Vector3::zeros(); KEYFRAMES],
            Bias::default(),
            &VelocityRefineConfig::default(),
        )
        .unwrap();
        assert!(out.iterations < VelocityRefineConfig::default().max_iterations);
        for (v, &i) in out.velocities.iter().zip(&picks) {
            vel_err.push((v - gt[i].state.v_w_b).norm());
        }
        let n = KEYFRAMES as f64;
        let bg = picks
            .iter()
            .map(|&i| gt[i].bias().gyro)
            .sum::<Vector3<f64>>()
            / n;
        let ba = picks
            .iter()
            .map(|&i| gt[i].bias().accel)
            .sum::<Vector3<f64>>()
            / n;
        bg_err.push((out.bias.gyro - bg).norm());
        ba_err.push((out.bias.accel - ba).norm());
        println!(
            "window at {:.1} s: {} iterations, chi2 {:.0}, |v| error max {:.4} m/s, bias \
             errors {:.5} rad/s, {:.4} m/s^2",
            gt[start].t_s,
            out.iterations,
            out.chi2,
            vel_err[vel_err.len() - KEYFRAMES..]
                .iter()
                .cloned()
                .fold(0.0, f64::max),
            bg_err[bg_err.len() - 1],
            ba_err[ba_err.len() - 1]
        );
    }
    let (v, bg, ba) = (
        median_max(&vel_err),
        median_max(&bg_err),
        median_max(&ba_err),
    );
    println!(
        "{} windows: |v| error median {:.4} max {:.4} m/s; gyro bias median {:.5} max {:.5} \
         rad/s; accel bias median {:.4} max {:.4} m/s^2",
        bg_err.len(),
        v.0,
        v.1,
        bg.0,
        bg.1,
        ba.0,
        ba.1
    );
    // Measured (from zero velocities and bias; vicon2gt speeds reach ~1 m/s): |v| error
    // median 0.0034 max 0.0258 m/s, gyro bias median 0.00068 max 0.00140 rad/s, accel bias
    // median 0.0034 max 0.0075 m/s^2, 3 to 9 iterations. The velocity errors are the size of
    // the residuals of the ground truth itself (median |r_v| 0.013 m/s per 0.5 s, see
    // residual_real.rs). Bounds are 1.5x the measured values.
    assert!(v.0 < 0.005 && v.1 < 0.039, "velocity error m/s {v:?}");
    assert!(bg.1 < 0.0021, "gyro bias error rad/s {bg:?}");
    assert!(ba.1 < 0.011, "accel bias error m/s^2 {ba:?}");
}
