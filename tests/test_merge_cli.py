"""``ferroslam merge``: two real RGB-D sessions of TUM fr1/rpy that overlap (frames 0-79 and
60-139) merge into one map whose frame holds both trajectories; two EuRoC places (V1_01 and
MH_01, same camera) stay apart; bad input is one error line."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_data

from ferroslam import cli
from ferroslam.datasets import open_sequence
from ferroslam.export import write_trajectory
from ferroslam.io import read_tum_trajectory
from ferroslam.metrics import ate
from ferroslam.pipeline import run_sequence
from ferroslam.fleet import apply_similarity, merge_chain


def _rotation_error_deg(result) -> float:
    """Median angle between the aligned estimate's and the reference's rotations."""
    R = np.einsum("nji,njk->nik", result.reference.rotations, result.aligned.rotations)
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return float(np.degrees(np.median(np.arccos(cos))))


def _session(path, sensor, out, name, first_frame, max_frames):
    """Map one session, save its atlas and the largest map's trajectory; return the result
    and the two files."""
    seq = open_sequence(path, sensor=sensor)
    map_file = out / f"{name}.map"
    result = run_sequence(seq, {}, sensor=sensor, max_frames=max_frames, first_frame=first_frame,
                          progress=False, save_map=map_file)
    traj = result.largest_map_trajectory
    traj_file = write_trajectory(out / f"{name}.txt", traj.timestamps, traj.poses, "tum")
    return result, map_file, traj_file


@pytest.fixture(scope="module")
def rpy_sessions(tum_rpy, tmp_path_factory):
    """Frames 0-79 and 60-139 of fr1/rpy, RGB-D (about 2 s each on two cores)."""
    out = tmp_path_factory.mktemp("rpy_sessions")
    return [_session(tum_rpy, "rgbd", out, name, first, 80)
            for name, first in (("session1", 0), ("session2", 60))]


def test_two_overlapping_sessions_merge_into_one_frame(rpy_sessions, tmp_path, capsys):
    (r1, map1, traj1), (r2, map2, traj2) = rpy_sessions
    assert [len(r.atlas) for r in (r1, r2)] == [1, 1]  # one map per session
    merged = tmp_path / "merged.map"
    argv = ["merge", str(map1), str(map2), "-o", str(merged), "--trajectory", str(traj1),
            str(traj2), "--out-trajectories", str(tmp_path / "traj")]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out.splitlines()
    # The merge file renumbers the maps: input 0's gets id 1, input 1's id 2.
    assert printed[0].startswith(f"merged map 2 ({map2}) into map 1 ({map1}): ")
    assert printed[1] == f"1 map(s) from 2 file(s), 1 merge(s): {merged}"
    assert merged.is_file()

    # What the command printed, from the core itself: one merge, one map left, and every
    # keyframe of both sessions in it (measured 19 + 22 = 41: the merge fuses points, it
    # culls no keyframe).
    from ferroslam.fleet import merge_maps

    result = merge_maps([map1, map2], tmp_path / "again.map")
    assert len(result["merges"]) == 1 and len(result["maps"]) == 1
    keyframes = [r.atlas[0]["keyframes"] for r in (r1, r2)]
    assert result["maps"][0]["keyframes"] == sum(keyframes)
    assert result["merges"][0]["num_matches"] > 100  # measured 684

    # Session 1 is the frame merged into: its trajectory comes back unchanged.
    t1 = read_tum_trajectory(tmp_path / "traj" / "session1.txt")
    np.testing.assert_allclose(t1.poses, r1.largest_map_trajectory.poses, atol=1e-6)
    # Session 2 in session 1's frame: aligning session 1 alone to the ground truth (SE(3))
    # puts session 2 on its ground truth too. Measured 0.014 m (session 1's own
    # 0.012 m); in its own frame (unmerged) 0.075 m.
    t2 = read_tum_trajectory(tmp_path / "traj" / "session2.txt")
    gt = r1.groundtruth
    S = ate(gt, t1, align="se3").alignment
    merged_error = ate(gt, apply_similarity(S, t2), align="none")
    unmerged_error = ate(gt, apply_similarity(S, r2.largest_map_trajectory), align="none")
    assert merged_error.pairs == 80
    assert merged_error.rmse < 0.03, merged_error.rmse
    assert unmerged_error.rmse > 3 * merged_error.rmse
    # fr1/rpy mostly turns on the spot, so a position-only alignment leaves session 1's
    # own rotations 10 deg off (measured 10.0 median); session 2 merged has the same
    # (measured 10.0), unmerged 80 deg.
    own = ate(gt, apply_similarity(S, t1), align="none")
    assert abs(_rotation_error_deg(merged_error) - _rotation_error_deg(own)) < 2
    assert _rotation_error_deg(unmerged_error) > 45
    # Frames 60-79 are in both sessions: the same poses in the merged frame (measured at
    # most 0.032 m and 1.3 deg apart over the 20 frames).
    in1, in2 = np.isin(t1.timestamps, t2.timestamps), np.isin(t2.timestamps, t1.timestamps)
    assert in1.sum() == in2.sum() == 20
    p1, p2 = t1.poses[in1], t2.poses[in2]
    assert np.linalg.norm(p1[:, :3, 3] - p2[:, :3, 3], axis=1).max() < 0.06
    R = np.einsum("nji,njk->nik", p1[:, :3, :3], p2[:, :3, :3])
    angles = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert angles.max() < 3
    # The chain of the library gives the same similarity as the file.
    final, S2 = merge_chain(result["merges"], result["inputs"][1][-1])
    assert final == result["maps"][0]["id"]
    np.testing.assert_allclose(apply_similarity(S2, r2.largest_map_trajectory).poses, t2.poses,
                               atol=1e-5)


def test_different_places_stay_apart(tmp_path, capsys):
    """EuRoC V1_01 (Vicon room) and MH_01 (machine hall), same camera: nothing to merge
    (no false merge), both maps kept (about 4 s per session)."""
    v1 = _session(require_data("euroc", "V1_01_easy_micro"), "stereo", tmp_path, "v1", 0, 95)
    mh = _session(require_data("euroc", "MH_01_easy_window"), "stereo", tmp_path, "mh", 0, 100)
    assert v1[0].camera.fx == mh[0].camera.fx  # the same camera: the merge is attempted
    merged = tmp_path / "merged.map"
    assert cli.main(["merge", str(v1[1]), str(mh[1]), "-o", str(merged)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith(f"kept apart map 1 ({v1[1]}): it overlaps no other map")
    assert printed[1].startswith(f"kept apart map 2 ({mh[1]}): it overlaps no other map")
    assert printed[2] == f"2 map(s) from 2 file(s), 0 merge(s): {merged}"


def _error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ferroslam: error: "), err
    return err


def test_bad_input_is_one_error_line(rpy_sessions, tmp_path, capsys):
    (_, map1, traj1), _ = rpy_sessions
    out = tmp_path / "out.map"
    assert cli.main(["merge", str(map1), str(tmp_path / "nope.map"), "-o", str(out)]) == 1
    assert "nope.map: no such map file" in _error(capsys)
    bad = tmp_path / "bad.map"
    bad.write_text("not a map\n")
    assert cli.main(["merge", str(map1), str(bad), "-o", str(out)]) == 1
    assert "not a ferroslam map file" in _error(capsys)
    assert cli.main(["merge", str(map1), str(map1), "-o", str(out), "--trajectory",
                     str(traj1)]) == 1
    assert "--trajectory: 1 file(s) for 2 map file(s)" in _error(capsys)
    assert cli.main(["merge", "-o", str(out)]) == 1
    assert "no map files given" in _error(capsys)
    assert not out.exists()  # nothing written on an error


def test_trajectories_of_maps_with_one_name(rpy_sessions, tmp_path, capsys):
    """Sessions' folders each hold map.map: the re-expressed files are numbered, in the
    default folder <MERGED stem>_trajectories next to MERGED.map."""
    (_, map1, traj1), (_, map2, traj2) = rpy_sessions
    maps = []
    for name, source in (("a", map1), ("b", map2)):
        (tmp_path / name).mkdir()
        maps.append(tmp_path / name / "map.map")
        maps[-1].write_bytes(source.read_bytes())
    assert cli.main(["merge", *map(str, maps), "-o", str(tmp_path / "fleet.map"),
                     "--trajectory", str(traj1), str(traj2)]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in (tmp_path / "fleet_trajectories").iterdir()) == [
        "0_map.txt", "1_map.txt"]
