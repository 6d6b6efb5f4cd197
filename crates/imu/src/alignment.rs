//! Visual-inertial initialisation: gyro bias, metric scale, gravity, velocities and
//! (optionally) accelerometer bias from keyframe poses given by vision and the IMU
//! preintegrated between them (Mur-Artal and Tardós, "Visual-Inertial Monocular SLAM with
//! Map Reuse", RA-L 2017; Qin and Shen, VINS-Mono, T-RO 2018).
//!
//! # Frames and units
//!
//! Vision gives camera poses `T_w_c` in an arbitrary world frame `w` whose positions are
//! `1 / scale` times metric (monocular); rotations are metric already. `T_b_c` is the
//! camera pose in the IMU frame `b` (EuRoC's `T_BS`), metric. Preintegration `k` runs from
//! keyframe `k` to keyframe `k + 1`. All outputs are in `w`: gravity in m/s^2, body
//! velocities in m/s (metric, in the directions of `w`).
//!
//! # Method
//!
//! 1. Gyro bias: Gauss-Newton on `r_k = Log(dR_k(b_g)^T R_w_bk^T R_w_bk+1)`, reintegrating
//!    every interval at the new bias after each step (exact, not first order).
//! 2. Linear least squares over `x = [v_0 .. v_{N-1}, g, s]` (VINS-Mono), velocities solved
//!    explicitly, from the position and velocity equations of every interval:
//!    `s (c_j - c_i) - v_i dt - g dt^2/2 - R_i J_pa b_a = R_i dp + d_i - d_j` and
//!    `v_j - v_i - g dt - R_i J_va b_a = R_i dv`, with `c` the visual camera centres and
//!    `d = R_w_c t_c_b` the metric lever arm.
//! 3. Gravity refinement with `|g|` fixed: `g = |g| (g0 + B dtheta)` over the 2-DOF tangent
//!    basis `B` of the current direction, relinearised a few times, optionally with the
//!    accelerometer bias as 3 more unknowns (RA-L 2017). A last solve at the fixed gravity
//!    gives scale, velocities and bias.
//!
//! # Failure modes
//!
//! Too few keyframes, mismatched inputs, non-finite poses, motion without varying
//! acceleration (static or constant velocity: scale and gravity are then unobservable),
//! a rank-deficient system or a non-positive scale give [`AlignmentError`], never a panic.

use ferroslam_geometry::so3;
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, UnitQuaternion, Vector3};
use thiserror::Error;

use crate::{Bias, ImuError, Preintegrated};

/// Why an alignment was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AlignmentError {
    /// Fewer keyframes than [`AlignmentConfig::min_keyframes`].
    #[error("{got} keyframes given, the alignment needs at least {needed}: wait for more")]
    TooFewKeyframes {
        /// Keyframes given.
        got: usize,
        /// Keyframes required.
        needed: usize,
    },
    /// There must be exactly one preintegration per consecutive pair of keyframes.
    #[error("{poses} keyframe poses need {} preintegrations, got {preintegrations}", poses.saturating_sub(1))]
    CountMismatch {
        /// Keyframe poses given.
        poses: usize,
        /// Preintegrations given.
        preintegrations: usize,
    },
    /// A keyframe pose (or the camera-IMU transform, index `usize::MAX`) is not finite.
    #[error("keyframe pose {index} is not finite (usize::MAX: the camera-IMU transform)")]
    NonFinitePose {
        /// Index of the offending pose.
        index: usize,
    },
    /// The world-frame specific force hardly varies over the window: static or
    /// constant-velocity motion, where scale and gravity cannot be told apart.
    #[error(
        "acceleration excitation {excitation_m_s2:.4} m/s^2 is below {threshold_m_s2} m/s^2: \
         scale and gravity are unobservable without varying acceleration (static or \
         constant-velocity motion); wait for the platform to move"
    )]
    NoExcitation {
        /// RMS deviation of the per-interval mean world-frame specific force, m/s^2.
        excitation_m_s2: f64,
        /// The configured minimum, m/s^2.
        threshold_m_s2: f64,
    },
    /// The linear system is (numerically) rank deficient.
    #[error("degenerate alignment system: {reason}")]
    Degenerate {
        /// What could not be determined.
        reason: &'static str,
    },
    /// The estimated scale is not positive and finite.
    #[error("estimated scale {scale} is not positive: vision and IMU disagree")]
    BadScale {
        /// The scale found.
        scale: f64,
    },
    /// Reintegration failed (the gyro bias diverged to a non-finite value).
    #[error(transparent)]
    Imu(#[from] ImuError),
}

