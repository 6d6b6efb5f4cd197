"""A run's maps in its outputs ("Never lose a run"): ``trajectory.txt`` holds the largest
map's frames only, ``maps/map_<id>.txt`` each map's, ``results.json`` lists the maps.

The multi-map run is real: TUM fr1/rpy, monocular, the first 200 frames, 1000 features,
seed 2. Measured on this build (deterministic: the same figures twice): 142 frames "ok", 54
"lost", 4 not initialised; 179 frame poses in 2 maps of 132 and 47 frames (144 in 126 + 18
without the frames of tracking gaps posed afterwards, ``gap_frames`` 0). Map 0 was kept
in the atlas after a second lost, map 1 started, was lost in turn, and a later frame
relocalised in map 0, which is the current and largest map at the end (22 keyframes; map 1:
6). Before the atlas (maps dropped when lost): 111 poses in 3 maps of 20, 18 and 73. About
4 s on a shared core.
The one-map run (RGB-D, 10 frames of fr1/desk: 9 poses, 3 keyframes) writes what it always did.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ferroslam import cli
from ferroslam.datasets import TumSequence
from ferroslam.export import write_trajectory
from ferroslam.outputs import publish_run_outputs, write_run_outputs
from ferroslam.pipeline import RunResult, _map_outputs, run_sequence
from ferroslam.trajectory import Trajectory

MULTI_MAP_CONFIG = {"n_features": 1000, "seed": 2}
MULTI_MAP_FRAMES = 200


@pytest.fixture(scope="module")
def multi_map_run(tum_rpy):
    seq = TumSequence(tum_rpy, with_depth=False)
    return run_sequence(seq, MULTI_MAP_CONFIG, sensor="mono", max_frames=MULTI_MAP_FRAMES,
                        progress=False)


def _rows(path) -> np.ndarray:
    return np.loadtxt(path, ndmin=2)


def test_multi_map_run_outputs(multi_map_run, tmp_path, capsys):
    result = multi_map_run
    maps = result.maps
    assert len(maps) >= 2, result.summary()["states"]  # measured: 3
    largest = result.largest_map
    assert largest.frames == max(m.frames for m in maps)
    assert [m.id for m in maps] == sorted(set(result.map_ids.tolist()))
    out = tmp_path / "out"
    summary = publish_run_outputs(result, out)

    trajectory = _rows(out / "trajectory.txt")
    assert trajectory.shape == (largest.frames, 8)
    # Only the largest map's frames, in its frame: the same bytes as its own map file.
    own_file = out / f"maps/map_{largest.id}.txt"
    assert (out / "trajectory.txt").read_bytes() == own_file.read_bytes()
    np.testing.assert_array_equal(trajectory[:, 0], largest.trajectory.timestamps)
    others = result.trajectory.timestamps[result.map_ids != largest.id]
    assert not np.isin(trajectory[:, 0], others).any()
    assert sorted(p.name for p in (out / "maps").iterdir()) == [f"map_{m.id}.txt" for m in maps]
    for m in maps:
        rows = _rows(out / f"maps/map_{m.id}.txt")
        assert rows.shape == (m.frames, 8)

    saved = json.loads((out / "results.json").read_text())
    assert saved == summary
    assert saved["trajectory_map"] == largest.id
    assert saved["maps"] == [m.summary() for m in maps]
    poses = saved["trajectory_poses"]
    assert sum(m["frames"] for m in saved["maps"]) == poses == len(result.trajectory)
    # Every "ok" frame has a pose; the others are each map's initial reference frame and
    # the frames of tracking gaps posed afterwards (measured 142 "ok" of 179 poses).
    assert saved["tracked_frames"] < poses
    # The atlas keeps every map with its keyframes and points; the largest one is the map
    # the run's keyframes (results.json "keyframes") and points come from.
    assert all(m["keyframes"] > 0 and m["points"] > 0 for m in saved["maps"])
    (largest_saved,) = [m for m in saved["maps"] if m["id"] == largest.id]
    assert largest_saved["keyframes"] == saved["keyframes"] == len(result.keyframes)
    assert largest_saved["points"] == len(result.map_points)
    # ATE of a scale-free run: over the same poses trajectory.txt holds.
    assert result.ate_frames.pairs == largest.frames

    cli._print_summary(saved, out)
    printed = capsys.readouterr().out
    assert (f"maps            {len(maps)}; the trajectory holds map {largest.id} "
            f"({largest.frames} frames, the largest), maps/ each one") in printed


def test_one_map_run_writes_what_it_always_did(tum_desk, tmp_path, capsys):
    """An RGB-D run that never gets lost has one map: trajectory.txt is the whole trajectory
    (measured: 9 poses, the 10 frames but one) and maps/ holds one copy of it."""
    out = tmp_path / "out"
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--max-frames", "10",
                     "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    saved = json.loads((out / "results.json").read_text())
    assert saved["maps"] == [{"id": 0, "frames": saved["trajectory_poses"],
                              "keyframes": saved["keyframes"], "points": saved["map_points"]}]
    assert saved["trajectory_map"] == 0 and saved["num_maps"] == 1
    poses = saved["trajectory_poses"]
    assert f"maps            1: map 0 ({poses} frames), the trajectory" in printed
    assert sorted(p.name for p in (out / "maps").iterdir()) == ["map_0.txt"]
    assert (out / "maps/map_0.txt").read_bytes() == (out / "trajectory.txt").read_bytes()
    assert _rows(out / "trajectory.txt").shape == (saved["trajectory_poses"], 8)


# -- the same rules on a made-up result: formats, ties, stale folders, no map -------------
def _result(map_ids, keyframe_stamps=(), atlas=()) -> RunResult:
    """A result with one pose per entry of ``map_ids`` (1 cm apart), keyframes at
    ``keyframe_stamps`` and the core's map list ``atlas``."""
    n = len(map_ids)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * 0.01
    stamps = np.arange(n, dtype=np.float64)
    kf = np.flatnonzero(np.isin(stamps, keyframe_stamps))
    return RunResult(
        sequence="made-up", sensor="mono", config={}, timestamps=stamps, states=["ok"] * n,
        num_tracked=np.zeros(n, np.int64), timings={}, trajectory=Trajectory(stamps, poses),
        keyframes=Trajectory(stamps[kf], poses[kf]),
        keyframe_ids=np.arange(len(kf), dtype=np.uint32),
        map_points=np.zeros((0, 3)), map_point_colors=np.zeros((0, 3), np.uint8),
        map_ids=np.asarray(map_ids, dtype=np.int64), atlas=list(atlas))


