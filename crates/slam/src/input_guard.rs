//! The checks every frame passes before it may change a system: the right `track_*` call for
//! the sensor, well-formed features, rectified stereo, increasing timestamps. Kept apart from
//! [`crate::SlamSystem`] so a background submitter can reject bad input at once, in the
//! caller's thread, with the same messages.

use crate::config::Sensor;
use crate::context::{InputShape, ObserverShape};
use crate::error::SlamError;
use crate::frame::{MonoInput, ObserverInput, RgbdInput, StereoInput};
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

    /// Checks an RGB-D frame of a single camera and, if it passes, accepts its timestamp:
    /// [`Self::accept_rgbd_rig`] without further cameras.
    pub fn accept_rgbd(&mut self, input: &RgbdInput<'_>) -> Result<(), SlamError> {
        self.accept_rgbd_from("track_rgbd", input, &[])
    }

    /// Checks an RGB-D rig's features (the first camera's `input`, then one `observers[k]`
    /// per further camera `k + 1`, in the order they were added) and, if they pass, accepts
    /// the timestamp. Every camera's features are checked before any is used, so a rejected
    /// frame changes nothing.
    pub fn accept_rgbd_rig(
        &mut self,
        input: &RgbdInput<'_>,
        observers: &[ObserverInput<'_>],
    ) -> Result<(), SlamError> {
        self.accept_rgbd_from("track_rgbd_rig", input, observers)
    }

    fn accept_rgbd_from(
        &mut self,
        method: &str,
        input: &RgbdInput<'_>,
        observers: &[ObserverInput<'_>],
    ) -> Result<(), SlamError> {
        self.expect_sensor(Sensor::Rgbd, method)?;
        if observers.len() != self.observers.len() {
            let n = self.observers.len();
            return Err(SlamError::InvalidInput(if observers.is_empty() {
                format!(
                    "{method} takes the first camera's features only, but this rig has {n} \
                     further camera(s): give theirs to track_rgbd_rig, or track its images \
                     (track)"
                )
            } else {
                format!(
                    "{method} got the features of {} further camera(s), but this rig has {n} \
                     (added with add_camera): give one per further camera, in the order they \
                     were added",
                    observers.len()
                )
            }));
        }
        input.validate(&self.shape)?;
        for (k, (observed, shape)) in observers.iter().zip(&self.observers).enumerate() {
            // Camera 0 is the first camera; further cameras follow it in the rig's order.
            self.check_observer(observed, shape, input.colors.is_some())
                .map_err(|why| SlamError::InvalidInput(format!("camera {}: {why}", k + 1)))?;
        }
        self.advance(input.timestamp)
    }

    /// Checks a further camera's features against its `shape`: what every camera's
    /// features must be (as the first camera's, in its own image size), colours as the first
    /// camera's (all given or none, so the frame's colours stay one per keypoint), and depth
    /// exactly for a depth camera. The reason, without the camera, on failure.
    fn check_observer(
        &self,
        observed: &ObserverInput<'_>,
        shape: &ObserverShape,
        first_has_colors: bool,
    ) -> Result<(), String> {
        let n = observed.keypoints.len();
        // Empty colours are none, as `RgbdInput::colors == None`.
        let colors = (!observed.colors.is_empty()).then_some(observed.colors);
        let as_mono = MonoInput {
            timestamp: 0.0,
            keypoints: observed.keypoints,
            descriptors: observed.descriptors,
            colors,
        };
        let own = InputShape {
            width: shape.width,
            height: shape.height,
            ..self.shape
        };
        as_mono.validate(&own).map_err(|e| match e {
            SlamError::InvalidInput(why) => why,
            other => other.to_string(),
        })?;
        if first_has_colors && colors.is_none() && n > 0 {
            return Err(format!(
                "no colours for its {n} keypoints, but camera 0's were given: give every \
                 camera's colours or none"
            ));
        }
        if !first_has_colors && colors.is_some() {
            return Err(format!(
                "{n} colours given, but camera 0 has none: give every camera's colours or none"
            ));
        }
        match (observed.depth_m, shape.has_depth) {
            (Some(depth), true) if depth.len() != n => Err(format!(
                "got {n} keypoints and {} depths: lengths must match",
                depth.len()
            )),
            (None, true) => Err("added with depth (has_depth), but no depths were given".into()),
            (Some(_), false) => {
                Err("added without depth (has_depth false), but depths were given".into())
            }
            _ => Ok(()),
        }
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
        let further: Vec<(usize, usize)> = self
            .observers
            .iter()
            .flat_map(ObserverShape::images)
            .map(|(size, _)| size)
            .collect();
        let cameras = first + further.len();
        if camera >= cameras {
            return Err(SlamError::InvalidInput(format!(
                "mask for camera {camera}, but a {} system has {cameras} camera(s)",
                self.sensor.name()
            )));
        }
        let size = match camera.checked_sub(first) {
            None => (self.shape.width as usize, self.shape.height as usize),
            Some(o) => further[o],
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
        self.expect_sensor(sensor, method)
    }

    fn expect_sensor(&self, sensor: Sensor, method: &str) -> Result<(), SlamError> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::SlamConfig;
    use crate::system::SlamSystem;
    use crate::tracking::TrackingState;
    use ferroslam_features::{Descriptor, Keypoint};
    use ferroslam_geometry::camera::test_cameras;
    use nalgebra::Isometry3;

    fn keypoint(x: f32, y: f32, octave: u8) -> Keypoint {
        Keypoint {
            x,
            y,
            octave,
            angle_deg: 0.0,
            response: 1.0,
        }
    }

    /// An RGB-D guard of a 640x480 first camera, a 320x240 depth camera 1 and a 640x480
    /// camera 2 without depth.
    fn rig_guard() -> InputGuard {
        let shape = InputShape {
            n_levels: 8,
            width: 640,
            height: 480,
        };
        let observer = |width, height, has_depth| ObserverShape {
            width,
            height,
            has_depth,
            paired: false,
        };
        InputGuard::new(Sensor::Rgbd, shape, false)
            .with_observers(vec![observer(320, 240, true), observer(640, 480, false)])
    }

    /// Two keypoints per camera, inside every camera's image.
    struct Features {
        keypoints: Vec<Keypoint>,
        descriptors: Vec<Descriptor>,
        depth_m: Vec<f32>,
    }

    fn features() -> Features {
        Features {
            keypoints: vec![keypoint(10.0, 20.0, 0), keypoint(300.0, 200.0, 1)],
            descriptors: vec![[1; 32], [2; 32]],
            depth_m: vec![1.5, 2.0],
        }
    }

    fn first(t: f64, f: &Features) -> RgbdInput<'_> {
        RgbdInput {
            timestamp: t,
            keypoints: &f.keypoints,
            descriptors: &f.descriptors,
            depth_m: &f.depth_m,
            colors: None,
        }
    }

    fn observer<'a>(f: &'a Features, depth_m: Option<&'a [f32]>) -> ObserverInput<'a> {
        ObserverInput {
            keypoints: &f.keypoints,
            descriptors: &f.descriptors,
            colors: &[],
            depth_m,
        }
    }

    fn message(result: Result<(), SlamError>) -> String {
        match result {
            Err(SlamError::InvalidInput(m)) => m,
            other => panic!("expected InvalidInput, got {other:?}"),
        }
    }

    #[test]
    fn a_rig_needs_one_observer_per_further_camera() {
        let mut guard = rig_guard();
        let f = features();
        let m = message(guard.accept_rgbd(&first(0.0, &f)));
        assert!(
            m.contains("track_rgbd takes the first camera's features only"),
            "{m}"
        );
        assert!(
            m.contains("2 further camera(s)") && m.contains("track_rgbd_rig"),
            "{m}"
        );
        let one = [observer(&f, Some(&f.depth_m))];
        let m = message(guard.accept_rgbd_rig(&first(0.0, &f), &one));
        assert!(
            m.contains("features of 1 further camera(s), but this rig has 2"),
            "{m}"
        );
        let both = [observer(&f, Some(&f.depth_m)), observer(&f, None)];
        guard.accept_rgbd_rig(&first(0.0, &f), &both).unwrap();
        // Accepted: the timestamp moved on.
        let m = message(guard.accept_rgbd_rig(&first(0.0, &f), &both));
        assert!(m.contains("not after"), "{m}");
    }

    #[test]
    fn each_observer_error_names_its_camera_and_changes_nothing() {
        let mut guard = rig_guard();
        let f = features();
        let short = &f.depth_m[..1];
        let mut nan = features();
        nan.keypoints[1].y = f32::NAN;
        let mut outside = features();
        // Inside camera 0's and camera 2's 640x480, outside camera 1's 320x240.
        outside.keypoints[1].x = 400.0;
        let mut deep = features();
        deep.keypoints[0].octave = 8;
        let colors = [[7u8; 3]; 2];
        let with_colors = |f| ObserverInput {
            colors: &colors,
            ..observer(f, None)
        };
        let few_descriptors = ObserverInput {
            descriptors: &f.descriptors[..1],
            ..observer(&f, None)
        };
        let cases: Vec<([ObserverInput<'_>; 2], &str)> = vec![
            (
                [observer(&f, None), observer(&f, None)],
                "camera 1: added with depth (has_depth), but no depths were given",
            ),
            (
                [
                    observer(&f, Some(&f.depth_m)),
                    observer(&f, Some(&f.depth_m)),
                ],
                "camera 2: added without depth (has_depth false), but depths were given",
            ),
            (
                [observer(&f, Some(short)), observer(&f, None)],
                "camera 1: got 2 keypoints and 1 depths: lengths must match",
            ),
            (
                [observer(&f, Some(&f.depth_m)), few_descriptors],
                "camera 2: got 2 keypoints and 1 descriptors: lengths must match",
            ),
            (
                [observer(&nan, Some(&f.depth_m)), observer(&f, None)],
                "camera 1: keypoint 1 has non-finite coordinates",
            ),
            (
                [observer(&outside, Some(&f.depth_m)), observer(&f, None)],
                "camera 1: keypoint 1 at (400, 200) px lies outside the camera's 320x240 image",
            ),
            (
                [observer(&f, Some(&f.depth_m)), observer(&deep, None)],
                "camera 2: keypoint 0 has octave 8 but the pyramid has 8 levels",
            ),
            (
                [observer(&f, Some(&f.depth_m)), with_colors(&f)],
                "camera 2: 2 colours given, but camera 0 has none",
            ),
        ];
        for (observers, expected) in &cases {
            let m = message(guard.accept_rgbd_rig(&first(1.0, &f), observers));
            assert!(m.starts_with(expected), "{m}\nexpected: {expected}");
        }
        let first_colors = [[1u8; 3]; 2];
        let coloured = RgbdInput {
            colors: Some(&first_colors),
            ..first(1.0, &f)
        };
        let m = message(guard.accept_rgbd_rig(
            &coloured,
            &[observer(&f, Some(&f.depth_m)), observer(&f, None)],
        ));
        assert!(
            m.starts_with("camera 1: no colours for its 2 keypoints"),
            "{m}"
        );
        let few_colors = ObserverInput {
            colors: &colors[..1],
            ..observer(&f, Some(&f.depth_m))
        };
        let m = message(guard.accept_rgbd_rig(&coloured, &[few_colors, with_colors(&f)]));
        assert!(
            m.starts_with("camera 1: got 2 keypoints and 1 colors"),
            "{m}"
        );
        // Nothing was accepted: the first timestamp is still free.
        let fine = [
            ObserverInput {
                depth_m: Some(&f.depth_m),
                ..with_colors(&f)
            },
            with_colors(&f),
        ];
        guard.accept_rgbd_rig(&coloured, &fine).unwrap();
    }

    #[test]
    fn a_single_camera_takes_no_observers() {
        let shape = InputShape {
            n_levels: 8,
            width: 640,
            height: 480,
        };
        let mut guard = InputGuard::new(Sensor::Rgbd, shape, false);
        let f = features();
        let m = message(guard.accept_rgbd_rig(&first(0.0, &f), &[observer(&f, None)]));
        assert!(
            m.contains("features of 1 further camera(s), but this rig has 0"),
            "{m}"
        );
        guard.accept_rgbd_rig(&first(0.0, &f), &[]).unwrap();
        guard.accept_rgbd(&first(0.1, &f)).unwrap();
    }

    /// Through the system: a rejected rig frame leaves it untracked, a good one starts the map
    /// with every camera's keypoints.
    #[test]
    fn the_system_tracks_a_rig_from_features_and_refuses_bad_ones_unchanged() {
        let (_, camera) = test_cameras()[0];
        let mut system = SlamSystem::new(camera, SlamConfig::for_sensor(Sensor::Rgbd)).unwrap();
        let T_c0_c1 = Isometry3::translation(0.1, 0.0, 0.0);
        system.add_camera(camera, T_c0_c1, true).unwrap();
        // More than the 500 keypoints an RGB-D map needs to start, on a grid, all unique.
        let f = Features {
            keypoints: (0..600)
                .map(|i| {
                    keypoint(
                        20.0 + (i % 30) as f32 * 20.0,
                        20.0 + (i / 30) as f32 * 22.0,
                        0,
                    )
                })
                .collect(),
            descriptors: (0..600u32)
                .map(|i| {
                    let mut d = [0x5a; 32];
                    d[..4].copy_from_slice(&i.to_le_bytes());
                    d
                })
                .collect(),
            depth_m: vec![2.0; 600],
        };
        let bad = system.track_rgbd_rig(&first(0.0, &f), &[observer(&f, None)]);
        assert!(
            matches!(&bad, Err(SlamError::InvalidInput(m)) if m.starts_with("camera 1: added with depth")),
            "{bad:?}"
        );
        assert_eq!(system.state(), TrackingState::NotInitialized);
        assert!(system.frame_trajectory().is_empty());
        let result = system
            .track_rgbd_rig(&first(0.0, &f), &[observer(&f, Some(&f.depth_m))])
            .unwrap();
        assert_eq!(result.state, TrackingState::Ok);
        let keyframe = system.map().keyframe_ids()[0];
        let features = system.map().keyframe(keyframe).unwrap().features();
        assert_eq!(features.len(), 1200);
        assert_eq!(features.camera_range(1), 600..1200);
    }
}
