//! EPnP (Lepetit, Moreno-Noguer, Fua, IJCV 2009): camera pose from `n >= 4` 3D-2D
//! correspondences in closed form, the minimal solver inside [`crate::pnp`].
//!
//! World points are written as barycentric combinations of 4 control points; the camera
//! coordinates of the control points lie in the null space of a `2n x 12` matrix `M`,
//! spanned by its 4 weakest right singular vectors `v_k`. The coefficients `beta` are
//! found from the control-point distances (linearised for 1, 2 and 3 null vectors, then
//! Gauss-Newton on all 4) and the candidate with the lowest reprojection error is kept.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, SMatrix, SymmetricEigen, Vector3, Vector4};

use crate::umeyama::umeyama;

type Matrix12 = SMatrix<f64, 12, 12>;
type Vector12 = SMatrix<f64, 12, 1>;

/// The 6 pairs of control points whose distances fix `beta`.
const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// Pose `T_c_w` from world points and camera rays (same order).
///
/// `rays` are directions in the camera frame with `z > 0`, normally `(x, y, 1)` from
/// [`crate::camera::PinholeCamera::unproject`].
///
/// Exact on noise-free data from 5 points on. With exactly 4 points the distance
/// equations have several roots and the Gauss-Newton step can settle on a wrong one, so
/// [`crate::pnp`] samples 5.
///
/// Returns `None` for fewer than 4 points, mismatched lengths, non-finite input, rays with
/// `z <= 0`, or (near-)planar or collinear world points: this is the general-position
/// EPnP, without the planar variant.
#[allow(non_snake_case)]
pub fn epnp(points_w: &[Vector3<f64>], rays: &[Vector3<f64>]) -> Option<Isometry3<f64>> {
    let n = points_w.len();
    let finite = |p: &Vector3<f64>| p.iter().all(|v| v.is_finite());
    if n < 4
        || rays.len() != n
        || !points_w.iter().all(finite)
        || !rays.iter().all(|r| finite(r) && r.z > 0.0)
    {
        return None;
    }
    let control_w = control_points(points_w)?;
    let basis = Matrix3::from_columns(&[
        control_w[1] - control_w[0],
        control_w[2] - control_w[0],
        control_w[3] - control_w[0],
    ]);
    let basis_inv = basis.try_inverse()?;
    let alphas: Vec<Vector4<f64>> = points_w
        .iter()
        .map(|p| {
            let a = basis_inv * (p - control_w[0]);
            Vector4::new(1.0 - a.sum(), a.x, a.y, a.z)
        })
        .collect();

    let mut mtm = Matrix12::zeros();
    for (alpha, ray) in alphas.iter().zip(rays) {
        let (u, v) = (ray.x / ray.z, ray.y / ray.z);
        let (mut r1, mut r2) = (Vector12::zeros(), Vector12::zeros());
        for j in 0..4 {
            r1[3 * j] = alpha[j];
            r1[3 * j + 2] = -alpha[j] * u;
            r2[3 * j + 1] = alpha[j];
            r2[3 * j + 2] = -alpha[j] * v;
        }
        mtm += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let eig = SymmetricEigen::new(mtm);
    let mut order: Vec<usize> = (0..12).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let null: [Vector12; 4] =
        std::array::from_fn(|k| eig.eigenvectors.column(order[k]).into_owned());

    // dv[p][k]: difference of the pair's control points in null vector k.
    let dv: [[Vector3<f64>; 4]; 6] = PAIRS.map(|(i, j)| {
        std::array::from_fn(|k| {
            null[k].fixed_rows::<3>(3 * i).into_owned()
                - null[k].fixed_rows::<3>(3 * j).into_owned()
        })
    });
    let rho: [f64; 6] = PAIRS.map(|(i, j)| (control_w[i] - control_w[j]).norm_squared());

    let mut best: Option<(f64, Isometry3<f64>)> = None;
    for beta in initial_betas(&dv, &rho) {
        let beta = refine_betas(beta, &dv, &rho);
        let Some(T_c_w) = pose_from_betas(&beta, &null, &alphas, points_w) else {
            continue;
        };
        let error = reprojection_error(&T_c_w, points_w, rays);
        if best.as_ref().is_some_and(|(e, _)| *e <= error) {
            continue;
        }
        best = Some((error, T_c_w));
    }
    best.map(|(_, t)| t)
}

/// Centroid plus the principal axes scaled by their standard deviations; `None` when the
/// points are (nearly) planar or collinear.
fn control_points(points_w: &[Vector3<f64>]) -> Option<[Vector3<f64>; 4]> {
    let n = points_w.len() as f64;
    let c0 = points_w.iter().sum::<Vector3<f64>>() / n;
    let cov = points_w.iter().fold(Matrix3::zeros(), |acc, p| {
        acc + (p - c0) * (p - c0).transpose()
    }) / n;
    let eig = SymmetricEigen::new(cov);
    let (lo, hi) = (eig.eigenvalues.min(), eig.eigenvalues.max());
    if lo.is_nan() || lo <= 1e-10 * hi {
        return None;
    }
    Some(std::array::from_fn(|k| {
        if k == 0 {
            c0
        } else {
            c0 + eig.eigenvectors.column(k - 1) * eig.eigenvalues[k - 1].sqrt()
        }
    }))
}

/// The three linearised initialisations of EPnP (1, 2 and 3 null vectors, as in the paper,
/// with the 1-vector case using the 4-term approximation of the reference code).
fn initial_betas(dv: &[[Vector3<f64>; 4]; 6], rho: &[f64; 6]) -> Vec<Vector4<f64>> {
    // Columns of the 6x10 system L b = rho, b = [b00 b01 b11 b02 b12 b22 b03 b13 b23 b33].
    let products = [
        (0, 0),
        (0, 1),
        (1, 1),
        (0, 2),
        (1, 2),
        (2, 2),
        (0, 3),
        (1, 3),
        (2, 3),
        (3, 3),
    ];
    let l = DMatrix::from_fn(6, 10, |p, c| {
        let (a, b) = products[c];
        let factor = if a == b { 1.0 } else { 2.0 };
        factor * dv[p][a].dot(&dv[p][b])
    });
    let rho = DVector::from_column_slice(rho);
    let solve = |cols: &[usize]| least_squares(l.select_columns(cols), &rho);
    // From b00 and b11 (up to the common sign of all b), with b01 fixing the relative sign.
    let first_two = |b: &DVector<f64>| -> Vector4<f64> {
        let sign = if b[0] < 0.0 { -1.0 } else { 1.0 };
        let b0 = (sign * b[0]).sqrt();
        let b1 = if sign * b[2] > 0.0 {
            (sign * b[2]).sqrt()
        } else {
            0.0
        };
        let b0 = if sign * b[1] < 0.0 { -b0 } else { b0 };
        Vector4::new(b0, b1, 0.0, 0.0)
    };
    let mut out = Vec::with_capacity(3);
    if let Some(b) = solve(&[0, 1, 3, 6]) {
        let sign = if b[0] < 0.0 { -1.0 } else { 1.0 };
        let b0 = (sign * b[0]).sqrt();
        out.push(Vector4::new(
            b0,
            sign * b[1] / b0,
            sign * b[2] / b0,
            sign * b[3] / b0,
        ));
    }
    if let Some(b) = solve(&[0, 1, 2]) {
        out.push(first_two(&b));
    }
    if let Some(b) = solve(&[0, 1, 2, 3, 4]) {
        let mut beta = first_two(&b);
        beta[2] = if beta[0] != 0.0 { b[3] / beta[0] } else { 0.0 };
        out.push(beta);
    }
    out.retain(|b| b.iter().all(|v| v.is_finite()));
    out
}

/// Gauss-Newton on `|sum_k beta_k dv[p][k]|^2 = rho[p]` for the 6 pairs.
fn refine_betas(
    mut beta: Vector4<f64>,
    dv: &[[Vector3<f64>; 4]; 6],
    rho: &[f64; 6],
) -> Vector4<f64> {
    for _ in 0..10 {
        let mut jac = DMatrix::<f64>::zeros(6, 4);
        let mut res = DVector::<f64>::zeros(6);
        for p in 0..6 {
            let d: Vector3<f64> = (0..4).map(|k| dv[p][k] * beta[k]).sum();
            res[p] = d.norm_squared() - rho[p];
            for k in 0..4 {
                jac[(p, k)] = 2.0 * d.dot(&dv[p][k]);
            }
        }
        let Some(step) = least_squares(jac, &(-res)) else {
            break;
        };
        let step = Vector4::from_column_slice(step.as_slice());
        beta += step;
        if step.norm() <= 1e-12 * beta.norm() {
            break;
        }
    }
    beta
}

/// The least-squares solution of `a x = b` (`a` tall, full column rank) by QR, as EPnP's
/// reference code solves it. With SVD instead, EPnP took 56 us per 5-point call against 30
/// (`cargo bench -p ferroslam-geometry --bench pnp`), and relocalisation a tenth of the
/// tracking thread's time on TUM mono. `None` when `a` is near rank-deficient or the
/// solution is not finite.
fn least_squares(a: DMatrix<f64>, b: &DVector<f64>) -> Option<DVector<f64>> {
    let qr = a.qr();
    let r = qr.r();
    let diagonal = r.diagonal().abs();
    if diagonal.min() <= 1e-12 * diagonal.max() {
        return None; // NaN input falls through to the finiteness filter
    }
    r.solve_upper_triangular(&(qr.q().transpose() * b))
        .filter(|x| x.iter().all(|v| v.is_finite()))
}

/// Camera-frame control points from `beta`, then the rigid fit of world to camera points.
fn pose_from_betas(
    beta: &Vector4<f64>,
    null: &[Vector12; 4],
    alphas: &[Vector4<f64>],
    points_w: &[Vector3<f64>],
) -> Option<Isometry3<f64>> {
    let cc: Vector12 = (0..4).map(|k| null[k] * beta[k]).sum();
    let control_c: [Vector3<f64>; 4] =
        std::array::from_fn(|j| cc.fixed_rows::<3>(3 * j).into_owned());
    let mut points_c: Vec<Vector3<f64>> = alphas
        .iter()
        .map(|a| (0..4).map(|j| control_c[j] * a[j]).sum())
        .collect();
    // The null space fixes the control points up to sign; the points must be in front.
    if points_c.iter().map(|p| p.z).sum::<f64>() < 0.0 {
        points_c.iter_mut().for_each(|p| *p = -*p);
    }
    let s = umeyama(points_w, &points_c, false)?;
    Some(Isometry3::from_parts(s.translation.into(), s.rotation))
}

/// Sum of squared reprojection errors in normalized coordinates (infinite if any point
/// falls behind the camera).
#[allow(non_snake_case)]
fn reprojection_error(
    T_c_w: &Isometry3<f64>,
    points_w: &[Vector3<f64>],
    rays: &[Vector3<f64>],
) -> f64 {
    points_w
        .iter()
        .zip(rays)
        .map(|(p, r)| {
            let q = T_c_w.rotation * p + T_c_w.translation.vector;
            if q.z <= 0.0 {
                return f64::INFINITY;
            }
            (q.xy() / q.z - r.xy() / r.z).norm_squared()
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3;
    use approx::assert_relative_eq;
    use nalgebra::Vector6;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    #[allow(non_snake_case)]
    fn exact_on_noise_free_data() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for n in [5, 6, 10, 50] {
            for _ in 0..20 {
                let T_c_w = se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-0.5..0.5)));
                let points_c: Vec<Vector3<f64>> = (0..n)
                    .map(|_| {
                        Vector3::new(
                            rng.random_range(-2.0..2.0),
                            rng.random_range(-2.0..2.0),
                            rng.random_range(1.0..6.0),
                        )
                    })
                    .collect();
                let points_w: Vec<_> = points_c
                    .iter()
                    .map(|p| T_c_w.inverse_transform_vector(&(p - T_c_w.translation.vector)))
                    .collect();
                let rays: Vec<_> = points_c.iter().map(|p| p / p.z).collect();
                let est = epnp(&points_w, &rays).expect("general position");
                assert_relative_eq!(est, T_c_w, epsilon = 1e-6);
            }
        }
    }

    #[test]
    fn least_squares_matches_the_normal_equations_and_refuses_rank_deficiency() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let a = DMatrix::from_fn(6, 4, |_, _| rng.random_range(-1.0..1.0));
        let b = DVector::from_fn(6, |_, _| rng.random_range(-1.0..1.0));
        let x = least_squares(a.clone(), &b).expect("full column rank");
        let normal = (a.transpose() * &a)
            .lu()
            .solve(&(a.transpose() * &b))
            .unwrap();
        assert_relative_eq!(x, normal, epsilon = 1e-10);
        let mut deficient = a.clone();
        let first = deficient.column(0).into_owned();
        deficient.set_column(3, &(first * 2.0));
        assert!(least_squares(deficient, &b).is_none());
    }

    #[test]
    fn rejects_bad_input() {
        let p = [Vector3::x(), Vector3::y(), Vector3::z(), Vector3::zeros()];
        let r = [Vector3::new(0.0, 0.0, 1.0); 4];
        assert!(epnp(&p[..3], &r[..3]).is_none());
        assert!(epnp(&p, &r[..3]).is_none());
        let planar = [
            Vector3::x(),
            Vector3::y(),
            Vector3::new(1.0, 1.0, 0.0),
            Vector3::zeros(),
        ];
        assert!(epnp(&planar, &r).is_none());
        assert!(epnp(&p, &[Vector3::new(0.0, 0.0, -1.0); 4]).is_none());
    }
}
