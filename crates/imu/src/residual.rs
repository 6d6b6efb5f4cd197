//! Inertial residuals for bundle adjustment and tracking: the preintegrated IMU residual
//! between two keyframe states (Forster et al. 2017, eq. 45; ORB-SLAM3 `EdgeInertial`)
//! and the bias random-walk residual between consecutive biases.
//!
//! # State and perturbations
//!
//! A keyframe's [`ImuState`] is the body (IMU) pose `T_w_b`, its velocity `v_w_b` in the
//! world frame and its [`Bias`]. Jacobians are with respect to:
//!
//! - poses: LEFT perturbation in the world frame, `T_w_b <- exp(delta) * T_w_b` with
//!   `delta = [rho; phi]` in the order of `ferroslam_geometry::se3` (`se3::retract`), like
//!   every other pose in ferroslam; unlike Forster and ORB-SLAM3, which perturb `R` on the
//!   right and `p` additively;
//! - velocities and biases: additive, `v <- v + dv`, `b <- b + db`.
//!
//! # Residual
//!
//! With `dR, dv, dp` the preintegrated deltas corrected to first order to the bias of `i`
//! ([`Preintegrated::corrected`]), `R_i, p_i` from `T_w_b` at `i` and `g` gravity in `w`:
//!
//! ```text
//! r_R = Log(dR^T R_i^T R_j)                                  (rad)
//! r_v = R_i^T (v_j - v_i - g dt) - dv                         (m/s)
//! r_p = R_i^T (p_j - p_i - v_i dt - g dt^2 / 2) - dp          (m)
//! ```
//!
//! stacked as `[r_R; r_v; r_p]` in the order of [`crate::preintegration::ROT`], `VEL`,
//! `POS`, weighted by the inverse of [`Preintegrated::covariance`]. Only the bias of `i`
//! enters: the bias of `j` is tied to it by [`BiasWalkFactor`].

use ferroslam_geometry::{se3, so3};
use nalgebra::{Cholesky, Isometry3, Matrix3, Matrix6, SMatrix, SVector, Vector3, Vector6};

use crate::preintegration::{Matrix9, POS, ROT, VEL};
use crate::{Bias, ImuError, Preintegrated};

/// A 9-vector over `[r_R; r_v; r_p]`.
pub type Vector9 = SVector<f64, 9>;

/// Pose, velocity and bias of the body (IMU) frame `b` at one keyframe.
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuState {
    /// Body pose in the world: `p_w = T_w_b * p_b`, metres.
    pub T_w_b: Isometry3<f64>,
    /// Velocity of `b` in `w`, m/s.
    pub v_w_b: Vector3<f64>,
    /// IMU biases at this keyframe.
    pub bias: Bias,
}

/// Derivatives of the 9-dimensional inertial residual, one block per variable. Pose blocks
/// are for a left perturbation `exp([rho; phi]) * T_w_b` (columns `se3::TRANS`, `se3::ROT`);
/// the others are for additive perturbations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InertialJacobians {
    /// `d r / d delta_i`, pose of `i`.
    pub d_res_d_pose_i: SMatrix<f64, 9, 6>,
    /// `d r / d v_i`.
    pub d_res_d_vel_i: SMatrix<f64, 9, 3>,
    /// `d r / d b_g` (gyro bias of `i`).
    pub d_res_d_bias_gyro_i: SMatrix<f64, 9, 3>,
    /// `d r / d b_a` (accelerometer bias of `i`).
    pub d_res_d_bias_accel_i: SMatrix<f64, 9, 3>,
    /// `d r / d delta_j`, pose of `j`.
    pub d_res_d_pose_j: SMatrix<f64, 9, 6>,
    /// `d r / d v_j`.
    pub d_res_d_vel_j: SMatrix<f64, 9, 3>,
}

/// The preintegrated IMU measurement between keyframes `i` and `j` as a residual with its
/// information matrix. Build once per keyframe pair; evaluate at every iteration.
#[derive(Clone, Debug, PartialEq)]
pub struct InertialFactor {
    preintegrated: Preintegrated,
    gravity_w: Vector3<f64>,
    information: Matrix9,
}

