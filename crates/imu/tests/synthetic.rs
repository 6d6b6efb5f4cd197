//! Preintegration against an exactly known smooth trajectory: ideal IMU readings are
//! synthesised from closed-form R(t), p(t), so every delta has an exact ground truth.

#![allow(non_snake_case)]

use ferroslam_geometry::{so3, testing::check_jacobian};
use ferroslam_imu::preintegration::{Matrix9, POS, ROT, VEL};
use ferroslam_imu::{Bias, ImuDelta, ImuMeasurement, ImuParams, NavState, Preintegrated};
use nalgebra::{DMatrix, DVector, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);

/// Rotation vector phi(t) and its derivative: a tumbling motion up to ~1.3 rad/s.
fn phi(t: f64) -> (Vector3<f64>, Vector3<f64>) {
    (
        Vector3::new(
            0.6 * (1.1 * t).sin(),
            0.4 * (0.7 * t).cos(),
            0.9 * (0.9 * t).sin() + 0.3,
        ),
        Vector3::new(
            0.66 * (1.1 * t).cos(),
            -0.28 * (0.7 * t).sin(),
            0.81 * (0.9 * t).cos(),
        ),
    )
}

/// Position, velocity, acceleration in the world: a figure of about a metre, ~2 m/s^2.
fn position(t: f64) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let (a, b, c) = (1.3, 1.7, 0.9);
    (
        Vector3::new((a * t).sin(), 0.5 * (b * t).cos(), 0.3 * (c * t).sin()),
        Vector3::new(
            a * (a * t).cos(),
            -0.5 * b * (b * t).sin(),
            0.3 * c * (c * t).cos(),
        ),
        Vector3::new(
            -a * a * (a * t).sin(),
            -0.5 * b * b * (b * t).cos(),
            -0.3 * c * c * (c * t).sin(),
        ),
    )
}

fn state(t: f64) -> NavState {
    let (p, v, _) = position(t);
    NavState {
        R_w_b: so3::exp(&phi(t).0),
        v_w_b: v,
        p_w_b: p,
    }
}

/// Ideal readings: body rate `J_r(phi) phi'` (right Jacobian) and specific force
/// `R^T (a_w - g)`, plus a constant bias.
fn measurement(t: f64, bias: &Bias) -> ImuMeasurement {
    let (ph, dph) = phi(t);
    let R = so3::exp(&ph);
    let (_, _, acc) = position(t);
    ImuMeasurement::new(
        t,
        so3::right_jacobian(&ph) * dph + bias.gyro,
        R.inverse() * (acc - GRAVITY) + bias.accel,
    )
}

fn stream(rate_hz: f64, duration_s: f64, bias: &Bias) -> Vec<ImuMeasurement> {
    let n = (duration_s * rate_hz).ceil() as usize + 1;
    (0..n)
        .map(|k| measurement(k as f64 / rate_hz, bias))
        .collect()
}

fn bias() -> Bias {
    Bias::new(
        Vector3::new(0.01, -0.02, 0.015),
        Vector3::new(0.1, 0.05, -0.08),
    )
}

/// (rotation error rad, velocity error m/s, position error m) of `delta` against `truth`.
fn errors(delta: &ImuDelta, truth: &ImuDelta) -> (f64, f64, f64) {
    (
        so3::log(&(truth.delta_r.inverse() * delta.delta_r)).norm(),
        (delta.delta_v - truth.delta_v).norm(),
        (delta.delta_p - truth.delta_p).norm(),
    )
}

#[test]
fn deltas_converge_to_the_exact_ones_at_first_order() {
    // Interval ends off the sample grid, so the partial first and last pieces are exercised.
    let (start, end) = (0.2013, 1.4437);
    let truth = ImuDelta::between(&state(start), &state(end), end - start, &GRAVITY);
    let b = bias();
    let errs: Vec<_> = [100.0, 200.0, 400.0, 800.0]
        .iter()
        .map(|&rate| {
            let m = stream(rate, 1.5, &b);
            let pre = Preintegrated::between(&m, start, end, b, &ImuParams::euroc()).unwrap();
            let e = errors(&pre.delta(), &truth);
            println!(
                "{rate} Hz: rot {:.2e} rad, vel {:.2e} m/s, pos {:.2e} m",
                e.0, e.1, e.2
            );
            e
        })
        .collect();
    // Measured (rot rad, vel m/s, pos m): 100 Hz 7.4e-6, 3.4e-2, 2.6e-2; 800 Hz 1.2e-7,
    // 4.3e-3, 3.2e-3. Each doubling of the rate halves the velocity and position errors
    // (forward Euler: the accelerometer is rotated by dR at the step start) and quarters
    // the rotation error (midpoint gyro, second order).
    for pair in errs.windows(2) {
        let (coarse, fine) = (pair[0], pair[1]);
        assert!(
            fine.0 < 0.35 * coarse.0,
            "rotation error must shrink ~4x: {errs:?}"
        );
        assert!(
            fine.1 < 0.6 * coarse.1,
            "velocity error must shrink ~2x: {errs:?}"
        );
        assert!(
            fine.2 < 0.6 * coarse.2,
            "position error must shrink ~2x: {errs:?}"
        );
    }
    let last = errs[errs.len() - 1];
    assert!(
        last.0 < 1e-5 && last.1 < 1e-2 && last.2 < 5e-3,
        "800 Hz: {last:?}"
    );
}

