"""``ferroslam check`` (``ferroslam.check``, ``ferroslam.time_offset``): the camera-IMU time
offset found in the MH_01 window with its IMU stamps shifted, and used by a stereo-inertial
run; an error line and exit status 1 for each bad calibration class and for frame times out
of order; ``--json``; ``ferroslam run`` failing early on the cheap checks."""

from __future__ import annotations

import contextlib
import functools
import io
import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import require_data
from ferroslam.check import check_depth_scale, check_frame_times
from ferroslam.cli import main
from ferroslam.datasets import open_sequence
from ferroslam.metrics import ate
from ferroslam.pipeline import run_sequence

MH_01 = ("euroc", "MH_01_easy_window")


def _euroc_copy(dest: Path, *, imu_shift_s: float = 0.0, edit=None) -> Path:
    """The MH_01 window under ``dest``: images linked, text files copied, the IMU stamps
    moved by ``imu_shift_s`` (``t_imu = t_cam + shift``: the stamps run late for a positive
    shift), then ``edit(mav0)`` to break something."""
    source = require_data(*MH_01) / "mav0"
    mav0 = dest / "mav0"
    for folder in ("cam0", "cam1", "imu0", "state_groundtruth_estimate0"):
        (mav0 / folder).mkdir(parents=True)
        for item in (source / folder).iterdir():
            if item.is_dir():
                (mav0 / folder / item.name).symlink_to(item)
            else:
                shutil.copyfile(item, mav0 / folder / item.name)
    shutil.copyfile(source / "body.yaml", mav0 / "body.yaml")
    imu = mav0 / "imu0" / "data.csv"
    header, *rows = imu.read_text().splitlines()
    shift_ns = round(imu_shift_s * 1e9)
    imu.write_text("\n".join([header] + [f"{int(r.split(',', 1)[0]) + shift_ns},"
                                         f"{r.split(',', 1)[1]}" for r in rows]) + "\n")
    if edit is not None:
        edit(mav0)
    return dest


def _check(argv: list[str], capsys) -> tuple[int, str]:
    status = main(["check", *map(str, argv)])
    return status, capsys.readouterr().out


@functools.lru_cache(maxsize=None)
def _shifted_report(shift_s: float, root: Path) -> tuple[Path, dict]:
    """``ferroslam check --json`` of the MH_01 window with the IMU stamps shifted (once per
    shift: the tests of the estimate and of the run share it)."""
    path = _euroc_copy(root / f"shift_{shift_s:+.3f}", imu_shift_s=shift_s)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main(["check", str(path), "--json"])
    return path, {"status": status, **json.loads(stdout.getvalue())}


@pytest.fixture(scope="module")
def shifted(tmp_path_factory):
    root = tmp_path_factory.mktemp("shifted")
    return lambda shift_s: _shifted_report(shift_s, root)


@pytest.mark.parametrize("shift_s", [0.020, -0.035, 0.0], ids=["+20ms", "-35ms", "none"])
def test_the_time_offset_is_found_within_3_ms(shifted, shift_s):
    """The issue's bound is 3 ms; measured: -0.5 ms on the unshifted window (the data's own
    offset, or the 10 us rounding of its IMU stamps), and the shift plus that, +-0.4 ms from
    the bootstrap."""
    _, report = shifted(shift_s)
    assert report["status"] == 0, report
    offset = report["imu_time_offset_s"]
    uncertainty = report["imu_time_offset_uncertainty_s"]
    print(f"\nIMU shifted {1e3 * shift_s:+.1f} ms: estimated {1e3 * offset:+.2f} "
          f"+- {1e3 * uncertainty:.2f} ms")
    assert abs(offset - shift_s) < 0.003
    assert 0 < uncertainty < 0.003
    line = next(c for c in report["checks"] if c["name"] == "time offset")
    if shift_s == 0.0:
        assert line["verdict"] == "ok", line
    else:  # a shift of tens of ms is worth correcting: the line says the value to set
        assert line["verdict"] == "warning", line
        assert f"imu_time_offset_s = {offset:.4f}" in line["message"], line
    assert set(report) == {"status", "ok", "checks", "imu_time_offset_s",
                           "imu_time_offset_uncertainty_s"}
    assert {"name", "verdict", "message", "values"} == set(report["checks"][0])
    # The rest of the window is sound: every other check is ok.
    assert [c["name"] for c in report["checks"] if c["verdict"] != "ok"] in (
        [], ["time offset"])


def test_stereo_inertial_with_the_suggested_offset_reaches_5_mm(shifted):
    """IMU stamps 20 ms late: with the imu_time_offset_s check suggests, the stereo-inertial
    run aligns, tracks 400/400 and stays within the 5 mm the unshifted window reaches (4.25
    mm, as test_real_data_matrix.py's 4.3). The stereo trajectory does not show the offset
    (4.25 mm without the correction too, docs/usage.md); the next test shows its effect."""
    path, report = shifted(0.020)
    seq = open_sequence(path)
    result = run_sequence(seq, {"imu_time_offset_s": report["imu_time_offset_s"]},
                          sensor="stereo-inertial", progress=False)
    error = ate(result.groundtruth, result.trajectory, align="se3").rmse
    print(f"\nIMU 20 ms late, imu_time_offset_s as suggested: ATE {1e3 * error:.2f} mm")
    assert result.inertial["status"] == "aligned", result.inertial
    assert len(result.trajectory.timestamps) == len(seq)
    assert error <= 0.005


