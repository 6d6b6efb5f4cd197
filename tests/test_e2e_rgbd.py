"""End to end: RGB-D SLAM on the real TUM fr1/rpy frames, against the motion-capture truth.

fr1/rpy is the hard hand-held case: rotation about all three axes at ~50 deg/s on average with
peaks of ~155 deg/s (motion blur), and only 17 cm of translation. Bounds below were measured
on this build (`python benches/stages.py`, see docs/benchmarks.md) and sit ~25% above the measured
values, so a real regression fails while the run-to-run spread of equivalent builds (the
pipeline is deterministic for a fixed build, but small changes move ATE by a few mm) does not.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ferroslam import metrics
from ferroslam.cli import main as cli_main
from ferroslam.datasets import ReplayedSequence, TumSequence
from ferroslam.pipeline import run_sequence
from ferroslam.trajectory import Trajectory

# Measured: all-frame ATE 2.15 cm, keyframe ATE 2.45 cm (SE(3) alignment, 300 frames, 56
# keyframes; pyramid resized as OpenCV's ORB does). The RGB-D keyframe limit of 250 tracked
# points made 55 keyframes instead of 45, more of them at fast rotations, whose poses err most:
# all-frame ATE 2.73 -> 2.64 cm, keyframe ATE 2.61 -> 3.42 cm (over five extractor settings,
# all-frame 3.13 -> 2.46 cm and keyframe 2.92 -> 3.01 cm on average), which the bounds allow.
# ORB-SLAM3 RGB-D on the same frames: 2.5-2.7 cm; the ORB-SLAM2-class target is < 2
# cm, which this build does not reach yet.
KEYFRAME_ATE_BOUND_M = 0.042
FRAME_ATE_BOUND_M = 0.033
# Measured: 0.53 deg RMSE per frame, of which GT association alone (up to 5 ms at 50 deg/s)
# accounts for ~0.25; 1.5 deg before the quaternion-drift fix, so this bound catches it.
RPE_ROT_BOUND_DEG = 0.8


@pytest.fixture(scope="module")
def rpy_run(tum_rpy):
    seq = TumSequence(tum_rpy)
    return seq, run_sequence(seq, {}, progress=False)


def test_tracks_every_frame(rpy_run):
    seq, result = rpy_run
    assert len(result.states) == len(seq) == 300
    assert all(s == "ok" for s in result.states), [
        (i, s) for i, s in enumerate(result.states) if s != "ok"
    ]
    assert len(result.trajectory.timestamps) == 300


def test_keyframe_and_frame_ate(rpy_run):
    seq, result = rpy_run
    gt = Trajectory(*seq.groundtruth())
    kf = metrics.ate(gt, result.keyframes, align="se3")
    frames = metrics.ate(gt, result.trajectory, align="se3")
    assert kf.pairs == len(result.keyframes.timestamps) >= 20
    assert kf.rmse < KEYFRAME_ATE_BOUND_M, f"keyframe ATE {kf.rmse:.4f} m"
    assert frames.rmse < FRAME_ATE_BOUND_M, f"frame ATE {frames.rmse:.4f} m"
    rpe = metrics.rpe(gt, result.trajectory, delta=1)
    assert rpe.rot_deg_rmse < RPE_ROT_BOUND_DEG


# The freiburg1 camera's rolling shutter (FR1_READOUT_S, the TumSequence default) modelled:
# measured 1.13 cm ATE and 0.56 cm RPE per frame at 15 ms (2.14 / 0.84 cm as a global
# shutter; sweep in docs/benchmarks.md). The bounds are the targets, 40 % and 25 %
# above the measured figures: room for the run-to-run spread of inline TUM RGB-D runs
# (docs/benchmarks.md, "Reproducible runs"), none for the global-shutter figures.
ROLLING_SHUTTER_ATE_BOUND_M = 0.016
ROLLING_SHUTTER_RPE_BOUND_M = 0.007


def test_the_fr1_rolling_shutter_model_reaches_the_targets(rpy_run):
    seq, result = rpy_run
    assert seq.camera.rolling_shutter_readout_s > 0
    gt = Trajectory(*seq.groundtruth())
    frames = metrics.ate(gt, result.trajectory, align="se3")
    rpe = metrics.rpe(gt, result.trajectory, delta=1, align="none")
    assert frames.rmse < ROLLING_SHUTTER_ATE_BOUND_M, f"frame ATE {frames.rmse:.4f} m"
    assert rpe.trans_rmse < ROLLING_SHUTTER_RPE_BOUND_M, f"RPE {rpe.trans_rmse:.4f} m"


def test_keyframe_frames_hold_their_keyframes_final_pose(rpy_run):
    """A keyframe's frame is anchored to that keyframe before local BA and loop closing move
    it, so the frame trajectory ends with the keyframe's corrected pose. Anchored after
    inline mapping had moved the keyframe, such a frame kept its tracked pose: off by the BA
    correction, and by 19.8 cm on fr1/rpy (ini_fast 19) when a loop closed at it."""
    _, result = rpy_run
    frames = dict(zip(result.trajectory.timestamps, result.trajectory.poses))
    kf = result.keyframes
    assert len(kf.timestamps) >= 20
    gaps_m = [np.linalg.norm(frames[t][:3, 3] - T[:3, 3]) for t, T in zip(kf.timestamps, kf.poses)]
    assert max(gaps_m) < 1e-9, max(gaps_m)


def test_stage_timings_add_up(rpy_run):
    # Per-stage times (issue 7's breakdown) are parts of what the core reports per frame.
    _, result = rpy_run
    t = result.timings
    assert np.all(t["pose_optimisation_ms"][1:] > 0)  # every frame after the first is tracked
    assert np.all(t["pose_optimisation_ms"] <= t["tracking_ms"])
    np.testing.assert_allclose(t["matching_ms"] + t["pose_optimisation_ms"], t["tracking_ms"])
    keyframes = t["local_ba_ms"] > 0
    assert keyframes.sum() >= 20  # local BA ran for every mapped keyframe (inline mapping)
    assert np.all(t["local_ba_ms"] + t["loop_closing_ms"] <= t["mapping_ms"])
    assert np.all(t["loop_closing_ms"][~keyframes] == 0)


def test_map_is_metric_and_bounded(rpy_run):
    _, result = rpy_run
    points = result.map_points
    assert points.shape[1] == 3 and len(points) > 1000
    # The room: every point within ~8 m (the depth range) of the start, none at infinity.
    assert np.isfinite(points).all()
    assert np.percentile(np.linalg.norm(points, axis=1), 99) < 8.0


def test_deterministic(tum_rpy):
    seq = TumSequence(tum_rpy)
    first = run_sequence(seq, {}, max_frames=40, progress=False)
    second = run_sequence(seq, {}, max_frames=40, progress=False)
    np.testing.assert_array_equal(first.trajectory.poses, second.trajectory.poses)


def test_cli_run_writes_outputs(tum_rpy, tmp_path, capsys):
    out = tmp_path / "run"
    code = cli_main(["run", str(tum_rpy), "--sensor", "rgbd", "--max-frames", "40",
                     "--out", str(out), "--silent"])
    assert code == 0
    for name in ("trajectory.txt", "keyframes.txt", "trajectory_top.png", "results.json"):
        assert (out / name).stat().st_size > 0, name
    rows = np.loadtxt(out / "trajectory.txt")
    assert rows.shape == (40, 8)
    summary = json.loads((out / "results.json").read_text())
    assert summary["tracked_frames"] == 40


class _BlankStretch:
    """fr1/rpy with frames 100-109 blacked out: nothing to track, so tracking is lost."""

    def __init__(self, seq, blank=range(100, 110)):
        self.seq, self.blank = seq, set(blank)
        self.camera, self.timestamps, self.name = seq.camera, seq.timestamps, "rpy-blank"
        self.has_groundtruth = True

    def __len__(self):
        return len(self.seq)

    def load_gray(self, i):
        gray = self.seq.load_gray(i)
        return np.zeros_like(gray) if i in self.blank else gray

    def load_depth(self, i):
        return self.seq.load_depth(i)

    def groundtruth(self):
        return self.seq.groundtruth()


def test_relocalises_in_the_same_map_after_a_loss(tum_rpy):
    """Measured: lost on the 10 blank frames, relocalised (bag-of-words candidates, PnP) at
    the first real frame, in the same map (no reset), all-frame ATE 2.7 cm."""
    result = run_sequence(_BlankStretch(TumSequence(tum_rpy)), {}, progress=False)
    states = result.states
    assert states[100:110] == ["lost"] * 10
    assert "ok" in states[110:113], states[108:115]
    assert states[113:] == ["ok"] * (300 - 113)
    assert result.num_maps == 1 and result.summary()["states"]["ok"] == 290
    assert result.ate_frames.rmse < FRAME_ATE_BOUND_M


def test_revisits_add_few_keyframes(tum_rpy, rpy_run):
    """A run revisiting mapped places (issue 7: time and memory per frame flat over a long
    run), inline, where mapping is always idle for the next frame. Measured against the 56
    keyframes / 5134 points of the first pass: 88 / 6090 after three passes (x1.57 / x1.19).
    Before frames viewing mapped structure stopped making keyframes the revisits added them
    in bursts: 109 / 8140 (x2.42 / x1.92), and 212 keyframes after 8 passes against 94 now."""
    _, first_pass = rpy_run
    replayed = ReplayedSequence(TumSequence(tum_rpy), passes=3)  # 898 frames
    result = run_sequence(replayed, {}, progress=False)
    assert result.summary()["states"] == {"ok": 898}
    kf_growth = len(result.keyframes.timestamps) / len(first_pass.keyframes.timestamps)
    point_growth = len(result.map_points) / len(first_pass.map_points)
    assert kf_growth < 1.9 and point_growth < 1.45, (kf_growth, point_growth)
