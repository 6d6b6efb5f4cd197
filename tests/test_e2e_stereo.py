"""End to end: stereo SLAM on real KITTI and EuRoC frames, against their ground truth.

Settings are ORB-SLAM2's for these datasets (KITTI: 2000 features, ThDepth 35; EuRoC: 1200
features, ThDepth 35). Bounds were measured on this build with the commands in docs/benchmarks.md.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ferroslam import metrics
from ferroslam.cli import main as cli_main
from ferroslam.datasets import EurocSequence, KittiSequence
from ferroslam.pipeline import run_sequence

KITTI_CONFIG = {"n_features": 2000, "depth_threshold": 35.0}
EUROC_CONFIG = {"n_features": 1200, "depth_threshold": 35.0}

# KITTI 01, frames 0-50 (52 m motorway ramp with a 98 deg right turn). Measured: ATE 0.665 m
# over all frames, 0.713 m over keyframes (SE(3)); ORB-SLAM3 stereo on the same frames: 0.69 m.
# Nearly all of it is metric scale (see below): with Sim(3) alignment the ATE is 0.060 m, and a
# perfect trajectory scaled by 4.5 % alone scores 0.63 m SE(3). Bounds: ~12 % above measured.
KITTI_ATE_BOUND_M = 0.75
KITTI_SIM3_ATE_BOUND_M = 0.10
# The issue asks for a scale error under 2 %, which this fixture does not allow: frame-to-frame
# stereo odometry with no map at all (OpenCV PnP on stereo depths below 40 m, from our matcher
# or from OpenCV's SGBM) already measures the steps +3.9 % (median, frames 0-25) and +6.8 %
# (frames 25-50) longer than the ground truth. SLAM lands within that range (measured +4.8 %
# path length, Sim(3) scale 0.955); the bound keeps it there and fails a map whose scale
# drifts beyond the evidence (an earlier build that mapped far stereo depth: +6.7 %).
KITTI_SCALE_ERROR_BOUND = 0.055
# EuRoC V1_01 micro: the MAV stands still for 4.7 s (ground truth moves 2.2 mm). Measured ATE
# 0.7 mm; 3 mm is well below any real motion and above vicon2gt's own jitter (1.7 cm summed).
EUROC_ATE_BOUND_M = 0.003


@pytest.fixture(scope="module")
def kitti_run(kitti_stereo):
    seq = KittiSequence(kitti_stereo)
    return seq, run_sequence(seq, KITTI_CONFIG, sensor="stereo", progress=False)


def test_kitti_tracks_every_pair(kitti_run):
    seq, result = kitti_run
    assert len(seq) == 51
    assert result.states == ["ok"] * 51
    assert len(result.trajectory) == 51


def test_kitti_accuracy_and_scale(kitti_run):
    _, result = kitti_run
    assert result.ate_frames.pairs == 51
    assert result.ate_frames.rmse < KITTI_ATE_BOUND_M, f"ATE {result.ate_frames.rmse:.3f} m"
    assert result.ate_keyframes.rmse < KITTI_ATE_BOUND_M
    scale = result.path_length.scale_error
    assert abs(scale) < KITTI_SCALE_ERROR_BOUND, f"scale error {100 * scale:+.2f} %"
    gt = result.groundtruth
    shape = metrics.ate(gt, result.trajectory, align="sim3")
    assert shape.rmse < KITTI_SIM3_ATE_BOUND_M, f"Sim(3) ATE {shape.rmse:.3f} m"
    # Rotation is what stereo gets right: the 98 deg turn within 1 deg.
    rpe = result.rpe_frames
    assert rpe.rot_deg_rmse < 0.15, rpe.rot_deg_rmse


def test_kitti_map_is_metric(kitti_run):
    _, result = kitti_run
    points = result.map_points
    assert len(points) > 1500 and np.isfinite(points).all()
    # The road lies about 1.7 m below the camera (KITTI mounts it at 1.65 m): the lowest
    # tenth of the close points sits there in metric units.
    close = points[np.linalg.norm(points, axis=1) < 20]
    assert 1.2 < np.percentile(close[:, 1], 90) < 2.2


def test_kitti_deterministic(kitti_stereo, kitti_run):
    _, full = kitti_run
    runs = [run_sequence(KittiSequence(kitti_stereo), KITTI_CONFIG, sensor="stereo",
                         max_frames=20, progress=False) for _ in range(2)]
    np.testing.assert_array_equal(runs[0].trajectory.poses, runs[1].trajectory.poses)
    # The first 20 frames of the full run went through the same code on the same input.
    np.testing.assert_array_equal(runs[0].states, full.states[:20])


def test_euroc_static_start(euroc_micro):
    seq = EurocSequence(euroc_micro)
    result = run_sequence(seq, EUROC_CONFIG, sensor="stereo", progress=False)
    assert result.states == ["ok"] * 95
    assert result.ate_frames.pairs == 95
    assert result.ate_frames.rmse < EUROC_ATE_BOUND_M, result.ate_frames.rmse
    positions = result.trajectory.positions
    assert np.linalg.norm(positions[-1] - positions[0]) < 0.01
    assert result.keyframes.timestamps.size <= 10  # standing still needs few keyframes


def test_cli_stereo_run(kitti_stereo, tmp_path, capsys):
    out = tmp_path / "kitti"
    config = tmp_path / "kitti.json"
    config.write_text(json.dumps(KITTI_CONFIG))
    assert cli_main(["run", str(kitti_stereo), "--sensor", "stereo", "--config", str(config),
                     "--max-frames", "10", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "tracked frames  10/10" in printed and "scale error" in printed
    summary = json.loads((out / "results.json").read_text())
    assert summary["sensor"] == "stereo" and summary["tracked_frames"] == 10
    assert summary["metrics"]["path_length"]["pairs"] == 10
    assert np.loadtxt(out / "trajectory.txt").shape == (10, 8)


def test_stereo_needs_a_stereo_sequence(tmp_path):
    with pytest.raises(ValueError, match="has no depth images"):
        run_sequence(_MonoOnly(), {}, sensor="rgbd", progress=False)
    with pytest.raises(ValueError, match="is not a stereo sequence"):
        run_sequence(_MonoOnly(), {}, sensor="stereo", progress=False)


class _MonoOnly:
    name = "mono-only"
    is_stereo = False

    def __len__(self):
        return 1


def test_cli_stereo_inertial_run_on_euroc(euroc_micro, tmp_path, capsys):
    """``--sensor stereo-inertial``: the EuRoC IMU goes in with the frames and the alignment
    (static start, see tests/test_vslam.py) is in the summary and results.json."""
    out = tmp_path / "si"
    config = tmp_path / "si.json"
    config.write_text(json.dumps({**EUROC_CONFIG, "num_poses_threshold": 10}))
    assert cli_main(["run", str(euroc_micro), "--sensor", "stereo-inertial", "--config",
                     str(config), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "tracked frames  95/95" in printed and "IMU alignment   scale 1.0000" in printed
    summary = json.loads((out / "results.json").read_text())
    assert summary["sensor"] == "stereo-inertial"
    assert summary["inertial"]["status"] == "aligned"
    assert summary["metrics"]["ate_frames"]["align"] == "se3"
    assert summary["metrics"]["ate_frames"]["rmse"] < EUROC_ATE_BOUND_M