impl InertialFactor {
    /// The factor for `preintegrated` (from `i` to `j`) under gravity `gravity_w` (world
    /// frame, m/s^2, e.g. `(0, 0, -9.81)` for a z-up world).
    ///
    /// Fails with [`ImuError::InvalidParameter`] if gravity is not finite and with
    /// [`ImuError::SingularCovariance`] if the covariance is not positive definite (no
    /// samples integrated, or zero noise densities).
    pub fn new(preintegrated: Preintegrated, gravity_w: Vector3<f64>) -> Result<Self, ImuError> {
        if !gravity_w.iter().all(|g| g.is_finite()) {
            return Err(ImuError::InvalidParameter {
                name: "gravity_w",
                value: gravity_w.norm(),
                reason: "must be finite",
            });
        }
        let covariance = preintegrated.covariance();
        // Symmetrised: the propagation is symmetric only up to rounding.
        let information = Cholesky::new(0.5 * (covariance + covariance.transpose()))
            .ok_or(ImuError::SingularCovariance {
                dt: preintegrated.dt(),
            })?
            .inverse();
        Ok(Self {
            preintegrated,
            gravity_w,
            information: 0.5 * (information + information.transpose()),
        })
    }

    /// The same factor with `extra` added to the covariance (over `[r_R; r_v; r_p]`): the
    /// uncertainty of a state the caller holds fixed, propagated into the residual (e.g. a
    /// tracking anchor whose velocity and biases are only known to some accuracy).
    ///
    /// Fails with [`ImuError::SingularCovariance`] if the sum is not positive definite.
    pub fn with_added_covariance(&self, extra: &Matrix9) -> Result<Self, ImuError> {
        let covariance = self.preintegrated.covariance() + extra;
        let information = Cholesky::new(0.5 * (covariance + covariance.transpose()))
            .ok_or(ImuError::SingularCovariance {
                dt: self.preintegrated.dt(),
            })?
            .inverse();
        Ok(Self {
            information: 0.5 * (information + information.transpose()),
            ..self.clone()
        })
    }

    /// The preintegration this factor measures with.
    pub fn preintegrated(&self) -> &Preintegrated {
        &self.preintegrated
    }

    /// Gravity in the world frame, m/s^2.
    pub fn gravity_w(&self) -> &Vector3<f64> {
        &self.gravity_w
    }

    /// Information matrix: the inverse of [`Preintegrated::covariance`], over `[r_R; r_v; r_p]`.
    pub fn information(&self) -> &Matrix9 {
        &self.information
    }

    /// The residual `[r_R; r_v; r_p]` (see the module docs) between `state_i` and `state_j`.
    pub fn residual(&self, state_i: &ImuState, state_j: &ImuState) -> Vector9 {
        self.evaluate(state_i, state_j).0
    }

    /// Squared Mahalanobis norm `r^T information r` of [`residual`](Self::residual):
    /// chi-square with 9 degrees of freedom if the states are true and only white sensor
    /// noise corrupts the preintegration.
    pub fn chi2(&self, state_i: &ImuState, state_j: &ImuState) -> f64 {
        let r = self.residual(state_i, state_j);
        r.dot(&(self.information * r))
    }

