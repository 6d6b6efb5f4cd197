//! `OrbExtractor`: the core's whole ORB extractor, one GIL-free call per image or stereo pair.

use crate::pool;
use ferroslam_features::extractor::FastThresholds;
use ferroslam_features::{
    Features, FeaturesError, GrayImage, ImagePyramid, OrbConfig, OrbExtractor,
};
use numpy::ndarray::Array2;
use numpy::PyArray2;
use pyo3::prelude::*;

use crate::convert;
use crate::errors::features_to_py;

/// `(keypoints (N, 5) float32, descriptors (N, 32) uint8, pyramid [2-D uint8 arrays])`.
type FeatureArrays<'py> = (
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray2<u8>>,
    Vec<Bound<'py, PyArray2<u8>>>,
);

/// ORB-SLAM's ORB extractor with OpenCV's descriptors, all in the core.
#[pyclass(name = "OrbExtractor", module = "ferroslam._core", frozen)]
pub struct PyOrbExtractor(OrbExtractor);

/// `value` of setting `name` as a `T` (`default` when not given), or the error naming it.
fn setting_or<T: TryFrom<i64>>(
    name: &str,
    value: Option<i64>,
    default: T,
) -> Result<T, FeaturesError> {
    let Some(value) = value else {
        return Ok(default);
    };
    T::try_from(value)
        .map_err(|_| FeaturesError::InvalidOrbConfig(format!("{name} = {value} is out of range")))
}

/// The levels of `pyramid` as 2-D uint8 arrays (their pixels moved, not copied).
fn level_arrays(py: Python<'_>, pyramid: ImagePyramid) -> Vec<Bound<'_, PyArray2<u8>>> {
    pyramid
        .into_levels()
        .into_iter()
        .map(|level| {
            let (w, h) = (level.view().width(), level.view().height());
            let pixels = Array2::from_shape_vec((h, w), level.into_pixels())
                .unwrap_or_else(|_| unreachable!("a level holds width x height pixels"));
            PyArray2::from_owned_array(py, pixels)
        })
        .collect()
}

/// `features` as numpy arrays.
fn arrays(py: Python<'_>, features: Features) -> FeatureArrays<'_> {
    let n = features.keypoints.len();
    let keypoints = Array2::from_shape_fn((n, 5), |(i, c)| {
        let k = &features.keypoints[i];
        [k.x, k.y, f32::from(k.octave), k.angle_deg, k.response][c]
    });
    let descriptors = Array2::from_shape_fn((n, 32), |(i, b)| features.descriptors[i][b]);
    (
        PyArray2::from_owned_array(py, keypoints),
        PyArray2::from_owned_array(py, descriptors),
        level_arrays(py, features.pyramid),
    )
}

#[pymethods]
impl PyOrbExtractor {
    /// Settings as ORB-SLAM's `ORBextractor` takes them; one left out (`None`) takes the
    /// core's default (`OrbConfig::default`). A `ValueError` names an invalid one.
    #[new]
    #[pyo3(signature = (*, n_features = None, scale_factor = None, n_levels = None,
                        ini_fast = None, min_fast = None))]
    fn new(
        n_features: Option<i64>,
        scale_factor: Option<f64>,
        n_levels: Option<i64>,
        ini_fast: Option<i64>,
        min_fast: Option<i64>,
    ) -> PyResult<Self> {
        let config = || -> Result<OrbConfig, FeaturesError> {
            let d = OrbConfig::default();
            Ok(OrbConfig {
                n_features: setting_or("n_features", n_features, d.n_features)?,
                scale_factor: scale_factor.unwrap_or(d.scale_factor),
                n_levels: setting_or("n_levels", n_levels, d.n_levels)?,
                fast: FastThresholds {
                    initial: setting_or("ini_fast", ini_fast, d.fast.initial)?,
                    min: setting_or("min_fast", min_fast, d.fast.min)?,
                },
            })
        };
        config()
            .and_then(OrbExtractor::new)
            .map(Self)
            .map_err(features_to_py)
    }

    /// Keypoints wanted per image.
    #[getter]
    fn n_features(&self) -> usize {
        self.0.config().n_features
    }

    /// Scale between neighbouring pyramid levels.
    #[getter]
    fn scale_factor(&self) -> f64 {
        self.0.config().scale_factor
    }

    /// Pyramid levels.
    #[getter]
    fn n_levels(&self) -> usize {
        self.0.config().n_levels
    }

    /// FAST threshold tried first in every grid cell.
    #[getter]
    fn ini_fast(&self) -> u8 {
        self.0.config().fast.initial
    }

    /// FAST threshold of the cells where `ini_fast` finds no corner.
    #[getter]
    fn min_fast(&self) -> u8 {
        self.0.config().fast.min
    }

    /// Keypoints wanted per pyramid level, finest first (they sum to n_features).
    #[getter]
    fn level_budgets(&self) -> Vec<usize> {
        self.0.level_budgets().to_vec()
    }

    /// `(keypoints (N, 5) float32 [x, y, octave, angle_deg, response] in raw level-0 pixels,
    /// descriptors (N, 32) uint8, pyramid)` of a `(H, W)` uint8 grey image.
    fn extract<'py>(
        &self,
        py: Python<'py>,
        image: &Bound<'py, PyAny>,
    ) -> PyResult<FeatureArrays<'py>> {
        let (w, h, pixels) = convert::gray_image(image, "image")?;
        let features = pool::detach(py, || {
            let image = GrayImage::new(w, h, &pixels)?;
            self.0.extract(&image)
        })?;
        Ok(arrays(py, features.map_err(features_to_py)?))
    }

    /// The image pyramid of a `(H, W)` uint8 grey image alone, finest (a copy of the image)
    /// first.
    fn pyramid<'py>(
        &self,
        py: Python<'py>,
        image: &Bound<'py, PyAny>,
    ) -> PyResult<Vec<Bound<'py, PyArray2<u8>>>> {
        let (w, h, pixels) = convert::gray_image(image, "image")?;
        let c = self.0.config();
        let pyramid = pool::detach(py, || {
            let image = GrayImage::new(w, h, &pixels)?;
            ImagePyramid::build(&image, c.scale_factor, c.n_levels)
        })?;
        Ok(level_arrays(py, pyramid.map_err(features_to_py)?))
    }

    /// `extract` of both images of a stereo pair, in parallel, in one call.
    fn extract_stereo<'py>(
        &self,
        py: Python<'py>,
        left: &Bound<'py, PyAny>,
        right: &Bound<'py, PyAny>,
    ) -> PyResult<(FeatureArrays<'py>, FeatureArrays<'py>)> {
        let (lw, lh, left) = convert::gray_image(left, "left")?;
        let (rw, rh, right) = convert::gray_image(right, "right")?;
        let features = pool::detach(py, || {
            let left = GrayImage::new(lw, lh, &left)?;
            let right = GrayImage::new(rw, rh, &right)?;
            self.0.extract_stereo(&left, &right)
        })?;
        let (left, right) = features.map_err(features_to_py)?;
        Ok((arrays(py, left), arrays(py, right)))
    }

    fn __repr__(&self) -> String {
        let c = self.0.config();
        format!(
            "OrbExtractor(n_features={}, scale_factor={}, n_levels={}, ini_fast={}, min_fast={})",
            c.n_features, c.scale_factor, c.n_levels, c.fast.initial, c.fast.min
        )
    }
}
