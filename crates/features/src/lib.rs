//! ORB features for the ferroslam core: ORB-SLAM's extractor (image pyramid, FAST, even
//! spread, orientation, rotated BRIEF; [`OrbExtractor`]), descriptor and keypoint types, the
//! scale pyramid, the keypoint grid used for radius search, and the Hamming matchers of
//! ORB-SLAM2/3.
//!
//! Conventions:
//! - Keypoints are pixel coordinates (x right, y down): RAW (distorted) as the extractor gives
//!   them, UNDISTORTED once a frame has undistorted them, which is what the matchers and the
//!   grid take; angles in degrees in `[0, 360)` as produced by OpenCV's ORB, `octave` is the
//!   pyramid level.
//! - Descriptors are 256-bit ORB descriptors stored as `[u8; 32]`; distances are Hamming
//!   distances in `0..=256`.
//! - Functions never panic on malformed input (mismatched slice lengths, out-of-range
//!   octaves, non-finite coordinates): such entries are skipped or left unmatched, as
//!   documented on each item.
#![warn(missing_docs)]

pub mod descriptor;
pub mod error;
pub mod extractor;
pub mod grid;
pub mod image;
pub mod keypoint;
pub mod mask;
pub mod matcher;
pub mod pyramid;
pub mod stereo;

pub use descriptor::{hamming, Descriptor};
pub use error::FeaturesError;
pub use extractor::{Features, ImagePyramid, OrbConfig, OrbExtractor};
pub use grid::{ImageBounds, KeypointGrid};
pub use image::{GrayImage, OwnedGrayImage};
pub use keypoint::Keypoint;
pub use mask::{check_mask_size, image_circle_mask, LevelMask};
pub use matcher::{
    match_brute_force, search_by_projection, search_by_projection_with, search_for_triangulation,
    search_for_triangulation_rays, MatchOptions, ProjectionQuery, RotationHistogram,
};
pub use pyramid::ScalePyramid;
pub use stereo::{match_stereo, StereoMatch, StereoView};
