//! Bounded proptest strategies and synthetic scenes shared by the integration tests.
#![allow(dead_code)] // each test binary uses a different subset

use ferroslam_geometry::sim3::{Sim3, Vector7};
use ferroslam_geometry::{se3, so3};
use nalgebra::{Isometry3, Vector3, Vector6};
use proptest::prelude::*;

/// Rotation vectors with angle in `[0, pi - 0.01]`, where `log(exp(phi)) == phi`.
pub fn rotation_vector() -> impl Strategy<Value = Vector3<f64>> {
    (
        prop::array::uniform3(-1.0..1.0f64),
        0.0..std::f64::consts::PI - 0.01,
    )
        .prop_filter("direction needs a length", |(d, _)| {
            Vector3::from(*d).norm() > 0.1
        })
        .prop_map(|(d, angle)| Vector3::from(d).normalize() * angle)
}

/// Points in a 20 m cube around the origin.
pub fn point() -> impl Strategy<Value = Vector3<f64>> {
    prop::array::uniform3(-10.0..10.0f64).prop_map(Vector3::from)
}

/// se(3) vectors `[rho; phi]` with bounded translation and angle below pi.
pub fn se3_tangent() -> impl Strategy<Value = Vector6<f64>> {
    (prop::array::uniform3(-5.0..5.0f64), rotation_vector()).prop_map(|(rho, phi)| {
        let mut xi = Vector6::zeros();
        xi.fixed_rows_mut::<3>(se3::TRANS.start)
            .copy_from(&Vector3::from(rho));
        xi.fixed_rows_mut::<3>(se3::ROT.start).copy_from(&phi);
        xi
    })
}

/// sim(3) vectors `[rho; phi; sigma]`, scale in `[e^-2, e^2]`.
pub fn sim3_tangent() -> impl Strategy<Value = Vector7<f64>> {
    (se3_tangent(), -2.0..2.0f64).prop_map(|(xi, sigma)| {
        let mut zeta = Vector7::zeros();
        zeta.fixed_rows_mut::<6>(0).copy_from(&xi);
        zeta[6] = sigma;
        zeta
    })
}

/// Rigid transforms.
pub fn isometry() -> impl Strategy<Value = Isometry3<f64>> {
    se3_tangent().prop_map(|xi| se3::exp(&xi))
}

/// Similarity transforms.
pub fn sim3() -> impl Strategy<Value = Sim3> {
    sim3_tangent().prop_map(|zeta| Sim3::exp(&zeta))
}

/// Rotation angle of `a^-1 b` in radians.
pub fn rotation_error(a: &nalgebra::UnitQuaternion<f64>, b: &nalgebra::UnitQuaternion<f64>) -> f64 {
    so3::log(&(a.inverse() * b)).norm()
}
