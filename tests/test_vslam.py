"""The MATLAB-style objects (``RGBDVSlam``, ``StereoVSlam``, ``MonoVSlam``) on real frames:
the workflow of the seeds' loops, map save/load with localisation, logging and bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ferroslam import metrics
from ferroslam.datasets import KittiSequence, TumSequence
from ferroslam.trajectory import Trajectory
from ferroslam.pipeline import run_sequence
from ferroslam.vslam import MonoVSlam, RGBDVSlam, StereoVSlam, TrackingStatus

pytest.importorskip("ferroslam._core")

N_FRAMES = 60


def raw_depth(seq, i):
    return cv2.imread(str(seq.frames[i].depth_path), cv2.IMREAD_UNCHANGED)


@pytest.fixture(scope="module")
def tum(tum_rpy):
    return TumSequence(tum_rpy)


@pytest.fixture(scope="module")
def rgbd_run(tum):
    """The seeds' RGB-D loop over the first frames, each frame finished in ``add_frame``:
    (vslam, statuses, new-keyframe flags)."""
    vslam = RGBDVSlam(tum.camera, depth_scale_factor=5000, skip_max_frames=30, threaded=False)
    statuses, new_keyframes = [], []
    for i in range(N_FRAMES):
        vslam.add_frame(tum.load_gray(i), raw_depth(tum, i), timestamp=tum.timestamps[i])
        new_keyframes.append(vslam.has_new_keyframe())
        statuses.append(vslam.check_status())
    assert vslam.is_done()
    return vslam, statuses, new_keyframes


def test_rgbd_workflow_matches_the_pipeline(tum, rgbd_run):
    vslam, statuses, new_keyframes = rgbd_run
    assert statuses[0] is not TrackingStatus.NOT_INITIALIZED
    assert all(s in (TrackingStatus.SUCCESSFUL, TrackingStatus.FREQUENT_KEYFRAMES)
               for s in statuses)
    assert new_keyframes[0] and sum(new_keyframes) >= 3
    assert not vslam.has_new_keyframe()  # the flag was consumed
    ids, poses = vslam.poses()
    assert poses.shape == (len(ids), 4, 4) and len(ids) == vslam._system.num_keyframes
    # Same extractor, same options: the object gives exactly the pipeline's trajectory.
    reference = run_sequence(tum, {"skip_max_frames": 30}, max_frames=N_FRAMES, progress=False)
    stamps, frame_poses, segments = vslam.frame_trajectory()
    np.testing.assert_array_equal(frame_poses, reference.trajectory.poses)
    assert (segments == 0).all() and vslam.map_points().shape[1] == 3


def test_threaded_stress_matches_synchronous(tum, rgbd_run):
    """Frames pushed as fast as extraction allows (no pacing, ~5x real time): the tracking
    thread lags, the bounded queue blocks the producer instead of growing, local mapping runs
    in a third thread on map snapshots, and every frame is still tracked with an accuracy
    close to the synchronous run's. Measured on these 60 frames: 3.6-4.0 cm over four
    threaded runs against 2.35 cm synchronous; runs differ because mapping lags tracking by a
    varying number of frames. Paced at 30 Hz instead, the whole sequence gives 2.78 cm
    threaded against 2.73 cm synchronous (scratch run), so the gap is the price of feeding
    faster than real time; the bound allows 2.5x."""
    vslam = RGBDVSlam(tum.camera, depth_scale_factor=5000, skip_max_frames=30)
    seen_pending = False
    for i in range(N_FRAMES):
        vslam.add_frame(tum.load_gray(i), raw_depth(tum, i), timestamp=tum.timestamps[i])
        seen_pending |= not vslam.is_done()
    assert vslam.num_frames == N_FRAMES
    vslam.wait()
    assert vslam.is_done() and vslam.num_processed == N_FRAMES
    assert seen_pending  # the work really happened in the background
    assert vslam.check_status() is not TrackingStatus.LOST
    sync, _, _ = rgbd_run
    groundtruth = Trajectory(*tum.groundtruth())

    def ate(v):
        stamps, poses, _ = v.frame_trajectory()
        return metrics.ate(groundtruth, Trajectory(stamps, poses)).rmse

    threaded_stamps = vslam.frame_trajectory()[0]
    assert len(threaded_stamps) == N_FRAMES
    assert ate(vslam) < 2.5 * ate(sync), (ate(vslam), ate(sync))
    assert vslam._system.num_keyframes >= 3
    vslam.close()


def test_shutdown_with_queued_frames(tum):
    """Closing (or dropping) right after queueing frames neither hangs nor crashes."""
    frames = [(tum.load_gray(i), raw_depth(tum, i)) for i in range(12)]
    with RGBDVSlam(tum.camera, depth_scale_factor=5000) as vslam:
        for color, depth in frames:
            vslam.add_frame(color, depth)
    assert vslam.is_done() and vslam.num_processed == 12
    dropped = RGBDVSlam(tum.camera, depth_scale_factor=5000)
    for color, depth in frames:
        dropped.add_frame(color, depth)
    del dropped  # joins the worker after it finishes the queue


def test_threaded_bad_input_raises_at_add_frame(tum):
    vslam = RGBDVSlam(tum.camera, depth_scale_factor=5000)
    vslam.add_frame(tum.load_gray(0), raw_depth(tum, 0), timestamp=1.0)
    with pytest.raises(ValueError, match="is not after the previous frame's"):
        vslam.add_frame(tum.load_gray(1), raw_depth(tum, 1), timestamp=0.5)
    vslam.add_frame(tum.load_gray(1), raw_depth(tum, 1), timestamp=1.1)
    vslam.wait()
    assert vslam.num_processed == 2


def test_plot_writes_the_map(rgbd_run, tmp_path):
    vslam, _, _ = rgbd_run
    ax = vslam.plot(path=tmp_path / "map.png")
    assert ax.name == "3d" and (tmp_path / "map.png").stat().st_size > 5000


def test_saved_map_relocalises_and_stays_unchanged(tum, rgbd_run, tmp_path):
    vslam, _, _ = rgbd_run
    path = tmp_path / "rpy.map"
    vslam.save_map(path)
    keyframes = vslam._system.num_keyframes
    with RGBDVSlam(tum.camera, depth_scale_factor=5000, threaded=False) as other:
        other.load_map(path)
        assert other.localization_only and other.check_status() is TrackingStatus.NOT_INITIALIZED
        states = []
        for i in range(20, 40):  # frames the saved map has seen: relocalise at once
            other.add_frame(tum.load_gray(i), raw_depth(tum, i), timestamp=tum.timestamps[i])
            states.append(other.check_status())
        assert states[0] in (TrackingStatus.SUCCESSFUL, TrackingStatus.FREQUENT_KEYFRAMES), states[:3]
        assert states.count(TrackingStatus.LOST) == 0
        assert other._system.num_keyframes == keyframes  # localisation never adds keyframes
        _, poses, _ = other.frame_trajectory()
        _, ref_poses, _ = vslam.frame_trajectory()
        # Same frames, the final map: within 2 cm of the poses first tracked while that map
        # was still being refined (measured 13 mm at most; the run's ATE is ~2.7 cm).
        assert np.abs(poses[:, :3, 3] - ref_poses[20:40, :3, 3]).max() < 0.02


def test_map_points_take_the_colours_of_the_images_given(tum, rgbd_run, tmp_path):
    """Grey images give grey points; colour images give each point its keypoint's colour,
    and a saved map keeps them."""
    vslam, _, _ = rgbd_run  # fed grey images
    grey = vslam.map_point_colors()
    assert grey.dtype == np.uint8 and grey.shape == vslam.map_points().shape
    assert (grey == grey[:, :1]).all() and len(np.unique(grey[:, 0])) > 50

    with RGBDVSlam(tum.camera, depth_scale_factor=5000, threaded=False) as colour:
        for i in range(10):
            colour.add_frame(tum.load_gray_and_color(i)[1], raw_depth(tum, i),
                             timestamp=tum.timestamps[i])
        points, colors = colour.map_points(), colour.map_point_colors()
        colour.save_map(tmp_path / "colour.map")
    assert len(colors) == len(points) > 500
    assert np.abs(np.diff(colors.astype(int), axis=1)).mean() > 5  # not grey
    with RGBDVSlam(tum.camera, depth_scale_factor=5000, threaded=False) as loaded:
        loaded.load_map(tmp_path / "colour.map")
        np.testing.assert_array_equal(loaded.map_points(), points)
        np.testing.assert_array_equal(loaded.map_point_colors(), colors)


def test_relocalises_without_a_vocabulary_too(tum, rgbd_run, tmp_path):
    """Without place recognition a loaded map is searched keyframe by keyframe."""
    vslam, _, _ = rgbd_run
    vslam.save_map(tmp_path / "rpy.map")
    other = RGBDVSlam(tum.camera, depth_scale_factor=5000, vocabulary=None, threaded=False)
    other.load_map(tmp_path / "rpy.map")
    other.add_frame(tum.load_gray(45), raw_depth(tum, 45), timestamp=tum.timestamps[45])
    assert other.check_status() in (TrackingStatus.SUCCESSFUL, TrackingStatus.FREQUENT_KEYFRAMES)


def test_map_file_errors(tum, rgbd_run, tmp_path):
    vslam, _, _ = rgbd_run
    good = tmp_path / "good.map"
    vslam.save_map(good)
    data = good.read_bytes()
    other = RGBDVSlam(tum.camera, depth_scale_factor=5000)
    with pytest.raises(FileNotFoundError, match="missing.map"):
        other.load_map(tmp_path / "missing.map")
    (tmp_path / "cut.map").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.map"):
        other.load_map(tmp_path / "cut.map")
    flipped = bytearray(data)
    flipped[len(data) // 3] ^= 0x40
    (tmp_path / "flipped.map").write_bytes(bytes(flipped))
    with pytest.raises(ValueError, match="flipped.map.*checksum"):
        other.load_map(tmp_path / "flipped.map")
    other_pyramid = RGBDVSlam(tum.camera, depth_scale_factor=5000, num_levels=4)
    with pytest.raises(ValueError, match="built with 8 pyramid levels"):
        other_pyramid.load_map(good)


def test_verbose_log_and_close(tum, capsys):
    with RGBDVSlam(tum.camera, depth_scale_factor=5000, verbose=3, threaded=False) as vslam:
        for i in range(3):
            vslam.add_frame(tum.load_gray(i), raw_depth(tum, i))
        log = vslam.log_path
    printed = capsys.readouterr().out
    assert "frame 0: map initialised" in printed and str(log) in printed
    text = log.read_text()
    assert text.count("\nframe ") + text.startswith("frame ") == 3
    assert "T_w_c after local BA" in text and "T_w_c before local BA" in text
    assert "initial map: 1 keyframes" in text
    with pytest.raises(RuntimeError, match="closed"):
        vslam.add_frame(tum.load_gray(3), raw_depth(tum, 3))


def test_mono_object_initialises_on_kitti(kitti_mono):
    seq = KittiSequence(kitti_mono)
    vslam = MonoVSlam(seq.camera, max_num_points=2000, frame_rate_hz=10, threaded=False)
    statuses = []
    for i in range(6):
        vslam.add_frame(seq.load_gray(i))
        statuses.append(vslam.check_status())
    assert statuses[0] is TrackingStatus.NOT_INITIALIZED
    assert statuses[-1] in (TrackingStatus.SUCCESSFUL, TrackingStatus.FREQUENT_KEYFRAMES)
    assert vslam.has_new_keyframe() and len(vslam.poses()[0]) >= 2


def test_stereo_object_and_input_errors(kitti_stereo, tum):
    seq = KittiSequence(kitti_stereo)
    vslam = StereoVSlam(seq.camera, seq.baseline_m, max_num_points=2000)
    for i in range(3):
        vslam.add_frame(*seq.load_stereo(i), timestamp=seq.timestamps[i])
    vslam.wait()
    assert vslam.check_status() in (TrackingStatus.SUCCESSFUL, TrackingStatus.FREQUENT_KEYFRAMES)
    left, right = seq.load_stereo(3)
    with pytest.raises(ValueError, match="left and right images differ in size"):
        vslam.add_frame(left, right[:, :-8])
    with pytest.raises(ValueError, match="intrinsics must have no distortion"):
        StereoVSlam(tum.camera, 0.1)
    with pytest.raises(ValueError, match="baseline must be a positive"):
        StereoVSlam(seq.camera, 0.0)
    with pytest.raises(ValueError, match="depth_scale_factor must be positive"):
        RGBDVSlam(tum.camera, depth_scale_factor=-1)
    with pytest.raises(ValueError, match="verbose must be 0, 1, 2 or 3"):
        MonoVSlam(tum.camera, verbose=5)
    with pytest.raises(TypeError, match="intrinsics must be a ferroslam.Camera"):
        MonoVSlam((1, 2, 3, 4))
    rgbd = RGBDVSlam(tum.camera, depth_scale_factor=5000)
    with pytest.raises(ValueError, match="color and depth images differ in size"):
        rgbd.add_frame(tum.load_gray(0), raw_depth(tum, 0)[:-1])


def test_stereo_inertial_static_start_on_euroc(euroc_micro):
    """Static start (issue 11) with the IMU options (MATLAB imuParameters, CameraToIMUTransform,
    NumPosesThreshold, AlignmentFraction) on the real V1_01 micro stereo pair and IMU: the MAV
    stands still for 4.7 s. Before the alignment a keyframe is inserted every 0.25 s
    (ORB-SLAM3), the stereo map keeps its metric scale (fixed to 1, so gravity is observable
    without motion) and the alignment succeeds after 10 keyframes.

    Measured against vicon2gt (its gravity-aligned orientation and its biases, averaged over
    the 95 frames): gyro bias off by 0.0017 rad/s (the bias is 0.080 rad/s; the bound 0.0025
    rad/s is 0.14 deg/s, 3 % of the bias); gravity 0.56 deg, as expected from the
    accelerometer bias the static window cannot separate from gravity (0.08 m/s^2 = 0.47 deg;
    bound 1 deg, the issue's target); velocities at most 2.4 cm/s (truth < 3 mm/s; bound
    5 cm/s); camera centres move at most 0.9 mm from the first while the official ground
    truth moves 3.3 mm (bound 5 mm: no drift beyond the MAV's own jitter)."""
    from ferroslam.datasets import EurocSequence
    from ferroslam.transforms import quat_to_matrix

    seq = EurocSequence(euroc_micro, stereo=True)
    t_imu, gyro, accel = seq.imu()
    common = dict(max_num_points=1200, threaded=False)
    with StereoVSlam(seq.camera, seq.baseline_m, **common) as plain, \
            StereoVSlam(seq.camera, seq.baseline_m, imu=seq.imu_params(),
                        camera_to_imu_transform=seq.T_b_c, num_poses_threshold=10,
                        **common) as inertial:
        previous = -np.inf
        for i in range(len(seq)):
            t = float(seq.timestamps[i])
            left, right = seq.load_stereo(i)
            between = (t_imu > previous) & (t_imu <= t)
            plain.add_frame(left, right, timestamp=t)
            inertial.add_frame(left, right, timestamp=t,
                               imu=(t_imu[between], gyro[between], accel[between]))
            previous = t
        assert plain.inertial_alignment() is None
        status = inertial.inertial_alignment()
        assert status["status"] == "aligned", status
        assert status["scale"] == 1.0 and not status["map_rescaled"]
        assert len(status["keyframe_ids"]) == 9  # 0.9 of 10
        vicon2gt = np.loadtxt(euroc_micro.parent / "V1_01_easy_imu_gt" / "groundtruth_vicon2gt.csv",
                              delimiter=",")
        during = (vicon2gt[:, 0] * 1e-9 >= seq.timestamps[0]) & \
            (vicon2gt[:, 0] * 1e-9 <= seq.timestamps[-1])
        assert during.sum() == len(seq)
        gyro_error = np.linalg.norm(status["gyro_bias"] - vicon2gt[during, 11:14].mean(axis=0))
        qw, qx, qy, qz = vicon2gt[during][0, 4:8]
        R_W_b0 = quat_to_matrix(np.array([qx, qy, qz, qw]))
        # The map's world is the first camera frame.
        gravity_true = seq.T_b_c[:3, :3].T @ R_W_b0.T @ np.array([0.0, 0.0, -9.81])
        g = status["gravity_w"]
        gravity_deg = np.degrees(np.arccos(g @ gravity_true / np.linalg.norm(g) / 9.81))
        speeds = np.linalg.norm(status["velocities"], axis=1)
        _, poses, _ = inertial.frame_trajectory()
        centres = poses[:, :3, 3]
        drift_mm = 1e3 * np.linalg.norm(centres - centres[0], axis=1).max()
        print(f"\nstatic start: gyro bias error {gyro_error:.5f} rad/s, gravity {gravity_deg:.2f} "
              f"deg, speeds <= {speeds.max():.3f} m/s, centres within {drift_mm:.2f} mm")
        assert len(poses) == len(seq)
        assert gyro_error < 0.0025
        assert gravity_deg < 1.0
        assert speeds.max() < 0.05
        assert drift_mm < 5.0
        # Samples must keep moving forward in time; the object stays usable after a refusal.
        with pytest.raises(ValueError, match="is not after the last sample added"):
            inertial.add_frame(left, right, timestamp=previous + 0.05,
                               imu=(t_imu[-3:], gyro[-3:], accel[-3:]))
        assert inertial.num_frames == len(seq)  # the refused frame was not queued
        with pytest.raises(ValueError, match="no IMU"):
            plain.add_frame(left, right, imu=(t_imu[:2], gyro[:2], accel[:2]))
    with pytest.raises(ValueError, match="camera_to_imu_transform"):
        StereoVSlam(seq.camera, seq.baseline_m, imu=seq.imu_params())
