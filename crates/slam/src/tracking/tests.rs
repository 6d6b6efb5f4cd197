//! Unit tests of the tracking state machine.

use ferroslam_features::{Keypoint, ScalePyramid};
use ferroslam_geometry::camera::{test_cameras, CameraModel};
use ferroslam_geometry::rolling_shutter::ReadoutDirection;
use ferroslam_map::FrameFeatures;
use nalgebra::Vector3;

use super::*;
use crate::config::{Sensor, SlamConfig};
use crate::frame::{MonoInput, ObserverInput, RgbdInput};

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

/// The fr1 camera, read over `readout_s` seconds top first; without distortion when `ideal`.
fn rolling_shutter_camera(readout_s: f64, ideal: bool) -> CameraModel {
    let (_, mut camera) = test_cameras()
        .into_iter()
        .find(|(name, _)| *name == "tum_fr1")
        .unwrap();
    if ideal {
        camera.distortion = Default::default();
    }
    CameraModel::from(camera)
        .with_readout(readout_s, ReadoutDirection::TopToBottom)
        .unwrap()
}

#[test]
fn observations_carry_the_time_of_their_raw_row() {
    let camera = rolling_shutter_camera(0.03, false);
    let ctx = Context::new(camera, SlamConfig::for_sensor(Sensor::Rgbd));
    let keypoints: Vec<Keypoint> = [(10.0, 5.0), (600.0, 470.0), (320.0, 240.0)]
        .iter()
        .map(|&(x, y)| Keypoint {
            x,
            y,
            octave: 0,
            angle_deg: 0.0,
            response: 1.0,
        })
        .collect();
    let input = RgbdInput {
        timestamp: 1.0,
        keypoints: &keypoints,
        descriptors: &[[0u8; 32]; 3],
        depth_m: &[2.0; 3],
        colors: None,
    };
    let frame = Frame::from_rgbd(0, &input, &ctx).unwrap();
    for (i, kp) in keypoints.iter().enumerate() {
        let raw = Vector2::new(kp.x as f64, kp.y as f64);
        // The raw row's time, not the undistorted keypoint's (fr1 moves corners by pixels).
        assert_eq!(frame.features.time_offset_s(i), camera.time_offset_s(&raw));
        assert_ne!(frame.features.keypoints[i].y, kp.y);
    }
    assert!(frame.features.time_offset_s(0) < -0.014 && frame.features.time_offset_s(1) > 0.014);

    // A global shutter keeps no offsets at all.
    let global = Context::new(rolling_shutter_camera(0.0, false), ctx.config.clone());
    let frame = Frame::from_rgbd(0, &input, &global).unwrap();
    assert!(frame.features.time_offsets_s.is_empty());
    assert_eq!(frame.features.time_offset_s(1), 0.0);
}

