//! Motion-only BA of a rolling-shutter frame: a TUM fr1-like camera (640x480, 517 px)
//! reading its rows over 25 ms while it turns at a hand-held rate.
#![allow(non_snake_case)]

mod common;

use common::{gaussian, gaussian3, perturb, pose_error, K};
use ferroslam_geometry::rolling_shutter::{
    motion_over, point_at_offset, ReadoutDirection, RollingShutter,
};
use ferroslam_optim::pose_rolling_shutter::{optimize_pose_and_velocity, VelocityPrior};
use ferroslam_optim::{optimize_pose, OptimError, PoseObservation, RigCamera};
use nalgebra::{Isometry3, Point3, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const READOUT_S: f64 = 0.025;
const PIXEL_SIGMA: f64 = 1.0;

struct Frame {
    T_true: Isometry3<f64>,
    xi_dot_true: Vector6<f64>,
    obs: Vec<PoseObservation>,
    dt: Vec<f64>,
    planted: Vec<bool>,
}

/// Observations of points 1-4 m away, each at the row its own readout time puts it on (the
/// fixed point of "row -> time -> projection -> row", reached in a few iterations since a
/// readout moves a point by a few pixels), with pixel noise and `outliers` gross errors.
fn frame(seed: u64, n: usize, outliers: f64, depth: bool) -> Frame {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let rs = RollingShutter::from_readout(READOUT_S, 480, ReadoutDirection::TopToBottom).unwrap();
    let extent = Vector2::new(common::WIDTH, common::HEIGHT);
    let T_true = perturb(&mut rng, &Isometry3::identity(), 0.2, 0.3);
    // 1.5 rad/s about a random axis (fr1/rpy's peaks) and 0.4 m/s.
    let w = gaussian3(&mut rng, 1.0).normalize() * 1.5;
    let v = gaussian3(&mut rng, 1.0).normalize() * 0.4;
    let xi_dot_true = Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z);
    let (mut obs, mut dt, mut planted) = (Vec::new(), Vec::new(), Vec::new());
    while obs.len() < n {
        let p_c0 = Vector3::new(
            rng.random_range(-1.2..1.2),
            rng.random_range(-0.9..0.9),
            rng.random_range(1.0..4.0),
        );
        let p_w = (T_true.inverse() * Point3::from(p_c0)).coords;
        let mut t = 0.0;
        let mut uv = Vector2::zeros();
        let mut z = 0.0;
        for _ in 0..10 {
            let p_c = point_at_offset(&T_true, &xi_dot_true, t, &Point3::from(p_w)).p_c;
            uv = Vector2::new(K.fx * p_c.x / p_c.z + K.cx, K.fy * p_c.y / p_c.z + K.cy);
            z = p_c.z;
            t = rs.time_offset_s(&uv, &extent);
        }
        if !(0.0..common::WIDTH).contains(&uv.x) || !(0.0..common::HEIGHT).contains(&uv.y) {
            continue;
        }
        let is_outlier = rng.random_bool(outliers);
        let noise = Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * PIXEL_SIGMA;
        let uv_obs = if is_outlier {
            uv + Vector2::new(25.0, -20.0)
        } else {
            uv + noise
        };
        obs.push(PoseObservation {
            camera: 0,
            p_w,
            uv: uv_obs,
            u_right: depth.then(|| uv_obs.x - K.bf / z),
            inv_sigma2: 1.0 / (PIXEL_SIGMA * PIXEL_SIGMA),
        });
        dt.push(t);
        planted.push(is_outlier);
    }
    Frame {
        T_true,
        xi_dot_true,
        obs,
        dt,
        planted,
    }
}

/// The motion model's guess: the true velocity off by 0.3 rad/s and 0.1 m/s per axis.
fn motion_model_prior(f: &Frame, rng: &mut impl Rng) -> VelocityPrior {
    let (dv, dw) = (gaussian3(rng, 0.1), gaussian3(rng, 0.3));
    let guess = f.xi_dot_true + Vector6::new(dv.x, dv.y, dv.z, dw.x, dw.y, dw.z);
    VelocityPrior::isotropic(guess, 0.2, 0.5)
}

fn errors_deg_mm(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let (t, r) = pose_error(a, b);
    (r.to_degrees(), t * 1e3)
}

#[test]
fn rolling_shutter_frames_are_recovered_where_the_global_model_is_biased() {
    // Over 20 frames: the global-shutter estimate carries the readout's motion as a pose
    // error (1.5 rad/s over +-12.5 ms is up to 1.1 degrees across the image), the joint
    // estimate does not.
    let (mut global, mut joint, mut velocity) = (0.0f64, 0.0f64, 0.0f64);
    for seed in 0..20 {
        let f = frame(seed, 300, 0.0, false);
        let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
        let start = perturb(&mut rng, &f.T_true, 0.02, 0.02);
        let mut flags = vec![false; f.obs.len()];
        let g = optimize_pose(&start, &f.obs, &[RigCamera::first(K)], &mut flags).unwrap();
        let prior = motion_model_prior(&f, &mut rng);
        let mut flags = vec![false; f.obs.len()];
        let j = optimize_pose_and_velocity(
            &start,
            &prior,
            &f.obs,
            &f.dt,
            &[RigCamera::first(K)],
            &mut flags,
        )
        .unwrap();
        global = global.max(errors_deg_mm(&g.T_c_w, &f.T_true).0);
        joint = joint.max(errors_deg_mm(&j.T_c_w, &f.T_true).0);
        let w_err = (j.xi_dot - f.xi_dot_true).fixed_rows::<3>(3).norm();
        let w_prior = (prior.xi_dot - f.xi_dot_true).fixed_rows::<3>(3).norm();
        velocity = velocity.max(w_err / w_prior);
    }
    eprintln!("worst rotation error: global {global:.3} deg, joint {joint:.3} deg; worst w error / prior's {velocity:.2}");
    assert!(
        global > 0.1,
        "the scene must show rolling-shutter bias, got {global} deg"
    );
    assert!(
        joint < global / 3.0,
        "joint {joint} deg vs global {global} deg"
    );
    assert!(
        velocity < 1.0,
        "the angular rate must improve on the prior's, ratio {velocity}"
    );
}

