"""Bad input gets a clear error naming the problem, and nothing is lost (issue "Every bad
input gets a clear error"): the cases found by probing every entry point, each of which was
mishandled before (accepted silently, a raw ``cv2.error``, a traceback, a lost result)."""

from __future__ import annotations

import json
import os
import shutil
import warnings

import numpy as np
import pytest
from conftest import require_data

from ferroslam import Camera, MonoVSlam, RGBDVSlam, StereoVSlam
from ferroslam._core import SlamSystem, Vocabulary
from ferroslam.cli import main
from ferroslam.datasets import EurocSequence, TumSequence, open_sequence
from ferroslam.pipeline import imu_batch_end

CAMERA = Camera(500.0, 500.0, 320.0, 240.0)


def _euroc_stereo_inertial(**options):
    seq = open_sequence(require_data("euroc", "V1_01_easy_micro"))
    vslam = StereoVSlam(seq.camera, seq.baseline_m, imu=seq.imu_params(),
                        camera_to_imu_transform=seq.T_b_c, threaded=False, vocabulary=None,
                        **options)
    return seq, vslam


def test_accelerometer_in_centimetres_is_refused_naming_it():
    seq, vslam = _euroc_stereo_inertial()
    t, gyro, accel = seq.imu()
    end = imu_batch_end(t, float(seq.timestamps[0]), 0.005)
    with vslam, pytest.raises(ValueError, match=r"accel.*cm/s\^2"):
        vslam.add_frame(*seq.load_stereo(0), timestamp=seq.timestamps[0],
                        imu=(t[:end], gyro[:end], accel[:end] * 100.0))


def test_imu_samples_long_after_the_frame_are_refused():
    seq, vslam = _euroc_stereo_inertial()
    t, gyro, accel = seq.imu()
    with vslam, pytest.raises(ValueError, match="imu: a sample .* after the frame"):
        vslam.add_frame(*seq.load_stereo(0), timestamp=seq.timestamps[0],
                        imu=(t[:3] + 10.0, gyro[:3], accel[:3]))


def test_a_frame_refused_for_its_timestamp_can_be_retried_with_its_imu_batch():
    seq, vslam = _euroc_stereo_inertial()
    t, gyro, accel = seq.imu()
    period = 1.0 / seq.imu_params().rate_hz
    with vslam:
        first = imu_batch_end(t, float(seq.timestamps[0]), period)
        vslam.add_frame(*seq.load_stereo(0), timestamp=seq.timestamps[0],
                        imu=(t[:first], gyro[:first], accel[:first]))
        second = imu_batch_end(t, float(seq.timestamps[1]), period)
        batch = (t[first:second], gyro[first:second], accel[first:second])
        with pytest.raises(ValueError, match="not after the previous frame"):
            vslam.add_frame(*seq.load_stereo(1), timestamp=seq.timestamps[0], imu=batch)
        vslam.add_frame(*seq.load_stereo(1), timestamp=seq.timestamps[1], imu=batch)
        assert vslam.num_processed == 2


def test_images_of_another_size_than_the_camera_are_refused_naming_both():
    with MonoVSlam(CAMERA, threaded=False, vocabulary=None) as vslam:
        with pytest.raises(ValueError, match="1280x960 .* camera is 640x480"):
            vslam.add_frame(np.zeros((960, 1280), np.uint8))
    tiny = Camera(500.0, 500.0, 2.0, 0.5, width=5, height=1)
    with pytest.raises(ValueError, match="n_levels = 8 .* at most 0 levels"):
        MonoVSlam(tiny, threaded=False, vocabulary=None)


def test_keypoints_outside_the_image_are_refused_by_the_core():
    slam = SlamSystem(500.0, 500.0, 320.0, 240.0, [], 640, 480, sensor="mono")
    keypoints = np.array([[1e9, 10.0, 0, 0.0, 1.0]], np.float32)
    with pytest.raises(ValueError, match=r"outside the camera's 640x480 image"):
        slam.track_mono(0.0, keypoints, np.zeros((1, 32), np.uint8))


