//! [`Rig`]: the sensor and camera a map was built with, stored in map files so that a map is
//! only loaded into a system it fits.

use nalgebra::Isometry3;

/// The sensor and calibrated camera of the system that built a map.
///
/// A monocular map has an arbitrary scale, and keyframe features are pixels of one camera:
/// loaded into a system with another sensor or camera, such a map would track garbage.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    /// Sensor name as the systems spell it (`"mono"`, `"stereo"`, `"rgbd"`).
    pub sensor: String,
    /// Camera model as the bindings spell it ([`Rig::PINHOLE`], `"kannala_brandt"`); map
    /// files from before the model was recorded hold pinhole cameras.
    pub model: String,
    /// `fx, fy, cx, cy`, pixels.
    pub intrinsics: [f64; 4],
    /// Distortion: radial-tangential `k1, k2, p1, p2, k3` for the pinhole, Kannala-Brandt
    /// `k1, k2, k3, k4, 0` for the fisheye.
    pub distortion: [f64; 5],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// The second camera of an unrectified stereo pair (map files of version 7 on; older
    /// files hold none): its depths made the map's metric points.
    pub pair: Option<PairCamera>,
    /// Cameras after the first of a multi-camera rig (map files of version 8 on; older files hold none), in camera order: camera k = `cameras[k - 1]`.
    pub cameras: Vec<RigMember>,
}

/// A further camera of a multi-camera rig (camera 1 on; the fields above the list are
/// camera 0's): keyframe keypoints of camera `k` are pixels of this camera.
#[derive(Clone, Debug, PartialEq)]
#[allow(non_snake_case)]
pub struct RigMember {
    /// Camera model name, as [`Rig::model`].
    pub model: String,
    /// `fx, fy, cx, cy`, pixels.
    pub intrinsics: [f64; 4],
    /// Distortion, as [`Rig::distortion`].
    pub distortion: [f64; 5],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Pose of this camera in the first camera's frame (`p_c0 = T_c0_c p_c`), metres.
    pub T_c0_c: Isometry3<f64>,
    /// Whether the camera's keypoints come with depths (an RGB-D camera of the rig, or one
    /// with a stereo partner).
    pub has_depth: bool,
    /// The camera's stereo partner (map files of version 9 on; older files hold none): its
    /// depths come from matching into the partner's image, `T_left_right` the partner's pose
    /// in this camera.
    pub pair: Option<PairCamera>,
}

/// The second camera of an unrectified stereo pair, as map files record it: of the first
/// camera's image size.
#[derive(Clone, Debug, PartialEq)]
#[allow(non_snake_case)]
pub struct PairCamera {
    /// Camera model name, as [`Rig::model`].
    pub model: String,
    /// `fx, fy, cx, cy`, pixels.
    pub intrinsics: [f64; 4],
    /// Distortion, as [`Rig::distortion`].
    pub distortion: [f64; 5],
    /// Pose of the second camera in the first (`p_left = T_left_right p_right`), metres.
    pub T_left_right: Isometry3<f64>,
}

impl Rig {
    /// The model name of the pinhole camera (and of every map file older than version 5).
    pub const PINHOLE: &'static str = "pinhole";

    /// Number of observing cameras: the first and [`Rig::cameras`] (the unrectified
    /// [`Rig::pair`] only gives the first camera depths: it observes nothing itself).
    pub fn num_cameras(&self) -> usize {
        1 + self.cameras.len()
    }

    /// Why `self` (a map's) does not fit `system` (a system's), naming both sides; `None`
    /// when it does (intrinsics equal to 1e-6 relative).
    pub fn mismatch(&self, system: &Rig) -> Option<String> {
        if self.sensor != system.sensor {
            return Some(format!(
                "the map was built by a {:?} system, this system is {:?}",
                self.sensor, system.sensor
            ));
        }
        if let Some(m) = Lens::of_first(self).mismatch(&Lens::of_first(system)) {
            return Some(m);
        }
        if let Some(m) = self.cameras_mismatch(system) {
            return Some(m);
        }
        match (&self.pair, &system.pair) {
            (None, None) => None,
            (Some(_), None) => Some(
                "the map was built with an unrectified stereo pair, this system has none".into(),
            ),
            (None, Some(_)) => Some(
                "the map was built without an unrectified stereo pair, this system has one".into(),
            ),
            (Some(a), Some(b)) => a.mismatch(b),
        }
    }
}

impl Rig {
    /// Why the further cameras of `self` (a map's) are not `system`'s, naming both sides and
    /// the camera index; `None` when they are.
    fn cameras_mismatch(&self, system: &Rig) -> Option<String> {
        if self.num_cameras() != system.num_cameras() {
            return Some(format!(
                "the map was built with a rig of {} cameras, this system's has {}",
                self.num_cameras(),
                system.num_cameras()
            ));
        }
        self.cameras
            .iter()
            .zip(&system.cameras)
            .enumerate()
            .find_map(|(i, (a, b))| a.mismatch(b).map(|m| format!("camera {}: {m}", i + 1)))
    }
}

