//! On-manifold IMU preintegration (Forster, Carlone, Dellaert, Scaramuzza, "On-Manifold
//! Preintegration for Real-Time Visual-Inertial Odometry", T-RO 2017), with the
//! sample handling of ORB-SLAM3.
//!
//! # Model
//!
//! With bias-corrected readings `w_k = gyro_k - b_g`, `a_k = accel_k - b_a`, each step of
//! `dt` seconds updates (Forster eq. 37, forward Euler with the rotation at the step start):
//!
//! ```text
//! dp <- dp + dv dt + 1/2 dR a_k dt^2
//! dv <- dv + dR a_k dt
//! dR <- dR Exp(w_k dt)
//! ```
//!
//! # Noise, covariance and bias Jacobians
//!
//! The 9x9 covariance is over `[dphi; dv; dp]` (indices [`ROT`], [`VEL`], [`POS`], the order of
//! ORB-SLAM3), with the rotation error on the RIGHT: `dR_measured = dR_true Exp(dphi)`
//! (Forster eq. 42), unlike the project's left perturbations on poses. Discrete white noise
//! over a step has variance `density^2 / dt` (Forster eq. 26). Bias Jacobians (Forster
//! appendix B) give the first-order correction [`Preintegrated::corrected`]; for large bias
//! changes use [`Preintegrated::reintegrated`].

use std::ops::Range;

use ferroslam_geometry::so3;
use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

use crate::{check_stream, Bias, ImuDelta, ImuError, ImuMeasurement, ImuParams, NavState};

/// Rotation error `dphi` (rad) in the preintegration covariance.
pub const ROT: Range<usize> = 0..3;
/// Velocity error (m/s) in the preintegration covariance.
pub const VEL: Range<usize> = 3..6;
/// Position error (m) in the preintegration covariance.
pub const POS: Range<usize> = 6..9;

/// Largest spacing of consecutive samples [`Preintegrated::between`] integrates across, in
/// sample periods (`1 / ImuParams::rate_hz`): a few dropped readings are bridged by linear
/// interpolation, a longer outage is missing data.
pub const MAX_GAP_PERIODS: f64 = 10.0;

/// A 9x9 matrix over `[dphi; dv; dp]`.
pub type Matrix9 = SMatrix<f64, 9, 9>;

/// Derivatives of the preintegrated deltas with respect to the biases, at the
/// linearisation bias. `d_r_d_bg` maps a gyro-bias change to a right rotation increment:
/// `dR(b + db) ≈ dR(b) Exp(d_r_d_bg db_g)`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BiasJacobians {
    /// Rotation vs gyro bias, rad per rad/s.
    pub d_r_d_bg: Matrix3<f64>,
    /// Velocity vs gyro bias, m/s per rad/s.
    pub d_v_d_bg: Matrix3<f64>,
    /// Velocity vs accelerometer bias, m/s per m/s^2 (seconds).
    pub d_v_d_ba: Matrix3<f64>,
    /// Position vs gyro bias, m per rad/s.
    pub d_p_d_bg: Matrix3<f64>,
    /// Position vs accelerometer bias, m per m/s^2 (seconds^2).
    pub d_p_d_ba: Matrix3<f64>,
}

/// One integration step: raw readings held constant over `dt` seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Step {
    dt: f64,
    gyro: Vector3<f64>,
    accel: Vector3<f64>,
}

/// IMU readings between two times, preintegrated at a fixed bias.
///
/// Build it with [`between`](Self::between) from a timestamped stream, or step by step with
/// [`new`](Self::new) and [`integrate`](Self::integrate). The raw steps are kept so that
/// [`reintegrated`](Self::reintegrated) can redo the work at another bias.
#[derive(Clone, Debug, PartialEq)]
pub struct Preintegrated {
    bias: Bias,
    params: ImuParams,
    dt: f64,
    delta_r: UnitQuaternion<f64>,
    delta_v: Vector3<f64>,
    delta_p: Vector3<f64>,
    covariance: Matrix9,
    jacobians: BiasJacobians,
    steps: Vec<Step>,
}

