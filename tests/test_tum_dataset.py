"""TUM RGB-D loader on the real excerpts, and its error messages."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from ferroslam.datasets import (
    TUM_CAMERAS,
    Camera,
    ReplayedSequence,
    TumSequence,
    associate_greedy,
    open_sequence,
    replay_order,
)
from ferroslam.datasets.tum import FR1_READOUT_S


def _associate_py(first, second, max_difference):
    """TUM's associate.py algorithm, verbatim in spirit (quadratic, for checking)."""
    first_keys, second_keys = list(first), list(second)
    potential = sorted(
        (abs(a - b), a, b) for a in first_keys for b in second_keys if abs(a - b) < max_difference
    )
    matches = []
    for _, a, b in potential:
        if a in first_keys and b in second_keys:
            first_keys.remove(a)
            second_keys.remove(b)
            matches.append((a, b))
    return sorted(matches)


def test_rpy_sequence_loads(tum_rpy):
    seq = TumSequence(tum_rpy)
    assert len(seq) == 300
    assert seq.camera == TUM_CAMERAS[1]
    assert seq.camera.fx == 517.3 and seq.camera.dist.shape == (5,)
    frame = seq[0]
    assert frame.index == 0 and frame.timestamp == pytest.approx(1305031229.528748)
    assert frame.rgb_path.suffix == ".jpg" and frame.depth_path.suffix == ".png"
    assert np.all(np.diff(seq.timestamps) > 0)
    assert [f.index for f in seq][:3] == [0, 1, 2] and seq[-1].index == 299

    gray = seq.load_gray(0)
    assert gray.dtype == np.uint8 and gray.shape == (480, 640)
    # One read of the file, the grey image bit for bit load_gray's (JPEG's stored luma).
    same_gray, color = seq.load_gray_and_color(0)
    np.testing.assert_array_equal(same_gray, gray)
    assert color.dtype == np.uint8 and color.shape == (480, 640, 3)
    assert np.abs(np.diff(color.astype(int), axis=2)).mean() > 5  # a colour image
    depth = seq.load_depth(0)
    assert depth.dtype == np.float32 and depth.shape == (480, 640)
    valid = depth[depth > 0]
    assert 0.5 < valid.size / depth.size <= 1.0
    assert 0.3 < valid.min() and valid.max() < 10.0  # metres, factor 5000 applied

    t, T = seq.groundtruth()
    assert t.shape == (1197,) and T.shape == (1197, 4, 4)
    np.testing.assert_allclose(T[:, :3, :3] @ np.swapaxes(T[:, :3, :3], 1, 2),
                               np.broadcast_to(np.eye(3), (1197, 3, 3)), atol=1e-9)
    assert t[0] <= seq.timestamps[0] and t[-1] >= seq.timestamps[-1]


def test_association_matches_tum_associate_py(tum_rpy, tum_desk):
    for path in (tum_rpy, tum_desk):
        seq = TumSequence(path)
        pairs = [(f.timestamp, f.depth_timestamp) for f in seq]
        rgb = [float(l.split()[0]) for l in (path / "rgb.txt").read_text().splitlines()
               if l and not l.startswith("#")]
        depth = [float(l.split()[0]) for l in (path / "depth.txt").read_text().splitlines()
                 if l and not l.startswith("#")]
        assert pairs == _associate_py(rgb, depth, 0.02)


def test_associate_greedy_is_one_to_one():
    a = np.array([0.0, 0.010, 0.040])
    b = np.array([0.005, 0.041, 0.2])
    i, j = associate_greedy(a, b, 0.02)
    # 0.010 and 0.0 both want 0.005; the closer (0.010, |dt|=0.005 tie -> first) wins once.
    assert list(zip(i.tolist(), j.tolist())) == [(0, 0), (2, 1)]


def test_desk_sequence_png(tum_desk):
    seq = open_sequence(tum_desk)
    assert isinstance(seq, TumSequence) and len(seq) == 9
    assert seq[0].rgb_path.suffix == ".png"
    assert seq.load_gray(8).shape == (480, 640)


def test_camera_from_yaml_and_argument(tum_desk, tmp_path):
    folder = tmp_path / "my_sequence"
    shutil.copytree(tum_desk, folder)
    with pytest.raises(ValueError, match="camera"):
        TumSequence(folder)
    explicit = Camera(500.0, 500.0, 320.0, 240.0)
    assert TumSequence(folder, camera=explicit).camera is explicit
    (folder / "camera.yaml").write_text(
        "%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n"
        "Camera.k1: 0.1\nCamera.width: 640\nCamera.height: 480\nDepthMapFactor: 5000.0\n"
    )
    cam = TumSequence(folder).camera
    assert (cam.fx, cam.cy, cam.dist[0], cam.dist[4]) == (535.4, 247.6, 0.1, 0.0)
    for name, number in (("rgbd_dataset_freiburg3_x", 3), ("fr2_desk", 2)):
        renamed = tmp_path / name
        shutil.copytree(tum_desk, renamed)
        assert TumSequence(renamed).camera == TUM_CAMERAS[number]
        # No frames of the freiburg2/3 Kinects to measure a readout on: global shutters.
        assert TUM_CAMERAS[number].rolling_shutter_readout_s == 0.0
    assert cam.rolling_shutter_readout_s == 0.0  # a camera.yaml without the key
    assert TUM_CAMERAS[1].rolling_shutter_readout_s == FR1_READOUT_S > 0


