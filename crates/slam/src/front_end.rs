//! The front end: one instant of the rig's cameras in as images ([`RigFrame`]), the frame's
//! measured features out ([`Measured`]): ORB extraction of every camera in parallel, static
//! and per-frame masks, depth and colour sampled at the keypoints, stereo matching on the
//! extraction's own pyramids. It runs inside the one tracking call, so no pyramid or keypoint
//! list crosses into the caller and back, and the images are checked once.
//!
//! Images are generic in their storage (`D`: borrowed slices for a synchronous call, owned
//! vectors for a frame queued to the tracking thread), so one set of checks and one
//! measurement serve both.

use std::borrow::Cow;

use ferroslam_features::{
    Descriptor, Features, GrayImage, Keypoint, OrbExtractor, OwnedGrayImage, ScalePyramid,
    StereoView,
};
use ferroslam_map::Rgb;
use rayon::prelude::*;

use crate::config::Sensor;
use crate::context::{Context, InputShape, ObserverShape};
use crate::error::SlamError;
use crate::frame::{Frame, MonoInput, ObserverInput, RgbdInput, StereoInput, UnmatchedPair};

/// An 8-bit image as OpenCV holds it: rows of grey, BGR or BGRA pixels, no padding.
#[derive(Clone, Debug)]
pub struct Image<D> {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// 1 (grey), 3 (BGR) or 4 (BGRA).
    pub channels: usize,
    /// `height * width * channels` bytes, row-major.
    pub data: D,
}

/// A depth image registered to its camera's image: metres per pixel, row-major; 0, negative
/// or NaN means no measurement.
#[derive(Clone, Debug)]
pub struct DepthImage<F> {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// `height * width` depths, metres.
    pub data: F,
}

/// One camera's image at one instant.
#[derive(Clone, Debug)]
pub struct CameraImage<D, F> {
    /// The image tracked: grey, or BGR(A) converted to grey as OpenCV converts it.
    pub image: Image<D>,
    /// The same view in colour, when `image` is grey: the map points' colours come from it
    /// (else from `image`, grey images giving grey colours).
    pub color: Option<Image<D>>,
    /// Registered depth (RGB-D cameras).
    pub depth_m: Option<DepthImage<F>>,
    /// This frame's mask, one byte per pixel: 0 = no keypoint there (combined with the
    /// camera's static mask).
    pub mask: Option<Image<D>>,
}

/// One instant of the rig: the time and every camera's image, in the rig's camera order.
#[derive(Clone, Debug)]
pub struct RigFrame<D, F> {
    /// Capture time, seconds.
    pub timestamp: f64,
    /// One image per camera.
    pub cameras: Vec<CameraImage<D, F>>,
}

/// A frame borrowing the caller's pixels (a synchronous call).
pub type RigFrameView<'a> = RigFrame<&'a [u8], &'a [f32]>;
/// A frame owning its pixels (queued to the tracking thread).
pub type OwnedRigFrame = RigFrame<Vec<u8>, Vec<f32>>;

/// The cameras a sensor's frame holds for its first camera (and pair partner).
fn expected_cameras(sensor: Sensor) -> (usize, &'static str) {
    match sensor {
        Sensor::Monocular => (1, "one image"),
        Sensor::Rgbd => (1, "one colour image with its depth"),
        Sensor::Stereo => (2, "two images (left, right)"),
    }
}

impl<D: AsRef<[u8]>> Image<D> {
    fn check(&self, what: &str, channels: &[usize], size: (usize, usize)) -> Result<(), SlamError> {
        if !channels.contains(&self.channels) {
            return Err(invalid(format!(
                "{what} has {} channels: it must be grey (H, W) or BGR (H, W, 3)",
                self.channels
            )));
        }
        if (self.width, self.height) != size {
            return Err(invalid(format!(
                "{what} is {}x{} but the camera is {}x{} (width x height)",
                self.width, self.height, size.0, size.1
            )));
        }
        let len = self.data.as_ref().len();
        if Some(len) != self.width.checked_mul(self.height * self.channels) {
            return Err(invalid(format!(
                "{what}: {len} bytes do not hold {}x{}x{} pixels",
                self.width, self.height, self.channels
            )));
        }
        Ok(())
    }