_SIGN_FRAMES = 120


def test_the_suggested_offset_has_the_sign_the_run_uses(shifted):
    """End to end, the sign: the gyro bias the alignment finds on the shifted data with the
    suggested offset is the unshifted window's; with the offset's sign reversed (40 ms off) it
    is not: the bias absorbs the mismatch. The first 120 frames (the first alignment).
    Measured: 3e-5 rad/s as suggested, 2.6e-3 reversed (full runs: 4.5e-5 suggested, 2.7e-3
    uncorrected, 5.4e-3 reversed); the bounds sit between, 17x and 2.6x away."""
    path, report = shifted(0.020)
    offset = report["imu_time_offset_s"]

    def gyro_bias(seq, offset_s: float) -> np.ndarray:
        result = run_sequence(seq, {"imu_time_offset_s": offset_s}, sensor="stereo-inertial",
                              max_frames=_SIGN_FRAMES, progress=False)
        assert result.inertial["status"] == "aligned", result.inertial
        return np.asarray(result.inertial["gyro_bias"])

    unshifted = gyro_bias(open_sequence(require_data(*MH_01)), 0.0)
    seq = open_sequence(path)
    distance = {label: float(np.linalg.norm(gyro_bias(seq, value) - unshifted))
                for label, value in (("suggested", offset), ("reversed", -offset))}
    print(f"\ngyro bias distance to the unshifted run's, rad/s: {distance}")
    assert distance["suggested"] < 5e-4
    assert distance["reversed"] > 1e-3


def test_a_window_that_hardly_rotates_gives_no_offset(euroc_micro, capsys):
    """V1_01 before take-off (0.2 deg net rotation, rotor vibration): the rates correlate (the
    vibration is seen by both) but the rotation is too small to trust the peak: a warning, and
    no estimate in the JSON. The rotor vibration also shows in the noise line."""
    status, out = _check([euroc_micro, "--json"], capsys)
    report = json.loads(out)
    assert status == 0 and report["imu_time_offset_s"] is None
    lines = {c["name"]: c for c in report["checks"]}
    assert lines["time offset"]["verdict"] == "warning"
    assert "hardly rotate" in lines["time offset"]["message"]
    assert lines["time offset"]["values"]["rotation_rate_rad_s"] < 0.05
    assert lines["imu noise"]["verdict"] == "warning"


def _edit_camera(mav0: Path, old: str, new: str) -> None:
    path = mav0 / "cam0" / "sensor.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


