//! The Python extractor's core: `detect_orb_corners` (ORB-SLAM's per-level keypoint detection)
//! and `BriefPattern` (the rotated BRIEF descriptors).

use ferroslam_features::extractor::brief::{BriefPattern, BriefTest};
use ferroslam_features::extractor::{detect_pyramid, FastThresholds};
use numpy::ndarray::Array2;
use numpy::{PyArray2, PyReadonlyArray2};
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
    budgets: &Bound<'py, PyAny>,
    ini_fast: u8,
    min_fast: u8,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let budgets: Vec<usize> = budgets.extract().map_err(|_| {
        PyValueError::new_err(format!(
            "budgets must be a list of keypoint counts >= 0, one per level, got {budgets}"
        ))
    })?;
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

/// ORB's rotated BRIEF with a given set of 256 tests (`OrbExtractor` reads OpenCV's off
/// `cv2.ORB`, so that the descriptors are OpenCV's bit for bit).
#[pyclass(name = "BriefPattern", module = "ferroslam._core", frozen)]
pub struct PyBriefPattern(BriefPattern);

#[pymethods]
impl PyBriefPattern {
    /// `tests`: `(256, 4)` int32 rows `[x1, y1, x2, y2]`, bit `k` of byte `i` being
    /// `I(x1, y1) < I(x2, y2)` of row `8 i + k` (offsets in pixels, at most 31 from the centre).
    #[new]
    fn new(tests: &Bound<'_, PyAny>) -> PyResult<Self> {
        let arr: PyReadonlyArray2<'_, i32> =
            convert::array(tests, "tests", "an int32 (256, 4) array")?;
        let a = arr.as_array();
        if a.shape() != [256, 4] {
            return Err(PyValueError::new_err(format!(
                "tests must have shape (256, 4), got {:?}",
                a.shape()
            )));
        }
        let offset = |v: i32| {
            i8::try_from(v)
                .ok()
                .filter(|o| o.unsigned_abs() <= 31)
                .ok_or_else(|| {
                    PyValueError::new_err(format!("test offset {v} is not in [-31, 31]"))
                })
        };
        let mut tests = [BriefTest {
            first: [0; 2],
            second: [0; 2],
        }; 256];
        for (test, row) in tests.iter_mut().zip(a.rows()) {
            *test = BriefTest {
                first: [offset(row[0])?, offset(row[1])?],
                second: [offset(row[2])?, offset(row[3])?],
            };
        }
        Ok(Self(BriefPattern::new(&tests)))
    }

    /// Descriptors `(N, 32)` uint8 of `keypoints` (`(N, 5)` float32 rows `[x, y, level,
    /// angle_deg, score]` in LEVEL pixels, as `detect_orb_corners` gives them) on the
    /// `smoothed` pyramid (each level Gaussian-smoothed as ORB smooths it).
    fn describe<'py>(
        &self,
        py: Python<'py>,
        smoothed: &Bound<'py, PyAny>,
        keypoints: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let pixels = convert::pyramid(smoothed, "smoothed")?;
        let views = convert::views(&pixels).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let kp: PyReadonlyArray2<'_, f32> =
            convert::array(keypoints, "keypoints", "a float32 (N, 5) array")?;
        let kp = kp.as_array();
        if kp.ncols() != 5 {
            return Err(PyValueError::new_err(format!(
                "keypoints must have shape (N, 5), got {:?}",
                kp.shape()
            )));
        }
        let pixel = |v: f32| (v.is_finite() && v >= 0.0 && v.fract() == 0.0).then_some(v as usize);
        let corners = kp
            .rows()
            .into_iter()
            .enumerate()
            .map(
                |(i, r)| match (pixel(r[2]), pixel(r[0]), pixel(r[1]), r[3].is_finite()) {
                    (Some(l), Some(x), Some(y), true) => Ok((l, x, y, r[3])),
                    _ => Err(PyValueError::new_err(format!(
                        "keypoints row {i}: level, x and y must be non-negative integers and the \
                     angle finite, got {:?}",
                        r.to_vec()
                    ))),
                },
            )
            .collect::<PyResult<Vec<_>>>()?;
        let described = py.detach(|| self.0.describe_all(&views, &corners));
        let mut out = Array2::<u8>::zeros((corners.len(), 32));
        for (i, (mut row, d)) in out.rows_mut().into_iter().zip(described).enumerate() {
            let d = d.ok_or_else(|| {
                PyValueError::new_err(format!(
                    "keypoints row {i} has no level {} or lies closer to its border than the \
                     pattern reaches ({:.1} px)",
                    corners[i].0,
                    self.0.reach_px()
                ))
            })?;
            row.iter_mut().zip(d).for_each(|(o, v)| *o = v);
        }
        Ok(PyArray2::from_owned_array(py, out))
    }
}