    /// The grey image: borrowed when grey, else OpenCV's `COLOR_BGR2GRAY` (BT.601 weights in
    /// 15-bit fixed point, rounded: equal to OpenCV 5's for all 2^24 colours), so keypoints
    /// equal those of the image converted by OpenCV.
    fn gray(&self) -> Cow<'_, [u8]> {
        let data = self.data.as_ref();
        if self.channels == 1 {
            return Cow::Borrowed(data);
        }
        const B2Y: u32 = 3735;
        const G2Y: u32 = 19235;
        const R2Y: u32 = 9798;
        Cow::Owned(
            data.chunks_exact(self.channels)
                .map(|p| {
                    let sum = u32::from(p[0]) * B2Y + u32::from(p[1]) * G2Y + u32::from(p[2]) * R2Y;
                    ((sum + (1 << 14)) >> 15) as u8
                })
                .collect(),
        )
    }

    /// RGB at pixel `(x, y)` (inside the image).
    fn rgb(&self, (x, y): (usize, usize)) -> Rgb {
        let i = (y * self.width + x) * self.channels;
        let p = &self.data.as_ref()[i..i + self.channels];
        if self.channels == 1 {
            [p[0]; 3]
        } else {
            [p[2], p[1], p[0]]
        }
    }
}

/// The pixel a keypoint falls on: its raw position rounded half to even (as numpy's `rint`),
/// `None` outside the image.
fn pixel_of(k: &Keypoint, width: usize, height: usize) -> Option<(usize, usize)> {
    let (u, v) = (
        f64::from(k.x).round_ties_even(),
        f64::from(k.y).round_ties_even(),
    );
    let inside = u >= 0.0 && v >= 0.0 && u < width as f64 && v < height as f64;
    inside.then_some((u as usize, v as usize))
}

impl<D: AsRef<[u8]>, F: AsRef<[f32]>> RigFrame<D, F> {
    /// Checks the frame against a `sensor` system whose cameras have `shape`, and whose
    /// further cameras are `observers`: the number of cameras, every image's size and
    /// channels, depth exactly where the camera has it.
    pub fn validate(
        &self,
        sensor: Sensor,
        shape: &InputShape,
        observers: &[ObserverShape],
    ) -> Result<(), SlamError> {
        if !self.timestamp.is_finite() {
            return Err(invalid("timestamp is not finite".into()));
        }
        let (first, what) = expected_cameras(sensor);
        let further: Vec<((usize, usize), bool)> =
            observers.iter().flat_map(ObserverShape::images).collect();
        let n = first + further.len();
        if self.cameras.len() != n {
            let partners = if observers.iter().any(|o| o.paired) {
                ", a stereo partner's after its camera's"
            } else {
                ""
            };
            let what = if observers.is_empty() {
                what.to_owned()
            } else {
                format!("{what} and one per further camera{partners} ({n} in all)")
            };
            return Err(invalid(format!(
                "a {} frame has {what}, got {} image(s)",
                sensor.name(),
                self.cameras.len()
            )));
        }
        for (i, camera) in self.cameras.iter().enumerate() {
            let name = |part: &str| match n {
                1 => part.to_string(),
                _ => format!("camera {i} {part}"),
            };
            let (size, wants_depth) = match i.checked_sub(first) {
                None => (
                    (shape.width as usize, shape.height as usize),
                    sensor == Sensor::Rgbd,
                ),
                Some(o) => further[o],
            };
            camera.image.check(&name("image"), &[1, 3, 4], size)?;
            if let Some(color) = &camera.color {
                color.check(&name("colour image"), &[1, 3, 4], size)?;
            }
            if let Some(mask) = &camera.mask {
                mask.check(&name("mask"), &[1], size)?;
            }
            match (&camera.depth_m, wants_depth) {
                (Some(depth), true) => {
                    let len = depth.data.as_ref().len();
                    if (depth.width, depth.height) != size || len != size.0 * size.1 {
                        return Err(invalid(format!(
                            "the depth image is {}x{} but the camera is {}x{} (width x \
                             height): depth must be registered to the colour image",
                            depth.width, depth.height, size.0, size.1
                        )));
                    }
                }
                (None, true) if i >= first => {
                    return Err(invalid(format!(
                        "camera {i} is a depth camera: its depth image is missing"
                    )))
                }
                (Some(_), false) if i >= first => {
                    return Err(invalid(format!(
                        "camera {i} has no depth sensor: a depth image was given for it"
                    )))
                }
                (None, true) => return Err(invalid("an RGB-D frame needs its depth image".into())),
                (Some(_), false) => {
                    return Err(invalid(format!(
                        "a depth image was given to a {} system: only RGB-D systems use depth",
                        sensor.name()
                    )))
                }
                (None, false) => {}
            }
        }
        Ok(())
    }
}

