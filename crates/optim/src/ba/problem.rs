//! The data of a bundle adjustment problem.

use crate::error::OptimError;
use crate::residual::{self, Linearization};
use crate::rig_camera::{carry_jacobian, seen_from, RigCamera};
use crate::robust::chi2_threshold;
use nalgebra::{Isometry3, Vector2, Vector3};
use rayon::prelude::*;

/// One keypoint of a map point in a keyframe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Index into [`BaProblem::poses`].
    pub pose: usize,
    /// Index into [`BaProblem::points`].
    pub point: usize,
    /// Index into [`BaProblem::cameras`]: the rig's camera that made the observation (0 for
    /// a single camera).
    pub camera: usize,
    /// Observed undistorted keypoint, pixels.
    pub uv: Vector2<f64>,
    /// Virtual right coordinate `u - bf / depth` (pixels) for stereo / RGB-D, else `None`.
    pub u_right: Option<f64>,
    /// Information weight `1 / sigma^2` (1/pixels^2).
    pub inv_sigma2: f64,
    /// Rolling shutter: the fixed motion `D` of the rig's first camera from its pose's
    /// reference line to this observation's row (timed by the observing camera's shutter,
    /// `ferroslam_geometry::rolling_shutter::motion_over`), so that the point is seen from
    /// `T_c_c0 * D * T_c_w` (see [`RigCamera::view`]): the rig moves rigidly over a readout;
    /// `None` for a global shutter (or the reference line), which keeps the arithmetic of
    /// the camera's pose itself.
    pub readout_motion: Option<Isometry3<f64>>,
}

#[allow(non_snake_case)]
impl Observation {
    /// True for a stereo / RGB-D observation (3 residual rows).
    pub fn is_stereo(&self) -> bool {
        self.u_right.is_some()
    }

    /// The fixed motion the observation is seen through, `T_c_c0 * D` (see
    /// [`RigCamera::view`]), and its camera; `cameras` is the problem's, with the
    /// observation's camera in range.
    fn view<'a>(&self, cameras: &'a [RigCamera]) -> (&'a RigCamera, Option<Isometry3<f64>>) {
        let camera = &cameras[self.camera];
        (camera, camera.view(self.readout_motion.as_ref()))
    }

    /// `inv_sigma2 * |e|^2` of the point `p_w` seen by the observation's camera of the rig
    /// whose first camera is at `T_c_w` (see [`residual::chi2`]).
    pub fn chi2(
        &self,
        cameras: &[RigCamera],
        T_c_w: &Isometry3<f64>,
        p_w: &Vector3<f64>,
    ) -> Option<f64> {
        let (camera, view) = self.view(cameras);
        let T = seen_from(view.as_ref(), T_c_w);
        residual::chi2(
            &camera.intrinsics,
            &T,
            p_w,
            &self.uv,
            self.u_right,
            self.inv_sigma2,
        )
    }

    /// [`residual::linearize`] of the point `p_w` seen by the observation's camera from
    /// `V * T_c_w` (`V = T_c_c0 * D`, see [`RigCamera::view`]), with `d_e_d_xi` for the left
    /// perturbation of `T_c_w`: `V * exp(xi) * T_c_w` is `exp(Ad(V) xi) * V * T_c_w`, so the
    /// Jacobian of the camera's pose is carried through the adjoint.
    pub fn linearize(
        &self,
        cameras: &[RigCamera],
        T_c_w: &Isometry3<f64>,
        p_w: &Vector3<f64>,
    ) -> Option<Linearization> {
        let (camera, view) = self.view(cameras);
        let T = seen_from(view.as_ref(), T_c_w);
        let mut l = residual::linearize(&camera.intrinsics, &T, p_w, &self.uv, self.u_right)?;
        carry_jacobian(view.as_ref(), &mut l.d_e_d_xi);
        Some(l)
    }
}