/// Magnitude of gravity the alignment enforces by default, m/s^2: the value ORB-SLAM3 and the
/// EuRoC tools use, within 0.03 of its value anywhere on Earth's surface (9.780 at the
/// equator, 9.832 at the poles).
pub const GRAVITY_M_S2: f64 = 9.81;

/// Settings of [`align`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlignmentConfig {
    /// Magnitude enforced on the gravity vector, m/s^2.
    pub gravity_magnitude: f64,
    /// Fewest keyframes accepted.
    pub min_keyframes: usize,
    /// Gauss-Newton iterations for the gyro bias (stops early on convergence).
    pub gyro_iterations: usize,
    /// Relinearisations of the gravity direction with `|g|` fixed.
    pub gravity_iterations: usize,
    /// Also estimate the accelerometer bias (RA-L 2017); needs rotation excitation, see
    /// [`min_rotation_for_accel_bias_rad`](Self::min_rotation_for_accel_bias_rad). Off by
    /// default, as in VINS-Mono and ORB-SLAM3's first initialisation: on short real flights
    /// it is confounded with the gravity tilt and degrades the gravity estimate (see
    /// `tests/alignment_real.rs`).
    pub estimate_accel_bias: bool,
    /// Below this largest body rotation from the first keyframe (radians) the
    /// accelerometer bias is indistinguishable from gravity and is left at its prior.
    pub min_rotation_for_accel_bias_rad: f64,
    /// Minimum RMS variation of the world-frame specific force over the window, m/s^2.
    /// Not required with [`known_scale`](Self::known_scale).
    pub min_acceleration_excitation: f64,
    /// The poses are metric already (stereo, RGB-D): the scale is fixed to 1, as in
    /// ORB-SLAM3's stereo-inertial initialisation. Gravity is then observable without
    /// motion (the specific force of a resting IMU is `-g`), so a static start aligns.
    pub known_scale: bool,
}

impl Default for AlignmentConfig {
    fn default() -> Self {
        Self {
            gravity_magnitude: GRAVITY_M_S2,
            min_keyframes: 5,
            gyro_iterations: 5,
            gravity_iterations: 4,
            estimate_accel_bias: false,
            min_rotation_for_accel_bias_rad: 0.35,
            min_acceleration_excitation: 0.1,
            known_scale: false,
        }
    }
}

/// Result of [`align`]; everything is expressed in the visual world frame `w`.
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct Alignment {
    /// Metric length of one visual unit: `p_metric = scale * p_visual`.
    pub scale: f64,
    /// Gravity in `w`, m/s^2, of magnitude [`AlignmentConfig::gravity_magnitude`].
    pub gravity_w: Vector3<f64>,
    /// Rotation from a gravity-aligned frame (z up) into `w`:
    /// `gravity_w = R_w_gravity * (0, 0, -|g|)`, with no rotation about the vertical.
    pub R_w_gravity: UnitQuaternion<f64>,
    /// Gyro bias, rad/s.
    pub gyro_bias: Vector3<f64>,
    /// Accelerometer bias, m/s^2 (the prior of the preintegrations when not estimated).
    pub accel_bias: Vector3<f64>,
    /// Whether [`accel_bias`](Self::accel_bias) was estimated.
    pub accel_bias_estimated: bool,
    /// Body (IMU) velocity at each keyframe in `w`, m/s.
    pub velocities: Vec<Vector3<f64>>,
    /// RMS variation of the world-frame specific force over the window, m/s^2.
    pub acceleration_excitation: f64,
}

