"""EuRoC (ASL layout) loader and stereo rectification on the real micro excerpt, and errors on
small fake layouts."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from conftest import require_data
from ferroslam.datasets import EurocSequence, open_sequence, read_sensor_yaml
from ferroslam.datasets.images import read_gray
from ferroslam.transforms import quat_to_matrix


@pytest.fixture(scope="module")
def micro():
    return require_data("euroc", "V1_01_easy_micro")


@pytest.fixture(scope="module")
def seq(micro):
    return open_sequence(micro)


def _orb_row_error(left, right):
    """Median |y_left - y_right| of cross-checked ORB matches with a plausible disparity."""
    orb = cv2.ORB_create(1000)
    k1, d1 = orb.detectAndCompute(left, None)
    k2, d2 = orb.detectAndCompute(right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    a = np.array([k1[m.queryIdx].pt for m in matches])
    b = np.array([k2[m.trainIdx].pt for m in matches])
    keep = (a[:, 0] - b[:, 0] > 0) & (a[:, 0] - b[:, 0] < 150)
    assert keep.sum() > 100
    return float(np.median(np.abs(a[keep, 1] - b[keep, 1])))


def _flow_row_error(left, right):
    """Median |y_left - y_right| of sub-pixel LK tracks (forward-backward checked)."""
    p = cv2.goodFeaturesToTrack(left, 500, 0.01, 10)
    q, ok, _ = cv2.calcOpticalFlowPyrLK(left, right, p, None, winSize=(21, 21), maxLevel=3)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(right, left, q, None, winSize=(21, 21), maxLevel=3)
    p, q, back = p.reshape(-1, 2), q.reshape(-1, 2), back.reshape(-1, 2)
    keep = (ok.ravel() == 1) & (ok_back.ravel() == 1) & (np.linalg.norm(back - p, axis=1) < 0.5)
    assert keep.sum() > 100
    return float(np.median(np.abs(p[keep, 1] - q[keep, 1])))


def test_stereo_sequence(seq, micro):
    assert isinstance(seq, EurocSequence) and seq.is_stereo and seq.name == "V1_01_easy_micro"
    assert len(seq) == 95 and len(list(seq)) == 95
    assert seq.timestamps_ns[0] == 1403715273262142976
    assert seq[0].timestamp_ns == seq.timestamps_ns[0]
    assert seq.timestamps.dtype == np.float64 and np.all(np.diff(seq.timestamps) > 0)
    assert seq.timestamps[-1] - seq.timestamps[0] == pytest.approx(4.70, abs=1e-6)
    assert seq.baseline_m == pytest.approx(0.1101, abs=5e-4)
    cam = seq.camera
    assert (cam.width, cam.height) == (752, 480) and not cam.dist.any() and cam.fx == cam.fy
    left, right = seq.load_stereo(0)
    assert left.dtype == right.dtype == np.uint8 and left.shape == right.shape == (480, 752)
    np.testing.assert_array_equal(seq.load_gray(0), left)
    # mav0 itself opens the same sequence
    assert EurocSequence(micro / "mav0").name == "V1_01_easy_micro"


def test_rectification_aligns_rows(seq, capsys):
    for i in (0, 94):
        left, right = seq.load_stereo(i)
        raw = read_gray(seq[i].left_path), read_gray(seq[i].right_path)
        orb_rect, orb_raw = _orb_row_error(left, right), _orb_row_error(*raw)
        flow_rect, flow_raw = _flow_row_error(left, right), _flow_row_error(*raw)
        with capsys.disabled():
            print(f"\nframe {i}: median |dy| ORB raw {orb_raw:.2f} -> rectified {orb_rect:.2f} px, "
                  f"LK raw {flow_raw:.3f} -> rectified {flow_rect:.3f} px")
        assert orb_rect < 0.5 and flow_rect < 0.25
        assert orb_raw > 5.0 and flow_raw > 5.0


def test_rectifier_geometry(seq):
    """Points seen by both raw cameras land on one rectified row with disparity fx*b/z."""
    rect = seq.rectifier
    cam0, cam1 = seq.raw_cameras
    T_c1_c0 = np.linalg.inv(seq.T_b_cam1) @ seq.T_b_cam0
    rng = np.random.default_rng(0)
    p0 = np.column_stack(
        [rng.uniform(-1, 1, 50), rng.uniform(-0.7, 0.7, 50), rng.uniform(2, 8, 50)]
    )
    p1 = p0 @ T_c1_c0[:3, :3].T + T_c1_c0[:3, 3]

    def raw_pixels(p, cam):
        return cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].reshape(-1, 2)

    K = rect.camera.K
    P2 = np.hstack([K, [[-K[0, 0] * rect.baseline_m], [0], [0]]])
    uv_l = cv2.undistortPoints(raw_pixels(p0, cam0), cam0.K, cam0.dist, R=rect.R1, P=K)
    uv_r = cv2.undistortPoints(raw_pixels(p1, cam1), cam1.K, cam1.dist, R=rect.R2, P=P2)
    uv_l, uv_r = uv_l.reshape(-1, 2), uv_r.reshape(-1, 2)
    p_rect = p0 @ rect.R1.T  # p_rect = R1 @ p_raw_left
    expected = p_rect[:, :2] / p_rect[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    np.testing.assert_allclose(uv_l, expected, atol=1e-3)
    np.testing.assert_allclose(uv_r[:, 1], uv_l[:, 1], atol=1e-3)
    np.testing.assert_allclose(uv_l[:, 0] - uv_r[:, 0], K[0, 0] * rect.baseline_m / p_rect[:, 2],
                               atol=1e-3)


def test_groundtruth_is_of_the_returned_camera(seq, micro):
    t, T = seq.groundtruth()
    assert t.shape == (95,) and T.shape == (95, 4, 4)
    assert abs(t[0] - seq.timestamps[0]) < 1e-6
    assert np.linalg.norm(T[-1, :3, 3] - T[0, :3, 3]) < 0.01  # the MAV stands still
    np.testing.assert_allclose(T[:, :3, :3] @ np.swapaxes(T[:, :3, :3], 1, 2),
                               np.broadcast_to(np.eye(3), (95, 3, 3)), atol=1e-6)
    mono = EurocSequence(micro, stereo=False)
    t_mono, T_mono = mono.groundtruth()
    np.testing.assert_array_equal(t_mono, t)
    np.testing.assert_allclose(T, T_mono @ seq.rectifier.T_left_rect, atol=1e-12)
    # first row of the file: p_RS_R and q_RS in w, x, y, z order; T_w_c = T_w_b @ T_b_cam0
    T_w_b = np.eye(4)
    T_w_b[:3, :3] = quat_to_matrix([-0.824237, -0.106942, -0.551702, 0.069433])  # x y z w
    T_w_b[:3, 3] = (0.878895, 2.1834, 0.948427)
    np.testing.assert_allclose(T_mono[0], T_w_b @ seq.T_b_cam0, atol=1e-12)


def test_mono_sequence(micro):
    mono = EurocSequence(micro, stereo=False)
    assert not mono.is_stereo and mono.baseline_m is None and mono.rectifier is None
    assert mono.camera.fx == 458.654 and mono.camera.dist[0] == pytest.approx(-0.28340811)
    assert mono.camera.dist[4] == 0.0
    np.testing.assert_array_equal(mono.load_gray(5), read_gray(mono[5].left_path))
    with pytest.raises(ValueError, match="stereo=False"):
        mono.load_stereo(0)


def test_imu(seq):
    t, gyro, acc = seq.imu()
    assert t.shape == (942,) and gyro.shape == acc.shape == (942, 3)
    assert np.all(np.diff(t) > 0) and t[0] == seq.timestamps[0]
    assert np.linalg.norm(acc.mean(0)) == pytest.approx(9.78, abs=0.01)
    assert np.linalg.norm(gyro.mean(0)) < 0.1
    params = seq.imu_params()
    assert params.gyroscope_noise_density == 1.6968e-4 and params.rate_hz == 200.0
    assert params.accelerometer_random_walk == 3.0e-3
    np.testing.assert_array_equal(params.T_b_imu, np.eye(4))


def test_sensor_yaml_parser(micro, tmp_path):
    yaml = read_sensor_yaml(micro / "mav0" / "cam1" / "sensor.yaml")
    assert yaml["intrinsics"] == [457.587, 456.134, 379.999, 255.238]
    assert yaml["resolution"] == [752, 480] and yaml["camera_model"] == "pinhole"
    assert len(yaml["T_BS"]["data"]) == 16 and yaml["T_BS"]["rows"] == 4
    bad = tmp_path / "sensor.yaml"
    bad.write_text("intrinsics: [1, 2,\n  3, 4\n")
    with pytest.raises(ValueError, match="sensor.yaml:1: unterminated list"):
        read_sensor_yaml(bad)


# --- errors, on a tiny fake layout (real sensor.yaml files, three frames) ------------------

_NS = [1403715273262142976, 1403715273312143104, 1403715273362142976]


def _fake(micro, root, left=_NS, right=_NS):
    mav0 = root / "mav0"
    for sensor, stamps in (("cam0", left), ("cam1", right)):
        (mav0 / sensor / "data").mkdir(parents=True)
        shutil.copy(micro / "mav0" / sensor / "sensor.yaml", mav0 / sensor)
        rows = "".join(f"{t},{t}.png\n" for t in stamps)
        (mav0 / sensor / "data.csv").write_text("#timestamp [ns],filename\n" + rows)
    (mav0 / "imu0").mkdir()
    shutil.copy(micro / "mav0" / "imu0" / "sensor.yaml", mav0 / "imu0")
    return root


def test_unpaired_stereo_timestamps(micro, tmp_path):
    root = _fake(micro, tmp_path / "seq", right=[_NS[0], _NS[1], _NS[2] + 1])
    with pytest.raises(ValueError, match=f"only in cam0 .*{_NS[2]}.*only in cam1: .{_NS[2] + 1}"):
        EurocSequence(root)
    assert len(EurocSequence(root, stereo=False)) == 3  # cam1 is not read


def test_out_of_order_timestamps(micro, tmp_path):
    root = _fake(micro, tmp_path / "seq", left=[_NS[0], _NS[2], _NS[1]])
    with pytest.raises(ValueError, match=r"cam0/data.csv:4: timestamps out of order"):
        EurocSequence(root)
    root_ok = _fake(micro, tmp_path / "ok")
    (root_ok / "mav0" / "imu0" / "data.csv").write_text("2,0,0,0,0,0,9.8\n1,0,0,0,0,0,9.8\n")
    with pytest.raises(ValueError, match=r"imu0/data.csv:2: timestamps out of order"):
        EurocSequence(root_ok).imu()


def test_missing_files_are_named(micro, tmp_path):
    root = _fake(micro, tmp_path / "seq")
    seq = EurocSequence(root)
    assert not seq.has_groundtruth
    with pytest.raises(FileNotFoundError, match="state_groundtruth_estimate0/data.csv"):
        seq.groundtruth()
    with pytest.raises(FileNotFoundError, match="imu0/data.csv"):
        seq.imu()
    (root / "mav0" / "cam1" / "sensor.yaml").unlink()
    with pytest.raises(FileNotFoundError, match="cam1/sensor.yaml"):
        EurocSequence(root)
    (root / "mav0" / "cam0" / "data.csv").unlink()
    with pytest.raises(FileNotFoundError, match="cam0/data.csv"):
        EurocSequence(root, stereo=False)


def test_wrong_image_size(micro, tmp_path):
    root = _fake(micro, tmp_path / "seq")
    for cam in ("cam0", "cam1"):
        image = root / "mav0" / cam / "data" / f"{_NS[0]}.png"
        cv2.imwrite(str(image), np.zeros((10, 12), np.uint8))
    seq = open_sequence(root)
    assert isinstance(seq, EurocSequence)
    with pytest.raises(ValueError, match="is 12x10, sensor.yaml says 752x480"):
        seq.load_stereo(0)