def test_missing_folder_and_files(tum_desk, tmp_path):
    missing = tmp_path / "rgbd_dataset_freiburg1_none"
    with pytest.raises(FileNotFoundError, match="rgbd_dataset_freiburg1_none"):
        TumSequence(missing)
    folder = tmp_path / "rgbd_dataset_freiburg1_desk"
    shutil.copytree(tum_desk, folder)
    (folder / "depth.txt").unlink()
    with pytest.raises(FileNotFoundError, match="depth.txt"):
        TumSequence(folder)
    assert len(TumSequence(folder, with_depth=False)) == 9
    (folder / "rgb.txt").rename(folder / "rgb.old")
    with pytest.raises(FileNotFoundError, match="rgb.txt"):
        TumSequence(folder, with_depth=False)


def test_missing_and_broken_images(tum_desk, tmp_path):
    folder = tmp_path / "rgbd_dataset_freiburg1_desk"
    shutil.copytree(tum_desk, folder)
    seq = TumSequence(folder)
    seq[0].rgb_path.unlink()
    with pytest.raises(FileNotFoundError, match=seq[0].rgb_path.name):
        seq.load_gray(0)
    seq[1].rgb_path.write_bytes(b"")
    with pytest.raises(ValueError, match="empty"):
        seq.load_gray(1)
    seq[2].rgb_path.write_bytes(b"not a png at all")
    with pytest.raises(ValueError, match="unreadable"):
        seq.load_gray(2)
    # an 8-bit image where a 16-bit depth map is expected
    shutil.copy(seq[3].rgb_path, seq[3].depth_path)
    with pytest.raises(ValueError, match="16-bit"):
        seq.load_depth(3)


def _write_list(path, lines):
    path.write_text("# color images\n# timestamp filename\n" + "\n".join(lines) + "\n")


def test_malformed_and_unordered_lists(tum_desk, tmp_path):
    folder = tmp_path / "rgbd_dataset_freiburg1_desk"
    shutil.copytree(tum_desk, folder)
    original = [l for l in (folder / "rgb.txt").read_text().splitlines() if not l.startswith("#")]
    _write_list(folder / "rgb.txt", [original[1], original[0]] + original[2:])
    with pytest.raises(ValueError, match=r"rgb.txt:4.*out of order"):
        TumSequence(folder)
    _write_list(folder / "rgb.txt", original[:2] + ["1305031453.5"] + original[3:])
    with pytest.raises(ValueError, match=r"rgb.txt:5"):
        TumSequence(folder)
    _write_list(folder / "rgb.txt", ["abc rgb/x.png"])
    with pytest.raises(ValueError, match="bad timestamp"):
        TumSequence(folder)
    _write_list(folder / "rgb.txt", original)
    gt = (folder / "groundtruth.txt").read_text().splitlines()
    (folder / "groundtruth.txt").write_text("\n".join(gt[:3] + [gt[4], gt[3]] + gt[5:]))
    with pytest.raises(ValueError, match="out of order"):
        TumSequence(folder).groundtruth()
    (folder / "groundtruth.txt").unlink()
    seq = TumSequence(folder)
    assert not seq.has_groundtruth
    with pytest.raises(FileNotFoundError, match="groundtruth.txt"):
        seq.groundtruth()


def test_replay_order_turns_without_repeating_a_frame():
    np.testing.assert_array_equal(replay_order(4, 3), [0, 1, 2, 3, 2, 1, 0, 1, 2, 3])
    np.testing.assert_array_equal(replay_order(4, 1), [0, 1, 2, 3])


def test_replayed_sequence_serves_the_frames_on_increasing_timestamps(tum_rpy):
    seq = TumSequence(tum_rpy)
    replayed = ReplayedSequence(seq, passes=2, max_frames=5)
    assert len(replayed) == 9 and replayed.camera == seq.camera
    np.testing.assert_array_equal(replayed.order, [0, 1, 2, 3, 4, 3, 2, 1, 0])
    assert np.all(np.diff(replayed.timestamps) > 0) and replayed.timestamps[0] == seq.timestamps[0]
    np.testing.assert_array_equal(replayed.load_gray(6), seq.load_gray(2))
    np.testing.assert_array_equal(replayed.load_depth(8), seq.load_depth(0))
