"""The head-to-head bench (``benches/compare.py``): its summary of run pairs, the ORB-SLAM3
trajectory it reads and the extractor options it gives both systems."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benches"))

import compare  # noqa: E402


def test_per_pair_takes_the_median_ratio_and_counts_wins_pair_by_pair():
    # [count, ours, theirs]: pair by pair ours is lower in two of three (ratios 0.5, 0.8,
    # 1.5), though the median of ours (0.8) is above the median of theirs (0.6).
    pairs = [[4, 0.3, 0.6], [7, 0.8, 1.0], [4, 0.9, 0.6]]
    assert compare._per_pair(pairs) == "per pair: ratio median 0.80, ours lower in 2 of 3"


def test_per_pair_leaves_out_pairs_that_failed():
    pairs = [[4, None, 0.6], [0, math.nan, math.nan], [4, 0.2, 0.0], [4, 0.3, 0.2]]
    assert compare._per_pair(pairs) == "per pair: ratio median 1.50, ours lower in 0 of 1"
    assert compare._per_pair([[0, None, None]]) == "no valid pair"


def test_orbslam3_trajectory_keeps_one_pose_per_frame(tmp_path):
    # ORB-SLAM3 writes each lost frame as a copy of the last tracked one (same nanosecond
    # stamp and pose): the copies are dropped, so an ATE weighs each tracked frame once.
    import _orbslam3

    rows = ["2000000000 1 0 0 0 0 0 1", "1000000000 0 0 0 0 0 0 1",
            "2000000000 1 0 0 0 0 0 1", "2000000000 1 0 0 0 0 0 1",
            "3000000000 2 0 0 0 0 0.7071067811865476 0.7071067811865476"]
    path = tmp_path / "traj.txt"
    path.write_text("\n".join(rows) + "\n")
    traj = _orbslam3.read_euroc_trajectory(path)
    assert traj.timestamps.tolist() == [1.0, 2.0, 3.0]
    assert [p[0, 3] for p in traj.poses] == [0.0, 1.0, 2.0]
    # A quarter turn about z: the rotation maps x to y.
    assert abs(traj.poses[2][1, 0] - 1.0) < 1e-12


def test_extractor_options_reach_both_systems(tmp_path, tum_desk):
    import _orbslam3
    from ferroslam.datasets import open_sequence

    seq = open_sequence(tum_desk)
    extractor = {"n_features": 1100, "ini_fast": 19}
    config = _orbslam3.ferroslam_config(seq, "rgbd", extractor)
    assert (config["n_features"], config["ini_fast"], config["min_fast"]) == (1100, 19, 7)
    settings = _orbslam3.write_settings(seq, "rgbd", tmp_path, extractor).read_text()
    assert "ORBextractor.nFeatures: 1100\n" in settings
    assert "ORBextractor.iniThFAST: 19\n" in settings
    assert "ORBextractor.minThFAST: 7\n" in settings
    with pytest.raises(ValueError, match="unknown extractor options \\['nfeatures'\\]"):
        _orbslam3.ferroslam_config(seq, "rgbd", {"nfeatures": 1100})


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="SCHED_IDLE is Linux's")
def test_cpus_kept_busy_runs_one_idle_priority_spinner_per_cpu_and_stops_them():
    import _orbslam3

    with _orbslam3.cpus_kept_busy() as spinners:
        assert len(spinners) == os.cpu_count()
        for spinner in spinners:
            assert spinner.poll() is None
            assert os.sched_getscheduler(spinner.pid) == os.SCHED_IDLE
    assert all(spinner.poll() is not None for spinner in spinners)
    with _orbslam3.cpus_kept_busy(False) as none:
        assert none == []


def test_ate_alignment_fits_a_scale_only_to_scale_free_trajectories():
    assert compare.ate_alignment("mono", False) == "sim3"
    assert compare.ate_alignment("mono-inertial", False) == "sim3"
    assert compare.ate_alignment("mono-inertial", True) == "se3"
    assert compare.ate_alignment("stereo-inertial", False) == "se3"
    assert compare.ate_alignment("stereo", False) == "se3"


def test_imu_bounds_give_each_frame_the_samples_since_the_previous_one():
    # Frame i gets the samples in (frame i - 1, frame i]; the first frame all up to it.
    import _orbslam3
    import numpy as np

    imu_t = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5])
    bounds = _orbslam3.imu_bounds(imu_t, np.array([1.0, 2.0, 2.2]))
    windows = [imu_t[a:b].tolist() for a, b in zip(bounds[:-1], bounds[1:])]
    assert windows == [[0.0, 0.5, 1.0], [1.5, 2.0], []]