#[test]
fn predict_reaches_the_true_state_and_chains() {
    let b = bias();
    let m = stream(1000.0, 1.0, &b);
    let params = ImuParams::euroc();
    let whole = Preintegrated::between(&m, 0.0, 1.0, b, &params).unwrap();
    let predicted = whole.predict(&state(0.0), &GRAVITY);
    let truth = state(1.0);
    assert!(so3::log(&(truth.R_w_b.inverse() * predicted.R_w_b)).norm() < 1e-5);
    assert!((predicted.v_w_b - truth.v_w_b).norm() < 1e-2);
    assert!((predicted.p_w_b - truth.p_w_b).norm() < 5e-3);
    // Integrating [0, 0.4] then [0.4, 1] (a sample time) is the same computation.
    let first = Preintegrated::between(&m, 0.0, 0.4, b, &params).unwrap();
    let second = Preintegrated::between(&m, 0.4, 1.0, b, &params).unwrap();
    let chained = second.predict(&first.predict(&state(0.0), &GRAVITY), &GRAVITY);
    approx::assert_relative_eq!(chained.R_w_b, predicted.R_w_b, epsilon = 1e-12);
    approx::assert_relative_eq!(chained.v_w_b, predicted.v_w_b, epsilon = 1e-12);
    approx::assert_relative_eq!(chained.p_w_b, predicted.p_w_b, epsilon = 1e-12);
}

/// `[log(dR0^T dR); dv; dp]` of a reintegration at `b0 + [dbg; dba]`, relative to `b0`'s.
fn delta_vector(pre: &Preintegrated, x: &DVector<f64>) -> DVector<f64> {
    let b0 = *pre.bias();
    let b = Bias::new(
        b0.gyro + Vector3::new(x[0], x[1], x[2]),
        b0.accel + Vector3::new(x[3], x[4], x[5]),
    );
    let (d0, d) = (pre.delta(), pre.reintegrated(b).unwrap().delta());
    let mut out = DVector::zeros(9);
    out.rows_mut(ROT.start, 3)
        .copy_from(&so3::log(&(d0.delta_r.inverse() * d.delta_r)));
    out.rows_mut(VEL.start, 3)
        .copy_from(&(d.delta_v - d0.delta_v));
    out.rows_mut(POS.start, 3)
        .copy_from(&(d.delta_p - d0.delta_p));
    out
}

#[test]
fn bias_jacobians_match_finite_differences() {
    let b = bias();
    let m = stream(200.0, 1.0, &b);
    // Linearise away from the true bias: the Jacobians must hold at any bias.
    let lin = Bias::new(b.gyro + Vector3::new(0.02, 0.01, -0.03), b.accel * 0.5);
    let pre = Preintegrated::between(&m, 0.1, 0.85, lin, &ImuParams::euroc()).unwrap();
    let j = pre.jacobians();
    let mut analytic = DMatrix::zeros(9, 6);
    analytic
        .view_mut((ROT.start, 0), (3, 3))
        .copy_from(&j.d_r_d_bg);
    analytic
        .view_mut((VEL.start, 0), (3, 3))
        .copy_from(&j.d_v_d_bg);
    analytic
        .view_mut((VEL.start, 3), (3, 3))
        .copy_from(&j.d_v_d_ba);
    analytic
        .view_mut((POS.start, 0), (3, 3))
        .copy_from(&j.d_p_d_bg);
    analytic
        .view_mut((POS.start, 3), (3, 3))
        .copy_from(&j.d_p_d_ba);
    let f = |x: &DVector<f64>| delta_vector(&pre, x);
    check_jacobian(
        "preintegration bias Jacobians",
        &analytic,
        f,
        &DVector::zeros(6),
        1e-5,
        1e-6,
    );
}

