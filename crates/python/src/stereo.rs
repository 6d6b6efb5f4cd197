//! `match_stereo`: the core's stereo matcher on its own, for inspection and tests.

use crate::pool;
use ferroslam_features::{match_stereo as core_match_stereo, ScalePyramid, StereoView};
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert;
use crate::errors::features_to_py;

/// `(u_right (N,), depth_m (N,))` float32 arrays.
type StereoArrays<'py> = (Bound<'py, PyArray1<f32>>, Bound<'py, PyArray1<f32>>);

/// Matches left keypoints into the right image of a rectified pair (ORB-SLAM2's stereo
/// matching: row band, octave, Hamming distance, SAD refinement on the pyramid level).
///
/// Returns `(u_right (N,), depth_m (N,))` float32, -1 where a keypoint has no match.
#[pyfunction]
#[pyo3(signature = (left_keypoints, left_descriptors, left_pyramid, right_keypoints,
                    right_descriptors, right_pyramid, *, fx, baseline, scale_factor = 1.2))]
#[allow(clippy::too_many_arguments)]
pub fn match_stereo<'py>(
    py: Python<'py>,
    left_keypoints: &Bound<'py, PyAny>,
    left_descriptors: &Bound<'py, PyAny>,
    left_pyramid: &Bound<'py, PyAny>,
    right_keypoints: &Bound<'py, PyAny>,
    right_descriptors: &Bound<'py, PyAny>,
    right_pyramid: &Bound<'py, PyAny>,
    fx: f64,
    baseline: f64,
    scale_factor: f64,
) -> PyResult<StereoArrays<'py>> {
    if !(fx.is_finite() && fx > 0.0 && baseline.is_finite() && baseline > 0.0) {
        return Err(PyValueError::new_err(format!(
            "fx and baseline must be positive, got fx = {fx}, baseline = {baseline}"
        )));
    }
    let (lk, ld) = convert::features(left_keypoints, left_descriptors, "left")?;
    let (rk, rd) = convert::features(right_keypoints, right_descriptors, "right")?;
    let (lp, rp) = (
        convert::pyramid(left_pyramid, "left_pyramid")?,
        convert::pyramid(right_pyramid, "right_pyramid")?,
    );
    for (l, (left, right)) in lp.iter().zip(&rp).enumerate() {
        if (left.0, left.1) != (right.0, right.1) {
            return Err(PyValueError::new_err(format!(
                "left_pyramid[{l}] is {}x{} but right_pyramid[{l}] is {}x{} (width x height): \
                 a rectified pair has images of one size",
                left.0, left.1, right.0, right.1
            )));
        }
    }
    let too_high =
        |k: &[ferroslam_features::Keypoint], n: usize| k.iter().any(|k| k.octave as usize >= n);
    if too_high(&lk, lp.len()) || too_high(&rk, rp.len()) {
        return Err(PyValueError::new_err(
            "keypoint octaves exceed the number of pyramid levels given",
        ));
    }
    let pyramid =
        ScalePyramid::new(scale_factor, lp.len().max(rp.len())).map_err(features_to_py)?;
    let views = (convert::views(&lp), convert::views(&rp));
    let (li, ri) = match views {
        (Ok(l), Ok(r)) => (l, r),
        (Err(e), _) | (_, Err(e)) => return Err(features_to_py(e)),
    };
    let left = StereoView {
        keypoints: &lk,
        descriptors: &ld,
        levels: &li,
    };
    let right = StereoView {
        keypoints: &rk,
        descriptors: &rd,
        levels: &ri,
    };
    let matches = pool::detach(py, || {
        core_match_stereo(&left, &right, &pyramid, fx * baseline, fx)
    })?;
    let (u, z): (Vec<f32>, Vec<f32>) = matches
        .iter()
        .map(|m| m.map_or((-1.0, -1.0), |m| (m.u_right, m.depth_m)))
        .unzip();
    Ok((PyArray1::from_vec(py, u), PyArray1::from_vec(py, z)))
}
