//! The checks every camera model's constructor shares.

use crate::GeometryError;

/// Finite positive focal lengths, a finite principal point, finite distortion
/// coefficients (`names` and `values` in the model's order) and a non-empty image.
pub(super) fn check_intrinsics(
    [fx, fy, cx, cy]: [f64; 4],
    coefficients: impl IntoIterator<Item = (&'static str, f64)>,
    [width, height]: [u32; 2],
) -> Result<(), GeometryError> {
    let invalid = |name, value, reason| {
        Err(GeometryError::InvalidParameter {
            name,
            value,
            reason,
        })
    };
    for (name, value) in [("fx", fx), ("fy", fy)] {
        if !(value.is_finite() && value > 0.0) {
            return invalid(name, value, "focal length must be finite and positive");
        }
    }
    for (name, value) in [("cx", cx), ("cy", cy)] {
        if !value.is_finite() {
            return invalid(name, value, "principal point must be finite");
        }
    }
    for (name, value) in coefficients {
        if !value.is_finite() {
            return invalid(name, value, "distortion coefficients must be finite");
        }
    }
    for (name, value) in [("width", width), ("height", height)] {
        if value == 0 {
            return invalid(name, 0.0, "image size must be positive");
        }
    }
    for (name, value, size) in [("cx", cx, width), ("cy", cy, height)] {
        if !(0.0..=f64::from(size)).contains(&value) {
            return invalid(
                name,
                value,
                "principal point must lie inside the image (0 to width / height pixels)",
            );
        }
    }
    Ok(())
}

/// Largest factor by which distortion may scale a radius inside the image (either way).
/// Real lenses stay far inside it: at the farthest image corner EuRoC's cam0 scales the
/// radius by 0.80, TUM fr1 by 1.07, the T265 fisheye (Kannala-Brandt) by 0.99;
/// `k1 = 100` scales it by 16 and more, a fold-free but meaningless image.
pub const MAX_DISTORTION_SCALE: f64 = 3.0;
/// Samples of the radius between the centre and the farthest corner.
const MONOTONIC_SAMPLES: usize = 1000;

/// Distortion that keeps the image one-to-one and plausible over the image area: the
/// distorted radius `distorted(r)` (normalized units: the pinhole's `r`, the fisheye's
/// incidence angle) must strictly increase from the centre until it reaches the farthest
/// image corner's radius `corner` (normalized), scaling the radius by at most
/// [`MAX_DISTORTION_SCALE`] on the way. `max_r` is where the model's field of view ends
/// (infinite for the pinhole; the fisheye's last incidence angle, beyond which pixels do
/// not unproject: a fisheye's image circle may end before the corners). `terms(r)` gives
/// each coefficient's name, value and contribution at `r`: the error names the largest.
pub(super) fn check_monotonic_over_image(
    distorted: impl Fn(f64) -> f64,
    terms: impl Fn(f64) -> Vec<(&'static str, f64, f64)>,
    corner: f64,
    max_r: f64,
) -> Result<(), GeometryError> {
    let blame = |r: f64, reason| {
        let mut terms = terms(r);
        terms.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
        let (name, value, _) = terms[0];
        Err(GeometryError::InvalidParameter {
            name,
            value,
            reason,
        })
    };
    let step = corner / MONOTONIC_SAMPLES as f64;
    let mut previous = 0.0;
    // Ends: by the scale bound, `r_d >= corner` once `r >= 3 * corner`.
    for i in 1usize.. {
        let r = (step * i as f64).min(max_r);
        let r_d = distorted(r);
        // NaN fails the test too: `partial_cmp` is None then.
        if r_d.partial_cmp(&previous) != Some(std::cmp::Ordering::Greater) {
            return blame(
                r,
                "the distortion folds the image over inside the image area (the distorted \
                 radius stops increasing before the farthest corner)",
            );
        }
        let scale = r_d / r;
        if !(1.0 / MAX_DISTORTION_SCALE..=MAX_DISTORTION_SCALE).contains(&scale) {
            return blame(
                r,
                "the distortion scales radii inside the image by more than a factor 3: \
                 not a plausible lens",
            );
        }
        if r_d >= corner || r >= max_r {
            return Ok(());
        }
        previous = r_d;
    }
    unreachable!("the scan ends by r = 3 * corner")
}

/// The farthest image corner's distance from the principal point in normalized units
/// (pixels divided by the focal lengths).
pub(super) fn corner_radius([fx, fy, cx, cy]: [f64; 4], [width, height]: [u32; 2]) -> f64 {
    let (w, h) = (f64::from(width), f64::from(height));
    let dx = cx.max(w - cx) / fx;
    let dy = cy.max(h - cy) / fy;
    dx.hypot(dy)
}
