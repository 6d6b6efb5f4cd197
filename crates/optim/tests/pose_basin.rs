//! Motion-only BA converges from the kind of initial error tracking hands it.
#![allow(non_snake_case)]

use ferroslam_geometry::se3;
use ferroslam_optim::{optimize_pose, Intrinsics, PoseObservation, RigCamera};
use nalgebra::{Isometry3, Point3, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn converges_from_several_degrees_off() {
    let k = Intrinsics {
        fx: 517.3,
        fy: 516.5,
        cx: 318.6,
        cy: 255.3,
        bf: 40.0,
        fisheye: None,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let T_c_w = se3::exp(&Vector6::new(0.1, -0.05, 0.2, 0.3, -0.2, 0.1));
    let mut obs = Vec::new();
    while obs.len() < 200 {
        let p_c = Vector3::new(
            rng.random_range(-1.5..1.5),
            rng.random_range(-1.0..1.0),
            rng.random_range(0.8..4.0),
        );
        let u = k.fx * p_c.x / p_c.z + k.cx;
        let v = k.fy * p_c.y / p_c.z + k.cy;
        if !(0.0..640.0).contains(&u) || !(0.0..480.0).contains(&v) {
            continue;
        }
        let p_w = T_c_w.inverse() * Point3::from(p_c);
        let stereo = obs.len() % 2 == 0;
        obs.push(PoseObservation {
            camera: 0,
            p_w: p_w.coords,
            uv: Vector2::new(u, v),
            u_right: stereo.then(|| u - k.bf / p_c.z),
            inv_sigma2: 1.0,
        });
    }
    for (deg, metres) in [
        (1e-5, 1e-7),
        (1e-3, 1e-5),
        (1.0, 0.01),
        (3.0, 0.03),
        (5.0, 0.05),
        (8.0, 0.08),
    ] {
        let r = f64::to_radians(deg);
        let delta = Vector6::new(metres, -metres, metres, r, -r * 0.5, r * 0.3);
        let init: Isometry3<f64> = se3::exp(&delta) * T_c_w;
        let mut outlier = vec![false; obs.len()];
        let est = optimize_pose(&init, &obs, &[RigCamera::first(k)], &mut outlier).unwrap();
        let err = se3::log(&(est.T_c_w * T_c_w.inverse()));
        assert!(
            err.norm() < 1e-6,
            "{deg} deg: error {err:?}, inliers {}",
            est.num_inliers
        );
        assert_eq!(est.num_inliers, obs.len(), "{deg} deg");
    }
}
