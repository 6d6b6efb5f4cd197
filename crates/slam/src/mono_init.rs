//! Monocular map initialisation (ORB-SLAM `MonocularInitialization`): a reference frame is
//! matched against each later frame until a pair gives a trustworthy two-view reconstruction;
//! the map then starts with both frames as keyframes and the triangulated points, bundle
//! adjusted and scaled so the median scene depth of the first keyframe is 1.

use ferroslam_features::matcher::TH_LOW;
use ferroslam_features::{search_by_projection, MatchOptions, ProjectionQuery};
use ferroslam_geometry::camera::{CameraModel, KannalaBrandtCamera, PinholeCamera, RadTan};
use ferroslam_geometry::two_view::{reconstruct_two_view, TwoViewOptions, TwoViewReconstruction};
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use nalgebra::{Isometry3, Vector2};

use crate::config::InitializationConfig;
use crate::context::Context;
use crate::error::SlamError;
use crate::frame::Frame;
use crate::local_ba_problem::adjust_around;

/// Why the last frame did not start the map; for status reports.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum InitStatus {
    /// No reference frame yet (or it was just replaced by this frame): one needs more than
    /// `min_keypoints` keypoints (`initialization.mono_min_keypoints`).
    #[error("waiting for a reference frame with more than {min_keypoints} keypoints")]
    WaitingForReference {
        /// Keypoints a reference frame needs (more than these).
        min_keypoints: usize,
    },
    /// Too few matches with the reference: this frame became the new reference.
    #[error("{found} matches with the reference frame (need {needed}): new reference")]
    TooFewMatches {
        /// Matches found.
        found: usize,
        /// Matches needed (`initialization.mono_min_matches`).
        needed: usize,
    },
    /// The two-view reconstruction refused the pair (degenerate motion): the reason.
    #[error("two-view reconstruction refused: {0}")]
    Refused(String),
    /// A reconstruction was found but the map failed its checks after bundle adjustment.
    #[error("initial map rejected: {0}")]
    RejectedAfterBa(String),
}

/// The matching state between the reference frame and later frames.
#[derive(Debug, Default)]
pub struct MonoInitializer {
    reference: Option<Frame>,
    /// Where each reference keypoint was last matched; the search window follows it.
    prev_matched: Vec<Vector2<f64>>,
}

/// A pair that passed the two-view checks: the reference frame, the matches and the
/// reconstruction (points in the reference camera, unit baseline).
pub struct TwoViewPair {
    /// The first view (becomes the map's origin keyframe).
    pub reference: Frame,
    /// `(reference keypoint, current keypoint)` per match.
    pub matches: Vec<(usize, usize)>,
    /// Pose and points from [`reconstruct_two_view`].
    pub reconstruction: TwoViewReconstruction,
}

impl MonoInitializer {
    /// Forgets the reference frame.
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// Offers `frame` (undistorted features) as the second view; `Ok` with the pair when it
    /// initialises, `Err` with the reason otherwise.
    pub fn add_frame(&mut self, frame: &Frame, ctx: &Context) -> Result<TwoViewPair, InitStatus> {
        let init = &ctx.config.initialization;
        let min_keypoints = init.mono_min_keypoints;
        let Some(reference) = self
            .reference
            .as_ref()
            .filter(|_| frame.len() > min_keypoints)
        else {
            self.set_reference(frame, min_keypoints);
            return Err(InitStatus::WaitingForReference { min_keypoints });
        };
        let matches = self.search(reference, frame, init);
        if matches.len() < init.mono_min_matches {
            let found = matches.len();
            self.set_reference(frame, min_keypoints);
            return Err(InitStatus::TooFewMatches {
                found,
                needed: init.mono_min_matches,
            });
        }
        for &(i, j) in &matches {
            let kp = &frame.features.keypoints[j];
            self.prev_matched[i] = Vector2::new(kp.x as f64, kp.y as f64);
        }
        let options = TwoViewOptions {
            seed: ctx.config.seed ^ frame.index as u64,
            ..TwoViewOptions::default()
        };
        let (pinhole, pixels, matches) = match &ctx.camera {
            CameraModel::Pinhole(c) => {
                let pixels = |f: &Frame| -> Vec<Vector2<f64>> {
                    f.features
                        .keypoints
                        .iter()
                        .map(|k| Vector2::new(k.x as f64, k.y as f64))
                        .collect()
                };
                (*c, [pixels(reference), pixels(frame)], matches)
            }
            CameraModel::KannalaBrandt(c) => {
                virtual_pinhole_pairs(c, reference, frame, matches, ctx)
            }
        };
        match reconstruct_two_view(&pixels[0], &pixels[1], &matches, &pinhole, &options) {
            Ok(reconstruction) => Ok(TwoViewPair {
                reference: self.reference.take().expect("checked above"),
                matches,
                reconstruction,
            }),
            Err(refusal) => Err(InitStatus::Refused(refusal.to_string())),
        }
    }

