//! Rolling shutter: image lines exposed one after another, and where a point is seen from
//! the pose the camera had when its line was read out.
//!
//! A rolling-shutter camera reads line `l` at `t_ref + (l - l_ref) * line_delay_s`, where
//! `t_ref` is the frame's timestamp and `l_ref` the line that timestamp refers to. Over one
//! readout (10-30 ms for consumer cameras) the camera's motion is modelled as constant:
//! with `xi_dot = [v; w]` the velocity of `T_c_w` (metres per second, radians per second,
//! tangent order of [`crate::se3`]), the pose at offset `dt` seconds is
//!
//! `T_c(dt)_w = D(dt) * T_c_w` with `D(dt) = [exp(dt w) | dt v]`,
//!
//! a rigid motion in the reference camera frame (left, as every perturbation in this crate).
//! `w` is the angular rate of the points in the camera frame: a camera turning by `+Omega`
//! in its own frame has `w = -Omega`. `dt = 0` (a global shutter, or the reference line)
//! gives `T_c_w` exactly, so global-shutter arithmetic is unchanged.
//!
//! The line of an observation is its measured pixel coordinate, not the re-projected one:
//! the offset is a constant of each observation (as VINS-Mono and Basalt treat it), which
//! keeps the residual's Jacobians those of a pose and a velocity.

// Frame-named variables (`T_c_w`, `R_d`) follow the crate's pose convention.
#![allow(non_snake_case)]

use nalgebra::{Isometry3, Matrix3, Matrix3x6, Point3, Translation3, Vector2, Vector3, Vector6};

use crate::camera::CameraModel;
use crate::{so3, GeometryError};

/// The order in which a sensor reads its lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadoutDirection {
    /// Rows, top (y = 0) first: most CMOS sensors mounted upright.
    TopToBottom,
    /// Rows, bottom first: a sensor mounted upside down.
    BottomToTop,
    /// Columns, left (x = 0) first: a sensor mounted on its side.
    LeftToRight,
    /// Columns, right first.
    RightToLeft,
}

/// When each line of an image is read, relative to the frame's timestamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RollingShutter {
    line_delay_s: f64,
    direction: ReadoutDirection,
    reference_line: f64,
}

impl RollingShutter {
    /// A global shutter: every line at the frame's timestamp.
    pub fn global() -> Self {
        Self {
            line_delay_s: 0.0,
            direction: ReadoutDirection::TopToBottom,
            reference_line: 0.0,
        }
    }

    /// Lines `line_delay_s` seconds apart (>= 0, finite), read in `direction`; the frame's
    /// timestamp is the time of line `reference_line` (pixels along the readout direction,
    /// counted from the line read first).
    pub fn new(
        line_delay_s: f64,
        direction: ReadoutDirection,
        reference_line: f64,
    ) -> Result<Self, GeometryError> {
        if !(line_delay_s.is_finite() && line_delay_s >= 0.0) {
            return Err(GeometryError::InvalidParameter {
                name: "line_delay_s",
                value: line_delay_s,
                reason: "must be finite and >= 0 (0 = global shutter)",
            });
        }
        if !reference_line.is_finite() {
            return Err(GeometryError::InvalidParameter {
                name: "reference_line",
                value: reference_line,
                reason: "must be finite",
            });
        }
        Ok(Self {
            line_delay_s,
            direction,
            reference_line,
        })
    }

    /// A readout of `readout_s` seconds over `lines` lines (the image height for row
    /// readouts), timestamped at the middle line: the usual convention of drivers that
    /// stamp mid-exposure, and the one that keeps offsets within half a readout.
    pub fn from_readout(
        readout_s: f64,
        lines: u32,
        direction: ReadoutDirection,
    ) -> Result<Self, GeometryError> {
        if lines < 2 {
            return Err(GeometryError::InvalidParameter {
                name: "lines",
                value: f64::from(lines),
                reason: "a readout spans at least 2 lines",
            });
        }
        let delay = readout_s / f64::from(lines - 1);
        Self::new(delay, direction, 0.5 * f64::from(lines - 1))
    }

