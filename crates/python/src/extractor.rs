//! `detect_orb_corners`: ORB-SLAM's per-level keypoint detection, for the Python extractor.

use ferroslam_features::extractor::{detect_pyramid, FastThresholds};
use numpy::ndarray::Array2;
use numpy::PyArray2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert;

/// FAST corners on every pyramid level, the per-cell threshold fallback, the even spread to
/// each level's budget and the intensity-centroid orientation (ORB-SLAM's `ORBextractor`
/// without the descriptors).
///
/// Returns `(N, 5)` float32 rows `[x, y, level, angle_deg, score]` in LEVEL pixels, grouped
/// by level, each level in spread order.
#[pyfunction]
#[pyo3(signature = (levels, budgets, *, ini_fast, min_fast))]
pub fn detect_orb_corners<'py>(
    py: Python<'py>,
    levels: &Bound<'py, PyAny>,
    budgets: Vec<usize>,
    ini_fast: u8,
    min_fast: u8,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    if !(0 < min_fast && min_fast <= ini_fast) {
        return Err(PyValueError::new_err(format!(
            "need 0 < min_fast <= ini_fast, got min_fast = {min_fast}, ini_fast = {ini_fast}"
        )));
    }
    let pixels = convert::pyramid(levels, "levels")?;
    if budgets.len() != pixels.len() {
        return Err(PyValueError::new_err(format!(
            "budgets ({}) must give one count per level ({})",
            budgets.len(),
            pixels.len()
        )));
    }
    let views = convert::views(&pixels).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let fast = FastThresholds {
        initial: ini_fast,
        min: min_fast,
    };
    let per_level = py.detach(|| detect_pyramid(&views, &budgets, fast));
    let n = per_level.iter().map(Vec::len).sum();
    let mut rows = Array2::<f32>::zeros((n, 5));
    let all = per_level
        .iter()
        .enumerate()
        .flat_map(|(l, corners)| corners.iter().map(move |c| (l, c)));
    for (mut row, (l, c)) in rows.rows_mut().into_iter().zip(all) {
        let values = [
            c.corner.x as f32,
            c.corner.y as f32,
            l as f32,
            c.angle_deg,
            c.corner.score,
        ];
        row.iter_mut().zip(values).for_each(|(o, v)| *o = v);
    }
    Ok(PyArray2::from_owned_array(py, rows))
}