/// The features of one camera's image with what was sampled at them.
struct CameraFeatures {
    features: Features,
    colors: Vec<Rgb>,
    depth_m: Option<Vec<f32>>,
}

/// The front end's result for one frame: every camera's features.
pub struct Measured {
    timestamp: f64,
    cameras: Vec<CameraFeatures>,
}

impl Measured {
    /// The frame tracking works on (the one place the sensors part ways): depth from the
    /// sensor (RGB-D), from matching the pair (stereo), or none yet (monocular), then the
    /// further cameras' keypoints, each with its depth image's depths if it has one.
    pub fn frame(
        &self,
        index: usize,
        sensor: Sensor,
        pyramid: &ScalePyramid,
        ctx: &Context,
    ) -> Result<Frame, SlamError> {
        let frame = self.first_camera_frame(index, sensor, pyramid, ctx)?;
        if ctx.observers.is_empty() {
            return Ok(frame);
        }
        // Each further camera's image, then its stereo partner's if it has one.
        let mut images = self.cameras[expected_cameras(sensor).0..].iter();
        let mut measured = Vec::with_capacity(ctx.observers.len());
        let mut unmatched = Vec::new();
        let missing = || invalid("a frame has fewer images than the rig's cameras".into());
        for (k, observer) in ctx.observers.iter().enumerate() {
            let c = images.next().ok_or_else(missing)?;
            let paired_depth = match &observer.pair {
                Some(_) if !ctx.config.depth.match_pair_every_frame => {
                    // Matched if the frame starts the map or becomes a keyframe, as the
                    // first camera's pair.
                    let right = &images.next().ok_or_else(missing)?.features;
                    unmatched.push(UnmatchedPair {
                        camera: k + 1,
                        left_raw: c.features.keypoints.clone(),
                        right_keypoints: right.keypoints.clone(),
                        right_descriptors: right.descriptors.clone(),
                    });
                    Some(vec![0.0; c.features.keypoints.len()])
                }
                Some(pair) => {
                    let right = images.next().ok_or_else(missing)?;
                    Some(pair.depths(
                        &observer.camera,
                        (&c.features.keypoints, &c.features.descriptors),
                        (&right.features.keypoints, &right.features.descriptors),
                        &pyramid.sigma2,
                    ))
                }
                None => None,
            };
            measured.push((c, paired_depth));
        }
        let observed: Vec<ObserverInput<'_>> = measured
            .iter()
            .map(|(c, paired_depth)| ObserverInput {
                keypoints: &c.features.keypoints,
                descriptors: &c.features.descriptors,
                colors: &c.colors,
                depth_m: paired_depth.as_deref().or(c.depth_m.as_deref()),
            })
            .collect();
        let mut frame = frame.with_observers(&observed, ctx)?;
        frame.unmatched_pairs.extend(unmatched);
        Ok(frame)
    }

