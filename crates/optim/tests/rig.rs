//! Observations from the cameras of a multi-camera rig: motion-only BA and local BA on
//! synthetic rigs whose cameras look in different directions, and the rig's input checks.
#![allow(non_snake_case)]

mod common;

use common::{perturb, pose_error, project, K};
use ferroslam_geometry::rolling_shutter::{point_at_offset, ReadoutDirection, RollingShutter};
use ferroslam_optim::pose_rolling_shutter::{optimize_pose_and_velocity, VelocityPrior};
use ferroslam_optim::{
    local_bundle_adjust, optimize_pose, BaProblem, Observation, OptimError, PoseObservation,
    RigCamera,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `T_ck_c0` of a camera yawed `yaw_deg` about the rig's vertical (camera y) axis, `offset`
/// metres from the first camera.
fn yawed(yaw_deg: f64, offset: Vector3<f64>) -> Isometry3<f64> {
    let R = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians());
    Isometry3::from_parts(Translation3::from(offset), R)
}

/// Three cameras yawed 0, 90 and 180 degrees: no two see the same point.
fn three_camera_rig() -> Vec<RigCamera> {
    vec![
        RigCamera::first(K),
        RigCamera::new(K, yawed(90.0, Vector3::new(-0.05, 0.01, 0.03))),
        RigCamera::new(K, yawed(180.0, Vector3::new(0.02, -0.01, -0.08))),
    ]
}

/// `T_ck_w` of camera `k` of the rig at `T_c0_w`.
fn camera_pose(cameras: &[RigCamera], k: usize, T_c0_w: &Isometry3<f64>) -> Isometry3<f64> {
    cameras[k].T_c_c0.map_or(*T_c0_w, |T| T * T_c0_w)
}

/// A random world point in front of camera `k` of the rig at `T_c0_w`, inside its image.
fn point_seen_by(
    rng: &mut impl Rng,
    cameras: &[RigCamera],
    k: usize,
    T_c0_w: &Isometry3<f64>,
) -> Vector3<f64> {
    let T_ck_w = camera_pose(cameras, k, T_c0_w);
    loop {
        let p_c = Vector3::new(
            rng.random_range(-2.5..2.5),
            rng.random_range(-2.0..2.0),
            rng.random_range(3.0..8.0),
        );
        if project(&Isometry3::identity(), &p_c).is_some() {
            return T_ck_w.inverse_transform_point(&Point3::from(p_c)).coords;
        }
    }
}

/// Exact (noise-free) observations by the given cameras of the rig at `T_c0_w`, 30 per
/// camera, every third one stereo.
fn pose_observations(
    rng: &mut impl Rng,
    cameras: &[RigCamera],
    seen_by: &[usize],
    T_c0_w: &Isometry3<f64>,
) -> Vec<PoseObservation> {
    let mut obs = Vec::new();
    for &k in seen_by {
        for i in 0..30 {
            let p_w = point_seen_by(rng, cameras, k, T_c0_w);
            let (uv, z) = project(&camera_pose(cameras, k, T_c0_w), &p_w).unwrap();
            obs.push(PoseObservation {
                camera: k,
                p_w,
                uv,
                u_right: (i % 3 == 0).then(|| uv.x - K.bf / z),
                inv_sigma2: 1.0,
            });
        }
    }
    obs
}

/// Motion-only BA of the rig from a perturbed pose with the observations of `seen_by`.
fn recovers_the_pose(seed: u64, seen_by: &[usize]) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let cameras = three_camera_rig();
    let T_true = common::true_poses(&mut rng, 1)[0];
    let obs = pose_observations(&mut rng, &cameras, seen_by, &T_true);
    let start = perturb(&mut rng, &T_true, 0.05, 0.035);
    let mut outlier = vec![false; obs.len()];
    let est = optimize_pose(&start, &obs, &cameras, &mut outlier).unwrap();
    let (dt, dr) = pose_error(&est.T_c_w, &T_true);
    let (dt0, dr0) = pose_error(&start, &T_true);
    println!("cameras {seen_by:?}: {dt:.2e} m {dr:.2e} rad (from {dt0:.3} m {dr0:.3} rad)");
    assert!(dt < 1e-6 && dr < 1e-6, "{dt} m, {dr} rad");
    assert_eq!(est.num_inliers, obs.len());
}

#[test]
fn points_seen_only_by_the_side_and_rear_cameras_recover_the_pose() {
    for seed in 0..5 {
        recovers_the_pose(seed, &[1, 2]);
    }
}