    /// Makes `frame` the reference if it has more than `min_keypoints` keypoints, else
    /// forgets the reference.
    fn set_reference(&mut self, frame: &Frame, min_keypoints: usize) {
        if frame.len() > min_keypoints {
            self.prev_matched = frame
                .features
                .keypoints
                .iter()
                .map(|k| Vector2::new(k.x as f64, k.y as f64))
                .collect();
            self.reference = Some(frame.clone());
        } else {
            self.reset();
        }
    }

    /// ORB-SLAM `SearchForInitialization`: reference keypoints searched in a window of
    /// half-side `init.mono_window_px` around their last match among the current keypoints of
    /// the same octave (ratio `init.mono_nn_ratio`, rotation consistency, one-to-one). ORB-SLAM searches the finest
    /// level only; under KITTI's forward motion that found too few matches to start.
    fn search(
        &self,
        reference: &Frame,
        frame: &Frame,
        init: &InitializationConfig,
    ) -> Vec<(usize, usize)> {
        let mut ids = Vec::new();
        let mut queries = Vec::new();
        for (i, kp) in reference.features.keypoints.iter().enumerate() {
            queries.push(ProjectionQuery {
                u: self.prev_matched[i].x,
                v: self.prev_matched[i].y,
                radius: init.mono_window_px,
                min_level: kp.octave,
                max_level: kp.octave,
                descriptor: reference.features.descriptors[i],
                angle_deg: Some(kp.angle_deg),
            });
            ids.push(i);
        }
        let opts = MatchOptions {
            max_distance: TH_LOW,
            nn_ratio: Some(init.mono_nn_ratio),
            check_orientation: true,
        };
        let f = &frame.features;
        search_by_projection(
            &queries,
            &f.keypoints,
            &f.descriptors,
            f.grid(0),
            &[],
            &opts,
        )
        .into_iter()
        .enumerate()
        .filter_map(|(q, hit)| hit.map(|(j, _)| (ids[q], j)))
        .collect()
    }
}

/// The map [`create_initial_map`] made.
pub struct InitialMap {
    /// The reference keyframe (the world frame).
    pub kf1: KeyFrameId,
    /// The current frame's keyframe.
    pub kf2: KeyFrameId,
    /// The points created, oldest first.
    pub points: Vec<MapPointId>,
}

/// Largest angle (degrees) off a fisheye's axis of the rays the two-view reconstruction
/// uses: their `(x/z, y/z)` is a pinhole point, whose plane grows without bound towards 90.
const TWO_VIEW_MAX_RAY_DEG: f64 = 70.0;

/// The virtual pinhole, both frames' pixels and the matches of [`virtual_pinhole_pairs`].
type VirtualPinholePairs = (PinholeCamera, [Vec<Vector2<f64>>; 2], Vec<(usize, usize)>);