    /// The first camera's frame, as its sensor's.
    fn first_camera_frame(
        &self,
        index: usize,
        sensor: Sensor,
        pyramid: &ScalePyramid,
        ctx: &Context,
    ) -> Result<Frame, SlamError> {
        let first = &self.cameras[0];
        let (keypoints, descriptors) = (&first.features.keypoints, &first.features.descriptors);
        let colors = Some(first.colors.as_slice());
        match sensor {
            Sensor::Monocular => Frame::from_mono(
                index,
                &MonoInput {
                    timestamp: self.timestamp,
                    keypoints,
                    descriptors,
                    colors,
                },
                ctx,
            ),
            Sensor::Rgbd => Frame::from_rgbd(
                index,
                &RgbdInput {
                    timestamp: self.timestamp,
                    keypoints,
                    descriptors,
                    depth_m: first.depth_m.as_deref().unwrap_or_default(),
                    colors,
                },
                ctx,
            ),
            Sensor::Stereo => {
                let right = &self.cameras[1].features;
                if ctx.pair.is_some() && !ctx.config.depth.match_pair_every_frame {
                    let input = RgbdInput {
                        timestamp: self.timestamp,
                        keypoints,
                        descriptors,
                        depth_m: &vec![0.0; keypoints.len()],
                        colors,
                    };
                    let mut frame = Frame::from_rgbd(index, &input, ctx)?;
                    frame.unmatched_pairs.push(UnmatchedPair {
                        camera: 0,
                        left_raw: keypoints.clone(),
                        right_keypoints: right.keypoints.clone(),
                        right_descriptors: right.descriptors.clone(),
                    });
                    return Ok(frame);
                }
                if let Some(pair) = &ctx.pair {
                    let depth_m = pair.depths(
                        &ctx.camera,
                        (keypoints, descriptors),
                        (&right.keypoints, &right.descriptors),
                        &pyramid.sigma2,
                    );
                    let input = RgbdInput {
                        timestamp: self.timestamp,
                        keypoints,
                        descriptors,
                        depth_m: &depth_m,
                        colors,
                    };
                    return Frame::from_rgbd(index, &input, ctx);
                }
                let (left_levels, right_levels) =
                    (first.features.pyramid.views(), right.pyramid.views());
                let input = StereoInput {
                    timestamp: self.timestamp,
                    left: stereo_view(keypoints, descriptors, &left_levels),
                    right: stereo_view(&right.keypoints, &right.descriptors, &right_levels),
                    colors,
                };
                Frame::from_stereo(index, &input, pyramid, ctx)
            }
        }
    }

    /// Every camera's raw keypoints (what the caller is shown).
    pub fn into_keypoints(self) -> Vec<Vec<Keypoint>> {
        self.cameras
            .into_iter()
            .map(|c| c.features.keypoints)
            .collect()
    }
}

fn stereo_view<'a>(
    keypoints: &'a [Keypoint],
    descriptors: &'a [Descriptor],
    levels: &'a [GrayImage<'a>],
) -> StereoView<'a> {
    StereoView {
        keypoints,
        descriptors,
        levels,
    }
}

/// The ORB extractor and the cameras' static masks.
#[derive(Clone, Debug)]
pub struct FrontEnd {
    extractor: OrbExtractor,
    /// Per camera, the static mask (0 = no keypoint), if any.
    masks: Vec<Option<OwnedGrayImage>>,
}

impl FrontEnd {
    /// A front end with `extractor` and no masks.
    pub fn new(extractor: OrbExtractor) -> Self {
        Self {
            extractor,
            masks: Vec::new(),
        }
    }

    /// Sets camera `camera`'s static mask (`None` removes it); its size is checked by the
    /// caller against the camera's.
    pub fn set_mask(&mut self, camera: usize, mask: Option<OwnedGrayImage>) {
        if self.masks.len() <= camera {
            self.masks.resize(camera + 1, None);
        }
        self.masks[camera] = mask;
    }

    /// Camera `camera`'s static mask.
    pub fn mask(&self, camera: usize) -> Option<&OwnedGrayImage> {
        self.masks.get(camera).and_then(Option::as_ref)
    }