    /// The residual and its Jacobians (see [`InertialJacobians`] for the perturbations).
    #[allow(non_snake_case)]
    pub fn evaluate(&self, state_i: &ImuState, state_j: &ImuState) -> (Vector9, InertialJacobians) {
        let pre = &self.preintegrated;
        let g = self.gravity_w;
        let dt = pre.dt();
        let delta = pre.corrected(&state_i.bias);
        let R_i = state_i.T_w_b.rotation.to_rotation_matrix().into_inner();
        let R_j = state_j.T_w_b.rotation.to_rotation_matrix().into_inner();
        let R_i_t = R_i.transpose();
        let (p_i, p_j) = (
            state_i.T_w_b.translation.vector,
            state_j.T_w_b.translation.vector,
        );
        let (v_i, v_j) = (state_i.v_w_b, state_j.v_w_b);

        let r_r = so3::log(
            &(delta.delta_r.inverse() * state_i.T_w_b.rotation.inverse() * state_j.T_w_b.rotation),
        );
        let dv_w = v_j - v_i - g * dt;
        let dp_w = p_j - p_i - v_i * dt - g * (0.5 * dt * dt);
        let mut residual = Vector9::zeros();
        residual.fixed_rows_mut::<3>(ROT.start).copy_from(&r_r);
        residual
            .fixed_rows_mut::<3>(VEL.start)
            .copy_from(&(R_i_t * dv_w - delta.delta_v));
        residual
            .fixed_rows_mut::<3>(POS.start)
            .copy_from(&(R_i_t * dp_w - delta.delta_p));

        // Left pose perturbation to first order: R <- (I + hat(phi)) R, p <- p + rho - hat(p) phi.
        let jr_inv = so3::right_jacobian_inverse(&r_r);
        let mut d_pose_i = SMatrix::<f64, 9, 6>::zeros();
        let mut d_pose_j = SMatrix::<f64, 9, 6>::zeros();
        let (t, r) = (se3::TRANS.start, se3::ROT.start);
        d_pose_i
            .fixed_view_mut::<3, 3>(ROT.start, r)
            .copy_from(&(-jr_inv * R_j.transpose()));
        d_pose_i
            .fixed_view_mut::<3, 3>(VEL.start, r)
            .copy_from(&(R_i_t * so3::hat(&dv_w)));
        d_pose_i
            .fixed_view_mut::<3, 3>(POS.start, t)
            .copy_from(&-R_i_t);
        d_pose_i
            .fixed_view_mut::<3, 3>(POS.start, r)
            .copy_from(&(R_i_t * so3::hat(&(dp_w + p_i))));
        d_pose_j
            .fixed_view_mut::<3, 3>(ROT.start, r)
            .copy_from(&(jr_inv * R_j.transpose()));
        d_pose_j
            .fixed_view_mut::<3, 3>(POS.start, t)
            .copy_from(&R_i_t);
        d_pose_j
            .fixed_view_mut::<3, 3>(POS.start, r)
            .copy_from(&(-R_i_t * so3::hat(&p_j)));

        let mut d_vel_i = SMatrix::<f64, 9, 3>::zeros();
        d_vel_i
            .fixed_view_mut::<3, 3>(VEL.start, 0)
            .copy_from(&-R_i_t);
        d_vel_i
            .fixed_view_mut::<3, 3>(POS.start, 0)
            .copy_from(&(-R_i_t * dt));
        let mut d_vel_j = SMatrix::<f64, 9, 3>::zeros();
        d_vel_j
            .fixed_view_mut::<3, 3>(VEL.start, 0)
            .copy_from(&R_i_t);

        // Gyro bias enters dR = dR(b0) Exp(J (b_g - b0_g)) (Forster eq. 44, ORB-SLAM3).
        let j = pre.jacobians();
        let dbg = state_i.bias.gyro - pre.bias().gyro;
        let exp_r_t = so3::exp(&r_r).to_rotation_matrix().into_inner().transpose();
        let mut d_bg = SMatrix::<f64, 9, 3>::zeros();
        d_bg.fixed_view_mut::<3, 3>(ROT.start, 0).copy_from(
            &(-jr_inv * exp_r_t * so3::right_jacobian(&(j.d_r_d_bg * dbg)) * j.d_r_d_bg),
        );
        d_bg.fixed_view_mut::<3, 3>(VEL.start, 0)
            .copy_from(&-j.d_v_d_bg);
        d_bg.fixed_view_mut::<3, 3>(POS.start, 0)
            .copy_from(&-j.d_p_d_bg);
        let mut d_ba = SMatrix::<f64, 9, 3>::zeros();
        d_ba.fixed_view_mut::<3, 3>(VEL.start, 0)
            .copy_from(&-j.d_v_d_ba);
        d_ba.fixed_view_mut::<3, 3>(POS.start, 0)
            .copy_from(&-j.d_p_d_ba);

        (
            residual,
            InertialJacobians {
                d_res_d_pose_i: d_pose_i,
                d_res_d_vel_i: d_vel_i,
                d_res_d_bias_gyro_i: d_bg,
                d_res_d_bias_accel_i: d_ba,
                d_res_d_pose_j: d_pose_j,
                d_res_d_vel_j: d_vel_j,
            },
        )
    }
}

