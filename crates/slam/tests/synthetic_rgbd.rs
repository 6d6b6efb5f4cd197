//! The whole RGB-D pipeline on a synthetic scene with exact ground truth: landmarks with
//! unique descriptors seen through the (distorted) TUM fr1 camera along a known path.
#![allow(non_snake_case)]

mod common;

use ferroslam_features::{Descriptor, Keypoint};
use ferroslam_geometry::camera::{test_cameras, ImageBounds, PinholeCamera};
use ferroslam_geometry::se3;
use ferroslam_slam::{RgbdInput, SlamConfig, SlamError, SlamSystem, TrackingState};
use nalgebra::{Isometry3, Point3, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Scene {
    camera: PinholeCamera,
    bounds: ImageBounds,
    landmarks: Vec<(Vector3<f64>, Descriptor)>,
}

impl Scene {
    fn new(seed: u64, n: usize) -> Self {
        let (_, camera) = test_cameras()
            .into_iter()
            .find(|(name, _)| *name == "tum_fr1")
            .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let landmarks = (0..n)
            .map(|_| {
                let p = Vector3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(1.5..5.0),
                );
                let mut d = [0u8; 32];
                rng.fill(&mut d);
                (p, d)
            })
            .collect();
        Self {
            bounds: camera.undistorted_bounds(),
            camera,
            landmarks,
        }
    }

    /// Camera pose of frame `i`: a slow pan with a sideways drift (T_w_c).
    fn T_w_c(i: usize) -> Isometry3<f64> {
        let s = i as f64;
        se3::exp(&Vector6::new(
            0.01 * s,
            0.002 * s,
            0.004 * s,
            0.003 * s,
            0.008 * s,
            0.002 * s,
        ))
    }

    /// Raw (distorted) keypoints, descriptors and depths of frame `i`, with pixel noise.
    fn observe(
        &self,
        i: usize,
        rng: &mut ChaCha8Rng,
        noise_px: f64,
    ) -> (Vec<Keypoint>, Vec<Descriptor>, Vec<f32>) {
        let T_c_w = Self::T_w_c(i).inverse();
        let (mut kps, mut descs, mut depths) = (Vec::new(), Vec::new(), Vec::new());
        for (p_w, d) in &self.landmarks {
            let p_c = T_c_w * Point3::from(*p_w);
            let Some(uv) = self.camera.project(&p_c.coords) else {
                continue;
            };
            let noisy = uv
                + Vector2::new(
                    rng.random_range(-noise_px..=noise_px),
                    rng.random_range(-noise_px..=noise_px),
                );
            // Only points inside the undistorted image: beyond it the distortion polynomial
            // folds back and would map far-away points into the image (no real lens does).
            if !self.bounds.contains(&noisy) {
                continue;
            }
            let raw = self.camera.distort_pixel(&noisy);
            if raw.x < 5.0 || raw.y < 5.0 || raw.x > 634.0 || raw.y > 474.0 {
                continue;
            }
            kps.push(common::keypoint(&raw, 0));
            descs.push(*d);
            depths.push(p_c.z as f32);
        }
        (kps, descs, depths)
    }
}

/// One frame's input (raw keypoints, descriptors, depths) at time `t`, seconds.
fn input<'a>(
    t: f64,
    keypoints: &'a [Keypoint],
    descriptors: &'a [Descriptor],
    depth_m: &'a [f32],
) -> RgbdInput<'a> {
    RgbdInput {
        timestamp: t,
        keypoints,
        descriptors,
        depth_m,
        colors: None,
    }
}

fn run(scene: &Scene, frames: usize, noise_px: f64) -> SlamSystem {
    run_with(scene, frames, noise_px, SlamConfig::default())
}

fn run_with(scene: &Scene, frames: usize, noise_px: f64, config: SlamConfig) -> SlamSystem {
    let mut system = SlamSystem::new(scene.camera, config).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    track_path(&mut system, scene, frames, noise_px, &mut rng);
    system
}

/// Tracks frames `0..frames` of the path at 30 Hz, each of which must be tracked; returns how
/// many became keyframes.
fn track_path(
    system: &mut SlamSystem,
    scene: &Scene,
    frames: usize,
    noise_px: f64,
    rng: &mut ChaCha8Rng,
) -> usize {
    let mut keyframes = 0;
    for i in 0..frames {
        let (kps, descs, depth) = scene.observe(i, rng, noise_px);
        let result = system
            .track_rgbd(&input(i as f64 / 30.0, &kps, &descs, &depth))
            .unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {i}");
        keyframes += usize::from(result.is_keyframe);
    }
    keyframes
}