/// Aligns `poses_w_c` (vision, up to scale) with `preintegrations` (`k`: keyframe `k` to
/// `k + 1`) given the camera pose in the IMU frame `T_b_c`.
///
/// The preintegrations are reintegrated at the estimated gyro bias, starting from the bias
/// of the first one; its accelerometer bias is the prior for (or the value of) the
/// accelerometer bias. See the module documentation for the method and the errors.
#[allow(non_snake_case)]
pub fn align(
    poses_w_c: &[Isometry3<f64>],
    T_b_c: &Isometry3<f64>,
    preintegrations: &[Preintegrated],
    config: &AlignmentConfig,
) -> Result<Alignment, AlignmentError> {
    let n = poses_w_c.len();
    if n < config.min_keyframes.max(3) {
        return Err(AlignmentError::TooFewKeyframes {
            got: n,
            needed: config.min_keyframes.max(3),
        });
    }
    if preintegrations.len() + 1 != n {
        return Err(AlignmentError::CountMismatch {
            poses: n,
            preintegrations: preintegrations.len(),
        });
    }
    let finite = |t: &Isometry3<f64>| {
        t.translation.vector.iter().all(|v| v.is_finite())
            && t.rotation.coords.iter().all(|v| v.is_finite())
    };
    if !finite(T_b_c) {
        return Err(AlignmentError::NonFinitePose { index: usize::MAX });
    }
    if let Some(index) = poses_w_c.iter().position(|t| !finite(t)) {
        return Err(AlignmentError::NonFinitePose { index });
    }

    let T_c_b = T_b_c.inverse();
    let keyframes: Vec<Keyframe> = poses_w_c
        .iter()
        .map(|t| Keyframe {
            R_w_b: t.rotation * T_c_b.rotation,
            centre: t.translation.vector,
            lever: t.rotation * T_c_b.translation.vector,
        })
        .collect();

    let prior = *preintegrations[0].bias();
    let gyro_bias = estimate_gyro_bias(&keyframes, preintegrations, prior, config)?;
    let pres = preintegrations
        .iter()
        .map(|p| p.reintegrated(Bias::new(gyro_bias, prior.accel)))
        .collect::<Result<Vec<_>, _>>()?;

    let acceleration_excitation = excitation(&keyframes, &pres);
    if !config.known_scale
        && (acceleration_excitation.is_nan()
            || acceleration_excitation < config.min_acceleration_excitation)
    {
        return Err(AlignmentError::NoExcitation {
            excitation_m_s2: acceleration_excitation,
            threshold_m_s2: config.min_acceleration_excitation,
        });
    }
    let max_rotation = keyframes
        .iter()
        .map(|k| keyframes[0].R_w_b.angle_to(&k.R_w_b))
        .fold(0.0, f64::max);
    let with_ba =
        config.estimate_accel_bias && max_rotation >= config.min_rotation_for_accel_bias_rad;

    let system = System {
        keyframes: &keyframes,
        pres: &pres,
        known_scale: config.known_scale,
    };
    let g_norm = config.gravity_magnitude;
    // Free gravity first: its direction seeds the constrained refinement.
    let free = system.solve(&Vector3::zeros(), &DMatrix::identity(3, 3), false)?;
    let mut gravity = free.gravity;
    if !gravity.norm().is_normal() {
        return Err(AlignmentError::Degenerate {
            reason: "no gravity direction",
        });
    }
    gravity = gravity.normalize() * g_norm;
    for _ in 0..config.gravity_iterations {
        let basis = tangent_basis(&gravity);
        let step = system.solve(&gravity, &basis, with_ba)?;
        gravity = step.gravity.normalize() * g_norm;
    }
    let last = system.solve(&gravity, &DMatrix::zeros(3, 0), with_ba)?;
    if !(last.scale.is_finite() && last.scale > 0.0) {
        return Err(AlignmentError::BadScale { scale: last.scale });
    }
    let down = gravity / g_norm;
    let R_w_gravity = UnitQuaternion::rotation_between(&-Vector3::z(), &down).unwrap_or_else(
        // Gravity along +z: any half turn about a horizontal axis.
        || UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    );
    Ok(Alignment {
        scale: last.scale,
        gravity_w: gravity,
        R_w_gravity,
        gyro_bias,
        accel_bias: prior.accel + last.accel_bias,
        accel_bias_estimated: with_ba,
        velocities: last.velocities,
        acceleration_excitation,
    })
}

