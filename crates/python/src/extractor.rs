//! `OrbExtractor`: the core's whole ORB extractor, one GIL-free call per image or stereo pair,
//! each image with an optional keypoint mask.

use crate::pool;
use ferroslam_features::extractor::FastThresholds;
use ferroslam_features::{
    check_mask_size, image_circle_mask, Features, FeaturesError, GrayImage, ImagePyramid,
    OrbConfig, OrbExtractor,
};
use numpy::ndarray::Array2;
use numpy::PyArray2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert;
use crate::errors::features_to_py;
use crate::rig_frame;

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

/// An image as [`convert::gray_image`] gives it: `(width, height, pixels)`.
type Pixels = (usize, usize, Vec<u8>);

/// A keypoint mask (see [`rig_frame::mask_pixels`]); `None` when none is given.
fn mask_pixels(obj: Option<&Bound<'_, PyAny>>, name: &str) -> PyResult<Option<Pixels>> {
    obj.filter(|o| !o.is_none())
        .map(|o| rig_frame::mask_pixels(o, name))
        .transpose()
}

/// A `ValueError` naming `name` unless `mask` is the size of `image` (checked before the
/// GIL-free call, so a stereo pair's message says which mask).
fn check_mask(image: &Pixels, mask: &Option<Pixels>, name: &str) -> PyResult<()> {
    let Some((mw, mh, mask)) = mask else {
        return Ok(());
    };
    let (iw, ih, pixels) = image;
    let image = GrayImage::new(*iw, *ih, pixels).map_err(features_to_py)?;
    GrayImage::new(*mw, *mh, mask)
        .and_then(|mask| check_mask_size(&image, &mask))
        .map_err(|err| PyValueError::new_err(format!("{name}: {err}")))
}

/// A borrowed view of a checked mask.
fn mask_view(mask: &Option<Pixels>) -> Result<Option<GrayImage<'_>>, FeaturesError> {
    mask.as_ref()
        .map(|(w, h, pixels)| GrayImage::new(*w, *h, pixels))
        .transpose()
}

/// `features` as numpy arrays.
fn arrays(py: Python<'_>, features: Features) -> FeatureArrays<'_> {
    let n = features.keypoints.len();
    let descriptors = Array2::from_shape_fn((n, 32), |(i, b)| features.descriptors[i][b]);
    (
        convert::keypoint_array(py, &features.keypoints),
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
    /// descriptors (N, 32) uint8, pyramid)` of a `(H, W)` uint8 grey image; with a `mask`
    /// (`(H, W)` uint8 or bool), no keypoint where it is 0.
    #[pyo3(signature = (image, mask = None))]
    fn extract<'py>(
        &self,
        py: Python<'py>,
        image: &Bound<'py, PyAny>,
        mask: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<FeatureArrays<'py>> {
        let image = convert::gray_image(image, "image")?;
        let mask = mask_pixels(mask, "mask")?;
        check_mask(&image, &mask, "mask")?;
        let features = pool::detach(py, || {
            let (w, h, pixels) = &image;
            let image = GrayImage::new(*w, *h, pixels)?;
            self.0.extract(&image, mask_view(&mask)?.as_ref())
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

    /// `extract` of both images of a stereo pair, in parallel, in one call, each with its
    /// own optional mask.
    #[pyo3(signature = (left, right, left_mask = None, right_mask = None))]
    fn extract_stereo<'py>(
        &self,
        py: Python<'py>,
        left: &Bound<'py, PyAny>,
        right: &Bound<'py, PyAny>,
        left_mask: Option<&Bound<'py, PyAny>>,
        right_mask: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(FeatureArrays<'py>, FeatureArrays<'py>)> {
        let left = convert::gray_image(left, "left")?;
        let right = convert::gray_image(right, "right")?;
        let left_mask = mask_pixels(left_mask, "left_mask")?;
        let right_mask = mask_pixels(right_mask, "right_mask")?;
        check_mask(&left, &left_mask, "left_mask")?;
        check_mask(&right, &right_mask, "right_mask")?;
        let features = pool::detach(py, || {
            let ((lw, lh, left), (rw, rh, right)) = (&left, &right);
            let left = GrayImage::new(*lw, *lh, left)?;
            let right = GrayImage::new(*rw, *rh, right)?;
            let (left_mask, right_mask) = (mask_view(&left_mask)?, mask_view(&right_mask)?);
            self.0
                .extract_stereo(&left, &right, left_mask.as_ref(), right_mask.as_ref())
        })?;
        let (left, right) = features.map_err(features_to_py)?;
        Ok((arrays(py, left), arrays(py, right)))
    }

    /// A `(height, width)` uint8 mask, 255 inside a fisheye's image circle (centre and radius
    /// in pixels) `margin_px` inside its edge, 0 elsewhere (`ferroslam_features::image_circle_mask`).
    #[staticmethod]
    fn image_circle_mask<'py>(
        py: Python<'py>,
        width: usize,
        height: usize,
        centre_x_px: f64,
        centre_y_px: f64,
        radius_px: f64,
        margin_px: f64,
    ) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let mask = image_circle_mask(
            width,
            height,
            centre_x_px,
            centre_y_px,
            radius_px,
            margin_px,
        )
        .map_err(features_to_py)?;
        let pixels = Array2::from_shape_vec((height, width), mask.into_pixels())
            .unwrap_or_else(|_| unreachable!("a mask holds width x height pixels"));
        Ok(PyArray2::from_owned_array(py, pixels))
    }

    fn __repr__(&self) -> String {
        let c = self.0.config();
        format!(
            "OrbExtractor(n_features={}, scale_factor={}, n_levels={}, ini_fast={}, min_fast={})",
            c.n_features, c.scale_factor, c.n_levels, c.fast.initial, c.fast.min
        )
    }
}
