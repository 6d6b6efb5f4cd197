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
    Ok(())
}