#[test]
fn first_order_bias_correction_is_second_order_accurate() {
    let b = bias();
    let m = stream(200.0, 1.0, &b);
    let pre = Preintegrated::between(&m, 0.0, 1.0, Bias::default(), &ImuParams::euroc()).unwrap();
    let mut previous: Option<(f64, f64, f64)> = None;
    for scale in [1.0, 0.5, 0.25] {
        let target = Bias::new(b.gyro * scale, b.accel * scale);
        let exact = pre.reintegrated(target).unwrap().delta();
        let e = errors(&pre.corrected(&target), &exact);
        // The linearisation error of the correction is quadratic in the bias change.
        if let Some(p) = previous {
            assert!(
                e.0 < 0.3 * p.0 && e.1 < 0.3 * p.1 && e.2 < 0.3 * p.2,
                "{p:?} -> {e:?}"
            );
        }
        previous = Some(e);
    }
    // And it beats not correcting at all by far.
    let exact = pre.reintegrated(b).unwrap().delta();
    let (uncorrected, corrected) = (
        errors(&pre.delta(), &exact),
        errors(&pre.corrected(&b), &exact),
    );
    assert!(corrected.1 < 0.01 * uncorrected.1 && corrected.2 < 0.01 * uncorrected.2);
}

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    // Box-Muller; 1 - u keeps the logarithm finite.
    let (u, v): (f64, f64) = (rng.random(), rng.random());
    (-2.0 * (1.0 - u).ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

#[test]
fn covariance_matches_monte_carlo() {
    const SEED: u64 = 11;
    const RUNS: usize = 2000;
    // Noise 50x EuRoC's, still small enough for the first-order model.
    let params = ImuParams {
        gyro_noise_density: 50.0 * 1.6968e-4,
        accel_noise_density: 50.0 * 2.0e-3,
        ..ImuParams::euroc()
    };
    let (rate, b) = (200.0, bias());
    let clean = stream(rate, 0.5, &b);
    let dt = 1.0 / rate;
    let integrate = |noise: &mut dyn FnMut() -> Vector3<f64>| {
        let mut pre = Preintegrated::new(b, &params).unwrap();
        for m in &clean[..clean.len() - 1] {
            let (ng, na) = (noise(), noise());
            let (ng, na) = (
                ng * (params.gyro_noise_density / dt.sqrt()),
                na * (params.accel_noise_density / dt.sqrt()),
            );
            pre.integrate(dt, &(m.gyro_rad_s + ng), &(m.accel_m_s2 + na))
                .unwrap();
        }
        pre
    };
    let reference = integrate(&mut || Vector3::zeros());
    let d0 = reference.delta();
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut sample_cov = Matrix9::zeros();
    for _ in 0..RUNS {
        let mut noise = || Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng));
        let d = integrate(&mut noise).delta();
        let mut e = nalgebra::SVector::<f64, 9>::zeros();
        e.fixed_rows_mut::<3>(ROT.start)
            .copy_from(&so3::log(&(d0.delta_r.inverse() * d.delta_r)));
        e.fixed_rows_mut::<3>(VEL.start)
            .copy_from(&(d.delta_v - d0.delta_v));
        e.fixed_rows_mut::<3>(POS.start)
            .copy_from(&(d.delta_p - d0.delta_p));
        sample_cov += e * e.transpose() / RUNS as f64;
    }
    let cov = reference.covariance();
    // Variances: relative sampling error sqrt(2/N) = 3.2 %, so 15 % is ~5 sigma. Correlations:
    // sampling error ~1/sqrt(N) = 0.022, so 0.1 is ~4.5 sigma.
    for r in 0..9 {
        let rel = (sample_cov[(r, r)] - cov[(r, r)]).abs() / cov[(r, r)];
        assert!(
            rel < 0.15,
            "seed {SEED}: variance {r}: model {:.3e}, Monte Carlo {:.3e}",
            cov[(r, r)],
            sample_cov[(r, r)]
        );
        for c in 0..r {
            let corr = |m: &Matrix9| m[(r, c)] / (m[(r, r)] * m[(c, c)]).sqrt();
            assert!(
                (corr(&sample_cov) - corr(cov)).abs() < 0.1,
                "seed {SEED}: correlation ({r}, {c}): model {:.3}, Monte Carlo {:.3}",
                corr(cov),
                corr(&sample_cov)
            );
        }
    }
}

#[test]
fn covariance_grows_with_time_and_is_symmetric_positive_definite() {
    let b = bias();
    let m = stream(200.0, 1.0, &b);
    let params = ImuParams::euroc();
    let short = Preintegrated::between(&m, 0.0, 0.3, b, &params).unwrap();
    let long = Preintegrated::between(&m, 0.0, 0.9, b, &params).unwrap();
    for pre in [&short, &long] {
        let c = pre.covariance();
        approx::assert_relative_eq!(*c, c.transpose(), epsilon = 1e-18);
        assert!(c.cholesky().is_some());
    }
    for r in 0..9 {
        assert!(long.covariance()[(r, r)] > short.covariance()[(r, r)]);
    }
    // Rotation variance per axis is density^2 * dt exactly (rotation noise just accumulates).
    let expected = params.gyro_noise_density.powi(2) * 0.9;
    approx::assert_relative_eq!(
        long.covariance().fixed_view::<3, 3>(0, 0).trace() / 3.0,
        expected,
        max_relative = 1e-2
    );
}
