//! Visual-inertial motion-only optimisation on a synthetic scene with a known truth: a body
//! moving with constant angular rate and world acceleration, ideal IMU samples (plus a known
//! bias) preintegrated from the previous state, and map points seen by the current camera.
//! The true current state is the IMU prediction (`Preintegrated::predict`), so the inertial
//! residual vanishes exactly at the truth.
#![allow(non_snake_case)]

mod common;

use common::{gaussian, perturb, pose_error, K};
use ferroslam_geometry::{se3, so3};
use ferroslam_imu::Bias;
use ferroslam_imu::{
    BiasWalkFactor, ImuMeasurement, ImuParams, ImuState, InertialFactor, NavState, Preintegrated,
};
use ferroslam_optim::pose_inertial::{BIAS_ACCEL, BIAS_GYRO};
use ferroslam_optim::residual::linearize;
use ferroslam_optim::{
    optimize_pose, optimize_pose_inertial, InertialLink, InertialPoseEstimate, OptimError,
    PoseObservation, RigCamera,
};
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Rotation3, Translation3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);
/// Keyframe-to-frame interval, seconds (ORB-SLAM3 tracks against the last keyframe).
const INTERVAL: f64 = 0.25;
const PIXEL_SIGMA: f64 = 1.0;
/// 99.9% quantile of chi-square with 6 dof.
const CHI2_6_999: f64 = 22.458;

/// Closed-form body motion: constant body rate and constant world acceleration.
struct Motion {
    R0: Rotation3<f64>,
    p0: Vector3<f64>,
    v0: Vector3<f64>,
    w_b: Vector3<f64>,
    a_w: Vector3<f64>,
}

impl Motion {
    fn nav(&self, t: f64) -> NavState {
        NavState {
            R_w_b: (self.R0 * so3::exp(&(self.w_b * t)).to_rotation_matrix()).into(),
            v_w_b: self.v0 + self.a_w * t,
            p_w_b: self.p0 + self.v0 * t + self.a_w * (0.5 * t * t),
        }
    }

    /// Ideal readings with `bias` added: `gyro = w_b + b_g`, `accel = R^T (a - g) + b_a`.
    fn sample(&self, t: f64, bias: &Bias) -> ImuMeasurement {
        let R = self.nav(t).R_w_b;
        ImuMeasurement::new(
            t,
            self.w_b + bias.gyro,
            R.inverse() * (self.a_w - GRAVITY) + bias.accel,
        )
    }
}

fn imu_state(nav: &NavState, bias: Bias) -> ImuState {
    ImuState {
        T_w_b: Isometry3::from_parts(Translation3::from(nav.p_w_b), nav.R_w_b),
        v_w_b: nav.v_w_b,
        bias,
    }
}

/// Camera looking along the body's +x axis (image x = body -y, image y = body -z).
fn extrinsics() -> Isometry3<f64> {
    let R_b_c = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
    Isometry3::from_parts(
        Translation3::new(0.05, -0.02, 0.01),
        Rotation3::from_matrix_unchecked(R_b_c).into(),
    )
}

struct Scene {
    previous: ImuState,
    factor: InertialFactor,
    bias_walk: BiasWalkFactor,
    /// True current state (= IMU prediction from `previous`).
    truth: ImuState,
    T_c_w_true: Isometry3<f64>,
    T_b_c: Isometry3<f64>,
}

fn scene() -> Scene {
    scene_with(ImuParams::euroc())
}