/// Poses, points and observations of a bundle adjustment.
///
/// Free poses (`pose_fixed[i] == false`) and every point observed by at least one free pose
/// are optimised; fixed poses and points seen only from fixed poses stay as they are (the
/// latter cannot move without a free camera to pull them; ORB-SLAM never builds them).
#[derive(Clone, Debug, PartialEq)]
pub struct BaProblem {
    /// The rig's cameras, shared by all keyframes (one [`RigCamera::first`] for a single
    /// camera); never empty.
    pub cameras: Vec<RigCamera>,
    /// World-to-camera poses `T_c_w` of the rig's first camera.
    pub poses: Vec<Isometry3<f64>>,
    /// `true` for poses held constant (gauge anchors, ORB-SLAM's fixed covisible keyframes).
    pub pose_fixed: Vec<bool>,
    /// World points `p_w`, metres.
    pub points: Vec<Vector3<f64>>,
    /// All observations.
    pub observations: Vec<Observation>,
}

impl BaProblem {
    /// Checks the cameras (at least one), lengths, indices, finiteness and positive
    /// information weights.
    pub fn validate(&self) -> Result<(), OptimError> {
        RigCamera::validate_all(&self.cameras)?;
        if self.pose_fixed.len() != self.poses.len() {
            return Err(OptimError::InvalidInput(format!(
                "pose_fixed has {} flags for {} poses",
                self.pose_fixed.len(),
                self.poses.len()
            )));
        }
        for (i, t) in self.poses.iter().enumerate() {
            let finite = t
                .translation
                .vector
                .iter()
                .chain(t.rotation.coords.iter())
                .all(|v| v.is_finite());
            if !finite {
                return Err(OptimError::NonFinite {
                    what: "pose",
                    index: i,
                });
            }
        }
        if let Some(i) = self
            .points
            .iter()
            .position(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Err(OptimError::NonFinite {
                what: "point",
                index: i,
            });
        }
        for (i, o) in self.observations.iter().enumerate() {
            for (what, index, len) in [
                ("pose", o.pose, self.poses.len()),
                ("point", o.point, self.points.len()),
                ("camera", o.camera, self.cameras.len()),
            ] {
                OptimError::check_index(i, what, index, len)?;
            }
            residual::validate_measurement(i, &o.uv, o.u_right, o.inv_sigma2)?;
        }
        Ok(())
    }

    /// `inv_sigma2 * |e|^2` of observation `i` at the current estimate; `None` if the point is
    /// not in front of the camera (or non-finite). Panics if `i` is out of range.
    pub fn chi2(&self, i: usize) -> Option<f64> {
        let o = &self.observations[i];
        o.chi2(&self.cameras, &self.poses[o.pose], &self.points[o.point])
    }

    /// ORB-SLAM's classification of every observation at the current estimate: outlier iff
    /// `chi2` exceeds [`crate::robust::CHI2_MONO`] / [`crate::robust::CHI2_STEREO`] or the point
    /// is not in front of the camera. Requires a valid problem (see [`Self::validate`]).
    pub fn classify_outliers(&self) -> Vec<bool> {
        (0..self.observations.len())
            .into_par_iter()
            .map(|i| {
                let stereo = self.observations[i].is_stereo();
                self.chi2(i).is_none_or(|c| c > chi2_threshold(stereo))
            })
            .collect()
    }
}

#[cfg(test)]
#[allow(non_snake_case)]
mod tests {
    use super::*;
    use crate::intrinsics::Intrinsics;
    use ferroslam_geometry::camera::test_fisheye_cameras;
    use ferroslam_geometry::rolling_shutter::motion_over;
    use ferroslam_geometry::se3;
    use ferroslam_geometry::testing::check_jacobian;
    use nalgebra::{DMatrix, DVector, Vector6};

