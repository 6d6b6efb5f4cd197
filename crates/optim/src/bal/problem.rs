//! The data of a BAL problem and its cost.

use super::snavely::{CameraParams, SnavelyCamera};
use crate::error::OptimError;
use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;

/// Observations per chunk of the cost sum (fixed, so the summation order is too).
const COST_CHUNK: usize = 1024;

/// Point `point` seen by camera `camera` at pixel `uv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalObservation {
    /// Index into [`BalProblem::cameras`].
    pub camera: usize,
    /// Index into [`BalProblem::points`].
    pub point: usize,
    /// Measured image position, pixels, BAL's centred convention (principal point at 0).
    pub uv: Vector2<f64>,
}

/// Cameras, points and observations of a BAL problem.
#[derive(Clone, Debug, PartialEq)]
pub struct BalProblem {
    /// Snavely cameras.
    pub cameras: Vec<CameraParams>,
    /// World points.
    pub points: Vec<Vector3<f64>>,
    /// All observations, in file order.
    pub observations: Vec<BalObservation>,
}

impl BalProblem {
    /// Checks indices and finiteness.
    ///
    /// # Errors
    /// [`OptimError::IndexOutOfRange`] for an observation naming a missing camera or point,
    /// [`OptimError::NonFinite`] for a NaN or infinite value.
    pub fn validate(&self) -> Result<(), OptimError> {
        for (i, o) in self.observations.iter().enumerate() {
            for (what, index, len) in [
                ("camera", o.camera, self.cameras.len()),
                ("point", o.point, self.points.len()),
            ] {
                OptimError::check_index(i, what, index, len)?;
            }
        }
        let non_finite = |what: &'static str, index: Option<usize>| match index {
            Some(index) => Err(OptimError::NonFinite { what, index }),
            None => Ok(()),
        };
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        non_finite(
            "camera",
            self.cameras.iter().position(|c| !finite(c.as_slice())),
        )?;
        non_finite(
            "point",
            self.points.iter().position(|p| !finite(p.as_slice())),
        )?;
        non_finite(
            "observation",
            self.observations
                .iter()
                .position(|o| !finite(o.uv.as_slice())),
        )
    }

    /// `0.5 * sum |residual|^2` (pixels^2) at the current estimate; infinite if a point lies
    /// on a camera's image plane (`P.z == 0`). Requires a valid problem (see
    /// [`Self::validate`]); panics on out-of-range indices.
    pub fn cost(&self) -> f64 {
        cost_at(&self.observations, &self.cameras, &self.points)
    }
}

/// `0.5 * sum |residual|^2` of `observations` at the given cameras and points, summed in
/// fixed chunks so the result does not depend on the thread count.
pub(crate) fn cost_at(
    observations: &[BalObservation],
    cameras: &[CameraParams],
    points: &[Vector3<f64>],
) -> f64 {
    let cameras: Vec<SnavelyCamera> = cameras.iter().map(SnavelyCamera::new).collect();
    let partial: Vec<f64> = observations
        .par_chunks(COST_CHUNK)
        .map(|chunk| {
            chunk
                .iter()
                .map(|o| {
                    cameras[o.camera]
                        .project(&points[o.point])
                        .map_or(f64::INFINITY, |uv| (uv - o.uv).norm_squared())
                })
                .sum::<f64>()
        })
        .collect();
    0.5 * partial.iter().sum::<f64>()
}