    /// Measures a frame already checked by [`RigFrame::validate`]: all cameras in parallel.
    pub fn measure<D, F>(&self, frame: &RigFrame<D, F>) -> Result<Measured, SlamError>
    where
        D: AsRef<[u8]> + Sync,
        F: AsRef<[f32]> + Sync,
    {
        let cameras = frame
            .cameras
            .par_iter()
            .enumerate()
            .map(|(i, camera)| self.measure_camera(i, camera))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Measured {
            timestamp: frame.timestamp,
            cameras,
        })
    }

    fn measure_camera<D: AsRef<[u8]>, F: AsRef<[f32]>>(
        &self,
        index: usize,
        camera: &CameraImage<D, F>,
    ) -> Result<CameraFeatures, SlamError> {
        let image = &camera.image;
        let (w, h) = (image.width, image.height);
        let gray = image.gray();
        let gray = GrayImage::new(w, h, &gray).map_err(|e| invalid(e.to_string()))?;
        let mask = combined_mask(self.mask(index), camera.mask.as_ref());
        let mask = mask
            .as_deref()
            .map(|m| GrayImage::new(w, h, m))
            .transpose()
            .map_err(|e| invalid(e.to_string()))?;
        let features = self
            .extractor
            .extract(&gray, mask.as_ref())
            .map_err(|e| invalid(e.to_string()))?;
        let pixels: Vec<Option<(usize, usize)>> = features
            .keypoints
            .iter()
            .map(|k| pixel_of(k, w, h))
            .collect();
        let source = camera.color.as_ref().unwrap_or(image);
        let colors = pixels
            .iter()
            .map(|p| p.map_or([0; 3], |p| source.rgb(p)))
            .collect();
        let depth_m = camera.depth_m.as_ref().map(|depth| {
            let data = depth.data.as_ref();
            pixels
                .iter()
                .map(|p| {
                    let d = p.map_or(0.0, |(x, y)| data[y * depth.width + x]);
                    if d.is_finite() && d > 0.0 {
                        d
                    } else {
                        0.0
                    }
                })
                .collect()
        });
        Ok(CameraFeatures {
            features,
            colors,
            depth_m,
        })
    }
}

/// The pixels both masks allow (each 0 = no keypoint), `None` when neither is given.
fn combined_mask<'a, D: AsRef<[u8]>>(
    fixed: Option<&'a OwnedGrayImage>,
    frame: Option<&'a Image<D>>,
) -> Option<Cow<'a, [u8]>> {
    match (
        fixed.map(|m| m.view().pixels()),
        frame.map(|m| m.data.as_ref()),
    ) {
        (Some(a), Some(b)) => Some(Cow::Owned(
            a.iter()
                .zip(b)
                .map(|(&a, &b)| u8::from(a != 0 && b != 0))
                .collect(),
        )),
        (Some(a), None) => Some(Cow::Borrowed(a)),
        (None, Some(b)) => Some(Cow::Borrowed(b)),
        (None, None) => None,
    }
}

fn invalid(message: String) -> SlamError {
    SlamError::InvalidInput(message)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bgr_to_grey_is_opencvs() {
        // cv2.cvtColor(..., COLOR_BGR2GRAY) of these BGR pixels; a 14-bit rounding (OpenCV's
        // older tables) misses each by one grey level.
        let cases = [
            ([230, 0, 21], 32),
            ([240, 159, 93], 148),
            ([83, 225, 137], 183),
            ([226, 113, 95], 120),
            ([108, 248, 186], 214),
            ([62, 30, 180], 78),
            ([255, 255, 255], 255),
            ([0, 0, 0], 0),
        ];
        let data: Vec<u8> = cases.iter().flat_map(|(bgr, _)| *bgr).collect();
        let image = Image {
            width: cases.len(),
            height: 1,
            channels: 3,
            data: data.as_slice(),
        };
        let expected: Vec<u8> = cases.iter().map(|&(_, g)| g).collect();
        assert_eq!(image.gray().as_ref(), expected.as_slice());
    }
}
