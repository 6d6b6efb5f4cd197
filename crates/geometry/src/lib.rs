//! Geometry for ferroslam: Lie groups (SO(3), SE(3), Sim(3)), camera models, triangulation,
//! PnP, point-set alignment and the loop-closing Sim(3) RANSAC ([`sim3_ransac`]).
//!
//! This crate is where the project-wide conventions are written down. Every other crate
//! follows them; change them here or nowhere.
//!
//! # Frames and poses
//!
//! A transform named `T_a_b` maps a point from frame `b` into frame `a`:
//! `p_a = T_a_b * p_b`. Inner indices cancel when composing: `T_w_c = T_w_b * T_b_c`.
//! The pose of a camera in the world is `T_w_c`; projection uses its inverse `T_c_w`.
//! Poses are [`nalgebra::Isometry3<f64>`] (alias [`se3::SE3`]); similarities are
//! [`sim3::Sim3`], written `S_a_b` with the same meaning.
//!
//! # Tangent spaces and perturbations
//!
//! * se(3): `xi = [rho; phi]`, translation part `rho` at indices [`se3::TRANS`] (`0..3`),
//!   rotation part `phi` at [`se3::ROT`] (`3..6`).
//! * sim(3): `zeta = [rho; phi; sigma]` with `sigma = ln(scale)` at index 6.
//! * so(3): `phi`, a rotation vector (axis times angle, radians).
//! * Perturbations are on the LEFT: `T <- exp(delta) * T`, so `delta` is expressed in the
//!   frame the transform maps into (for `T_c_w`, the camera frame).
//!
//! # Units and images
//!
//! Metres, pixels, radians, seconds (f64 timestamps). Image origin is the top-left pixel
//! corner convention of OpenCV (pixel centres at integer coordinates), x right, y down;
//! the camera looks along +z.
//!
//! Keypoints inside the Rust core are in "core pixels" of the camera model
//! ([`camera::CameraModel`]): for a pinhole camera the UNDISTORTED pixel coordinates (the
//! ideal `(fx, fy, cx, cy)` maps camera points onto them, and lens distortion is removed
//! once, when keypoints are extracted); for a fisheye the raw pixels, since a field of view
//! beyond 180 degrees has no undistorted plane. Directions are unit rays. RGB-D and stereo
//! observations of a pinhole camera use ORB-SLAM's "virtual right" coordinate
//! `u_right = u - bf / depth` with `bf = fx * baseline`.
//!
//! # Failure modes
//!
//! Nothing in this crate panics on bad input (except the test helpers in [`testing`],
//! whose job is to fail tests). Operations without a unique answer return `Option`;
//! invalid parameters return [`GeometryError`].

#![warn(missing_docs)]

pub mod camera;
pub mod epnp;
pub mod error;
pub mod pnp;
pub mod rolling_shutter;
pub mod se3;
pub mod sim3;
pub mod sim3_ransac;
pub mod so3;
pub mod testing;
pub mod triangulation;
pub mod two_view;
pub mod umeyama;

pub use error::GeometryError;