fn scene_with(params: ImuParams) -> Scene {
    let bias = Bias::new(
        Vector3::new(0.004, -0.003, 0.002),
        Vector3::new(0.05, -0.03, 0.08),
    );
    let motion = Motion {
        R0: Rotation3::from_scaled_axis(Vector3::new(0.02, -0.03, 0.1)),
        p0: Vector3::new(0.3, -0.2, 1.2),
        v0: Vector3::new(0.8, 0.2, -0.1),
        w_b: Vector3::new(0.2, -0.3, 0.4),
        a_w: Vector3::new(0.6, -0.4, 0.3),
    };
    let samples: Vec<ImuMeasurement> = (0..=60)
        .map(|k| motion.sample(k as f64 / params.rate_hz, &bias))
        .collect();
    let pre = Preintegrated::between(&samples, 0.0, INTERVAL, bias, &params).unwrap();
    let previous = imu_state(&motion.nav(0.0), bias);
    let predicted = pre.predict(&motion.nav(0.0), &GRAVITY);
    // The prediction is the integrated closed-form motion (forward Euler: millimetres).
    let exact = motion.nav(INTERVAL);
    assert!((predicted.p_w_b - exact.p_w_b).norm() < 2e-3);
    assert!((predicted.R_w_b.inverse() * exact.R_w_b).angle() < 1e-6);
    let truth = imu_state(&predicted, bias);
    let T_b_c = extrinsics();
    Scene {
        previous,
        factor: InertialFactor::new(pre, GRAVITY).unwrap(),
        bias_walk: BiasWalkFactor::new(&params, INTERVAL).unwrap(),
        truth,
        T_c_w_true: (truth.T_w_b * T_b_c).inverse(),
        T_b_c,
    }
}

impl Scene {
    fn link(&self) -> InertialLink<'_> {
        InertialLink {
            previous: &self.previous,
            factor: &self.factor,
            bias_walk: &self.bias_walk,
        }
    }

    /// `n` observations of points 2-12 m in front of the true camera, 1 px noise; the
    /// `outliers` first ones are wrong matches at least 20 px away from the truth.
    fn observations(
        &self,
        rng: &mut ChaCha8Rng,
        n: usize,
        outliers: usize,
        stereo_fraction: f64,
    ) -> Vec<PoseObservation> {
        let T_w_c = self.T_c_w_true.inverse();
        (0..n)
            .map(|i| {
                let uv = Vector2::new(
                    rng.random_range(0.0..common::WIDTH),
                    rng.random_range(0.0..common::HEIGHT),
                );
                let z = rng.random_range(2.0..12.0);
                let p_c = Vector3::new((uv.x - K.cx) / K.fx * z, (uv.y - K.cy) / K.fy * z, z);
                let p_w = (T_w_c * Point3::from(p_c)).coords;
                let uv_obs = if i < outliers {
                    let dir = rng.random_range(0.0..std::f64::consts::TAU);
                    uv + rng.random_range(20.0..80.0) * Vector2::new(dir.cos(), dir.sin())
                } else {
                    uv + PIXEL_SIGMA * Vector2::new(gaussian(rng), gaussian(rng))
                };
                let u_right = rng
                    .random_bool(stereo_fraction)
                    .then(|| uv_obs.x - K.bf / z + PIXEL_SIGMA * gaussian(rng));
                // Independent noise on u_right (about the true u - bf / z): chi2 is then
                // chi-square with 3 dof, as the thresholds assume.
                let u_right = u_right.map(|ur| ur - (uv_obs.x - uv.x));
                PoseObservation {
                    camera: 0,
                    p_w,
                    uv: uv_obs,
                    u_right,
                    inv_sigma2: 1.0 / (PIXEL_SIGMA * PIXEL_SIGMA),
                }
            })
            .collect()
    }

    /// A start away from the truth: 3 cm / 1.4 deg sigma on the pose, velocity off by
    /// ~0.3 m/s, bias off the previous one.
    fn initial(&self, rng: &mut ChaCha8Rng) -> ImuState {
        let T_c_w = perturb(rng, &self.T_c_w_true, 0.03, 0.025);
        ImuState {
            T_w_b: T_c_w.inverse() * self.T_b_c.inverse(),
            v_w_b: self.truth.v_w_b + Vector3::new(0.2, -0.15, 0.15),
            bias: Bias::new(
                self.truth.bias.gyro + Vector3::new(1e-3, 0.0, -1e-3),
                self.truth.bias.accel + Vector3::new(0.0, 0.02, 0.0),
            ),
        }
    }
}

