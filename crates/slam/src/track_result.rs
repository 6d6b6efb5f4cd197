//! [`TrackResult`]: what tracking one frame gives back.

use nalgebra::Isometry3;

use crate::local_mapping::MappingReport;
use crate::loop_closing::{LoopClosure, MapMerge};
use crate::mono_init::InitStatus;
use crate::tracking::TrackingState;

/// Outcome of tracking one frame.
#[derive(Clone, Debug)]
pub struct TrackResult {
    /// Tracking state after this frame.
    pub state: TrackingState,
    /// Camera pose in the world when tracked.
    pub T_w_c: Option<Isometry3<f64>>,
    /// The map `T_w_c` is in (its world); a merge during the call may have joined it to an
    /// older map since (see [`Self::merge`]).
    pub map_id: usize,
    /// The merge this frame's keyframes made, if any.
    pub merge: Option<MapMerge>,
    /// Whether this frame became a keyframe.
    pub is_keyframe: bool,
    /// Map points matched as inliers in this frame.
    pub num_tracked: usize,
    /// Wall time of tracking, milliseconds (after the front end).
    pub tracking_ms: f64,
    /// Wall time of the front end ([`crate::SlamSystem::track`]: extraction, masks, sampling),
    /// milliseconds; 0 when the caller gave the features.
    pub extraction_ms: f64,
    /// Wall time of local mapping triggered by this frame, milliseconds.
    pub mapping_ms: f64,
    /// Of `tracking_ms`, the time spent in motion-only BA, milliseconds.
    pub pose_optimisation_ms: f64,
    /// Of `mapping_ms`, loop detection, verification and correction (inline mapping only;
    /// the mapping thread's is its own), milliseconds.
    pub loop_closing_ms: f64,
    /// What local mapping did, when a keyframe was inserted.
    pub mapping: Option<MappingReport>,
    /// Monocular only: why this frame did not start the map (`None` once initialised).
    pub init_status: Option<InitStatus>,
    /// The loop this frame's keyframe closed, if any.
    pub loop_closure: Option<LoopClosure>,
    /// Every camera's raw keypoints, as the front end extracted them
    /// ([`crate::SlamSystem::track`]; empty when the caller gave the features).
    pub keypoints: Vec<Vec<ferroslam_features::Keypoint>>,
}
