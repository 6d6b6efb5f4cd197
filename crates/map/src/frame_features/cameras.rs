//! The cameras of a multi-camera rig within one frame's keypoints: the keypoints are sorted
//! by camera, so camera `k`'s are one contiguous range, found from the first keypoint of
//! each camera (`camera_starts`).

use std::ops::Range;

use ferroslam_features::{ImageBounds, Keypoint, KeypointGrid};

use crate::MapError;

/// Checks that `starts` can be a rig's camera starts over `len` keypoints: the first is 0,
/// none decreases, none is beyond `len` (a camera may see no keypoint).
///
/// # Errors
/// [`MapError::CameraStartsNotAtZero`], [`MapError::CameraStartsDecreasing`],
/// [`MapError::CameraStartBeyondKeypoints`], naming the starts and the camera.
pub(crate) fn check_camera_starts(starts: &[usize], len: usize) -> Result<(), MapError> {
    if starts.first() != Some(&0) {
        return Err(MapError::CameraStartsNotAtZero {
            starts: starts.to_vec(),
        });
    }
    if let Some(camera) = (1..starts.len()).find(|&k| starts[k] < starts[k - 1]) {
        return Err(MapError::CameraStartsDecreasing {
            starts: starts.to_vec(),
            camera,
        });
    }
    if let Some(camera) = starts.iter().position(|&s| s > len) {
        return Err(MapError::CameraStartBeyondKeypoints {
            starts: starts.to_vec(),
            camera,
            len,
        });
    }
    Ok(())
}

/// Keypoint indices of camera `k`: `starts[k]..starts[k + 1]` (the last camera's ends at
/// `len`). Clamped into `0..len` and never reversed, so that inconsistent starts (a
/// corrupt file, before its check) still give a valid slice; empty for `k` beyond the
/// cameras.
pub(crate) fn camera_range(starts: &[usize], len: usize, k: usize) -> Range<usize> {
    let start = starts.get(k).map_or(len, |&s| s.min(len));
    let end = starts.get(k + 1).map_or(len, |&s| s.min(len));
    start..end.max(start)
}

/// The camera whose range holds keypoint `i`; 0 for an out-of-range `i`. With empty
/// cameras (equal starts), the last camera starting at or before `i`: the one holding it.
pub(crate) fn camera_of(starts: &[usize], len: usize, i: usize) -> usize {
    if i >= len {
        return 0;
    }
    starts.partition_point(|&s| s <= i).saturating_sub(1)
}

/// One grid per camera over its range of `keypoints`, indexed locally, built over its
/// `bounds` (one per start; extra bounds or starts are ignored).
pub(crate) fn camera_grids(
    keypoints: &[Keypoint],
    starts: &[usize],
    bounds: impl IntoIterator<Item = ImageBounds>,
) -> Vec<KeypointGrid> {
    bounds
        .into_iter()
        .take(starts.len())
        .enumerate()
        .map(|(k, b)| KeypointGrid::new(&keypoints[camera_range(starts, keypoints.len(), k)], b))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_tolerate_inconsistent_starts() {
        assert_eq!(camera_range(&[0, 2, 5], 7, 0), 0..2);
        assert_eq!(camera_range(&[0, 2, 5], 7, 2), 5..7);
        assert_eq!(camera_range(&[0, 2, 5], 7, 3), 7..7);
        assert_eq!(camera_range(&[0, 5, 2], 7, 1), 5..5);
        assert_eq!(camera_range(&[0, 9], 7, 1), 7..7);
    }

    #[test]
    fn empty_cameras_hold_no_keypoint() {
        let starts = [0, 3, 3, 5];
        let cameras: Vec<_> = (0..7).map(|i| camera_of(&starts, 6, i)).collect();
        assert_eq!(cameras, [0, 0, 0, 2, 2, 3, 0]);
    }
}
