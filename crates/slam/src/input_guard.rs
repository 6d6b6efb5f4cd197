//! The checks every frame passes before it may change a system: the right `track_*` call for
//! the sensor, well-formed features, rectified stereo, increasing timestamps. Kept apart from
//! [`crate::SlamSystem`] so a background submitter can reject bad input at once, in the
//! caller's thread, with the same messages.

use crate::config::Sensor;
use crate::context::{InputShape, ObserverShape};
use crate::error::SlamError;
use crate::frame::{MonoInput, RgbdInput, StereoInput};
use crate::front_end::RigFrame;
use ferroslam_features::OwnedGrayImage;

/// Input rules of one system and the last accepted timestamp.
#[derive(Clone, Debug)]
pub struct InputGuard {
    sensor: Sensor,
    shape: InputShape,
    distorted: bool,
    observers: Vec<ObserverShape>,
    last_timestamp: Option<f64>,
}

impl InputGuard {
    /// Rules for a `sensor` system whose input has `shape` and whose camera is `distorted`
    /// (stereo input must be rectified).
    pub fn new(sensor: Sensor, shape: InputShape, distorted: bool) -> Self {
        Self {
            sensor,
            shape,
            distorted,
            observers: Vec::new(),
            last_timestamp: None,
        }
    }

    /// The same rules for a rig whose further cameras' images are `observers`.
    pub fn with_observers(self, observers: Vec<ObserverShape>) -> Self {
        Self { observers, ..self }
    }

    /// Checks an RGB-D frame and, if it passes, accepts its timestamp.
    pub fn accept_rgbd(&mut self, input: &RgbdInput<'_>) -> Result<(), SlamError> {
        self.expect(Sensor::Rgbd, "track_rgbd")?;
        input.validate(&self.shape)?;
        self.advance(input.timestamp)
    }

    /// Checks a stereo pair and, if it passes, accepts its timestamp.
    pub fn accept_stereo(&mut self, input: &StereoInput<'_>) -> Result<(), SlamError> {
        self.expect(Sensor::Stereo, "track_stereo")?;
        if self.distorted {
            return Err(SlamError::InvalidInput(
                "stereo input must come from rectified images, but the camera has distortion \
                 coefficients: rectify the pair and pass the rectified pinhole intrinsics"
                    .into(),
            ));
        }
        input.validate(&self.shape)?;
        self.advance(input.timestamp)
    }

    /// Checks a frame of images (the sensor's number of cameras, their sizes, depth where the
    /// sensor has it) and, if it passes, accepts its timestamp.
    pub fn accept_frame<D: AsRef<[u8]>, F: AsRef<[f32]>>(
        &mut self,
        frame: &RigFrame<D, F>,
    ) -> Result<(), SlamError> {
        frame.validate(self.sensor, &self.shape, &self.observers)?;
        self.advance(frame.timestamp)
    }

    /// Checks a static mask for camera `camera`: a camera of the rig, the camera's size.
    pub fn check_mask(
        &self,
        camera: usize,
        mask: Option<&OwnedGrayImage>,
    ) -> Result<(), SlamError> {
        let first = if self.sensor == Sensor::Stereo { 2 } else { 1 };
        let cameras = first + self.observers.len();
        if camera >= cameras {
            return Err(SlamError::InvalidInput(format!(
                "mask for camera {camera}, but a {} system has {cameras} camera(s)",
                self.sensor.name()
            )));
        }
        let size = match camera.checked_sub(first) {
            None => (self.shape.width as usize, self.shape.height as usize),
            Some(o) => (
                self.observers[o].width as usize,
                self.observers[o].height as usize,
            ),
        };
        match mask.map(|m| (m.view().width(), m.view().height())) {
            Some(got) if got != size => Err(SlamError::InvalidInput(format!(
                "the mask is {}x{} but the camera is {}x{} (width x height)",
                got.0, got.1, size.0, size.1
            ))),
            _ => Ok(()),
        }
    }

    /// Checks a monocular frame and, if it passes, accepts its timestamp.
    pub fn accept_mono(&mut self, input: &MonoInput<'_>) -> Result<(), SlamError> {
        self.expect(Sensor::Monocular, "track_mono")?;
        input.validate(&self.shape)?;
        self.advance(input.timestamp)
    }

    fn expect(&self, sensor: Sensor, method: &str) -> Result<(), SlamError> {
        if !self.observers.is_empty() {
            return Err(SlamError::InvalidInput(format!(
                "{method} takes the first camera's features only, but this rig has {} further \
                 camera(s): track its images (track)",
                self.observers.len()
            )));
        }
        if self.sensor == sensor {
            return Ok(());
        }
        let own = self.sensor.name();
        Err(SlamError::InvalidInput(format!(
            "{method} needs a system created with sensor=\"{}\"; this one is \"{own}\" \
             (use track_{own})",
            sensor.name()
        )))
    }

    fn advance(&mut self, timestamp: f64) -> Result<(), SlamError> {
        if let Some(t) = self.last_timestamp.filter(|&t| timestamp <= t) {
            return Err(SlamError::InvalidInput(format!(
                "timestamp {timestamp} is not after the previous frame's {t}"
            )));
        }
        self.last_timestamp = Some(timestamp);
        Ok(())
    }
}
