//! Small linear-algebra helpers: SVDs that refuse non-finite input (nalgebra's sorted SVD
//! panics on NaN) and rotation matrices turned into isometries.

use nalgebra::{
    DMatrix, Isometry3, Matrix3, Rotation3, SVector, Translation3, UnitQuaternion, Vector3,
};

/// Largest number of SVD sweeps before giving up; well-conditioned inputs need < 50.
const MAX_SVD_ITERATIONS: usize = 1000;

/// A full 3x3 SVD `m = u * diag(w) * v_t`, `w` in decreasing order.
pub(super) struct Svd3 {
    pub u: Matrix3<f64>,
    pub w: Vector3<f64>,
    pub v_t: Matrix3<f64>,
}

/// Full SVD of `m`, or `None` if `m` is not finite or the SVD does not converge.
pub(super) fn svd3(m: &Matrix3<f64>) -> Option<Svd3> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = m.try_svd(true, true, f64::EPSILON, MAX_SVD_ITERATIONS)?;
    Some(Svd3 {
        u: svd.u?,
        w: svd.singular_values,
        v_t: svd.v_t?,
    })
}

/// Unit vector `x` minimising `|a x|` (the right singular vector of the smallest singular
/// value) for a system with 9 unknowns. `None` if `a` does not have 9 columns or is not
/// finite.
pub(super) fn null_vector_9(a: &DMatrix<f64>) -> Option<SVector<f64, 9>> {
    if a.ncols() != 9 || !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    // A thin SVD of an 8x9 matrix has only 8 right singular vectors; zero rows added to
    // make it at least square keep the null space and expose the ninth.
    let mut padded = DMatrix::zeros(a.nrows().max(9), 9);
    padded.view_mut((0, 0), (a.nrows(), 9)).copy_from(a);
    let svd = padded.try_svd(false, true, f64::EPSILON, MAX_SVD_ITERATIONS)?;
    let x = SVector::<f64, 9>::from_iterator(svd.v_t?.row(8).iter().copied());
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The rigid transform `p -> r p + t`, or `None` if `r` is not a rotation (orthonormal,
/// determinant +1, to 1e-6) or anything is not finite.
pub(super) fn rigid(r: &Matrix3<f64>, t: &Vector3<f64>) -> Option<Isometry3<f64>> {
    let orthonormal = (r.transpose() * r - Matrix3::identity()).norm() < 1e-6;
    if !(orthonormal && r.determinant() > 0.0 && t.iter().all(|v| v.is_finite())) {
        return None;
    }
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    Some(Isometry3::from_parts(Translation3::from(*t), q))
}
