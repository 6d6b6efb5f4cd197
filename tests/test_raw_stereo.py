"""Raw stereo rigs: ``StereoVSlam.from_raw`` (rectification inside), ``open_sequence(path,
rectify=False)`` and ``StereoRectifier`` for Kannala-Brandt (fisheye) pairs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import require_data
from ferroslam import Camera
from ferroslam.datasets import EurocSequence, open_sequence
from ferroslam.metrics import ate
from ferroslam.pipeline import run_sequence
from ferroslam.stereo import StereoRectifier
from ferroslam.trajectory import Trajectory
from ferroslam.vslam import StereoVSlam

MH_01 = ("euroc", "MH_01_easy_window")
# TUM-VI 512 cam0 and cam1 (Kannala-Brandt, about 195 degrees).
TUM_VI_LEFT = Camera.kannala_brandt(
    190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504,
    [0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
     0.00020293673591811182], 512, 512)
TUM_VI_RIGHT = Camera.kannala_brandt(
    190.44236969414825, 190.4344384721956, 252.59949716835982, 254.91723064636983,
    [0.0034003170790442797, 0.001766278153469831, -0.00266312569781606,
     0.0003299517423931039], 512, 512)


def _rig(rotation_rad=(0.01, -0.02, 0.015), t=(0.1, 0.002, -0.001)) -> np.ndarray:
    """``T_left_right``: the right camera 10 cm along +x, slightly turned."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array(rotation_rad, dtype=np.float64))[0]
    T[:3, 3] = t
    return T


@pytest.fixture(scope="module")
def mh01_raw():
    return open_sequence(require_data(*MH_01), rectify=False)


