//! RGB-D tracking through a 190-degree Kannala-Brandt fisheye on a synthetic scene that
//! surrounds the camera: map points beyond 90 degrees from the optical axis (behind the
//! image plane a pinhole would need) must be triangulated from rays and then tracked.
#![allow(non_snake_case)]

mod common;

use ferroslam_features::{Descriptor, Keypoint};
use ferroslam_geometry::camera::{KannalaBrandtCamera, PinholeCamera, RadTan};
use ferroslam_geometry::se3;
use ferroslam_slam::{RgbdInput, Sensor, SlamConfig, SlamError, SlamSystem, TrackingState};
use nalgebra::{Isometry3, Point3, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Half the field of view seen (degrees): 190 degrees across.
const HALF_FOV_DEG: f64 = 95.0;
/// Depth is measured only this close to the axis (degrees), as a depth camera's narrower
/// field of view would: wider features have no depth and must be triangulated.
const DEPTH_HALF_FOV_DEG: f64 = 55.0;
const FRAMES: usize = 90;

/// fx = fy = 150 px per radian on a 640 x 640 image: 95 degrees lands 249 px from the centre.
fn fisheye() -> KannalaBrandtCamera {
    KannalaBrandtCamera::new(
        150.0,
        150.0,
        320.0,
        320.0,
        [-0.01, 0.002, 0.0, 0.0],
        640,
        640,
    )
    .unwrap()
}

/// Landmarks 2-6 m around the path, in every direction, with unique descriptors.
fn landmarks(seed: u64, n: usize) -> Vec<(Vector3<f64>, Descriptor)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let dir = loop {
                let v = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                if (0.1..1.0).contains(&v.norm()) {
                    break v.normalize();
                }
            };
            let mut d = [0u8; 32];
            rng.fill(&mut d);
            (dir * rng.random_range(2.0..6.0), d)
        })
        .collect()
}

/// Camera pose of frame `i` (a pan with a sideways and forward drift).
fn T_w_c(i: usize) -> Isometry3<f64> {
    let s = i as f64;
    se3::exp(&Vector6::new(
        0.008 * s,
        0.002 * s,
        0.004 * s,
        0.003 * s,
        0.008 * s,
        0.002 * s,
    ))
}

/// Angle of `p_c` from the optical axis, degrees.
fn incidence_deg(p_c: &Vector3<f64>) -> f64 {
    p_c.xy().norm().atan2(p_c.z).to_degrees()
}

/// Raw keypoints, descriptors and z-depths (0 = none) of frame `i`, with pixel noise.
fn observe(
    camera: &KannalaBrandtCamera,
    scene: &[(Vector3<f64>, Descriptor)],
    i: usize,
    rng: &mut ChaCha8Rng,
) -> (Vec<Keypoint>, Vec<Descriptor>, Vec<f32>) {
    let T_c_w = T_w_c(i).inverse();
    let (mut kps, mut descs, mut depths) = (Vec::new(), Vec::new(), Vec::new());
    for (p_w, d) in scene {
        let p_c = (T_c_w * Point3::from(*p_w)).coords;
        let theta = incidence_deg(&p_c);
        if theta > HALF_FOV_DEG {
            continue;
        }
        let uv = camera.project(&p_c).unwrap()
            + Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
        kps.push(common::keypoint(&uv, 0));
        descs.push(*d);
        depths.push(if theta < DEPTH_HALF_FOV_DEG {
            p_c.z as f32
        } else {
            0.0
        });
    }
    (kps, descs, depths)
}

