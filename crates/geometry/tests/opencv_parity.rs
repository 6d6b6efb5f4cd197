//! The radial-tangential model agrees with OpenCV's (the model every TUM/EuRoC calibration
//! is written for). Reference values: `cv2.undistortPoints(pts, K, d, P=K)` for TUM fr1,
//! whose results re-distort through `cv2.projectPoints` to within 1e-7 px.

use ferroslam_geometry::camera::test_cameras;
use nalgebra::Vector2;

#[test]
fn tum_fr1_undistortion_matches_opencv() {
    let (_, fr1) = test_cameras()
        .into_iter()
        .find(|(name, _)| *name == "tum_fr1")
        .unwrap();
    let cases = [
        ((600.0, 400.0), (592.694_485_23, 397.454_106_47)),
        ((320.0, 240.0), (319.998_022_03, 240.011_099_96)),
        ((50.0, 450.0), (54.779_396_72, 447.243_693_56)),
    ];
    for ((ux, uy), (ex, ey)) in cases {
        let raw = Vector2::new(ux, uy);
        let und = fr1.undistort_pixel(&raw);
        assert!(
            (und - Vector2::new(ex, ey)).norm() < 1e-5,
            "{raw:?} -> {und:?}, OpenCV ({ex}, {ey})"
        );
        assert!((fr1.distort_pixel(&und) - raw).norm() < 1e-6);
    }
}

#[test]
fn undistortion_inverts_distortion_inside_the_undistorted_bounds() {
    for (name, camera) in test_cameras() {
        let b = camera.undistorted_bounds();
        let mut worst: f64 = 0.0;
        for i in 0..=40 {
            for j in 0..=30 {
                let uv = Vector2::new(
                    b.min_x + (b.max_x - b.min_x) * i as f64 / 40.0,
                    b.min_y + (b.max_y - b.min_y) * j as f64 / 30.0,
                );
                let back = camera.undistort_pixel(&camera.distort_pixel(&uv));
                worst = worst.max((back - uv).norm());
            }
        }
        assert!(worst < 1e-6, "{name}: worst round trip {worst} px");
    }
}
