//! Gauge freedom of the BA normal equations, from the public residual Jacobians.
//!
//! With every pose and point free, a rigid motion of the whole scene leaves all residuals
//! unchanged, so `H = J^T W J` has a 6-dimensional null space (7 for monocular-only data,
//! where a global scale is unobservable too), and no more.

mod common;

use common::{scene, SceneSpec, K};
use ferroslam_optim::residual::linearize;
use ferroslam_optim::BaProblem;
use nalgebra::{DMatrix, SymmetricEigen};

fn normal_matrix(p: &BaProblem) -> DMatrix<f64> {
    let (np, nx) = (p.poses.len(), p.points.len());
    let n = 6 * np + 3 * nx;
    let mut h = DMatrix::zeros(n, n);
    for o in &p.observations {
        let l = linearize(&K, &p.poses[o.pose], &p.points[o.point], &o.uv, o.u_right).unwrap();
        let mut j = DMatrix::zeros(3, n);
        j.view_mut((0, 6 * o.pose), (3, 6)).copy_from(&l.d_e_d_xi);
        j.view_mut((0, 6 * np + 3 * o.point), (3, 3))
            .copy_from(&l.d_e_d_p_w);
        h += o.inv_sigma2 * j.transpose() * j;
    }
    h
}

fn null_space_dim(stereo_fraction: f64) -> usize {
    let spec = SceneSpec {
        seed: 31,
        poses: 4,
        fixed: 0,
        points: 40,
        visibility: 1.0,
        stereo_fraction,
        pixel_sigma: 1.0,
        pose_sigma_t: 0.02,
        pose_sigma_r: 0.01,
        point_sigma: 0.05,
    };
    let h = normal_matrix(&scene(&spec).problem);
    let mut ev: Vec<f64> = SymmetricEigen::new(h).eigenvalues.iter().copied().collect();
    ev.sort_by(f64::total_cmp);
    let largest = ev[ev.len() - 1];
    let zero = ev.iter().filter(|&&e| e.abs() < 1e-10 * largest).count();
    // A clear gap between the null space and the weakest observable direction (the stereo
    // scale, with an 8 cm baseline at 5-12 m, is only ~1e-7 of the largest eigenvalue).
    let null_max = ev[..zero].iter().fold(0.0f64, |m, e| m.max(e.abs()));
    assert!(
        ev[zero] > 1e6 * null_max,
        "no spectral gap: {:?} (largest {largest:e})",
        &ev[..zero + 2]
    );
    zero
}

#[test]
fn stereo_gauge_is_six_dimensional() {
    assert_eq!(null_space_dim(1.0), 6);
}

#[test]
fn mono_gauge_adds_scale() {
    assert_eq!(null_space_dim(0.0), 7);
}