/// What vision says about one keyframe's IMU frame.
#[allow(non_snake_case)]
struct Keyframe {
    /// IMU orientation in `w`.
    R_w_b: UnitQuaternion<f64>,
    /// Camera centre in `w`, visual units.
    centre: Vector3<f64>,
    /// `p_w_b - scale * centre = R_w_c t_c_b`, metres.
    lever: Vector3<f64>,
}

/// Gauss-Newton on the rotation residuals, reintegrating at each new bias.
fn estimate_gyro_bias(
    keyframes: &[Keyframe],
    preintegrations: &[Preintegrated],
    prior: Bias,
    config: &AlignmentConfig,
) -> Result<Vector3<f64>, AlignmentError> {
    let mut bias = prior;
    let mut pres = preintegrations
        .iter()
        .map(|p| p.reintegrated(bias))
        .collect::<Result<Vec<_>, _>>()?;
    for _ in 0..config.gyro_iterations {
        let (mut h, mut b) = (Matrix3::zeros(), Vector3::zeros());
        for (pre, pair) in pres.iter().zip(keyframes.windows(2)) {
            let vision = pair[0].R_w_b.inverse() * pair[1].R_w_b;
            let r = so3::log(&(pre.delta().delta_r.inverse() * vision));
            // Log(Exp(J d)^T Exp(r)) ≈ r - Jl^-1(r) J d.
            let a = so3::left_jacobian_inverse(&r) * pre.jacobians().d_r_d_bg;
            h += a.transpose() * a;
            b += a.transpose() * r;
        }
        let step = h.try_inverse().ok_or(AlignmentError::Degenerate {
            reason: "gyro bias (no IMU data between keyframes?)",
        })? * b;
        bias.gyro += step;
        pres = pres
            .iter()
            .map(|p| p.reintegrated(bias))
            .collect::<Result<Vec<_>, _>>()?;
        if step.norm() < 1e-10 {
            break;
        }
    }
    Ok(bias.gyro)
}

/// RMS deviation of the per-interval mean world-frame specific force `R_w_bi dv / dt`:
/// zero when the true acceleration is constant (static, constant velocity).
fn excitation(keyframes: &[Keyframe], pres: &[Preintegrated]) -> f64 {
    let forces: Vec<Vector3<f64>> = pres
        .iter()
        .zip(keyframes)
        .map(|(p, k)| k.R_w_b * p.delta().delta_v / p.dt())
        .collect();
    let mean = forces.iter().sum::<Vector3<f64>>() / forces.len() as f64;
    (forces
        .iter()
        .map(|f| (f - mean).norm_squared())
        .sum::<f64>()
        / forces.len() as f64)
        .sqrt()
}

/// A unit vector orthogonal pair spanning the plane orthogonal to `g`, as columns.
fn tangent_basis(g: &Vector3<f64>) -> DMatrix<f64> {
    let a = g.normalize();
    let helper = if a.z.abs() < 0.9 {
        Vector3::z()
    } else {
        Vector3::x()
    };
    let b = (helper - a * a.dot(&helper)).normalize();
    let c = a.cross(&b);
    DMatrix::from_columns(&[
        DVector::from_column_slice(b.as_slice()),
        DVector::from_column_slice(c.as_slice()),
    ])
}