fn run(
    s: &Scene,
    initial: &ImuState,
    obs: &[PoseObservation],
) -> (InertialPoseEstimate, Vec<bool>) {
    let mut outlier = vec![false; obs.len()];
    let est = optimize_pose_inertial(
        initial,
        &s.link(),
        &s.T_b_c,
        obs,
        &[RigCamera::first(K)],
        &mut outlier,
    )
    .unwrap();
    assert_eq!(est.num_inliers, outlier.iter().filter(|&&o| !o).count());
    // The two views of the estimate agree.
    let (dt, dr) = pose_error(&est.T_c_w, &(est.state.T_w_b * s.T_b_c).inverse());
    assert!(dt < 1e-12 && dr < 1e-12);
    (est, outlier)
}

/// Visual information of the pose (true inliers, true pose), for a Mahalanobis comparison.
fn visual_information(s: &Scene, obs: &[PoseObservation], skip: usize) -> Matrix6<f64> {
    obs.iter().skip(skip).fold(Matrix6::zeros(), |h, o| {
        let l = linearize(&K, &s.T_c_w_true, &o.p_w, &o.uv, o.u_right).unwrap();
        h + o.inv_sigma2 * l.d_e_d_xi.transpose() * l.d_e_d_xi
    })
}

fn check_information(s: &Scene, est: &InertialPoseEstimate) {
    let h = est.information;
    assert!((h - h.transpose()).norm() <= 1e-9 * h.norm());
    assert!(
        h.cholesky().is_some(),
        "information must be positive definite"
    );
    let bias_block = h.fixed_view::<6, 6>(BIAS_GYRO.start, BIAS_GYRO.start);
    assert!((bias_block - s.bias_walk.information()).norm() <= 1e-9 * bias_block.norm());
    assert_eq!(BIAS_ACCEL.end, 15);
}

#[test]
fn good_observations_recover_the_true_pose_and_velocity() {
    let s = scene();
    for (seed, stereo) in [(1, 0.0), (2, 0.0), (3, 0.5)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let obs = s.observations(&mut rng, 150, 0, stereo);
        let initial = s.initial(&mut rng);
        let clock = std::time::Instant::now();
        let (est, outlier) = run(&s, &initial, &obs);
        let elapsed_ms = clock.elapsed().as_secs_f64() * 1e3;
        let (dt, dr) = pose_error(&est.T_c_w, &s.T_c_w_true);
        let dv = (est.state.v_w_b - s.truth.v_w_b).norm();
        let visual = optimize_pose(
            &(initial.T_w_b * s.T_b_c).inverse(),
            &obs,
            &[RigCamera::first(K)],
            &mut [false; 150],
        )
        .unwrap();
        let (vt, vr) = pose_error(&visual.T_c_w, &s.T_c_w_true);
        // The inertial estimate lies inside the visual-only estimate's confidence region.
        let xi = se3::log(&(est.T_c_w * visual.T_c_w.inverse()));
        let mahalanobis = xi.dot(&(visual_information(&s, &obs, 0) * xi));
        println!(
            "seed {seed} stereo {stereo}: inertial {:.3} mm {:.4} deg, dv {dv:.2e} m/s, {} inliers; \
             visual-only {:.3} mm {:.4} deg, {} inliers; mahalanobis^2 to it {mahalanobis:.2}; {elapsed_ms:.2} ms",
            dt * 1e3,
            dr.to_degrees(),
            est.num_inliers,
            vt * 1e3,
            vr.to_degrees(),
            visual.num_inliers
        );
        assert!(dt < 1e-3 && dr.to_degrees() < 0.01, "{dt} m {dr} rad");
        // Started 0.29 m/s off; what remains is the pose error seen through the
        // preintegration's rotation-velocity correlation (~1e-4 rad * g * dt).
        assert!(dv < 2e-3, "velocity error {dv} m/s");
        assert!(mahalanobis < CHI2_6_999, "{mahalanobis}");
        assert!(outlier.iter().filter(|&&o| o).count() < 15);
        // ORB-SLAM3 corrects with the previous bias: the walk pulls the current one onto it.
        assert!((est.state.bias.gyro - s.previous.bias.gyro).norm() < 1e-9);
        assert!((est.state.bias.accel - s.previous.bias.accel).norm() < 1e-9);
        check_information(&s, &est);
    }
}

