"""``ferroslam fleet`` on a real local Ray cluster (2 CPUs, 127.0.0.1): three overlapping
RGB-D sessions of TUM fr1/rpy (frames 0-79, 60-139, 120-199) mapped in parallel and merged
as a tree (two levels: the odd one waits), and 30 KITTI stereo frames kept apart (another
camera); plus the SPEC checks, without Ray."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import require_data
from test_batch import _require_ray

from ferroslam import batch, cli
from ferroslam.fleet import read_fleet_spec
from ferroslam.io import read_tum_trajectory


@pytest.mark.parametrize("spec, message", [
    ({"repeats": 2, "runs": [{"sequence": "s", "sensor": "rgbd"}]},
     r"the SPEC\.repeats is 2: a fleet maps each session once"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd", "repeats": 3}]}, r"runs\[0\]\.repeats is 3"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd"},
               {"sequence": "s", "sensor": "rgbd", "grid": {"n_features": [800, 1000]}}]},
     r"runs\[1\]\.grid: a fleet maps each session once"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd", "first_frame": -1}]},
     r"runs\[0\]\.first_frame must be a non-negative integer"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd"}, {"sequence": "s", "sensor": "lidar"}]},
     r"runs\[1\]\.sensor must be one of"),
    ({"runs": []}, r"'runs' must be a non-empty list"),
])
def test_spec_errors(tmp_path, spec, message):
    path = tmp_path / "fleet.json"
    path.write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=message):
        read_fleet_spec(path)


def test_spec_sessions_of_one_sequence_get_their_own_folders(tmp_path):
    path = tmp_path / "fleet.json"
    path.write_text(json.dumps({"max_frames": 80, "runs": [
        {"sequence": "seq", "sensor": "rgbd"},
        {"sequence": "seq", "sensor": "rgbd", "first_frame": 60}]}))
    runs = read_fleet_spec(path)
    assert [(r.first_frame, r.spec.max_frames) for r in runs] == [(0, 80), (60, 80)]
    assert [r.folder for r in runs] == ["00_seq_rgbd_from0", "01_seq_rgbd_from60"]
    assert runs[0].spec.path == tmp_path / "seq"


def test_error_line_for_a_repeated_spec(tmp_path, capsys):
    path = tmp_path / "fleet.json"
    path.write_text(json.dumps({"runs": [{"sequence": "s", "sensor": "rgbd", "repeats": 2}]}))
    assert cli.main(["fleet", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ferroslam: error: ") and err.count("\n") == 1


def test_fleet_merges_the_sessions_and_keeps_kitti_apart(tmp_path, capsys):
    """Measured on 2 cores: about 17 s in all (Ray's start ~6 s, mapping 10 s, merging
    0.6 s; serial 17 s, speedup 1.6x); 2 merges (level 0: session 1 into session 0, 684
    matches; level 1: session 2 into that, 683 matches); ATE in the merged frame 0.012,
    0.0095, 0.0054 m (SE(3) per session) and 0.014, 0.012 m for sessions 1 and 2 with
    session 0's alignment; KITTI stereo 0.36 m, KITTI mono 0.031 m (Sim(3)), each apart."""
    _require_ray()
    rpy = str(require_data("tum", "rgbd_dataset_freiburg1_rpy"))
    spec = {"max_frames": 80, "runs": [
        {"sequence": rpy, "sensor": "rgbd"},
        {"sequence": rpy, "sensor": "rgbd", "first_frame": 60},
        {"sequence": str(require_data("kitti", "stereo_51_frames")), "sensor": "stereo",
         "max_frames": 30},
        {"sequence": rpy, "sensor": "rgbd", "first_frame": 120},
        {"sequence": str(require_data("kitti", "odometry_06_first51")), "sensor": "mono",
         "max_frames": 40},
        {"sequence": "no_such_sequence", "sensor": "mono"},
    ]}
    (tmp_path / "fleet.json").write_text(json.dumps(spec))
    out = tmp_path / "out"
    assert cli.main(["fleet", str(tmp_path / "fleet.json"), "--out", str(out),
                     "--num-cpus", "2"]) == 1  # the missing sequence
    captured = capsys.readouterr()
    printed = captured.out
    assert "ferroslam: run 05_no_such_sequence_mono_from0 failed: FileNotFoundError" in captured.err
    summary = json.loads((out / "summary.json").read_text())
    runs = summary["runs"]
    assert [r["status"] for r in runs] == ["ok"] * 5 + ["failed"]
    assert "merged_file" not in runs[5] and not (out / runs[5]["run_dir"]).exists()
    mono, runs = runs[4], runs[:4]
    assert [r["frames"] for r in runs] == [80, 80, 30, 80]
    assert all(r["poses"] == r["frames"] for r in runs)
    # Monocular: its own group, ATE after Sim(3) alignment.
    assert mono["frames"] == 40 and mono["merged_file"] == "merged_2.map"
    assert mono["ate"]["align"] == "sim3"
    rgbd = [runs[0], runs[1], runs[3]]
    # The three sessions end in one map of merged.map; KITTI in its own file.
    assert {(r["merged_file"], r["merged_map"]) for r in rgbd} == {("merged.map", 1)}
    assert runs[2]["merged_file"] == "merged_1.map"
    assert [g["runs"] for g in summary["groups"]] == [
        [runs[0]["run_dir"], runs[1]["run_dir"], runs[3]["run_dir"]], [runs[2]["run_dir"]],
        [mono["run_dir"]]]
    assert [len(g["maps"]) for g in summary["groups"]][:2] == [1, 1]
    assert len(summary["groups"]) == 3 and summary["groups"][2]["sensor"] == "mono"
    merges = [(t["level"], t["group"], len(t["merges"])) for t in summary["merge_tasks"]]
    # Level 0: sessions 0 and 1 merge, KITTI's group is written alone; level 1: session 2.
    assert sorted(merges) == [(0, 0, 1), (0, 1, 0), (0, 2, 0), (1, 0, 1)]
    assert (out / "merged.map").is_file() and (out / "merged_1.map").is_file()
    for r in runs:
        assert r["ate"]["align"] == "se3"
        merged = read_tum_trajectory(out / r["run_dir"] / "trajectory_merged.txt")
        assert len(merged) == r["largest_map_poses"] == r["frames"]
    # Session 0 is the frame merged into; KITTI is not moved.
    for r in (runs[0], runs[2]):
        np.testing.assert_allclose(r["similarity"], np.eye(4), atol=1e-12)
    for r in rgbd:
        assert r["ate"]["rmse"] < 0.03, r["ate"]
    for r in (runs[1], runs[3]):
        shared = r["ate_first_session_alignment"]
        assert shared["aligned_with"] == runs[0]["run_dir"] and shared["pairs"] == 80
        assert shared["rmse"] < 0.05, shared
    assert runs[2]["ate"]["rmse"] < 1.0  # 30 KITTI frames, ~0.36 m measured
    t = summary["times"]
    assert t["serial_s"] > 0 and t["speedup"] > 0
    assert "speedup" in printed and "3 groups kept apart" in printed