def _track_three_keypoints(slam, sensor, colors):
    """One frame of three keypoints with ``colors`` through the sensor's track call."""
    keypoints = np.array([[10.0 * k, 20.0, 0, 0.0, 1.0] for k in range(1, 4)], np.float32)
    descriptors = np.zeros((3, 32), np.uint8)
    if sensor == "mono":
        return slam.track_mono(0.0, keypoints, descriptors, colors=colors)
    if sensor == "rgbd":
        return slam.track_rgbd(0.0, keypoints, descriptors, np.ones(3, np.float32),
                               colors=colors)
    image = [np.zeros((480, 640), np.uint8)]
    return slam.track_stereo(0.0, keypoints, descriptors, image, keypoints, descriptors, image,
                             colors=colors)


@pytest.mark.parametrize("colors, error, match", [
    (np.zeros((2, 3), np.uint8), ValueError,
     r"colors \(2\) and (left_)?keypoints \(3\) must have the same length"),
    (np.zeros((3, 4), np.uint8), ValueError,
     r"colors must have shape \(N, 3\) RGB, got \(3, 4\)"),
    # Wrong dtype or rank is a TypeError naming the argument, as for every array the track
    # calls take (tests/test_core_api.py).
    (np.zeros(9, np.uint8), TypeError,
     r"colors must be a uint8 \(N, 3\) RGB array, got uint8 array of shape \(9,\)"),
    (np.zeros((3, 3), np.float32), TypeError, "colors must be a uint8 .* got float32"),
    ([[0, 0, 0]] * 3, TypeError, "colors must be a uint8 .* got list"),
])
@pytest.mark.parametrize("sensor", ["mono", "rgbd", "stereo"])
@pytest.mark.parametrize("threaded", [False, True])
def test_bad_colors_are_refused_naming_them(colors, error, match, sensor, threaded):
    options = {"baseline": 0.1} if sensor == "stereo" else {}
    slam = SlamSystem(500.0, 500.0, 320.0, 240.0, [], 640, 480, sensor=sensor,
                      threaded=threaded, **options)
    with pytest.raises(error, match=match):
        _track_three_keypoints(slam, sensor, colors)
    # Nothing was taken: the same frame with one colour per keypoint is.
    _track_three_keypoints(slam, sensor, np.zeros((3, 3), np.uint8))
    slam.wait()
    results = slam.take_results()  # threaded mode only: there the result comes later
    assert len(results) == int(threaded) and all(r.state == "not_initialized" for r in results)


def test_a_pyramid_too_deep_for_the_image_is_refused_at_construction():
    with pytest.raises(ValueError, match="extractor.n_levels = 12 with scale_factor 2.*at most 4 levels"):
        MonoVSlam(CAMERA, scale_factor=2.0, num_levels=12)


def test_a_monocular_map_does_not_load_into_an_rgbd_system(tmp_path):
    with MonoVSlam(CAMERA, threaded=False, vocabulary=None) as mono:
        mono.save_map(tmp_path / "mono.map")
    with RGBDVSlam(CAMERA, 5000, threaded=False, vocabulary=None) as rgbd:
        with pytest.raises(ValueError, match=r'"mono" system, this system is "rgbd"'):
            rgbd.load_map(tmp_path / "mono.map")
    other = Camera(520.0, 520.0, 320.0, 240.0)
    with MonoVSlam(other, threaded=False, vocabulary=None) as mono:
        with pytest.raises(ValueError, match="camera fx, fy, cx, cy"):
            mono.load_map(tmp_path / "mono.map")


def test_reset_with_queued_frames_then_wait_processes_them_all():
    seq = TumSequence(require_data("tum", "rgbd_dataset_freiburg1_rpy"))
    with RGBDVSlam(seq.camera, 5000, vocabulary=None) as vslam:
        for i in range(20):
            vslam.add_frame(seq.load_gray(i), (seq.load_depth(i) * 5000).astype(np.uint16),
                            timestamp=seq.timestamps[i])
        vslam.reset()
        vslam.wait()
        assert vslam.num_processed == vslam.num_frames == 20
        assert vslam.is_done()


