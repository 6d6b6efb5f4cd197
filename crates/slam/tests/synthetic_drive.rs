//! A KITTI-like drive with exact ground truth: landmarks along a road (4-30 m to the side, up
//! to 150 m ahead), the rectified KITTI 00 camera moving forward 1 m per frame while slowly
//! turning, depth from noisy disparity as a 0.54 m stereo rig gives it. Checks that the metric
//! scale does not drift when most points are far (disparity of a few pixels).
#![allow(non_snake_case)]

mod common;

use ferroslam_features::Descriptor;
use ferroslam_geometry::camera::{test_cameras, PinholeCamera};
use ferroslam_slam::{DepthConfig, RgbdInput, SlamConfig, SlamSystem, TrackingState};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const BASELINE_M: f64 = 0.54;

fn camera() -> PinholeCamera {
    test_cameras()
        .into_iter()
        .find(|(n, _)| *n == "kitti_00")
        .unwrap()
        .1
}

fn T_w_c(i: usize) -> Isometry3<f64> {
    let s = i as f64;
    Isometry3::from_parts(
        Translation3::new(0.02 * s, 0.0, 1.0 * s),
        UnitQuaternion::from_euler_angles(0.0, 0.004 * s, 0.0),
    )
}

/// Relative path-length error of the tracked trajectory (estimate / truth - 1).
fn scale_error(disparity_sigma: f64, frames: usize) -> f64 {
    let cam = camera();
    let bf = cam.fx * BASELINE_M;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let landmarks: Vec<(Vector3<f64>, Descriptor)> = (0..6000)
        .map(|_| {
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let p = Vector3::new(
                side * rng.random_range(4.0..30.0),
                rng.random_range(-4.0..1.6),
                rng.random_range(3.0..frames as f64 + 150.0),
            );
            let mut d = [0u8; 32];
            rng.fill(&mut d);
            (p, d)
        })
        .collect();
    let gauss = |rng: &mut ChaCha8Rng, sigma: f64| {
        let (u1, u2): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random());
        sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    let mut config = SlamConfig::default();
    config.depth = DepthConfig {
        bf,
        depth_threshold: 35.0,
        depth_range: (0.0, f64::INFINITY),
        ..config.depth
    };
    let mut system = SlamSystem::new(cam, config).unwrap();
    for i in 0..frames {
        let T_c_w = T_w_c(i).inverse();
        let (mut kps, mut descs, mut depths) = (Vec::new(), Vec::new(), Vec::new());
        for (p_w, d) in &landmarks {
            let p_c = T_c_w * Point3::from(*p_w);
            let Some(uv) = cam.project(&p_c.coords) else {
                continue;
            };
            let uv = uv + Vector2::new(gauss(&mut rng, 0.5), gauss(&mut rng, 0.5));
            if uv.x < 20.0
                || uv.y < 20.0
                || uv.x > cam.width as f64 - 20.0
                || uv.y > cam.height as f64 - 20.0
            {
                continue;
            }
            let d_px = bf / p_c.z + gauss(&mut rng, disparity_sigma);
            kps.push(common::keypoint(&uv, 0));
            descs.push(*d);
            depths.push(if d_px > 0.0 && d_px < cam.fx {
                (bf / d_px) as f32
            } else {
                0.0
            });
        }
        let r = system
            .track_rgbd(&RgbdInput {
                timestamp: i as f64 * 0.1,
                keypoints: &kps,
                descriptors: &descs,
                depth_m: &depths,
                colors: None,
            })
            .unwrap();
        assert_eq!(r.state, TrackingState::Ok, "frame {i}");
    }
    let traj = system.frame_trajectory();
    let len: f64 = traj
        .windows(2)
        .map(|w| (w[1].1.translation.vector - w[0].1.translation.vector).norm())
        .sum();
    let gt: f64 = (1..frames)
        .map(|i| (T_w_c(i).translation.vector - T_w_c(i - 1).translation.vector).norm())
        .sum();
    len / gt - 1.0
}

#[test]
fn scale_holds_on_a_far_field_drive() {
    // Measured: +0.01 % without disparity noise, 0.00 % with 0.3 px; 0.5 % is far below the
    // 4-7 % a drifting map shows on real KITTI data, and above numerical noise.
    for sigma in [0.0, 0.3] {
        let e = scale_error(sigma, 50);
        assert!(
            e.abs() < 0.005,
            "disparity noise {sigma} px: scale error {e:+.4}"
        );
    }
}
