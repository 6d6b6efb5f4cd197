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
