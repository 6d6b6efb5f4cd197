//! Unit tests of the tracking state machine.

use ferroslam_features::{Keypoint, ScalePyramid};
use ferroslam_geometry::camera::test_cameras;
use ferroslam_map::FrameFeatures;
use nalgebra::Vector3;

use super::*;
use crate::config::{Sensor, SlamConfig};
use crate::frame::RgbdInput;

const N: usize = 800;
const FRAME: usize = 40;
/// The last keyframe 5 frames ago; 35 is past `skip_max_frames` (30).
const RECENT: usize = FRAME - 5;
const STALE: usize = FRAME - 35;

/// A frame of `N` far keypoints (no close structure to track) and a map whose keyframe
/// `r` sees `N` points, each also seen by a second keyframe with depth, so all `N` count
/// as the reference's tracked points.
fn scene() -> (Context, Map, Frame, KeyFrameId) {
    scene_with(Sensor::Rgbd, N)
}

/// As [`scene`] for `sensor`, with only the first `mapped` keypoints seen by `r`.
fn scene_with(sensor: Sensor, mapped: usize) -> (Context, Map, Frame, KeyFrameId) {
    let (_, camera) = test_cameras()
        .into_iter()
        .find(|(name, _)| *name == "tum_fr1")
        .unwrap();
    let config = SlamConfig::for_sensor(sensor);
    let ctx = Context::new(camera, config);
    let keypoints: Vec<Keypoint> = (0..N)
        .map(|i| Keypoint {
            x: 20.0 + (i % 40) as f32 * 15.0,
            y: 20.0 + (i / 40) as f32 * 20.0,
            octave: 0,
            angle_deg: 0.0,
            response: 1.0,
        })
        .collect();
    let descriptors = vec![[0u8; 32]; N];
    let (depth, u_right) = (vec![20.0f32; N], vec![100.0f32; N]);
    let features = || {
        FrameFeatures::new(
            keypoints.clone(),
            descriptors.clone(),
            depth.clone(),
            u_right.clone(),
            ctx.bounds,
        )
        .unwrap()
    };
    let mut map = Map::new(ScalePyramid::new(1.2, 8).unwrap());
    let r = map.insert_keyframe(0.0, 0, Isometry3::identity(), features());
    let other = map.insert_keyframe(0.1, 1, Isometry3::identity(), features());
    for i in 0..mapped {
        let m = map
            .create_map_point(Vector3::new(0.0, 0.0, 20.0), r)
            .unwrap();
        map.add_observation(m, r, i).unwrap();
        map.add_observation(m, other, i).unwrap();
    }
    let input = RgbdInput {
        timestamp: 1.0,
        keypoints: &keypoints,
        descriptors: &descriptors,
        depth_m: &depth,
        colors: None,
    };
    let frame = Frame::from_rgbd(FRAME, &input, &ctx).unwrap();
    (ctx, map, frame, r)
}

fn tracker(reference: KeyFrameId, inliers: usize, last_keyframe_frame: usize) -> Tracker {
    Tracker {
        state: TrackingState::Ok,
        reference_kf: Some(reference),
        matches_inliers: inliers,
        last_keyframe_frame,
        ..Tracker::default()
    }
}

#[test]
fn busy_mapping_defers_the_reference_ratio_keyframe() {
    let (ctx, map, frame, r) = scene();
    assert_eq!(map.tracked_points(r, 3), N);
    // 500 of 800 (< 0.75): ORB-SLAM's ratio asks for a keyframe, if mapping can take it.
    let ratio_only = tracker(r, 500, RECENT);
    assert!(ratio_only.need_new_keyframe(&frame, &map, &ctx, true));
    assert!(!ratio_only.need_new_keyframe(&frame, &map, &ctx, false));
}

#[test]
fn weak_or_stale_tracking_asks_even_while_mapping_is_busy() {
    let (ctx, map, frame, r) = scene();
    // Under a quarter of the reference's points (ORB-SLAM c1c, with depth).
    assert!(tracker(r, 150, RECENT).need_new_keyframe(&frame, &map, &ctx, false));
    // SkipMaxFrames (30) frames since the last keyframe (MATLAB's rule, ORB-SLAM c1a).
    assert!(tracker(r, 500, STALE).need_new_keyframe(&frame, &map, &ctx, false));
    // Strong tracking is never a keyframe, idle or not.
    let strong = tracker(r, 700, RECENT);
    assert!(!strong.need_new_keyframe(&frame, &map, &ctx, true));
    assert!(!strong.need_new_keyframe(&frame, &map, &ctx, false));
}

#[test]
fn monocular_upper_limit_needs_the_reference_ratio() {
    // 95 tracked points, under the upper limit (100 monocular, 250 RGB-D), against a
    // reference seeing 100.
    for sensor in [Sensor::Monocular, Sensor::Rgbd] {
        let (ctx, map, frame, r) = scene_with(sensor, 100);
        assert!(95 < ctx.config.tracking.track_feature_range.1);
        let near_reference = tracker(r, 95, RECENT);
        let expected = sensor.has_depth(); // MATLAB's bare limit, with depth only
        assert_eq!(
            near_reference.need_new_keyframe(&frame, &map, &ctx, false),
            expected
        );
        // 85 < 0.9 * 100: monocular asks too, while mapping is busy.
        assert!(tracker(r, 85, RECENT).need_new_keyframe(&frame, &map, &ctx, false));
    }
}

#[test]
fn monocular_keyframes_wait_at_most_one_frame_for_busy_mapping() {
    let (mono, _, _, r) = scene_with(Sensor::Monocular, N);
    let lower = mono.config.tracking.track_feature_range.0;
    let mut t = tracker(r, 2 * lower, RECENT);
    assert!(t.defer_keyframe(10, &mono));
    assert!(!t.defer_keyframe(11, &mono), "deferred on the frame before");
    assert!(t.defer_keyframe(13, &mono));
    let mut weak = tracker(r, 2 * lower - 1, RECENT);
    assert!(!weak.defer_keyframe(10, &mono));
    let (rgbd, _, _, r) = scene();
    assert!(!tracker(r, N, RECENT).defer_keyframe(10, &rgbd));
}