    /// Seconds between two consecutive lines.
    pub fn line_delay_s(&self) -> f64 {
        self.line_delay_s
    }

    /// The order of the lines.
    pub fn direction(&self) -> ReadoutDirection {
        self.direction
    }

    /// True when every line is read at the frame's timestamp.
    pub fn is_global(&self) -> bool {
        self.line_delay_s == 0.0
    }

    /// Seconds from the frame's timestamp to the readout of the line through `pixel`
    /// (raw image pixels; `extent` is the image size along x and y, needed for the
    /// directions that start at the far edge).
    pub fn time_offset_s(&self, pixel: &Vector2<f64>, extent: &Vector2<f64>) -> f64 {
        if self.is_global() {
            return 0.0;
        }
        let line = match self.direction {
            ReadoutDirection::TopToBottom => pixel.y,
            ReadoutDirection::BottomToTop => extent.y - 1.0 - pixel.y,
            ReadoutDirection::LeftToRight => pixel.x,
            ReadoutDirection::RightToLeft => extent.x - 1.0 - pixel.x,
        };
        (line - self.reference_line) * self.line_delay_s
    }
}

/// The motion `D(dt) = [exp(dt w) | dt v]` of the camera frame over `dt` seconds at the
/// velocity `xi_dot = [v; w]` of `T_c_w`.
pub fn motion_over(xi_dot: &Vector6<f64>, dt: f64) -> Isometry3<f64> {
    let v = xi_dot.fixed_rows::<3>(0).into_owned();
    let w = xi_dot.fixed_rows::<3>(3).into_owned();
    Isometry3::from_parts(Translation3::from(dt * v), so3::exp(&(dt * w)))
}

/// The motion over a readout of a camera mounted at `T_c_c0` on a rig whose first camera
/// moves by `D_c0` (see [`motion_over`]): the rig is rigid, so the camera sees the world
/// from `T_c_c0 * D_c0 * T_c0_w = (T_c_c0 * D_c0 * T_c_c0^-1) * T_c_w`; `D_c0` itself for
/// the first camera (`None`).
pub fn mounted_motion(D_c0: &Isometry3<f64>, T_c_c0: Option<&Isometry3<f64>>) -> Isometry3<f64> {
    T_c_c0.map_or(*D_c0, |T| T * D_c0 * T.inverse())
}

/// The velocity `[v; w]` of `T_c_w` that moves `T_c0_w` onto `T_c1_w` in `dt` seconds
/// (`dt != 0`): the inverse of [`motion_over`], `motion_over(xi_dot, dt) * T_c0_w == T_c1_w`.
/// A motion model's velocity, and the prior of a frame's velocity in tracking.
pub fn velocity_between(
    T_c0_w: &Isometry3<f64>,
    T_c1_w: &Isometry3<f64>,
    dt: f64,
) -> Option<Vector6<f64>> {
    if dt == 0.0 || !dt.is_finite() {
        return None;
    }
    let D = T_c1_w * T_c0_w.inverse();
    let w = so3::log(&D.rotation) / dt;
    let v = D.translation.vector / dt;
    Some(Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z))
}

/// A world point `p_w` in the camera frame at offset `dt` seconds, with the Jacobians a
/// rolling-shutter residual needs.
#[derive(Debug, Clone, PartialEq)]
pub struct PointAtOffset {
    /// `p_c(dt) = D(dt) * T_c_w * p_w`, metres.
    pub p_c: Vector3<f64>,
    /// d p_c(dt) / d delta for `T_c_w <- exp(delta) * T_c_w`, delta = [rho; phi] in c.
    pub d_p_c_d_pose: Matrix3x6<f64>,
    /// d p_c(dt) / d xi_dot, xi_dot = [v; w].
    pub d_p_c_d_velocity: Matrix3x6<f64>,
}

/// `p_c(dt)` of [`point_at_offset`] alone (the same arithmetic), for a residual that needs no
/// Jacobian.
pub fn position_at_offset(
    T_c_w: &Isometry3<f64>,
    xi_dot: &Vector6<f64>,
    dt: f64,
    p_w: &Point3<f64>,
) -> Vector3<f64> {
    rotation_at_offset(T_c_w, xi_dot, dt, p_w).3
}

