//! Map files of a multi-camera rig: each keyframe's cameras and the rig's further cameras
//! round-trip; inconsistent cameras are refused, naming the keyframe and the values.

use std::sync::Arc;

use ferroslam_features::ImageBounds;

use super::{assert_same, load, refused, sample_map_from, to_bytes};
use crate::test_support::map_with_keyframes;
use crate::{KeyFrameId, Map, Rig, RigMember};

/// Camera `k`'s image bounds (px) in [`rig_map`]: each camera's own, all holding its
/// keypoints (x = index, y = 10).
fn bounds(k: usize) -> ImageBounds {
    [
        ImageBounds {
            min_x: 0.0,
            max_x: 640.0,
            min_y: 0.0,
            max_y: 480.0,
        },
        ImageBounds {
            min_x: 10.0,
            max_x: 320.0,
            min_y: -4.0,
            max_y: 240.0,
        },
        ImageBounds {
            min_x: 40.0,
            max_x: 70.0,
            min_y: 0.0,
            max_y: 30.0,
        },
    ][k]
}

/// Keypoints of camera 0, 1, 2 in each keyframe of [`rig_map`] start here (60 keypoints).
const STARTS: [usize; 3] = [0, 20, 45];

/// A fisheye camera of the rig at `x` m along the first camera's x axis.
fn member(x: f64, has_depth: bool) -> RigMember {
    RigMember {
        model: "kannala_brandt".into(),
        intrinsics: [284.0, 285.3, 417.2, 400.4],
        distortion: [-0.002, 0.039, -0.038, 0.007, 0.0],
        width: 848,
        height: 800,
        T_c0_c: nalgebra::Isometry3::new(
            nalgebra::Vector3::new(x, 0.01, 0.0),
            nalgebra::Vector3::new(0.0, 0.3, 0.0),
        ),
        has_depth,
        pair: None,
    }
}

/// `camera` with a stereo partner 8 cm to its right.
fn paired(camera: RigMember) -> RigMember {
    RigMember {
        pair: Some(crate::PairCamera {
            model: camera.model.clone(),
            intrinsics: camera.intrinsics,
            distortion: camera.distortion,
            T_left_right: nalgebra::Isometry3::translation(0.08, 0.0, 0.0),
        }),
        ..camera
    }
}

/// The persist tests' uncoloured sample map, its keyframes of a 3-camera rig (camera 2 with
/// a stereo partner).
fn rig_map() -> (Map, Vec<KeyFrameId>) {
    let (mut map, kfs) = map_with_keyframes(5, 60);
    for kf in &kfs {
        let kf = map.keyframes.get_mut(kf).unwrap();
        let features = Arc::make_mut(&mut kf.features);
        *features = features
            .clone()
            .with_cameras(STARTS.to_vec(), &[bounds(0), bounds(1), bounds(2)])
            .unwrap();
    }
    let (mut map, kfs) = sample_map_from((map, kfs));
    map.set_rig(Rig {
        sensor: "mono".into(),
        model: Rig::PINHOLE.into(),
        intrinsics: [500.0, 501.0, 320.0, 240.0],
        distortion: [0.1, -0.2, 0.0, 0.001, 0.0],
        width: 640,
        height: 480,
        pair: None,
        cameras: vec![member(0.064, false), paired(member(-0.1, true))],
    });
    (map, kfs)
}

#[test]
fn keyframes_of_a_rig_round_trip_with_every_camera() {
    let (map, _) = rig_map();
    let bytes = to_bytes(&map);
    let loaded = load(&bytes).unwrap();
    loaded.check_consistency().unwrap();
    assert_same(&map, &loaded);
    assert_eq!(loaded.rig(), map.rig());
    assert_eq!(loaded.rig().unwrap().num_cameras(), 3);
    for kf in loaded.keyframes() {
        let f = kf.features();
        assert_eq!(f.camera_starts, STARTS);
        let loaded_bounds: Vec<_> = f.grids.iter().map(|g| g.bounds()).collect();
        assert_eq!(loaded_bounds, [bounds(0), bounds(1), bounds(2)]);
        assert!((0..3).all(|k| !f.camera_range(k).is_empty()));
        // Camera 2's grid is local: keypoint 50 (x = 50) is its keypoint 5.
        let local = &f.keypoints[f.camera_range(2)];
        assert_eq!(
            f.grid(2)
                .features_in_area(local, 50.0, 10.0, 0.5, None, None),
            [5]
        );
    }
    assert_eq!(
        to_bytes(&loaded),
        bytes,
        "saving a loaded map gives the same bytes"
    );
}

