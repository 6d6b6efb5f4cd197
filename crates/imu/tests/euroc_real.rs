//! Preintegration of the REAL EuRoC V1_01_easy IMU between ground-truth states.
//!
//! Data: see `common` (missing data fails the test loudly).

#![allow(non_snake_case)]

mod common;

use common::{data_dir, fitted_gravity, load, median_max, GroundTruth};
use ferroslam_geometry::so3;
use ferroslam_imu::{check_units, Bias, ImuDelta, ImuParams, Preintegrated};
use nalgebra::Vector3;

/// Per-window errors of predicted deltas against ground-truth deltas.
#[derive(Default)]
struct Errors {
    rot_deg: Vec<f64>,
    vel_m_s: Vec<f64>,
    pos_m: Vec<f64>,
}

impl Errors {
    fn push(&mut self, delta: &ImuDelta, truth: &ImuDelta) {
        let rot = so3::log(&(truth.delta_r.inverse() * delta.delta_r)).norm();
        self.rot_deg.push(rot.to_degrees());
        self.vel_m_s.push((delta.delta_v - truth.delta_v).norm());
        self.pos_m.push((delta.delta_p - truth.delta_p).norm());
    }

    /// ((median, max) rotation deg, velocity m/s, position m), printed under `name`.
    fn summary(&self, name: &str) -> [(f64, f64); 3] {
        let s = [
            median_max(&self.rot_deg),
            median_max(&self.vel_m_s),
            median_max(&self.pos_m),
        ];
        println!(
            "{name} ({} windows): rotation median {:.4} max {:.4} deg, velocity median {:.4} \
             max {:.4} m/s, position median {:.4} max {:.4} m",
            self.rot_deg.len(),
            s[0].0,
            s[0].1,
            s[1].0,
            s[1].1,
            s[2].0,
            s[2].1
        );
        s
    }
}

/// Every 0.5 s window of the vicon2gt ground truth (20 Hz: sample i to i + 10), sliding by
/// one sample over the whole flight (2885 windows).
const WINDOW: usize = 10;

#[test]
fn preintegrated_deltas_match_vicon2gt_over_half_second_windows() {
    let (imu, gt) = load();
    check_units(&imu).unwrap();
    let params = ImuParams::from_euroc_file(data_dir().join("imu0/sensor.yaml")).unwrap();
    let windows: Vec<(&GroundTruth, &GroundTruth, Preintegrated)> = gt
        .iter()
        .zip(&gt[WINDOW..])
        .map(|(a, b)| {
            let pre = Preintegrated::between(&imu, a.t_s, b.t_s, a.bias(), &params).unwrap();
            (a, b, pre)
        })
        .collect();

    // The ground truth's world z is not exactly vertical: the velocity residual with
    // g = (0, 0, -9.81) has a constant WORLD-frame part (-0.040 m/s^2 along x, std 0.016
    // across windows) that body-frame causes (accelerometer bias) cannot produce while the
    // MAV yaws. So fit gravity once, by least squares over all windows:
    // v_j - v_i - R_i dv = g dt.
    let gravity = fitted_gravity(windows.iter().map(|(a, b, pre)| (*a, *b, pre)));
    let tilt_deg = gravity.angle(&-Vector3::z()).to_degrees();
    println!(
        "fitted gravity {:?}: |g| {:.4} m/s^2, tilt {tilt_deg:.3} deg",
        gravity.as_slice(),
        gravity.norm()
    );
    // Measured: |g| = 9.8072 (Zurich: 9.8066), tilt 0.236 deg.
    assert!(
        (gravity.norm() - 9.8066).abs() < 0.01,
        "|g| = {}",
        gravity.norm()
    );
    assert!(tilt_deg < 0.5, "gravity tilt {tilt_deg} deg");

    let nominal = Vector3::new(0.0, 0.0, -9.81);
    let (mut fitted, mut untilted, mut from_zero_bias) =
        (Errors::default(), Errors::default(), Errors::default());
    for (a, b, pre) in &windows {
        let dt = b.t_s - a.t_s;
        let truth = ImuDelta::between(&a.nav_state(), &b.nav_state(), dt, &gravity);
        fitted.push(&pre.delta(), &truth);
        untilted.push(
            &pre.delta(),
            &ImuDelta::between(&a.nav_state(), &b.nav_state(), dt, &nominal),
        );
        // Bias Jacobians on real data: integrate at zero bias, correct to the true bias.
        let zero = pre.reintegrated(Bias::default()).unwrap();
        from_zero_bias.push(&zero.corrected(&a.bias()), &truth);
    }
    let [rot, vel, pos] = fitted.summary("fitted gravity");
    let [rot_n, vel_n, pos_n] = untilted.summary("g = (0, 0, -9.81)");
    let [rot_z, vel_z, pos_z] = from_zero_bias.summary("zero bias, first-order corrected");

    // Measured with the fitted gravity: rotation median 0.057 max 0.180 deg, velocity median
    // 0.0126 max 0.0448 m/s, position median 0.0032 max 0.0118 m. For scale, sensor white
    // noise alone gives 0.007 deg, 0.0014 m/s, 0.0004 m per axis (1 sigma of the 9x9
    // covariance over 0.5 s), so the errors come from the ground truth itself (Vicon
    // orientation noise, the vicon2gt velocity spline, biases only as good as vicon2gt's)
    // and from the first-order discretisation (synthetic tests: about 1.4 cm/s per second of
    // brisk flight at 200 Hz). Bounds are 1.5x the measured values, tight enough to catch a
    // regression in the scheme, the frames or the interpolation of partial intervals.
    assert!(rot.0 < 0.09 && rot.1 < 0.27, "rotation deg {rot:?}");
    assert!(vel.0 < 0.019 && vel.1 < 0.067, "velocity m/s {vel:?}");
    assert!(pos.0 < 0.005 && pos.1 < 0.018, "position m {pos:?}");
    // Measured with the nominal gravity: velocity median 0.0238 max 0.0528 m/s, position
    // median 0.0060 max 0.0150 m (0.040 m/s^2 * 0.5 s = 0.02 m/s from the tilt alone).
    assert_eq!(rot_n, rot, "gravity does not enter the rotation");
    assert!(vel_n.0 < 0.036 && vel_n.1 < 0.08, "velocity m/s {vel_n:?}");
    assert!(pos_n.0 < 0.009 && pos_n.1 < 0.023, "position m {pos_n:?}");
    // Starting from zero bias (vicon2gt: gyro bias ~0.08 rad/s, accel up to 0.29 m/s^2), the
    // first-order correction is as accurate as integrating at the true bias (measured maxima
    // 0.179 deg, 0.0431 m/s, 0.0116 m).
    assert!(rot_z.1 < 1.1 * rot.1 && vel_z.1 < 1.1 * vel.1 && pos_z.1 < 1.1 * pos.1);
}