@pytest.mark.parametrize("fmt, suffix, columns", [("kitti", ".txt", 12), ("euroc", ".csv", 8)])
def test_formats_tie_goes_to_the_older_map(tmp_path, fmt, suffix, columns):
    atlas = [{"id": 0, "frames": 2, "keyframes": 2, "points": 20, "current": False},
             {"id": 2, "frames": 1, "keyframes": 1, "points": 5, "current": True}]
    result = _result([0, 0, 1, 1, 2], keyframe_stamps=[4], atlas=atlas)
    summary = write_run_outputs(result, tmp_path, fmt)
    assert summary["trajectory_map"] == 0  # maps 0 and 1 tie at 2 frames
    # Map 1 is not in the core's list (dropped): its counts are unknown.
    assert summary["maps"] == [{"id": 0, "frames": 2, "keyframes": 2, "points": 20},
                               {"id": 1, "frames": 2, "keyframes": None, "points": None},
                               {"id": 2, "frames": 1, "keyframes": 1, "points": 5}]
    reference = tmp_path / "reference"
    write_trajectory(reference, result.trajectory.timestamps[:2], result.trajectory.poses[:2], fmt)
    assert (tmp_path / f"trajectory{suffix}").read_bytes() == reference.read_bytes()
    assert (tmp_path / f"maps/map_0{suffix}").read_bytes() == reference.read_bytes()
    rows = np.loadtxt(tmp_path / f"maps/map_1{suffix}", ndmin=2,
                      delimiter="," if fmt == "euroc" else None)
    assert rows.shape == (2, columns)