def test_raw_euroc_sequence(mh01_raw):
    seq = mh01_raw
    assert isinstance(seq, EurocSequence) and seq.is_stereo and not seq.is_rectified
    assert seq.rectifier is None and "rectify=False" in repr(seq)
    assert seq.left_camera.model == "pinhole" and np.any(seq.left_camera.dist != 0)
    assert seq.camera is seq.left_camera
    np.testing.assert_allclose(seq.T_left_right, np.linalg.inv(seq.T_b_cam0) @ seq.T_b_cam1)
    np.testing.assert_array_equal(seq.T_b_c, seq.T_b_cam0)
    rectified = open_sequence(require_data(*MH_01))
    assert rectified.is_rectified and rectified.rectifier is not None
    assert seq.baseline_m == pytest.approx(rectified.baseline_m, abs=1e-9)
    # Raw pairs as on disk; rectifying them gives what the rectified sequence loads.
    left, right = seq.load_stereo(3)
    np.testing.assert_array_equal(left, cv2.imread(str(seq[3].left_path), cv2.IMREAD_GRAYSCALE))
    for a, b in zip(rectified.rectifier.rectify(left, right), rectified.load_stereo(3)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(seq.load_gray(3), left)
    # Ground truth of the raw left camera; positions equal the rectified frame's.
    _, T_raw = seq.groundtruth()
    _, T_rect = rectified.groundtruth()
    np.testing.assert_allclose(T_raw @ rectified.rectifier.T_left_rect, T_rect, atol=1e-12)
    # run_sequence wants rectified pairs and says what to do with raw ones.
    with pytest.raises(ValueError, match="rectify=False.*StereoVSlam.from_raw"):
        run_sequence(seq, sensor="stereo", progress=False)


def test_rectify_false_is_for_euroc_only():
    with pytest.raises(ValueError, match="rectify=False is for raw EuRoC stereo pairs; kitti"):
        open_sequence(require_data("kitti", "stereo_51_frames"), rectify=False)


def test_mh01_raw_through_from_raw_tracks_every_frame(mh01_raw):
    """The MH_01 window, raw pairs into StereoVSlam.from_raw: 400/400 and ATE <= 5 mm, as the
    rectified run (mh01_stereo in test_real_data_matrix.py: 400/400, 4.2 mm)."""
    seq = mh01_raw
    vslam = StereoVSlam.from_raw(seq.left_camera, seq.right_camera, seq.T_left_right,
                                 threaded=False)
    with vslam:
        np.testing.assert_allclose(vslam.T_left_rect,
                                   open_sequence(require_data(*MH_01)).rectifier.T_left_rect)
        for i in range(len(seq)):
            vslam.add_frame(*seq.load_stereo(i), timestamp=float(seq.timestamps[i]))
        stamps, T_w_rect, _ = vslam.frame_trajectory()
    # Poses are the rectified left camera's: ground truth T_w_b @ T_b_cam0 @ T_left_rect.
    gt_stamps, T_w_left = seq.groundtruth()
    gt = Trajectory(gt_stamps, T_w_left @ vslam.T_left_rect)
    result = ate(gt, Trajectory(stamps, T_w_rect), align="se3")
    print(f"MH_01 from_raw: {len(stamps)}/{len(seq)} tracked, ATE {result.rmse * 100:.2f} cm "
          f"over {result.pairs} pairs")
    assert len(stamps) == len(seq) == 400
    assert result.pairs == 400
    assert result.rmse <= 0.005


def test_fisheye_pair_rectifies_to_shared_rows_and_true_depth():
    """Synthetic points projected with Camera.project into both raw fisheye images land on
    one row after rectification, and the disparity gives their depth."""
    T_left_right = _rig()
    rectifier = StereoRectifier(TUM_VI_LEFT, TUM_VI_RIGHT, T_left_right)
    camera = rectifier.camera
    assert camera.model == "pinhole" and np.all(camera.dist == 0)
    assert camera.fx == pytest.approx(min(TUM_VI_LEFT.fx, TUM_VI_RIGHT.fy, TUM_VI_RIGHT.fx))
    assert rectifier.baseline_m == pytest.approx(np.linalg.norm(T_left_right[:3, 3]), rel=1e-9)
    # Points in front of the rectified camera, inside its image.
    rng = np.random.default_rng(3)
    n = 400
    u = rng.uniform(20, camera.width - 20, n)
    v = rng.uniform(20, camera.height - 20, n)
    z = rng.uniform(0.5, 8.0, n)
    p_rect = np.stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z], 1)
    p_left = p_rect @ rectifier.R1  # R1^T p_rect
    T_right_left = np.linalg.inv(T_left_right)
    p_right = p_left @ T_right_left[:3, :3].T + T_right_left[:3, 3]
    raw_left, raw_right = TUM_VI_LEFT.project(p_left), TUM_VI_RIGHT.project(p_right)
    keep = np.all(np.isfinite(raw_right), axis=1)
    assert keep.sum() > 0.9 * n
    left = rectifier.rectify_points(raw_left[keep], "left")
    right = rectifier.rectify_points(raw_right[keep], "right")
    rows = np.abs(left[:, 1] - right[:, 1]).max()
    np.testing.assert_allclose(left, np.stack([u, v], 1)[keep], atol=1e-6)
    depth = camera.fx * rectifier.baseline_m / (left[:, 0] - right[:, 0])
    depth_error = np.abs(depth / z[keep] - 1).max()
    print(f"fisheye rectification: rows within {rows:.1e} px, depth within {depth_error:.1e}")
    assert rows <= 0.5
    assert depth_error <= 1e-6
    # The image maps agree with the point-wise rectification: each rectified pixel samples
    # the raw pixel that rectifies back onto it (maps in 1/32 px fixed point).
    h, w = camera.height, camera.width
    raw_u, raw_v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    for side, index in (("left", 0), ("right", 1)):
        sampled_u = rectifier._remap(raw_u, index)
        sampled_v = rectifier._remap(raw_v, index)
        r, c = rng.integers(40, h - 40, 200), rng.integers(40, w - 40, 200)
        raw = np.stack([sampled_u[r, c], sampled_v[r, c]], 1).astype(np.float64)
        back = rectifier.rectify_points(raw, side)
        assert np.abs(back - np.stack([c, r], 1)).max() < 0.1, side


def test_fisheye_pair_through_from_raw():
    """from_raw with two Kannala-Brandt cameras: rectified pinhole intrinsics, raw frames."""
    vslam = StereoVSlam.from_raw(TUM_VI_LEFT, TUM_VI_RIGHT, _rig(), threaded=False)
    with vslam:
        assert vslam.intrinsics == vslam.rectifier.camera
        assert vslam.baseline == pytest.approx(vslam.rectifier.baseline_m)
        image = np.zeros((512, 512), np.uint8)
        vslam.add_frame(image, image, timestamp=0.0)
        assert vslam.num_frames == 1
        with pytest.raises(ValueError, match="left image is 640x480"):
            vslam.add_frame(np.zeros((480, 640), np.uint8), np.zeros((480, 640), np.uint8))


