//! numpy images of one rig instant -> the core's [`RigFrame`], borrowing contiguous arrays
//! (copying the others once), for `SlamSystem.track`.

use std::borrow::Cow;

use ferroslam_slam::{CameraImage, DepthImage, Image, OwnedRigFrame, RigFrame};
use numpy::{
    PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyList, PyTuple};

use crate::convert::shape_tuple;

/// A frame borrowing the caller's contiguous arrays.
pub type FrameCow<'a> = RigFrame<Cow<'a, [u8]>, Cow<'a, [f32]>>;

/// The arrays of one `track` call, held (read-only) while the frame borrows them.
pub struct FrameArrays<'py> {
    timestamp: f64,
    images: Vec<PyReadonlyArrayDyn<'py, u8>>,
    colors: Vec<Option<PyReadonlyArrayDyn<'py, u8>>>,
    masks: Vec<Option<PyReadonlyArrayDyn<'py, u8>>>,
    depths: Vec<Option<Depth<'py>>>,
}

enum Depth<'py> {
    F32(PyReadonlyArrayDyn<'py, f32>),
    F64(PyReadonlyArrayDyn<'py, f64>),
}

/// `obj` as a list: a sequence's items, or `[obj]` for one array.
fn items<'py>(obj: &Bound<'py, PyAny>) -> Vec<Bound<'py, PyAny>> {
    if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
        obj.try_iter()
            .map(|it| it.filter_map(Result::ok).collect())
            .unwrap_or_default()
    } else {
        vec![obj.clone()]
    }
}

/// `obj` as a uint8 array of rank 2, or rank 3 with 1, 3 or 4 channels (`mask`: rank 2 of
/// uint8 or bool).
fn image_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    mask: bool,
) -> PyResult<PyReadonlyArrayDyn<'py, u8>> {
    let untyped = obj.cast::<PyUntypedArray>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name} must be a numpy array, got {}",
            obj.get_type()
                .name()
                .map_or_else(|_| "another type".into(), |n| n.to_string())
        ))
    })?;
    let shape = untyped.shape().to_vec();
    let dtype = untyped.dtype().to_string();
    let shape_ok = match shape.as_slice() {
        [h, w] => *h > 0 && *w > 0,
        [h, w, c] => !mask && *h > 0 && *w > 0 && matches!(c, 1 | 3 | 4),
        _ => false,
    };
    if !shape_ok {
        let wanted = if mask {
            "(H, W)"
        } else {
            "(H, W) grey or (H, W, 3) BGR"
        };
        return Err(PyValueError::new_err(format!(
            "{name} must be {wanted}, got shape {}",
            shape_tuple(&shape)
        )));
    }
    let as_u8 = if mask && dtype == "bool" {
        obj.call_method1("astype", ("uint8",))?
    } else if dtype != "uint8" {
        let wanted = if mask { "uint8 or bool" } else { "uint8" };
        return Err(PyValueError::new_err(format!(
            "{name} dtype must be {wanted}, got {dtype}"
        )));
    } else {
        obj.clone()
    };
    Ok(as_u8.cast::<PyArrayDyn<u8>>()?.try_readonly()?)
}

fn depth_array<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Depth<'py>> {
    let untyped = obj.cast::<PyUntypedArray>().map_err(|_| {
        PyTypeError::new_err("depth must be a numpy array of metres (H, W), float32 or float64")
    })?;
    if untyped.ndim() != 2 {
        return Err(PyValueError::new_err(format!(
            "depth must be a 2-D (H, W) array of metres, got shape {}",
            shape_tuple(untyped.shape())
        )));
    }
    if let Ok(a) = obj.cast::<PyArrayDyn<f32>>() {
        return Ok(Depth::F32(a.try_readonly()?));
    }
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        return Ok(Depth::F64(a.try_readonly()?));
    }
    Err(PyValueError::new_err(format!(
        "depth dtype must be float32 or float64 (metres), got {}",
        untyped.dtype()
    )))
}

/// A keypoint mask (0 / False = no keypoint there) as `(width, height, pixels)`: the one
/// reader of masks given apart from a frame (static masks, the extractor's); errors name it
/// `name`.
pub fn mask_pixels(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(usize, usize, Vec<u8>)> {
    let mask = image_array(obj, name, true)?;
    let view = image(&mask);
    Ok((view.width, view.height, view.data.into_owned()))
}

/// One optional array per camera: `None`, one array (one camera), or a sequence of arrays
/// or `None`s.
fn per_camera<'py>(
    obj: Option<&Bound<'py, PyAny>>,
    cameras: usize,
    name: &str,
    mask: bool,
) -> PyResult<Vec<Option<PyReadonlyArrayDyn<'py, u8>>>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok((0..cameras).map(|_| None).collect());
    };
    let given = items(obj);
    if given.len() != cameras {
        return Err(PyValueError::new_err(format!(
            "{name}: {} given for {cameras} image(s): one per image (None for none)",
            given.len()
        )));
    }
    given
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let label = if cameras == 1 {
                name.to_string()
            } else {
                format!("{name}[{i}]")
            };
            (!o.is_none())
                .then(|| image_array(o, &label, mask))
                .transpose()
        })
        .collect()
}

