//! Seeded synthetic scenes shared by the integration tests and the benchmark.
#![allow(dead_code, non_snake_case)]

pub mod flight;

use ferroslam_geometry::se3;
use ferroslam_optim::residual::linearize;
use ferroslam_optim::{BaProblem, Intrinsics, Observation, RigCamera};
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix3x6, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// TUM fr1-like ideal pinhole with a 8 cm virtual baseline (bf = fx * b).
pub const K: Intrinsics = Intrinsics {
    fx: 517.3,
    fy: 516.5,
    cx: 318.6,
    cy: 255.3,
    bf: 517.3 * 0.08,
    fisheye: None,
};
pub const WIDTH: f64 = 640.0;
pub const HEIGHT: f64 = 480.0;

/// Standard normal sample (Box-Muller; avoids a rand_distr dependency).
pub fn gaussian(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

pub fn gaussian3(rng: &mut impl Rng, sigma: f64) -> Vector3<f64> {
    Vector3::from_fn(|_, _| sigma * gaussian(rng))
}

/// Perturbs a pose on the left by a random twist with the given translation / rotation sigmas.
pub fn perturb(
    rng: &mut impl Rng,
    T: &Isometry3<f64>,
    sigma_t: f64,
    sigma_r: f64,
) -> Isometry3<f64> {
    let t = gaussian3(rng, sigma_t);
    let r = gaussian3(rng, sigma_r);
    se3::exp(&Vector6::new(t.x, t.y, t.z, r.x, r.y, r.z)) * T
}

/// Translation (m) and rotation (rad) difference of two poses.
pub fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a * b.inverse();
    (d.translation.vector.norm(), d.rotation.angle())
}

/// Cameras spread along x (and a little in y, z), looking roughly along +z at a point cloud.
pub fn true_poses(rng: &mut impl Rng, n: usize) -> Vec<Isometry3<f64>> {
    (0..n)
        .map(|i| {
            let x = -2.0 + 4.0 * i as f64 / (n.max(2) - 1) as f64;
            let c = Vector3::new(x, 0.3 * gaussian(rng), 0.3 * gaussian(rng)); // centre in world
            let r = gaussian3(rng, 0.05);
            let R_w_c = nalgebra::UnitQuaternion::from_scaled_axis(r);
            Isometry3::from_parts(c.into(), R_w_c).inverse()
        })
        .collect()
}

pub fn project(T_c_w: &Isometry3<f64>, p_w: &Vector3<f64>) -> Option<(Vector2<f64>, f64)> {
    let p_c = T_c_w * nalgebra::Point3::from(*p_w);
    if p_c.z < 0.5 {
        return None;
    }
    let uv = Vector2::new(K.fx * p_c.x / p_c.z + K.cx, K.fy * p_c.y / p_c.z + K.cy);
    (uv.x >= 0.0 && uv.x < WIDTH && uv.y >= 0.0 && uv.y < HEIGHT).then_some((uv, p_c.z))
}

pub fn random_point(rng: &mut impl Rng) -> Vector3<f64> {
    Vector3::new(
        rng.random_range(-5.0..5.0),
        rng.random_range(-3.5..3.5),
        rng.random_range(5.0..12.0),
    )
}

/// What to generate.
#[derive(Clone, Copy, Debug)]
pub struct SceneSpec {
    pub seed: u64,
    pub poses: usize,
    /// Number of fixed poses, spread evenly from the first to the last.
    pub fixed: usize,
    pub points: usize,
    /// Probability that a camera that sees a point observes it (thins the graph like ORB-SLAM).
    pub visibility: f64,
    pub stereo_fraction: f64,
    pub pixel_sigma: f64,
    pub pose_sigma_t: f64,
    pub pose_sigma_r: f64,
    pub point_sigma: f64,
}

pub struct Scene {
    pub problem: BaProblem,
    pub true_poses: Vec<Isometry3<f64>>,
    pub true_points: Vec<Vector3<f64>>,
}