/// The bytes of a run's frame trajectory (timestamps, translations, rotations) and map
/// points: equal bytes are bit-identical results.
fn result_bytes(system: &SlamSystem) -> Vec<u8> {
    let mut bytes = Vec::new();
    for (t, T_w_c) in system.frame_trajectory() {
        let (v, q) = (T_w_c.translation.vector, T_w_c.rotation.coords);
        for x in [t].iter().chain(v.iter()).chain(q.iter()) {
            bytes.extend(x.to_le_bytes());
        }
    }
    for p in system.map_points() {
        p.iter().for_each(|x| bytes.extend(x.to_le_bytes()));
    }
    bytes
}

/// A keyframe at least every 4 frames, so that local BA, culling and fusion run often.
fn frequent_keyframes() -> SlamConfig {
    let mut config = SlamConfig::default();
    config.tracking.skip_max_frames = 4;
    config
}

#[test]
fn two_runs_of_one_input_and_seed_are_bit_identical() {
    let scene = Scene::new(5, 1500);
    let first = run_with(&scene, 60, 0.5, frequent_keyframes());
    let keyframes = first.map().num_keyframes();
    // 6 measured.
    assert!(
        keyframes >= 5,
        "{keyframes} keyframes: local BA and culling must run"
    );
    let second = run_with(&scene, 60, 0.5, frequent_keyframes());
    assert_eq!(result_bytes(&second), result_bytes(&first));
}

#[test]
fn the_deterministic_mapping_thread_equals_inline_mapping() {
    let scene = Scene::new(5, 1500);
    let inline = run_with(&scene, 60, 0.5, frequent_keyframes());
    let config = SlamConfig {
        deterministic: true,
        ..frequent_keyframes()
    };
    let mut threaded = SlamSystem::new(scene.camera, config).unwrap();
    threaded.set_concurrent_mapping(true).unwrap();
    track_path(
        &mut threaded,
        &scene,
        60,
        0.5,
        &mut ChaCha8Rng::seed_from_u64(99),
    );
    threaded.finish_mapping().unwrap();
    assert_eq!(result_bytes(&threaded), result_bytes(&inline));
}

