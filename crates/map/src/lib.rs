//! The SLAM map of ORB-SLAM2/3: keyframes, map points, the covisibility graph and the
//! spanning tree, kept mutually consistent by every mutation.
//!
//! All state lives in one [`Map`] arena; modules refer to entities by id
//! ([`KeyFrameId`], [`MapPointId`]) and never by index or reference across calls.
//!
//! # Removal policy
//! A keyframe or map point that becomes bad (ORB-SLAM `SetBadFlag`) is **removed from the
//! arena**: [`Map::keyframe`] / [`Map::map_point`] return `None` for it, and every link to it
//! (observations, keyframe slots, covisibility edges, spanning-tree parent/children) is gone
//! in the same call. Ids are never reused, not even after [`Map::clear`]. Two small
//! tombstone tables keep what ORB-SLAM keeps bad objects alive for:
//! - [`Map::resolve_keyframe_pose`]: the pose of a culled keyframe relative to its spanning
//!   tree parent (ORB-SLAM `mTcp`), for writing full trajectories;
//! - [`Map::resolve_map_point`]: the point a fused point was replaced by (`GetReplaced`).
//!
//! # Invariants ([`Map::check_consistency`])
//! - an observation `kf -> index` of a point exists iff slot `index` of `kf` holds the point;
//! - covisibility edges are symmetric and their weight is the exact number of good points
//!   both keyframes observe (maintained incrementally); which pairs are connected is decided
//!   by [`Map::update_connections`] (ORB-SLAM's threshold of
//!   [`COVISIBILITY_THRESHOLD`] shared points, or the single best);
//! - the spanning tree is acyclic, parents/children agree and reference live keyframes; the
//!   first keyframe ([`Map::origin`]) is the root and is never culled.
//!
//! # Map files
//! [`Map::save`] / [`Map::load`] (and `save_to_path` / `load_from_path`) write and read the
//! whole map in a versioned, checksummed binary format, laid out in [`map::persist`].
//!
//! Poses follow the workspace convention: `T_c_w` maps world points into the camera.
//!
//! # Example
//! ```
//! use ferroslam_features::{ImageBounds, Keypoint, ScalePyramid};
//! use ferroslam_map::{FrameFeatures, Map};
//! use nalgebra::{Isometry3, Vector3};
//!
//! let kp = Keypoint { x: 320.0, y: 240.0, octave: 0, angle_deg: 0.0, response: 1.0 };
//! let bounds = ImageBounds { min_x: 0.0, max_x: 640.0, min_y: 0.0, max_y: 480.0 };
//! let features = || FrameFeatures::new(vec![kp], vec![[0; 32]], vec![], vec![], bounds).unwrap();
//!
//! let mut map = Map::new(ScalePyramid::default());
//! let kf0 = map.insert_keyframe(0.0, 0, Isometry3::identity(), features());
//! let kf1 = map.insert_keyframe(0.1, 1, Isometry3::translation(-0.1, 0.0, 0.0), features());
//! let mp = map.create_map_point(Vector3::new(0.0, 0.0, 2.0), kf0).unwrap();
//! map.add_observation(mp, kf0, 0).unwrap();
//! map.add_observation(mp, kf1, 0).unwrap();
//! map.update_connections(kf1).unwrap();
//! assert_eq!(map.covisibles(kf1), vec![(kf0, 1)]); // below 15 shared points: the single best
//! assert_eq!(map.keyframe(kf1).unwrap().parent(), Some(kf0));
//!
//! // A monocular point seen twice has nObs = 2: erasing one observation culls it.
//! assert!(map.erase_observation(mp, kf1));
//! assert!(map.map_point(mp).is_none());
//! assert!(map.covisibles(kf0).is_empty());
//! map.check_consistency().unwrap();
//! ```
#![warn(missing_docs)]

pub mod error;
pub mod frame_features;
pub mod ids;
pub mod keyframe;
pub mod map;
pub mod map_point;
pub mod rig;
pub mod sparse_model;

#[cfg(test)]
pub(crate) mod test_support;

pub use error::MapError;
pub use frame_features::{FrameFeatures, Rgb};
pub use ids::{KeyFrameId, MapPointId};
pub use keyframe::KeyFrame;
pub use map::{Map, MapEdit, MapJournal, COVISIBILITY_THRESHOLD};
pub use map_point::MapPoint;
pub use rig::{PairCamera, Rig, RigMember};
pub use sparse_model::{SparseImage, SparseModel, SparsePoint};
