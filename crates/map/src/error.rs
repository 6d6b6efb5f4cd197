//! The crate's error type.

use crate::{KeyFrameId, MapPointId};

/// Errors of map mutations on invalid input, and of reading / writing map files
/// ([`crate::Map::save`], [`crate::Map::load`]). Removals (`erase_observation`,
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
    /// The rig's camera starts do not begin at keypoint 0 (or name no camera at all).
    #[error(
        "FrameFeatures: camera_starts {starts:?} must begin with 0 (camera 0 starts at the \
         first keypoint)"
    )]
    CameraStartsNotAtZero {
        /// The rejected starts.
        starts: Vec<usize>,
    },
    /// A camera starts before the previous one: keypoints must be sorted by camera.
    #[error(
        "FrameFeatures: camera_starts {starts:?} decrease at camera {camera}: keypoints must \
         be sorted by camera"
    )]
    CameraStartsDecreasing {
        /// The rejected starts.
        starts: Vec<usize>,
        /// The first camera starting before its predecessor.
        camera: usize,
    },
    /// A camera starts beyond the last keypoint.
    #[error(
        "FrameFeatures: camera_starts {starts:?}: camera {camera} starts beyond the {len} \
         keypoints"
    )]
    CameraStartBeyondKeypoints {
        /// The rejected starts.
        starts: Vec<usize>,
        /// The first camera starting beyond the keypoints.
        camera: usize,
        /// Number of keypoints.
        len: usize,
    },
    /// Not one image bounds per camera.
    #[error("FrameFeatures: {cameras} cameras but {bounds} image bounds (one per camera)")]
    CameraBoundsMismatch {
        /// Number of cameras (entries of `camera_starts`).
        cameras: usize,
        /// Number of bounds given.
        bounds: usize,
    },
    /// Reading or writing a map file failed (the `std::io::Error` kind and message).
    #[error("{message}")]
    MapFileIo {
        /// Kind of the underlying I/O error.
        kind: std::io::ErrorKind,
        /// Its message.
        message: String,
    },
    /// The data does not start with the map-file magic bytes.
    #[error("not a ferroslam map file: starts with {found:02x?}, expected the magic {expected:?}")]
    NotAMapFile {
        /// The first bytes read (up to the magic's length).
        found: Vec<u8>,
        /// The expected magic.
        expected: &'static str,
    },
    /// The map file was written in a format version this build cannot read.
    #[error(
        "map file format version {found} is not supported (this build reads versions \
         {oldest} to {newest}): load it with the ferroslam version that wrote it"
    )]
    UnsupportedMapVersion {
        /// Version in the file.
        found: u32,
        /// The oldest version this build reads.
        oldest: u32,
        /// The version this build writes, the newest it reads.
        newest: u32,
    },
    /// The map file ends early.
    #[error("map file truncated while reading {what}: needed {needed} bytes, {available} left")]
    TruncatedMapFile {
        /// What was being read.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// Bytes that were left.
        available: u64,
    },
    /// The trailing checksum does not match the content: the file was altered or damaged.
    #[error(
        "map file checksum mismatch (stored {stored:#018x}, computed {computed:#018x}): \
         the file is damaged"
    )]
    MapFileChecksum {
        /// Checksum stored in the file.
        stored: u64,
        /// Checksum of the bytes read.
        computed: u64,
    },
    /// The map file has a valid checksum but content that cannot be a map.
    #[error("corrupt map file: {what}")]
    CorruptMapFile {
        /// What is wrong.
        what: String,
    },
    /// A whole-map operation that the journal cannot record was called while recording.
    #[error("Map::{0} is not recorded in the journal: stop recording (Map::take_journal) first")]
    Recording(&'static str),
    /// An argument outside its domain.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Renumbering would push ids past `u32::MAX`.
    #[error("shifting {what} ids by {offset} overflows u32 (the next id is {next})")]
    IdOverflow {
        /// "keyframe" or "map point".
        what: &'static str,
        /// The map's next id of that kind.
        next: u32,
        /// The rejected offset.
        offset: u32,
    },
    /// Both maps of a merge hold this keyframe id (live or culled).
    #[error(
        "keyframe id {0} is in both maps (live or culled): renumber one with Map::shift_ids \
         first (e.g. by the other's Map::next_ids)"
    )]
    KeyFrameIdCollision(KeyFrameId),
    /// Both maps of a merge hold this map point id (live or fused).
    #[error(
        "map point id {0} is in both maps (live or fused): renumber one with Map::shift_ids \
         first (e.g. by the other's Map::next_ids)"
    )]
    MapPointIdCollision(MapPointId),
    /// The maps of a merge use different ORB scale pyramids.
    #[error(
        "scale pyramids differ: this map has {ours_levels} levels of factor {ours_factor}, \
         the other {theirs_levels} of factor {theirs_factor}"
    )]
    PyramidMismatch {
        /// Levels of the absorbing map.
        ours_levels: usize,
        /// Scale factor of the absorbing map.
        ours_factor: f64,
        /// Levels of the absorbed map.
        theirs_levels: usize,
        /// Scale factor of the absorbed map.
        theirs_factor: f64,
    },
    /// The link keyframe of the absorbed map is not connected to that map's origin.
    #[error(
        "keyframe {kf} does not reach its map's origin {origin} by parent links: connect it \
         (Map::update_connections) before merging through it"
    )]
    NotInSpanningTree {
        /// The link keyframe.
        kf: KeyFrameId,
        /// The absorbed map's origin.
        origin: KeyFrameId,
    },
}

impl From<std::io::Error> for MapError {
    fn from(e: std::io::Error) -> Self {
        MapError::MapFileIo {
            kind: e.kind(),
            message: e.to_string(),
        }
    }
}
