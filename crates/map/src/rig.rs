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

    /// Why `self` (a map's) does not fit `system` (a system's), naming both sides; `None`
    /// when it does (intrinsics equal to 1e-6 relative).
    pub fn mismatch(&self, system: &Rig) -> Option<String> {
        if self.sensor != system.sensor {
            return Some(format!(
                "the map was built by a {:?} system, this system is {:?}",
                self.sensor, system.sensor
            ));
        }
        if self.model != system.model {
            return Some(format!(
                "the map was built with a {:?} camera model, this system's camera is {:?}",
                self.model, system.model
            ));
        }
        if (self.width, self.height) != (system.width, system.height) {
            return Some(format!(
                "the map was built with {}x{} images, this system's camera is {}x{}",
                self.width, self.height, system.width, system.height
            ));
        }
        if !close(&self.intrinsics, &system.intrinsics)
            || !close(&self.distortion, &system.distortion)
        {
            return Some(format!(
                "the map was built with the camera fx, fy, cx, cy = {:?}, distortion {:?}; \
                 this system's is {:?}, {:?}",
                self.intrinsics, self.distortion, system.intrinsics, system.distortion
            ));
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

/// Equal to 1e-6 relative (1e-6 absolute below 1).
fn close(a: &[f64], b: &[f64]) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 1e-6 * x.abs().max(y.abs()).max(1.0))
}

impl PairCamera {
    /// Why `self` (a map's second camera) is not `system`'s, naming both; `None` when it is.
    fn mismatch(&self, system: &PairCamera) -> Option<String> {
        let pose = |iso: &Isometry3<f64>| {
            let (t, q) = (iso.translation.vector, iso.rotation.coords);
            [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
        };
        let same = self.model == system.model
            && close(&self.intrinsics, &system.intrinsics)
            && close(&self.distortion, &system.distortion)
            && close(&pose(&self.T_left_right), &pose(&system.T_left_right));
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
}