def test_imu_transform_moves_to_the_rectified_camera(monkeypatch):
    import ferroslam.vslam as vslam_module

    seen = {}
    session = vslam_module.Session

    def capture(*args, **kwargs):
        seen["T_b_c"] = kwargs["T_b_c"]
        return session(*args, **kwargs)

    monkeypatch.setattr(vslam_module, "Session", capture)
    T_b_left = _rig((0.3, 0.1, -0.2), (0.05, -0.02, 0.01))
    pinhole = Camera(458.654, 457.296, 367.215, 248.375,
                     [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0], 752, 480)
    imu = dict(gyroscope_noise_density=1.7e-4, gyroscope_random_walk=1.9e-5,
               accelerometer_noise_density=2e-3, accelerometer_random_walk=3e-3, rate_hz=200.0)
    right = _rig((0.01, 0.0, 0.0), (0.11, 0.0, 0.0))
    vslam = StereoVSlam.from_raw(pinhole, pinhole, right, threaded=False, imu=imu,
                                 camera_to_imu_transform=T_b_left)
    with vslam:
        assert not np.allclose(vslam.T_left_rect, np.eye(4))
        np.testing.assert_allclose(seen["T_b_c"], T_b_left @ vslam.T_left_rect)


@pytest.mark.parametrize("T, message", [
    (np.eye(3), r"T_left_right must be a finite \(4, 4\) pose, got shape \(3, 3\)"),
    (np.full((4, 4), np.nan), r"T_left_right must be a finite \(4, 4\) pose"),
    (np.diag([2.0, 1.0, 1.0, 1.0]), r"T_left_right is not a rigid transform"),
    (np.eye(4), r"T_left_right has a zero baseline"),
    (_rig((0, 0, 0), (-0.1, 0, 0)), r"right camera on the \+x side.*\(T_left_right\)"),
    # The finding of issue 53: a raw rig rotated 180 degrees about y "tracked".
    (_rig((0, np.pi, 0), (0.1, 0, 0)), r"T_left_right turns the right camera 180 degrees away"),
    (_rig((0, 0.55 * np.pi, 0), (0.1, 0, 0)), r"turns the right camera 99 degrees away"),
    ("abc", r"T_left_right must be a \(4, 4\) rigid transform"),
])
def test_from_raw_refuses_a_bad_rig(T, message):
    with pytest.raises(ValueError, match=message):
        StereoVSlam.from_raw(TUM_VI_LEFT, TUM_VI_RIGHT, T)


def test_from_raw_refuses_a_vertical_pinhole_rig():
    # (cv2.fisheye.stereoRectify rolls a vertical fisheye rig into a horizontal one.)
    pinhole = Camera(458.654, 457.296, 367.215, 248.375, np.zeros(5), 752, 480)
    with pytest.raises(ValueError, match=r"horizontal stereo rig.*\(T_left_right\)"):
        StereoVSlam.from_raw(pinhole, pinhole, _rig((0, 0, 0), (0, 0.1, 0)))


def test_from_raw_refuses_mismatched_cameras():
    pinhole = Camera(190.0, 190.0, 256.0, 256.0, np.zeros(5), 512, 512)
    with pytest.raises(ValueError, match="stereo cameras differ in model: kannala_brandt vs "
                                         "pinhole"):
        StereoVSlam.from_raw(TUM_VI_LEFT, pinhole, _rig())
    small = Camera(190.0, 190.0, 256.0, 256.0, np.zeros(5), 640, 480)
    with pytest.raises(ValueError, match="stereo cameras differ in image size"):
        StereoVSlam.from_raw(pinhole, small, _rig())
    with pytest.raises(TypeError, match="right_camera must be a ferroslam.Camera"):
        StereoVSlam.from_raw(pinhole, "cam1.yaml", _rig())
    # The constructor still wants rectified intrinsics, and says where raw cameras go.
    with pytest.raises(ValueError, match="StereoVSlam.from_raw"):
        StereoVSlam(TUM_VI_LEFT, 0.1)