@pytest.mark.skipif(os.name != "posix", reason="symbolic links")
def test_save_map_never_writes_through_a_planted_partial_link(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / "room.map.partial").symlink_to(victim)
    with MonoVSlam(CAMERA, threaded=False, vocabulary=None) as vslam:
        vslam.save_map(tmp_path / "room.map")
    assert victim.read_text() == "keep me"
    assert (tmp_path / "room.map").stat().st_size > 0


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_vocabulary_load_refuses_devices_at_once():
    with pytest.raises((ValueError, OSError), match="expected a regular vocabulary file"):
        Vocabulary.load("/dev/zero")


@pytest.mark.parametrize("args, name", [
    (("500", 500.0, 320.0, 240.0), "fx"),
    ((500.0, 500.0, 320.0, 240.0, np.zeros(5), 640.7), "width"),
    ((500.0, 500.0, 320.0, 240.0, np.zeros(5), 10**12), "width"),
])
def test_camera_values_of_the_wrong_kind_name_the_field(args, name):
    with pytest.raises((TypeError, ValueError), match=name):
        Camera(*args)


@pytest.mark.parametrize("flag", ["loop_closure", "threaded"])
def test_flags_must_be_booleans(flag):
    with pytest.raises(TypeError, match=flag):
        MonoVSlam(CAMERA, vocabulary=None, **{flag: "no"})