impl RigMember {
    /// Why `self` (a map's camera) is not `system`'s, naming both sides; `None` when it is.
    fn mismatch(&self, system: &RigMember) -> Option<String> {
        if let Some(m) = Lens::of_member(self).mismatch(&Lens::of_member(system)) {
            return Some(m);
        }
        if !close(&pose_values(&self.T_c0_c), &pose_values(&system.T_c0_c)) {
            return Some(format!(
                "the map was built with the camera at translation {:?} m, rotation {:?} \
                 (quaternion ijkw) in the first; this system's is at {:?} m, {:?}",
                self.T_c0_c.translation.vector.as_slice(),
                self.T_c0_c.rotation.coords.as_slice(),
                system.T_c0_c.translation.vector.as_slice(),
                system.T_c0_c.rotation.coords.as_slice()
            ));
        }
        if self.has_depth != system.has_depth {
            let with = |d: bool| if d { "with" } else { "without" };
            return Some(format!(
                "the map was built with the camera {} depth, this system's is {} depth",
                with(self.has_depth),
                with(system.has_depth)
            ));
        }
        match (&self.pair, &system.pair) {
            (None, None) => None,
            (Some(_), None) => {
                Some("the map was built with a stereo partner, this system's has none".into())
            }
            (None, Some(_)) => {
                Some("the map was built without a stereo partner, this system's has one".into())
            }
            (Some(a), Some(b)) => a.mismatch(b),
        }
    }
}

/// What a camera's pixels depend on, of the first camera or a [`RigMember`]: compared
/// alike for both.
struct Lens<'a> {
    model: &'a str,
    size: (u32, u32),
    intrinsics: &'a [f64; 4],
    distortion: &'a [f64; 5],
}

impl<'a> Lens<'a> {
    fn of_first(rig: &'a Rig) -> Self {
        Lens {
            model: &rig.model,
            size: (rig.width, rig.height),
            intrinsics: &rig.intrinsics,
            distortion: &rig.distortion,
        }
    }

    fn of_member(camera: &'a RigMember) -> Self {
        Lens {
            model: &camera.model,
            size: (camera.width, camera.height),
            intrinsics: &camera.intrinsics,
            distortion: &camera.distortion,
        }
    }

    /// Why `self` (a map's camera) is not `system`'s, naming both sides; `None` when it is
    /// (intrinsics and distortion equal to 1e-6 relative).
    fn mismatch(&self, system: &Lens) -> Option<String> {
        if self.model != system.model {
            return Some(format!(
                "the map was built with a {:?} camera model, this system's camera is {:?}",
                self.model, system.model
            ));
        }
        if self.size != system.size {
            return Some(format!(
                "the map was built with {}x{} images, this system's camera is {}x{}",
                self.size.0, self.size.1, system.size.0, system.size.1
            ));
        }
        (!close(self.intrinsics, system.intrinsics) || !close(self.distortion, system.distortion))
            .then(|| {
                format!(
                    "the map was built with the camera fx, fy, cx, cy = {:?}, distortion {:?}; \
                     this system's is {:?}, {:?}",
                    self.intrinsics, self.distortion, system.intrinsics, system.distortion
                )
            })
    }
}

/// Translation xyz (m) and quaternion ijkw of a pose, for comparing poses with [`close`].
fn pose_values(iso: &Isometry3<f64>) -> [f64; 7] {
    let (t, q) = (iso.translation.vector, iso.rotation.coords);
    [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
}

/// Equal to 1e-6 relative (1e-6 absolute below 1).
fn close(a: &[f64], b: &[f64]) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 1e-6 * x.abs().max(y.abs()).max(1.0))
}

