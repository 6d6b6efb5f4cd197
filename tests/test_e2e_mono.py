"""End to end: monocular SLAM on real KITTI, TUM and EuRoC frames.

Monocular scale is arbitrary, so trajectories are compared after a Sim(3) alignment (over the
longest map segment). Bounds were measured on this build (the commands in docs/benchmarks.md) with seed 0, the
test's, and checked against seeds 1 and 2 (their figures are noted next to each bound).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ferroslam.cli import main as cli_main
from ferroslam.datasets import TUM_CAMERAS, EurocSequence, KittiSequence, TumSequence
from ferroslam.pipeline import run_sequence

KITTI_CONFIG = {"n_features": 2000}  # ORB-SLAM's KITTI monocular setting
# 640x480 TUM: 1500 features. With ORB-SLAM's 1000 the map thins out under fr1/rpy's fast
# rotation: 73.9 % of the frames after initialisation tracked (ATE 3.1 cm) against 98.3 %.
TUM_CONFIG = {"n_features": 1500}

# KITTI 06, frames 0-50: a 60 m straight street at 41 km/h. Measured: initialised at frame 1,
# every later frame tracked, Sim(3) ATE 4.40 cm (seeds 1: 4.65 cm). ORB-SLAM3 monocular: at
# 10 Hz it tracks only 8 of 51 frames; fed 4x slower, 50/51 at 4.6 cm.
KITTI_ATE_BOUND_M = 0.06
# TUM fr1/rpy, 300 frames, colour only. Measured at 6f648fc (seeds 0/1/2): 89.3 / 83.3 / 74.6 %
# of the frames after initialisation tracked, Sim(3) ATE 2.62 / 3.15 / 2.30 cm; seed 2 tracks
# less than the bound. Before 6f648fc: seed 0 79.9-81.6 %, 3.02-3.47 cm (two processes), seeds
# 1/2 76.5 / 56.9 %, 2.48 / 3.59 cm. ORB-SLAM3 monocular: 191/300 tracked (64 %), lost 4 times,
# ATE 3.5 cm. The issue aims at >= 80 % and 1-3 cm.
TUM_TRACKED_BOUND = 0.8
TUM_ATE_BOUND_M = 0.06


@pytest.fixture(scope="module")
def kitti_run(kitti_mono):
    seq = KittiSequence(kitti_mono)
    return seq, run_sequence(seq, KITTI_CONFIG, sensor="mono", progress=False)


def test_kitti_initialises_early_and_tracks_every_later_frame(kitti_run):
    seq, result = kitti_run
    first = result.first_initialised_frame
    assert first is not None and first <= 10, result.init_reasons[:12]
    assert result.states[first:] == ["ok"] * (len(seq) - first)
    assert result.num_maps == 1
    # The reference frame of the two-view pair is in the trajectory too.
    assert len(result.trajectory) >= len(seq) - first


def test_kitti_sim3_ate(kitti_run):
    _, result = kitti_run
    ate = result.ate_frames
    assert ate.pairs >= 45
    assert ate.rmse < KITTI_ATE_BOUND_M, f"Sim(3) ATE {ate.rmse:.4f} m"
    assert result.ate_keyframes.rmse < KITTI_ATE_BOUND_M
    # Median scene depth 1 at initialisation: the car drives ~1.1 m per frame, so the map
    # unit is some tens of metres, and the alignment scale says so.
    assert 5.0 < ate.scale < 100.0


def test_kitti_deterministic(kitti_mono, kitti_run):
    _, full = kitti_run
    runs = [run_sequence(KittiSequence(kitti_mono), KITTI_CONFIG, sensor="mono", max_frames=15,
                         progress=False) for _ in range(2)]
    np.testing.assert_array_equal(runs[0].trajectory.poses, runs[1].trajectory.poses)
    assert runs[0].states == full.states[:15]


def test_tum_rpy_rotation_heavy(tum_rpy):
    seq = TumSequence(tum_rpy, with_depth=False)
    result = run_sequence(seq, TUM_CONFIG, sensor="mono", progress=False)
    assert result.first_initialised_frame is not None
    assert result.tracked_after_init >= TUM_TRACKED_BOUND, result.summary()["states"]
    ate = result.ate_frames
    assert ate.pairs >= 100
    assert ate.rmse < TUM_ATE_BOUND_M, f"Sim(3) ATE {ate.rmse:.4f} m"
    summary = result.summary()
    assert summary["num_maps"] == result.num_maps >= 1
    assert summary["metrics"]["ate_frames"]["align"] == "sim3"


def test_euroc_static_never_initialises(euroc_micro):
    """The MAV stands still: every pair is degenerate, so the map must not start."""
    seq = EurocSequence(euroc_micro, stereo=False)
    result = run_sequence(seq, {}, sensor="mono", progress=False)
    assert result.states == ["not_initialized"] * 95
    assert result.first_initialised_frame is None and len(result.trajectory) == 0
    refusals = [r for r in result.init_reasons if r and "refused" in r]
    assert len(refusals) > 80, result.init_reasons[:5]
    assert result.ate_frames is None and result.metric_errors


class _BlankSequence:
    """Ten black frames: nothing to detect, nothing to initialise from."""

    name = "blank"
    camera = TUM_CAMERAS[1]
    timestamps = np.arange(10) * 0.1
    has_groundtruth = False

    def __len__(self):
        return 10

    def load_gray(self, i):
        return np.zeros((480, 640), np.uint8)


def test_blank_images_end_not_initialised():
    result = run_sequence(_BlankSequence(), {}, sensor="mono", progress=False)
    assert result.states == ["not_initialized"] * 10
    assert all("waiting for a reference frame" in r for r in result.init_reasons)


def test_cli_mono_run(kitti_mono, tmp_path, capsys):
    out = tmp_path / "mono"
    config = tmp_path / "kitti.json"
    config.write_text(json.dumps(KITTI_CONFIG))
    assert cli_main(["run", str(kitti_mono), "--sensor", "mono", "--config", str(config),
                     "--max-frames", "12", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "initialised at  frame 1" in printed and "Sim(3), largest map" in printed
    summary = json.loads((out / "results.json").read_text())
    assert summary["sensor"] == "mono" and summary["num_maps"] == 1
