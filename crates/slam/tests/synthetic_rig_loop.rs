//! Loop closing over a multi-camera rig, end to end on a synthetic scene with exact ground
//! truth: a ring corridor driven once around by a two-camera RGB-D rig whose heading turns
//! by an extra quarter turn over the lap, so that at the return the side camera (1) faces
//! what the front camera (0) faced at the start, while camera 0 sees only landmarks it never
//! saw near the start. The loop is there only for a system that matches every camera of a
//! keyframe; one that verifies loops in the first camera alone closes none.
//!
//! Landmarks are textured like real surfaces: each is seen only within
//! [`MAX_VIEW_ANGLE_DEG`] of its surface normal and [`MAX_RANGE_M`], so no camera matches a
//! view it could not really match (a grazing view's descriptor would differ).
#![allow(non_snake_case)]

mod common;

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::sync::Arc;
use std::time::Instant;

use ferroslam_features::{Descriptor, Keypoint};
use ferroslam_geometry::camera::{CameraModel, PinholeCamera, RadTan};
use ferroslam_geometry::rolling_shutter::ReadoutDirection;
use ferroslam_slam::{
    ObserverInput, RgbdInput, SlamConfig, SlamSystem, TrackResult, TrackingState,
};
use ferroslam_vocabulary::{TrainParams, Vocabulary};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Radius of the corridor's outer wall, metres.
const OUTER_RADIUS_M: f64 = 5.0;
/// Radius of the corridor's inner wall, metres.
const INNER_RADIUS_M: f64 = 3.0;
/// Radius of the rig's path, metres (mid-corridor).
const PATH_RADIUS_M: f64 = 4.0;
/// Floor and ceiling height below and above the cameras, metres.
const HALF_HEIGHT_M: f64 = 1.2;
/// Landmarks per square metre of wall, and of floor and ceiling.
const WALL_DENSITY_PER_M2: f64 = 150.0;
const FLOOR_DENSITY_PER_M2: f64 = 40.0;
/// Farthest a landmark is seen from, metres.
const MAX_RANGE_M: f64 = 3.0;
/// Widest angle between a landmark's surface normal and the ray to the camera, degrees.
const MAX_VIEW_ANGLE_DEG: f64 = 60.0;
/// Speed along the path, metres per second, and frame rate, Hz.
const SPEED_M_S: f64 = 1.2;
const FPS: f64 = 30.0;
/// How far past the start (path angle, radians) the run goes on after the lap.
const PAST_START_RAD: f64 = 0.5;
/// Heading turned over one lap on top of the path's own turn, radians: a quarter turn to
/// the left brings the right camera onto the start's forward view.
const EXTRA_HEADING_PER_LAP_RAD: f64 = FRAC_PI_2;
/// Pixel noise (standard deviation, pixels) and depth noise (`sigma = k z^2`, 1 / metres).
const PIXEL_NOISE_PX: f64 = 1.2;
const DEPTH_NOISE_PER_M: f64 = 0.01;
/// A landmark's descriptor is detected at octave 0 from this distance, one octave higher
/// for every pyramid scale step closer (a surface of fixed size grows in the image).
const OCTAVE_0_RANGE_M: f64 = 3.0;
const SCALE_FACTOR: f64 = 1.2;
const TOP_OCTAVE: u8 = 7;

/// A textured point of the corridor.
struct Landmark {
    p_w: Vector3<f64>,
    /// Unit surface normal, pointing into the corridor.
    normal: Vector3<f64>,
    descriptor: Descriptor,
}

/// One camera's measurements of a frame.
#[derive(Default)]
struct Observed {
    keypoints: Vec<Keypoint>,
    descriptors: Vec<Descriptor>,
    depth_m: Vec<f32>,
}

struct Scene {
    camera: PinholeCamera,
    /// Camera 1 (right side) in camera 0's frame.
    T_c0_c1: Isometry3<f64>,
    landmarks: Vec<Landmark>,
    /// Seconds both cameras take to read their rows, top first, centred on the frame's
    /// time (0: global shutters): each landmark is seen from the pose of its row's time.
    readout_s: f64,
    /// The readout the system is told (a run that ignores the shutter is told 0).
    told_readout_s: f64,
}

