//! The crate's error type.

use crate::{KeyFrameId, MapPointId};

/// Errors of map mutations on invalid input. Removals (`erase_observation`,
/// `set_map_point_bad`, `set_keyframe_bad`) are idempotent and report `false` instead.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MapError {
    /// The keyframe was never inserted or has been culled.
    #[error(
        "keyframe {0} is not in the map (never inserted, or culled): check Map::keyframe first"
    )]
    UnknownKeyFrame(KeyFrameId),
    /// The map point was never created or has been removed (culled or fused).
    #[error(
        "map point {0} is not in the map (never created, culled or fused): \
         check Map::map_point or follow Map::resolve_map_point"
    )]
    UnknownMapPoint(MapPointId),
    /// A keypoint index beyond the keyframe's keypoints.
    #[error("keypoint index {index} out of range: keyframe {kf} has {len} keypoints")]
    KeypointOutOfRange {
        /// The keyframe.
        kf: KeyFrameId,
        /// The rejected index.
        index: usize,
        /// Number of keypoints of the keyframe.
        len: usize,
    },
    /// The keypoint already observes another map point.
    #[error(
        "keypoint {index} of keyframe {kf} already observes {existing}: erase that \
         observation first, or fuse the points with Map::replace_map_point"
    )]
    SlotOccupied {
        /// The keyframe.
        kf: KeyFrameId,
        /// The keypoint index.
        index: usize,
        /// The point the keypoint already observes.
        existing: MapPointId,
    },
    /// The map point is already observed by the keyframe (through another keypoint).
    #[error("{mp} is already observed by keyframe {kf} through keypoint {index}")]
    AlreadyObserved {
        /// The map point.
        mp: MapPointId,
        /// The keyframe.
        kf: KeyFrameId,
        /// The keypoint that observes it.
        index: usize,
    },
    /// Per-keypoint arrays of different lengths.
    #[error(
        "FrameFeatures: {field} has {got} entries but there are {expected} keypoints \
         (depth and u_right may also be empty for monocular frames)"
    )]
    LengthMismatch {
        /// Name of the offending array.
        field: &'static str,
        /// Number of keypoints.
        expected: usize,
        /// Length of the offending array.
        got: usize,
    },
}
