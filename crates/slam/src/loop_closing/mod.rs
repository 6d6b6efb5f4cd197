//! Loop closing (ORB-SLAM `LoopClosing`): after local mapping, each new keyframe is checked
//! for a loop with an earlier, unconnected part of the map; a loop found consistent over
//! several keyframes is verified geometrically by a Sim(3), corrected, and the whole map is
//! optimised (essential graph, then global bundle adjustment).
//!
//! Stages, one file each: [`detection`] (bag-of-words candidates and their consistency over
//! consecutive keyframes), [`keyframe_matching`] (bag-of-words and Sim(3)-guided matching
//! between two keyframes), [`verification`] (Sim(3) RANSAC, refinement, projection of the
//! loop's map points), [`correction`] (Sim(3) propagation to the current keyframe's
//! neighbourhood, fusion of duplicated points, new loop links) and [`essential_graph`]
//! (Sim(3) pose-graph optimisation over the spanning tree, loop edges and strong covisibility
//! edges).
//! [`merging`] joins a map of the atlas to another through the same verification and
//! correction. Through a rolling shutter, [`row_projection`] makes each keyframe observation's projection
//! from its row's pose.
//!
//! A keyframe of a multi-camera rig is one generalised camera: bag-of-words matching pairs
//! keypoints of any of its cameras, the Sim(3) is fitted between the keyframes' reference
//! (first-camera) frames with each keypoint compared in the camera that measured it, and the
//! guided searches project into every camera. A place seen by the front camera and, on the
//! return, by a side camera closes as any loop.

mod correction;
mod detection;
mod essential_graph;
mod keyframe_matching;
mod merging;
mod row_projection;
mod verification;

use ferroslam_map::{KeyFrameId, Map};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::context::Context;
use crate::error::SlamError;
use crate::local_ba_problem::adjust_keyframes;
use crate::place_recognition::PlaceRecognition;
pub(crate) use detection::{min_neighbour_score, LoopDetector};
pub use merging::MapMerge;
pub(crate) use merging::{join_maps, seam_keyframes, verify_merge, MergeMatch};
pub(crate) use verification::pose_of;

/// A loop the system closed.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopClosure {
    /// The keyframe that detected the loop.
    pub current: KeyFrameId,
    /// The earlier keyframe it was matched to.
    pub matched: KeyFrameId,
    /// Frame timestamps of the two keyframes, seconds.
    pub timestamps: (f64, f64),
    /// Map points of the loop matched in the current keyframe after verification.
    pub num_matches: usize,
    /// Scale of the Sim(3) correction (1 with depth sensors).
    pub scale: f64,
    /// Distance the current keyframe moved (correction and global BA), metres (map units).
    pub correction_m: f64,
    /// Cost of the essential graph before and after optimisation.
    pub graph_cost: (f64, f64),
}

/// Counters of what loop detection did, for diagnostics ("no false loops" reports).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoopStats {
    /// Keyframes checked for a loop.
    pub keyframes_checked: usize,
    /// Keyframes with at least one bag-of-words candidate.
    pub with_candidates: usize,
    /// Candidates consistent over enough keyframes to be verified geometrically.
    pub verified: usize,
    /// Verified candidates refused by the Sim(3) or the match count.
    pub rejected: usize,
}

/// Loop detection and correction state.
#[derive(Debug, Default)]
pub struct LoopCloser {
    detector: LoopDetector,
    last_loop: Option<KeyFrameId>,
    stats: LoopStats,
}

impl LoopCloser {
    /// Forgets the candidate groups of a discarded map; the counters stay (they describe
    /// the run).
    pub fn reset_map(&mut self) {
        self.detector.clear();
        self.last_loop = None;
    }

    /// What detection has done so far.
    pub fn stats(&self) -> LoopStats {
        self.stats
    }

    /// Checks keyframe `kf` (already indexed in `place`) for a loop and closes it: Sim(3)
    /// correction of its neighbourhood, fusion, essential-graph optimisation, then global
    /// bundle adjustment. Returns the loop closed, if any.
    pub fn process_keyframe(
        &mut self,
        kf: KeyFrameId,
        map: &mut Map,
        ctx: &Context,
        place: &PlaceRecognition,
    ) -> Result<Option<LoopClosure>, SlamError> {
        let config = &ctx.config.loop_closing;
        let between = config.min_keyframes_between;
        let too_soon = self
            .last_loop
            .is_some_and(|l| (kf.0 as usize) < l.0 as usize + between);
        if map.num_keyframes() <= between || too_soon {
            return Ok(None);
        }
        self.stats.keyframes_checked += 1;
        let candidates = self
            .detector
            .consistent_candidates(kf, map, place, config.consistency);
        if self.detector.had_candidates() {
            self.stats.with_candidates += 1;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(ctx.config.seed ^ u64::from(kf.0));
        for candidate in candidates {
            self.stats.verified += 1;
            let fv = place
                .feature_vector(kf)
                .zip(place.feature_vector(candidate));
            let Some(found) =
                fv.and_then(|fv| verification::verify_loop(kf, candidate, map, ctx, fv, &mut rng))
            else {
                self.stats.rejected += 1;
                continue;
            };
            let before = map.keyframe(kf).map(|k| k.camera_center());
            let graph = correction::correct_loop(kf, &found, map, ctx)?;
            // ORB-SLAM runs global BA in its own thread; here it runs inline, in order.
            let all: Vec<KeyFrameId> = map.keyframe_ids();
            adjust_keyframes(&all, map, ctx, None)?;
            let after = map.keyframe(kf).map(|k| k.camera_center());
            let loop_closure = LoopClosure {
                current: kf,
                matched: candidate,
                timestamps: (
                    map.keyframe(kf).map_or(f64::NAN, |k| k.timestamp()),
                    map.keyframe(candidate).map_or(f64::NAN, |k| k.timestamp()),
                ),
                num_matches: found.num_matches,
                scale: found.S_cw.scale,
                correction_m: match (before, after) {
                    (Some(b), Some(a)) => (a - b).norm(),
                    _ => f64::NAN,
                },
                graph_cost: graph,
            };
            self.last_loop = Some(kf);
            self.detector.clear();
            return Ok(Some(loop_closure));
        }
        Ok(None)
    }
}
