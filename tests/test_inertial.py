"""Camera-IMU alignment (issue 11): monocular SLAM on synthetic vision along the real EuRoC
V1_01 flight, fed the REAL 200 Hz IMU of that flight between frames.

After ``num_poses_threshold`` keyframes the system aligns the most recent
``alignment_fraction`` of them with the preintegrated IMU and rescales the map to metres,
then refines the alignment (ORB-SLAM3 style) when the keyframes since it span 5 s and 15 s.
Checked against vicon2gt: the metric scale of the keyframes (Sim(3) fit to the ground truth)
and their path length, gravity in the ground-truth world, the gyro bias and the keyframe
velocities. Measured numbers are in each test's docstring (this build, seed 0). The issue's
target (scale within 3 %, gravity within 1 degree) is met after the last refinement.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import require_data
from ferroslam import metrics
from ferroslam._core import SlamSystem
from ferroslam.synthetic import SyntheticStereoSequence
from ferroslam.trajectory import Trajectory

START_S, DURATION_S = 10.0, 25.0  # in flight (take-off at ~5.3 s)


@pytest.fixture(scope="module")
def seq():
    return SyntheticStereoSequence(require_data("euroc", "V1_01_easy_imu_gt"), start_s=START_S,
                                   duration_s=DURATION_S)


def _mono(seq) -> SlamSystem:
    c = seq.camera
    return SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor="mono", seed=0)


@pytest.fixture(scope="module")
def run(seq):
    """Tracks the whole cut; snapshots the keyframes right after each alignment (the first
    one and its refinements, told apart by their newest keyframe), oldest first."""
    slam = _mono(seq)
    slam.set_imu(seq.imu_params(), seq.T_b_c, num_poses_threshold=20, alignment_fraction=0.9)
    assert slam.inertial_alignment() == {"status": "waiting", "keyframes": 0, "needed": 20}
    snapshots = []
    for i in range(len(seq)):
        slam.add_imu(*seq.imu_between(i))
        f = seq.features(i)
        slam.track_mono(seq.timestamps[i], f["keypoints"], f["descriptors"])
        status = slam.inertial_alignment()
        if status["status"] == "aligned" and (
                not snapshots or snapshots[-1][1]["timestamp"] != status["timestamp"]):
            snapshots.append((i, status, slam.keyframe_trajectory()))
        elif not snapshots and status["status"] == "failed":
            print(f"frame {i}: alignment failed: {status['reason']}")
    assert snapshots, slam.inertial_alignment()
    return slam, snapshots


def _gt_index(seq, t: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(seq.timestamps, t - 1e-6)
    np.testing.assert_allclose(seq.timestamps[idx], t, atol=1e-6)
    return idx


def _alignment_errors(seq, snapshot):
    """Errors of an alignment against vicon2gt, from the live keyframes right after it."""
    frame, status, (ids, stamps, T_w_c) = snapshot
    gt_idx = _gt_index(seq, stamps)
    _, gt_T_w_c = seq.groundtruth()
    R, _, c = metrics.umeyama_alignment(T_w_c[:, :3, 3], gt_T_w_c[gt_idx, :3, 3],
                                        with_scale=True)
    lengths = metrics.path_length(Trajectory(stamps, gt_T_w_c[gt_idx]), Trajectory(stamps, T_w_c))
    gravity_gt = R @ status["gravity_w"]
    gravity_deg = float(np.degrees(np.arccos(-gravity_gt[2] / np.linalg.norm(gravity_gt))))
    window = _gt_index(seq, status["keyframe_timestamps"])
    gyro_err = float(np.linalg.norm(status["gyro_bias"] - seq.gyro_bias[window].mean(0)))
    v_err = R @ status["velocities"].T - seq.v_w_b[window].T
    v_rms = float(np.sqrt(np.mean(np.sum(v_err ** 2, 0))))
    print(f"aligned at frame {frame} ({status['keyframes']} keyframes, "
          f"{status['keyframe_timestamps'][-1] - status['keyframe_timestamps'][0]:.2f} s): "
          f"scale {status['scale']:.4f}; Sim(3) scale of the {len(ids)} live keyframes "
          f"{c:.4f}, path length error {100 * lengths.scale_error:.2f} %, gravity "
          f"{gravity_deg:.3f} deg, gyro bias error {gyro_err:.5f} rad/s, velocity RMS "
          f"{v_rms:.4f} m/s")
    return c, lengths.scale_error, gravity_deg, gyro_err, v_rms


def test_first_alignment_rescales_the_map_and_finds_gravity(seq, run):
    """Measured (start 10 s, 20 keyframes, 18 aligned over 4.0 s, aligned at frame 87; a
    keyframe at least every 0.25 s before the alignment, ORB-SLAM3's rule): scale 3.67; live
    keyframes' Sim(3) scale to vicon2gt 1.056 (path length -5.2 %), gravity 1.41 deg, gyro
    bias 0.0014 rad/s from vicon2gt, velocities 2.2 cm/s RMS. (Before the 0.25 s rule the 18
    keyframes spanned 2.25 s and the scale was 16 % off.) The window rotates too little for
    the accelerometer bias (vicon2gt: 0.05..0.17 m/s^2) to be estimated. Bounds: about twice
    the measured errors; the refinements below reach the issue's target."""
    _, snapshots = run
    status = snapshots[0][1]
    assert status["map_rescaled"]
    assert status["keyframes"] >= 18  # 0.9 of at least 20
    c, length_error, gravity_deg, gyro_err, v_rms = _alignment_errors(seq, snapshots[0])
    assert abs(c - 1.0) < 0.12
    assert abs(length_error) < 0.12
    assert gravity_deg < 2.0
    assert gyro_err < 3e-3
    assert v_rms < 0.1
    np.testing.assert_allclose(np.linalg.norm(status["gravity_w"]), 9.81, rtol=1e-9)
    np.testing.assert_allclose(status["R_w_g"] @ [0, 0, -9.81], status["gravity_w"], atol=1e-9)


def test_refinements_at_5_and_15_s_meet_the_issue_target(seq, run):
    """Measured (refinements with the accelerometer bias, the windows rotating enough):
    at 15 s (29 keyframes, frame 390) Sim(3) scale 1.0150, path length -1.4 %, gravity
    0.17 deg, gyro bias 0.00055 rad/s, velocities 4.5 cm/s RMS. Without the accelerometer bias the refinements ended 13 % (Sim(3) 0.866,
    path +16 %) off, so the bias estimate is what closes the gap. Bounds: the issue's target
    (3 %, 1 deg), twice the measured scale error; the rest measured + margin."""
    _, snapshots = run
    assert len(snapshots) == 3, [s[0] for s in snapshots]
    spans = [s[1]["keyframe_timestamps"][-1] - s[1]["keyframe_timestamps"][0]
             for s in snapshots]
    # A refinement window starts at the first keyframe of its span: within one keyframe gap
    # (0.1 s here) of the span.
    assert spans[0] < 5.0, spans
    assert 4.75 < spans[1] <= 5.0 + 1e-6 and 14.75 < spans[2] <= 15.0 + 1e-6, spans
    for _, status, _ in snapshots:
        assert status["map_rescaled"]
        np.testing.assert_allclose(np.linalg.norm(status["gravity_w"]), 9.81, rtol=1e-9)
    c, length_error, gravity_deg, gyro_err, v_rms = _alignment_errors(seq, snapshots[-1])
    assert abs(c - 1.0) < 0.03
    assert abs(length_error) < 0.03
    assert gravity_deg < 1.0
    assert gyro_err < 2e-3
    assert v_rms < 0.08
    assert np.linalg.norm(snapshots[-1][1]["accel_bias"]) > 0.0  # estimated


def test_map_stays_at_the_new_scale_after_the_alignment(seq, run):
    """Frames tracked after the last alignment (rescaled map, trajectory and motion model)
    keep the scale the alignment gave the keyframes: no jump, no relapse to visual units.
    Measured: 109 frames, Sim(3) scale 1.0116 (keyframes 1.0150), ATE 4.0 mm (1.6 mm
    without local inertial BA, which runs from here on: the real IMU and vicon2gt, the truth
    of the synthetic vision, disagree by millimetres over 0.5 s, more than the datasheet
    noise the factors are weighted with allows)."""
    slam, snapshots = run
    frame = snapshots[-1][0]
    c_keyframes = _alignment_errors(seq, snapshots[-1])[0]
    stamps, T_w_c = slam.frame_trajectory()
    after = stamps > seq.timestamps[frame]
    gt_idx = _gt_index(seq, stamps[after])
    _, gt_T_w_c = seq.groundtruth()
    est = Trajectory(stamps[after], T_w_c[after])
    ref = Trajectory(seq.timestamps[gt_idx], gt_T_w_c[gt_idx])
    ate = metrics.ate(ref, est, align="sim3")
    print(f"{after.sum()} frames after alignment: Sim(3) scale {ate.scale:.4f} "
          f"(keyframes at alignment: {c_keyframes:.4f}), ATE {ate.rmse:.4f} m")
    assert after.sum() > 0.8 * (len(seq) - frame)
    assert abs(ate.scale / c_keyframes - 1.0) < 0.05
    assert slam.inertial_alignment()["status"] == "aligned"


def test_local_inertial_ba_refines_the_newest_imu_state(seq, run):
    """After the last refinement local inertial BA (poses, velocities, biases over the newest
    10 keyframes) runs at every keyframe. Measured at the end of the run against vicon2gt:
    body velocity 2.3 cm/s off (of 0.58 m/s), gyro bias 0.00028 rad/s (the alignment's:
    0.00053), accelerometer bias 0.043 m/s^2 (the alignment's: 0.013; true 0.18). Bounds:
    about twice the measured."""
    slam, _ = run
    state = slam.keyframe_imu_state()
    ids, stamps, T_w_c = slam.keyframe_trajectory()
    assert state["keyframe_id"] == ids.max()
    aligned = slam.inertial_alignment()
    assert not np.allclose(state["gyro_bias"], aligned["gyro_bias"])  # BA moved it
    _, gt_T_w_c = seq.groundtruth()
    R, _, _ = metrics.umeyama_alignment(T_w_c[:, :3, 3], gt_T_w_c[_gt_index(seq, stamps), :3, 3],
                                        with_scale=True)
    i = _gt_index(seq, np.array([state["timestamp"]]))[0]
    v_err = np.linalg.norm(R @ state["velocity"] - seq.v_w_b[i])
    bg_err = np.linalg.norm(state["gyro_bias"] - seq.gyro_bias[i])
    ba_err = np.linalg.norm(state["accel_bias"] - seq.acc_bias[i])
    print(f"\nnewest keyframe state: velocity {v_err:.4f} m/s, gyro bias {bg_err:.5f} rad/s, "
          f"accel bias {ba_err:.4f} m/s^2 off")
    assert v_err < 0.05
    assert bg_err < 6e-4
    assert ba_err < 0.09


def _imu_chunk(t0=0.0, n=10):
    t = t0 + 0.005 * np.arange(n)
    gyro = np.tile([0.01, -0.02, 0.03], (n, 1))
    accel = np.tile([0.1, 0.2, 9.81], (n, 1))
    return t, gyro, accel


def test_bad_imu_input_raises_and_leaves_the_system_unchanged(seq):
    slam = _mono(seq)
    assert slam.inertial_alignment() is None
    with pytest.raises(ValueError, match="set_imu first"):
        slam.add_imu(*_imu_chunk())
    params, T_b_c = seq.imu_params(), seq.T_b_c
    with pytest.raises(ValueError, match="alignment_fraction"):
        slam.set_imu(params, T_b_c, alignment_fraction=0.0)
    with pytest.raises(ValueError, match="num_poses_threshold"):
        slam.set_imu(params, T_b_c, num_poses_threshold=2)
    with pytest.raises(ValueError, match="rigid"):
        slam.set_imu(params, 2.0 * T_b_c)
    with pytest.raises(TypeError, match="T_b_c"):
        slam.set_imu(params, T_b_c.astype(np.float32))
    with pytest.raises(TypeError, match="gyroscope_noise_density"):
        slam.set_imu({"rate_hz": 200.0}, T_b_c)
    bad_params = {k: getattr(params, k) for k in (
        "gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
        "accelerometer_random_walk", "rate_hz")}
    with pytest.raises(ValueError, match="rate_hz"):
        slam.set_imu({**bad_params, "rate_hz": -1.0}, T_b_c)
    assert slam.inertial_alignment() is None

    slam.set_imu(bad_params, T_b_c)
    slam.add_imu(*_imu_chunk(0.0))
    t, gyro, accel = _imu_chunk(1.0)
    with pytest.raises(ValueError, match="not after"):
        slam.add_imu(t[::-1].copy(), gyro, accel)
    with pytest.raises(ValueError, match="last sample added"):
        slam.add_imu(*_imu_chunk(0.02))
    nan = accel.copy()
    nan[3, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        slam.add_imu(t, gyro, nan)
    with pytest.raises(ValueError, match="deg/s"):
        slam.add_imu(t, np.degrees(gyro) * 1000.0, accel)
    with pytest.raises(ValueError, match="in g"):
        slam.add_imu(t, gyro, accel / 9.81)
    with pytest.raises(ValueError, match="shape"):
        slam.add_imu(t, gyro[:, :2].copy(), accel)
    with pytest.raises(TypeError, match="gyro"):
        slam.add_imu(t, gyro.astype(np.float32), accel)
    slam.add_imu(t, gyro, accel)  # the rejected batches left the buffer as it was
    assert slam.inertial_alignment()["status"] == "waiting"


DROP_START_S, DROP_S = 9.0, 1.0  # after the 5 s refinement (first alignment at ~2.5 s)


@pytest.fixture(scope="module")
def seq12():
    return SyntheticStereoSequence(require_data("euroc", "V1_01_easy_imu_gt"), start_s=START_S,
                                   duration_s=12.0)


def _run_with_dropped_features(seq, sensor: str, imu: bool, keep: int):
    """Tracks the cut with all but ``keep`` features (a random subset) removed from the frames
    of a 1 s stretch."""
    c = seq.camera
    slam = SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor=sensor, seed=0)
    if imu:
        slam.set_imu(seq.imu_params(), seq.T_b_c, num_poses_threshold=10)
    rel = seq.timestamps - seq.timestamps[0]
    dropped = (rel >= DROP_START_S) & (rel < DROP_START_S + DROP_S)
    states = []
    for i in range(len(seq)):
        if imu:
            slam.add_imu(*seq.imu_between(i))
        f = seq.features(i)  # in random order
        kept = slice(0, keep) if dropped[i] else slice(None)
        if sensor == "rgbd":
            r = slam.track_rgbd(seq.timestamps[i], f["keypoints"][kept], f["descriptors"][kept],
                                f["depth_m"][kept])
        else:
            r = slam.track_mono(seq.timestamps[i], f["keypoints"][kept], f["descriptors"][kept])
        states.append(r.state)
    return slam, np.array(states), dropped


def _stretch_errors(seq, slam, dropped) -> np.ndarray:
    """Position error (m) of the frames of the stretch in the motion since the last tracked
    frame before it, rotated into the map by that frame's pose."""
    stamps, T_w_c = slam.frame_trajectory()
    _, gt_T_w_c = seq.groundtruth()
    idx = _gt_index(seq, stamps)
    assert dropped[idx].sum() == dropped.sum()  # every frame of the stretch has a pose
    last = int(np.flatnonzero(dropped)[0]) - 1
    j = int(np.flatnonzero(idx == last)[0])
    R_align = T_w_c[j, :3, :3] @ gt_T_w_c[last, :3, :3].T
    moved_est = T_w_c[:, :3, 3] - T_w_c[j, :3, 3]
    moved_gt = (gt_T_w_c[idx, :3, 3] - gt_T_w_c[last, :3, 3]) @ R_align.T
    return np.linalg.norm(moved_est - moved_gt, axis=1)[dropped[idx]]


@pytest.mark.parametrize("sensor", ["rgbd", "mono"])
def test_imu_carries_tracking_through_weak_vision(seq12, sensor):
    """Issue 11: vision fails for 1 s (20 frames with no feature, or with only 15). Without
    the IMU those frames are lost (no pose). With it (RGB-D-inertial, mono-inertial) each
    frame gets the IMU's prediction from the last tracked frame (state ``recently_lost``),
    fused with whatever matches the local map offers around it (visual-inertial motion-only
    BA, the prediction as prior); the first full frame afterwards tracks the map again: no
    relocalisation, no new map segment.

    Measured (error of the motion since the last tracked frame, over 0.48 m of flight):
    IMU alone 5.3 / 5.2 cm at the end of the second (RGB-D / mono; it grows with the square
    of the time from the alignment's gravity and bias errors); with 15 features the RMS
    over the stretch falls from 2.7 / 2.7 cm to 1.5 / 1.3 cm (max 3.1 / 2.7 cm). Bounds: 10 cm for the IMU alone
    (twice the measured); the fused RMS below 0.75 of the IMU-only RMS."""
    errors = {}
    for keep in (0, 15):
        slam, states, dropped = _run_with_dropped_features(seq12, sensor, imu=True, keep=keep)
        assert slam.inertial_alignment()["status"] == "aligned"
        assert set(states[dropped]) == {"recently_lost"}
        assert states[int(np.flatnonzero(dropped)[-1]) + 1] == "ok"
        assert set(slam.frame_map_ids()) == {0}
        errors[keep] = _stretch_errors(seq12, slam, dropped)
    rms = {k: float(np.sqrt(np.mean(e ** 2))) for k, e in errors.items()}
    print(f"\n{sensor}-inertial, 1 s of weak vision: IMU alone {100 * errors[0][-1]:.1f} cm "
          f"at the end (RMS {100 * rms[0]:.1f} cm); with 15 features RMS {100 * rms[15]:.1f} "
          f"cm (max {100 * errors[15].max():.1f} cm)")
    assert errors[0].max() < 0.1
    assert rms[15] < 0.75 * rms[0]

    plain, plain_states, _ = _run_with_dropped_features(seq12, sensor, imu=False, keep=15)
    assert set(plain_states[dropped]) == {"lost"}
    plain_stamps, _ = plain.frame_trajectory()
    assert not np.isin(seq12.timestamps[dropped], plain_stamps).any()


def test_missing_imu_falls_back_to_vision(seq12):
    """IMU samples missing for 0.5 s (never added) before the alignment: vision tracks on,
    the alignment reports the gap (named, with the samples around it) and waits, then
    aligns on the 9 keyframes after it (at 3.5 s instead of 2.25 s)."""
    c = seq12.camera
    slam = SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor="rgbd", seed=0)
    slam.set_imu(seq12.imu_params(), seq12.T_b_c, num_poses_threshold=10)
    rel = seq12.timestamps - seq12.timestamps[0]
    states, reasons, aligned_at = [], set(), None
    for i in range(len(seq12)):
        if not 1.0 <= rel[i] < 1.5:
            slam.add_imu(*seq12.imu_between(i))
        f = seq12.features(i)
        states.append(slam.track_rgbd(seq12.timestamps[i], f["keypoints"], f["descriptors"],
                                      f["depth_m"]).state)
        status = slam.inertial_alignment()
        if status["status"] == "failed":
            reasons.add(status["reason"])
        elif status["status"] == "aligned" and aligned_at is None:
            aligned_at = rel[i]
    assert states == ["ok"] * len(seq12)
    assert reasons and all("IMU data are missing" in r and "0.505 s apart" in r for r in reasons)
    assert aligned_at is not None and 3.0 < aligned_at < 4.0, aligned_at
    assert min(slam.inertial_alignment()["keyframe_timestamps"]) > seq12.timestamps[0] + 1.5