/// The previous state's velocity is off by 8 cm/s, so the IMU predicts a pose 2 cm from the
/// one the images show. The information weights decide: an EuRoC-grade IMU (position sigma
/// ~0.1 mm over 0.25 s) overrules 150 observations, as in ORB-SLAM3, while an IMU 100x noisier
/// (sigma ~1.5 cm) yields to them.
#[test]
fn information_weights_decide_between_imu_and_vision() {
    let noisy = ImuParams {
        gyro_noise_density: 100.0 * ImuParams::euroc().gyro_noise_density,
        accel_noise_density: 100.0 * ImuParams::euroc().accel_noise_density,
        ..ImuParams::euroc()
    };
    for (name, params) in [("euroc", ImuParams::euroc()), ("100x noisier", noisy)] {
        let s = scene_with(params);
        let mut previous = s.previous;
        previous.v_w_b.x += 0.08;
        let link = InertialLink {
            previous: &previous,
            ..s.link()
        };
        let prediction = s.factor.preintegrated().predict(
            &NavState {
                R_w_b: previous.T_w_b.rotation,
                v_w_b: previous.v_w_b,
                p_w_b: previous.T_w_b.translation.vector,
            },
            &GRAVITY,
        );
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let obs = s.observations(&mut rng, 150, 0, 0.0);
        let initial = imu_state(&prediction, previous.bias);
        let mut outlier = vec![false; obs.len()];
        let est = optimize_pose_inertial(
            &initial,
            &link,
            &s.T_b_c,
            &obs,
            &[RigCamera::first(K)],
            &mut outlier,
        )
        .unwrap();
        let to_truth = pose_error(&est.T_c_w, &s.T_c_w_true).0;
        let to_prediction = (est.state.T_w_b.translation.vector - prediction.p_w_b).norm();
        let T_c_w_initial = (initial.T_w_b * s.T_b_c).inverse();
        let visual = optimize_pose(
            &T_c_w_initial,
            &obs,
            &[RigCamera::first(K)],
            &mut [false; 150],
        )
        .unwrap();
        let to_visual = pose_error(&est.T_c_w, &visual.T_c_w).0;
        println!(
            "{name}: {:.2} mm from the truth, {:.2} mm from the IMU prediction ({:.2} mm apart), \
             {:.2} mm from visual-only, {} inliers",
            to_truth * 1e3,
            to_prediction * 1e3,
            (prediction.p_w_b - s.truth.T_w_b.translation.vector).norm() * 1e3,
            to_visual * 1e3,
            est.num_inliers
        );
        if name == "euroc" {
            assert!(to_prediction < 1e-3, "{to_prediction}");
        } else {
            assert!(
                to_visual < 2e-3 && to_truth < 6e-3,
                "{to_visual} {to_truth}"
            );
        }
        assert!(est.num_inliers > 130);
    }
}

#[test]
fn without_observations_the_result_is_the_imu_prediction() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let initial = s.initial(&mut rng);
    let (est, _) = run(&s, &initial, &[]);
    let (dt, dr) = pose_error(&est.state.T_w_b, &s.truth.T_w_b);
    let dv = (est.state.v_w_b - s.truth.v_w_b).norm();
    println!("no observations: {dt:.2e} m {dr:.2e} rad {dv:.2e} m/s from the prediction");
    assert!(dt < 1e-9 && dr < 1e-9 && dv < 1e-9, "{dt} {dr} {dv}");
    assert_eq!(est.num_inliers, 0);
    assert!((est.state.bias.gyro - s.previous.bias.gyro).norm() < 1e-12);
    assert!((est.state.bias.accel - s.previous.bias.accel).norm() < 1e-12);
    check_information(&s, &est);
}

#[test]
fn few_observations_stay_on_the_imu_prediction() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let obs = s.observations(&mut rng, 4, 0, 0.0);
    let initial = s.initial(&mut rng);
    let (est, outlier) = run(&s, &initial, &obs);
    let (dt, dr) = pose_error(&est.state.T_w_b, &s.truth.T_w_b);
    println!(
        "4 observations: {:.4} mm {:.5} deg from the truth",
        dt * 1e3,
        dr.to_degrees()
    );
    assert!(dt < 5e-4 && dr.to_degrees() < 2e-3, "{dt} {dr}");
    assert!(outlier.iter().all(|&o| !o));
}

