//! Map merging (ORB-SLAM3 `LoopClosing::MergeLocal`) with loop closing's own stages: a place
//! the current map shares with an older one of the atlas is verified as a loop is (both maps
//! seen as one, each keyframe posed in its own map's world), the current map is moved into the
//! older map's world by the verified similarity and joined to it at the matched keyframes, and
//! the seam is then corrected as a loop (duplicated points fused, new links, the essential
//! graph). The mapping pipeline then welds it, a local bundle adjustment of the two
//! keyframes' neighbourhoods ([`seam_keyframes`]) with the rest of the map fixed, and
//! bundle-adjusts the whole map; in the mapping thread, tracking goes on meanwhile.
//!
//! ORB-SLAM3 welds before its essential graph; here the essential graph is loop closing's
//! own stage, run as a loop's, and the weld after it refines the seam where the graph left
//! it, ahead of global BA.

use ferroslam_geometry::sim3::Sim3;
use ferroslam_map::{KeyFrameId, Map};
use ferroslam_vocabulary::FeatureVector;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::correction::correct_loop;
use super::verification::{verify_window, LoopMatch};
use crate::context::Context;
use crate::error::SlamError;
use crate::place_recognition::PlaceRecognition;

/// Two maps the system merged.
#[derive(Clone, Debug, PartialEq)]
pub struct MapMerge {
    /// The map that was merged away (the current one when the place was recognised).
    pub merged_map: usize,
    /// The older map it joined, whose id and world frame the merged map keeps.
    pub into_map: usize,
    /// The current map's keyframe that recognised the place.
    pub current: KeyFrameId,
    /// The older map's keyframe it was matched to.
    pub matched: KeyFrameId,
    /// Frame timestamps of the two keyframes, seconds.
    pub timestamps: (f64, f64),
    /// Map points of the older map matched in the current keyframe after verification.
    pub num_matches: usize,
    /// Scale of the similarity from the merged map's world to the older one's (1 with depth
    /// sensors).
    pub scale: f64,
    /// Cost of the essential graph before and after optimisation.
    pub graph_cost: (f64, f64),
    /// Keyframes of the seam's local BA (the two matched keyframes' neighbourhoods).
    pub welded_keyframes: usize,
    /// The similarity that moved the merged map into the older one's world before the seam
    /// was corrected: `p_into = S p_merged` (metres of the older map).
    pub similarity: Sim3,
}

/// A place keyframe `kf` of `current` shares with keyframe `candidate` of `older`, verified.
pub(crate) struct MergeMatch {
    found: LoopMatch,
    /// From the current map's world to the older map's: `p_older = S p_current`.
    pub S_older_current: Sim3,
}

impl MergeMatch {
    /// Map points of the older map matched in the current keyframe.
    pub(crate) fn num_matches(&self) -> usize {
        self.found.num_matches
    }

    /// The older map's keyframe of the window the current one was matched to.
    pub(crate) fn matched(&self) -> KeyFrameId {
        self.found.loop_kf
    }
}

/// Verifies `candidate` (of `older`) as the place `kf` (of `current`) shows, over the
/// candidate's window of covisible keyframes (`loop_closing.merge_window`, see
/// [`verify_window`]); `fv` is `kf`'s bag-of-words feature vector and `place` the older map's
/// index. The maps' ids must be disjoint. `None` when any stage falls short or the
/// similarity's scale is implausible: the maps are not touched.
pub(crate) fn verify_merge(
    (current, kf, fv): (&Map, KeyFrameId, &FeatureVector),
    (older, candidate, place): (&Map, KeyFrameId, &PlaceRecognition),
    ctx: &Context,
) -> Result<Option<MergeMatch>, SlamError> {
    let config = &ctx.config.loop_closing;
    let window: Vec<(KeyFrameId, &FeatureVector)> = std::iter::once(candidate)
        .chain(older.best_covisibles(candidate, config.merge_window))
        .filter_map(|k| place.feature_vector(k).map(|f| (k, f)))
        .collect();
    let mut both = older.clone();
    both.absorb(current.clone(), (kf, candidate))?;
    let mut rng = ChaCha8Rng::seed_from_u64(ctx.config.seed ^ u64::from(kf.0) ^ 0x6d65_7267);
    let Some(found) = verify_window((kf, fv), &window, &both, ctx, &mut rng) else {
        return Ok(None);
    };
    let T_cw = *current.keyframe(kf).expect("verified keyframe").T_c_w();
    let S_older_current = found.S_cw.inverse() * Sim3::from_isometry(&T_cw);
    // A map whose scale drifted by orders of magnitude (one diverged to a median point depth
    // of 1e5) can still line up a few dozen points: its merge would rescale the older map.
    let scale = S_older_current.scale;
    if !(1.0 / config.max_merge_scale..=config.max_merge_scale).contains(&scale) {
        return Ok(None);
    }
    Ok(Some(MergeMatch {
        found,
        S_older_current,
    }))
}

/// Joins `current` (already moved into the older map's world, see [`MergeMatch`]) to
/// `older` at the verified keyframes and corrects the seam as a loop; returns the merged
/// map (the older one's origin and world) and the essential graph's costs.
pub(crate) fn join_maps(
    mut older: Map,
    current: Map,
    (kf, candidate): (KeyFrameId, KeyFrameId),
    merge: &MergeMatch,
    ctx: &Context,
) -> Result<(Map, (f64, f64)), SlamError> {
    older.absorb(current, (kf, candidate))?;
    // The similarity is applied: the loop correction at the seam starts from identity.
    let found = LoopMatch {
        S_cw: Sim3::from_isometry(older.keyframe(kf).expect("absorbed keyframe").T_c_w()),
        ..merge.found.clone()
    };
    let graph = correct_loop(kf, &found, &mut older, ctx)?;
    Ok((older, graph))
}

/// The keyframes of the seam's local BA between `kf` and `candidate` of the merged `map`:
/// the two and their covisible keyframes (after fusion, each side's include the other's),
/// in id order.
pub(crate) fn seam_keyframes(
    (kf, candidate): (KeyFrameId, KeyFrameId),
    map: &Map,
) -> Vec<KeyFrameId> {
    let mut seam: Vec<KeyFrameId> = [kf, candidate]
        .into_iter()
        .flat_map(|k| std::iter::once(k).chain(map.covisibles(k).into_iter().map(|(n, _)| n)))
        .collect();
    seam.sort_unstable();
    seam.dedup();
    seam
}