# A Ray cluster of its own process: its head (GCS and raylet) on 127.0.0.1 with 2 CPUs, up
# until its stdin closes. Ray reads the loopback switch at import, hence a process of its own.
_CLUSTER = """
import sys
from ray.cluster_utils import Cluster
cluster = Cluster(initialize_head=True, head_node_args={
    "num_cpus": 2, "node_ip_address": "127.0.0.1", "include_dashboard": False})
print(cluster.address, flush=True)
sys.stdin.read()
cluster.shutdown()
"""


def test_fleet_on_a_running_cluster_reached_by_address(tmp_path):
    """``--address``: a cluster started beforehand takes the tasks of two overlapping RGB-D
    sessions (frames 0-59 and 40-99), which merge into one map; the cluster outlives the
    fleet, which only disconnects from it. Measured: 322 matches at the merge, about 10 s
    with the cluster's start."""
    _require_ray()
    import ray

    rpy = str(require_data("tum", "rgbd_dataset_freiburg1_rpy"))
    spec = {"max_frames": 60, "runs": [{"sequence": rpy, "sensor": "rgbd"},
                                       {"sequence": rpy, "sensor": "rgbd", "first_frame": 40}]}
    (tmp_path / "fleet.json").write_text(json.dumps(spec))
    env = {**os.environ, batch._RAY_LOOPBACK_ENV: "0"}
    with subprocess.Popen([sys.executable, "-c", _CLUSTER], stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, text=True, env=env) as head:
        try:
            address = head.stdout.readline().strip()
            assert address.startswith("127.0.0.1:"), address
            assert cli.main(["fleet", str(tmp_path / "fleet.json"), "--out",
                             str(tmp_path / "out"), "--address", address]) == 0
            summary = json.loads((tmp_path / "out" / "summary.json").read_text())
            assert [len(t["merges"]) for t in summary["merge_tasks"]] == [1]
            runs = summary["runs"]
            assert {(r["merged_file"], r["merged_map"]) for r in runs} == {("merged.map", 1)}
            assert [r["largest_map_poses"] for r in runs] == [60, 60]
            # Measured 1.31 and 1.15 cm in the merged frame (SE(3) per session).
            assert all(r["ate"]["rmse"] < 0.03 for r in runs), [r["ate"] for r in runs]
            ray.init(address=address, log_to_driver=False)
            try:
                assert ray.cluster_resources()["CPU"] == 2
            finally:
                ray.shutdown()
        finally:
            head.stdin.close()
            head.wait(timeout=120)