/// The bias random walk between consecutive keyframes `dt` seconds apart:
/// `r = [b_g,j - b_g,i; b_a,j - b_a,i]` (rad/s, m/s^2) with information
/// `diag(1 / (sigma_g^2 dt), 1 / (sigma_a^2 dt))` from [`crate::ImuParams::bias_walk_covariance`].
/// Jacobians are constant: `d r / d b_i = -I_6`, `d r / d b_j = I_6`, columns `[b_g; b_a]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BiasWalkFactor {
    information: Matrix6<f64>,
}

impl BiasWalkFactor {
    /// The factor for `params` over `dt` seconds.
    ///
    /// Fails with [`ImuError::EmptyInterval`] if `dt` is not positive and finite,
    /// [`ImuError::InvalidParameter`] if `params` are invalid and
    /// [`ImuError::SingularCovariance`] if a random walk is zero (the bias would be fixed:
    /// hold it constant instead).
    pub fn new(params: &crate::ImuParams, dt: f64) -> Result<Self, ImuError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(ImuError::EmptyInterval {
                start_s: 0.0,
                end_s: dt,
            });
        }
        params.validate()?;
        if params.gyro_random_walk == 0.0 || params.accel_random_walk == 0.0 {
            return Err(ImuError::SingularCovariance { dt });
        }
        let (cov_g, cov_a) = params.bias_walk_covariance(dt);
        let mut information = Matrix6::zeros();
        information
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::from_diagonal(&cov_g.diagonal().map(|c| 1.0 / c)));
        information
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&Matrix3::from_diagonal(&cov_a.diagonal().map(|c| 1.0 / c)));
        Ok(Self { information })
    }

    /// `[b_g,j - b_g,i; b_a,j - b_a,i]`.
    pub fn residual(&self, bias_i: &Bias, bias_j: &Bias) -> Vector6<f64> {
        let mut r = Vector6::zeros();
        r.fixed_rows_mut::<3>(0)
            .copy_from(&(bias_j.gyro - bias_i.gyro));
        r.fixed_rows_mut::<3>(3)
            .copy_from(&(bias_j.accel - bias_i.accel));
        r
    }

    /// Information matrix over `[r_g; r_a]`, diagonal.
    pub fn information(&self) -> &Matrix6<f64> {
        &self.information
    }

    /// `r^T information r`: chi-square with 6 degrees of freedom for a true random walk.
    pub fn chi2(&self, bias_i: &Bias, bias_j: &Bias) -> f64 {
        let r = self.residual(bias_i, bias_j);
        r.dot(&(self.information * r))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ImuParams, NavState};
    use approx::assert_relative_eq;
    use ferroslam_geometry::testing::check_jacobian;
    use nalgebra::{DMatrix, DVector, Translation3, UnitQuaternion};

    const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);

    /// 0.4 s of brisk, varying motion at 200 Hz, integrated at a non-zero bias.
    fn preintegrated() -> Preintegrated {
        let bias = Bias::new(
            Vector3::new(0.01, -0.02, 0.015),
            Vector3::new(0.1, 0.05, -0.08),
        );
        let mut pre = Preintegrated::new(bias, &ImuParams::euroc()).unwrap();
        for k in 0..80 {
            let t = k as f64 * 0.005;
            let gyro = Vector3::new(0.5 * (3.0 * t).sin(), -0.3 + t, 0.8 * (2.0 * t).cos());
            let accel = Vector3::new(1.0 + t, -0.5 * (4.0 * t).sin(), 9.5 + 0.3 * t);
            pre.integrate(0.005, &gyro, &accel).unwrap();
        }
        pre
    }

    fn state(rotation: Vector3<f64>, p: Vector3<f64>, v: Vector3<f64>, bias: Bias) -> ImuState {
        ImuState {
            T_w_b: Isometry3::from_parts(
                Translation3::from(p),
                UnitQuaternion::from_scaled_axis(rotation),
            ),
            v_w_b: v,
            bias,
        }
    }

    /// States with a clearly non-zero residual and a bias away from the linearisation one,
    /// so that every term of every Jacobian matters.
    fn states() -> (ImuState, ImuState) {
        let bias = Bias::new(Vector3::new(0.03, -0.01, 0.0), Vector3::new(0.2, -0.1, 0.0));
        (
            state(
                Vector3::new(0.3, -0.7, 1.2),
                Vector3::new(1.0, -2.0, 0.5),
                Vector3::new(0.4, 0.1, -0.3),
                bias,
            ),
            state(
                Vector3::new(0.5, -0.4, 1.6),
                Vector3::new(1.3, -1.8, 0.2),
                Vector3::new(0.9, -0.2, 0.1),
                Bias::default(),
            ),
        )
    }

    fn factor() -> InertialFactor {
        InertialFactor::new(preintegrated(), GRAVITY).unwrap()
    }

    /// Checks one Jacobian block: `perturb` applies a tangent vector to the states.
    fn check(
        name: &str,
        analytic: DMatrix<f64>,
        perturb: impl Fn(&DVector<f64>, &mut ImuState, &mut ImuState),
    ) {
        let f = factor();
        let (i, j) = states();
        let x0 = DVector::zeros(analytic.ncols());
        let res = |x: &DVector<f64>| {
            let (mut a, mut b) = (i, j);
            perturb(x, &mut a, &mut b);
            DVector::from_column_slice(f.residual(&a, &b).as_slice())
        };
        check_jacobian(name, &analytic, res, &x0, 1e-6, 1e-7);
    }

    fn v3(x: &DVector<f64>) -> Vector3<f64> {
        Vector3::new(x[0], x[1], x[2])
    }

    fn left(x: &DVector<f64>, t: &Isometry3<f64>) -> Isometry3<f64> {
        se3::exp(&Vector6::from_column_slice(x.as_slice())) * t
    }

    fn dyn_matrix<const C: usize>(m: &SMatrix<f64, 9, C>) -> DMatrix<f64> {
        DMatrix::from_column_slice(9, C, m.as_slice())
    }

    #[test]
    fn added_covariance_weakens_the_information() {
        let f = factor();
        let mut extra = Matrix9::zeros();
        for k in 0..9 {
            extra[(k, k)] = 1e-2;
        }
        let inflated = f.with_added_covariance(&extra).unwrap();
        let expected = (f.preintegrated().covariance() + extra)
            .try_inverse()
            .unwrap();
        assert_relative_eq!(*inflated.information(), expected, max_relative = 1e-8);
        assert!(inflated.information().trace() < f.information().trace());
        assert_eq!(inflated.preintegrated(), f.preintegrated());
        let bad = -f.preintegrated().covariance() * 2.0;
        assert!(matches!(
            f.with_added_covariance(&bad),
            Err(ImuError::SingularCovariance { .. })
        ));
    }

    #[test]
    fn jacobians_match_central_differences() {
        let (i, j) = states();
        let (r, jac) = factor().evaluate(&i, &j);
        assert!(
            r.norm() > 0.1,
            "the test states must be far from a zero residual"
        );
        check("pose i", dyn_matrix(&jac.d_res_d_pose_i), |x, a, _| {
            a.T_w_b = left(x, &a.T_w_b)
        });
        check("pose j", dyn_matrix(&jac.d_res_d_pose_j), |x, _, b| {
            b.T_w_b = left(x, &b.T_w_b)
        });
        check("velocity i", dyn_matrix(&jac.d_res_d_vel_i), |x, a, _| {
            a.v_w_b += v3(x)
        });
        check("velocity j", dyn_matrix(&jac.d_res_d_vel_j), |x, _, b| {
            b.v_w_b += v3(x)
        });
        check(
            "gyro bias i",
            dyn_matrix(&jac.d_res_d_bias_gyro_i),
            |x, a, _| a.bias.gyro += v3(x),
        );
        check(
            "accel bias i",
            dyn_matrix(&jac.d_res_d_bias_accel_i),
            |x, a, _| a.bias.accel += v3(x),
        );
    }

    #[test]
    fn residual_vanishes_on_the_predicted_state() {
        let f = factor();
        let (i, _) = states();
        let i = ImuState {
            bias: *f.preintegrated().bias(),
            ..i
        };
        let nav = NavState {
            R_w_b: i.T_w_b.rotation,
            v_w_b: i.v_w_b,
            p_w_b: i.T_w_b.translation.vector,
        };
        let end = f.preintegrated().predict(&nav, &GRAVITY);
        let j = ImuState {
            T_w_b: Isometry3::from_parts(Translation3::from(end.p_w_b), end.R_w_b),
            v_w_b: end.v_w_b,
            bias: Bias::default(),
        };
        assert_relative_eq!(f.residual(&i, &j), Vector9::zeros(), epsilon = 1e-12);
        assert!(f.chi2(&i, &j) < 1e-12);
        // Information is the inverse covariance.
        assert_relative_eq!(
            f.information() * f.preintegrated().covariance(),
            Matrix9::identity(),
            epsilon = 1e-6
        );
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let empty = Preintegrated::new(Bias::default(), &ImuParams::euroc()).unwrap();
        assert!(matches!(
            InertialFactor::new(empty, GRAVITY),
            Err(ImuError::SingularCovariance { .. })
        ));
        assert!(matches!(
            InertialFactor::new(preintegrated(), Vector3::new(0.0, f64::NAN, -9.81)),
            Err(ImuError::InvalidParameter {
                name: "gravity_w",
                ..
            })
        ));
        let params = ImuParams::euroc();
        assert!(BiasWalkFactor::new(&params, 0.0).is_err());
        assert!(BiasWalkFactor::new(&params, f64::INFINITY).is_err());
        let fixed = ImuParams {
            gyro_random_walk: 0.0,
            ..params
        };
        assert!(matches!(
            BiasWalkFactor::new(&fixed, 0.5),
            Err(ImuError::SingularCovariance { .. })
        ));
    }

    #[test]
    fn bias_walk_residual_and_information() {
        let params = ImuParams::euroc();
        let f = BiasWalkFactor::new(&params, 0.5).unwrap();
        let (bi, bj) = (
            Bias::new(Vector3::new(0.1, 0.2, 0.3), Vector3::new(-0.1, 0.0, 0.2)),
            Bias::new(
                Vector3::new(0.1, 0.2, 0.3 + 1e-5),
                Vector3::new(-0.1, 0.003, 0.2),
            ),
        );
        let r = f.residual(&bi, &bj);
        assert_relative_eq!(
            r,
            Vector6::new(0.0, 0.0, 1e-5, 0.0, 0.003, 0.0),
            epsilon = 1e-15
        );
        // One sigma of drift on each of two axes: chi2 = 2.
        let sigma_g = params.gyro_random_walk * 0.5f64.sqrt();
        let sigma_a = params.accel_random_walk * 0.5f64.sqrt();
        let one_sigma = Bias::new(
            bi.gyro + Vector3::new(sigma_g, 0.0, 0.0),
            bi.accel + Vector3::new(0.0, 0.0, -sigma_a),
        );
        assert_relative_eq!(f.chi2(&bi, &one_sigma), 2.0, epsilon = 1e-9);
        // The documented constant Jacobians, -I for b_i and +I for b_j.
        let to_bias = |x: &DVector<f64>| {
            Bias::new(
                Vector3::new(x[0], x[1], x[2]),
                Vector3::new(x[3], x[4], x[5]),
            )
        };
        let x0 = DVector::from_column_slice(&[0.1, 0.2, 0.3, -0.1, 0.0, 0.2]);
        let as_dyn = |r: Vector6<f64>| DVector::from_column_slice(r.as_slice());
        check_jacobian(
            "bias walk, b_i",
            &-DMatrix::identity(6, 6),
            |x| as_dyn(f.residual(&to_bias(x), &bj)),
            &x0,
            1e-6,
            1e-9,
        );
        check_jacobian(
            "bias walk, b_j",
            &DMatrix::identity(6, 6),
            |x| as_dyn(f.residual(&bi, &to_bias(x))),
            &x0,
            1e-6,
            1e-9,
        );
    }
}
