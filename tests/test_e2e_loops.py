"""End to end: loop closing (bag-of-words detection, Sim(3) verification and correction,
essential graph, global BA).

Real frames without a revisit (KITTI 06 and 01 drive straight on): the system must close no
loop, and the trajectory must be the one computed with loop closing switched off. Detection must
still have run and refused its candidates, so these tests cannot pass by never looking. TUM
fr1/rpy turns in place and views the same desk again within seconds: a loop closed there must
join keyframes whose ground-truth poses view the same place, and must lower the ATE.

A real trajectory with real revisits: the whole 144 s EuRoC V1_01 flight with synthetic vision
(``ferroslam.synthetic``; 3 m sensing range, 1 px noise, 700 features per frame, so the map
drifts as a real one does). Each loop closed must join two frames that see the same landmarks
(ground truth: the landmark ids each frame sees), and loop closing must lower the ATE.
Measured on this build, seed 0 (scratch runs; figures in the docstring of each test).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import require_data
from ferroslam import metrics
from ferroslam._core import SlamSystem
from ferroslam.datasets import KittiSequence, TumSequence
from ferroslam.pipeline import load_vocabulary, run_sequence
from ferroslam.synthetic import SyntheticStereoSequence, VisionModel
from ferroslam.trajectory import Trajectory

REAL_RUNS = {
    "kitti06_mono": ("kitti_mono", "mono", {"n_features": 2000}),
    "kitti01_stereo": ("kitti_stereo", "stereo", {"n_features": 2000, "depth_threshold": 35}),
}
# Keyframes whose bag-of-words query found candidates, at least (measured 11 / 4; KITTI 01 had
# 11 before keyframes with depth stopped triangulating with neighbours that bring few points:
# its map has fewer points, 2625 against 2889).
MIN_WITH_CANDIDATES = {"kitti06_mono": 10, "kitti01_stereo": 3}


@pytest.mark.parametrize("case", sorted(REAL_RUNS))
def test_no_false_loop_on_real_sequences_without_loops(case, request):
    fixture, sensor, config = REAL_RUNS[case]
    path = request.getfixturevalue(fixture)
    with_loops = run_sequence(KittiSequence(path, stereo=sensor == "stereo"), config,
                              sensor=sensor, progress=False)
    without = run_sequence(KittiSequence(path, stereo=sensor == "stereo"),
                           {**config, "loop_closure": False}, sensor=sensor, progress=False)
    assert with_loops.loops == []
    stats = with_loops.loop_stats
    # Detection ran on every keyframe once the map held more than 10 (measured: 21 / 31
    # checked) and found bag-of-words candidates (KITTI 06: 15 verified; KITTI 01's forward
    # drive yields candidates but none consistent over 3 keyframes), and every one was
    # refused.
    assert stats["keyframes_checked"] >= len(with_loops.keyframe_ids) - 10, stats
    assert stats["with_candidates"] >= MIN_WITH_CANDIDATES[case], stats
    assert stats["rejected"] == stats["verified"], stats
    assert without.loop_stats["keyframes_checked"] == 0
    np.testing.assert_array_equal(with_loops.trajectory.poses, without.trajectory.poses)
    assert with_loops.ate_frames.rmse == without.ate_frames.rmse


# A loop's two keyframes view the same place: ground-truth camera centres this close and
# optical axes within 30 deg, under half the camera's 63 deg horizontal field of view, so the
# two views share more than half their width (measured on fr1/rpy: 5.8 cm and 25 deg; 2.4 cm
# and 10 deg with ORB-SLAM's INTER_LINEAR pyramid).
SAME_PLACE_M = 0.10
SAME_VIEW_DEG = 30.0


def test_fr1_rpy_with_its_readout_re_finds_the_desk_instead_of_closing_a_loop(tum_rpy):
    """With fr1's 15 ms readout modelled (the loader's default camera) the map drifts so little
    that tracking re-finds the earlier keyframes' points when the camera turns back: the
    keyframes of every revisit are already covisible, so no loop is left to close (candidates
    must be unconnected to the keyframe, as in ORB-SLAM). Measured (2026-12-02, inline,
    default options): 43 keyframes, 33 checked, 30 with candidates, 24 verified, each a view
    33-109 deg off the current one (bag-of-words matches 3-14 of the 20 the Sim(3) needs, a
    stage with no projection) and refused; every keyframe pair within 10 cm and 20 deg by
    the ground truth is covisible. ATE 1.13 cm, against 2.14 cm for the global-shutter run
    with its loop (below)."""
    seq = TumSequence(tum_rpy)
    assert seq.camera.rolling_shutter_readout_s == 0.015
    with_loops = run_sequence(seq, {}, progress=False)
    without = run_sequence(TumSequence(tum_rpy), {"loop_closure": False}, progress=False)
    stats = with_loops.loop_stats
    assert stats["keyframes_checked"] >= len(with_loops.keyframe_ids) - 10, stats
    assert stats["with_candidates"] >= 20, stats
    # Every candidate verified views another part of the desk: closing one would be false.
    assert with_loops.loops == [] and stats["rejected"] == stats["verified"] >= 10, stats
    np.testing.assert_array_equal(with_loops.trajectory.poses, without.trajectory.poses)
    # The target is 1.6 cm (measured 1.13 cm).
    assert with_loops.ate_frames.rmse < 0.016


def test_loops_on_fr1_rpy_join_views_of_the_same_place(tum_rpy):
    """fr1/rpy turns in place, so it comes back to views it mapped a second or more before,
    when those keyframes have left the local map. Measured (inline, default options): one
    loop, keyframe 21 against keyframe 4 (frames 67 and 12, 1.84 s apart, 236 matches,
    ground truth 5.8 cm and 25 deg apart), which moved keyframe 21 by 9 cm: ATE 3.61 cm
    without loop closing, 2.14 cm with it. Detection checked 37 keyframes, 36 had
    candidates, 52 of 53 verified candidates were refused. (With ORB-SLAM's INTER_LINEAR
    pyramid: keyframe 19 against 6, 1.06 s, 311 matches, 2.4 cm and 10 deg; 5.56 -> 2.49
    cm.)"""
    # As a global shutter: the only real revisit of our data left unconnected by tracking.
    # With fr1's readout modelled the map holds on to the desk and no loop is needed (above).
    camera = dataclasses.replace(TumSequence(tum_rpy).camera, rolling_shutter_readout_s=0.0)
    with_loops = run_sequence(TumSequence(tum_rpy, camera=camera), {}, progress=False)
    without = run_sequence(TumSequence(tum_rpy, camera=camera), {"loop_closure": False},
                           progress=False)
    stats, loops = with_loops.loop_stats, with_loops.loops
    # Detection waits for 10 keyframes at the start and after each loop.
    assert stats["keyframes_checked"] >= len(with_loops.keyframe_ids) - 10 * (1 + len(loops))
    assert stats["with_candidates"] >= 20, stats
    assert loops, stats
    gt = with_loops.groundtruth
    for loop in loops:
        T_w_a, T_w_b = (gt.poses[np.argmin(np.abs(gt.timestamps - t))] for t in loop["timestamps"])
        axes_cos = T_w_a[:3, 2] @ T_w_b[:3, 2]
        assert np.linalg.norm(T_w_a[:3, 3] - T_w_b[:3, 3]) < SAME_PLACE_M, loop
        assert np.degrees(np.arccos(np.clip(axes_cos, -1.0, 1.0))) < SAME_VIEW_DEG, loop
        assert loop["scale"] == 1.0 and loop["num_matches"] >= 40, loop
    assert with_loops.ate_frames.rmse < 0.7 * without.ate_frames.rmse


# ---------------------------------------------------------------------------------------------
# Synthetic vision on the real V1_01 flight: real revisits.

# With stereo depth, tracking at 1 px noise drifts about 1 cm over the flight, too little for
# loop closing's gain to stand out from which revisiting frames happen to become keyframes
# (2-13 % over four keyframe-rule variants); at 1.5 px it drifts 2.9-3.1 cm.
VISION = {
    "mono": VisionModel(max_range_m=3.0, pixel_sigma=1.0, max_features=700),
    "rgbd": VisionModel(max_range_m=3.0, pixel_sigma=1.5, max_features=700),
}
MIN_SHARED_LANDMARKS = 20
MIN_LOOP_GAP_S = 10.0


def _run_synthetic(seq, sensor: str, loop_closure: bool):
    c = seq.camera
    options = {"bf": seq.bf} if sensor == "rgbd" else {}
    slam = SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor=sensor, seed=0,
                      loop_closure=loop_closure, **options)
    slam.set_vocabulary(load_vocabulary("default"))
    for i in range(len(seq)):
        f = seq.features(i)
        if sensor == "rgbd":  # stereo observations, fed through the RGB-D entry point
            slam.track_rgbd(seq.timestamps[i], f["keypoints"], f["descriptors"], f["depth_m"])
        else:
            slam.track_mono(seq.timestamps[i], f["keypoints"], f["descriptors"])
    align = "se3" if sensor == "rgbd" else "sim3"
    ate = metrics.ate(Trajectory(*seq.groundtruth()), Trajectory(*slam.frame_trajectory()),
                      align=align)
    return slam, ate


@pytest.fixture(scope="module", params=["mono", "rgbd"])
def flight_runs(request):
    sensor = request.param
    seq = SyntheticStereoSequence(require_data("euroc", "V1_01_easy_imu_gt"),
                                  vision=VISION[sensor])
    return sensor, seq, _run_synthetic(seq, sensor, True), _run_synthetic(seq, sensor, False)


def _frame_at(seq, t: float) -> int:
    i = int(np.argmin(np.abs(seq.timestamps - t)))
    assert abs(seq.timestamps[i] - t) < 1e-6
    return i


def test_synthetic_flight_loops_only_at_true_revisits(flight_runs):
    """Measured: 4 loops monocular and 5 stereo, between frames sharing 44-282 landmarks,
    13-106 s apart."""
    sensor, flight_seq, (slam, _), _ = flight_runs
    loops = slam.loops()
    assert len(loops) >= 3, slam.loop_stats()
    for loop in loops:
        t_current, t_matched = loop["timestamps"]
        assert t_current - t_matched >= MIN_LOOP_GAP_S, loop
        a, b = _frame_at(flight_seq, t_current), _frame_at(flight_seq, t_matched)
        shared = np.intersect1d(flight_seq.visible(a)[0], flight_seq.visible(b)[0]).size
        assert shared >= MIN_SHARED_LANDMARKS, (loop, shared)
        assert loop["num_matches"] >= 40
        assert loop["graph_cost"][1] < loop["graph_cost"][0]
        if sensor == "rgbd":
            assert loop["scale"] == 1.0


def test_synthetic_flight_loop_closing_lowers_ate(flight_runs):
    """Measured (seed 0): mono Sim(3) ATE 1.81 cm without loop closing, 1.36 cm with it;
    stereo SE(3) at 1.5 px noise 3.11 cm without, 2.19 cm with (landmark seeds 1 and 2:
    2.90 -> 2.15 and 3.13 -> 2.30 cm). The gain is modest because tracking against the local
    map already re-finds most old landmarks in this room, so little drift is left for loop
    closing to remove (with 8 m range the runs drift by 2 mm only)."""
    sensor, _, (_, on), (_, off) = flight_runs
    print(f"{sensor}: ATE {off.rmse * 100:.2f} cm without loop closing, "
          f"{on.rmse * 100:.2f} cm with it")
    assert on.pairs == off.pairs and on.pairs > 2700
    assert on.rmse < 0.9 * off.rmse
    assert on.rmse < {"mono": 0.02, "rgbd": 0.025}[sensor]
