//! Velocities and a shared IMU bias from fixed keyframe poses: inertial-only
//! Levenberg-Marquardt over the [`InertialFactor`]s between consecutive keyframes (the
//! velocity and bias part of ORB-SLAM3's `InertialOptimization`, poses and gravity held).
//!
//! The unknowns are `x = [v_0; ..; v_{n-1}; b_g; b_a]` (m/s in the world frame, rad/s, m/s^2),
//! one bias for the whole window: over a few seconds the random walk is far below what the
//! factors resolve. The normal equations are dense (`3n + 6` unknowns), so keep `n` to tens.

use nalgebra::{DMatrix, DVector, Isometry3, Vector3};

use crate::{Bias, ImuError, ImuState, InertialFactor};

/// Stopping rules for [`inertial_velocity_refine`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityRefineConfig {
    /// Maximum number of LM iterations (accepted or rejected steps).
    pub max_iterations: usize,
    /// Stop when the step's norm falls below this (mixed units, m/s and bias units).
    pub min_step_norm: f64,
    /// Initial LM damping, relative to the diagonal of the normal matrix.
    pub initial_lambda: f64,
}

impl Default for VelocityRefineConfig {
    fn default() -> Self {
        Self {
            max_iterations: 30,
            min_step_norm: 1e-9,
            initial_lambda: 1e-4,
        }
    }
}

/// The refined estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct VelocityRefinement {
    /// Velocity of the body at each keyframe, world frame, m/s.
    pub velocities: Vec<Vector3<f64>>,
    /// The shared bias.
    pub bias: Bias,
    /// Final total chi2, `sum r^T information r`.
    pub chi2: f64,
    /// LM iterations run.
    pub iterations: usize,
}