#[test]
fn a_frame_of_wrong_matches_follows_the_imu_and_flags_them_all() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let obs = s.observations(&mut rng, 40, 40, 0.0);
    let initial = s.initial(&mut rng);
    let (est, outlier) = run(&s, &initial, &obs);
    let (dt, dr) = pose_error(&est.state.T_w_b, &s.truth.T_w_b);
    println!("40 wrong matches: {dt:.2e} m {dr:.2e} rad from the prediction");
    assert!(outlier.iter().all(|&o| o));
    assert!(dt < 1e-9 && dr < 1e-9, "{dt} {dr}");
}

#[test]
fn gross_outliers_are_classified_as_outliers() {
    let s = scene();
    for seed in [11, 12] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let planted = 20;
        let obs = s.observations(&mut rng, 150, planted, 0.3);
        let initial = s.initial(&mut rng);
        let (est, outlier) = run(&s, &initial, &obs);
        assert!(
            outlier[..planted].iter().all(|&o| o),
            "seed {seed}: {outlier:?}"
        );
        let false_alarms = outlier[planted..].iter().filter(|&&o| o).count();
        let (dt, dr) = pose_error(&est.T_c_w, &s.T_c_w_true);
        println!(
            "seed {seed}: {false_alarms} false alarms of 130, error {:.3} mm {:.4} deg",
            dt * 1e3,
            dr.to_degrees()
        );
        assert!(false_alarms < 13, "seed {seed}: {false_alarms}");
        assert!(dt < 1e-3 && dr.to_degrees() < 0.01);
    }
}

#[test]
fn bad_input_is_an_error() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let obs = s.observations(&mut rng, 10, 0, 0.0);
    let good = s.truth;
    let link = s.link();
    let call = |initial: &ImuState,
                link: &InertialLink,
                T_b_c: &Isometry3<f64>,
                obs: &[PoseObservation],
                n: usize| {
        optimize_pose_inertial(
            initial,
            link,
            T_b_c,
            obs,
            &[RigCamera::first(K)],
            &mut vec![false; n],
        )
    };
    assert!(matches!(
        call(&good, &link, &s.T_b_c, &obs, 9),
        Err(OptimError::InvalidInput(_))
    ));
    let mut bad = obs.clone();
    bad[3].p_w.z = f64::INFINITY;
    assert_eq!(
        call(&good, &link, &s.T_b_c, &bad, 10).unwrap_err(),
        OptimError::NonFinite {
            what: "observation",
            index: 3
        }
    );
    let mut bad = obs.clone();
    bad[1].inv_sigma2 = -1.0;
    assert!(matches!(
        call(&good, &link, &s.T_b_c, &bad, 10),
        Err(OptimError::InvalidInput(_))
    ));
    let mut nan_velocity = good;
    nan_velocity.v_w_b.y = f64::NAN;
    assert_eq!(
        call(&nan_velocity, &link, &s.T_b_c, &obs, 10).unwrap_err(),
        OptimError::NonFinite {
            what: "initial state",
            index: 0
        }
    );
    let mut nan_bias = s.previous;
    nan_bias.bias.accel.x = f64::NAN;
    let bad_link = InertialLink {
        previous: &nan_bias,
        ..link
    };
    assert_eq!(
        call(&good, &bad_link, &s.T_b_c, &obs, 10).unwrap_err(),
        OptimError::NonFinite {
            what: "previous state",
            index: 0
        }
    );
    let mut bad_extrinsics = s.T_b_c;
    bad_extrinsics.translation.x = f64::NAN;
    assert_eq!(
        call(&good, &link, &bad_extrinsics, &obs, 10).unwrap_err(),
        OptimError::NonFinite {
            what: "extrinsics",
            index: 0
        }
    );
    let bad_k = ferroslam_optim::Intrinsics { fx: -1.0, ..K };
    assert!(matches!(
        optimize_pose_inertial(
            &good,
            &link,
            &s.T_b_c,
            &obs,
            &[RigCamera::first(bad_k)],
            &mut [false; 10]
        ),
        Err(OptimError::InvalidInput(_))
    ));
}
