//! Group laws and Jacobians of SO(3), SE(3) and Sim(3).

mod common;

use approx::assert_relative_eq;
use common::*;
use ferroslam_geometry::sim3::{Sim3, Vector7};
use ferroslam_geometry::testing::check_jacobian;
use ferroslam_geometry::{se3, so3};
use nalgebra::{DMatrix, DVector, Isometry3, Vector3, Vector6};
use proptest::prelude::*;

fn v3(x: &DVector<f64>) -> Vector3<f64> {
    Vector3::new(x[0], x[1], x[2])
}

fn dvec(v: &Vector3<f64>) -> DVector<f64> {
    DVector::from_column_slice(v.as_slice())
}

fn dmat3(m: &nalgebra::Matrix3<f64>) -> DMatrix<f64> {
    DMatrix::from_column_slice(3, 3, m.as_slice())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn so3_log_exp_round_trip(phi in rotation_vector()) {
        assert_relative_eq!(so3::log(&so3::exp(&phi)), phi, epsilon = 1e-9);
    }

    #[test]
    fn se3_exp_log_round_trip(xi in se3_tangent()) {
        let t = se3::exp(&xi);
        assert_relative_eq!(se3::log(&t), xi, epsilon = 1e-8);
        assert_relative_eq!(se3::exp(&se3::log(&t)), t, epsilon = 1e-9);
    }

    #[test]
    fn se3_inverse_gives_identity(t in isometry()) {
        assert_relative_eq!(t * t.inverse(), Isometry3::identity(), epsilon = 1e-12);
    }

    #[test]
    fn se3_adjoint_identity(t in isometry(), xi in se3_tangent()) {
        let small = xi * 0.1;
        let lhs = t * se3::exp(&small) * t.inverse();
        assert_relative_eq!(lhs, se3::exp(&(se3::adjoint(&t) * small)), epsilon = 1e-9);
    }

    #[test]
    fn sim3_exp_log_round_trip(zeta in sim3_tangent()) {
        let s = Sim3::exp(&zeta);
        assert_relative_eq!(s.log(), zeta, epsilon = 1e-8);
        let back = Sim3::exp(&s.log());
        assert_relative_eq!(back.translation, s.translation, epsilon = 1e-9);
        assert_relative_eq!(back.scale, s.scale, epsilon = 1e-12);
        prop_assert!(rotation_error(&back.rotation, &s.rotation) < 1e-12);
    }

    #[test]
    fn sim3_inverse_and_composition(a in sim3(), b in sim3(), p in point()) {
        let id = a * a.inverse();
        assert_relative_eq!(id.scale, 1.0, epsilon = 1e-12);
        assert_relative_eq!(id.translation, Vector3::zeros(), epsilon = 1e-9);
        prop_assert!(rotation_error(&id.rotation, &nalgebra::UnitQuaternion::identity()) < 1e-12);
        assert_relative_eq!((a * b).transform_point(&p), a.transform_point(&b.transform_point(&p)), epsilon = 1e-9);
    }

    #[test]
    fn sim3_with_unit_scale_is_se3(xi in se3_tangent(), p in point()) {
        let mut zeta = Vector7::zeros();
        zeta.fixed_rows_mut::<6>(0).copy_from(&xi);
        let (s, t) = (Sim3::exp(&zeta), se3::exp(&xi));
        assert_relative_eq!(s.transform_point(&p), (t * nalgebra::Point3::from(p)).coords, epsilon = 1e-9);
        assert_relative_eq!(Sim3::from_isometry(&t).log(), zeta, epsilon = 1e-8);
    }

    #[test]
    fn so3_jacobians_match_numeric(phi in rotation_vector()) {
        // Stay away from pi, where the inverse Jacobians of log's branch cut blow up.
        let phi = phi * 0.9;
        let q = so3::exp(&phi);
        let x0 = DVector::zeros(3);
        check_jacobian("left", &dmat3(&so3::left_jacobian(&phi)),
            |d| dvec(&so3::log(&(so3::exp(&(phi + v3(d))) * q.inverse()))), &x0, 1e-6, 1e-6);
        check_jacobian("right", &dmat3(&so3::right_jacobian(&phi)),
            |d| dvec(&so3::log(&(q.inverse() * so3::exp(&(phi + v3(d)))))), &x0, 1e-6, 1e-6);
        check_jacobian("left inverse", &dmat3(&so3::left_jacobian_inverse(&phi)),
            |d| dvec(&(so3::log(&(so3::exp(&v3(d)) * q)) - phi)), &x0, 1e-6, 1e-6);
        check_jacobian("right inverse", &dmat3(&so3::right_jacobian_inverse(&phi)),
            |d| dvec(&(so3::log(&(q * so3::exp(&v3(d)))) - phi)), &x0, 1e-6, 1e-6);
    }

    #[test]
    fn se3_adjoint_is_the_jacobian_of_conjugation(t in isometry()) {
        let ad = se3::adjoint(&t);
        check_jacobian("adjoint", &DMatrix::from_column_slice(6, 6, ad.as_slice()),
            |d| {
                let xi = Vector6::from_column_slice(d.as_slice());
                DVector::from_column_slice(se3::log(&(t * se3::exp(&xi) * t.inverse())).as_slice())
            },
            &DVector::zeros(6), 1e-6, 1e-6);
    }
}

#[test]
fn so3_jacobians_near_zero_match_numeric() {
    for phi in [
        Vector3::zeros(),
        Vector3::new(1e-7, -2e-7, 3e-8),
        Vector3::new(4e-3, 1e-3, -5e-3),
    ] {
        let q = so3::exp(&phi);
        check_jacobian(
            "left near zero",
            &dmat3(&so3::left_jacobian(&phi)),
            |d| dvec(&so3::log(&(so3::exp(&(phi + v3(d))) * q.inverse()))),
            &DVector::zeros(3),
            1e-6,
            1e-7,
        );
    }
}
