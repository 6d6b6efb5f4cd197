//! Robust least-squares refinement of a relative pose on the Sampson epipolar error, the
//! statistically sound cost that the linear 8-point fit only approximates.

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector2, Vector3};

use crate::so3::{self, hat};

/// Levenberg-Marquardt iterations; the start is close, a few suffice.
const MAX_ITERATIONS: usize = 15;
/// Central-difference step on the 5 pose parameters (radians).
const STEP: f64 = 1e-6;

type Params = SVector<f64, 5>;

/// Rounds of re-selecting the matches to refine on.
const MAX_ROUNDS: usize = 3;
/// A match takes part in the refinement while its squared Sampson distance is below this
/// many `sigma^2` (chi-square 99%, 1 DoF): generous, so the set is not truncated to the
/// matches the initial estimate happened to fit.
const GATE_CHI2: f64 = 6.635;
/// Scale of the Cauchy loss, in `sigma`: residuals beyond it are progressively ignored, so a
/// few outliers that slipped past the gate cannot bend a weakly constrained translation.
const CAUCHY_SCALE: f64 = 2.0;

/// `(R, t)` (`p_c2 = R p_c1 + t`, `|t| = 1`) minimising the Cauchy loss (scale `2 sigma`)
/// of the Sampson distances (pixels) of matches `(pixels1[i], pixels2[i])` under the
/// fundamental matrix `K^-T [t]x R K^-1` of intrinsics `k`.
///
/// The first round uses the matches `initial`; later rounds use every match within
/// `sqrt(6.635) * sigma` of the current estimate, until the set stops changing. Returns
/// the start unchanged if it cannot improve it (too few matches, non-finite data).
pub(super) fn refine_essential(
    r: &UnitQuaternion<f64>,
    t: &Vector3<f64>,
    k: &Matrix3<f64>,
    pixels1: &[Vector2<f64>],
    pixels2: &[Vector2<f64>],
    initial: &[usize],
    sigma: f64,
) -> (UnitQuaternion<f64>, Vector3<f64>) {
    let Some(k_inv) = k.try_inverse() else {
        return (*r, *t);
    };
    let (mut r, mut t) = (*r, t.normalize());
    let mut indices = initial.to_vec();
    for _ in 0..MAX_ROUNDS {
        (r, t) = minimize(
            &r,
            &t,
            &k_inv,
            pixels1,
            pixels2,
            &indices,
            CAUCHY_SCALE * sigma,
        );
        let f = fundamental(&r, &t, &k_inv);
        let gated: Vec<usize> = (0..pixels1.len())
            .filter(|&i| {
                sampson_distance(&f, &pixels1[i], &pixels2[i]).powi(2) < GATE_CHI2 * sigma * sigma
            })
            .collect();
        if gated == indices {
            break;
        }
        indices = gated;
    }
    (r, t)
}

/// `K^-T [t]x R K^-1`.
fn fundamental(r: &UnitQuaternion<f64>, t: &Vector3<f64>, k_inv: &Matrix3<f64>) -> Matrix3<f64> {
    k_inv.transpose() * hat(t) * r.to_rotation_matrix().matrix() * k_inv
}