impl PairCamera {
    /// Why `self` (a map's second camera) is not `system`'s, naming both; `None` when it is.
    fn mismatch(&self, system: &PairCamera) -> Option<String> {
        let same = self.model == system.model
            && close(&self.intrinsics, &system.intrinsics)
            && close(&self.distortion, &system.distortion)
            && close(
                &pose_values(&self.T_left_right),
                &pose_values(&system.T_left_right),
            );
        (!same).then(|| {
            format!(
                "the map was built with the second camera {} {:?}, distortion {:?} at \
                 translation {:?} m; this system's is {} {:?}, {:?} at {:?} m",
                self.model,
                self.intrinsics,
                self.distortion,
                self.T_left_right.translation.vector.as_slice(),
                system.model,
                system.intrinsics,
                system.distortion,
                system.T_left_right.translation.vector.as_slice()
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig(sensor: &str) -> Rig {
        Rig {
            sensor: sensor.into(),
            model: Rig::PINHOLE.into(),
            intrinsics: [517.3, 516.5, 318.6, 255.3],
            distortion: [0.26, -0.95, 0.0, 0.0, 1.16],
            width: 640,
            height: 480,
            pair: None,
            cameras: Vec::new(),
        }
    }

    #[test]
    fn mismatches_name_both_sides() {
        assert_eq!(rig("rgbd").mismatch(&rig("rgbd")), None);
        let m = rig("mono").mismatch(&rig("rgbd")).unwrap();
        assert!(m.contains("\"mono\"") && m.contains("\"rgbd\""), "{m}");
        let wide = Rig {
            width: 752,
            ..rig("rgbd")
        };
        let m = wide.mismatch(&rig("rgbd")).unwrap();
        assert!(m.contains("752x480") && m.contains("640x480"), "{m}");
        let other = Rig {
            intrinsics: [500.0, 500.0, 320.0, 240.0],
            ..rig("rgbd")
        };
        assert!(other.mismatch(&rig("rgbd")).unwrap().contains("500.0"));
        let fisheye = Rig {
            model: "kannala_brandt".into(),
            ..rig("rgbd")
        };
        let m = fisheye.mismatch(&rig("rgbd")).unwrap();
        assert!(
            m.contains("\"kannala_brandt\"") && m.contains("\"pinhole\""),
            "{m}"
        );
        let pair = |x: f64| PairCamera {
            model: Rig::PINHOLE.into(),
            intrinsics: [517.3, 516.5, 318.6, 255.3],
            distortion: [0.0; 5],
            T_left_right: Isometry3::translation(x, 0.0, 0.0),
        };
        let paired = |x| Rig {
            pair: Some(pair(x)),
            ..rig("stereo")
        };
        assert_eq!(paired(0.11).mismatch(&paired(0.11)), None);
        let m = paired(0.11).mismatch(&paired(0.2)).unwrap();
        assert!(m.contains("0.11") && m.contains("0.2"), "{m}");
        let m = paired(0.11).mismatch(&rig("stereo")).unwrap();
        assert!(m.contains("this system has none"), "{m}");
    }

    #[test]
    fn rig_cameras_mismatch_on_count_and_pose() {
        let member = |x: f64| RigMember {
            model: "kannala_brandt".into(),
            intrinsics: [284.0, 285.3, 417.2, 400.4],
            distortion: [-0.002, 0.039, -0.038, 0.007, 0.0],
            width: 848,
            height: 800,
            T_c0_c: Isometry3::translation(x, 0.0, 0.0),
            has_depth: false,
            pair: None,
        };
        let rig_of = |cameras| Rig {
            cameras,
            ..rig("mono")
        };
        let three = rig_of(vec![member(0.064), member(-0.1)]);
        assert_eq!(three.num_cameras(), 3);
        assert_eq!(three.mismatch(&three.clone()), None);
        let m = three.mismatch(&rig("mono")).unwrap();
        assert_eq!(
            m,
            "the map was built with a rig of 3 cameras, this system's has 1"
        );
        let moved = rig_of(vec![member(0.064), member(-0.25)]);
        let m = three.mismatch(&moved).unwrap();
        assert!(
            m.starts_with("camera 2: ") && m.contains("[-0.1, 0.0, 0.0]") && m.contains("[-0.25"),
            "{m}"
        );
        let deep = rig_of(vec![
            member(0.064),
            RigMember {
                has_depth: true,
                ..member(-0.1)
            },
        ]);
        let m = three.mismatch(&deep).unwrap();
        assert!(
            m.starts_with("camera 2: ") && m.contains("without depth"),
            "{m}"
        );
        let wide = rig_of(vec![
            RigMember {
                width: 640,
                ..member(0.064)
            },
            member(-0.1),
        ]);
        let m = three.mismatch(&wide).unwrap();
        assert!(
            m.starts_with("camera 1: ") && m.contains("848x800") && m.contains("640x800"),
            "{m}"
        );
        // A further camera's stereo partner: present or not, and where.
        let partnered = |x: f64| {
            rig_of(vec![
                member(0.064),
                RigMember {
                    has_depth: true,
                    pair: Some(PairCamera {
                        model: Rig::PINHOLE.into(),
                        intrinsics: [284.0, 285.3, 417.2, 400.4],
                        distortion: [0.0; 5],
                        T_left_right: Isometry3::translation(x, 0.0, 0.0),
                    }),
                    ..member(-0.1)
                },
            ])
        };
        assert_eq!(partnered(0.08).mismatch(&partnered(0.08)), None);
        let m = partnered(0.08).mismatch(&deep).unwrap();
        assert_eq!(
            m,
            "camera 2: the map was built with a stereo partner, this system's has none"
        );
        let m = deep.mismatch(&partnered(0.08)).unwrap();
        assert!(
            m.ends_with("without a stereo partner, this system's has one"),
            "{m}"
        );
        let m = partnered(0.08).mismatch(&partnered(0.12)).unwrap();
        assert!(m.starts_with("camera 2: ") && m.contains("0.12"), "{m}");
    }
}
