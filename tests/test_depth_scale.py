"""Any dataset folder with your camera and depth scale: ``--camera`` and ``--depth-scale`` for
dataset folders, the depth factor of calibration files, and the plausibility check that names
the scale a wrong one should have been."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import require_data
from ferroslam import cli
from ferroslam.calibration import load_calibration
from ferroslam.datasets import TumSequence
from ferroslam.datasets.tum import TUM_CAMERAS
from ferroslam.depth_scale import check_depth_scale
from ferroslam.io import read_tum_trajectory
from ferroslam.pipeline import run_sequence

# fr1/rpy frames of the runs: 3.3 s of its rotation, enough for an ATE that is not noise.
FRAMES = 100
FR1 = TUM_CAMERAS[1]
FLAT_FR1 = (f"fx: {FR1.fx!r}\nfy: {FR1.fy!r}\ncx: {FR1.cx!r}\ncy: {FR1.cy!r}\n"
            + "".join(f"{k}: {float(v)!r}\n" for k, v in zip(("k1", "k2", "p1", "p2", "k3"),
                                                                FR1.dist))
            + f"rolling_shutter_readout_s: {FR1.rolling_shutter_readout_s!r}\n")


@pytest.mark.parametrize("text, factor", [
    ('%YAML:1.0\nFile.version: "1.0"\nCamera.type: "PinHole"\nCamera1.fx: 517.3\n'
     "Camera1.fy: 516.5\nCamera1.cx: 318.6\nCamera1.cy: 255.3\nCamera.width: 640\n"
     "Camera.height: 480\nRGBD.DepthMapFactor: 1000.0\n", 1000.0),
    ("%YAML:1.0\nCamera.fx: 517.3\nCamera.fy: 516.5\nCamera.cx: 318.6\nCamera.cy: 255.3\n"
     "DepthMapFactor: 5000.0\n", 5000.0),
    (FLAT_FR1 + "depth_scale: 1000\n", 1000.0),
    (FLAT_FR1, None),
])
def test_calibration_files_give_the_depth_factor(tmp_path, text, factor):
    path = tmp_path / "settings.yaml"
    path.write_text(text)
    assert load_calibration(path).depth_factor == factor


def test_a_non_positive_depth_factor_names_the_key(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_text(FLAT_FR1 + "depth_scale: 0\n")
    with pytest.raises(ValueError, match=f"{path}: depth_scale must be a positive"):
        load_calibration(path)


@pytest.mark.parametrize("median_raw, factor, named", [
    (1500.0, 1.0, "--depth-scale 1000"),  # millimetres read as metres
    (7000.0, 1e6, "--depth-scale 5000"),  # TUM's values with a scale a thousand times off
])
def test_implausible_scales_name_the_plausible_one(median_raw, factor, named):
    depth_m = np.full((4, 4), median_raw / factor, dtype=np.float32)
    prefix = f"frame 0: a depth scale of {factor:g} pixel values per metre puts the median"
    with pytest.raises(ValueError, match=re.escape(prefix) + ".*" + re.escape(named)):
        check_depth_scale(depth_m, factor, "frame 0")
    assert check_depth_scale(np.zeros((4, 4)), factor, "frame 0") is None  # nothing to judge


def millimetre_folder(tum_rpy: Path, folder: Path) -> Path:
    """fr1/rpy's first frames in the TUM layout under a name that names no freiburg camera,
    with depth in millimetres (TUM's 5000 per metre divided by 5, rounded), as a RealSense
    records it."""
    folder.mkdir()
    (folder / "rgb").symlink_to(tum_rpy / "rgb")
    (folder / "depth").mkdir()
    (folder / "rgb.txt").write_text((tum_rpy / "rgb.txt").read_text())
    (folder / "groundtruth.txt").write_text((tum_rpy / "groundtruth.txt").read_text())
    lines = [line for line in (tum_rpy / "depth.txt").read_text().splitlines()
             if line and not line.startswith("#")][:FRAMES + 5]
    for line in lines:
        name = line.split()[1]
        raw = cv2.imread(str(tum_rpy / name), cv2.IMREAD_UNCHANGED).astype(np.float64)
        cv2.imwrite(str(folder / name), np.round(raw / 5.0).astype(np.uint16))
    (folder / "depth.txt").write_text("\n".join(lines) + "\n")
    return folder


def _ate_rmse(out: Path) -> float:
    return json.loads((out / "results.json").read_text())["metrics"]["ate_frames"]["rmse"]



def test_a_millimetre_folder_with_camera_and_depth_scale(tum_rpy, tmp_path, capsys):
    """``--camera`` + ``--depth-scale 1000`` on a RealSense-like folder: the run of the loader
    told so, and an ATE near the TUM original's.

    Bound, measured with the same camera settings (fr1's 15 ms rolling-shutter readout in
    both): original 1.21 cm, millimetres 1.18 cm over these 100 frames (-2 %; 300 frames:
    1.13 and 1.12 cm). Before the readout was modelled the rounding of depth to 1 mm cost
    +22 to +29 %; the issue's bound, 10 %, holds with a margin of 8 points. The scale
    itself is checked apart: read at TUM's 5000, the same folder's map is 5x smaller."""
    folder = millimetre_folder(tum_rpy, tmp_path / "my_realsense_room")
    camera = tmp_path / "camera.yaml"
    camera.write_text(FLAT_FR1)
    common = ["--sensor", "rgbd", "--max-frames", str(FRAMES)]
    mm = [str(folder), *common, "--camera", str(camera), "--depth-scale", "1000"]
    assert cli.main(["run", str(tum_rpy), *common, "--out", str(tmp_path / "tum"),
                     "--silent"]) == 0
    assert cli.main(["run", *mm, "--out", str(tmp_path / "mm")]) == 0
    printed = capsys.readouterr().out
    assert f"note: calibration from {camera}, not the tum layout's own" in printed
    assert "note: depth scale 1000 pixel values per metre" in printed
    original, millimetres = _ate_rmse(tmp_path / "tum"), _ate_rmse(tmp_path / "mm")
    assert original < 0.025  # a tracked run, not a lost one
    assert abs(millimetres - original) <= 0.1 * original, (millimetres, original)

    # Without the vocabulary runs repeat bit for bit (with it, RGB-D ones do not yet): the
    # command line's run is the loader's, to the digits of the TUM file.
    config = tmp_path / "inline.json"
    config.write_text('{"vocabulary": null}')
    assert cli.main(["run", *mm, "--config", str(config), "--out", str(tmp_path / "told"),
                     "--silent"]) == 0
    told = run_sequence(TumSequence(folder, camera=FR1, depth_factor=1000.0),
                        {"vocabulary": None}, max_frames=FRAMES, progress=False, sensor="rgbd")
    written = read_tum_trajectory(tmp_path / "told" / "trajectory.txt")
    np.testing.assert_allclose(written.poses, told.trajectory.poses, rtol=0, atol=1e-6)
    wrong = run_sequence(TumSequence(folder, camera=FR1, depth_factor=5000.0),
                         {"vocabulary": None}, max_frames=FRAMES, progress=False,
                         sensor="rgbd")
    # The map's size says the scale (scale_error does not here: rpy barely translates, so a
    # Sim(3) scale of a few centimetres of path is noise): 1000 / 5000 = 0.2.
    ratio = (np.median(np.linalg.norm(wrong.map_points, axis=1))
             / np.median(np.linalg.norm(told.map_points, axis=1)))
    assert ratio == pytest.approx(0.2, abs=0.02), ratio


def test_a_wrong_depth_scale_names_the_right_one(tum_rpy, tmp_path, capsys):
    folder = millimetre_folder(tum_rpy, tmp_path / "my_realsense_room")
    camera = tmp_path / "camera.yaml"
    camera.write_text(FLAT_FR1)
    assert cli.main(["run", str(folder), "--sensor", "rgbd", "--camera", str(camera),
                     "--depth-scale", "1", "--out", str(tmp_path / "out"), "--silent"]) == 1
    err = capsys.readouterr().err
    assert "a depth scale of 1 pixel values per metre puts the median depth at" in err, err
    assert "(command line: --depth-scale 1000)" in err, err
    # Without --camera the folder's name says nothing of its camera.
    assert cli.main(["run", str(folder), "--sensor", "rgbd", "--silent"]) == 1
    assert "names no freiburg camera" in capsys.readouterr().err


def test_camera_yaml_in_the_folder_carries_the_depth_scale(tum_rpy, tmp_path):
    folder = millimetre_folder(tum_rpy, tmp_path / "my_realsense_room")
    (folder / "camera.yaml").write_text(FLAT_FR1 + "depth_scale: 1000\n")
    seq = TumSequence(folder)
    assert seq.depth_factor == 1000.0
    raw = cv2.imread(str(seq.frames[0].depth_path), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(seq.load_depth(0), raw.astype(np.float32) / np.float32(1000))
    assert TumSequence(folder, depth_factor=500.0).depth_factor == 500.0  # given wins


def test_depth_scale_is_refused_where_there_is_no_depth(tmp_path, capsys):
    euroc = require_data("euroc", "MH_01_easy_window")
    assert cli.main(["run", str(euroc), "--sensor", "stereo", "--depth-scale", "1000",
                     "--silent"]) == 1
    assert "a depth scale is for RGB-D folders (TUM layout), not euroc" in \
        capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", str(euroc), "--sensor", "stereo", "--depth-scale", "0"])
    assert exit_.value.code == 2
    assert "option 'depth_scale' = 0.0: must be > 0" in capsys.readouterr().err



def test_camera_is_refused_for_kitti(kitti_stereo, tmp_path, capsys):
    camera = tmp_path / "camera.yaml"
    camera.write_text(FLAT_FR1)
    assert cli.main(["run", str(kitti_stereo), "--sensor", "stereo", "--camera", str(camera),
                     "--silent"]) == 1
    assert "calib.txt holds the rectified cameras its images are in" in capsys.readouterr().err