#[test]
fn rgbd_observations_are_recovered_too() {
    let f = frame(7, 300, 0.0, true);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let start = perturb(&mut rng, &f.T_true, 0.02, 0.02);
    let prior = motion_model_prior(&f, &mut rng);
    let mut flags = vec![false; f.obs.len()];
    let g = optimize_pose(&start, &f.obs, &[RigCamera::first(K)], &mut flags.clone()).unwrap();
    let j = optimize_pose_and_velocity(
        &start,
        &prior,
        &f.obs,
        &f.dt,
        &[RigCamera::first(K)],
        &mut flags,
    )
    .unwrap();
    let (g_deg, g_mm) = errors_deg_mm(&g.T_c_w, &f.T_true);
    let (j_deg, j_mm) = errors_deg_mm(&j.T_c_w, &f.T_true);
    eprintln!("RGB-D: global {g_deg:.3} deg {g_mm:.2} mm, joint {j_deg:.3} deg {j_mm:.2} mm");
    assert!(
        j_deg < g_deg / 3.0 && j_mm < g_mm,
        "joint {j_deg} deg {j_mm} mm, global {g_deg} deg {g_mm} mm"
    );
}

#[test]
fn zero_offsets_give_the_global_shutter_estimate() {
    let f = frame(3, 200, 0.1, true);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let start = perturb(&mut rng, &f.T_true, 0.02, 0.02);
    let prior = motion_model_prior(&f, &mut rng);
    let (mut flags_g, mut flags_j) = (vec![false; f.obs.len()], vec![false; f.obs.len()]);
    let g = optimize_pose(&start, &f.obs, &[RigCamera::first(K)], &mut flags_g).unwrap();
    let zeros = vec![0.0; f.obs.len()];
    let j = optimize_pose_and_velocity(
        &start,
        &prior,
        &f.obs,
        &zeros,
        &[RigCamera::first(K)],
        &mut flags_j,
    )
    .unwrap();
    let (t, r) = pose_error(&g.T_c_w, &j.T_c_w);
    assert!(t < 1e-12 && r < 1e-12, "pose differs by {t} m, {r} rad");
    assert_eq!(flags_g, flags_j);
    assert_eq!(
        j.xi_dot, prior.xi_dot,
        "no offset: nothing moves the velocity off its prior"
    );
}

#[test]
fn planted_outliers_are_flagged() {
    let f = frame(11, 300, 0.15, false);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let start = perturb(&mut rng, &f.T_true, 0.02, 0.02);
    let prior = motion_model_prior(&f, &mut rng);
    let mut flags = vec![false; f.obs.len()];
    let j = optimize_pose_and_velocity(
        &start,
        &prior,
        &f.obs,
        &f.dt,
        &[RigCamera::first(K)],
        &mut flags,
    )
    .unwrap();
    let missed = f
        .planted
        .iter()
        .zip(&flags)
        .filter(|(&p, &o)| p && !o)
        .count();
    let inliers = f.planted.iter().filter(|&&p| !p).count();
    let false_flags = f
        .planted
        .iter()
        .zip(&flags)
        .filter(|(&p, &o)| !p && o)
        .count();
    assert_eq!(missed, 0, "every planted outlier must be flagged");
    // The chi-square test at 95 % flags about 5 % of true inliers (ORB-SLAM's threshold);
    // 10 % bounds that at this sample size (260 inliers: 5 % +- 1.4 %).
    assert!(
        false_flags * 10 <= inliers,
        "{false_flags} of {inliers} inliers flagged"
    );
    assert_eq!(j.num_inliers, flags.iter().filter(|&&o| !o).count());
    // The readout's motion itself: the velocity's prediction over 25 ms is a real motion.
    assert!(motion_over(&j.xi_dot, READOUT_S).rotation.angle() > 0.02);
}

#[test]
fn bad_offsets_and_priors_are_refused() {
    let f = frame(1, 20, 0.0, false);
    let prior = VelocityPrior::isotropic(Vector6::zeros(), 0.2, 0.5);
    let mut flags = vec![false; f.obs.len()];
    let short = &f.dt[..19];
    let err = optimize_pose_and_velocity(
        &f.T_true,
        &prior,
        &f.obs,
        short,
        &[RigCamera::first(K)],
        &mut flags,
    );
    assert!(
        matches!(err, Err(OptimError::InvalidInput(ref m)) if m.contains("20 observations")),
        "{err:?}"
    );
    let mut nan = f.dt.clone();
    nan[4] = f64::NAN;
    let err = optimize_pose_and_velocity(
        &f.T_true,
        &prior,
        &f.obs,
        &nan,
        &[RigCamera::first(K)],
        &mut flags,
    );
    assert!(
        matches!(err, Err(OptimError::InvalidInput(ref m)) if m.contains("time offset 4")),
        "{err:?}"
    );
    let bad = VelocityPrior::isotropic(Vector6::zeros(), f64::NAN, 0.5);
    let err = optimize_pose_and_velocity(
        &f.T_true,
        &bad,
        &f.obs,
        &f.dt,
        &[RigCamera::first(K)],
        &mut flags,
    );
    assert!(
        matches!(err, Err(OptimError::InvalidInput(ref m)) if m.contains("velocity prior")),
        "{err:?}"
    );
}
