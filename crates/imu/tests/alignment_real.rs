//! Visual-inertial alignment on the REAL EuRoC V1_01_easy IMU, with vision imitated by the
//! vicon2gt poses: cam0 poses (via `T_BS`) in a rotated, translated, scaled world frame with
//! seeded noise, as monocular SLAM would deliver them.
//!
//! Data: see `common` (missing data fails the test loudly).

#![allow(non_snake_case)]

mod common;

use common::{data_dir, load, read, GroundTruth as Truth};
use ferroslam_imu::alignment::{align, Alignment, AlignmentConfig, AlignmentError};
use ferroslam_imu::{Bias, ImuMeasurement, ImuParams, Preintegrated};
use nalgebra::{Isometry3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `T_BS` of cam0: the camera pose in the IMU frame, `T_b_c`.
fn T_b_c() -> Isometry3<f64> {
    let text = read("cam0_sensor.yaml");
    let start = text.find("data:").unwrap();
    let list = &text[start + 5..];
    let list = &list[list.find('[').unwrap() + 1..list.find(']').unwrap()];
    let v: Vec<f64> = list.split(',').map(|f| f.trim().parse().unwrap()).collect();
    let m = Matrix4::from_row_slice(&v);
    let r = Rotation3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned());
    Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Standard normal sample (Box-Muller), seeded through `rng`.
fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

fn noise(rng: &mut ChaCha8Rng, sigma: f64) -> Vector3<f64> {
    Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * sigma
}

/// The visual world `v`: vicon world rotated and translated; positions times `VISUAL_SCALE`.
const VISUAL_SCALE: f64 = 0.37;

fn T_v_w() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(3.0, -1.5, 0.7),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.5, -1.1, 2.0)),
    )
}

/// Keyframes every `stride` vicon2gt samples (20 Hz) from `t_start` s, `count` of them,
/// as noisy monocular camera poses plus the real IMU preintegrated at zero bias between.
fn keyframes(
    imu: &[ImuMeasurement],
    gt: &[Truth],
    t_start: f64,
    stride: usize,
    count: usize,
    seed: u64,
) -> (Vec<Isometry3<f64>>, Vec<Preintegrated>, Vec<usize>) {
    let first = gt.iter().position(|g| g.t_s >= t_start).unwrap();
    let picks: Vec<usize> = (0..count).map(|k| first + k * stride).collect();
    let (T_b_c, T_v_w) = (T_b_c(), T_v_w());
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let poses = picks
        .iter()
        .map(|&i| {
            let T_v_c = T_v_w * gt[i].state.T_w_b * T_b_c;
            // 1 mm and 0.1 deg of vision noise, the position noise in visual units.
            let p = (T_v_c.translation.vector + noise(&mut rng, 1e-3)) * VISUAL_SCALE;
            let q = UnitQuaternion::from_scaled_axis(noise(&mut rng, 0.1f64.to_radians()))
                * T_v_c.rotation;
            Isometry3::from_parts(Translation3::from(p), q)
        })
        .collect();
    let params = ImuParams::from_euroc_file(data_dir().join("imu0/sensor.yaml")).unwrap();
    let pres = picks
        .windows(2)
        .map(|w| {
            Preintegrated::between(imu, gt[w[0]].t_s, gt[w[1]].t_s, Bias::default(), &params)
                .unwrap()
        })
        .collect();
    (poses, pres, picks)
}

/// Gravity in the vicon world fitted over the keyframe intervals from vicon2gt velocities
/// and biases (`v_j - v_i - R_i dv = g dt`): the vicon world's z is tilted by ~0.24 deg.
fn fitted_gravity(gt: &[Truth], picks: &[usize], pres: &[Preintegrated]) -> Vector3<f64> {
    let (num, den) =
        picks
            .windows(2)
            .zip(pres)
            .fold((Vector3::zeros(), 0.0), |(num, den), (w, pre)| {
                let (a, b) = (&gt[w[0]], &gt[w[1]]);
                let pre = pre.reintegrated(a.bias()).unwrap();
                let lhs =
                    b.state.v_w_b - a.state.v_w_b - a.state.T_w_b.rotation * pre.delta().delta_v;
                (num + lhs * pre.dt(), den + pre.dt() * pre.dt())
            });
    num / den
}

/// Errors against the truth: scale (%), gravity direction (deg) against the vicon world's
/// -z and against [`fitted_gravity`], gyro and accelerometer bias against vicon2gt's mean
/// over the window (rad/s, m/s^2).
struct Errors {
    scale_percent: f64,
    gravity_deg: f64,
    gravity_fitted_deg: f64,
    gyro_bias: f64,
    accel_bias: f64,
}

