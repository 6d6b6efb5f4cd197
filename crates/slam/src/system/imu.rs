//! The system's IMU: its setup, its samples, the keyframes' preintegration and the
//! camera-IMU alignment.

use ferroslam_map::KeyFrameId;
use nalgebra::Vector3;

use super::SlamSystem;
use crate::error::SlamError;
use crate::inertial::{
    rescale_map, AlignmentStatus, Bias, ImuSample, Inertial, InertialConfig, Preintegrated,
};

impl SlamSystem {
    /// Sets the IMU (noise model, camera pose in the body frame, alignment knobs): from now
    /// on keyframes keep their preintegrated IMU and the camera-IMU alignment runs once the
    /// map holds `num_poses_threshold` keyframes (see the `inertial` module). Replaces an
    /// earlier IMU setup, its buffered samples and its alignment.
    ///
    /// # Errors
    /// `InvalidConfig` naming the bad value; the system is unchanged then.
    pub fn set_imu(&mut self, config: InertialConfig) -> Result<(), SlamError> {
        let known_scale = self.ctx.config.sensor.has_depth();
        let tuning = self.ctx.config.inertial.clone();
        self.inertial = Some(Inertial::new(config, tuning, known_scale)?);
        Ok(())
    }

    /// The IMU setup, if any.
    pub fn imu_config(&self) -> Option<&InertialConfig> {
        self.inertial.as_ref().map(Inertial::config)
    }

    /// Adds IMU samples (body frame, rad/s and m/s^2, camera clock). Feed the samples up to
    /// (and including) a frame's time before tracking that frame: a keyframe's IMU is
    /// integrated once samples cover it.
    ///
    /// # Errors
    /// `InvalidInput` without [`Self::set_imu`], for non-finite values, timestamps not
    /// strictly increasing (within the batch or after the samples already added) or values
    /// that look like deg/s or g; the system is unchanged then.
    pub fn add_imu(&mut self, samples: &[ImuSample]) -> Result<(), SlamError> {
        let inertial = self.inertial.as_mut().ok_or_else(|| {
            SlamError::InvalidInput("add_imu: no IMU configured, call set_imu first".into())
        })?;
        inertial.add(samples)
    }

    /// Where the camera-IMU alignment of the current map stands (`None` without an IMU).
    pub fn inertial_alignment(&self) -> Option<&AlignmentStatus> {
        self.inertial.as_ref().map(Inertial::status)
    }

    /// The newest keyframe's IMU state once aligned: `(keyframe, timestamp s, body velocity
    /// in the world m/s, biases)`; refined by local inertial BA after the last refinement of
    /// the alignment, predicted from the previous keyframe before.
    pub fn keyframe_imu_state(&self) -> Option<(KeyFrameId, f64, Vector3<f64>, Bias)> {
        let (id, velocity, bias) = self.inertial.as_ref()?.newest_state()?;
        let timestamp = self.map.keyframe(id)?.timestamp();
        Some((id, timestamp, velocity, bias))
    }

    /// IMU preintegrated from the previous live keyframe (returned with it) to keyframe `kf`,
    /// at the newest keyframe's biases once aligned (zero before).
    pub fn keyframe_imu(&self, kf: KeyFrameId) -> Option<(KeyFrameId, &Preintegrated)> {
        self.inertial.as_ref()?.preintegrated(kf)
    }

    /// Gives `kf`, a keyframe since tracking resumed in a stored visual-inertial map, its
    /// IMU state once tracking has measured the body's velocity over its baseline (see
    /// `Inertial::resume`); a keyframe before that waits for the next.
    pub(super) fn resume_inertial(&mut self, kf: KeyFrameId) {
        let Some(inertial) = self.inertial.as_mut().filter(|i| i.resuming()) else {
            return;
        };
        if let Some((_, state)) = self.predictor.last_tracked_state(inertial) {
            inertial.resume(kf, state.v_w_b);
        }
    }

    /// Whether a frame at `timestamp` must become a keyframe for the camera-IMU alignment
    /// (not aligned yet and `inertial.init_keyframe_interval_s` since the newest keyframe).
    pub(super) fn inertial_keyframe_due(&self, timestamp: f64) -> bool {
        let waiting = self.inertial.as_ref().is_some_and(|i| !i.is_aligned());
        let newest = self.map.keyframes().map(|k| k.timestamp()).reduce(f64::max);
        let (tracking, inertial) = (&self.ctx.config.tracking, &self.ctx.config.inertial);
        waiting
            && self.tracker.matches_inliers > tracking.min_keyframe_inliers
            && newest.is_some_and(|t| timestamp - t >= inertial.init_keyframe_interval_s)
    }

    /// Preintegrates the new keyframe's IMU and, when due, aligns camera and IMU: a
    /// monocular map is then rescaled to metres (map, frame trajectory, motion model).
    pub(super) fn update_inertial(&mut self) -> Result<(), SlamError> {
        let Some(mut alignment) = self.inertial.as_mut().and_then(|i| i.try_align(&self.map))
        else {
            return Ok(());
        };
        if !self.ctx.config.sensor.has_depth() {
            // The mapping thread's edits land first, so none arrives in the old scale.
            self.finish_mapping()?;
            let s = alignment.scale;
            self.trajectory
                .rescale(s, &mut self.map, |map| rescale_map(map, s))?;
            self.tracker.rescale(s);
            self.predictor.clear();
            alignment.map_rescaled = true;
        }
        if let Some(inertial) = self.inertial.as_mut() {
            inertial.accept(alignment, &self.map);
        }
        Ok(())
    }
}