/// [`rig_map`] with keyframe 0's features edited, refused on load: the error text.
fn refused_features(edit: impl FnOnce(&mut crate::FrameFeatures)) -> String {
    let (mut map, kfs) = rig_map();
    let kf = map.keyframes.get_mut(&kfs[0]).unwrap();
    edit(Arc::make_mut(&mut kf.features));
    refused(&map)
}

#[test]
fn inconsistent_camera_starts_are_refused_naming_them() {
    let starts = |s: Vec<usize>| refused_features(|f| f.camera_starts = s);
    assert_eq!(
        starts(vec![1, 20, 45]),
        "keyframe KF0: FrameFeatures: camera_starts [1, 20, 45] must begin with 0 (camera 0 \
         starts at the first keypoint)"
    );
    assert_eq!(
        starts(vec![0, 45, 20]),
        "keyframe KF0: FrameFeatures: camera_starts [0, 45, 20] decrease at camera 2: \
         keypoints must be sorted by camera"
    );
    assert_eq!(
        starts(vec![0, 20, 61]),
        "keyframe KF0: FrameFeatures: camera_starts [0, 20, 61]: camera 2 starts beyond the \
         60 keypoints"
    );
    // Consistent starts, but two cameras where the rig has three.
    let two = refused_features(|f| {
        *f = f
            .clone()
            .with_cameras(vec![0, 20], &[bounds(0), bounds(1)])
            .unwrap()
    });
    assert_eq!(
        two,
        "keyframe KF0: 2 cameras (camera_starts [0, 20]), but the map's rig has 3"
    );
    // The rig lost a camera: every keyframe has one too many.
    let (mut map, _) = rig_map();
    let mut rig = map.rig().unwrap().clone();
    rig.cameras.pop();
    map.set_rig(rig);
    assert_eq!(
        refused(&map),
        "keyframe KF0: 3 cameras (camera_starts [0, 20, 45]), but the map's rig has 2"
    );
}

#[test]
fn keypoints_are_checked_against_their_own_camera() {
    // x = 200 is in camera 0's and 1's image, far outside camera 2's (x in [40, 70] px).
    let what = refused_features(|f| f.keypoints[50].x = 200.0);
    assert_eq!(
        what,
        "keyframe KF0: keypoint 50 at (200, 10) px is outside camera 2's image bounds x [40, \
         70], y [0, 30] (by more than 0.25 of them)"
    );
    // Within camera 1's bounds widened by the margin: loads.
    let (mut map, kfs) = rig_map();
    let kf = map.keyframes.get_mut(&kfs[0]).unwrap();
    Arc::make_mut(&mut kf.features).keypoints[25].y = -50.0;
    load(&to_bytes(&map)).unwrap();
    let what = refused_features(|f| f.keypoints[25].y = -70.0);
    assert!(
        what.starts_with("keyframe KF0: keypoint 25 at (25, -70) px is outside camera 1's"),
        "{what}"
    );
}

#[test]
fn non_finite_rig_camera_poses_are_refused() {
    let (mut map, _) = rig_map();
    let mut rig = map.rig().unwrap().clone();
    rig.cameras[1].T_c0_c.translation.vector.y = f64::NAN;
    map.set_rig(rig);
    let what = refused(&map);
    assert!(
        what.starts_with("the camera record: camera 2's pose T_c0_c translation"),
        "{what}"
    );
}