/// `(T_c_w * p_w, R(dt), R(dt) * T_c_w * p_w, p_c(dt))`: the motion's rotation over `dt` and
/// the point before and after it.
fn rotation_at_offset(
    T_c_w: &Isometry3<f64>,
    xi_dot: &Vector6<f64>,
    dt: f64,
    p_w: &Point3<f64>,
) -> (Vector3<f64>, Matrix3<f64>, Vector3<f64>, Vector3<f64>) {
    let p_c0 = (T_c_w * p_w).coords;
    let w = xi_dot.fixed_rows::<3>(3).into_owned();
    let R_d = so3::exp(&(dt * w)).to_rotation_matrix().into_inner();
    let rotated = R_d * p_c0;
    let p_c = rotated + dt * xi_dot.fixed_rows::<3>(0).into_owned();
    (p_c0, R_d, rotated, p_c)
}

/// `p_w` seen at offset `dt` from the pose `T_c_w` moving at `xi_dot` (see the module doc),
/// with its Jacobians.
pub fn point_at_offset(
    T_c_w: &Isometry3<f64>,
    xi_dot: &Vector6<f64>,
    dt: f64,
    p_w: &Point3<f64>,
) -> PointAtOffset {
    let (p_c0, R_d, rotated, p_c) = rotation_at_offset(T_c_w, xi_dot, dt, p_w);
    let w = xi_dot.fixed_rows::<3>(3).into_owned();

    let mut d_p_c0_d_pose = Matrix3x6::zeros();
    d_p_c0_d_pose
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    d_p_c0_d_pose
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&-so3::hat(&p_c0));

    // exp(phi + d) = exp(J_l(phi) d) exp(phi): the rotated point moves by -[R p]x J_l dt dw.
    let mut d_p_c_d_velocity = Matrix3x6::zeros();
    d_p_c_d_velocity
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(dt * Matrix3::identity()));
    d_p_c_d_velocity
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(-dt * so3::hat(&rotated) * so3::left_jacobian(&(dt * w))));

    PointAtOffset {
        p_c,
        d_p_c_d_pose: R_d * d_p_c0_d_pose,
        d_p_c_d_velocity,
    }
}

/// Fixed-point steps of [`predicted_readout_motion`]: each moves the predicted pixel by the
/// change of its line's motion, which is the previous step's line error times about
/// `|w| * line_delay * focal length` (0.05 for fr1's Kinect at 2 rad/s in an image corner,
/// measured in the tests), so three steps leave under a thousandth of a pixel.
const PREDICTION_STEPS: usize = 3;

/// The motion `D(dt)` (see the module doc) of a camera from its reference line to the line
/// on which it sees the point `p_c` (the reference line's camera frame, metres), the camera
/// mounted at `T_c_c0` on a rig whose first camera moves at `xi_dot` (`None`: the first
/// camera, moving at `xi_dot` itself; see [`mounted_motion`]): the line is that of the pixel
/// `D(dt) * p_c` projects to, found by iteration. For projection searches, where the
/// keypoint (and so its line) is not known yet.
///
/// `None` for a global shutter or a point `camera` does not project, where the reference
/// pose itself is the one to project through (global-shutter arithmetic unchanged).
pub fn predicted_readout_motion(
    camera: &CameraModel,
    xi_dot: &Vector6<f64>,
    T_c_c0: Option<&Isometry3<f64>>,
    p_c: &Vector3<f64>,
) -> Option<Isometry3<f64>> {
    if camera.rolling_shutter().is_global() {
        return None;
    }
    let mut uv_raw = camera.project_raw(p_c)?;
    let mut motion = Isometry3::identity();
    for _ in 0..PREDICTION_STEPS {
        motion = mounted_motion(&motion_over(xi_dot, camera.time_offset_s(&uv_raw)), T_c_c0);
        match camera.project_raw(&(motion * Point3::from(*p_c)).coords) {
            Some(uv) => uv_raw = uv,
            None => break,
        }
    }
    Some(motion)
}