/// A depth array as the core's image, borrowing float32 pixels.
fn depth_image<'a>(d: &'a Depth<'_>) -> DepthImage<Cow<'a, [f32]>> {
    let (shape, data) = match d {
        Depth::F32(a) => (a.shape(), pixels(a)),
        Depth::F64(a) => (
            a.shape(),
            Cow::Owned(a.as_array().iter().map(|&v| v as f32).collect()),
        ),
    };
    DepthImage {
        width: shape[1],
        height: shape[0],
        data,
    }
}

/// `depth` of `SlamSystem.track`: `None`, one array (the first camera's), or a sequence with
/// one array or `None` per image.
fn depths<'py>(
    depth: Option<&Bound<'py, PyAny>>,
    cameras: usize,
) -> PyResult<Vec<Option<Depth<'py>>>> {
    let mut out: Vec<Option<Depth<'py>>> = (0..cameras).map(|_| None).collect();
    let Some(depth) = depth.filter(|d| !d.is_none()) else {
        return Ok(out);
    };
    if !(depth.is_instance_of::<PyList>() || depth.is_instance_of::<PyTuple>()) {
        if let Some(first) = out.first_mut() {
            *first = Some(depth_array(depth)?);
        }
        return Ok(out);
    }
    let given = items(depth);
    if given.len() != cameras {
        return Err(PyValueError::new_err(format!(
            "depth: {} given for {cameras} image(s): one per image (None for none)",
            given.len()
        )));
    }
    for (slot, d) in out.iter_mut().zip(&given) {
        if !d.is_none() {
            *slot = Some(depth_array(d)?);
        }
    }
    Ok(out)
}

fn pixels<'a, T: numpy::Element + Clone>(a: &'a PyReadonlyArrayDyn<'_, T>) -> Cow<'a, [T]> {
    match a.as_slice() {
        Ok(s) => Cow::Borrowed(s),
        Err(_) => Cow::Owned(a.as_array().iter().cloned().collect()),
    }
}

fn image<'a>(a: &'a PyReadonlyArrayDyn<'_, u8>) -> Image<Cow<'a, [u8]>> {
    let shape = a.shape();
    Image {
        width: shape[1],
        height: shape[0],
        channels: shape.get(2).copied().unwrap_or(1),
        data: pixels(a),
    }
}

impl<'py> FrameArrays<'py> {
    /// Reads the arguments of `SlamSystem.track` (checking types, ranks and dtypes; sizes
    /// are the core's to check, once).
    pub fn parse(
        timestamp: f64,
        images: &Bound<'py, PyAny>,
        depth: Option<&Bound<'py, PyAny>>,
        colors: Option<&Bound<'py, PyAny>>,
        masks: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Self> {
        let given = items(images);
        let n = given.len();
        let images = given
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let label = if n == 1 {
                    "image".to_string()
                } else {
                    format!("images[{i}]")
                };
                image_array(o, &label, false)
            })
            .collect::<PyResult<Vec<_>>>()?;
        Ok(Self {
            timestamp,
            colors: per_camera(colors, n, "colors", false)?,
            masks: per_camera(masks, n, "masks", true)?,
            depths: depths(depth, n)?,
            images,
        })
    }

    /// The frame, borrowing the arrays.
    pub fn frame(&self) -> FrameCow<'_> {
        let cameras = self
            .images
            .iter()
            .zip(&self.colors)
            .zip(&self.masks)
            .zip(&self.depths)
            .map(|(((img, color), mask), depth)| CameraImage {
                image: image(img),
                color: color.as_ref().map(image),
                depth_m: depth.as_ref().map(depth_image),
                mask: mask.as_ref().map(image),
            })
            .collect();
        RigFrame {
            timestamp: self.timestamp,
            cameras,
        }
    }
}

/// The frame with its pixels owned (to queue it to the tracking thread).
pub fn owned(frame: FrameCow<'_>) -> OwnedRigFrame {
    let own = |i: Image<Cow<'_, [u8]>>| Image {
        width: i.width,
        height: i.height,
        channels: i.channels,
        data: i.data.into_owned(),
    };
    RigFrame {
        timestamp: frame.timestamp,
        cameras: frame
            .cameras
            .into_iter()
            .map(|c| CameraImage {
                image: own(c.image),
                color: c.color.map(own),
                depth_m: c.depth_m.map(|d| DepthImage {
                    width: d.width,
                    height: d.height,
                    data: d.data.into_owned(),
                }),
                mask: c.mask.map(own),
            })
            .collect(),
    }
}
