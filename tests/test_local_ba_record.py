"""Local BA problems recorded from a real run (``SlamSystem.record_local_ba_problems``): the
problems ``benches/solvers_compare.py`` hands to gtsam and to ours, as local mapping built them
before solving."""

from __future__ import annotations

import pytest

from ferroslam import _core
from ferroslam.datasets import TumSequence
from ferroslam.pipeline import run_sequence


def _recorded_run(path, frames: int):
    systems = []

    def recording(*args, **kwargs):
        system = _core.SlamSystem(*args, **kwargs)
        system.record_local_ba_problems(True)
        systems.append(system)
        return system

    result = run_sequence(TumSequence(path), {}, max_frames=frames, progress=False,
                          system_factory=recording)
    return result, systems[0]


def _sections(text: str) -> dict:
    """Section name -> its data lines, after checking the header and the counts."""
    lines = text.splitlines()
    assert lines[0] == "ferroslam-ba 1"
    assert lines[1].split()[0] == "intrinsics"
    sections, i = {"intrinsics": [lines[1].split()[1:]]}, 2
    for name in ("poses", "points", "observations"):
        key, n = lines[i].split()
        assert key == name
        sections[name] = [line.split() for line in lines[i + 1:i + 1 + int(n)]]
        i += 1 + int(n)
    assert i == len(lines)
    return sections


def test_every_local_ba_of_an_rgbd_run_is_recorded_before_solving(tum_rpy):
    result, system = _recorded_run(tum_rpy, 60)
    problems = system.take_local_ba_problems()
    # Every keyframe after the first is mapped inline and runs one local BA. None was culled in
    # these 60 frames (measured 20 keyframes; 11 before RGB-D keyframes came below 250 points).
    ids = result.keyframe_ids
    assert len(ids) >= 10 and list(ids) == list(range(len(ids)))
    assert len(problems) == len(result.keyframe_ids) - 1
    assert system.take_local_ba_problems() == []
    for text in problems:
        s = _sections(text)
        assert s["intrinsics"] == [["517.3", "516.5", "318.6", "255.3", "40"]]
        fixed = [p[0] for p in s["poses"]]
        assert fixed[0] == "0" and "1" in fixed  # the new keyframe first, free; the origin fixed
        n_poses, n_points = len(s["poses"]), len(s["points"])
        for pose, point, *_ in s["observations"]:
            assert 0 <= int(pose) < n_poses and 0 <= int(point) < n_points
        stereo = sum(o[4] != "-" for o in s["observations"])
        assert stereo > 0.9 * len(s["observations"])  # RGB-D: most points have depth


def test_recording_needs_mapping_inline(tum_rpy):
    seq = TumSequence(tum_rpy)
    cam = seq.camera
    system = _core.SlamSystem(cam.fx, cam.fy, cam.cx, cam.cy, cam.dist, cam.width, cam.height,
                              sensor="rgbd")
    system.set_mapping_thread(True)
    with pytest.raises(ValueError, match="recorded with mapping inline only: stop the mapping"):
        system.record_local_ba_problems(True)
    system.set_mapping_thread(False)
    system.record_local_ba_problems(True)
    with pytest.raises(ValueError, match="recorded with mapping inline only: stop recording"):
        system.set_mapping_thread(True)
    system.record_local_ba_problems(False)
    system.set_mapping_thread(True)
    assert system.take_local_ba_problems() == []