impl Preintegrated {
    /// An empty preintegration (identity deltas, zero covariance) linearised at `bias`.
    ///
    /// Fails with [`ImuError::InvalidParameter`] if `params` or `bias` is not valid.
    pub fn new(bias: Bias, params: &ImuParams) -> Result<Self, ImuError> {
        params.validate()?;
        if !bias
            .gyro
            .iter()
            .chain(bias.accel.iter())
            .all(|v| v.is_finite())
        {
            return Err(ImuError::InvalidParameter {
                name: "bias",
                value: f64::NAN,
                reason: "must be finite",
            });
        }
        Ok(Self {
            bias,
            params: *params,
            dt: 0.0,
            delta_r: UnitQuaternion::identity(),
            delta_v: Vector3::zeros(),
            delta_p: Vector3::zeros(),
            covariance: Matrix9::zeros(),
            jacobians: BiasJacobians::default(),
            steps: Vec::new(),
        })
    }

    /// Preintegrates `measurements` over `[start_s, end_s]` at `bias`.
    ///
    /// The signal is taken as piecewise linear between samples, and each piece (clipped to
    /// the interval) is integrated with its midpoint value held constant. Inside the
    /// interval this is ORB-SLAM3's average of consecutive samples; at a partial first or
    /// last piece the interval end is interpolated first, as ORB-SLAM3 does.
    ///
    /// An end the samples do not reach is extrapolated, as ORB-SLAM3 does: the last sample
    /// (the first one for the start) is held to it. A camera and an IMU that are not
    /// hardware-synchronised sample a few microseconds to a period apart, so the sample
    /// after a frame time is often not there yet when the frame is tracked. The stretch held
    /// counts as a gap: at most [`MAX_GAP_PERIODS`] sample periods.
    ///
    /// Requires finite, strictly increasing samples at most [`MAX_GAP_PERIODS`] sample
    /// periods apart, reaching that close to both ends of the interval. Errors:
    /// [`ImuError::EmptyInterval`], [`ImuError::NotCovered`] (IMU data missing for this
    /// frame), [`ImuError::Gap`] (readings missing inside), [`ImuError::NonFinite`],
    /// [`ImuError::OutOfOrder`], [`ImuError::InvalidParameter`]. Only the samples bracketing
    /// the interval are checked, so slicing a long stream stays cheap; call
    /// [`check_stream`] once on the whole stream to validate the rest.
    ///
    /// ```
    /// use approx::assert_relative_eq;
    /// use ferroslam_imu::{Bias, ImuMeasurement, ImuParams, NavState, Preintegrated};
    /// use nalgebra::{UnitQuaternion, Vector3};
    /// // An IMU at rest, z up, yawing at 0.1 rad/s: 200 Hz for one second.
    /// let imu: Vec<_> = (0..=200)
    ///     .map(|k| ImuMeasurement::new(k as f64 / 200.0, Vector3::new(0.0, 0.0, 0.1),
    ///                                  Vector3::new(0.0, 0.0, 9.81)))
    ///     .collect();
    /// let pre = Preintegrated::between(&imu, 0.25, 0.75, Bias::default(), &ImuParams::euroc())?;
    /// let start = NavState { R_w_b: UnitQuaternion::identity(), v_w_b: Vector3::zeros(),
    ///                        p_w_b: Vector3::new(1.0, 2.0, 3.0) };
    /// let end = pre.predict(&start, &Vector3::new(0.0, 0.0, -9.81));
    /// assert_relative_eq!(end.R_w_b.angle(), 0.05, epsilon = 1e-12);
    /// assert_relative_eq!(end.v_w_b, start.v_w_b, epsilon = 1e-12);
    /// assert_relative_eq!(end.p_w_b, start.p_w_b, epsilon = 1e-12);
    /// # Ok::<(), ferroslam_imu::ImuError>(())
    /// ```
    pub fn between(
        measurements: &[ImuMeasurement],
        start_s: f64,
        end_s: f64,
        bias: Bias,
        params: &ImuParams,
    ) -> Result<Self, ImuError> {
        if !(start_s.is_finite() && end_s.is_finite() && end_s > start_s) {
            return Err(ImuError::EmptyInterval { start_s, end_s });
        }
        let mut pre = Self::new(bias, params)?;
        // Only the samples bracketing the interval are validated: streams can be long.
        let first = measurements
            .partition_point(|m| m.t_s <= start_s)
            .saturating_sub(1);
        let last = (measurements.partition_point(|m| m.t_s < end_s) + 1).min(measurements.len());
        let window = &measurements[first..last.max(first)];
        check_stream(window).map_err(|e| match e {
            ImuError::NonFinite { index } => ImuError::NonFinite {
                index: index + first,
            },
            ImuError::OutOfOrder {
                index,
                t_s,
                previous_s,
            } => ImuError::OutOfOrder {
                index: index + first,
                t_s,
                previous_s,
            },
            other => other,
        })?;
        let max_gap_s = MAX_GAP_PERIODS / params.rate_hz;
        let (Some(first), Some(last)) = (window.first(), window.last()) else {
            return Err(ImuError::NotCovered {
                start_s,
                end_s,
                first_s: f64::NAN,
                last_s: f64::NAN,
            });
        };
        if first.t_s - start_s > max_gap_s || end_s - last.t_s > max_gap_s {
            return Err(ImuError::NotCovered {
                start_s,
                end_s,
                first_s: first.t_s,
                last_s: last.t_s,
            });
        }
        if let Some(pair) = window.windows(2).find(|p| p[1].t_s - p[0].t_s > max_gap_s) {
            return Err(ImuError::Gap {
                start_s,
                end_s,
                before_s: pair[0].t_s,
                after_s: pair[1].t_s,
                gap_s: pair[1].t_s - pair[0].t_s,
                max_gap_s,
            });
        }
        let held = |m: &ImuMeasurement, dt: f64| Step {
            dt,
            gyro: m.gyro_rad_s,
            accel: m.accel_m_s2,
        };
        if first.t_s > start_s {
            pre.step(held(first, (first.t_s.min(end_s)) - start_s));
        }
        for pair in window.windows(2) {
            let (m0, m1) = (&pair[0], &pair[1]);
            let (a, b) = (m0.t_s.max(start_s), m1.t_s.min(end_s));
            if b > a {
                // Linear interpolation at the midpoint of the clipped piece.
                let s = (0.5 * (a + b) - m0.t_s) / (m1.t_s - m0.t_s);
                let gyro = m0.gyro_rad_s.lerp(&m1.gyro_rad_s, s);
                let accel = m0.accel_m_s2.lerp(&m1.accel_m_s2, s);
                pre.step(Step {
                    dt: b - a,
                    gyro,
                    accel,
                });
            }
        }
        if last.t_s < end_s {
            pre.step(held(last, end_s - last.t_s.max(start_s)));
        }
        Ok(pre)
    }

