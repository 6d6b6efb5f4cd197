"""Plausibility checks of the core (issue 53 item 3): implausible cameras and maps with a valid
checksum but impossible content are ValueErrors naming the parameter / keyframe / point, and
the real calibrations still pass."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
import yaml

from conftest import require_data
from ferroslam.datasets import EurocSequence, KittiSequence, TumSequence
from ferroslam.features import OrbExtractor, sample_depth

core = pytest.importorskip("ferroslam._core")
SlamSystem = core.SlamSystem

TUM_FR1 = (517.3, 516.5, 318.6, 255.3)


def system_of(camera, **options):
    c = camera
    return SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, model=c.model,
                      **options)


# -- cameras ----------------------------------------------------------------------------------

def test_real_calibrations_pass(tum_rpy, euroc_micro, kitti_mono):
    system_of(TumSequence(tum_rpy).camera)
    system_of(EurocSequence(euroc_micro, stereo=False).camera)
    system_of(KittiSequence(kitti_mono).camera, sensor="mono")
    t265 = yaml.safe_load((require_data("rosbag", "t265_locoffice") / "calibration.yaml")
                          .read_text())
    for cam in ("cam0", "cam1"):
        c = t265[cam]
        SlamSystem(*c["intrinsics"], c["distortion"], *c["resolution"], model="kannala_brandt",
                   sensor="mono")


@pytest.mark.parametrize(
    ("intrinsics", "dist", "model", "message"),
    [
        ((517.3, 516.5, 700.0, 255.3), [], "pinhole",
         "`cx` = 700: principal point must lie inside the image"),
        ((517.3, 516.5, 318.6, -3.0), [], "pinhole",
         "`cy` = -3: principal point must lie inside the image"),
        (TUM_FR1, [100, 0, 0, 0, 0], "pinhole",
         "`k1` = 100: the distortion scales radii inside the image by more than a factor 3"),
        (TUM_FR1, [1e9, 0, 0, 0, 0], "pinhole", "`k1` = 1000000000: the distortion scales"),
        (TUM_FR1, [-1.0, 0, 0, 0, 0], "pinhole", "`k1` = -1: the distortion folds the image"),
        (TUM_FR1, [0, 0, 0, 0, -50.0], "pinhole", "`k3` = -50: the distortion folds"),
        ((284.5, 285.5, 424.4, 393.7), [1e3, -1e3, 1e3, -1e3], "kannala_brandt",
         "`k1` = 1000: the distortion scales radii inside the image by more than a factor 3"),
        ((284.5, 285.5, 424.4, 393.7), [0, 0, 0, 0], "kannala_brandt",
         None),  # a valid equidistant lens: the control case
    ],
    ids=["cx outside", "cy negative", "k1 100", "k1 1e9", "k1 folds", "k3 folds", "kb 1e3",
         "kb equidistant"],
)
def test_implausible_cameras_name_the_parameter(intrinsics, dist, model, message):
    size = (848, 800) if model == "kannala_brandt" else (640, 480)
    if message is None:
        SlamSystem(*intrinsics, dist, *size, model=model, sensor="mono")
        return
    with pytest.raises(ValueError, match=re.escape(message)):
        SlamSystem(*intrinsics, dist, *size, model=model, sensor="mono")


def test_orbslam3_settings_with_k1_1e9_are_refused(tmp_path):
    from ferroslam.calibration import load_calibration
    settings = tmp_path / "orbslam3.yaml"
    settings.write_text(
        "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera1.fx: 517.3\nCamera1.fy: 516.5\n"
        "Camera1.cx: 318.6\nCamera1.cy: 255.3\nCamera1.k1: 1e9\nCamera1.k2: 0.0\n"
        "Camera1.p1: 0.0\nCamera1.p2: 0.0\nCamera.width: 640\nCamera.height: 480\n"
    )
    # Refused as the file is read (Camera runs the core's checks), naming file and key.
    with pytest.raises(ValueError, match=re.escape(f"{settings}: Camera1.fx: invalid camera: "
                                                   "invalid parameter `k1` = 1000000000")):
        load_calibration(settings)


# -- maps -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def saved_map(tum_rpy, tmp_path_factory):
    """A map of the first TUM frames: its bytes and its first map point (m)."""
    seq = TumSequence(tum_rpy)
    system = system_of(seq.camera)
    extractor = OrbExtractor()
    for i in range(3):
        kp, desc = extractor.detect(seq.load_gray(i))
        system.track_rgbd(float(seq.timestamps[i]), kp, desc,
                          sample_depth(seq.load_depth(i), kp))
    path = tmp_path_factory.mktemp("map") / "map.fslam"
    system.save_map(path)
    assert system.num_keyframes >= 1 and len(system.map_points()) > 100
    return path.read_bytes(), system.map_points()[0], seq.camera


def fnv1a64(data: bytes) -> int:
    """The codec's checksum: 64-bit FNV-1a of everything before the trailing 8 bytes."""
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def resealed(data: bytearray) -> bytes:
    data[-8:] = struct.pack("<Q", fnv1a64(bytes(data[:-8])))
    return bytes(data)