/// Levenberg-Marquardt on the Cauchy loss `c^2 ln(1 + e^2 / c^2)` of the Sampson
/// distances `e` of `indices` (reweighted Gauss-Newton normal equations), five parameters:
/// a left rotation increment and two directions orthogonal to `t` (the scale is
/// unobservable).
fn minimize(
    r: &UnitQuaternion<f64>,
    t: &Vector3<f64>,
    k_inv: &Matrix3<f64>,
    pixels1: &[Vector2<f64>],
    pixels2: &[Vector2<f64>],
    indices: &[usize],
    c: f64,
) -> (UnitQuaternion<f64>, Vector3<f64>) {
    let (mut r, mut t) = (*r, *t);
    if indices.len() < 5 || !t.iter().all(|v| v.is_finite()) {
        return (r, t);
    }
    // Pose after the increment `d` (rotation increment, then tangent move of t).
    let apply = |r: &UnitQuaternion<f64>, t: &Vector3<f64>, d: &Params| {
        let (b1, b2) = tangent_basis(t);
        let r_new = so3::exp(&Vector3::new(d[0], d[1], d[2])) * r;
        (r_new, (t + b1 * d[3] + b2 * d[4]).normalize())
    };
    let residuals = |r: &UnitQuaternion<f64>, t: &Vector3<f64>| -> Vec<f64> {
        let f = fundamental(r, t, k_inv);
        indices
            .iter()
            .map(|&i| sampson_distance(&f, &pixels1[i], &pixels2[i]))
            .collect()
    };
    let cost = |res: &[f64]| {
        res.iter()
            .map(|e| c * c * (e * e / (c * c)).ln_1p())
            .sum::<f64>()
    };
    let mut current = residuals(&r, &t);
    if !current.iter().all(|e| e.is_finite()) {
        return (r, t);
    }
    let mut lambda = 1e-3;
    for _ in 0..MAX_ITERATIONS {
        // Numerical Jacobian, one column per parameter.
        let mut jacobian = vec![Params::zeros(); current.len()];
        for p in 0..5 {
            let mut d = Params::zeros();
            d[p] = STEP;
            let (rp, tp) = apply(&r, &t, &d);
            let (rm, tm) = apply(&r, &t, &(-d));
            for (row, (ep, em)) in jacobian
                .iter_mut()
                .zip(residuals(&rp, &tp).iter().zip(residuals(&rm, &tm)))
            {
                row[p] = (ep - em) / (2.0 * STEP);
            }
        }
        let mut h = SMatrix::<f64, 5, 5>::zeros();
        let mut g = Params::zeros();
        for (j, e) in jacobian.iter().zip(&current) {
            let w = 1.0 / (1.0 + e * e / (c * c));
            h += j * j.transpose() * w;
            g += j * (w * e);
        }
        let mut improved = false;
        while lambda < 1e8 {
            let damped = h + SMatrix::<f64, 5, 5>::from_diagonal(&h.diagonal()) * lambda;
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            let (rn, tn) = apply(&r, &t, &step);
            let next = residuals(&rn, &tn);
            if next.iter().all(|e| e.is_finite()) && cost(&next) < cost(&current) {
                let converged = cost(&current) - cost(&next) < 1e-10 * cost(&current);
                (r, t, current) = (rn, tn, next);
                lambda = (lambda * 0.1).max(1e-9);
                improved = !converged;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (r, t)
}

/// Sampson distance (pixels, signed) of a match under `f`: the first-order distance of
/// `(x1, x2)` to the nearest pair satisfying the epipolar constraint.
fn sampson_distance(f: &Matrix3<f64>, p1: &Vector2<f64>, p2: &Vector2<f64>) -> f64 {
    let (x1, x2) = (p1.push(1.0), p2.push(1.0));
    let (l2, l1) = (f * x1, f.transpose() * x2);
    x2.dot(&l2) / (l2.xy().norm_squared() + l1.xy().norm_squared()).sqrt()
}

/// Two unit vectors orthogonal to `t` and to each other.
fn tangent_basis(t: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if t.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let b1 = t.cross(&helper).normalize();
    (b1, t.cross(&b1).normalize())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_a_perturbed_pose_back_to_the_exact_one() {
        let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0);
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.02, -0.1, 0.03));
        let t = Vector3::new(0.8, 0.1, 0.3).normalize();
        let points: Vec<Vector3<f64>> = (0..60)
            .map(|i| {
                let i = i as f64;
                Vector3::new(
                    (i * 0.37).sin() * 3.0,
                    (i * 1.3).cos() * 2.0,
                    4.0 + (i * 0.7) % 5.0,
                )
            })
            .collect();
        let project = |p: Vector3<f64>| (k * p).xy() / p.z;
        let p1: Vec<_> = points.iter().map(|p| project(*p)).collect();
        let p2: Vec<_> = points.iter().map(|p| project(r * p + t)).collect();
        let start_r = UnitQuaternion::from_scaled_axis(Vector3::new(0.01, 0.01, -0.01)) * r;
        let start_t = (t + Vector3::new(0.0, 0.1, -0.1)).normalize();
        let indices: Vec<usize> = (0..60).collect();
        let (r_hat, t_hat) = refine_essential(&start_r, &start_t, &k, &p1, &p2, &indices, 1.0);
        assert!(r_hat.angle_to(&r) < 1e-7, "{}", r_hat.angle_to(&r));
        assert!((t_hat - t).norm() < 1e-7, "{t_hat}");
    }
}
