//! Isotropic-per-axis normalisation of pixel sets before the linear (DLT) solvers, as in
//! Hartley's normalised 8-point algorithm (ORB-SLAM's variant: unit mean absolute
//! deviation per axis).

use nalgebra::{Matrix3, Vector2};

/// Pixels mapped so that each axis has zero mean and unit mean absolute deviation, with
/// the transform `t` doing it: `normalized[i] = t * [pixels[i]; 1]`.
pub(super) struct Normalized {
    pub points: Vec<Vector2<f64>>,
    pub t: Matrix3<f64>,
}

/// Normalises `pixels`. `None` if the set is empty, not finite, or has no spread along an
/// axis (all x or all y equal): no homography or fundamental matrix is defined then.
pub(super) fn normalize(pixels: &[Vector2<f64>]) -> Option<Normalized> {
    let n = pixels.len() as f64;
    let mean = pixels.iter().sum::<Vector2<f64>>() / n;
    let deviation = pixels
        .iter()
        .map(|p| (p - mean).abs())
        .sum::<Vector2<f64>>()
        / n;
    let scale = deviation.map(|d| 1.0 / d);
    if !(scale.iter().all(|s| s.is_finite() && *s > 0.0) && mean.iter().all(|m| m.is_finite())) {
        return None;
    }
    let points = pixels
        .iter()
        .map(|p| (p - mean).component_mul(&scale))
        .collect();
    #[rustfmt::skip]
    let t = Matrix3::new(
        scale.x, 0.0, -mean.x * scale.x,
        0.0, scale.y, -mean.y * scale.y,
        0.0, 0.0, 1.0,
    );
    Some(Normalized { points, t })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn zero_mean_unit_deviation_and_matching_transform() {
        let pixels = [
            Vector2::new(10.0, 200.0),
            Vector2::new(30.0, 180.0),
            Vector2::new(70.0, 260.0),
        ];
        let n = normalize(&pixels).unwrap();
        let mean = n.points.iter().sum::<Vector2<f64>>() / 3.0;
        assert_relative_eq!(mean, Vector2::zeros(), epsilon = 1e-12);
        let dev = n.points.iter().map(|p| p.abs()).sum::<Vector2<f64>>() / 3.0;
        assert_relative_eq!(dev, Vector2::new(1.0, 1.0), epsilon = 1e-12);
        for (p, q) in pixels.iter().zip(&n.points) {
            assert_relative_eq!((n.t * p.push(1.0)).xy(), *q, epsilon = 1e-12);
        }
    }

    #[test]
    fn refuses_degenerate_sets() {
        assert!(normalize(&[]).is_none());
        assert!(normalize(&[Vector2::new(1.0, 2.0); 10]).is_none());
        assert!(normalize(&[Vector2::new(1.0, 2.0), Vector2::new(1.0, 5.0)]).is_none());
        assert!(normalize(&[Vector2::new(f64::NAN, 2.0), Vector2::new(1.0, 5.0)]).is_none());
    }
}