def test_raw_millimetre_depth_with_the_default_scale_warns_about_depth():
    seq = TumSequence(require_data("tum", "rgbd_dataset_freiburg1_rpy"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with RGBDVSlam(seq.camera, threaded=False, vocabulary=None) as vslam:  # factor 1
            for i in range(30):
                raw = (seq.load_depth(i) * 5000).astype(np.uint16)
                vslam.add_frame(seq.load_gray(i), raw, timestamp=seq.timestamps[i])
    depth_warnings = [w for w in caught if "depth_scale_factor" in str(w.message)]
    assert len(depth_warnings) == 1 and depth_warnings[0].category is UserWarning


@pytest.mark.parametrize("config, named", [
    ({"scale_factor": "x"}, "scale_factor"),
    ({"seed": -1}, "seed"),
    ({"n_features": 1e400}, "n_features"),
])
def test_cli_bad_config_values_are_one_line_errors(tmp_path, capsys, config, named):
    spec = tmp_path / "config.json"
    spec.write_text(json.dumps(config))
    path = require_data("tum", "rgbd_dataset_freiburg1_desk")
    code = main(["run", str(path), "--sensor", "rgbd", "--config", str(spec),
                 "--out", str(tmp_path / "out"), "--silent"])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("ferroslam: error:") and named in err
    assert "Traceback" not in err


def test_cli_unwritable_out_is_a_one_line_error(capsys):
    path = require_data("tum", "rgbd_dataset_freiburg1_desk")
    code = main(["run", str(path), "--sensor", "rgbd", "--out", "/proc/version/out",
                 "--silent"])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("ferroslam: error:") and "/proc/version/out" in err


def test_cli_binary_config_names_the_file(tmp_path, capsys):
    spec = tmp_path / "config.json"
    spec.write_bytes(bytes(range(256)))
    path = require_data("tum", "rgbd_dataset_freiburg1_desk")
    assert main(["run", str(path), "--sensor", "rgbd", "--config", str(spec), "--silent"]) == 1
    assert f"{spec}: not UTF-8 text" in capsys.readouterr().err


def test_a_corrupt_image_mid_run_keeps_the_frames_before_it(tmp_path, capsys):
    source = require_data("tum", "rgbd_dataset_freiburg1_rpy")
    seq_dir = tmp_path / "rgbd_dataset_freiburg1_rpy"
    seq_dir.mkdir()
    seq = TumSequence(source)
    frames = seq.frames[:20]
    for name in ("groundtruth.txt",):
        shutil.copy(source / name, seq_dir / name)
    for kind, paths in (("rgb", [f.rgb_path for f in frames]),
                        ("depth", [f.depth_path for f in frames])):
        (seq_dir / kind).mkdir()
        lines = []
        for f, p in zip(frames, paths):
            shutil.copy(p, seq_dir / kind / p.name)
            stamp = f.timestamp if kind == "rgb" else f.depth_timestamp
            lines.append(f"{stamp:.6f} {kind}/{p.name}")
        (seq_dir / f"{kind}.txt").write_text("\n".join(lines) + "\n")
    (seq_dir / "rgb" / frames[15].rgb_path.name).write_bytes(b"not an image")
    out = tmp_path / "out"
    code = main(["run", str(seq_dir), "--sensor", "rgbd", "--out", str(out), "--silent"])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("ferroslam: error: frame 15") and "15 frames" in err
    (partial,) = out.glob("partial-*")  # a failed run's results: beside earlier ones
    assert str(partial) in err
    lines = [l for l in (partial / "trajectory.txt").read_text().splitlines()
             if l and not l.startswith("#")]
    assert len(lines) == 15
    assert json.loads((partial / "results.json").read_text())["frames"] == 15


def test_an_image_of_another_size_mid_sequence_is_refused(tmp_path):
    seq = EurocSequence(require_data("euroc", "V1_01_easy_micro"), stereo=False)

    class OneSmallImage:
        def __getattr__(self, name):
            return getattr(seq, name)

        def __len__(self):
            return 10

        def load_gray(self, i):
            image = seq.load_gray(i)
            return image[::2, ::2].copy() if i == 7 else image

    from ferroslam.pipeline import RunError, run_sequence
    with pytest.raises(RunError, match="frame 7 .*image 7 is 376x240 .* camera is 752x480") as err:
        run_sequence(OneSmallImage(), sensor="mono", progress=False)
    assert err.value.partial.frames == 7


@pytest.mark.parametrize("options, error, named", [
    ({"max_num_points": "abc"}, TypeError, "max_num_points"),
    ({"track_feature_range": (30.7, 100.2)}, TypeError, "track_feature_range"),
    ({"imu": {"rate_hz": 200.0}, "camera_to_imu_transform": np.eye(4),
      "num_poses_threshold": -1}, ValueError, "num_poses_threshold"),
])
def test_vslam_options_of_the_wrong_kind_name_the_option(options, error, named):
    with pytest.raises(error, match=named):
        MonoVSlam(CAMERA, vocabulary=None, **options)


def test_stereo_baseline_as_text_names_it():
    with pytest.raises(TypeError, match="baseline"):
        StereoVSlam(CAMERA, "0.1")


def test_localization_only_needs_a_map():
    slam = SlamSystem(500.0, 500.0, 320.0, 240.0, [], 640, 480, sensor="mono")
    with pytest.raises(ValueError, match="localization_only needs a map"):
        slam.localization_only = True
    assert not slam.localization_only


def test_save_map_to_an_empty_path_or_a_folder_says_so(tmp_path):
    slam = SlamSystem(500.0, 500.0, 320.0, 240.0, [], 640, 480, sensor="mono")
    with pytest.raises(ValueError, match="is empty"):
        slam.save_map("")
    with pytest.raises(ValueError, match="is a folder"):
        slam.save_map(tmp_path)


def test_write_trajectory_refuses_a_pose_that_is_not_rigid(tmp_path):
    from ferroslam.export import write_trajectory

    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, :3] *= 2.0
    with pytest.raises(ValueError, match=r"poses\[1\] is not a rigid transform"):
        write_trajectory(tmp_path / "t.txt", np.array([0.0, 1.0]), poses)


def test_tum_depth_factor_must_be_a_positive_number():
    with pytest.raises(ValueError, match="depth_factor"):
        TumSequence(require_data("tum", "rgbd_dataset_freiburg1_desk"), depth_factor=float("nan"))


def test_eval_max_diff_must_not_be_negative(capsys):
    from ferroslam.metrics import associate

    with pytest.raises(ValueError, match="max_diff must be a number of seconds >= 0"):
        associate(np.arange(3.0), np.arange(3.0), max_diff=-1)
    with pytest.raises(SystemExit):
        main(["eval", "ate", "a.txt", "b.txt", "--max-diff", "-1"])
    assert "--max-diff: must be a number of seconds >= 0" in capsys.readouterr().err


class _with_gyro:
    """``seq`` whose IMU gyroscope readings are ``change(gyro)``."""

    def __init__(self, seq, change):
        self._seq, self._change = seq, change

    def __getattr__(self, name):
        return getattr(self._seq, name)

    def __len__(self):
        return len(self._seq)

    def imu(self):
        t, gyro, accel = self._seq.imu()
        return t, self._change(gyro), accel


def test_a_constant_gyro_never_aligns_and_the_reason_names_the_gyroscope():
    """A gyro stuck at 3 rad/s passes the unit checks (under 35 rad/s) but no alignment can
    match it to the rotation vision sees: it used to report "aligned" with absurd states."""
    from ferroslam.pipeline import run_sequence

    seq = open_sequence(require_data("euroc", "MH_01_easy_window"))

    stuck = _with_gyro(seq, lambda gyro: np.tile([0.0, 0.0, 3.0], (len(gyro), 1)))
    result = run_sequence(stuck, sensor="stereo-inertial", max_frames=150,
                          progress=False)
    assert result.inertial["status"] == "failed", result.inertial
    assert result.inertial["reason"].startswith("gyroscope"), result.inertial["reason"]


def test_tiny_images_are_a_value_error_not_a_cv2_error():
    from ferroslam.features import OrbExtractor

    with pytest.raises(ValueError, match="image 5x1 is too small for 8 pyramid levels"):
        OrbExtractor().detect(np.zeros((1, 5), np.uint8))


def test_match_stereo_refuses_pyramids_of_different_sizes():
    from ferroslam._core import match_stereo

    none = np.zeros((0, 5), np.float32), np.zeros((0, 32), np.uint8)
    with pytest.raises(ValueError,
                       match=r"left_pyramid\[0\] is 640x480 but right_pyramid\[0\] is 320x240"):
        match_stereo(*none, [np.zeros((480, 640), np.uint8)], *none,
                     [np.zeros((240, 320), np.uint8)], fx=500.0, baseline=0.1)


def test_orb_extractor_names_a_negative_setting():
    from ferroslam._core import OrbExtractor

    with pytest.raises(ValueError, match="n_levels = -5 is out of range"):
        OrbExtractor(n_levels=-5)


def test_plot_to_a_path_under_a_file_names_the_path(tmp_path):
    from ferroslam.plot import plot_map

    (tmp_path / "file").write_text("")
    with pytest.raises(OSError, match="cannot write the plot to .*file/map.png"):
        plot_map(np.zeros((3, 3)), np.tile(np.eye(4), (2, 1, 1)),
                 path=tmp_path / "file" / "map.png")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_threaded_system_refuses_work_in_a_forked_child():
    slam = SlamSystem(500.0, 500.0, 320.0, 240.0, [], 640, 480, sensor="mono", threaded=True)
    pid = os.fork()
    if pid == 0:  # the child: must raise at once, not wait for threads it does not have
        code = 1
        try:
            slam.wait()
        except RuntimeError as err:
            code = 0 if "forked" in str(err) or "fork of it" in str(err) else 2
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    slam.wait()  # the parent's threads still work


def test_a_second_thread_calling_in_is_told_the_system_is_not_thread_safe():
    import threading
    import time

    from ferroslam.features import OrbExtractor, sample_depth

    seq = TumSequence(require_data("tum", "rgbd_dataset_freiburg1_rpy"))
    orb = OrbExtractor()
    frames = []
    for i in range(60):
        kp, desc = orb.detect(seq.load_gray(i))
        frames.append((seq.timestamps[i], kp, desc, sample_depth(seq.load_depth(i), kp)))
    cam = seq.camera
    slam = SlamSystem(cam.fx, cam.fy, cam.cx, cam.cy, cam.dist, cam.width, cam.height,
                      sensor="rgbd", threaded=True)
    for frame in frames:
        slam.track_rgbd(*frame)
    waiter = threading.Thread(target=slam.wait)
    waiter.start()
    time.sleep(0.02)
    try:
        with pytest.raises(RuntimeError, match="in use by another thread: it is not thread-safe"):
            for _ in range(200):  # until the wait is seen holding the system
                slam.state
                time.sleep(0.001)
    finally:
        waiter.join()
    assert slam.state == "ok"


def test_complex_or_boolean_depth_is_refused():
    with RGBDVSlam(CAMERA, 5000, threaded=False, vocabulary=None) as vslam:
        image = np.zeros((480, 640), np.uint8)
        for depth in (np.zeros((480, 640), complex), np.zeros((480, 640), bool)):
            with pytest.raises(ValueError, match="depth must be an integer or float image"):
                vslam.add_frame(image, depth)


def test_an_imu_batch_of_two_arrays_names_imu():
    seq, vslam = _euroc_stereo_inertial()
    t, gyro, _ = seq.imu()
    with vslam, pytest.raises(ValueError, match=r"imu must be \(timestamps"):
        vslam.add_frame(*seq.load_stereo(0), timestamp=seq.timestamps[0], imu=(t[:2], gyro[:2]))


@pytest.mark.parametrize("argv", [
    ["vocab", "export-dbow2", "/proc/version/voc.txt"],
    ["demo", "--max-frames", "2", "--silent", "--out", "/proc/version/demo"],
    ["download", "tum", "freiburg1_xyz", "--to", "/proc/version/data", "--silent"],
])
def test_cli_unwritable_outputs_are_one_line_errors(argv, capsys):
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("ferroslam: error:") and "/proc/version" in err
    assert "Traceback" not in err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_vocabulary_load_refuses_a_fifo_without_blocking(tmp_path):
    fifo = tmp_path / "voc.fifo"
    os.mkfifo(fifo)
    with pytest.raises((ValueError, OSError), match="expected a regular vocabulary file"):
        Vocabulary.load(str(fifo))


def test_a_gyroscope_in_degrees_during_slow_motion_does_not_align():
    """Standing still, a gyro in deg/s reads about 4.6 (the bias x 57), under the 35 rad/s
    the unit check catches: the alignment must refuse, naming the gyroscope."""
    from ferroslam.pipeline import run_sequence

    seq = open_sequence(require_data("euroc", "V1_01_easy_micro"))

    result = run_sequence(_with_gyro(seq, np.degrees), {"num_poses_threshold": 10}, sensor="stereo-inertial",
                          progress=False)
    assert result.inertial["status"] == "failed", result.inertial
    assert result.inertial["reason"].startswith("gyroscope"), result.inertial["reason"]


def test_a_bad_ground_truth_line_keeps_every_result(tmp_path, capsys):
    """Ground truth is read after tracking: a bad line used to leave --out empty."""
    source = require_data("tum", "rgbd_dataset_freiburg1_desk")
    seq_dir = tmp_path / "rgbd_dataset_freiburg1_desk"
    shutil.copytree(source, seq_dir)
    with open(seq_dir / "groundtruth.txt", "a", encoding="utf-8") as f:
        f.write("1305031454.0 not a pose\n")
    out = tmp_path / "out"
    code = main(["run", str(seq_dir), "--sensor", "rgbd", "--out", str(out), "--silent"])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("ferroslam: error: ground truth")
    (partial,) = out.glob("partial-*")  # a failed run's results: beside earlier ones
    lines = [l for l in (partial / "trajectory.txt").read_text().splitlines()
             if l and not l.startswith("#")]
    assert len(lines) == 9
