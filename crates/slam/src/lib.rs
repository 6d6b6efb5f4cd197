//! The ferroslam SLAM system: ORB-SLAM's tracking and local mapping on top of the
//! `geometry`, `features`, `map` and `optim` crates.
//!
//! Conventions are those of `ferroslam_geometry`: `T_a_b` maps points from frame b into
//! frame a, camera poses are `T_w_c`, metres / pixels / seconds. Keypoints enter raw
//! (distorted) and become core pixels of the camera model once, when the frame is built
//! (undistorted for a pinhole, raw for a fisheye, whose geometry runs on unit rays).
#![allow(non_snake_case)]
#![warn(missing_docs)]

mod atlas;
mod background;
mod config;
mod context;
mod error;
mod frame;
mod front_end;
mod frustum;
mod imu_prediction;
mod inertial;
mod input_guard;
mod keyframe_insertion;
mod local_ba_problem;
mod local_inertial_ba;
mod local_mapping;
mod loop_closing;
mod mapping;
mod mono_init;
mod place_recognition;
mod point_fusion;
mod stereo_pair;
mod system;
mod track_result;
mod tracking;
mod trajectory;

pub use atlas::MapSummary;
pub use background::{BackgroundSlam, OwnedFrame};
pub use config::{
    user_options, DepthConfig, ExtractorConfig, InertialTuning, InitializationConfig,
    LoopClosingConfig, MappingConfig, OptionKind, OptionRange, OptionScope, PlaceRecognitionConfig,
    Sensor, SlamConfig, TrackingConfig, UserOption, VisibilityConfig,
};
pub use error::SlamError;
pub use frame::{MonoInput, ObserverInput, RgbdInput, StereoInput};
pub use front_end::{CameraImage, DepthImage, Image, OwnedRigFrame, RigFrame, RigFrameView};
pub use inertial::{
    AlignmentStatus, Bias, ImuParams, ImuSample, InertialAlignment, InertialConfig, Preintegrated,
};
pub use input_guard::InputGuard;
pub use local_mapping::MappingReport;
pub use loop_closing::{LoopClosure, LoopStats, MapMerge};
pub use mono_init::InitStatus;
pub use place_recognition::PlaceRecognition;
pub use system::{load_map_file, SlamSystem, TrackResult};
pub use tracking::TrackingState;
