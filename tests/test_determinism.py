"""Reproducible runs (issue 52, item 2): the same build, input and seed give bit-identical
trajectories and maps, inline every time, and with the mapping thread under
``deterministic=True`` equal to the inline run.

Every mode of the real-data matrix (tests/test_real_data_matrix.py) runs twice, each run in a
process of its own, and the sha256 of the final poses and of the map points must match: a
result that depends on the state of a process (hash-map seeds, allocation addresses) could
repeat within one. TUM RGB-D runs its whole 300-frame fixture, through the loop closed at
frame 67 whose correction once took point references from a hash map's order (see
docs/benchmarks.md); the other clips are long enough to insert keyframes with local BA,
culling and fusion.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import require_data

from ferroslam.datasets import open_sequence
from ferroslam.pipeline import run_sequence

TUM_RPY = ("tum", "rgbd_dataset_freiburg1_rpy")
KITTI_06 = ("kitti", "odometry_06_first51")
KITTI_01 = ("kitti", "stereo_51_frames")
V1_01 = ("euroc", "V1_01_easy_micro")
MH_01 = ("euroc", "MH_01_easy_window")

# (sequence, sensor, frames): one clip per case of tests/test_real_data_matrix.py.
MODES = {
    "tum_rgbd": (TUM_RPY, "rgbd", 300),
    "tum_mono": (TUM_RPY, "mono", 150),
    "kitti06_mono": (KITTI_06, "mono", 51),
    "kitti01_stereo": (KITTI_01, "stereo", 51),
    "kitti01_mono": (KITTI_01, "mono", 51),
    "v101_stereo": (V1_01, "stereo", 95),
    "v101_stereo_inertial": (V1_01, "stereo-inertial", 95),
    "mh01_stereo": (MH_01, "stereo", 120),
    "mh01_mono": (MH_01, "mono", 120),
    "mh01_stereo_inertial": (MH_01, "stereo-inertial", 120),
    "mh01_mono_inertial": (MH_01, "mono-inertial", 120),
}
# A clip where the monocular map starts late (KITTI 01 from frame ~17) tracks fewer frames.
MIN_TRACKED_SHARE = {"kitti01_mono": 0.25}


def run_hashes(name, config=None, max_frames=None):
    """sha256 of the trajectory (timestamps and poses) and of the map points, and the
    number of tracked frames (a run tracking nothing would trivially repeat itself), over
    the mode's clip or its first `max_frames` frames."""
    folder, sensor, frames = MODES[name]
    frames = max_frames or frames
    seq = open_sequence(require_data(*folder), sensor=sensor)
    result = run_sequence(seq, config=config, max_frames=frames, progress=False, sensor=sensor)
    trajectory = hashlib.sha256()
    trajectory.update(np.ascontiguousarray(result.trajectory.timestamps).tobytes())
    trajectory.update(np.ascontiguousarray(result.trajectory.poses).tobytes())
    points = hashlib.sha256(np.ascontiguousarray(result.map_points).tobytes())
    return [trajectory.hexdigest(), points.hexdigest(), result.tracked_frames]


def run_in_new_process(name):
    """:func:`run_hashes` of mode `name` in a fresh interpreter."""
    out = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), name],
        capture_output=True, text=True, check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", list(MODES))
def test_two_inline_runs_in_two_processes_are_bit_identical(name):
    require_data(*MODES[name][0])
    first = run_in_new_process(name)
    frames = MODES[name][2]
    assert first[2] >= MIN_TRACKED_SHARE.get(name, 0.5) * frames, (
        f"{name}: too few tracked frames ({first[2]}/{frames}) to compare"
    )
    assert run_in_new_process(name) == first


def test_repeated_and_deterministic_threaded_runs_equal_the_inline_one():
    # Past the loop at frame 67; a second run in the same process also catches state left
    # over from the first.
    inline = run_hashes("tum_rgbd", max_frames=120)
    assert run_hashes("tum_rgbd", max_frames=120) == inline
    threaded = run_hashes(
        "tum_rgbd", config={"mapping_thread": True, "deterministic": True}, max_frames=120
    )
    assert threaded == inline


if __name__ == "__main__":
    print(json.dumps(run_hashes(sys.argv[1])))