impl Scene {
    fn new(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut landmarks = Vec::new();
        let mut add = |p_w: Vector3<f64>, normal: Vector3<f64>, rng: &mut ChaCha8Rng| {
            let mut descriptor = [0u8; 32];
            rng.fill(&mut descriptor);
            landmarks.push(Landmark {
                p_w,
                normal,
                descriptor,
            });
        };
        for (radius, inwards) in [(OUTER_RADIUS_M, -1.0), (INNER_RADIUS_M, 1.0)] {
            let n = (TAU * radius * 2.0 * HALF_HEIGHT_M * WALL_DENSITY_PER_M2) as usize;
            for _ in 0..n {
                let a: f64 = rng.random_range(0.0..TAU);
                let z = rng.random_range(-HALF_HEIGHT_M..HALF_HEIGHT_M);
                let radial = Vector3::new(a.cos(), a.sin(), 0.0);
                add(
                    radial * radius + Vector3::z() * z,
                    radial * inwards,
                    &mut rng,
                );
            }
        }
        let ring_area = PI * (OUTER_RADIUS_M.powi(2) - INNER_RADIUS_M.powi(2));
        for up in [1.0, -1.0] {
            for _ in 0..(ring_area * FLOOR_DENSITY_PER_M2) as usize {
                let a: f64 = rng.random_range(0.0..TAU);
                // Uniform over the ring's area.
                let r2 = rng.random_range(INNER_RADIUS_M.powi(2)..OUTER_RADIUS_M.powi(2));
                let p = Vector3::new(a.cos(), a.sin(), 0.0) * r2.sqrt();
                // The floor (below, normal up) and the ceiling (above, normal down).
                add(
                    p - Vector3::z() * HALF_HEIGHT_M * up,
                    Vector3::z() * up,
                    &mut rng,
                );
            }
        }
        let camera =
            PinholeCamera::new(500.0, 500.0, 319.5, 239.5, RadTan::default(), 640, 480).unwrap();
        // Yaw -90 degrees (to the right) is +90 degrees about camera 0's y axis (down).
        let T_c0_c1 = Isometry3::from_parts(
            Translation3::new(0.1, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), FRAC_PI_2),
        );
        Self {
            camera,
            T_c0_c1,
            landmarks,
            readout_s: 0.0,
            told_readout_s: 0.0,
        }
    }

    /// The cameras as the system is told them: the readout it models.
    fn system_camera(&self) -> CameraModel {
        CameraModel::from(self.camera)
            .with_readout(self.told_readout_s, ReadoutDirection::TopToBottom)
            .unwrap()
    }

    /// Seconds one lap takes.
    fn lap_s() -> f64 {
        TAU * PATH_RADIUS_M / SPEED_M_S
    }

    /// Frames of the run: one lap and [`PAST_START_RAD`] more.
    fn frames() -> usize {
        ((TAU + PAST_START_RAD) * PATH_RADIUS_M / SPEED_M_S * FPS) as usize
    }

    /// Camera 0's pose at `t` seconds (z up, counter-clockwise around the ring): looking
    /// along the path at the start, turned left by [`EXTRA_HEADING_PER_LAP_RAD`] per lap.
    fn T_w_c0(t: f64) -> Isometry3<f64> {
        let a = t * SPEED_M_S / PATH_RADIUS_M;
        let heading = a + FRAC_PI_2 + EXTRA_HEADING_PER_LAP_RAD * a / TAU;
        let forward = Vector3::new(heading.cos(), heading.sin(), 0.0);
        let right = Vector3::new(heading.sin(), -heading.cos(), 0.0);
        let R_w_c = nalgebra::Matrix3::from_columns(&[right, -Vector3::z(), forward]);
        let rotation = UnitQuaternion::from_matrix(&R_w_c);
        // A gentle bob, so the path is not planar.
        let p = Vector3::new(a.cos(), a.sin(), 0.0) * PATH_RADIUS_M
            + Vector3::z() * 0.05 * (3.0 * a).sin();
        Isometry3::from_parts(Translation3::from(p), rotation)
    }

    /// Landmarks a camera at `T_w_c` sees: within range and viewing angle, in front, inside
    /// the image. Each with its true pixel and z-depth (metres).
    fn visible(&self, T_w_c: &Isometry3<f64>) -> Vec<(usize, nalgebra::Vector2<f64>, f64)> {
        let centre = T_w_c.translation.vector;
        let T_c_w = T_w_c.inverse();
        let min_cos = MAX_VIEW_ANGLE_DEG.to_radians().cos();
        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
        let mut seen = Vec::new();
        for (i, l) in self.landmarks.iter().enumerate() {
            let to_camera = centre - l.p_w;
            let range = to_camera.norm();
            if range > MAX_RANGE_M || to_camera.dot(&l.normal) < min_cos * range {
                continue;
            }
            let p_c = T_c_w * Point3::from(l.p_w);
            let Some(uv) = self.camera.project(&p_c.coords).filter(|_| p_c.z > 0.1) else {
                continue;
            };
            if uv.x >= 2.0 && uv.y >= 2.0 && uv.x < w - 2.0 && uv.y < h - 2.0 {
                seen.push((i, uv, p_c.z));
            }
        }
        seen
    }

    /// What a camera measures: noisy pixels and depths of the landmarks it sees, the camera
    /// at `T_w_c(dt)` `dt` seconds after the frame's time (each landmark at its row's time,
    /// [`Scene::readout_s`]; all at `T_w_c(0)` for a global shutter).
    fn observe(&self, T_w_c: &dyn Fn(f64) -> Isometry3<f64>, rng: &mut ChaCha8Rng) -> Observed {
        let mut o = Observed::default();
        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
        let shutter = CameraModel::from(self.camera)
            .with_readout(self.readout_s, ReadoutDirection::TopToBottom)
            .unwrap();
        let at_rows = self
            .visible(&T_w_c(0.0))
            .into_iter()
            .filter_map(|(i, uv0, z0)| {
                if self.readout_s == 0.0 {
                    return Some((i, uv0, z0));
                }
                // The row a landmark is read at depends on where the moving camera sees it.
                let (mut uv, mut z) = (uv0, z0);
                for _ in 0..5 {
                    let p_c = T_w_c(shutter.time_offset_s(&uv)).inverse()
                        * Point3::from(self.landmarks[i].p_w);
                    uv = self.camera.project(&p_c.coords).filter(|_| p_c.z > 0.1)?;
                    z = p_c.z;
                }
                Some((i, uv, z))
            });
        for (i, uv, z) in at_rows {
            let noisy = uv
                + nalgebra::Vector2::new(
                    common::gaussian(rng, PIXEL_NOISE_PX),
                    common::gaussian(rng, PIXEL_NOISE_PX),
                );
            if noisy.x < 0.0 || noisy.y < 0.0 || noisy.x >= w || noisy.y >= h {
                continue;
            }
            let steps = ((OCTAVE_0_RANGE_M / z).ln() / SCALE_FACTOR.ln()).round();
            let octave = steps.clamp(0.0, TOP_OCTAVE as f64) as u8;
            o.keypoints.push(common::keypoint(&noisy, octave));
            o.descriptors.push(self.landmarks[i].descriptor);
            let depth = z + common::gaussian(rng, DEPTH_NOISE_PER_M * z * z);
            o.depth_m.push(depth as f32);
        }
        o
    }

    /// Camera 1's pose when camera 0 is at `T_w_c0`.
    fn T_w_c1(&self, T_w_c0: &Isometry3<f64>) -> Isometry3<f64> {
        T_w_c0 * self.T_c0_c1
    }

    /// A vocabulary trained on what both cameras see every half second of the run.
    fn vocabulary(&self) -> Arc<Vocabulary> {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let training: Vec<Vec<Descriptor>> = (0..Self::frames())
            .step_by(15)
            .flat_map(|i| {
                let T_w_c0 = Self::T_w_c0(i as f64 / FPS);
                [T_w_c0, self.T_w_c1(&T_w_c0)]
            })
            .map(|T_w_c| self.observe(&|_| T_w_c, &mut rng).descriptors)
            .collect();
        let params = TrainParams {
            levels: 4,
            ..Default::default()
        };
        Arc::new(Vocabulary::train(&training, &params).unwrap())
    }
}