def test_maps_without_the_cores_list_have_no_counts(tmp_path):
    """A result made without the core's map list: frames per map, no keyframe counts."""
    summary = _result([0, 1, 1]).summary()
    assert [(m["frames"], m["keyframes"]) for m in summary["maps"]] == [(1, None), (2, None)]
    assert summary["trajectory_map"] == 1


def test_rerun_replaces_the_maps_folder_whole(tmp_path):
    """A one-map run into the --out of a three-map run leaves no stale map file."""
    publish_run_outputs(_result([0, 1, 1, 2]), tmp_path)
    assert len(list((tmp_path / "maps").iterdir())) == 3
    publish_run_outputs(_result([0, 0]), tmp_path)
    assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == ["map_0.txt"]


def test_nothing_tracked_writes_an_empty_maps_folder(tmp_path):
    summary = write_run_outputs(_result([]), tmp_path)
    assert summary["maps"] == [] and summary["trajectory_map"] is None
    assert list((tmp_path / "maps").iterdir()) == []
    assert (tmp_path / "trajectory.txt").read_text() == (tmp_path / "keyframes.txt").read_text()


class _EndsInAYoungMap:
    """The calls ``_map_outputs`` makes of a ``SlamSystem`` whose run ended in map 1, young
    (2 poses), after map 0 (3 poses) was lost: each map's keyframes and points differ."""

    def __init__(self):
        self.asked = []

    def frame_trajectory(self):
        return np.arange(5.0), np.tile(np.eye(4), (5, 1, 1))

    def frame_map_ids(self):
        return np.array([0, 0, 0, 1, 1])

    def _map(self, map_id):
        self.asked.append(map_id)
        return 1 if map_id is None else map_id  # the current map is 1

    def keyframe_trajectory(self, map_id=None):
        n = 4 - 2 * self._map(map_id)  # map 0: 4 keyframes, map 1: 2
        return np.arange(n, dtype=np.uint32), np.arange(float(n)), np.tile(np.eye(4), (n, 1, 1))

    def map_points(self, map_id=None):
        return np.full((30 - 20 * self._map(map_id), 3), 1.0)

    def map_point_colors(self, map_id=None):
        return np.full((30 - 20 * self._map(map_id), 3), 128, np.uint8)

    def sparse_model(self, map_id=None):
        ids, stamps, poses = self.keyframe_trajectory(map_id)
        points = self.map_points(map_id)
        return {"keyframe_ids": ids, "timestamps": stamps, "T_w_c": poses,
                "keypoint_offsets": np.zeros(len(ids) + 1, np.int64),
                "keypoints_px": np.zeros((0, 2)), "point_index": np.zeros(0, np.int64),
                "points_xyz": points, "point_colors": self.map_point_colors(map_id)}

    def maps(self):
        return [{"id": 0, "frames": 3, "keyframes": 4, "points": 30, "current": False},
                {"id": 1, "frames": 2, "keyframes": 2, "points": 10, "current": True}]

    def merges(self):
        return []

    def loops(self):
        return []

    def loop_stats(self):
        return {}


def test_keyframes_points_and_model_are_the_largest_maps_not_the_young_current_one():
    system = _EndsInAYoungMap()
    outputs = _map_outputs(system)
    # Map 0, which trajectory.txt holds, asked for by id, not the current map 1.
    assert set(system.asked) == {0}
    assert len(outputs["keyframes"]) == 4 and len(outputs["map_points"]) == 30
    assert len(outputs["map_point_colors"]) == 30
