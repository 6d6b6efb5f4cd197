//! The ways a frame comes in: images through the front end ([`SlamSystem::track`], the door
//! every image goes through), or features measured elsewhere (synthetic scenes, another
//! front end) per sensor.

use std::time::Instant;

use ferroslam_geometry::camera::CameraModel;
use nalgebra::Isometry3;

use super::{SlamSystem, TrackResult};
use crate::config::Sensor;
use crate::error::SlamError;
use crate::frame::{Frame, MonoInput, ObserverInput, RgbdInput, StereoInput};
use crate::front_end::RigFrame;
use crate::stereo_pair::UnrectifiedPair;

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

    /// Adds a further camera to the rig at `T_c0_c` (its pose in the first camera's frame,
    /// metres; `p_c0 = T_c0_c p_c`), with a registered depth image per frame when
    /// `has_depth`. Its image follows the first camera's (and its pair partner's) in every
    /// frame given to [`Self::track`]; its keypoints are observations of the same map, matched,
    /// optimised and triangulated (with every camera of this and the other keyframes) as the
    /// first camera's. Poses stay the first camera's.
    ///
    /// # Errors
    /// `InvalidConfig`, the system unchanged, after the first frame or with the mapping
    /// thread running, on a monocular system (its map's scale is not the rig's metres), or
    /// for a pose that is not finite.
    #[allow(non_snake_case)]
    pub fn add_camera(
        &mut self,
        camera: impl Into<CameraModel>,
        T_c0_c: Isometry3<f64>,
        has_depth: bool,
    ) -> Result<(), SlamError> {
        self.check_new_camera("add_camera", &T_c0_c)?;
        self.ctx.add_observer(camera.into(), T_c0_c, has_depth);
        self.camera_added();
        Ok(())
    }

    /// Adds a further camera to the rig at `T_c0_c` with its stereo partner at
    /// `T_left_right` (the partner's pose in this camera, `p_c = T_left_right p_partner`,
    /// metres): its image follows the camera's own in every frame given to [`Self::track`],
    /// and the camera's keypoints get depth by matching into it along epipolar curves (any
    /// model, no rectification), as the first camera's unrectified pair; the partner observes
    /// nothing itself. A rig of several stereo pairs is the first camera's pair (or depth)
    /// and one of these per further pair. Frames given as features ([`Self::track_rgbd_rig`])
    /// bring this camera's depths themselves.
    ///
    /// # Errors
    /// As [`Self::add_camera`], and `InvalidConfig` for a partner of another image size or
    /// no baseline.
    #[allow(non_snake_case)]
    pub fn add_camera_pair(
        &mut self,
        camera: impl Into<CameraModel>,
        T_c0_c: Isometry3<f64>,
        partner: impl Into<CameraModel>,
        T_left_right: Isometry3<f64>,
    ) -> Result<(), SlamError> {
        self.check_new_camera("add_camera_pair", &T_c0_c)?;
        let camera = camera.into();
        let pair =
            UnrectifiedPair::new(&camera, partner.into(), T_left_right).map_err(|e| match e {
                SlamError::InvalidConfig(why) => {
                    SlamError::InvalidConfig(format!("add_camera_pair: {why}"))
                }
                other => other,
            })?;
        self.ctx.add_observer_pair(camera, T_c0_c, pair);
        self.camera_added();
        Ok(())
    }

    /// Why a camera at `T_c0_c` cannot be added now (`call` names the method), if it cannot.
    #[allow(non_snake_case)]
    fn check_new_camera(&self, call: &str, T_c0_c: &Isometry3<f64>) -> Result<(), SlamError> {
        let refuse = |why: &str| Err(SlamError::InvalidConfig(format!("{call}: {why}")));
        if self.frames_seen > 0 || self.map.num_keyframes() > 0 {
            return refuse("cameras are added before the first frame");
        }
        if self.mapping.is_threaded() {
            return refuse("cameras are added before the mapping thread starts");
        }
        if self.ctx.config.sensor == Sensor::Monocular {
            return refuse(
                "a monocular rig's map has no metric scale for the cameras' metric poses: give \
                 the first camera depth or a stereo partner",
            );
        }
        let pose = T_c0_c
            .translation
            .vector
            .iter()
            .chain(T_c0_c.rotation.coords.iter());
        if !pose.clone().all(|v| v.is_finite()) {
            return refuse("T_c0_c is not finite");
        }
        Ok(())
    }

    /// The input rules and the map's rig record after a camera was added.
    fn camera_added(&mut self) {
        self.guard = self.input_guard();
        self.map.set_rig(self.ctx.rig());
    }

    /// Tracks one RGB-D frame; keypoints are raw (distorted) pixels with sensor depth.
    /// [`Self::track_rgbd_rig`] of a single camera.
    ///
    /// # Errors
    /// `InvalidInput` for mismatched lengths, non-finite values, octaves beyond the pyramid or
    /// a timestamp not after the previous one, and on a rig with further cameras (their
    /// features go to [`Self::track_rgbd_rig`]); the system state is unchanged then.
    pub fn track_rgbd(&mut self, input: &RgbdInput<'_>) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        self.guard.accept_rgbd(input)?;
        self.track_rgbd_checked(input, &[], start)
    }

    /// Tracks one instant of an RGB-D rig from features measured elsewhere (synthetic scenes,
    /// another front end): the first camera's `input` as [`Self::track_rgbd`]'s, then one
    /// `observers[k]` per further camera `k + 1`, in the order [`Self::add_camera`] added
    /// them: raw (distorted) keypoints of that camera, descriptors, colours (empty for none;
    /// given for every camera or none) and depths in metres (exactly for cameras added with
    /// depth; `<= 0` or NaN means no measurement). The frame is tracked as one made by
    /// [`Self::track`] from images.
    ///
    /// # Errors
    /// `InvalidInput` as [`Self::track_rgbd`], for another number of observers than the
    /// rig's further cameras, and naming the camera (`camera k: ...`) for an observer whose
    /// lengths differ, whose coordinates are non-finite or outside its image, whose octaves
    /// are beyond the pyramid, whose colours are given while camera 0's are not (or the
    /// reverse), or whose depths are missing, given to a camera without depth or of another
    /// length; the system state is unchanged then.
    pub fn track_rgbd_rig(
        &mut self,
        input: &RgbdInput<'_>,
        observers: &[ObserverInput<'_>],
    ) -> Result<TrackResult, SlamError> {
        let start = Instant::now();
        self.guard.accept_rgbd_rig(input, observers)?;
        self.track_rgbd_checked(input, observers, start)
    }

    /// Builds and tracks a frame the guard accepted: the first camera's features, then the
    /// further cameras' (as [`crate::front_end::Measured::frame`] appends them).
    fn track_rgbd_checked(
        &mut self,
        input: &RgbdInput<'_>,
        observers: &[ObserverInput<'_>],
        start: Instant,
    ) -> Result<TrackResult, SlamError> {
        let mut frame = Frame::from_rgbd(self.frames_seen, input, &self.ctx)?;
        if !observers.is_empty() {
            frame = frame.with_observers(observers, &self.ctx)?;
        }
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