fn errors(out: &Alignment, gt: &[Truth], picks: &[usize], fitted: &Vector3<f64>) -> Errors {
    let n = picks.len() as f64;
    let bg = picks
        .iter()
        .map(|&i| gt[i].state.bias.gyro)
        .sum::<Vector3<f64>>()
        / n;
    let ba = picks
        .iter()
        .map(|&i| gt[i].state.bias.accel)
        .sum::<Vector3<f64>>()
        / n;
    let R_v_w = T_v_w().rotation;
    Errors {
        scale_percent: (out.scale * VISUAL_SCALE - 1.0).abs() * 100.0,
        gravity_deg: out.gravity_w.angle(&(R_v_w * -Vector3::z())).to_degrees(),
        gravity_fitted_deg: out.gravity_w.angle(&(R_v_w * fitted)).to_degrees(),
        gyro_bias: (out.gyro_bias - bg).norm(),
        accel_bias: (out.accel_bias - ba).norm(),
    }
}

#[test]
fn aligns_real_imu_with_monocular_poses_in_flight() {
    let (imu, gt) = load();
    let T_b_c = T_b_c();
    // 40 keyframes 0.25 s apart over t = 10 .. 19.75 s (take-off is at about 5.3 s).
    let (poses, pres, picks) = keyframes(&imu, &gt, 10.0, 5, 40, 7);
    let fitted = fitted_gravity(&gt, &picks, &pres);
    println!(
        "fitted gravity: |g| {:.4}, tilt {:.3} deg",
        fitted.norm(),
        fitted.angle(&-Vector3::z()).to_degrees()
    );
    let mut results = Vec::new();
    for estimate_accel_bias in [false, true] {
        let config = AlignmentConfig {
            estimate_accel_bias,
            ..AlignmentConfig::default()
        };
        let out = align(&poses, &T_b_c, &pres, &config).unwrap();
        let e = errors(&out, &gt, &picks, &fitted);
        println!(
            "accel bias estimated {}: scale error {:.3} %, gravity {:.3} deg (fitted: {:.3}), \
             gyro bias error {:.5} rad/s, accel bias error {:.4} m/s^2, excitation {:.3} m/s^2",
            out.accel_bias_estimated,
            e.scale_percent,
            e.gravity_deg,
            e.gravity_fitted_deg,
            e.gyro_bias,
            e.accel_bias,
            out.acceleration_excitation
        );
        assert_eq!(out.accel_bias_estimated, estimate_accel_bias);
        assert_eq!(out.velocities.len(), poses.len());
        results.push(e);
    }
    // Default (accelerometer bias not estimated). Measured: scale 1.98 %, gravity 0.63 deg
    // from the vicon world's -z and 0.84 deg from the gravity fitted to vicon2gt (which is
    // tilted 0.24 deg), gyro bias 0.0015 rad/s from vicon2gt's window mean. Scale and gravity
    // errors come from the unmodelled accelerometer bias (vicon2gt: 0.05..0.17 m/s^2 over the
    // window; integrating at vicon2gt's bias gives 0.5 % and 0.16 deg). Without any vision
    // noise the gyro bias error is still 0.0012 rad/s: mostly vicon2gt's own bias drift over
    // the window, the 0.1 deg noise adds 0.0003. Bounds: the 3 % and 1 deg, and 2x
    // the gyro bias error.
    let e = &results[0];
    assert!(e.scale_percent < 3.0, "scale error {} %", e.scale_percent);
    assert!(e.gravity_deg < 1.0, "gravity error {} deg", e.gravity_deg);
    assert!(e.gravity_fitted_deg < 1.0, "{} deg", e.gravity_fitted_deg);
    assert!(e.gyro_bias < 0.003, "gyro bias error {} rad/s", e.gyro_bias);
    // Estimating the accelerometer bias too (RA-L 2017): measured scale 1.99 %, gravity
    // 1.10 deg, accelerometer bias 0.18 m/s^2 off: over mostly-yaw motion the bias trades
    // off against the gravity tilt. Only the scale bound holds.
    let e = &results[1];
    assert!(e.scale_percent < 3.0, "scale error {} %", e.scale_percent);
    assert!(e.gravity_deg < 1.5, "gravity error {} deg", e.gravity_deg);
}

#[test]
fn refuses_the_static_start() {
    let (imu, gt) = load();
    // Before take-off: 13 keyframes 0.25 s apart from the start of the ground truth.
    // Measured excitation 0.040 m/s^2 (in flight: 0.60), the threshold is 0.1.
    let t0 = gt[0].t_s;
    let (poses, pres, _) = keyframes(&imu, &gt, t0, 5, 13, 3);
    assert!(gt[5 * 12].t_s < 4.0);
    let err = align(&poses, &T_b_c(), &pres, &AlignmentConfig::default()).unwrap_err();
    println!("static start: {err}");
    assert!(matches!(err, AlignmentError::NoExcitation { .. }), "{err}");
}