#[test]
fn a_190_degree_fisheye_tracks_with_points_beyond_ninety_degrees() {
    let camera = fisheye();
    assert!(camera.max_incidence_rad().to_degrees() >= HALF_FOV_DEG);
    let scene = landmarks(5, 2500);
    // A keyframe at least every 10 frames (30 by default), so that points are triangulated
    // along the path and then tracked by the frames after.
    let mut config = SlamConfig::default();
    config.tracking.skip_max_frames = 10;
    let mut system = SlamSystem::new(camera, config).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    for i in 0..FRAMES {
        let (kps, descs, depth) = observe(&camera, &scene, i, &mut rng);
        let input = RgbdInput {
            timestamp: i as f64 / 30.0,
            keypoints: &kps,
            descriptors: &descs,
            depth_m: &depth,
            colors: None,
        };
        let result = system.track_rgbd(&input).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {i}");
    }

    // The first camera is the world origin: poses compare without alignment.
    let trajectory = system.frame_trajectory();
    assert_eq!(trajectory.len(), FRAMES);
    let (mut worst_t, mut worst_r) = (0.0f64, 0.0f64);
    for (k, (_, T)) in trajectory.iter().enumerate() {
        let error = se3::log(&(T_w_c(k).inverse() * T));
        worst_t = worst_t.max(error.fixed_rows::<3>(0).norm());
        worst_r = worst_r.max(error.fixed_rows::<3>(3).norm().to_degrees());
    }

    // Points a keyframe's frame tracked (created by an earlier keyframe) that lie beyond 90
    // degrees from its axis: only rays can have triangulated, projected and matched them.
    let map = system.map();
    map.check_consistency().unwrap();
    let (mut tracked, mut beyond_90) = (0, 0);
    for kf in map.keyframes() {
        for m in kf.map_points().iter().flatten() {
            let Some(p) = map.map_point(*m) else { continue };
            if p.first_keyframe() == kf.id() {
                continue;
            }
            tracked += 1;
            let p_c = (kf.T_c_w() * Point3::from(p.position())).coords;
            beyond_90 += usize::from(incidence_deg(&p_c) > 90.0);
        }
    }
    eprintln!(
        "190-degree fisheye: {FRAMES}/{FRAMES} tracked, worst error {:.2} mm / {:.3} deg, \
         {} keyframes, {tracked} tracked keyframe points, {beyond_90} beyond 90 degrees",
        worst_t * 1e3,
        worst_r,
        map.num_keyframes()
    );
    // Measured 128 of 2305 (the 90-95 degree band is about 4 % of the view): well above 0,
    // with room for other builds.
    assert!(
        beyond_90 >= 50,
        "{beyond_90} tracked points beyond 90 degrees"
    );
    // 0.5 px noise on rays 1/150 rad per pixel: millimetres, hundredths of a degree.
    assert!(worst_t < 0.01, "worst translation error {worst_t} m");
    assert!(worst_r < 0.2, "worst rotation error {worst_r} deg");

    // The saved map records the fisheye; a pinhole system with the same intrinsics refuses
    // it as it refuses another pinhole calibration.
    let path = std::env::temp_dir().join(format!("fisheye_map_{}.fslam", std::process::id()));
    system.save_map(&path).unwrap();
    let mut again = SlamSystem::new(camera, SlamConfig::default()).unwrap();
    again.load_map(&path).unwrap();
    assert_eq!(again.map().rig().unwrap().model, "kannala_brandt");
    assert_eq!(again.map().num_keyframes(), map.num_keyframes());
    let c = &camera;
    let pinhole = PinholeCamera::new(c.fx, c.fy, c.cx, c.cy, RadTan::default(), 640, 640);
    let mut other = SlamSystem::new(pinhole.unwrap(), SlamConfig::default()).unwrap();
    let err = other.load_map(&path).unwrap_err();
    std::fs::remove_file(&path).unwrap();
    assert!(matches!(err, SlamError::MapFile { .. }), "{err}");
    assert!(
        err.to_string().contains("\"kannala_brandt\" camera model"),
        "{err}"
    );
}

#[test]
fn a_stereo_system_refuses_a_fisheye() {
    let mut config = SlamConfig::for_sensor(Sensor::Stereo);
    config.depth.bf = 150.0 * 0.1;
    let err = SlamSystem::new(fisheye(), config).err().unwrap();
    assert!(matches!(err, SlamError::InvalidConfig(_)), "{err}");
    assert!(err.to_string().contains("from_raw"), "{err}");
}
