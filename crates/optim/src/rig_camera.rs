//! The cameras of a multi-camera rig as the optimisers see them.
//!
//! A pose being optimised is the rig's first camera's `T_c0_w` (the "body"); camera `k` sees
//! a point from `T_ck_c0 * T_c0_w`. A left perturbation of the body, `T_ck_c0 * exp(xi) *
//! T_c0_w = exp(Ad(T_ck_c0) xi) * T_ck_c0 * T_c0_w`, so a Jacobian taken for camera `k`'s
//! pose is carried to the body through the adjoint, as a rolling shutter's readout motion
//! already is ([`crate::ba::Observation::readout_motion`]).

use crate::error::OptimError;
use crate::intrinsics::Intrinsics;
use ferroslam_geometry::se3;
use nalgebra::{Isometry3, Matrix3x6};

/// A camera of a multi-camera rig as the optimisers see it: its projection, and its pose
/// relative to the rig's first camera, whose pose is the one optimised.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(non_snake_case)]
pub struct RigCamera {
    /// The camera's projection (and its stereo `bf` term).
    pub intrinsics: Intrinsics,
    /// `T_ck_c0`: maps points from the first camera's frame into this camera's (metres);
    /// `None` for the first camera itself, whose arithmetic is then exactly that of the pose
    /// alone.
    pub T_c_c0: Option<Isometry3<f64>>,
}

#[allow(non_snake_case)]
impl RigCamera {
    /// The rig's first camera (or the only camera): seen from the optimised pose itself.
    pub fn first(intrinsics: Intrinsics) -> Self {
        Self {
            intrinsics,
            T_c_c0: None,
        }
    }

    /// A further camera of the rig, `T_c_c0` from the first camera's frame into its own.
    pub fn new(intrinsics: Intrinsics, T_c_c0: Isometry3<f64>) -> Self {
        Self {
            intrinsics,
            T_c_c0: Some(T_c_c0),
        }
    }

    /// The fixed motion an observation of this camera is seen through: `T_c_c0 * D` with an
    /// optional readout motion `D` of the first camera (rolling shutter: the rig moves
    /// rigidly over the readout), either alone if the other is absent, `None` if both are
    /// (the pose's own arithmetic).
    pub fn view(&self, readout_motion: Option<&Isometry3<f64>>) -> Option<Isometry3<f64>> {
        match (readout_motion, &self.T_c_c0) {
            (None, None) => None,
            (Some(D), None) => Some(*D),
            (None, Some(T)) => Some(*T),
            (Some(D), Some(T)) => Some(T * D),
        }
    }

    /// Checks the intrinsics and that `T_c_c0` is finite; `index` names the camera.
    pub(crate) fn validate(&self, index: usize) -> Result<(), OptimError> {
        self.intrinsics.validate()?;
        let finite = self.T_c_c0.is_none_or(|t| {
            t.translation
                .vector
                .iter()
                .chain(t.rotation.coords.iter())
                .all(|v| v.is_finite())
        });
        if !finite {
            return Err(OptimError::NonFinite {
                what: "camera extrinsics",
                index,
            });
        }
        Ok(())
    }

    /// Checks every camera of a rig, which must have at least one.
    pub(crate) fn validate_all(cameras: &[Self]) -> Result<(), OptimError> {
        if cameras.is_empty() {
            return Err(OptimError::InvalidInput("no camera".into()));
        }
        cameras
            .iter()
            .enumerate()
            .try_for_each(|(i, c)| c.validate(i))
    }
}

/// The pose an observation was made from, `V * T_c_w` for the fixed motion `view` (see
/// [`RigCamera::view`]), `T_c_w` itself without one.
#[allow(non_snake_case)]
pub(crate) fn seen_from(view: Option<&Isometry3<f64>>, T_c_w: &Isometry3<f64>) -> Isometry3<f64> {
    view.map_or(*T_c_w, |V| V * T_c_w)
}

/// Carries `d e / d xi` taken for the pose `V * T_c_w` to the left perturbation of `T_c_w`
/// (through `Ad(V)`, see the module docs); untouched without a `view`.
#[allow(non_snake_case)]
pub(crate) fn carry_jacobian(view: Option<&Isometry3<f64>>, d_e_d_xi: &mut Matrix3x6<f64>) {
    if let Some(V) = view {
        *d_e_d_xi *= se3::adjoint(V);
    }
}