/// The linear position/velocity equations of every interval.
struct System<'a> {
    keyframes: &'a [Keyframe],
    pres: &'a [Preintegrated],
    /// Scale fixed to 1 (no scale unknown).
    known_scale: bool,
}

/// One solution of [`System::solve`].
struct Solution {
    scale: f64,
    gravity: Vector3<f64>,
    accel_bias: Vector3<f64>,
    velocities: Vec<Vector3<f64>>,
}

impl System<'_> {
    /// Solves for `[v_0 .. v_{N-1}, x_g, s, (b_a)]` with gravity `g = g0 + m x_g` (`m`: 3xk,
    /// k = 3 free, 2 tangent, 0 fixed) and the accelerometer bias relative to the
    /// preintegrations' when `with_ba`; without `s` (fixed to 1) for a known scale.
    fn solve(
        &self,
        g0: &Vector3<f64>,
        m: &DMatrix<f64>,
        with_ba: bool,
    ) -> Result<Solution, AlignmentError> {
        let n = self.keyframes.len();
        let (g_col, k) = (3 * n, m.ncols());
        let s_col = g_col + k;
        let ba_col = s_col + usize::from(!self.known_scale);
        let cols = ba_col + if with_ba { 3 } else { 0 };
        let rows = 6 * (n - 1);
        let mut a = DMatrix::<f64>::zeros(rows, cols);
        let mut rhs = DVector::<f64>::zeros(rows);
        for (i, pre) in self.pres.iter().enumerate() {
            let (ki, kj) = (&self.keyframes[i], &self.keyframes[i + 1]);
            let (d, dt) = (pre.delta(), pre.dt());
            let r = ki.R_w_b.to_rotation_matrix().into_inner();
            let (p_row, v_row) = (6 * i, 6 * i + 3);
            let half_dt2 = 0.5 * dt * dt;
            // Position: s (c_j - c_i) - v_i dt - g dt^2/2 - R_i J_pa b_a = R_i dp + d_i - d_j.
            let mut p_rhs = r * d.delta_p + ki.lever - kj.lever + g0 * half_dt2;
            if self.known_scale {
                p_rhs -= kj.centre - ki.centre;
            } else {
                a.view_mut((p_row, s_col), (3, 1))
                    .copy_from(&(kj.centre - ki.centre));
            }
            a.view_mut((p_row, 3 * i), (3, 3))
                .copy_from(&(Matrix3::identity() * -dt));
            a.view_mut((p_row, g_col), (3, k))
                .copy_from(&(m * -half_dt2));
            rhs.rows_mut(p_row, 3).copy_from(&p_rhs);
            // Velocity: v_j - v_i - g dt - R_i J_va b_a = R_i dv.
            a.view_mut((v_row, 3 * i), (3, 3))
                .copy_from(&(-Matrix3::identity()));
            a.view_mut((v_row, 3 * (i + 1)), (3, 3))
                .copy_from(&Matrix3::identity());
            a.view_mut((v_row, g_col), (3, k)).copy_from(&(m * -dt));
            rhs.rows_mut(v_row, 3).copy_from(&(r * d.delta_v + g0 * dt));
            if with_ba {
                let j = pre.jacobians();
                a.view_mut((p_row, ba_col), (3, 3))
                    .copy_from(&(-r * j.d_p_d_ba));
                a.view_mut((v_row, ba_col), (3, 3))
                    .copy_from(&(-r * j.d_v_d_ba));
            }
        }
        let x = least_squares(a, rhs)?;
        let xg = x.rows(g_col, k).into_owned();
        Ok(Solution {
            scale: if self.known_scale { 1.0 } else { x[s_col] },
            gravity: g0 + m * xg,
            accel_bias: if with_ba {
                Vector3::new(x[ba_col], x[ba_col + 1], x[ba_col + 2])
            } else {
                Vector3::zeros()
            },
            velocities: (0..n)
                .map(|i| Vector3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]))
                .collect(),
        })
    }
}