@pytest.mark.parametrize(("old", "new", "name", "message"), [
    ("367.215, 248.375", "900.0, 248.375", "principal point",
     "`cx` = 900: principal point must lie inside the image"),
    ("[-0.28340811, 0.07395907,", "[100.0, 0.07395907,", "distortion",
     "`k1` = 100: the distortion scales radii inside the image by more than a factor 3"),
    ("[-0.28340811, 0.07395907,", "[-1.0, 0.07395907,", "distortion",
     "the distortion folds the image over inside the image area"),
], ids=["principal point outside", "k1 100", "k1 folds"])
def test_each_bad_calibration_class_is_an_error_line(tmp_path, capsys, old, new, name,
                                                     message):
    path = _euroc_copy(tmp_path / "seq", edit=lambda mav0: _edit_camera(mav0, old, new))
    status, out = _check([path], capsys)
    assert status == 1
    lines = out.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error   {name}: "), out
    assert message in lines[0]
    # run refuses the same folder at once, in one line.
    assert main(["run", str(path), "--sensor", "stereo", "--out", str(tmp_path / "out"),
                 "--silent"]) == 1
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_image_size_against_the_calibration_and_run_fails_before_tracking(tmp_path, capsys):
    """A calibration of another resolution (cx, cy still inside): the image size line is an
    error, and run stops at it before tracking a frame (no output folder)."""
    path = _euroc_copy(tmp_path / "seq",
                       edit=lambda mav0: _edit_camera(mav0, "[752, 480]", "[640, 480]"))
    status, out = _check([path, "--sensor", "mono"], capsys)
    assert status == 1
    assert out.startswith("error   image size: ") and "is 752x480, sensor.yaml says 640x480" in out
    # A stereo rig of two sizes is refused as it is opened, on the same line.
    status, out = _check([path, "--sensor", "stereo"], capsys)
    assert status == 1
    assert out == "error   image size: stereo cameras differ in image size: 640x480 vs 752x480\n"
    assert main(["run", str(path), "--sensor", "mono", "--out", str(tmp_path / "out"),
                 "--silent"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ferroslam: error: image size: ") and "752x480" in err, err
    assert not (tmp_path / "out").exists()


def test_an_image_folder_with_its_camera_file(tmp_path, capsys):
    """The first 20 cam0 images (names in nanoseconds) with a flat camera file: ok at EuRoC's
    size, an image size error at another."""
    images = tmp_path / "images"
    images.mkdir()
    for frame in sorted((require_data(*MH_01) / "mav0" / "cam0" / "data").iterdir())[:20]:
        (images / frame.name).symlink_to(frame)
    camera = tmp_path / "camera.yaml"
    intrinsics = "fx: 458.654\nfy: 457.296\ncx: 367.215\ncy: 248.375\nk1: -0.28340811\n" \
                 "k2: 0.07395907\np1: 0.00019359\np2: 1.76187114e-05\n"
    camera.write_text(intrinsics + "width: 752\nheight: 480\n")
    status, out = _check([images, "--camera", camera], capsys)
    assert status == 0, out
    assert [line.split()[:2] for line in out.splitlines()] == [
        ["ok", "image"], ["ok", "distortion:"], ["ok", "frame"], ["ok", "frame"]]
    assert "20 frames at 20.00 Hz" in out
    camera.write_text(intrinsics + "width: 800\nheight: 600\n")
    status, out = _check([images, "--camera", camera], capsys)
    assert status == 1
    assert "error   image size: frame 0 is 752x480 (width x height) but the camera is " \
        "800x600" in out


def test_frame_times_out_of_order_or_repeated_are_errors(tmp_path, capsys):
    # Through a folder: the loaders refuse such lists, and check names the line.
    def swap(mav0: Path) -> None:
        path = mav0 / "cam0" / "data.csv"
        lines = path.read_text().splitlines()
        lines[5], lines[6] = lines[6], lines[5]
        path.write_text("\n".join(lines) + "\n")

    status, out = _check([_euroc_copy(tmp_path / "seq", edit=swap), "--sensor", "mono"],
                         capsys)
    assert status == 1 and out.startswith("error   frame times: ") and "out of order" in out
    images = tmp_path / "images"
    images.mkdir()
    frame = np.zeros((48, 64), np.uint8)
    for name in ("1.png", "1.0.png", "2.png"):
        cv2.imwrite(str(images / name), frame)
    status, out = _check([images], capsys)
    assert status == 1 and out.startswith("error   frame times: ") and "same time" in out
    # As a source that does not sort its frames (a bag) would give them.
    t = np.arange(10) * 0.05
    backwards = check_frame_times(t[[0, 1, 3, 2, 4, 5, 6, 7, 8, 9]])
    assert [(c.verdict, c.values) for c in backwards] == [("error", {"backwards": 1})]
    assert "frame 3 at 0.100000 s after 0.150000 s" in backwards[0].message
    repeated = check_frame_times(np.r_[t[:4], t[3:]])
    assert [(c.verdict, c.values) for c in repeated] == [("error", {"repeated": 1})]
    gap = check_frame_times(np.r_[t[:4], t[6:]])  # frames 4 and 5 dropped
    assert [c.verdict for c in gap] == ["ok", "warning"]
    assert "1 gap(s) of dropped frames (longest 0.150 s after frame 3)" in gap[1].message
    assert gap[1].values["rate_hz"] == pytest.approx(20.0)


def test_depth_scale_names_the_factor_that_makes_it_plausible():
    depth_mm = np.full((48, 64), 1800.0)  # a scene 1.8 m away, in millimetres
    assert check_depth_scale(depth_mm / 1000.0, 1000.0).verdict == "ok"
    as_metres = check_depth_scale(depth_mm, 1.0)  # millimetres read as metres: 1800 m
    assert as_metres.verdict == "error"
    assert "a scale of 1000 (millimetres: RealSense, Azure Kinect, ROS 16UC1) gives 1.80 m " \
        "(command line: --depth-scale 1000)" in as_metres.message
    assert as_metres.values["suggested_depth_factor"] == 1000.0
    assert check_depth_scale(np.zeros((4, 4)), 5000.0).verdict == "error"


def test_rgbd_folder_checks_its_depth(tum_rpy, capsys):
    status, out = _check([tum_rpy], capsys)
    assert status == 0, out
    depth = next(line for line in out.splitlines() if " depth scale: " in line)
    median = float(re.search(r"median depth ([\d.]+) m with depth factor 5000", depth)[1])
    assert depth.startswith("ok") and 0.5 < median < 3.0  # an office desk, hand-held


def test_a_gyro_in_degrees_is_an_error_line(tmp_path, capsys):
    def degrees(mav0: Path) -> None:
        path = mav0 / "imu0" / "data.csv"
        header, *rows = path.read_text().splitlines()
        out = []
        for row in rows:
            v = row.split(",")
            out.append(",".join([v[0]] + [repr(float(np.degrees(float(x)))) for x in v[1:4]] + v[4:]))
        path.write_text("\n".join([header] + out) + "\n")

    status, out = _check([_euroc_copy(tmp_path / "seq", edit=degrees), "--json"], capsys)
    report = json.loads(out)  # nothing but JSON on stdout
    assert status == 1 and not report["ok"] and report["imu_time_offset_s"] is None
    units = next(c for c in report["checks"] if c["name"] == "imu units")
    assert units["verdict"] == "error" and "deg/s" in units["message"], units