#[test]
fn tracks_a_synthetic_path_with_millimetre_accuracy() {
    let scene = Scene::new(1, 1500);
    let system = run(&scene, 40, 0.5);
    let trajectory = system.frame_trajectory();
    assert_eq!(trajectory.len(), 40);
    // The first camera is the world origin, so no alignment is needed.
    for (k, (t, T_w_c)) in trajectory.iter().enumerate() {
        assert!((t - k as f64 / 30.0).abs() < 1e-12);
        let error = se3::log(&(Scene::T_w_c(k).inverse() * T_w_c));
        // 0.5 px noise on ~1000 points at 1.5-5 m: a few mm and a few hundredths of a degree.
        assert!(
            error.fixed_rows::<3>(0).norm() < 0.005,
            "frame {k}: {error:?}"
        );
        assert!(
            error.fixed_rows::<3>(3).norm() < 0.1f64.to_radians(),
            "frame {k}: {error:?}"
        );
    }
    let map = system.map();
    assert!(map.num_keyframes() >= 2);
    map.check_consistency().unwrap();
    // Map points sit on their landmarks: depth points to ~z * 0.5 px / fx (< 5 mm); points
    // triangulated over a ~0.1 m baseline at 5 m to ~z^2 * 0.3 px / (fx * b), about 0.15 m.
    let mut misplacement: Vec<f64> = system
        .map_points()
        .iter()
        .map(|p| {
            scene
                .landmarks
                .iter()
                .map(|(l, _)| (l - p).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    misplacement.sort_by(f64::total_cmp);
    let quantile = |q: f64| misplacement[((misplacement.len() - 1) as f64 * q) as usize];
    assert!(
        quantile(0.5) < 0.006 && quantile(0.95) < 0.15,
        "median {} p95 {}",
        quantile(0.5),
        quantile(0.95)
    );
}

#[test]
fn loses_tracking_without_features_and_relocalises() {
    let scene = Scene::new(2, 1500);
    // A keyframe every other frame, so the map is past ORB-SLAM's reset-when-lost size (5).
    let mut config = SlamConfig::default();
    config.tracking.skip_max_frames = 2;
    let mut system = run_with(&scene, 40, 0.0, config);
    assert!(
        system.map().num_keyframes() > 5,
        "{} keyframes",
        system.map().num_keyframes()
    );
    let empty = input(2.0, &[], &[], &[]);
    assert_eq!(
        system.track_rgbd(&empty).unwrap().state,
        TrackingState::Lost
    );
    // Back at a viewpoint the map covers: PnP against the reference keyframe recovers.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (kps, descs, depth) = scene.observe(39, &mut rng, 0.0);
    let again = input(2.1, &kps, &descs, &depth);
    let result = system.track_rgbd(&again).unwrap();
    assert_eq!(result.state, TrackingState::Ok);
    let error = se3::log(&(Scene::T_w_c(39).inverse() * result.T_w_c.unwrap()));
    assert_eq!(system.resets(), 0);
    assert!(error.norm() < 1e-3, "{error:?}");
}

#[test]
fn rejects_bad_input_without_changing_state() {
    let scene = Scene::new(3, 1500);
    let mut system = run(&scene, 3, 0.0);
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let (kps, descs, depth) = scene.observe(3, &mut rng, 0.0);
    let stale = input(0.0, &kps, &descs, &depth);
    assert!(
        matches!(system.track_rgbd(&stale), Err(SlamError::InvalidInput(m)) if m.contains("not after"))
    );
    let short = input(1.0, &kps, &descs[1..], &depth);
    assert!(
        matches!(system.track_rgbd(&short), Err(SlamError::InvalidInput(m)) if m.contains("lengths must match"))
    );
    let mut nan = kps.clone();
    nan[0].x = f32::NAN;
    let bad = input(1.0, &nan, &descs, &depth);
    assert!(
        matches!(system.track_rgbd(&bad), Err(SlamError::InvalidInput(m)) if m.contains("non-finite"))
    );
    let one_color = [[0u8; 3]];
    let few_colors = RgbdInput {
        colors: Some(&one_color),
        ..input(1.0, &kps, &descs, &depth)
    };
    assert!(
        matches!(system.track_rgbd(&few_colors), Err(SlamError::InvalidInput(m)) if m.contains("colors: lengths must match"))
    );
    let good = input(0.1, &kps, &descs, &depth);
    assert_eq!(system.track_rgbd(&good).unwrap().state, TrackingState::Ok);
    assert_eq!(system.frame_trajectory().len(), 4);
}

#[test]
fn invalid_configuration_is_named() {
    let (_, camera) = test_cameras().into_iter().next().unwrap();
    let mut config = SlamConfig::default();
    config.tracking.track_feature_range = (50, 10);
    let err = SlamSystem::new(camera, config).err().unwrap();
    assert!(err.to_string().contains("track_feature_range"), "{err}");
}

#[test]
fn resets_when_lost_right_after_initialisation() {
    let scene = Scene::new(4, 1500);
    let mut system = run(&scene, 3, 0.0);
    let empty = input(1.0, &[], &[], &[]);
    assert_eq!(
        system.track_rgbd(&empty).unwrap().state,
        TrackingState::Lost
    );
    // ORB-SLAM's rule: a map of at most 5 keyframes is dropped and rebuilt from the next frame.
    assert_eq!((system.resets(), system.map().num_keyframes()), (1, 0));
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (kps, descs, depth) = scene.observe(3, &mut rng, 0.0);
    let next = input(1.1, &kps, &descs, &depth);
    assert_eq!(system.track_rgbd(&next).unwrap().state, TrackingState::Ok);
}

/// The colour the colour test gives a landmark: the first bytes of its (unique) descriptor.
fn color_of(d: &Descriptor) -> [u8; 3] {
    [d[0], d[1], d[2]]
}

/// Frames given with colours: every map point, made inline or by the mapping thread (whose
/// edits reach the map by replay), has the colour of the landmark it was made from.
#[test]
fn map_points_keep_the_colour_of_the_keypoint_that_made_them() {
    let scene = Scene::new(6, 1500);
    // A keyframe every other frame: most points are made by local mapping.
    let mut config = SlamConfig::default();
    config.tracking.skip_max_frames = 2;
    for concurrent in [false, true] {
        let mut system = SlamSystem::new(scene.camera, config.clone()).unwrap();
        system.set_concurrent_mapping(concurrent).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for i in 0..30 {
            let (kps, descs, depth) = scene.observe(i, &mut rng, 0.5);
            let colors: Vec<_> = descs.iter().map(color_of).collect();
            let frame = RgbdInput {
                colors: Some(&colors),
                ..input(i as f64 / 30.0, &kps, &descs, &depth)
            };
            assert_eq!(system.track_rgbd(&frame).unwrap().state, TrackingState::Ok);
        }
        system.finish_mapping().unwrap();
        let map = system.map();
        assert!(
            map.num_map_points() > 500,
            "{} points",
            map.num_map_points()
        );
        let later = map
            .map_points()
            .filter(|p| Some(p.first_keyframe()) != map.origin());
        let (keyframes, later) = (map.num_keyframes(), later.count());
        // Inline mapping is deterministic; how many keyframes the thread takes depends on
        // its timing.
        if !concurrent {
            assert!(
                keyframes > 5 && later > 20,
                "{keyframes} keyframes, {later} later points"
            );
        }
        for p in map.map_points() {
            // Every observation of a landmark has its descriptor, so the point's is too.
            let expected = color_of(p.descriptor());
            assert_eq!(p.color(), Some(expected), "point {} ({concurrent})", p.id());
        }
        let colors = system.map_point_colors();
        assert_eq!(colors.len(), system.map_points().len());
    }
}

/// Local mapping in its own thread, frames fed as fast as tracking takes them: the same
/// accuracy as inline mapping, a consistent map once the thread is done, and a clean stop.
#[test]
fn concurrent_mapping_keeps_the_accuracy_of_inline_mapping() {
    let scene = Scene::new(1, 1500);
    let mut system = SlamSystem::new(scene.camera, SlamConfig::default()).unwrap();
    system.set_concurrent_mapping(true).unwrap();
    assert!(system.concurrent_mapping());
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let keyframes = track_path(&mut system, &scene, 40, 0.5, &mut rng);
    system.finish_mapping().unwrap();
    assert_eq!(
        system
            .mapping_backlog()
            .unwrap()
            .load(std::sync::atomic::Ordering::SeqCst),
        0
    );
    let map = system.map();
    map.check_consistency().unwrap();
    assert!(keyframes >= 2 && map.num_keyframes() >= 2);
    for (k, (_, T_w_c)) in system.frame_trajectory().iter().enumerate() {
        let error = se3::log(&(Scene::T_w_c(k).inverse() * T_w_c));
        assert!(
            error.fixed_rows::<3>(0).norm() < 0.005,
            "frame {k}: {error:?}"
        );
    }
    // Switching back runs the remaining work and stops the thread; dropping with a keyframe
    // still in flight must not hang either.
    system.set_concurrent_mapping(false).unwrap();
    assert!(system.mapping_backlog().is_none());
    system.set_concurrent_mapping(true).unwrap();
    let (kps, descs, depth) = scene.observe(40, &mut rng, 0.5);
    system
        .track_rgbd(&input(40.0 / 30.0, &kps, &descs, &depth))
        .unwrap();
    drop(system);
}

/// With the mapping thread, tracking's keyframe index adopts the bags of words the thread
/// computed instead of computing them again: once mapping is done it holds every keyframe
/// with the words its descriptors give, and relocalisation (which, with a vocabulary, only
/// searches the keyframes the index recognises) finds a frame back at the start of the path.
#[test]
fn concurrent_mapping_hands_its_keyframe_index_to_relocalisation() {
    let scene = Scene::new(5, 1500);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let training: Vec<Vec<Descriptor>> = (0..40)
        .step_by(8)
        .map(|i| scene.observe(i, &mut rng, 0.0).1)
        .collect();
    let params = ferroslam_vocabulary::TrainParams {
        levels: 3,
        ..Default::default()
    };
    let vocabulary =
        std::sync::Arc::new(ferroslam_vocabulary::Vocabulary::train(&training, &params).unwrap());
    let mut config = SlamConfig::default();
    config.tracking.skip_max_frames = 2;
    let mut system = SlamSystem::new(scene.camera, config).unwrap();
    system.set_vocabulary(std::sync::Arc::clone(&vocabulary));
    system.set_concurrent_mapping(true).unwrap();
    track_path(&mut system, &scene, 40, 0.0, &mut rng);
    system.finish_mapping().unwrap();
    let (map, place) = (system.map(), system.place_recognition().unwrap());
    // How many of the 20 keyframes survive culling depends on the thread's timing: 4 or 6
    // in 16 runs (before and after the map became copy-on-write).
    assert!(map.num_keyframes() >= 3);
    assert_eq!(place.len(), map.num_keyframes());
    for kf in map.keyframe_ids() {
        let descriptors = &map.keyframe(kf).unwrap().features().descriptors;
        let levels_up = SlamConfig::default().place_recognition.feature_levels_up;
        let words = vocabulary.transform(descriptors, levels_up);
        assert_eq!(place.entry(kf), Some(&words), "{kf:?}");
    }
    let empty = input(2.0, &[], &[], &[]);
    assert_eq!(
        system.track_rgbd(&empty).unwrap().state,
        TrackingState::Lost
    );
    let (kps, descs, depth) = scene.observe(0, &mut rng, 0.0);
    let result = system
        .track_rgbd(&input(2.1, &kps, &descs, &depth))
        .unwrap();
    assert_eq!(result.state, TrackingState::Ok);
    let error = se3::log(&(Scene::T_w_c(0).inverse() * result.T_w_c.unwrap()));
    assert!(error.norm() < 1e-3, "{error:?}");
}