/// Least squares by SVD after scaling every column to unit norm (the unknowns mix m/s,
/// m/s^2 and visual units); refuses rank-deficient systems.
fn least_squares(mut a: DMatrix<f64>, b: DVector<f64>) -> Result<DVector<f64>, AlignmentError> {
    let norms: Vec<f64> = a.column_iter().map(|c| c.norm()).collect();
    if norms.iter().any(|&c| !(c > 0.0 && c.is_finite())) {
        return Err(AlignmentError::Degenerate {
            reason: "an unknown does not enter the equations (no translation?)",
        });
    }
    for (mut c, &norm) in a.column_iter_mut().zip(&norms) {
        c /= norm;
    }
    let svd = a.svd(true, true);
    let (max, min) = (svd.singular_values.max(), svd.singular_values.min());
    if min.is_nan() || min <= 1e-10 * max {
        return Err(AlignmentError::Degenerate {
            reason: "rank-deficient scale/gravity/velocity system",
        });
    }
    let mut x = svd.solve(&b, 0.0).map_err(|_| AlignmentError::Degenerate {
        reason: "SVD solve failed",
    })?;
    for (v, norm) in x.iter_mut().zip(&norms) {
        *v /= norm;
    }
    Ok(x)
}

#[cfg(test)]
#[allow(non_snake_case)]
mod tests {
    use super::*;
    use crate::{ImuParams, NavState};
    use approx::assert_relative_eq;
    use nalgebra::Translation3;

    const STEP: f64 = 0.005;

    /// Keyframe body states every `per_kf` steps and the preintegrations between them, for
    /// piecewise-constant readings: the states follow the very recursion the
    /// preintegration uses, so every delta is exact.
    fn simulate(
        gravity: &Vector3<f64>,
        bias: &Bias,
        moving: bool,
    ) -> (Vec<NavState>, Vec<Preintegrated>) {
        let (keyframes, per_kf) = (12, 40);
        let mut state = NavState {
            R_w_b: UnitQuaternion::from_scaled_axis(Vector3::new(0.1, -0.2, 0.3)),
            v_w_b: Vector3::new(0.3, 0.0, 0.1) * f64::from(u8::from(moving)),
            p_w_b: Vector3::new(1.0, -2.0, 0.5),
        };
        let mut states = vec![state];
        let mut pres = Vec::new();
        let mut pre = Preintegrated::new(Bias::default(), &ImuParams::euroc()).unwrap();
        for k in 1..=keyframes * per_kf {
            let t = k as f64 * STEP;
            let amp = if moving { 1.0 } else { 0.0 };
            let w = Vector3::new((1.3 * t).sin(), 0.8 * (0.9 * t).cos(), 0.5) * amp;
            let acc_w = Vector3::new((2.1 * t).cos(), (1.7 * t).sin(), 0.5 * (2.9 * t).sin()) * amp;
            let r = state.R_w_b;
            let f = r.inverse() * (acc_w - gravity);
            pre.integrate(STEP, &(w + bias.gyro), &(f + bias.accel))
                .unwrap();
            state.p_w_b += state.v_w_b * STEP + acc_w * (0.5 * STEP * STEP);
            state.v_w_b += acc_w * STEP;
            state.R_w_b = r * so3::exp(&(w * STEP));
            if k % per_kf == 0 {
                states.push(state);
                pres.push(pre);
                pre = Preintegrated::new(Bias::default(), &ImuParams::euroc()).unwrap();
            }
        }
        (states, pres)
    }

    fn camera_poses(
        states: &[NavState],
        T_b_c: &Isometry3<f64>,
        scale: f64,
    ) -> Vec<Isometry3<f64>> {
        states
            .iter()
            .map(|s| {
                let T_w_c = Isometry3::from_parts(Translation3::from(s.p_w_b), s.R_w_b) * T_b_c;
                Isometry3::from_parts(
                    Translation3::from(T_w_c.translation.vector / scale),
                    T_w_c.rotation,
                )
            })
            .collect()
    }

