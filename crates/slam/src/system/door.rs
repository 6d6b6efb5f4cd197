//! The ways a frame comes in: images through the front end ([`SlamSystem::track`], the door
//! every image goes through), or features measured elsewhere (synthetic scenes, another
//! front end) per sensor.

use std::time::Instant;

use super::{SlamSystem, TrackResult};
use crate::error::SlamError;
use crate::frame::{Frame, MonoInput, RgbdInput, StereoInput};
use crate::front_end::RigFrame;

impl SlamSystem {
    /// Tracks one instant of the rig from its images: the one door for images. The front end
    /// extracts every camera's features (in parallel, honouring the masks) and samples depth
    /// and colour at them, then the frame is tracked as its sensor's.
    ///
    /// # Errors
    /// `InvalidInput` naming the problem: the wrong number of images for the sensor, an image,
    /// colour image, mask or depth of another size than the camera, depth given to (or missing
    /// from) the wrong sensor, a timestamp not after the previous one; the state is unchanged.
    pub fn track<D, F>(&mut self, frame: &RigFrame<D, F>) -> Result<TrackResult, SlamError>
    where
        D: AsRef<[u8]> + Sync,
        F: AsRef<[f32]> + Sync,
    {
        let front_start = Instant::now();
        self.guard.accept_frame(frame)?;
        let measured = self.front_end.measure(frame)?;
        let start = Instant::now();
        let sensor = self.ctx.config.sensor;
        let tracked = measured.frame(self.frames_seen, sensor, self.map.pyramid(), &self.ctx)?;
        let mut result = self.track_frame(tracked, start)?;
        result.extraction_ms = (start - front_start).as_secs_f64() * 1e3;
        result.keypoints = measured.into_keypoints();
        Ok(result)
    }

    /// Sets the static mask of camera `camera` (0 = no keypoint there; `None` removes it),
    /// applied by [`Self::track`] on every frame.
    ///
    /// # Errors
    /// `InvalidInput` for a camera the rig does not have or a mask of another size.
    pub fn set_mask(
        &mut self,
        camera: usize,
        mask: Option<ferroslam_features::OwnedGrayImage>,
    ) -> Result<(), SlamError> {
        self.guard.check_mask(camera, mask.as_ref())?;
        self.front_end.set_mask(camera, mask);
        Ok(())
    }

    /// Tracks one RGB-D frame; keypoints are raw (distorted) pixels with sensor depth.
    ///
    /// # Errors
    /// `InvalidInput` for mismatched lengths, non-finite values, octaves beyond the pyramid or
    /// a timestamp not after the previous one; the system state is unchanged then.
    pub fn track_rgbd(&mut self, input: &RgbdInput<'_>) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        self.guard.accept_rgbd(input)?;
        let frame = Frame::from_rgbd(self.frames_seen, input, &self.ctx)?;
        self.track_frame(frame, start)
    }

    /// Tracks one rectified stereo pair: the left keypoints are matched into the right image
    /// (depth from disparity, `bf` of the configuration) and the left frame is tracked.
    ///
    /// # Errors
    /// `InvalidInput` as [`Self::track_rgbd`], for pyramids that miss levels or differ in size
    /// between the images, and when the camera has distortion (stereo input must be rectified).
    pub fn track_stereo(&mut self, input: &StereoInput<'_>) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        self.guard.accept_stereo(input)?;
        let frame = Frame::from_stereo(self.frames_seen, input, self.map.pyramid(), &self.ctx)?;
        self.track_frame(frame, start)
    }

    /// Tracks one monocular frame; keypoints are raw (distorted) pixels. Until the map exists
    /// each frame is offered to two-view initialisation (`init_status` says why it waits).
    ///
    /// # Errors
    /// `InvalidInput` as [`Self::track_rgbd`].
    pub fn track_mono(&mut self, input: &MonoInput<'_>) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        self.guard.accept_mono(input)?;
        let frame = Frame::from_mono(self.frames_seen, input, &self.ctx)?;
        self.track_frame(frame, start)
    }
}