/// A fisheye pair as a distortion-free pinhole with the same `fx, fy, cx, cy` would see it:
/// the camera, both frames' pixels (NaN for rays beyond [`TWO_VIEW_MAX_RAY_DEG`]) and the
/// matches whose rays are both within that angle.
fn virtual_pinhole_pairs(
    lens: &KannalaBrandtCamera,
    reference: &Frame,
    frame: &Frame,
    matches: Vec<(usize, usize)>,
    ctx: &Context,
) -> VirtualPinholePairs {
    let min_z = TWO_VIEW_MAX_RAY_DEG.to_radians().cos();
    let pixels = |f: &Frame| -> Vec<Vector2<f64>> {
        f.features
            .keypoints
            .iter()
            .map(|k| {
                let r = ctx.ray(k.x, k.y);
                if r.z > min_z {
                    Vector2::new(lens.fx * r.x / r.z + lens.cx, lens.fy * r.y / r.z + lens.cy)
                } else {
                    Vector2::repeat(f64::NAN)
                }
            })
            .collect()
    };
    let pixels = [pixels(reference), pixels(frame)];
    let matches = matches
        .into_iter()
        .filter(|&(i, j)| pixels[0][i].x.is_finite() && pixels[1][j].x.is_finite())
        .collect();
    let pinhole = PinholeCamera::new(
        lens.fx,
        lens.fy,
        lens.cx,
        lens.cy,
        RadTan::default(),
        lens.width,
        lens.height,
    )
    .expect("a valid fisheye's intrinsics make a valid pinhole");
    (pinhole, pixels, matches)
}

/// Builds the initial map from a pair (ORB-SLAM `CreateInitialMapMonocular`): two keyframes,
/// one point per triangulated match, bundle adjustment with the first keyframe fixed, then
/// the scale that puts the first keyframe's median scene depth at 1.
///
/// On success `current` carries its pose and point associations, and the keyframe ids and
/// the points created (for the mapping pipeline's recent points) are returned; on failure
/// the map is cleared and the reason returned.
pub fn create_initial_map(
    pair: TwoViewPair,
    current: &mut Frame,
    map: &mut Map,
    ctx: &Context,
) -> Result<Result<InitialMap, InitStatus>, SlamError> {
    let TwoViewPair {
        mut reference,
        matches,
        reconstruction,
    } = pair;
    reference.T_c_w = Isometry3::identity();
    current.T_c_w = reconstruction.T_c2_c1;
    let kf1 = map.insert_keyframe(
        reference.timestamp,
        reference.index,
        reference.T_c_w,
        reference.features.clone(),
    );
    let kf2 = map.insert_keyframe(
        current.timestamp,
        current.index,
        current.T_c_w,
        current.features.clone(),
    );
    current.clear_associations();
    let mut points = Vec::new();
    for (&(i, j), p) in matches.iter().zip(&reconstruction.points_c1) {
        let Some(p) = p else { continue };
        let m = map.create_map_point(*p, kf1)?;
        map.add_observation(m, kf1, i)?;
        map.add_observation(m, kf2, j)?;
        map.compute_distinctive_descriptor(m)?;
        map.update_normal_and_depth(m)?;
        points.push(m);
        current.map_points[j] = Some(m);
    }
    map.update_connections(kf1)?;
    map.update_connections(kf2)?;
    adjust_around(kf2, map, ctx, None)?;

    let median_depth = map.scene_median_depth(kf1);
    let tracked = map.tracked_points(kf2, 1);
    let needed = ctx.config.initialization.mono_min_points;
    let (Some(depth), true) = (median_depth, tracked >= needed) else {
        map.clear();
        return Ok(Err(InitStatus::RejectedAfterBa(format!(
            "{tracked} points left after bundle adjustment (need {needed})"
        ))));
    };
    let inv = 1.0 / depth;
    let mut T_c2_w = *map.keyframe(kf2).expect("just inserted").T_c_w();
    T_c2_w.translation.vector *= inv;
    map.set_keyframe_pose(kf2, T_c2_w)?;
    for m in map.map_point_ids() {
        let p = map.map_point(m).expect("live id").position();
        map.set_map_point_position(m, p * inv)?;
    }
    for m in map.map_point_ids() {
        map.update_normal_and_depth(m)?;
    }
    current.T_c_w = T_c2_w;
    for slot in current.map_points.iter_mut() {
        if slot.is_some_and(|m| map.map_point(m).is_none()) {
            *slot = None;
        }
    }
    Ok(Ok(InitialMap { kf1, kf2, points }))
}