    fn extrinsic() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(-0.02, -0.06, 0.01),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 1.57)),
        )
    }

    #[test]
    fn recovers_everything_from_perfect_data() {
        let gravity = UnitQuaternion::from_scaled_axis(Vector3::new(0.4, -0.3, 0.2))
            * Vector3::new(0.0, 0.0, -9.81);
        let bias = Bias::new(
            Vector3::new(0.02, -0.03, 0.05),
            Vector3::new(0.1, -0.05, 0.08),
        );
        let (states, pres) = simulate(&gravity, &bias, true);
        let T_b_c = extrinsic();
        let poses = camera_poses(&states, &T_b_c, 2.5);
        let config = AlignmentConfig {
            estimate_accel_bias: true,
            ..AlignmentConfig::default()
        };
        let out = align(&poses, &T_b_c, &pres, &config).unwrap();
        assert!(out.accel_bias_estimated);
        assert_relative_eq!(out.scale, 2.5, epsilon = 1e-8);
        assert_relative_eq!(out.gravity_w, gravity, epsilon = 1e-7);
        assert_relative_eq!(out.gyro_bias, bias.gyro, epsilon = 1e-9);
        assert_relative_eq!(out.accel_bias, bias.accel, epsilon = 1e-6);
        assert_relative_eq!(
            out.R_w_gravity * Vector3::new(0.0, 0.0, -9.81),
            gravity,
            epsilon = 1e-7
        );
        for (v, s) in out.velocities.iter().zip(&states) {
            assert_relative_eq!(*v, s.v_w_b, epsilon = 1e-7);
        }
    }

    #[test]
    fn refuses_bad_input_and_static_motion() {
        let gravity = Vector3::new(0.0, 0.0, -9.81);
        let (states, pres) = simulate(&gravity, &Bias::default(), false);
        let T_b_c = extrinsic();
        let poses = camera_poses(&states, &T_b_c, 1.0);
        let config = AlignmentConfig::default();
        assert!(matches!(
            align(&poses, &T_b_c, &pres, &config),
            Err(AlignmentError::NoExcitation { .. })
        ));
        assert!(matches!(
            align(&poses[..3], &T_b_c, &pres[..2], &config),
            Err(AlignmentError::TooFewKeyframes { got: 3, needed: 5 })
        ));
        assert!(matches!(
            align(&poses, &T_b_c, &pres[1..], &config),
            Err(AlignmentError::CountMismatch { .. })
        ));
        let mut bad = poses.clone();
        bad[4].translation.vector.x = f64::NAN;
        assert_eq!(
            align(&bad, &T_b_c, &pres, &config),
            Err(AlignmentError::NonFinitePose { index: 4 })
        );
    }

    #[test]
    fn known_scale_aligns_a_static_start() {
        // A resting IMU: gravity and gyro bias are observable once the scale is known.
        let gravity = UnitQuaternion::from_scaled_axis(Vector3::new(0.05, -0.1, 0.0))
            * Vector3::new(0.0, 0.0, -9.81);
        let bias = Bias::new(Vector3::new(-0.002, 0.02, 0.08), Vector3::zeros());
        let (states, pres) = simulate(&gravity, &bias, false);
        let T_b_c = extrinsic();
        let poses = camera_poses(&states, &T_b_c, 1.0);
        let config = AlignmentConfig {
            known_scale: true,
            ..AlignmentConfig::default()
        };
        let out = align(&poses, &T_b_c, &pres, &config).unwrap();
        assert_eq!(out.scale, 1.0);
        assert!(out.acceleration_excitation < 1e-9);
        assert_relative_eq!(out.gravity_w, gravity, epsilon = 1e-7);
        assert_relative_eq!(out.gyro_bias, bias.gyro, epsilon = 1e-9);
        for v in &out.velocities {
            assert!(v.norm() < 1e-7, "{v}");
        }
    }
}
