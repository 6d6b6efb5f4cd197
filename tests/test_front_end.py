"""The front end in the core (``SlamSystem.track``, one call per frame with the images): on
real frames it must give exactly what the features-level door gives when fed by the
standalone extractor and the numpy sampling it replaced, in every sensor mode; its
per-frame masks must hold; bad images are refused naming the problem, with the system
unchanged.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ferroslam import _core
from ferroslam.datasets.kitti import KittiSequence
from ferroslam.datasets.tum import TumSequence
from ferroslam.features import OrbExtractor, sample_colors, sample_depth

FRAMES = 40


def _systems(camera, sensor: str, **options):
    make = lambda: _core.SlamSystem(  # noqa: E731 - two identical systems
        camera.fx, camera.fy, camera.cx, camera.cy, list(camera.dist), camera.width,
        camera.height, sensor=sensor, model=camera.model,
        rolling_shutter_readout_s=camera.rolling_shutter_readout_s, **options)
    return make(), make()


def _poses(system) -> np.ndarray:
    _, poses = system.frame_trajectory()
    return np.asarray(poses)


def test_rgbd_and_mono_equal_the_features_door_bit_for_bit(tum_rpy):
    seq = TumSequence(tum_rpy)
    for sensor in ("rgbd", "mono"):
        door, features = _systems(seq.camera, sensor)
        extractor = OrbExtractor(**{k: door.options[k] for k in
                                    ("n_features", "scale_factor", "n_levels", "ini_fast",
                                     "min_fast")})
        for i in range(FRAMES):
            gray, color = seq.load_gray_and_color(i)
            t = float(seq.timestamps[i])
            kps, descs = extractor.detect(gray)
            colors = sample_colors(color, kps)
            if sensor == "rgbd":
                depth = seq.load_depth(i)
                res = door.track(t, gray, depth=depth, colors=color)
                features.track_rgbd(t, kps, descs, sample_depth(depth, kps), colors=colors)
            else:
                res = door.track(t, gray, colors=color)
                features.track_mono(t, kps, descs, colors=colors)
            np.testing.assert_array_equal(res.keypoints, kps)
        assert len(_poses(door)) > FRAMES // 2, sensor
        np.testing.assert_array_equal(_poses(door), _poses(features), err_msg=sensor)
        np.testing.assert_array_equal(np.asarray(door.map_point_colors()),
                                      np.asarray(features.map_point_colors()))


def test_stereo_equals_the_features_door_bit_for_bit(kitti_stereo):
    seq = KittiSequence(kitti_stereo)
    door, features = _systems(seq.camera, "stereo", baseline=float(seq.baseline_m))
    extractor = OrbExtractor(**{k: door.options[k] for k in
                                ("n_features", "scale_factor", "n_levels", "ini_fast",
                                 "min_fast")})
    for i in range(20):
        left, right = seq.load_stereo(i)
        t = float(seq.timestamps[i])
        door.track(t, (left, right))
        (lk, ld, lp), (rk, rd, rp) = extractor.detect_pair(left, right)
        features.track_stereo(t, lk, ld, lp, rk, rd, rp, colors=sample_colors(left, lk))
    assert len(_poses(door)) == 20
    np.testing.assert_array_equal(_poses(door), _poses(features))


def test_bgr_images_are_converted_as_opencv_converts_them(tum_rpy):
    seq = TumSequence(tum_rpy)
    _, color = seq.load_gray_and_color(0)
    # Noise: one grey level off at 2 % of the pixels (OpenCV's older 14-bit weights) moves
    # keypoints here.
    noise = np.random.default_rng(0).integers(0, 256, color.shape, dtype=np.uint8)
    for image in (color, noise):
        from_bgr, from_gray = _systems(seq.camera, "mono")
        res = from_bgr.track(1.0, image)
        ref = from_gray.track(1.0, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), colors=image)
        np.testing.assert_array_equal(res.keypoints, ref.keypoints)
        assert len(res.keypoints) > 500


def test_a_per_frame_mask_keeps_keypoints_off_its_pixels(tum_rpy):
    seq = TumSequence(tum_rpy)
    gray, _ = seq.load_gray_and_color(0)
    mask = np.ones_like(gray)
    mask[:, : gray.shape[1] // 2] = 0
    system, _ = _systems(seq.camera, "mono")
    kps = system.track(1.0, gray, masks=mask).keypoints
    assert len(kps) > 300
    assert np.all(np.rint(kps[:, 0]) >= gray.shape[1] // 2)
    system.set_mask(0, mask[::-1, ::-1].astype(bool))  # static: the other half
    assert len(system.track(2.0, gray, masks=mask).keypoints) == 0


@pytest.mark.parametrize("call, message", [
    (lambda s, g: s.track(1.0, g[:, :-1]),
     "invalid input: image is 639x480 but the camera is 640x480 (width x height)"),
    (lambda s, g: s.track(1.0, g.astype(np.float32)), "image dtype must be uint8, got float32"),
    (lambda s, g: s.track(1.0, g[None]), "image must be (H, W) grey or (H, W, 3) BGR, got "
                                         "shape (1, 480, 640)"),
    (lambda s, g: s.track(1.0, (g, g)), "invalid input: a mono frame has one image, got 2 "
                                        "image(s)"),
    (lambda s, g: s.track(1.0, g, depth=np.ones(g.shape, np.float32)),
     "invalid input: a depth image was given to a mono system: only RGB-D systems use depth"),
    (lambda s, g: s.track(1.0, g, masks=np.ones((4, 4), np.uint8)),
     "invalid input: mask is 4x4 but the camera is 640x480 (width x height)"),
    (lambda s, g: s.track(1.0, g, masks=np.ones(g.shape, np.float32)),
     "masks dtype must be uint8 or bool, got float32"),
    (lambda s, g: s.track(float("nan"), g), "invalid input: timestamp is not finite"),
    (lambda s, g: s.set_mask(1, np.ones(g.shape, np.uint8)),
     "invalid input: mask for camera 1, but a mono system has 1 camera(s)"),
])
def test_bad_images_are_refused_by_name_and_change_nothing(tum_rpy, call, message):
    seq = TumSequence(tum_rpy)
    gray, _ = seq.load_gray_and_color(0)
    system, _ = _systems(seq.camera, "mono")
    with pytest.raises(ValueError) as err:
        call(system, gray)
    assert str(err.value) == message
    assert system.track(1.0, gray).state == "not_initialized"  # the timestamp was not taken