    fn observation(readout_motion: Option<Isometry3<f64>>) -> Observation {
        Observation {
            pose: 0,
            point: 0,
            camera: 0,
            uv: Vector2::new(300.0, 200.0),
            u_right: Some(280.0),
            inv_sigma2: 1.0,
            readout_motion,
        }
    }

    fn intrinsics() -> Intrinsics {
        Intrinsics {
            fx: 517.3,
            fy: 516.5,
            cx: 318.6,
            cy: 255.3,
            bf: 40.0,
            fisheye: None,
        }
    }

    fn pose() -> Isometry3<f64> {
        Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.2, -0.1, 0.05))
    }

    #[test]
    fn a_row_is_seen_from_the_moved_pose_with_its_jacobians() {
        // 12 ms from the reference line at 1.5 rad/s and 0.3 m/s.
        let D = motion_over(&Vector6::new(0.3, 0.0, -0.1, 0.5, 1.5, -0.2), 0.012);
        let (k, T, p_w) = (intrinsics(), pose(), Vector3::new(0.4, 0.3, 2.5));
        let o = observation(Some(D));
        let l = o.linearize(&[RigCamera::first(k)], &T, &p_w).unwrap();
        let moved = residual::linearize(&k, &(D * T), &p_w, &o.uv, o.u_right).unwrap();
        assert_eq!(l.e, moved.e);
        assert_eq!(
            o.chi2(&[RigCamera::first(k)], &T, &p_w),
            Some(moved.e.norm_squared())
        );
        let e_of_pose = |x: &DVector<f64>| {
            let T = se3::exp(&Vector6::from_column_slice(x.as_slice())) * T;
            let e = residual::residual(&k, &(D * T), &p_w, &o.uv, o.u_right).unwrap();
            DVector::from_column_slice(e.as_slice())
        };
        let analytic = DMatrix::from_column_slice(3, 6, l.d_e_d_xi.as_slice());
        check_jacobian(
            "d_e_d_xi",
            &analytic,
            e_of_pose,
            &DVector::zeros(6),
            1e-6,
            1e-4,
        );
        let e_of_point = |x: &DVector<f64>| {
            let p = Vector3::from_column_slice(x.as_slice());
            let e = residual::residual(&k, &(D * T), &p, &o.uv, o.u_right).unwrap();
            DVector::from_column_slice(e.as_slice())
        };
        let analytic = DMatrix::from_column_slice(3, 3, l.d_e_d_p_w.as_slice());
        let x0 = DVector::from_column_slice(p_w.as_slice());
        check_jacobian("d_e_d_p_w", &analytic, e_of_point, &x0, 1e-6, 1e-4);
    }

    #[test]
    fn a_global_shutter_observation_is_the_plain_residual() {
        let (k, T, p_w) = (intrinsics(), pose(), Vector3::new(0.4, 0.3, 2.5));
        let o = observation(None);
        let plain = residual::linearize(&k, &T, &p_w, &o.uv, o.u_right).unwrap();
        assert_eq!(o.linearize(&[RigCamera::first(k)], &T, &p_w), Some(plain));
    }

    /// A further camera of a rig: yawed 0.3 rad, 10 cm to the side of the first.
    fn T_c_c0() -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(-0.1, 0.02, 0.01),
            Vector3::new(0.05, 0.3, -0.02),
        )
    }

    /// `linearize` of an observation of `camera` (index 1 of a rig) against central
    /// differences of the residual seen from `T_c_c0 * D * T_c_w`, written out.
    fn check_rig_derivatives(camera: RigCamera, D: Option<Isometry3<f64>>) {
        let cameras = [RigCamera::first(intrinsics()), camera];
        let (T, p_w) = (pose(), Vector3::new(0.4, 0.3, 2.5));
        let o = Observation {
            camera: 1,
            ..observation(D)
        };
        let k = camera.intrinsics;
        let T_c_c0 = camera.T_c_c0.unwrap();
        let D = D.unwrap_or_else(Isometry3::identity);
        let e_at = |T: &Isometry3<f64>, p: &Vector3<f64>| {
            let e = residual::residual(&k, &(T_c_c0 * (D * T)), p, &o.uv, o.u_right).unwrap();
            DVector::from_column_slice(e.as_slice())
        };
        let l = o.linearize(&cameras, &T, &p_w).unwrap();
        assert!((DVector::from_column_slice(l.e.as_slice()) - e_at(&T, &p_w)).norm() < 1e-9);
        let chi2 = o.chi2(&cameras, &T, &p_w).unwrap();
        assert!((chi2 - l.e.norm_squared()).abs() < 1e-9 * chi2.max(1.0));
        let e_of_pose = |x: &DVector<f64>| {
            e_at(
                &(se3::exp(&Vector6::from_column_slice(x.as_slice())) * T),
                &p_w,
            )
        };
        let analytic = DMatrix::from_column_slice(3, 6, l.d_e_d_xi.as_slice());
        check_jacobian(
            "d_e_d_xi",
            &analytic,
            e_of_pose,
            &DVector::zeros(6),
            1e-6,
            1e-4,
        );
        let e_of_point = |x: &DVector<f64>| e_at(&T, &Vector3::from_column_slice(x.as_slice()));
        let analytic = DMatrix::from_column_slice(3, 3, l.d_e_d_p_w.as_slice());
        let x0 = DVector::from_column_slice(p_w.as_slice());
        check_jacobian("d_e_d_p_w", &analytic, e_of_point, &x0, 1e-6, 1e-4);
    }

    fn readout_motion() -> Isometry3<f64> {
        motion_over(&Vector6::new(0.3, 0.0, -0.1, 0.5, 1.5, -0.2), 0.012)
    }

    #[test]
    fn a_rig_camera_is_seen_through_its_extrinsics_with_its_jacobians() {
        let pinhole = RigCamera::new(intrinsics(), T_c_c0());
        check_rig_derivatives(pinhole, None);
        check_rig_derivatives(pinhole, Some(readout_motion()));
    }

    #[test]
    fn a_fisheye_rig_camera_is_seen_through_its_extrinsics_with_its_jacobians() {
        let (_, lens) = test_fisheye_cameras()[0];
        let fisheye = RigCamera::new(Intrinsics::new(&lens.into(), 40.0), T_c_c0());
        check_rig_derivatives(fisheye, None);
        check_rig_derivatives(fisheye, Some(readout_motion()));
    }

    #[test]
    fn the_first_camera_with_a_readout_motion_keeps_todays_arithmetic() {
        let (k, T, p_w) = (intrinsics(), pose(), Vector3::new(0.4, 0.3, 2.5));
        let D = readout_motion();
        let o = observation(Some(D));
        let mut moved = residual::linearize(&k, &(D * T), &p_w, &o.uv, o.u_right).unwrap();
        moved.d_e_d_xi *= se3::adjoint(&D);
        assert_eq!(o.linearize(&[RigCamera::first(k)], &T, &p_w), Some(moved));
    }

    #[test]
    fn an_observation_of_a_missing_camera_fails_validation() {
        let o = Observation {
            camera: 2,
            ..observation(None)
        };
        let problem = BaProblem {
            cameras: vec![
                RigCamera::first(intrinsics()),
                RigCamera::new(intrinsics(), T_c_c0()),
            ],
            poses: vec![pose()],
            pose_fixed: vec![false],
            points: vec![Vector3::new(0.4, 0.3, 2.5)],
            observations: vec![o],
        };
        assert_eq!(
            problem.validate(),
            Err(OptimError::IndexOutOfRange {
                observation: 0,
                what: "camera",
                index: 2,
                len: 2
            })
        );
        let no_camera = BaProblem {
            cameras: vec![],
            ..problem
        };
        assert_eq!(
            no_camera.validate(),
            Err(OptimError::InvalidInput("no camera".into()))
        );
    }
}
