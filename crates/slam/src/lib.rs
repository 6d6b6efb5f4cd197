//! The ferroslam SLAM system: ORB-SLAM's tracking and local mapping on top of the
//! `geometry`, `features`, `map` and `optim` crates.
//!
//! Conventions are those of `ferroslam_geometry`: `T_a_b` maps points from frame b into
//! frame a, camera poses are `T_w_c`, metres / pixels / seconds. Keypoints enter raw
//! (distorted) and are undistorted once, in [`frame::Frame`].
#![allow(non_snake_case)]
#![warn(missing_docs)]

pub mod background;
pub mod config;
pub mod context;
pub mod error;
pub mod frame;
pub mod frustum;
pub mod imu_prediction;
pub mod inertial;
pub mod input_guard;
mod keyframe_insertion;
pub mod local_ba_problem;
pub mod local_inertial_ba;
pub mod local_mapping;
pub mod loop_closing;
mod mapping;
pub mod mono_init;
pub mod place_recognition;
pub mod point_fusion;
pub mod system;
pub mod tracking;
pub mod trajectory;

pub use background::{BackgroundSlam, OwnedFrame};
pub use config::{Sensor, SlamConfig};
pub use error::SlamError;
pub use frame::{MonoInput, RgbdInput, StereoInput};
pub use inertial::{
    AlignmentStatus, Bias, ImuParams, ImuSample, InertialAlignment, InertialConfig,
};
pub use input_guard::InputGuard;
pub use loop_closing::{LoopClosure, LoopStats};
pub use system::{SlamSystem, TrackResult};
pub use tracking::TrackingState;
