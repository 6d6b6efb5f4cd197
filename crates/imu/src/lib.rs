//! IMU support for ferroslam: measurements, noise parameters, biases, unit plausibility
//! checks, on-manifold preintegration (Forster et al., T-RO 2017), the inertial residuals
//! of visual-inertial BA ([`InertialFactor`], [`BiasWalkFactor`]; LEFT pose perturbations)
//! and velocity/bias refinement from fixed poses ([`inertial_velocity_refine`]).
//!
//! # Frames and units
//!
//! The IMU frame is the body frame `b` (EuRoC's `S`, equal to its body frame `B`). Gyro
//! readings are rad/s, accelerometer readings are specific force in m/s^2 (a resting IMU
//! reads `+9.81` upwards), both in `b` and both including their biases:
//! `gyro = w_b + b_g + n_g`, `accel = R_w_b^T (a_w - g_w) + b_a + n_a`. Gravity `g_w` is
//! a world-frame vector passed by the caller (e.g. `(0, 0, -9.81)` for a z-up world).
//! Timestamps are f64 seconds on the camera clock.
//!
//! # Tangent order and perturbation side
//!
//! The preintegration covariance is over `[dphi; dv; dp]` ([`preintegration::ROT`],
//! [`preintegration::VEL`], [`preintegration::POS`]) with the rotation error on the RIGHT of
//! `Delta R`, as in Forster et al. Poses elsewhere in ferroslam use left perturbations.
//!
//! # Failure modes
//!
//! Nothing panics on bad input: out-of-order or non-finite samples, empty intervals, missing
//! data and invalid parameters return [`ImuError`]. [`check_units`] flags streams in deg/s or g.

#![warn(missing_docs)]

pub mod alignment;
pub mod bias;
pub mod error;
pub mod measurement;
pub mod params;
pub mod plausibility;
pub mod preintegration;
pub mod residual;
pub mod state;
pub mod velocity_refine;

pub use bias::Bias;
pub use error::ImuError;
pub use measurement::{check_stream, ImuMeasurement};
pub use params::ImuParams;
pub use plausibility::check_units;
pub use preintegration::{BiasJacobians, Preintegrated};
pub use residual::{BiasWalkFactor, ImuState, InertialFactor, InertialJacobians};
pub use state::{ImuDelta, NavState};
pub use velocity_refine::{inertial_velocity_refine, VelocityRefineConfig, VelocityRefinement};