#[test]
fn points_of_the_first_camera_alone_recover_the_pose_as_without_a_rig() {
    for seed in 0..5 {
        recovers_the_pose(seed, &[0]);
    }
    // The first camera's arithmetic is that of the pose alone: the same result, bit for bit.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let cameras = three_camera_rig();
    let T_true = common::true_poses(&mut rng, 1)[0];
    let obs = pose_observations(&mut rng, &cameras, &[0], &T_true);
    let start = perturb(&mut rng, &T_true, 0.05, 0.035);
    let rig = optimize_pose(&start, &obs, &cameras, &mut vec![false; obs.len()]).unwrap();
    let alone = optimize_pose(
        &start,
        &obs,
        &[RigCamera::first(K)],
        &mut vec![false; obs.len()],
    );
    assert_eq!(rig, alone.unwrap());
}

#[test]
fn an_observation_of_a_camera_the_rig_does_not_have_is_refused() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let cameras = three_camera_rig();
    let T = common::true_poses(&mut rng, 1)[0];
    let mut obs = pose_observations(&mut rng, &cameras, &[0], &T);
    obs[4].camera = 3;
    assert_eq!(
        optimize_pose(&T, &obs, &cameras, &mut vec![false; obs.len()]),
        Err(OptimError::InvalidInput(
            "observation 4 is of camera 3, but the rig has 3 cameras".into()
        ))
    );
    assert_eq!(
        optimize_pose(&T, &obs, &[], &mut vec![false; obs.len()]),
        Err(OptimError::InvalidInput("no camera".into()))
    );
}

/// Noise-free observations by cameras `seen_by` of a rolling-shutter rig at `T_c0_w` moving
/// at `xi_dot` (the first camera's velocity), each camera reading its rows top to bottom over
/// `readout_s`: every point is seen from `T_ck_c0 * D(dt) * T_c0_w` at its own row's offset
/// `dt` (the fixed point of row -> time -> projection), with the offsets.
fn rolling_shutter_observations(
    rng: &mut impl Rng,
    cameras: &[RigCamera],
    seen_by: &[usize],
    T_c0_w: &Isometry3<f64>,
    xi_dot: &Vector6<f64>,
    readout_s: f64,
) -> (Vec<PoseObservation>, Vec<f64>) {
    let rs = RollingShutter::from_readout(readout_s, 480, ReadoutDirection::TopToBottom).unwrap();
    let extent = Vector2::new(common::WIDTH, common::HEIGHT);
    let (mut obs, mut offsets) = (Vec::new(), Vec::new());
    for &k in seen_by {
        while obs
            .iter()
            .filter(|o: &&PoseObservation| o.camera == k)
            .count()
            < 40
        {
            let p_w = point_seen_by(rng, cameras, k, T_c0_w);
            let mut t = 0.0;
            let mut seen = None;
            for _ in 0..10 {
                let p_c0 = point_at_offset(T_c0_w, xi_dot, t, &Point3::from(p_w)).p_c;
                let p_ck = cameras[k]
                    .T_c_c0
                    .map_or(p_c0, |T| (T * Point3::from(p_c0)).coords);
                seen = project(&Isometry3::identity(), &p_ck);
                let Some((uv, _)) = seen else { break };
                t = rs.time_offset_s(&uv, &extent);
            }
            let Some((uv, z)) = seen else { continue };
            obs.push(PoseObservation {
                camera: k,
                p_w,
                uv,
                u_right: (obs.len() % 3 == 0).then(|| uv.x - K.bf / z),
                inv_sigma2: 1.0,
            });
            offsets.push(t);
        }
    }
    (obs, offsets)
}

#[test]
fn a_rolling_shutter_rig_gives_pose_and_velocity_from_every_camera() {
    // 1.5 rad/s and 0.4 m/s (a hand-held rate), 25 ms readouts: seen by the side and rear
    // cameras only, the first camera's pose and velocity come back exactly, while the
    // global-shutter problem is biased by the readouts' motion.
    let cameras = three_camera_rig();
    for seed in 0..5 {
        let mut rng = ChaCha8Rng::seed_from_u64(20 + seed);
        let T_true = common::true_poses(&mut rng, 1)[0];
        let w = common::gaussian3(&mut rng, 1.0).normalize() * 1.5;
        let v = common::gaussian3(&mut rng, 1.0).normalize() * 0.4;
        let xi_true = Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z);
        let (obs, dt) =
            rolling_shutter_observations(&mut rng, &cameras, &[1, 2], &T_true, &xi_true, 0.025);
        let start = perturb(&mut rng, &T_true, 0.03, 0.02);
        let prior = VelocityPrior::isotropic(xi_true, 0.2, 0.5);
        let mut flags = vec![false; obs.len()];
        let joint =
            optimize_pose_and_velocity(&start, &prior, &obs, &dt, &cameras, &mut flags).unwrap();
        let (dt_m, dr) = pose_error(&joint.T_c_w, &T_true);
        let dv = (joint.xi_dot - xi_true).norm();
        let mut flags = vec![false; obs.len()];
        let global = optimize_pose(&start, &obs, &cameras, &mut flags).unwrap();
        let (_, dr_global) = pose_error(&global.T_c_w, &T_true);
        println!("seed {seed}: joint {dt_m:.1e} m {dr:.1e} rad, velocity {dv:.1e}; global {dr_global:.1e} rad");
        assert!(
            dt_m < 1e-6 && dr < 1e-6 && dv < 1e-4,
            "{dt_m} m, {dr} rad, {dv}"
        );
        assert_eq!(joint.num_inliers, obs.len());
        assert!(
            dr_global > 1e-3,
            "the readouts must bias a global model: {dr_global} rad"
        );
    }
}

