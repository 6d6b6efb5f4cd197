//! The data of a bundle adjustment problem.

use crate::error::OptimError;
use crate::intrinsics::Intrinsics;
use crate::residual::{self, Linearization};
use crate::robust::chi2_threshold;
use ferroslam_geometry::se3;
use nalgebra::{Isometry3, Vector2, Vector3};
use rayon::prelude::*;

/// One keypoint of a map point in a keyframe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Index into [`BaProblem::poses`].
    pub pose: usize,
    /// Index into [`BaProblem::points`].
    pub point: usize,
    /// Observed undistorted keypoint, pixels.
    pub uv: Vector2<f64>,
    /// Virtual right coordinate `u - bf / depth` (pixels) for stereo / RGB-D, else `None`.
    pub u_right: Option<f64>,
    /// Information weight `1 / sigma^2` (1/pixels^2).
    pub inv_sigma2: f64,
    /// Rolling shutter: the fixed motion `D` of the camera from its pose's reference line
    /// to this observation's row (`ferroslam_geometry::rolling_shutter::motion_over`), so
    /// that the point is seen from `D * T_c_w`; `None` for a global shutter (or the
    /// reference line), which keeps the arithmetic of `T_c_w` itself.
    pub readout_motion: Option<Isometry3<f64>>,
}

#[allow(non_snake_case)]
impl Observation {
    /// True for a stereo / RGB-D observation (3 residual rows).
    pub fn is_stereo(&self) -> bool {
        self.u_right.is_some()
    }

    /// The pose the observation was made from, `D * T_c_w` (see [`Self::readout_motion`]).
    fn seen_from(&self, T_c_w: &Isometry3<f64>) -> Isometry3<f64> {
        self.readout_motion.map_or(*T_c_w, |D| D * T_c_w)
    }

    /// `inv_sigma2 * |e|^2` of the point `p_w` seen from the pose `T_c_w` (see
    /// [`residual::chi2`]).
    pub fn chi2(&self, k: &Intrinsics, T_c_w: &Isometry3<f64>, p_w: &Vector3<f64>) -> Option<f64> {
        let T = self.seen_from(T_c_w);
        residual::chi2(k, &T, p_w, &self.uv, self.u_right, self.inv_sigma2)
    }

    /// [`residual::linearize`] of the point `p_w` seen from the pose `T_c_w`, with
    /// `d_e_d_xi` for the left perturbation of `T_c_w`: `D * exp(xi) * T_c_w` is
    /// `exp(Ad(D) xi) * D * T_c_w`, so the Jacobian of the row's pose is carried through
    /// the adjoint.
    pub fn linearize(
        &self,
        k: &Intrinsics,
        T_c_w: &Isometry3<f64>,
        p_w: &Vector3<f64>,
    ) -> Option<Linearization> {
        let T = self.seen_from(T_c_w);
        let mut l = residual::linearize(k, &T, p_w, &self.uv, self.u_right)?;
        if let Some(D) = &self.readout_motion {
            l.d_e_d_xi *= se3::adjoint(D);
        }
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
    /// Camera intrinsics shared by all keyframes.
    pub intrinsics: Intrinsics,
    /// World-to-camera poses `T_c_w`.
    pub poses: Vec<Isometry3<f64>>,
    /// `true` for poses held constant (gauge anchors, ORB-SLAM's fixed covisible keyframes).
    pub pose_fixed: Vec<bool>,
    /// World points `p_w`, metres.
    pub points: Vec<Vector3<f64>>,
    /// All observations.
    pub observations: Vec<Observation>,
}

impl BaProblem {
    /// Checks lengths, indices, finiteness and positive information weights.
    pub fn validate(&self) -> Result<(), OptimError> {
        self.intrinsics.validate()?;
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
        o.chi2(&self.intrinsics, &self.poses[o.pose], &self.points[o.point])
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
    use ferroslam_geometry::rolling_shutter::motion_over;
    use ferroslam_geometry::testing::check_jacobian;
    use nalgebra::{DMatrix, DVector, Vector6};

    fn observation(readout_motion: Option<Isometry3<f64>>) -> Observation {
        Observation {
            pose: 0,
            point: 0,
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
        let l = o.linearize(&k, &T, &p_w).unwrap();
        let moved = residual::linearize(&k, &(D * T), &p_w, &o.uv, o.u_right).unwrap();
        assert_eq!(l.e, moved.e);
        assert_eq!(o.chi2(&k, &T, &p_w), Some(moved.e.norm_squared()));
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
        assert_eq!(o.linearize(&k, &T, &p_w), Some(plain));
    }
}