def replaced(data: bytes, old: bytes, new: bytes) -> bytes:
    assert data.count(old) == 1, "the edited value is not unique in the file"
    return resealed(bytearray(data.replace(old, new)))


# The first keyframe initialises at identity: translation 0 0 0, quaternion i j k w = 0 0 0 1.
IDENTITY_POSE = struct.pack("<7d", 0, 0, 0, 0, 0, 0, 1)


def load_error(tmp_path, camera, data: bytes) -> str:
    path = tmp_path / "edited.fslam"
    path.write_bytes(data)
    system = system_of(camera)
    with pytest.raises(ValueError) as err:
        system.load_map(path)
    assert system.num_keyframes == 0  # unchanged
    return str(err.value)


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        ((float("nan"), 0, 0, 0, 0, 0, 1), "keyframe KF0: pose T_c_w translation [NaN, 0.0, 0.0] "
                                           "not finite"),
        ((1e300, 0, 0, 0, 0, 0, 1), "keyframe KF0: pose T_c_w translation [1e300, 0.0, 0.0] "
                                    "beyond 1e6 m"),
        ((0, 0, 0, 0, 0, 0, float("inf")), "keyframe KF0: pose T_c_w rotation quaternion"),
        ((0, 0, 0, 0, 0, 0, 2.0), "has norm 2 (not a rotation"),
    ],
    ids=["nan translation", "1e300 translation", "inf rotation", "scaled rotation"],
)
def test_bad_keyframe_poses_are_refused(saved_map, tmp_path, pose, message):
    data, _, camera = saved_map
    error = load_error(tmp_path, camera, replaced(data, IDENTITY_POSE, struct.pack("<7d", *pose)))
    assert message in error
    assert re.match(r"map file \S+edited\.fslam: corrupt map file: keyframe KF0: ", error), error


@pytest.mark.parametrize("value", [float("nan"), float("-inf"), 1e300],
                         ids=["nan", "-inf", "1e300"])
def test_bad_map_points_are_refused_naming_the_point(saved_map, tmp_path, value):
    data, point, camera = saved_map
    bad = point.copy()
    bad[2] = value
    error = load_error(tmp_path, camera,
                       replaced(data, struct.pack("<3d", *point), struct.pack("<3d", *bad)))
    assert re.search(r"map point MP\d+: position \[", error), error


def test_the_unedited_map_loads(saved_map, tmp_path):
    data, point, camera = saved_map
    path = tmp_path / "same.fslam"
    path.write_bytes(resealed(bytearray(data)))
    system = system_of(camera)
    system.load_map(path)
    assert np.array_equal(system.map_points()[0], point)