/// Solves for the keyframe velocities and one bias given fixed body poses `T_w_b` (one per
/// keyframe) and `factors[k]` between keyframes `k` and `k + 1`, starting from
/// `initial_velocities` and `initial_bias` (zeros work: the problem is nearly linear).
///
/// Fails with [`ImuError::InvalidParameter`] if the counts do not match (`n >= 2` poses,
/// `n - 1` factors, `n` velocities) or an input is not finite. A step the damped normal
/// equations cannot give is treated as rejected, so the result is always the best found.
#[allow(non_snake_case)]
pub fn inertial_velocity_refine(
    T_w_b: &[Isometry3<f64>],
    factors: &[InertialFactor],
    initial_velocities: &[Vector3<f64>],
    initial_bias: Bias,
    config: &VelocityRefineConfig,
) -> Result<VelocityRefinement, ImuError> {
    let n = T_w_b.len();
    if n < 2 || factors.len() + 1 != n || initial_velocities.len() != n {
        return Err(ImuError::InvalidParameter {
            name: "factors",
            value: factors.len() as f64,
            reason: "need n >= 2 poses, n velocities and n - 1 factors",
        });
    }
    let finite = T_w_b
        .iter()
        .all(|t| t.to_homogeneous().iter().all(|v| v.is_finite()))
        && initial_velocities.iter().flatten().all(|v| v.is_finite())
        && initial_bias
            .gyro
            .iter()
            .chain(&initial_bias.accel)
            .all(|v| v.is_finite());
    if !finite {
        return Err(ImuError::InvalidParameter {
            name: "T_w_b, initial_velocities or initial_bias",
            value: f64::NAN,
            reason: "must be finite",
        });
    }
    let dim = 3 * n + 6;
    let (bg, ba) = (3 * n, 3 * n + 3);
    let mut x = DVector::zeros(dim);
    for (k, v) in initial_velocities.iter().enumerate() {
        x.fixed_rows_mut::<3>(3 * k).copy_from(v);
    }
    x.fixed_rows_mut::<3>(bg).copy_from(&initial_bias.gyro);
    x.fixed_rows_mut::<3>(ba).copy_from(&initial_bias.accel);

    let state = |x: &DVector<f64>, k: usize| ImuState {
        T_w_b: T_w_b[k],
        v_w_b: x.fixed_rows::<3>(3 * k).into_owned(),
        bias: Bias::new(
            x.fixed_rows::<3>(bg).into_owned(),
            x.fixed_rows::<3>(ba).into_owned(),
        ),
    };
    let cost = |x: &DVector<f64>| -> f64 {
        factors
            .iter()
            .enumerate()
            .map(|(k, f)| f.chi2(&state(x, k), &state(x, k + 1)))
            .sum()
    };
    // Gauss-Newton normal equations H dx = -g at x.
    let normal_equations = |x: &DVector<f64>| {
        let (mut h, mut g) = (DMatrix::zeros(dim, dim), DVector::zeros(dim));
        for (k, f) in factors.iter().enumerate() {
            let (r, jac) = f.evaluate(&state(x, k), &state(x, k + 1));
            let mut j = DMatrix::zeros(9, dim);
            j.view_mut((0, 3 * k), (9, 3)).copy_from(&jac.d_res_d_vel_i);
            j.view_mut((0, 3 * k + 3), (9, 3))
                .copy_from(&jac.d_res_d_vel_j);
            j.view_mut((0, bg), (9, 3))
                .copy_from(&jac.d_res_d_bias_gyro_i);
            j.view_mut((0, ba), (9, 3))
                .copy_from(&jac.d_res_d_bias_accel_i);
            let info = DMatrix::from_column_slice(9, 9, f.information().as_slice());
            let jt_info = j.transpose() * info;
            h += &jt_info * &j;
            g += jt_info * DVector::from_column_slice(r.as_slice());
        }
        (h, g)
    };

    let mut chi2 = cost(&x);
    let mut lambda = config.initial_lambda;
    let mut iterations = 0;
    let (mut h, mut g) = normal_equations(&x);
    while iterations < config.max_iterations {
        iterations += 1;
        let mut damped = h.clone();
        for i in 0..dim {
            damped[(i, i)] += lambda * h[(i, i)].max(1e-12);
        }
        let step = damped.cholesky().map(|c| c.solve(&-&g));
        match step {
            Some(dx) if dx.iter().all(|v| v.is_finite()) => {
                let candidate = &x + &dx;
                let candidate_chi2 = cost(&candidate);
                if candidate_chi2 < chi2 {
                    x = candidate;
                    chi2 = candidate_chi2;
                    lambda = (lambda * 0.1).max(1e-12);
                    if dx.norm() < config.min_step_norm {
                        break;
                    }
                    (h, g) = normal_equations(&x);
                    continue;
                }
                if dx.norm() < config.min_step_norm {
                    break;
                }
            }
            _ => {}
        }
        lambda *= 10.0;
    }
    Ok(VelocityRefinement {
        velocities: (0..n).map(|k| state(&x, k).v_w_b).collect(),
        bias: state(&x, 0).bias,
        chi2,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ImuParams, Preintegrated};

    #[test]
    fn mismatched_or_non_finite_inputs_are_errors() {
        let mut pre = Preintegrated::new(Bias::default(), &ImuParams::euroc()).unwrap();
        pre.integrate(0.1, &Vector3::zeros(), &Vector3::new(0.0, 0.0, 9.81))
            .unwrap();
        let f = InertialFactor::new(pre, Vector3::new(0.0, 0.0, -9.81)).unwrap();
        let poses = [Isometry3::identity(); 2];
        let v = [Vector3::zeros(); 2];
        let config = VelocityRefineConfig::default();
        let refine = |p: &[Isometry3<f64>], fs: &[InertialFactor], v: &[Vector3<f64>]| {
            inertial_velocity_refine(p, fs, v, Bias::default(), &config)
        };
        assert!(refine(&poses[..1], &[], &v[..1]).is_err());
        assert!(refine(&poses, &[], &v).is_err());
        assert!(refine(&poses, std::slice::from_ref(&f), &v[..1]).is_err());
        let bad = [Vector3::new(f64::NAN, 0.0, 0.0), Vector3::zeros()];
        assert!(refine(&poses, std::slice::from_ref(&f), &bad).is_err());
        // At rest with the true (zero) bias the answer is zero velocity.
        let out = refine(&poses, &[f], &v).unwrap();
        assert!(out.chi2 < 1e-12 && out.velocities.iter().all(|v| v.norm() < 1e-9));
    }
}