/// The keypoint `uv` (core pixels) seen from its line's pose `D * T_c_w`, moved to where the
/// reference pose `T_c_w` sees the same point: `uv + project(p_c) - project(D * p_c)`, with
/// `p_c` the point's estimate in the reference camera frame. A residual against the
/// reference pose's projection of a nearby estimate `p_c + e` then equals the residual
/// against the line's pose up to `(J(D p_c) R_D - J(p_c)) e`, a fraction `|R_D - I|` (under
/// 2 % over a hand-held readout) of the reprojection change: solvers that know one pose per
/// image (Sim(3) alignment, PnP) see the rolling shutter through their measurements.
///
/// `None` where `camera` projects `p_c` or `D * p_c` nowhere.
#[allow(non_snake_case)]
pub fn pixel_at_reference_line(
    camera: &CameraModel,
    uv: &Vector2<f64>,
    p_c: &Vector3<f64>,
    D: &Isometry3<f64>,
) -> Option<Vector2<f64>> {
    let at_reference = camera.project(p_c)?;
    let at_line = camera.project(&(D * Point3::from(*p_c)).coords)?;
    Some(uv + (at_reference - at_line))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3;
    use crate::testing::check_jacobian;
    use approx::assert_relative_eq;
    use nalgebra::{DMatrix, DVector, UnitQuaternion};

    fn pose() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 1.1),
            UnitQuaternion::from_euler_angles(0.2, -0.4, 0.7),
        )
    }

    // A hand-held camera's velocity: 0.5 m/s and 2 rad/s (fr1/rpy peaks near 1.5 rad/s).
    fn velocity() -> Vector6<f64> {
        Vector6::new(0.3, -0.4, 0.1, 1.2, -0.9, 1.3)
    }

    const DT: f64 = 0.012;

    fn p_w() -> Point3<f64> {
        Point3::new(0.4, 0.1, 2.5)
    }

    fn dvec(v: &Vector3<f64>) -> DVector<f64> {
        DVector::from_column_slice(v.as_slice())
    }

    #[test]
    fn zero_offset_is_the_global_shutter_pose() {
        let at = point_at_offset(&pose(), &velocity(), 0.0, &p_w());
        assert_eq!(at.p_c, (pose() * p_w()).coords);
        assert_eq!(motion_over(&velocity(), 0.0), Isometry3::identity());
    }

    #[test]
    fn point_is_moved_by_the_motion_over_the_offset() {
        let at = point_at_offset(&pose(), &velocity(), DT, &p_w());
        let expected = motion_over(&velocity(), DT) * pose() * p_w();
        assert_relative_eq!(at.p_c, expected.coords, epsilon = 1e-14);
    }

    #[test]
    fn velocity_between_inverts_motion_over() {
        let T1 = motion_over(&velocity(), 0.033) * pose();
        let xi_dot = velocity_between(&pose(), &T1, 0.033).unwrap();
        assert_relative_eq!(xi_dot, velocity(), epsilon = 1e-12);
        assert!(velocity_between(&pose(), &T1, 0.0).is_none());
    }

    #[test]
    fn jacobian_of_pose_matches_numeric() {
        let at = point_at_offset(&pose(), &velocity(), DT, &p_w());
        let f = |d: &DVector<f64>| {
            let delta = Vector6::from_column_slice(d.as_slice());
            let moved = se3::exp(&delta) * pose();
            dvec(&point_at_offset(&moved, &velocity(), DT, &p_w()).p_c)
        };
        let analytic = DMatrix::from_column_slice(3, 6, at.d_p_c_d_pose.as_slice());
        check_jacobian("d_p_c_d_pose", &analytic, f, &DVector::zeros(6), 1e-6, 1e-7);
    }

    #[test]
    fn jacobian_of_velocity_matches_numeric() {
        let at = point_at_offset(&pose(), &velocity(), DT, &p_w());
        let f = |x: &DVector<f64>| {
            let xi_dot = Vector6::from_column_slice(x.as_slice());
            dvec(&point_at_offset(&pose(), &xi_dot, DT, &p_w()).p_c)
        };
        let analytic = DMatrix::from_column_slice(3, 6, at.d_p_c_d_velocity.as_slice());
        let x0 = DVector::from_column_slice(velocity().as_slice());
        check_jacobian("d_p_c_d_velocity", &analytic, f, &x0, 1e-6, 1e-7);
    }

    #[test]
    fn time_offsets_follow_the_readout_direction() {
        let extent = Vector2::new(640.0, 480.0);
        let rs = RollingShutter::from_readout(0.0239, 480, ReadoutDirection::TopToBottom).unwrap();
        let top = rs.time_offset_s(&Vector2::new(10.0, 0.0), &extent);
        let bottom = rs.time_offset_s(&Vector2::new(10.0, 479.0), &extent);
        assert_relative_eq!(bottom - top, 0.0239, epsilon = 1e-15);
        assert_relative_eq!(top, -0.5 * 0.0239, epsilon = 1e-15);
        assert_eq!(rs.time_offset_s(&Vector2::new(3.0, 239.5), &extent), 0.0);

        let up = RollingShutter::new(1e-4, ReadoutDirection::BottomToTop, 0.0).unwrap();
        assert_relative_eq!(up.time_offset_s(&Vector2::new(0.0, 479.0), &extent), 0.0);
        assert_relative_eq!(up.time_offset_s(&Vector2::new(0.0, 0.0), &extent), 479e-4);
        let left = RollingShutter::new(1e-4, ReadoutDirection::LeftToRight, 0.0).unwrap();
        assert_relative_eq!(left.time_offset_s(&Vector2::new(100.0, 7.0), &extent), 1e-2);
        let right = RollingShutter::new(1e-4, ReadoutDirection::RightToLeft, 0.0).unwrap();
        assert_relative_eq!(right.time_offset_s(&Vector2::new(639.0, 7.0), &extent), 0.0);
    }

    /// Every test camera of both models, reading its rows over fr1's 15 ms.
    fn readout_cameras() -> Vec<CameraModel> {
        use crate::camera::{test_cameras, test_fisheye_cameras};
        test_cameras()
            .into_iter()
            .map(|(_, c)| CameraModel::from(c))
            .chain(test_fisheye_cameras().into_iter().map(|(_, c)| c.into()))
            .map(|c| {
                c.with_readout(0.015, ReadoutDirection::TopToBottom)
                    .unwrap()
            })
            .collect()
    }

    /// Points across the image of `camera`, 1.5-3 m deep, in its camera frame.
    fn points_in_view(camera: &CameraModel) -> Vec<Vector3<f64>> {
        let (w, h) = camera.size();
        let mut out = Vec::new();
        for (fu, fv, z) in [
            (0.1, 0.05, 1.5),
            (0.5, 0.3, 2.0),
            (0.9, 0.95, 3.0),
            (0.2, 0.8, 2.5),
        ] {
            let uv = Vector2::new(fu * f64::from(w), fv * f64::from(h));
            let ray = camera.unproject_raw(&uv).unwrap();
            out.push(ray * (z / ray.z));
        }
        out
    }

    #[test]
    fn predicted_motion_is_that_of_the_line_the_point_lands_on() {
        for camera in readout_cameras() {
            let mut largest_shift_px = 0.0f64;
            for p_c in points_in_view(&camera) {
                let D = predicted_readout_motion(&camera, &velocity(), None, &p_c).unwrap();
                let uv = camera.project_raw(&(D * Point3::from(p_c)).coords).unwrap();
                let at_line = motion_over(&velocity(), camera.time_offset_s(&uv));
                let uv_line = camera.project_raw(&(at_line * Point3::from(p_c)).coords);
                // The fixed point: the line's own motion sends the point to the same pixel.
                assert_relative_eq!(uv, uv_line.unwrap(), epsilon = 0.01);
                let reference = camera.project_raw(&p_c).unwrap();
                largest_shift_px = largest_shift_px.max((uv - reference).norm());
            }
            assert!(
                largest_shift_px > 2.0,
                "the readout must show: {largest_shift_px} px"
            );
        }
        let global = readout_cameras()[0].with_readout(0.0, ReadoutDirection::TopToBottom);
        let p_c = Vector3::new(0.1, 0.2, 2.0);
        assert!(predicted_readout_motion(&global.unwrap(), &velocity(), None, &p_c).is_none());
        let behind = Vector3::new(0.1, 0.2, -2.0);
        assert!(
            predicted_readout_motion(&readout_cameras()[0], &velocity(), None, &behind).is_none()
        );
    }

    #[test]
    fn a_mounted_camera_moves_with_the_rig() {
        // A camera yawed 90 degrees and 12 cm to the side: the world it sees at each line
        // is the one the first camera's motion shows it, `T_c_c0 * D_c0 * T_c0_w`.
        let T_c_c0 = Isometry3::new(
            Vector3::new(0.12, -0.02, 0.05),
            Vector3::new(0.0, 1.57, 0.1),
        );
        let D_c0 = motion_over(&velocity(), 0.011);
        let T_c0_w = Isometry3::new(Vector3::new(0.3, 0.1, -0.2), Vector3::new(0.1, 0.2, -0.3));
        let p_w = Point3::new(0.5, -0.4, 3.0);
        let via_rig = T_c_c0 * (D_c0 * (T_c0_w * p_w));
        let via_camera = mounted_motion(&D_c0, Some(&T_c_c0)) * (T_c_c0 * T_c0_w * p_w);
        assert_relative_eq!(via_rig, via_camera, epsilon = 1e-12);
        assert_eq!(mounted_motion(&D_c0, None), D_c0);
        for camera in readout_cameras() {
            for p_c in points_in_view(&camera) {
                let D = predicted_readout_motion(&camera, &velocity(), Some(&T_c_c0), &p_c);
                let D = D.unwrap();
                let uv = camera.project_raw(&(D * Point3::from(p_c)).coords).unwrap();
                let at_line = motion_over(&velocity(), camera.time_offset_s(&uv));
                let at_line = mounted_motion(&at_line, Some(&T_c_c0));
                let uv_line = camera.project_raw(&(at_line * Point3::from(p_c)).coords);
                assert_relative_eq!(uv, uv_line.unwrap(), epsilon = 0.01);
            }
        }
    }

    #[test]
    fn a_keypoint_moved_to_the_reference_line_keeps_its_residuals() {
        for camera in readout_cameras() {
            for p_c in points_in_view(&camera) {
                let D = predicted_readout_motion(&camera, &velocity(), None, &p_c).unwrap();
                let seen = camera.project(&(D * Point3::from(p_c)).coords).unwrap();
                let moved = pixel_at_reference_line(&camera, &seen, &p_c, &D).unwrap();
                assert_relative_eq!(moved, camera.project(&p_c).unwrap(), epsilon = 1e-9);
                // A hypothesis 2 cm off: its residual through the reference pose against the
                // moved pixel is the line's residual within 2 % of its size.
                let p_off = p_c + Vector3::new(0.02, -0.01, 0.015);
                let e_line = seen - camera.project(&(D * Point3::from(p_off)).coords).unwrap();
                let e_reference = moved - camera.project(&p_off).unwrap();
                assert!(
                    (e_line - e_reference).norm() < 0.02 * e_line.norm(),
                    "{e_line} {e_reference}"
                );
            }
        }
    }

    #[test]
    fn global_shutter_has_no_offset() {
        let g = RollingShutter::global();
        assert!(g.is_global());
        assert_eq!(
            g.time_offset_s(&Vector2::new(5.0, 400.0), &Vector2::new(640.0, 480.0)),
            0.0
        );
    }

    #[test]
    fn bad_parameters_are_refused_by_name() {
        for (delay, line, name) in [
            (-1e-5, 0.0, "line_delay_s"),
            (f64::NAN, 0.0, "line_delay_s"),
            (1e-5, f64::INFINITY, "reference_line"),
        ] {
            match RollingShutter::new(delay, ReadoutDirection::TopToBottom, line) {
                Err(GeometryError::InvalidParameter { name: n, .. }) => assert_eq!(n, name),
                other => panic!("expected {name} refused, got {other:?}"),
            }
        }
        assert!(RollingShutter::from_readout(0.02, 1, ReadoutDirection::TopToBottom).is_err());
    }
}
