//! The atlas (ORB-SLAM3 `Atlas`): the maps a run keeps besides the one it tracks in. A map
//! lost for good is stored here with the frames tracked in it and its keyframe index, so a
//! later frame can relocalise in it and a later keyframe can recognise it and merge with it.
//! Map ids are unique within a run; keyframe and point ids are unique across its maps (each
//! new map continues the id counters), so two maps join without renumbering.

use ferroslam_map::Map;

use crate::inertial::InertialMapState;
use crate::loop_closing::LoopDetector;
use crate::place_recognition::PlaceRecognition;
use crate::trajectory::Trajectory;

/// A map of the atlas with what belongs to it.
pub(crate) struct StoredMap {
    /// Unique within the run; a merged map keeps the older map's id.
    pub id: usize,
    pub map: Map,
    /// The frames tracked in the map.
    pub trajectory: Trajectory,
    /// Its keyframe index (with a vocabulary).
    pub place: Option<PlaceRecognition>,
    /// Merge candidates of the current map's recent keyframes in this map, with their
    /// consistency counts (as loop candidates are counted).
    pub detector: LoopDetector,
    /// Its part of the IMU state, in a visual-inertial system.
    pub inertial: Option<InertialMapState>,
}

/// What a map looks like from outside: for `maps()` listings and run summaries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MapSummary {
    /// The map's id (unique within the run).
    pub id: usize,
    /// Frames tracked in the map.
    pub frames: usize,
    /// Live keyframes.
    pub keyframes: usize,
    /// Live map points.
    pub points: usize,
    /// Whether tracking runs in this map now.
    pub current: bool,
}

impl StoredMap {
    /// The map's summary (not the current one).
    pub(crate) fn summary(&self) -> MapSummary {
        MapSummary {
            id: self.id,
            frames: self.trajectory.poses(&self.map).len(),
            keyframes: self.map.num_keyframes(),
            points: self.map.num_map_points(),
            current: false,
        }
    }
}
