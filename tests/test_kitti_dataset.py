"""KITTI odometry loader on the real excerpts, and its errors on small fake layouts."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import require_data
from ferroslam.datasets import KittiSequence, open_sequence, read_kitti_calib


@pytest.fixture(scope="module")
def kitti_stereo():
    return require_data("kitti", "stereo_51_frames")


@pytest.fixture(scope="module")
def kitti_mono():
    return require_data("kitti", "odometry_06_first51")


def test_stereo_sequence(kitti_stereo):
    seq = open_sequence(kitti_stereo)
    assert isinstance(seq, KittiSequence) and seq.is_stereo and seq.name == "stereo_51_frames"
    assert len(seq) == 51 and len(list(seq)) == 51 and seq[50].index == 50
    assert seq.baseline_m == pytest.approx(0.5372, abs=1e-4)
    cam = seq.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (718.856, 718.856, 607.1928, 185.2157)
    assert (cam.width, cam.height) == (1241, 376) and not cam.dist.any()
    assert seq.timestamps.dtype == np.float64 and np.all(np.diff(seq.timestamps) > 0)
    assert seq.timestamps[-1] == pytest.approx(5.185269)

    left, right = seq.load_stereo(50)
    assert left.dtype == right.dtype == np.uint8 and left.shape == right.shape == (376, 1241)
    np.testing.assert_array_equal(seq.load_gray(50), left)

    assert seq.has_groundtruth
    t, T = seq.groundtruth()
    assert t.shape == (51,) and T.shape == (51, 4, 4)
    np.testing.assert_array_equal(t, seq.timestamps)
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(T[-1, :3, 3], (40.02, -0.86, 19.93), atol=0.01)


def test_mono_sequence(kitti_mono):
    seq = KittiSequence(kitti_mono)
    assert len(seq) == 51 and not seq.is_stereo and seq.baseline_m is None
    assert seq.camera.fx == 707.0912 and (seq.camera.width, seq.camera.height) == (1226, 370)
    assert seq.load_gray(0).shape == (370, 1226) and seq[0].right_path is None
    with pytest.raises(ValueError, match="mono"):
        seq.load_stereo(0)
    assert seq.groundtruth()[1].shape == (51, 4, 4)
    assert read_kitti_calib(kitti_mono / "calib.txt")["P1"][0, 3] == pytest.approx(-379.8145)


def test_stereo_folder_opened_as_mono(kitti_stereo):
    seq = KittiSequence(kitti_stereo, stereo=False)
    assert not seq.is_stereo and seq.baseline_m is None and len(seq) == 51


# --- errors, on a tiny fake layout -------------------------------------------------------

_CALIB = (
    "P0: 100 0 10 0 0 100 5 0 0 0 1 0\n"
    "P1: 100 0 10 -50 0 100 5 0 0 0 1 0\n"
)


def _fake(root, n=3, left="image_0", right="image_1", size=(8, 20), times=None):
    root.mkdir(parents=True, exist_ok=True)
    (root / "calib.txt").write_text(_CALIB)
    (root / "times.txt").write_text("\n".join(times or [f"{0.1 * i:e}" for i in range(n)]) + "\n")
    for folder in (left, right):
        if folder:
            (root / folder).mkdir()
            for i in range(n):
                cv2.imwrite(str(root / folder / f"{i:06d}.png"), np.full(size, i, np.uint8))
    return root


def test_fake_layout_loads_with_image_l_r_names(tmp_path):
    root = _fake(tmp_path / "seq", left="image_l", right="image_r")
    (root / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    seq = open_sequence(root)
    assert isinstance(seq, KittiSequence) and seq.is_stereo and seq.baseline_m == 0.5
    assert (seq.camera.width, seq.camera.height) == (20, 8)
    assert seq.load_stereo(2)[1][0, 0] == 2
    assert seq.groundtruth()[1].shape == (3, 4, 4)


def test_missing_calib(tmp_path):
    root = _fake(tmp_path / "seq")
    (root / "calib.txt").unlink()
    with pytest.raises(FileNotFoundError, match="calib.txt"):
        KittiSequence(root)


def test_missing_p1_line_for_stereo(tmp_path):
    root = _fake(tmp_path / "seq")
    (root / "calib.txt").write_text(_CALIB.splitlines()[0] + "\n")
    with pytest.raises(ValueError, match="calib.txt: no P1 line"):
        KittiSequence(root)
    assert not KittiSequence(root, stereo=False).is_stereo  # mono needs only P0


def test_bad_calib_line(tmp_path):
    root = _fake(tmp_path / "seq")
    (root / "calib.txt").write_text("P0: 1 2 3\n")
    with pytest.raises(ValueError, match=r"calib.txt:1: P0 must be 12"):
        KittiSequence(root)


def test_times_count_mismatch(tmp_path):
    root = _fake(tmp_path / "seq", times=["0", "0.1"])
    with pytest.raises(ValueError, match="3 images but .*times.txt has 2 times"):
        KittiSequence(root)


def test_times_out_of_order(tmp_path):
    root = _fake(tmp_path / "seq", times=["0", "0.2", "0.1"])
    with pytest.raises(ValueError, match=r"times.txt:3: times out of order"):
        KittiSequence(root)


def test_missing_right_image(tmp_path):
    root = _fake(tmp_path / "seq")
    (root / "image_1" / "000001.png").unlink()
    with pytest.raises(ValueError, match="right images missing .*000001.png"):
        KittiSequence(root)


def test_left_right_sizes_differ(tmp_path):
    root = _fake(tmp_path / "seq")
    cv2.imwrite(str(root / "image_1" / "000000.png"), np.zeros((9, 20), np.uint8))
    with pytest.raises(ValueError, match="000000.png is 20x9, expected 20x8"):
        KittiSequence(root)


def test_pose_count_mismatch(tmp_path):
    root = _fake(tmp_path / "seq")
    (root / "poses").mkdir()
    (root / "poses" / "00.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    seq = KittiSequence(root)
    with pytest.raises(ValueError, match="1 poses but the sequence has 3 frames"):
        seq.groundtruth()


def test_unknown_layout(tmp_path):
    with pytest.raises(ValueError, match=r"expected rgb.txt \(TUM\), calib.txt"):
        open_sequence(tmp_path)
    with pytest.raises(ValueError, match="unknown dataset format"):
        open_sequence(tmp_path, "bag")
