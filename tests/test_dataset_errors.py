"""Broken TUM / KITTI / EuRoC folders and calibration files, made in tmp_path: each is a
documented exception naming the file (or the reason no frame is usable), or a success; never
another exception, and nothing outside tmp_path is touched. Hypothesis generates list files."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import strategies as st

from ferroslam import load_calibration
from ferroslam.datasets import (EurocSequence, KittiSequence, TumSequence, open_sequence,
                                read_kitti_calib, read_sensor_yaml)
from ferroslam.pipeline import run_sequence

from conftest import require_data
from fuzzing import fuzz

DOCUMENTED = (FileNotFoundError, IsADirectoryError, ValueError)


def _tum(folder, rgb: str, depth: str):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "rgb.txt").write_text(rgb)
    (folder / "depth.txt").write_text(depth)
    (folder / "camera.yaml").write_text("fx: 500\nfy: 500\ncx: 320\ncy: 240\n")
    return folder


def test_tum_depth_list_pairing_with_no_rgb_frame_says_why(tmp_path):
    seq = _tum(tmp_path / "s", "1.0 rgb/a.png\n2.0 rgb/b.png\n", "5.0 d/a.png\n6.0 d/b.png\n")
    with pytest.raises(ValueError, match=rf"{seq}: no RGB frame has a depth frame within 0.02 s "
                                         r"\(rgb.txt 1.000..2.000 s, depth.txt 5.000..6.000 s\)"):
        TumSequence(seq)


def test_tum_nanosecond_timestamps_are_refused(tmp_path):
    seq = _tum(tmp_path / "s", "1305031102175304000 rgb/a.png\n", "1305031102175304000 d/a.png\n")
    with pytest.raises(ValueError, match=r"rgb.txt:1: timestamp 1305031102175304000 looks like "
                                         "nanoseconds; TUM lists give seconds"):
        TumSequence(seq)


def test_tum_empty_rgb_list_is_an_error(tmp_path):
    seq = _tum(tmp_path / "s", "# only a comment\n", "1.0 d/a.png\n")
    with pytest.raises(ValueError, match=r"rgb.txt: TUM rgb list lists no frames"):
        TumSequence(seq)
    with pytest.raises(ValueError, match="lists no frames"):
        open_sequence(seq, sensor="rgbd")


def test_tum_list_not_utf8_names_the_file(tmp_path):
    seq = _tum(tmp_path / "s", "1.0 rgb/a.png\n", "1.0 d/a.png\n")
    (seq / "depth.txt").write_bytes(b"1.0 d/\xff\xfe.png\n")
    with pytest.raises(ValueError, match=rf"{seq / 'depth.txt'}: not a UTF-8 text file"):
        TumSequence(seq)


def test_run_sequence_refuses_a_sequence_without_frames():
    class Empty:
        name = "empty"
        camera = None

        def __len__(self):
            return 0

    with pytest.raises(ValueError, match="empty: the sequence has no frames to track"):
        run_sequence(Empty(), sensor="mono", progress=False)


def test_kitti_folder_without_calib_says_calib_is_missing(tmp_path):
    seq = tmp_path / "00"
    (seq / "image_0").mkdir(parents=True)
    cv2.imwrite(str(seq / "image_0" / "000000.png"), np.zeros((10, 12), np.uint8))
    (seq / "times.txt").write_text("0.0\n")
    with pytest.raises(FileNotFoundError, match=rf"KITTI calibration file not found: "
                                                rf"{seq / 'calib.txt'}"):
        open_sequence(seq)
    (seq / "calib.txt").write_bytes(b"P0: 1 0 0 0 \xff")
    with pytest.raises(ValueError, match=rf"{seq / 'calib.txt'}: not UTF-8 text"):
        read_kitti_calib(seq / "calib.txt")


def test_euroc_sensor_yaml_not_utf8_names_the_file(tmp_path):
    path = tmp_path / "sensor.yaml"
    path.write_bytes(b"rate_hz: 200\ncomment: \xe9\n")
    with pytest.raises(ValueError, match=rf"{path}: not UTF-8 text"):
        read_sensor_yaml(path)


def test_calibration_not_utf8_or_a_fifo_names_the_file(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_bytes(b"fx: 500\n# caf\xe9\n")
    with pytest.raises(ValueError, match=rf"{path}: not UTF-8 text"):
        load_calibration(path)
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=rf"{fifo}: is a FIFO"):
        load_calibration(fifo)  # refused before open(): nothing blocks


# -- generated list files -------------------------------------------------------------------

_STAMP = st.one_of(st.floats(-1e3, 1e20).map(repr), st.sampled_from(["nan", "inf"]),
                   st.integers(0, 10**19).map(str), st.text("0123456789.e-x", max_size=6))
_LINE = st.one_of(st.tuples(_STAMP, st.sampled_from(["a.png", "", "b c"])).map(" ".join),
                  st.just("# comment"), st.just(""))
_LIST = st.lists(_LINE, max_size=6).map(lambda lines: "\n".join(lines) + "\n")
_BYTES = st.one_of(_LIST.map(str.encode), st.binary(max_size=40))


@given(rgb=_BYTES, depth=_BYTES, kind=st.sampled_from(["tum", "kitti", "euroc"]))
@fuzz(150, deadline=500,
      suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
def test_generated_broken_folders_raise_documented_errors(tmp_path_factory, rgb, depth, kind):
    root = tmp_path_factory.mktemp("gen")
    before = set(os.listdir(root.parent))
    if kind == "tum":
        (root / "rgb.txt").write_bytes(rgb)
        (root / "depth.txt").write_bytes(depth)
        (root / "camera.yaml").write_text("fx: 500\nfy: 500\ncx: 320\ncy: 240\n")
        opener = lambda: TumSequence(root)  # noqa: E731
    elif kind == "kitti":
        (root / "image_0").mkdir()
        (root / "calib.txt").write_bytes(rgb)
        (root / "times.txt").write_bytes(depth)
        opener = lambda: KittiSequence(root)  # noqa: E731
    else:
        (root / "cam0").mkdir()
        (root / "cam0" / "data.csv").write_bytes(rgb)
        (root / "cam0" / "sensor.yaml").write_bytes(depth)
        opener = lambda: EurocSequence(root)  # noqa: E731
    try:
        seq = opener()
    except DOCUMENTED as err:
        assert str(root) in str(err), str(err)
    else:
        assert len(seq) > 0  # a sequence that opens has usable frames
    # Only the generated folder changed: nothing written beside it.
    assert set(os.listdir(root.parent)) == before


def _euroc(root, shared_mav0):
    for sensor in ("cam0", "imu0"):
        (root / "mav0" / sensor).mkdir(parents=True)
        (root / "mav0" / sensor / "sensor.yaml").write_bytes(
            (shared_mav0 / sensor / "sensor.yaml").read_bytes())
    return root


def test_euroc_empty_lists_say_so(tmp_path):
    root = _euroc(tmp_path / "seq", require_data("euroc", "MH_01_easy_window", "mav0"))
    cams = root / "mav0" / "cam0" / "data.csv"
    cams.write_text("#timestamp [ns],filename\n")
    with pytest.raises(ValueError, match=rf"{cams}: EuRoC cam0 list lists no frames"):
        EurocSequence(root, stereo=False)
    cams.write_text("#timestamp [ns],filename\n1403636579763555584,a.png\n")
    imu = root / "mav0" / "imu0" / "data.csv"
    imu.write_text("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n")  # only the header
    with pytest.raises(ValueError, match=rf"{imu}: EuRoC IMU file holds no samples"):
        EurocSequence(root, stereo=False).imu()
