"""The native stereo path: the Rust stereo matcher against OpenCV's semi-global matcher on
real KITTI frames, and bad stereo input to ``SlamSystem.track_stereo`` (clear exception,
system unchanged)."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from ferroslam.datasets import KittiSequence
from ferroslam.features import OrbExtractor

core = pytest.importorskip("ferroslam._core")


@pytest.fixture(scope="module")
def kitti(kitti_stereo):
    return KittiSequence(kitti_stereo)


@pytest.fixture(scope="module")
def pairs(kitti):
    """Features and pyramids of the first three stereo pairs: (t, left, right) with each side
    ``(keypoints, descriptors, pyramid)``."""
    extractor = OrbExtractor(n_features=2000)
    out = []
    for i in range(3):
        left, right = kitti.load_stereo(i)
        out.append((float(kitti.timestamps[i]), extractor.detect_with_pyramid(left),
                    extractor.detect_with_pyramid(right)))
    return out


def make_system(seq, **options):
    c = seq.camera
    options.setdefault("baseline", seq.baseline_m)
    return core.SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height,
                           sensor="stereo", **options)


def test_matcher_agrees_with_semi_global_matching(kitti, pairs):
    """On KITTI frames 0-2 our per-feature disparities match OpenCV's SGBM (an independent
    dense method) without bias: measured median difference within +-0.02 px, 75-79 % of
    features within 1 px, about half the left features matched. Bounds leave room for
    OpenCV version differences but catch a half-pixel bias (5 % depth error at 10 px)."""
    sgbm = cv2.StereoSGBM_create(0, 128, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 mode=cv2.STEREO_SGBM_MODE_HH)
    for i, (_, (lk, ld, lp), (rk, rd, rp)) in enumerate(pairs):
        u_right, depth = core.match_stereo(lk, ld, lp, rk, rd, rp, fx=kitti.camera.fx,
                                           baseline=kitti.baseline_m)
        matched = u_right >= 0
        assert 0.4 < matched.mean() < 0.7, i
        disparity = lk[matched, 0] - u_right[matched]
        # depth = fx * baseline / disparity, checked in pixels of disparity: the columns are
        # float32 (~6e-5 px steps at u ~ 1000), which a relative bound on depth would magnify
        # for far features (a 0.012 px disparity misses rtol 2e-3 by float32 rounding alone).
        np.testing.assert_allclose(kitti.camera.fx * kitti.baseline_m / depth[matched],
                                   disparity, rtol=0, atol=1e-3)
        left, right = kitti.load_stereo(i)
        dense = sgbm.compute(left, right).astype(np.float32) / 16
        ref = dense[np.rint(lk[matched, 1]).astype(int), np.rint(lk[matched, 0]).astype(int)]
        diff = (disparity - ref)[ref > 0]
        assert abs(np.median(diff)) < 0.1, i
        assert np.mean(np.abs(diff) < 1.0) > 0.65, i


def test_track_stereo_runs_on_real_pairs(kitti, pairs):
    system = make_system(kitti)
    assert system.sensor == "stereo"
    states = [system.track_stereo(t, *left, *right).state for t, left, right in pairs]
    assert states == ["ok"] * 3
    assert system.num_map_points > 500


def test_option_errors(kitti):
    c = kitti.camera
    with pytest.raises(ValueError, match="sensor 'stereo' needs baseline"):
        core.SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor="stereo")
    with pytest.raises(ValueError, match="baseline: must be a positive number"):
        make_system(kitti, baseline=-0.5)
    with pytest.raises(ValueError, match="option baseline applies to sensor 'stereo'"):
        core.SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, baseline=0.5)


def test_sensor_mismatch_and_distorted_camera(kitti, pairs):
    t, left, right = pairs[0]
    system = make_system(kitti)
    with pytest.raises(ValueError, match=re.escape('track_rgbd needs a system created with '
                                                   'sensor="rgbd"; this one is "stereo"')):
        system.track_rgbd(t, left[0], left[1], np.zeros(len(left[0]), np.float32))
    c = kitti.camera
    distorted = core.SlamSystem(c.fx, c.fy, c.cx, c.cy, [0.1, 0, 0, 0], c.width, c.height,
                                sensor="stereo", baseline=kitti.baseline_m)
    with pytest.raises(ValueError, match="stereo input must come from rectified images"):
        distorted.track_stereo(t, *left, *right)


def bad_inputs(pairs):
    t, (lk, ld, lp), (rk, rd, rp) = pairs[1]
    half = [cv2.resize(level, (level.shape[1] // 2, level.shape[0])) for level in rp]
    return {
        "sizes differ": ((t, lk, ld, lp, rk, rd, half), ValueError,
                         "left and right images differ in size at pyramid level 0"),
        "too few levels": ((t, lk, ld, lp[:2], rk, rd, rp), ValueError,
                           "left image: keypoints reach octave 7 but only 2 pyramid levels"),
        "empty pyramid": ((t, lk, ld, [], rk, rd, rp), ValueError, "left_pyramid is empty"),
        "float level": ((t, lk, ld, [lp[0].astype(np.float32)] + lp[1:], rk, rd, rp),
                        TypeError, "left_pyramid[0] must be a 2-D uint8 array, got float32"),
        "not a list": ((t, lk, ld, 3, rk, rd, rp), TypeError,
                       "left_pyramid must be a list of 2-D uint8 arrays"),
        "lengths": ((t, lk, ld[:-1], lp, rk, rd, rp), ValueError,
                    f"left_keypoints ({len(lk)}) and left_descriptors ({len(lk) - 1})"),
        "time": ((pairs[0][0], lk, ld, lp, rk, rd, rp), ValueError,
                 "is not after the previous frame's"),
    }


@pytest.mark.parametrize("case", ["sizes differ", "too few levels", "empty pyramid",
                                  "float level", "not a list", "lengths", "time"])
def test_bad_stereo_input_leaves_the_system_unchanged(kitti, pairs, case):
    system = make_system(kitti)
    t, left, right = pairs[0]
    system.track_stereo(t, *left, *right)
    before = (system.state, system.num_map_points, system.frame_trajectory()[0].tolist())
    args, error, message = bad_inputs(pairs)[case]
    with pytest.raises(error, match=re.escape(message)):
        system.track_stereo(*args)
    assert (system.state, system.num_map_points, system.frame_trajectory()[0].tolist()) == before
    t1, left1, right1 = pairs[1]
    assert system.track_stereo(t1, *left1, *right1).state == "ok"