/// What a run gives: the system and how long tracking took, seconds.
struct Run {
    system: SlamSystem,
    seconds: f64,
}

/// Tracks the whole path with the rig (`rig`: both cameras, else camera 0 alone); every
/// frame must be tracked but those of `blackout` (seconds: from, to), whose images show
/// nothing.
fn run_with(
    scene: &Scene,
    vocabulary: &Arc<Vocabulary>,
    config: SlamConfig,
    rig: bool,
    blackout: Option<(f64, f64)>,
    after_frame: &mut dyn FnMut(&mut SlamSystem, &TrackResult),
) -> Run {
    let mut system = SlamSystem::new(scene.system_camera(), config).unwrap();
    if rig {
        system
            .add_camera(scene.system_camera(), scene.T_c0_c1, true)
            .unwrap();
    }
    system.set_vocabulary(Arc::clone(vocabulary));
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let start = Instant::now();
    for i in 0..Scene::frames() {
        let t = i as f64 / FPS;
        let dark = blackout.is_some_and(|(from, to)| (from..to).contains(&t));
        let (first, side) = if dark {
            (Observed::default(), Observed::default())
        } else {
            (
                scene.observe(&|dt| Scene::T_w_c0(t + dt), &mut rng),
                scene.observe(&|dt| scene.T_w_c1(&Scene::T_w_c0(t + dt)), &mut rng),
            )
        };
        let input = RgbdInput {
            timestamp: t,
            keypoints: &first.keypoints,
            descriptors: &first.descriptors,
            depth_m: &first.depth_m,
            colors: None,
        };
        let observers = [ObserverInput {
            keypoints: &side.keypoints,
            descriptors: &side.descriptors,
            colors: &[],
            depth_m: Some(&side.depth_m),
        }];
        let result = system
            .track_rgbd_rig(&input, if rig { &observers } else { &[] })
            .unwrap();
        if !dark {
            assert_eq!(result.state, TrackingState::Ok, "frame {i} at {t:.2} s");
        }
        after_frame(&mut system, &result);
    }
    Run {
        system,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// [`run_with`] without a blackout.
fn run(scene: &Scene, vocabulary: &Arc<Vocabulary>, config: SlamConfig, rig: bool) -> Run {
    run_with(scene, vocabulary, config, rig, None, &mut |_, _| {})
}

/// Absolute trajectory error of a run, metres.
fn ate_m(system: &SlamSystem) -> f64 {
    let (estimated, truth): (Vec<_>, Vec<_>) = system
        .frame_trajectory()
        .into_iter()
        .map(|(t, T_w_c)| (T_w_c, Scene::T_w_c0(t)))
        .unzip();
    common::ate_rmse_m(&estimated, &truth)
}

/// Error of the estimated position at the return (one lap after the start) relative to the
/// start, metres: the drift a loop closure has to correct.
fn drift_at_return_m(system: &SlamSystem) -> f64 {
    let trajectory = system.frame_trajectory();
    let at = |t: f64| {
        trajectory
            .iter()
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .unwrap()
    };
    let ((t0, est0), (t1, est1)) = (at(0.0), at(Scene::lap_s()));
    let estimated = (est0.inverse() * est1).translation.vector;
    let truth = (Scene::T_w_c0(*t0).inverse() * Scene::T_w_c0(*t1))
        .translation
        .vector;
    (estimated - truth).norm()
}

/// Whether keyframes of the first and of the last `window_s` seconds of the lap share a map
/// point: ordinary tracking re-finding the start.
fn start_is_refound(system: &SlamSystem, window_s: f64) -> bool {
    let map = system.map();
    let time_of = |kf| map.keyframe(kf).map(|k| k.timestamp());
    map.map_points().any(|p| {
        let times: Vec<f64> = p
            .observations()
            .keys()
            .filter_map(|&k| time_of(k))
            .collect();
        times.iter().any(|&t| t < window_s)
            && times
                .iter()
                .any(|&t| t > Scene::lap_s() - window_s && t < Scene::lap_s() + window_s)
    })
}

/// Landmarks both rig poses (camera 0 at `a` and at `b`) see, by any camera: a true loop's
/// keyframes share many.
fn shared_landmarks(scene: &Scene, a: &Isometry3<f64>, b: &Isometry3<f64>) -> usize {
    let seen = |T_w_c0: &Isometry3<f64>| -> std::collections::HashSet<usize> {
        [*T_w_c0, scene.T_w_c1(T_w_c0)]
            .iter()
            .flat_map(|T| scene.visible(T).into_iter().map(|(i, _, _)| i))
            .collect()
    };
    seen(a).intersection(&seen(b)).count()
}

/// Keyframes of a true loop are at most this far apart, metres: at the return the side camera
/// shares ~100 landmarks with the start's keyframes from 1.2 m away already (~300 from
/// 0.6 m, ~500 at the start itself), so a correct system may close the loop there.
const LOOP_MAX_APART_M: f64 = 1.5;
/// Landmarks (of either camera) a true loop's two keyframes both see, at least.
const LOOP_MIN_SHARED: usize = 30;

/// The side camera's view of the start closes the loop, and only true loops are closed;
/// loop closing then brings the trajectory well below the open-loop run's error.
///
/// Measured (release, seed 11): 678 frames, all tracked, 64 keyframes; one loop, keyframe 62
/// (21.3 s) to keyframe 1 (0.47 s), 477 points matched, scale 1, the current keyframe moved
/// 5.5 cm; loop stats 53 keyframes checked, 4 with candidates, 1 verified, 0 rejected. ATE
/// 0.0051 m against 0.0176 m without loop closing (0.29x); open-loop drift at the return
/// 0.058 m; camera 0 alone closes no loop (no candidate). With loop closing matching each
/// keyframe's first camera only (before the rig's loop closing), the same run closed no
/// loop: 3 candidates verified, 3 rejected. About 3 s of tracking per run, three runs.
#[test]
fn a_loop_seen_only_by_the_side_camera_is_closed() {
    let scene = Scene::new(11);
    let vocabulary = scene.vocabulary();
    let mut open = SlamConfig::default();
    open.loop_closing.loop_closure = false;
    let open_loop = run(&scene, &vocabulary, open, true);
    let closed = run(&scene, &vocabulary, SlamConfig::default(), true);
    let first_camera = run(&scene, &vocabulary, SlamConfig::default(), false);
    let (open_ate, closed_ate) = (ate_m(&open_loop.system), ate_m(&closed.system));
    let drift = drift_at_return_m(&open_loop.system);
    let system = &closed.system;
    eprintln!(
        "frames {} keyframes {} (open loop {}), loops {:?}, stats {:?}, ATE open {open_ate:.4} \
         m closed {closed_ate:.4} m, drift at return {drift:.4} m, tracking {:.1} s open, \
         {:.1} s closed; camera 0 alone: loops {:?}, stats {:?}",
        system.frame_trajectory().len(),
        system.map().num_keyframes(),
        open_loop.system.map().num_keyframes(),
        system.loops(),
        system.loop_stats(),
        open_loop.seconds,
        closed.seconds,
        first_camera.system.loops(),
        first_camera.system.loop_stats(),
    );
    // The scene's premises: without a loop closure nothing joins the start and the return,
    // the open loop drifts, and the first camera alone sees no loop.
    assert!(!start_is_refound(&open_loop.system, 3.0));
    assert!(
        drift > 0.03,
        "drift at the return {drift} m: nothing to correct"
    );
    assert!(first_camera.system.loops().is_empty());
    // (a) Every frame tracked (asserted in `run`), in one map.
    assert_eq!(system.frame_trajectory().len(), Scene::frames());
    assert!(system.frame_map_ids().iter().all(|&s| s == 0));
    assert_eq!(system.resets(), 0);
    // (b) A loop, and only true ones: keyframes of the start and of the return, close to
    // each other and seeing the same landmarks.
    assert!(!system.loops().is_empty(), "{:?}", system.loop_stats());
    for l in system.loops() {
        let (a, b) = (Scene::T_w_c0(l.timestamps.0), Scene::T_w_c0(l.timestamps.1));
        let apart_m = (a.translation.vector - b.translation.vector).norm();
        let shared = shared_landmarks(&scene, &a, &b);
        assert!(
            (l.timestamps.0 - l.timestamps.1).abs() >= 10.0
                && l.scale == 1.0
                && apart_m < LOOP_MAX_APART_M
                && shared >= LOOP_MIN_SHARED,
            "{l:?}: {apart_m:.2} m apart, {shared} landmarks seen by both"
        );
    }
    // (c) The closed loop's trajectory is well below the open loop's (0.29x measured).
    assert!(
        closed_ate < 0.5 * open_ate,
        "ATE {closed_ate} m with loop closing, {open_ate} m without"
    );
}

/// Both cameras read their rows over 30 ms while the rig drives the lap: each landmark is
/// seen from the rig's true pose at its row's time (up to 18 mm and 6 mrad from the middle
/// row). Modelling the shutter (each camera's rows at their times, the rig's velocity
/// estimated with its pose) keeps about the global-shutter run's error; a system told the
/// cameras are global carries the readouts' motion into its poses and points.
///
/// The rig is a vehicle turning steadily: its angular rate changes by far less than
/// 0.05 rad/s from frame to frame, which is the prior given here; the default 0.2 rad/s is a
/// hand-held camera's.
///
/// Measured (release, seed 11, loop closing off): every frame tracked in both runs; ATE
/// modelled 0.0170 m, ignored 0.0560 m (global shutters: 0.0176 m). With the default
/// prior, 0.0657 m: one frame's rows leave the angular rate free enough to trade against
/// the pose. Noise-free, the side camera's shutter alone is modelled to 0.4 mm (ignored
/// 84.6 mm), the first camera's alone to 3.6 mm (ignored 32.5 mm; global 0.1 mm).
#[test]
fn a_rolling_shutter_rig_is_tracked_at_each_camera_s_rows() {
    let rolling = |told_readout_s| Scene {
        readout_s: 0.03,
        told_readout_s,
        ..Scene::new(11)
    };
    let (modelled, ignored) = (rolling(0.03), rolling(0.0));
    let vocabulary = modelled.vocabulary();
    let mut config = SlamConfig::default();
    config.loop_closing.loop_closure = false;
    config.tracking.velocity_prior_sigma_rad_s = 0.05;
    let modelled_ate = ate_m(&run(&modelled, &vocabulary, config.clone(), true).system);
    let ignored_ate = ate_m(&run(&ignored, &vocabulary, config, true).system);
    eprintln!("rolling-shutter rig: ATE modelled {modelled_ate:.4} m, ignored {ignored_ate:.4} m");
    assert!(
        modelled_ate < 0.025 && modelled_ate < 0.5 * ignored_ate,
        "ATE {modelled_ate} m modelled, {ignored_ate} m with the shutter ignored"
    );
}

/// The cameras see nothing for [`BLACKOUT_S`] from a quarter lap on: the map is lost, kept in
/// the atlas after `relocalisation_window_s`, and a new map starts where the first never was.
const BLACKOUT_S: (f64, f64) = (5.0, 8.5);

/// The configuration of the blackout runs: a new map starts from the first frame after the
/// blackout, which sees about 80 landmarks (ORB-SLAM's 500 keypoints are for real images).
fn blackout_config() -> SlamConfig {
    let mut config = SlamConfig::default();
    config.initialization.min_keypoints = 50;
    config
}

/// Checks a merge against the scene: keyframes of the start and of the return, close to
/// each other and seeing the same landmarks, the older map kept.
fn assert_true_merge(scene: &Scene, m: &ferroslam_slam::MapMerge) {
    let (a, b) = (Scene::T_w_c0(m.timestamps.0), Scene::T_w_c0(m.timestamps.1));
    let apart_m = (a.translation.vector - b.translation.vector).norm();
    let shared = shared_landmarks(scene, &a, &b);
    assert!(
        (m.merged_map, m.into_map) == (1, 0)
            && m.timestamps.0 > BLACKOUT_S.1
            && m.timestamps.1 < BLACKOUT_S.0
            && m.scale == 1.0
            && apart_m < LOOP_MAX_APART_M
            && shared >= LOOP_MIN_SHARED,
        "{m:?}: {apart_m:.2} m apart, {shared} landmarks seen by both"
    );
}

/// [`run_with`] through the rig with the blackout.
fn run_blackout(
    scene: &Scene,
    vocabulary: &Arc<Vocabulary>,
    config: SlamConfig,
    after_frame: &mut dyn FnMut(&mut SlamSystem, &TrackResult),
) -> Run {
    run_with(
        scene,
        vocabulary,
        config,
        true,
        Some(BLACKOUT_S),
        after_frame,
    )
}

/// A map lost in a blackout is kept; the map started after it recognises the start at the
/// return and merges into it (SE(3), depth): one map holds every tracked frame, in the first
/// map's world, with about the error of a run that never lost its map and closed no loop
/// (the merge's one seam has nothing on its other side to correct the lap's drift with).
///
/// Measured (release, seed 11): map 0 kept after 150 frames (17 keyframes); map 1 from
/// 8.5 s, 27 keyframes; one merge, keyframe 41 (21.2 s) to keyframe 1 (0.47 s), 410 points,
/// scale 1; then one map of 573 frames (678 less the 105 dark ones), 43 keyframes; ATE
/// 0.0187 m over all of them, against 0.0176 m for the open loop without a blackout (1.06x).
/// Offline, the same two maps saved and merged by a new system: one merge at the same
/// keyframes (410 points), one map of 44 keyframes.
#[test]
fn a_map_lost_in_a_blackout_is_merged_back_at_the_return() {
    let scene = Scene::new(11);
    let vocabulary = scene.vocabulary();
    let dark = run_blackout(&scene, &vocabulary, blackout_config(), &mut |_, _| {});
    let mut open = SlamConfig::default();
    open.loop_closing.loop_closure = false;
    let open_ate = ate_m(&run(&scene, &vocabulary, open, true).system);
    let system = &dark.system;
    let ate = ate_m(system);
    eprintln!(
        "frames {} maps {:?} merges {:?} loops {:?} ATE {ate:.4} m",
        system.frame_trajectory().len(),
        system.maps(),
        system.merges(),
        system.loops(),
    );
    let blackout_frames = (0..Scene::frames())
        .filter(|&i| (BLACKOUT_S.0..BLACKOUT_S.1).contains(&(i as f64 / FPS)))
        .count();
    assert_eq!(system.merges().len(), 1, "{:?}", system.maps());
    assert_true_merge(&scene, &system.merges()[0]);
    let maps = system.maps();
    assert_eq!(maps.len(), 1, "{maps:?}");
    assert_eq!((maps[0].id, system.current_map_id()), (0, 0));
    assert_eq!(maps[0].frames, Scene::frames() - blackout_frames);
    assert!(system.frame_map_ids().iter().all(|&m| m == 0));
    assert!(
        ate < 1.25 * open_ate,
        "ATE {ate} m over both maps' frames in the merged world, {open_ate} m for the open \
         loop that never lost its map"
    );
}

/// The same two maps, built with loop closing (hence merging) off, saved as one atlas file
/// and merged offline by a new system: one merge, as online.
#[test]
fn two_saved_maps_merge_offline() {
    let scene = Scene::new(11);
    let vocabulary = scene.vocabulary();
    let mut apart = blackout_config();
    apart.loop_closing.loop_closure = false;
    let dark = run_blackout(&scene, &vocabulary, apart, &mut |_, _| {});
    let built = dark.system.maps();
    assert_eq!(built.len(), 2, "{built:?}");
    let dir = std::env::temp_dir().join(format!("ferroslam-merge-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("atlas.map");
    dark.system.save_map(&path).unwrap();

    let mut merger = SlamSystem::new(scene.camera, blackout_config()).unwrap();
    merger
        .add_camera(scene.camera, scene.T_c0_c1, true)
        .unwrap();
    merger.set_vocabulary(Arc::clone(&vocabulary));
    let ids = merger.add_maps(&path).unwrap();
    assert_eq!(ids.len(), 2);
    let merges = merger.merge_maps().unwrap();
    eprintln!(
        "maps {:?} -> merges {merges:?}, left {:?}",
        built,
        merger.maps()
    );
    assert_eq!(merges.len(), 1);
    let m = &merges[0];
    assert_eq!((m.merged_map, m.into_map), (ids[1], ids[0]));
    let left = merger.maps();
    assert_eq!(left.len(), 1, "{left:?}");
    assert_eq!(
        left[0].keyframes,
        built.iter().map(|m| m.keyframes).sum::<usize>()
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The blackout run with the mapping thread (from the second frame on): the merge's weld and
/// global BA run there, after the merge frame's call returned, so its keyframes still move
/// when the thread's work is taken in; with `deterministic` the call waits for them and the
/// run equals the inline one bit for bit. Either way one merge, every frame tracked (asserted per frame
/// in `run_with`).
///
/// Measured (release, seed 11): the keyframes move up to 13-19 mm once the BA is taken in
/// after the free-running merge call returned (0 deterministic); the seam's local BA held 12
/// keyframes.
#[test]
fn a_merge_s_bundle_adjustment_runs_in_the_mapping_thread() {
    let scene = Scene::new(11);
    let vocabulary = scene.vocabulary();
    let run_threaded = |deterministic: bool| {
        let mut config = blackout_config();
        config.deterministic = deterministic;
        // How far the keyframes move once the thread's work is taken in after the merge
        // frame returned, metres.
        let mut moved_m = None;
        let mut after_frame = |system: &mut SlamSystem, result: &TrackResult| {
            if !system.concurrent_mapping() {
                system.set_concurrent_mapping(true).unwrap();
            }
            if result.merge.is_some() {
                let returned = system.keyframe_trajectory();
                system.finish_mapping().unwrap();
                let adjusted = system.keyframe_trajectory();
                let moved = returned
                    .iter()
                    .filter_map(|(k, _, a)| {
                        let (_, _, b) = adjusted.iter().find(|(j, _, _)| j == k)?;
                        Some((a.translation.vector - b.translation.vector).norm())
                    })
                    .fold(0.0, f64::max);
                moved_m = Some(moved);
            }
        };
        let run = run_blackout(&scene, &vocabulary, config, &mut after_frame);
        (run, moved_m)
    };
    let inline = run_blackout(&scene, &vocabulary, blackout_config(), &mut |_, _| {});
    let (free, free_moved) = run_threaded(false);
    let (deterministic, deterministic_moved) = run_threaded(true);
    eprintln!(
        "moved after the merge frame: free {free_moved:?} deterministic {deterministic_moved:?}; \
         merges free {:?}",
        free.system.merges()
    );
    for run in [&free, &deterministic] {
        assert_eq!(run.system.merges().len(), 1, "{:?}", run.system.maps());
        assert_true_merge(&scene, &run.system.merges()[0]);
        assert!(run.system.merges()[0].welded_keyframes >= 2);
    }
    // Free-running, the call returned before global BA had moved anything.
    assert!(free_moved.is_some_and(|m| m > 1e-6), "{free_moved:?}");
    assert_eq!(deterministic_moved, Some(0.0));
    assert_eq!(
        deterministic.system.frame_trajectory(),
        inline.system.frame_trajectory()
    );
    assert_eq!(deterministic.system.merges(), inline.system.merges());
}