/// Noisy observations (sigma = `pixel_sigma`, `inv_sigma2` set accordingly) of random points,
/// each seen by at least two cameras; free poses and all points perturbed.
pub fn scene(spec: &SceneSpec) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let true_poses = true_poses(&mut rng, spec.poses);
    let mut true_points = Vec::with_capacity(spec.points);
    let mut observations = Vec::new();
    while true_points.len() < spec.points {
        let p = random_point(&mut rng);
        let seen: Vec<(usize, Vector2<f64>, f64)> = true_poses
            .iter()
            .enumerate()
            .filter_map(|(c, T)| project(T, &p).map(|(uv, z)| (c, uv, z)))
            .filter(|_| rng.random_bool(spec.visibility))
            .collect();
        if seen.len() < 2 {
            continue;
        }
        let point = true_points.len();
        true_points.push(p);
        for (pose, uv, z) in seen {
            let noisy =
                uv + Vector2::new(gaussian(&mut rng), gaussian(&mut rng)) * spec.pixel_sigma;
            let u_right = rng
                .random_bool(spec.stereo_fraction)
                .then(|| uv.x - K.bf / z + spec.pixel_sigma * gaussian(&mut rng));
            observations.push(Observation {
                camera: 0,
                pose,
                point,
                uv: noisy,
                u_right,
                inv_sigma2: 1.0 / (spec.pixel_sigma * spec.pixel_sigma),
                readout_motion: None,
            });
        }
    }
    // Fixed poses spread over the trajectory (first and last for two), so they anchor scale.
    let mut pose_fixed = vec![false; spec.poses];
    for k in 0..spec.fixed {
        pose_fixed[(k * (spec.poses - 1))
            .checked_div(spec.fixed - 1)
            .unwrap_or(0)] = true;
    }
    let poses = true_poses
        .iter()
        .zip(&pose_fixed)
        .map(|(T, &fixed)| {
            if fixed {
                *T
            } else {
                perturb(&mut rng, T, spec.pose_sigma_t, spec.pose_sigma_r)
            }
        })
        .collect();
    let points = true_points
        .iter()
        .map(|p| p + gaussian3(&mut rng, spec.point_sigma))
        .collect();
    Scene {
        problem: BaProblem {
            cameras: vec![RigCamera::first(K)],
            poses,
            pose_fixed,
            points,
            observations,
        },
        true_poses,
        true_points,
    }
}

/// Upper 99.9% quantile of chi-square with `k` dof (Wilson-Hilferty, accurate to ~1% here).
pub fn chi2_quantile_999(k: usize) -> f64 {
    let k = k as f64;
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + 3.0902 * a.sqrt()).powi(3)
}

/// Marginal information of the free poses (the reduced camera system at the TRUE state,
/// over the observations with `use_obs`), free poses in order, 6 per pose.
pub fn free_pose_information(s: &Scene, use_obs: &[bool]) -> DMatrix<f64> {
    let p = &s.problem;
    let free: Vec<usize> = (0..p.poses.len()).filter(|&i| !p.pose_fixed[i]).collect();
    let slot = |pose: usize| free.iter().position(|&f| f == pose);
    let n = 6 * free.len();
    let mut h = DMatrix::zeros(n, n);
    // Per point: (free slot of the pose, d_e_d_xi, d_e_d_p_w, inv_sigma2).
    type Term = (Option<usize>, Matrix3x6<f64>, Matrix3<f64>, f64);
    let mut by_point: Vec<Vec<Term>> = vec![Vec::new(); p.points.len()];
    for (o, _) in p.observations.iter().zip(use_obs).filter(|(_, &u)| u) {
        let l = linearize(
            &K,
            &s.true_poses[o.pose],
            &s.true_points[o.point],
            &o.uv,
            o.u_right,
        )
        .unwrap();
        by_point[o.point].push((slot(o.pose), l.d_e_d_xi, l.d_e_d_p_w, o.inv_sigma2));
    }
    for obs in &by_point {
        let v: Matrix3<f64> = obs
            .iter()
            .map(|(_, _, jp, w)| *w * jp.transpose() * jp)
            .sum();
        let Some(v_inv) = v.try_inverse() else {
            continue;
        };
        for (a, ja, jpa, wa) in obs {
            let Some(a) = *a else { continue };
            let ua = *wa * ja.transpose() * ja;
            let mut block = h.view_mut((6 * a, 6 * a), (6, 6));
            block += ua;
            let wa_cp = *wa * ja.transpose() * jpa;
            for (b, jb, jpb, wb) in obs {
                let Some(b) = *b else { continue };
                let wb_cp = *wb * jb.transpose() * jpb;
                let mut block = h.view_mut((6 * a, 6 * b), (6, 6));
                block -= wa_cp * v_inv * wb_cp.transpose();
            }
        }
    }
    h
}

/// Squared Mahalanobis distance of the free-pose errors `log(T_est * T_true^-1)` in `info`.
pub fn pose_mahalanobis(s: &Scene, poses: &[Isometry3<f64>], info: &DMatrix<f64>) -> f64 {
    let xi: Vec<f64> = (0..poses.len())
        .filter(|&i| !s.problem.pose_fixed[i])
        .flat_map(|i| {
            se3::log(&(poses[i] * s.true_poses[i].inverse()))
                .iter()
                .copied()
                .collect::<Vec<_>>()
        })
        .collect();
    let xi = DVector::from_vec(xi);
    xi.dot(&(info * &xi))
}