#[test]
fn a_rolling_shutter_rig_s_first_camera_alone_is_the_single_camera_problem() {
    // The first camera's arithmetic is the single camera's, bit for bit.
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let cameras = three_camera_rig();
    let T = common::true_poses(&mut rng, 1)[0];
    let xi = Vector6::new(0.1, -0.2, 0.3, 0.5, -1.0, 0.7);
    let (obs, dt) = rolling_shutter_observations(&mut rng, &cameras, &[0], &T, &xi, 0.02);
    let prior = VelocityPrior::isotropic(Vector6::zeros(), 1.0, 1.0);
    let start = perturb(&mut rng, &T, 0.03, 0.02);
    let mut flags = vec![false; obs.len()];
    let rig = optimize_pose_and_velocity(&start, &prior, &obs, &dt, &cameras, &mut flags);
    let mut flags = vec![false; obs.len()];
    let alone = optimize_pose_and_velocity(
        &start,
        &prior,
        &obs,
        &dt,
        &[RigCamera::first(K)],
        &mut flags,
    );
    assert_eq!(rig.unwrap(), alone.unwrap());
}

#[test]
fn local_ba_of_a_two_camera_rig_converges_to_the_truth() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    // A forward and a rear camera; the rig moves sideways over 1.2 m.
    let cameras = vec![
        RigCamera::first(K),
        RigCamera::new(K, yawed(180.0, Vector3::new(0.03, 0.0, -0.1))),
    ];
    let true_poses: Vec<Isometry3<f64>> = (0..4)
        .map(|i| {
            let centre = Vector3::new(-0.6 + 0.4 * i as f64, 0.05 * i as f64, 0.0);
            let R_w_c = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.03 * i as f64, 0.0));
            Isometry3::from_parts(Translation3::from(centre), R_w_c).inverse()
        })
        .collect();
    let mut true_points = Vec::new();
    let mut observations = Vec::new();
    for k in 0..cameras.len() {
        let mut seen_by_k = 0;
        while seen_by_k < 40 {
            let p_w = point_seen_by(&mut rng, &cameras, k, &true_poses[1]);
            let views: Vec<_> = true_poses
                .iter()
                .enumerate()
                .filter_map(|(pose, T)| {
                    project(&camera_pose(&cameras, k, T), &p_w).map(|v| (pose, v))
                })
                .collect();
            if views.len() < 2 {
                continue;
            }
            for (pose, (uv, z)) in views {
                observations.push(Observation {
                    pose,
                    point: true_points.len(),
                    camera: k,
                    uv,
                    u_right: (pose % 2 == 0).then(|| uv.x - K.bf / z),
                    inv_sigma2: 1.0,
                    readout_motion: None,
                });
            }
            true_points.push(p_w);
            seen_by_k += 1;
        }
    }
    let mut problem = BaProblem {
        cameras,
        poses: true_poses
            .iter()
            .enumerate()
            .map(|(i, T)| {
                if i == 0 {
                    *T
                } else {
                    perturb(&mut rng, T, 0.02, 0.01)
                }
            })
            .collect(),
        pose_fixed: vec![true, false, false, false],
        points: true_points
            .iter()
            .map(|p| p + common::gaussian3(&mut rng, 0.05))
            .collect(),
        observations,
    };
    let result = local_bundle_adjust(&mut problem).unwrap();
    assert!(result.outlier.iter().all(|&o| !o));
    for (T, truth) in problem.poses.iter().zip(&true_poses) {
        let (dt, dr) = pose_error(T, truth);
        assert!(dt < 1e-6 && dr < 1e-6, "{dt} m, {dr} rad");
    }
    let worst = problem
        .points
        .iter()
        .zip(&true_points)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max);
    println!("{:?}, worst point error {worst:.2e} m", result.report);
    assert!(worst < 1e-5, "{worst} m");
}
