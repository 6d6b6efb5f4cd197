"""Poses for the frames of a tracking gap ("Never lose a run"): frames that end without a pose
(lost, before a map starts, or in a young map that was dropped) are tracked backwards once
a later frame is tracked (``gap_frames``, default 30). Real frames of TUM fr1/rpy,
monocular, default options, mapping inline (deterministic).

Measured on this build: the 300 frames end with 280 frames tracked live (17 lost, 3
initialising) and, as before the gaps were filled, 281 poses; filled, 296 poses in the one
map, Sim(3) ATE 3.02 cm over them (2.86 cm over the 281: the frames filled in are the
blurred ones of the fast turns, where the map was lost). The first 150 frames as an MJPG
video with an ORB-SLAM settings file of the fr1 camera: 113 poses before, 144 now (the
first map, lost young, is dropped; its frames and those before it are posed again from the
next map)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from ferroslam import cli
from ferroslam.datasets import TumSequence
from ferroslam.pipeline import run_sequence

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from atlas_stress import write_video  # noqa: E402

pytest.importorskip("ferroslam._core")


@pytest.fixture(scope="module")
def runs(tum_rpy):
    seq = TumSequence(tum_rpy, with_depth=False)
    return {gap: run_sequence(seq, {"gap_frames": gap}, sensor="mono", progress=False)
            for gap in (0, 30)}


def test_gaps_fill_in_behind_tracking_and_change_nothing_else(runs):
    unfilled, filled = runs[0], runs[30]
    print(f"fr1/rpy mono: {len(unfilled.trajectory)} poses unfilled, "
          f"{len(filled.trajectory)} filled (maps {[(m.id, m.frames) for m in filled.maps]}), "
          f"ATE {unfilled.ate_frames.rmse * 100:.2f} -> {filled.ate_frames.rmse * 100:.2f} cm")
    # Live results and the map are those of the run without filling, bit for bit.
    assert filled.states == unfilled.states
    assert filled.states.count("ok") == 280
    np.testing.assert_array_equal(filled.map_points, unfilled.map_points)
    np.testing.assert_array_equal(filled.keyframes.poses, unfilled.keyframes.poses)
    # Every pose of the unfilled run is there, unchanged; the others are the gaps'.
    common = np.isin(filled.trajectory.timestamps, unfilled.trajectory.timestamps)
    np.testing.assert_array_equal(filled.trajectory.timestamps[common],
                                  unfilled.trajectory.timestamps)
    np.testing.assert_array_equal(filled.trajectory.poses[common], unfilled.trajectory.poses)
    assert len(unfilled.trajectory) == 281
    # The bar: >= 290 frames with a pose in some map (measured 296, one map).
    assert len(filled.maps) == 1 and filled.largest_map.frames == len(filled.trajectory) >= 290
    # Measured 3.02 cm: a frame posed wrongly by the backward tracking (off by the scene's
    # depth) would put it above 5 cm alone; the bound leaves the fill ~0.5 cm of spread.
    assert filled.ate_frames.pairs == len(filled.trajectory)
    assert filled.ate_frames.rmse <= 0.035


def test_a_video_keeps_its_first_frames(tum_rpy, tmp_path):
    """The issue's video case: >= 140 of the 150 frames with a pose (measured 144)."""
    video, settings = write_video(tum_rpy, tmp_path)
    out = tmp_path / "out"
    assert cli.main(["run", str(video), "--sensor", "mono", "--camera", str(settings),
                     "--out", str(out), "--silent"]) == 0
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    print(f"MJPG video: {results['trajectory_poses']} poses, maps "
          f"{[(m['id'], m['frames']) for m in results['maps']]}")
    assert results["frames"] == 150
    assert results["num_maps"] == 1 and results["maps"][0]["frames"] >= 140