    /// Integrates raw readings `gyro_rad_s`, `accel_m_s2` (IMU frame, bias included) held
    /// constant for `dt` seconds.
    ///
    /// Fails with [`ImuError::EmptyInterval`] if `dt` is not positive and finite, and with
    /// [`ImuError::NonFinite`] (index 0) if a reading is not finite; `self` is unchanged.
    pub fn integrate(
        &mut self,
        dt: f64,
        gyro_rad_s: &Vector3<f64>,
        accel_m_s2: &Vector3<f64>,
    ) -> Result<(), ImuError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(ImuError::EmptyInterval {
                start_s: self.dt,
                end_s: self.dt + dt,
            });
        }
        if !gyro_rad_s
            .iter()
            .chain(accel_m_s2.iter())
            .all(|v| v.is_finite())
        {
            return Err(ImuError::NonFinite { index: 0 });
        }
        self.step(Step {
            dt,
            gyro: *gyro_rad_s,
            accel: *accel_m_s2,
        });
        Ok(())
    }

    /// One validated step: covariance, then bias Jacobians, then deltas, each using the
    /// values at the start of the step.
    fn step(&mut self, step: Step) {
        let Step { dt, gyro, accel } = step;
        let w = gyro - self.bias.gyro;
        let a = accel - self.bias.accel;
        let r = self.delta_r.to_rotation_matrix().into_inner();
        let step_rotation = so3::exp(&(w * dt));
        let step_r = step_rotation.to_rotation_matrix().into_inner();
        let jr_dt = so3::right_jacobian(&(w * dt)) * dt;
        let r_a_hat = r * so3::hat(&a);
        let (dt2, i3) = (dt * dt, Matrix3::identity());

        // Error-state transition (Forster eq. 62, ORB-SLAM3 ImuTypes order [phi, v, p]).
        let mut f = Matrix9::identity();
        f.fixed_view_mut::<3, 3>(ROT.start, ROT.start)
            .copy_from(&step_r.transpose());
        f.fixed_view_mut::<3, 3>(VEL.start, ROT.start)
            .copy_from(&(-r_a_hat * dt));
        f.fixed_view_mut::<3, 3>(POS.start, ROT.start)
            .copy_from(&(-r_a_hat * (0.5 * dt2)));
        f.fixed_view_mut::<3, 3>(POS.start, VEL.start)
            .copy_from(&(i3 * dt));
        let mut g_gyro = SMatrix::<f64, 9, 3>::zeros();
        g_gyro
            .fixed_view_mut::<3, 3>(ROT.start, 0)
            .copy_from(&jr_dt);
        let mut g_accel = SMatrix::<f64, 9, 3>::zeros();
        g_accel
            .fixed_view_mut::<3, 3>(VEL.start, 0)
            .copy_from(&(r * dt));
        g_accel
            .fixed_view_mut::<3, 3>(POS.start, 0)
            .copy_from(&(r * (0.5 * dt2)));
        let var_gyro = self.params.gyro_noise_density.powi(2) / dt;
        let var_accel = self.params.accel_noise_density.powi(2) / dt;
        self.covariance = f * self.covariance * f.transpose()
            + g_gyro * g_gyro.transpose() * var_gyro
            + g_accel * g_accel.transpose() * var_accel;

        // Bias Jacobians (Forster appendix B); position first, it uses the old velocity ones.
        let j = &mut self.jacobians;
        j.d_p_d_ba += j.d_v_d_ba * dt - r * (0.5 * dt2);
        j.d_p_d_bg += j.d_v_d_bg * dt - r_a_hat * j.d_r_d_bg * (0.5 * dt2);
        j.d_v_d_ba -= r * dt;
        j.d_v_d_bg -= r_a_hat * j.d_r_d_bg * dt;
        j.d_r_d_bg = step_r.transpose() * j.d_r_d_bg - jr_dt;

        let a_rotated = r * a;
        self.delta_p += self.delta_v * dt + a_rotated * (0.5 * dt2);
        self.delta_v += a_rotated * dt;
        self.delta_r = UnitQuaternion::new_normalize((self.delta_r * step_rotation).into_inner());
        self.dt += dt;
        self.steps.push(step);
    }

    /// The same readings preintegrated again at `bias` (exact, unlike
    /// [`corrected`](Self::corrected)). Fails only if `bias` is not finite.
    pub fn reintegrated(&self, bias: Bias) -> Result<Self, ImuError> {
        let mut pre = Self::new(bias, &self.params)?;
        for &step in &self.steps {
            pre.step(step);
        }
        Ok(pre)
    }

    /// The deltas at the linearisation bias.
    pub fn delta(&self) -> ImuDelta {
        ImuDelta {
            dt: self.dt,
            delta_r: self.delta_r,
            delta_v: self.delta_v,
            delta_p: self.delta_p,
        }
    }

    /// The deltas at `bias`, to first order in `bias - self.bias()` (Forster eq. 44):
    /// `dR Exp(J_r^g db_g)`, `dv + J_v^g db_g + J_v^a db_a`, `dp + J_p^g db_g + J_p^a db_a`.
    pub fn corrected(&self, bias: &Bias) -> ImuDelta {
        let dbg = bias.gyro - self.bias.gyro;
        let dba = bias.accel - self.bias.accel;
        let j = &self.jacobians;
        ImuDelta {
            dt: self.dt,
            delta_r: self.delta_r * so3::exp(&(j.d_r_d_bg * dbg)),
            delta_v: self.delta_v + j.d_v_d_bg * dbg + j.d_v_d_ba * dba,
            delta_p: self.delta_p + j.d_p_d_bg * dbg + j.d_p_d_ba * dba,
        }
    }

    /// The state at the end of the interval from `state_i` at its start, at the
    /// linearisation bias; `gravity_w` in the world frame (m/s^2). See [`ImuDelta::predict`].
    pub fn predict(&self, state_i: &NavState, gravity_w: &Vector3<f64>) -> NavState {
        self.delta().predict(state_i, gravity_w)
    }

    /// Integrated time, seconds.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The bias the deltas were integrated with.
    pub fn bias(&self) -> &Bias {
        &self.bias
    }

    /// The noise model used for the covariance.
    pub fn params(&self) -> &ImuParams {
        &self.params
    }

    /// Covariance of the `[dphi; dv; dp]` errors from white sensor noise (no bias drift;
    /// add [`ImuParams::bias_walk_covariance`] for that). Units rad^2, m^2/s^2, m^2.
    pub fn covariance(&self) -> &Matrix9 {
        &self.covariance
    }

    /// Bias Jacobians at the linearisation bias.
    pub fn jacobians(&self) -> &BiasJacobians {
        &self.jacobians
    }

    /// Number of integration steps so far.
    pub fn num_steps(&self) -> usize {
        self.steps.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn stream(n: usize) -> Vec<ImuMeasurement> {
        (0..n)
            .map(|k| {
                let t = k as f64 * 0.005;
                ImuMeasurement::new(t, Vector3::new(0.1, -0.2, t), Vector3::new(t, 0.3, 9.8))
            })
            .collect()
    }

    fn between(m: &[ImuMeasurement], a: f64, b: f64) -> Result<Preintegrated, ImuError> {
        Preintegrated::between(m, a, b, Bias::default(), &ImuParams::euroc())
    }

    #[test]
    fn bad_intervals_are_errors() {
        let m = stream(11);
        for (a, b) in [(0.02, 0.02), (0.03, 0.01), (f64::NAN, 0.01)] {
            assert!(matches!(
                between(&m, a, b),
                Err(ImuError::EmptyInterval { .. })
            ));
        }
        // The samples span [0, 0.05] s at 200 Hz: ends up to 10 periods (50 ms) beyond are
        // extrapolated, further ones are missing data.
        assert!(matches!(
            between(&m, 0.01, 0.1001),
            Err(ImuError::NotCovered { last_s, .. }) if last_s == 0.05
        ));
        assert!(matches!(
            between(&m, -0.0501, 0.02),
            Err(ImuError::NotCovered { first_s, .. }) if first_s == 0.0
        ));
        assert!(between(&m, 0.01, 0.1).is_ok());
        assert!(between(&m, -0.05, 0.02).is_ok());
        assert!(matches!(
            between(&[], 0.0, 0.01),
            Err(ImuError::NotCovered { .. })
        ));
        // 200 Hz: 10 periods (50 ms) are bridged, 55 ms are missing data.
        let long = stream(41);
        let mut gappy: Vec<_> = long
            .iter()
            .filter(|m| !(0.05..0.1).contains(&m.t_s))
            .copied()
            .collect();
        assert!(matches!(
            between(&gappy, 0.01, 0.15),
            Err(ImuError::Gap { before_s, after_s, .. }) if before_s == 0.045 && after_s == 0.1
        ));
        assert!(between(&gappy, 0.1, 0.15).is_ok()); // the gap is outside
        gappy = long
            .iter()
            .filter(|m| !(0.05..0.09).contains(&m.t_s))
            .copied()
            .collect();
        assert!(between(&gappy, 0.01, 0.15).is_ok());
    }

    #[test]
    fn ends_beyond_the_samples_hold_the_nearest_sample() {
        // Unsynchronised clocks: the samples fall 3 us after the frame times (0, 0.05 s).
        let shifted = |n| -> Vec<_> {
            stream(n)
                .into_iter()
                .map(|mut s| {
                    s.t_s += 3e-6;
                    s
                })
                .collect()
        };
        // The sample after the end time (0.050003 s) is not there yet.
        let m = shifted(10);
        let pre = between(&m, 0.0, 0.05).unwrap();
        assert_relative_eq!(pre.dt(), 0.05, epsilon = 1e-15);
        // 3 us of the first sample, the 9 pieces between samples, 0.005 s - 3 us of the last.
        assert_eq!(pre.num_steps(), 11);
        let held_last = so3::exp(&(m[9].gyro_rad_s * (0.05 - m[9].t_s)));
        let interpolated = between(&m, 0.0, m[9].t_s).unwrap();
        assert_relative_eq!(
            pre.delta().delta_r,
            interpolated.delta().delta_r * held_last,
            epsilon = 1e-14
        );
        // With the sample after the end there, the last stretch is interpolated instead.
        let interpolated_end = between(&shifted(11), 0.0, 0.05).unwrap();
        assert_eq!(interpolated_end.num_steps(), 11);
        let midpoint_s = 0.5 * (m[9].t_s + 0.05);
        let gyro_mid = Vector3::new(0.1, -0.2, midpoint_s - 3e-6); // gyro z = unshifted time
        assert_relative_eq!(
            interpolated_end.delta().delta_r,
            interpolated.delta().delta_r * so3::exp(&(gyro_mid * (0.05 - m[9].t_s))),
            epsilon = 1e-14
        );
        // One sample inside the interval: held back to the start and on to the end.
        let one = [m[3]];
        let pre = between(&one, 0.012, 0.02).unwrap();
        assert_relative_eq!(pre.dt(), 0.008, epsilon = 1e-15);
        assert_eq!(pre.num_steps(), 2);
    }

    #[test]
    fn bad_samples_inside_the_interval_are_errors() {
        let mut m = stream(11);
        m[4].accel_m_s2.x = f64::INFINITY;
        assert_eq!(
            between(&m, 0.0, 0.05).unwrap_err(),
            ImuError::NonFinite { index: 4 }
        );
        let mut m = stream(11);
        m.swap(6, 7);
        assert!(matches!(
            between(&m, 0.0, 0.05),
            Err(ImuError::OutOfOrder { index: 7, .. })
        ));
    }

    #[test]
    fn integrate_rejects_bad_steps_and_leaves_state_unchanged() {
        let mut pre = Preintegrated::new(Bias::default(), &ImuParams::euroc()).unwrap();
        let (w, a) = (Vector3::new(0.1, 0.0, 0.0), Vector3::new(0.0, 0.0, 9.8));
        assert!(pre.integrate(0.0, &w, &a).is_err());
        assert!(pre.integrate(f64::NAN, &w, &a).is_err());
        assert!(pre.integrate(0.005, &(w * f64::NAN), &a).is_err());
        assert_eq!(pre.num_steps(), 0);
        assert_eq!(pre.dt(), 0.0);
        assert!(Preintegrated::new(
            Bias::new(Vector3::new(f64::NAN, 0.0, 0.0), Vector3::zeros()),
            &ImuParams::euroc()
        )
        .is_err());
    }

    #[test]
    fn partial_pieces_interpolate_at_their_midpoint() {
        // Constant-rate signal: the clipped pieces must integrate exactly to the interval.
        let m = stream(11);
        let pre = between(&m, 0.0012, 0.0437).unwrap();
        assert_relative_eq!(pre.dt(), 0.0437 - 0.0012, epsilon = 1e-15);
        assert_eq!(pre.num_steps(), 9);
        // Each clipped piece holds the linearly interpolated value at its midpoint.
        let expected = m
            .windows(2)
            .map(|p| {
                let (a, b) = (p[0].t_s.max(0.0012), p[1].t_s.min(0.0437));
                if b > a {
                    so3::exp(&(Vector3::new(0.1, -0.2, 0.5 * (a + b)) * (b - a)))
                } else {
                    UnitQuaternion::identity()
                }
            })
            .fold(UnitQuaternion::identity(), |acc, q| acc * q);
        assert_relative_eq!(pre.delta().delta_r, expected, epsilon = 1e-14);
    }
}