/// A rig panning at 1.5 rad/s (fr1/rpy's peaks) past 300 points 2-4 m away per camera of
/// `ctx`, each seen at the row its camera reads it at (camera `k` of `readout_cameras`, the
/// rig's cameras with their shutters, sees from `T_ck_c0 * D(dt) * T_c0_w`); returns the map,
/// the frame (its matches set, its pose the true one perturbed) and the true `T_c0_w` and
/// velocity.
#[allow(non_snake_case)]
fn panning_frame(
    ctx: &Context,
    readout_cameras: &[CameraModel],
) -> (Map, Frame, Isometry3<f64>, Vector6<f64>) {
    use ferroslam_geometry::rolling_shutter::motion_over;
    let T_c_w = Isometry3::new(
        Vector3::new(0.05, -0.02, 0.1),
        Vector3::new(0.02, 0.1, -0.03),
    );
    let xi_dot = Vector6::new(0.1, 0.0, -0.05, 0.2, 1.5, -0.3);
    let mut rng_state = 12345u64;
    let mut uniform = || {
        // A fixed LCG: the scene is the same every run.
        rng_state = rng_state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (rng_state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut keypoints, mut points_w) = (vec![Vec::new(); readout_cameras.len()], Vec::new());
    for (k, camera) in readout_cameras.iter().enumerate() {
        let T_ck_c0 = ctx
            .view(k)
            .T_c_c0
            .copied()
            .unwrap_or_else(Isometry3::identity);
        while keypoints[k].len() < 300 {
            let uv0 = Vector2::new(30.0 + 580.0 * uniform(), 30.0 + 420.0 * uniform());
            let z = 2.0 + 2.0 * uniform();
            let ray = camera.unproject(&uv0).unwrap();
            let p_w = (T_ck_c0 * T_c_w).inverse() * Point3::from(ray * (z / ray.z));
            // The row a point is read at depends on where the moving camera sees it: iterate.
            let mut uv = uv0;
            for _ in 0..10 {
                let dt = camera.time_offset_s(&uv);
                let p_c = T_ck_c0 * (motion_over(&xi_dot, dt) * T_c_w * p_w);
                let Some(next) = camera.project(&p_c.coords) else {
                    break;
                };
                uv = next;
            }
            if !(0.0..640.0).contains(&uv.x) || !(0.0..480.0).contains(&uv.y) {
                continue;
            }
            keypoints[k].push(Keypoint {
                x: uv.x as f32,
                y: uv.y as f32,
                octave: 0,
                angle_deg: 0.0,
                response: 1.0,
            });
            points_w.push(p_w.coords);
        }
    }
    let descriptors = vec![[0u8; 32]; 300];
    let input = MonoInput {
        timestamp: 1.0,
        keypoints: &keypoints[0],
        descriptors: &descriptors,
        colors: None,
    };
    let observers: Vec<ObserverInput<'_>> = keypoints[1..]
        .iter()
        .map(|kps| ObserverInput {
            keypoints: kps,
            descriptors: &descriptors,
            colors: &[],
            depth_m: None,
        })
        .collect();
    let mut frame = Frame::from_mono(0, &input, ctx).unwrap();
    if !observers.is_empty() {
        frame = frame.with_observers(&observers, ctx).unwrap();
    }
    let mut map = Map::new(ScalePyramid::new(1.2, 8).unwrap());
    let kf = map.insert_keyframe(0.0, 0, Isometry3::identity(), frame.features.clone());
    for (i, p_w) in points_w.iter().enumerate() {
        let m = map.create_map_point(*p_w, kf).unwrap();
        map.add_observation(m, kf, i).unwrap();
        frame.map_points[i] = Some(m);
    }
    frame.T_c_w = Isometry3::new(
        Vector3::new(0.01, 0.01, -0.01),
        Vector3::new(0.005, -0.01, 0.0),
    ) * T_c_w;
    (map, frame, T_c_w, xi_dot)
}

/// Pose error (metres, radians), inliers and velocity of `frame` refined under `ctx` from
/// the motion model's `prior`, against the true `T_c_w`.
#[allow(non_snake_case)]
fn refined(
    ctx: &Context,
    map: &Map,
    frame: &Frame,
    T_c_w: &Isometry3<f64>,
    prior: &Vector6<f64>,
) -> (f64, f64, usize, Vector6<f64>) {
    let mut f = frame.clone();
    let inliers = optimize_frame_pose(&mut f, map, ctx, prior).unwrap();
    let d = f.T_c_w * T_c_w.inverse();
    (
        d.translation.vector.norm(),
        d.rotation.angle(),
        inliers,
        f.features.xi_dot,
    )
}

/// The motion model a frame interval behind: its rates off by 0.3 rad/s.
fn motion_model(xi_dot: &Vector6<f64>) -> Vector6<f64> {
    xi_dot + Vector6::new(0.0, 0.0, 0.0, -0.3, 0.2, 0.1)
}

#[test]
#[allow(non_snake_case)]
fn rolling_shutter_tracking_recovers_the_pose_a_global_shutter_model_misses() {
    let readout_camera = rolling_shutter_camera(0.03, true);
    let rs = Context::new(readout_camera, SlamConfig::for_sensor(Sensor::Monocular));
    let gs = Context::new(rolling_shutter_camera(0.0, true), rs.config.clone());
    let (map, frame, T_c_w, xi_dot) = panning_frame(&rs, &[readout_camera]);
    assert_eq!(frame.features.time_offsets_s.len(), frame.len());
    // Noise-free rows: the rolling-shutter model is exact up to its prior's pull, the
    // global-shutter one carries the skew of 45 mrad over the image.
    rolling_shutter_model_beats_the_global_one(&rs, &gs, &map, &frame, &T_c_w, &xi_dot);
}

/// Refines `frame` under the rolling-shutter context `rs` and the global-shutter one `gs`
/// from the motion model's prior: `rs` recovers the true `T_c_w` and angular rate (noise-free
/// rows), `gs` misses the pose by ten times more and estimates no velocity.
#[allow(non_snake_case)]
fn rolling_shutter_model_beats_the_global_one(
    rs: &Context,
    gs: &Context,
    map: &Map,
    frame: &Frame,
    T_c_w: &Isometry3<f64>,
    xi_dot: &Vector6<f64>,
) {
    let prior = motion_model(xi_dot);
    let (gs_t, gs_r, gs_inliers, gs_xi) = refined(gs, map, frame, T_c_w, &prior);
    let (rs_t, rs_r, rs_inliers, rs_xi) = refined(rs, map, frame, T_c_w, &prior);
    println!("global shutter model: {gs_t:.2e} m {gs_r:.2e} rad, {gs_inliers} inliers");
    println!("rolling shutter model: {rs_t:.2e} m {rs_r:.2e} rad, {rs_inliers} inliers");
    assert!(rs_t < 1e-3 && rs_r < 1e-3, "{rs_t} m, {rs_r} rad");
    assert!(
        gs_t > 10.0 * rs_t && gs_r > 10.0 * rs_r,
        "{gs_t} vs {rs_t}, {gs_r} vs {rs_r}"
    );
    assert_eq!(rs_inliers, frame.len());
    assert!(
        (rs_xi - xi_dot).fixed_rows::<3>(3).norm() < 0.1,
        "{rs_xi} vs {xi_dot}"
    );
    assert_eq!(gs_xi, Vector6::zeros());
}

/// The rig of [`rolling_shutter_rig_tracking_takes_each_camera_s_rows_at_their_times`]: the
/// fr1 camera in front (read over `readout_s`) and a second one yawed 90 degrees, 8 cm to
/// its side, read over `side_readout_s`.
#[allow(non_snake_case)]
fn side_camera_rig(readout_s: f64, side_readout_s: f64) -> (Context, Vec<CameraModel>) {
    let cameras = vec![
        rolling_shutter_camera(readout_s, true),
        rolling_shutter_camera(side_readout_s, true),
    ];
    let mut ctx = Context::new(
        cameras[0].clone(),
        SlamConfig::for_sensor(Sensor::Monocular),
    );
    let T_c0_c = Isometry3::new(
        Vector3::new(0.08, 0.0, -0.02),
        Vector3::new(0.0, std::f64::consts::FRAC_PI_2, 0.0),
    );
    ctx.add_observer(cameras[1].clone(), T_c0_c, false);
    (ctx, cameras)
}

#[test]
#[allow(non_snake_case)]
fn rolling_shutter_rig_tracking_takes_each_camera_s_rows_at_their_times() {
    // Both cameras read over 30 ms: each keypoint carries its own camera's row time, and the
    // rig's pose and velocity come back where the global model misses them.
    let (rs, cameras) = side_camera_rig(0.03, 0.03);
    let (map, frame, T_c_w, xi_dot) = panning_frame(&rs, &cameras);
    for i in [0, 299, 300, 599] {
        let kp = frame.features.keypoints[i];
        let camera = &cameras[frame.features.camera_of(i)];
        // Ideal cameras: the core pixel is the raw one.
        let expected = camera.time_offset_s(&Vector2::new(kp.x as f64, kp.y as f64));
        assert!((frame.features.time_offset_s(i) - expected).abs() < 1e-9);
    }
    let (gs, _) = side_camera_rig(0.0, 0.0);
    rolling_shutter_model_beats_the_global_one(&rs, &gs, &map, &frame, &T_c_w, &xi_dot);

    // A global-shutter side camera beside a rolling-shutter first one: its rows all at the
    // frame's time (offset 0), and the rig still estimated with its velocity.
    let (mixed, cameras) = side_camera_rig(0.03, 0.0);
    let (map, frame, T_c_w, xi_dot) = panning_frame(&mixed, &cameras);
    assert_eq!(frame.features.time_offsets_s.len(), 600);
    assert!(frame.features.time_offsets_s[300..]
        .iter()
        .all(|&t| t == 0.0));
    let (t, r, _, _) = refined(&mixed, &map, &frame, &T_c_w, &motion_model(&xi_dot));
    assert!(t < 1e-3 && r < 1e-3, "{t} m, {r} rad");
}
