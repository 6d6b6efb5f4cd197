"""ferroslam.load_calibration on the calibration files users have: ORB-SLAM3 settings (1.0 and
legacy), flat camera.yaml, Kalibr camchain and IMU files, OpenCV FileStorage and ROS
camera_info, checked against the real EuRoC sensor.yaml files where they describe the same
sensor."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
import yaml

from conftest import require_data
from ferroslam import Calibration, Camera, Rig, load_calibration
from ferroslam.calibration import load_imu_params
from ferroslam.calibration import read_camera_yaml
from ferroslam.datasets import EurocSequence

# EuRoC cam0 / cam1 as in mav0/cam*/sensor.yaml.
CAM0 = (458.654, 457.296, 367.215, 248.375)
DIST0 = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
CAM1 = (457.587, 456.134, 379.999, 255.238)
DIST1 = [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05, 0.0]
# T_BS of cam0 (the IMU is EuRoC's body frame), as ORB-SLAM3's EuRoC settings write it.
T_BS0 = """[0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]"""
IMU_NOISE = """IMU.NoiseGyro: 1.6968e-04
IMU.NoiseAcc: 2.0e-3
IMU.GyroWalk: 1.9393e-05
IMU.AccWalk: 3.0e-03
IMU.Frequency: 200.0
"""

ORBSLAM3_STEREO_INERTIAL = f"""%YAML:1.0
File.version: "1.0"
Camera.type: "PinHole"
Camera1.fx: 458.654
Camera1.fy: 457.296
Camera1.cx: 367.215
Camera1.cy: 248.375
Camera1.k1: -0.28340811
Camera1.k2: 0.07395907
Camera1.p1: 0.00019359
Camera1.p2: 1.76187114e-05
Camera2.fx: 457.587
Camera2.fy: 456.134
Camera2.cx: 379.999
Camera2.cy: 255.238
Camera2.k1: -0.28368365
Camera2.k2: 0.07451284
Camera2.p1: -0.00010473
Camera2.p2: -3.55590700e-05
Camera.width: 752
Camera.height: 480
Camera.fps: 20
Camera.RGB: 1
Stereo.ThDepth: 60.0
Stereo.T_c1_c2: !!opencv-matrix
  rows: 4
  cols: 4
  dt: f
  data: [0.9999972564777967, -0.0023171357232751057, -0.0003433931206204861, 0.11007413780047799,
         0.0023120671924322465, 0.9998980485071031, -0.014090668452683376, -0.00015661205439167214,
         0.00037600810231955327, 0.01408983584669108, 0.9999006626380811, 0.0008893827854321804,
         0.0, 0.0, 0.0, 1.0]
IMU.T_b_c1: !!opencv-matrix
  rows: 4
  cols: 4
  dt: f
  data: {T_BS0}
{IMU_NOISE}
ORBextractor.nFeatures: 1200
"""

ORBSLAM_LEGACY_MONO_INERTIAL = f"""%YAML:1.0
Camera.type: "PinHole"
Camera.fx: 458.654
Camera.fy: 457.296
Camera.cx: 367.215
Camera.cy: 248.375
Camera.k1: -0.28340811
Camera.k2: 0.07395907
Camera.p1: 0.00019359
Camera.p2: 1.76187114e-05
Camera.width: 752
Camera.height: 480
Camera.fps: 20.0
Tbc: !!opencv-matrix
   rows: 4
   cols: 4
   dt: f
   data: {T_BS0}
{IMU_NOISE}"""

# Kalibr's EuRoC camchain: T_cam_imu = inv(T_BS), cam1.T_cn_cnm1 = T_c1_c0.
KALIBR_CAMCHAIN = """cam0:
  T_cam_imu:
    - [0.01486554298179427, 0.9995572490083462, -0.02577443669744028, 0.06522290953553112]
    - [-0.9998809296985752, 0.01496721332471924, 0.0037561883579669726, -0.02070638549271943]
    - [0.004140296794224038, 0.025715529947966016, 0.9996607271779023, -0.008054602460029517]
    - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cam_imu:
    - [0.012555267089102958, 0.999598781151433, -0.025389800891746528, -0.04490198068250875]
    - [-0.9997550997231162, 0.013011905181503854, 0.01790058382525125, -0.020569771258915234]
    - [0.018223771455443325, 0.02515883631155237, 0.999517347077547, -0.008638135126028098]
    - [0.0, 0.0, 0.0, 1.0]
  T_cn_cnm1:
    - [0.9999972564778812, 0.0023120671924238847, 0.0003760081024155938, -0.11007380812718678]
    - [-0.0023171357232812354, 0.9998980485066438, 0.014089835846648196, 0.00039912154701414806]
    - [-0.0003433931205241621, -0.01409066845271459, 0.9999006626377283, -0.0008537025033580449]
    - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_model: radtan
  distortion_coeffs: [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
"""

KALIBR_IMU = """imu0:
  T_i_b:
    - [1.0, 0.0, 0.0, 0.0]
    - [0.0, 1.0, 0.0, 0.0]
    - [0.0, 0.0, 1.0, 0.0]
    - [0.0, 0.0, 0.0, 1.0]
  accelerometer_noise_density: 2e-3
  accelerometer_random_walk: 3.0e-3
  gyroscope_noise_density: 1.6968e-04
  gyroscope_random_walk: 1.9393e-05
  model: calibrated
  rostopic: /imu0
  time_offset: 0.0
  update_rate: 200.0
"""

# TUM fr1, as ROS camera_info YAML (camera_calibration_parsers).
ROS_CAMERA_INFO = """image_width: 640
image_height: 480
camera_name: fr1_rgb
camera_matrix:
  rows: 3
  cols: 3
  data: [517.3, 0, 318.6, 0, 516.5, 255.3, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [517.3, 0, 318.6, 0, 0, 516.5, 255.3, 0, 0, 0, 1, 0]
"""
TUM_FR1 = (517.3, 516.5, 318.6, 255.3)
TUM_FR1_DIST = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]


@pytest.fixture(scope="module")
def euroc():
    """The real EuRoC sequence whose sensor.yaml files the fixtures above restate."""
    return EurocSequence(require_data("euroc", "V1_01_easy_micro"))


def _write(tmp_path, text, name="calib.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _assert_camera(camera, intrinsics, dist, size):
    assert isinstance(camera, Camera)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == intrinsics
    np.testing.assert_allclose(camera.dist, dist, rtol=1e-12)
    assert (camera.width, camera.height) == size


def _assert_euroc_imu(imu):
    assert imu.gyroscope_noise_density == 1.6968e-4 and imu.accelerometer_noise_density == 2.0e-3
    assert imu.gyroscope_random_walk == 1.9393e-5 and imu.accelerometer_random_walk == 3.0e-3
    assert imu.rate_hz == 200.0
    np.testing.assert_array_equal(imu.T_b_imu, np.eye(4))


def test_orbslam3_stereo_inertial(tmp_path, euroc):
    calib = load_calibration(_write(tmp_path, ORBSLAM3_STEREO_INERTIAL))
    assert isinstance(calib, Calibration) and len(calib.cameras) == 2
    _assert_camera(calib.cameras[0], CAM0, DIST0, (752, 480))
    _assert_camera(calib.cameras[1], CAM1, DIST1, (752, 480))
    # dt: f in the file, but the digits written are kept
    np.testing.assert_allclose(calib.camera_to_imu[0], euroc.T_b_cam0, atol=1e-12)
    np.testing.assert_allclose(calib.camera_to_imu[1], euroc.T_b_cam1, atol=1e-9)
    assert calib.camera_to_imu[0].dtype == np.float64
    assert calib.baseline_m == pytest.approx(0.1101, abs=1e-4)
    _assert_euroc_imu(calib.imu)


def test_orbslam_legacy_mono_inertial(tmp_path, euroc):
    calib = load_calibration(_write(tmp_path, ORBSLAM_LEGACY_MONO_INERTIAL))
    assert len(calib.cameras) == 1 and calib.T_left_right is None and calib.baseline_m is None
    _assert_camera(calib.cameras[0], CAM0, DIST0, (752, 480))
    np.testing.assert_allclose(calib.camera_to_imu[0], euroc.T_b_cam0, atol=1e-12)
    _assert_euroc_imu(calib.imu)
    _assert_euroc_imu(load_imu_params(tmp_path / "calib.yaml"))


def test_kalibr_camchain_and_imu(tmp_path, euroc):
    camchain = _write(tmp_path, KALIBR_CAMCHAIN, "camchain-imucam.yaml")
    calib = load_calibration(camchain, imu_path=_write(tmp_path, KALIBR_IMU, "imu.yaml"))
    _assert_camera(calib.cameras[0], CAM0, DIST0, (752, 480))
    _assert_camera(calib.cameras[1], CAM1, DIST1, (752, 480))
    np.testing.assert_allclose(calib.camera_to_imu[0], euroc.T_b_cam0, atol=1e-9)
    np.testing.assert_allclose(calib.camera_to_imu[1], euroc.T_b_cam1, atol=1e-9)
    T_cam0_cam1 = np.linalg.inv(euroc.T_b_cam0) @ euroc.T_b_cam1
    np.testing.assert_allclose(calib.T_left_right, T_cam0_cam1, atol=1e-9)
    assert calib.baseline_m == pytest.approx(euroc.rectifier.baseline_m, abs=1e-9)
    _assert_euroc_imu(calib.imu)  # "2e-3" (a string to PyYAML) is read as a number
    assert load_calibration(camchain).imu is None


def test_imu_params_of_the_real_euroc_sensor_yaml(euroc):
    _assert_euroc_imu(load_imu_params(euroc.mav0 / "imu0" / "sensor.yaml"))


def test_opencv_filestorage_written_by_opencv(tmp_path):
    path = tmp_path / "out_camera_data.yml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 640)
    storage.write("image_height", 480)
    storage.write("camera_matrix", np.array([[517.3, 0, 318.6], [0, 516.5, 255.3], [0, 0, 1]]))
    storage.write("distortion_coefficients", np.array([TUM_FR1_DIST]).T)
    storage.write("avg_reprojection_error", 0.21)
    storage.release()
    calib = load_calibration(path)
    _assert_camera(calib.cameras[0], TUM_FR1, TUM_FR1_DIST, (640, 480))
    assert calib.camera_to_imu == [None] and calib.imu is None


def test_ros_camera_info(tmp_path):
    calib = load_calibration(_write(tmp_path, ROS_CAMERA_INFO, "fr1.yaml"))
    _assert_camera(calib.cameras[0], TUM_FR1, TUM_FR1_DIST, (640, 480))


@pytest.mark.parametrize("text", [
    "fx: 517.3\nfy: 516.5\ncx: 318.6\ncy: 255.3\nk1: 0.2624\nk2: -0.9531\np1: -0.0054\n"
    "p2: 0.0026\nk3: 1.1633\n",
    "%YAML:1.0\nCamera.fx: 517.3\nCamera.fy: 516.5\nCamera.cx: 318.6\nCamera.cy: 255.3\n"
    "Camera.k1: 0.2624\nCamera.k2: -0.9531\nCamera.p1: -0.0054\nCamera.p2: 0.0026\n"
    "Camera.k3: 1.1633\nCamera.width: 640\nCamera.height: 480\nDepthMapFactor: 5000.0\n",
    "Camera1.fx: 517.3\nCamera1.fy: 516.5\nCamera1.cx: 318.6\nCamera1.cy: 255.3\n"
    "Camera1.k1: 0.2624\nCamera1.k2: -0.9531\nCamera1.p1: -0.0054\nCamera1.p2: 0.0026\n"
    "Camera1.k3: 1.1633\n",
], ids=["flat", "camera-prefix", "camera1-prefix"])
def test_flat_camera_yaml(tmp_path, text):
    """read_camera_yaml keeps its keys and its 640x480 default size."""
    path = _write(tmp_path, text, "camera.yaml")
    _assert_camera(read_camera_yaml(path), TUM_FR1, TUM_FR1_DIST, (640, 480))
    assert load_calibration(path).camera_to_imu == [None]


# TUM-VI cam0 and cam1 (Kannala-Brandt, 512x512) and T_cam0_cam1 of the TUM-VI 512 calibration.
TUM_VI0 = (190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504)
TUM_VI_K0 = [0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
             0.00020293673591811182]
TUM_VI1 = (190.44236969414825, 190.4344384721956, 252.59949716835982, 254.91723064636983)
TUM_VI_K1 = [0.0034003170790442797, 0.001766278153469831, -0.00266312569781606,
             0.0003299517423931039]
TUM_VI_T_C1_C0 = [[0.999998, -0.000874, -0.001935, -0.101180],
                  [0.000872, 0.999999, -0.001203, -0.001960],
                  [0.001936, 0.001202, 0.999997, -0.000473],
                  [0.0, 0.0, 0.0, 1.0]]


def _kalibr_fisheye_camchain() -> str:
    """KALIBR_CAMCHAIN with TUM-VI's equidistant cameras (Kalibr ``pinhole-equi``)."""
    text = KALIBR_CAMCHAIN
    for old, new in (
        ("[-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]", str(TUM_VI_K0)),
        ("[458.654, 457.296, 367.215, 248.375]", str(list(TUM_VI0))),
        ("[-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]", str(TUM_VI_K1)),
        ("[457.587, 456.134, 379.999, 255.238]", str(list(TUM_VI1))),
    ):
        assert old in text
        text = text.replace(old, new)
    return (text.replace("distortion_model: radtan", "distortion_model: equidistant")
            .replace("resolution: [752, 480]", "resolution: [512, 512]"))


def _assert_fisheye(camera, intrinsics, k, size):
    _assert_camera(camera, intrinsics, k, size)
    assert camera.model == "kannala_brandt"


def test_kalibr_equidistant_is_kannala_brandt(tmp_path):
    calib = load_calibration(_write(tmp_path, _kalibr_fisheye_camchain(), "camchain.yaml"))
    _assert_fisheye(calib.cameras[0], TUM_VI0, TUM_VI_K0, (512, 512))
    _assert_fisheye(calib.cameras[1], TUM_VI1, TUM_VI_K1, (512, 512))
    # A camera of another model in the same chain is still refused, listing the supported.
    text = KALIBR_CAMCHAIN.replace("distortion_model: radtan", "distortion_model: fov", 1)
    with pytest.raises(ValueError, match=r"calib.yaml: cam0.distortion_model 'fov' is not "
                                         r"supported \(supported: radtan, none, equidistant\)"):
        load_calibration(_write(tmp_path, text))
    text = KALIBR_CAMCHAIN.replace("camera_model: pinhole", "camera_model: omni", 1)
    with pytest.raises(ValueError, match=r"cam0.camera_model 'omni' is not supported"):
        load_calibration(_write(tmp_path, text))


def _orbslam3_fisheye(version_1: bool) -> str:
    """ORB-SLAM3's TUM-VI settings: KannalaBrandt8 with k1..k4 (format 1.0 or legacy)."""
    if version_1:
        cams = "".join(
            f"Camera{i}.fx: {c[0]}\nCamera{i}.fy: {c[1]}\nCamera{i}.cx: {c[2]}\n"
            f"Camera{i}.cy: {c[3]}\n" + "".join(f"Camera{i}.k{j + 1}: {v}\n"
                                                 for j, v in enumerate(k))
            for i, c, k in ((1, TUM_VI0, TUM_VI_K0), (2, TUM_VI1, TUM_VI_K1)))
        T = np.linalg.inv(np.array(TUM_VI_T_C1_C0))
        return (f'%YAML:1.0\nFile.version: "1.0"\nCamera.type: "KannalaBrandt8"\n{cams}'
                f"Camera.width: 512\nCamera.height: 512\nStereo.T_c1_c2: !!opencv-matrix\n"
                f"  rows: 4\n  cols: 4\n  dt: f\n  data: {T.ravel().tolist()}\n")
    ks = "".join(f"Camera.k{j + 1}: {v}\n" for j, v in enumerate(TUM_VI_K0))
    return (f'%YAML:1.0\nCamera.type: "KannalaBrandt8"\nCamera.fx: {TUM_VI0[0]}\n'
            f"Camera.fy: {TUM_VI0[1]}\nCamera.cx: {TUM_VI0[2]}\nCamera.cy: {TUM_VI0[3]}\n{ks}"
            f"Camera.width: 512\nCamera.height: 512\nCamera.fps: 20.0\n")


def test_orbslam3_kannala_brandt8(tmp_path):
    calib = load_calibration(_write(tmp_path, _orbslam3_fisheye(True)))
    _assert_fisheye(calib.cameras[0], TUM_VI0, TUM_VI_K0, (512, 512))
    _assert_fisheye(calib.cameras[1], TUM_VI1, TUM_VI_K1, (512, 512))
    T_c0_c1 = np.linalg.inv(np.array(TUM_VI_T_C1_C0))
    np.testing.assert_allclose(calib.T_left_right, T_c0_c1, atol=1e-12)
    legacy = load_calibration(_write(tmp_path, _orbslam3_fisheye(False), "legacy.yaml"))
    _assert_fisheye(legacy.cameras[0], TUM_VI0, TUM_VI_K0, (512, 512))
    text = ORBSLAM3_STEREO_INERTIAL.replace('"PinHole"', '"Rectified"')
    with pytest.raises(ValueError, match=r"Camera.type 'Rectified' is not supported "
                                         r"\(supported: PinHole, KannalaBrandt8\)"):
        load_calibration(_write(tmp_path, text))


def test_flat_camera_yaml_kannala_brandt(tmp_path):
    ks = "".join(f"k{j + 1}: {v}\n" for j, v in enumerate(TUM_VI_K0))
    text = (f"model: kannala_brandt\nfx: {TUM_VI0[0]}\nfy: {TUM_VI0[1]}\ncx: {TUM_VI0[2]}\n"
            f"cy: {TUM_VI0[3]}\n{ks}width: 512\nheight: 512\n")
    _assert_fisheye(read_camera_yaml(_write(tmp_path, text, "camera.yaml")), TUM_VI0, TUM_VI_K0,
                    (512, 512))
    # model: pinhole reads the 5 radial-tangential keys (k1 k2 p1 p2 k3): the fisheye's
    # coefficients read so fold the 512x512 image over, which the camera checks refuse.
    with pytest.raises(ValueError, match=r"calib.yaml: .*`k3` = .*folds the image over"):
        read_camera_yaml(_write(tmp_path, text.replace("kannala_brandt", "pinhole")))
    with pytest.raises(ValueError, match=r"camera.yaml: model 'omni' is not supported "
                                         r"\(supported: pinhole, kannala_brandt\)"):
        read_camera_yaml(_write(tmp_path, text.replace("kannala_brandt", "omni"),
                                "camera.yaml"))


def test_ros_camera_info_equidistant(tmp_path):
    text = (ROS_CAMERA_INFO.replace("plumb_bob", "equidistant")
            .replace("cols: 5\n  data: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]",
                     "cols: 4\n  data: [0.01, -0.005, 0.002, -0.0005]"))
    calib = load_calibration(_write(tmp_path, text))
    _assert_fisheye(calib.cameras[0], TUM_FR1, [0.01, -0.005, 0.002, -0.0005], (640, 480))
    with pytest.raises(ValueError, match=r"distortion_coefficients must hold 4 values "
                                         r"\(k1 k2 k3 k4\), got 5"):
        load_calibration(_write(tmp_path, ROS_CAMERA_INFO.replace("plumb_bob", "equidistant")))


def test_euroc_sensor_yaml_equidistant(tmp_path, euroc):
    """The ASL layout of a fisheye rig (TUM-VI): sensor.yaml with distortion_model
    equidistant gives Kannala-Brandt cameras."""
    import shutil

    mav0 = tmp_path / "seq" / "mav0"
    for cam, intrinsics, k in (("cam0", TUM_VI0, TUM_VI_K0), ("cam1", TUM_VI1, TUM_VI_K1)):
        (mav0 / cam / "data").mkdir(parents=True)
        shutil.copy(euroc.mav0 / cam / "data.csv", mav0 / cam / "data.csv")
        text = (euroc.mav0 / cam / "sensor.yaml").read_text()
        old_intrinsics = text[text.index("intrinsics:"):].split("\n", 1)[0]
        old_dist = text[text.index("distortion_coefficients:"):].split("\n", 1)[0]
        text = (text.replace(old_intrinsics, f"intrinsics: {list(intrinsics)}")
                .replace(old_dist, f"distortion_coefficients: {k}")
                .replace("radial-tangential", "equidistant")
                .replace("resolution: [752, 480]", "resolution: [512, 512]"))
        (mav0 / cam / "sensor.yaml").write_text(text)
    seq = EurocSequence(tmp_path / "seq", rectify=False)
    _assert_fisheye(seq.left_camera, TUM_VI0, TUM_VI_K0, (512, 512))
    _assert_fisheye(seq.right_camera, TUM_VI1, TUM_VI_K1, (512, 512))
    sensor = mav0 / "cam0" / "sensor.yaml"
    sensor.write_text(sensor.read_text().replace("equidistant", "omni-radtan"))
    with pytest.raises(ValueError, match=r"cam0/sensor.yaml: distortion_model 'omni-radtan' is "
                                         r"not supported \(supported: radial-tangential, "
                                         r"radtan, equidistant\)"):
        EurocSequence(tmp_path / "seq", rectify=False)


@pytest.mark.parametrize("old, new, message", [
    ("Camera1.fy: 457.296\n", "", r"calib.yaml: missing field Camera1.fy"),
    ("Camera1.fy: 457.296", "Camera1.fy: abc", r"calib.yaml: Camera1.fy is not a number: 'abc'"),
    ("Camera1.fx: 458.654", "Camera1.fx: -458.654", r"calib.yaml: Camera1.fx: fx and fy must "
                                                    "be positive"),
    ("Camera.width: 752", "Camera.width: 752.5", r"Camera.width must be a whole number"),
    ("0.0, 0.0, 0.0, 1.0]\nIMU.NoiseGyro", "0.0, 0.0, 0.0, 2.0]\nIMU.NoiseGyro",
     r"IMU.T_b_c1 is not a rigid transform"),
    ("rows: 4\n  cols: 4\n  dt: f\n  data: [0.99", "rows: 3\n  cols: 4\n  dt: f\n  data: [0.99",
     r"Stereo.T_c1_c2 declares 3x4 but holds 16 values"),
    ("IMU.GyroWalk: 1.9393e-05", "IMU.GyroWalk: 0", r"IMU.GyroWalk must be positive"),
    ('File.version: "1.0"', 'File.version: "2.0"', r"File.version '2.0' is not supported"),
])
def test_bad_fields_are_named(tmp_path, old, new, message):
    assert old in ORBSLAM3_STEREO_INERTIAL
    path = _write(tmp_path, ORBSLAM3_STEREO_INERTIAL.replace(old, new, 1))
    with pytest.raises(ValueError, match=message):
        load_calibration(path)


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.yaml"):
        load_calibration(tmp_path / "nowhere.yaml")
    with pytest.raises(ValueError, match=r"calib.yaml: not a calibration format.*keys: a, b"):
        load_calibration(_write(tmp_path, "a: 1\nb: 2\n"))
    with pytest.raises(ValueError, match=r"imu.yaml: holds IMU noise only.*load_imu_params"):
        load_calibration(_write(tmp_path, KALIBR_IMU, "imu.yaml"))
    with pytest.raises(ValueError, match=r"calib.yaml: no IMU noise parameters"):
        load_imu_params(_write(tmp_path, ROS_CAMERA_INFO))
    with pytest.raises(ValueError, match=r"calib.yaml: not valid YAML"):
        load_calibration(_write(tmp_path, "fx: [1, 2\n"))
    with pytest.raises(ValueError, match=r"calib.yaml: not a valid OpenCV FileStorage file"):
        load_calibration(_write(tmp_path, "%YAML:1.0\nfx: [1, 2\n"))
    text = ROS_CAMERA_INFO.replace("255.3, 0, 0, 1]", "255.3, 0, 0]", 1)
    with pytest.raises(ValueError, match=r"camera_matrix declares 3x3 but holds 8 values"):
        load_calibration(_write(tmp_path, text))
    text = ROS_CAMERA_INFO.replace("rows: 3\n  cols: 3\n  data: [517.3", "data: [517.3", 1)
    assert load_calibration(_write(tmp_path, text)).cameras[0].fx == 517.3  # flat 9 values


# --- rolling-shutter readout: one key per format, absent = 0 (global shutter) ----------------

def _flat_fr1(prefix: str) -> str:
    return "".join(f"{prefix}{k}: {v}\n" for k, v in zip(
        ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), (*TUM_FR1, *TUM_FR1_DIST)))


@pytest.mark.parametrize("text, readout_s", [
    (_flat_fr1("") + "rolling_shutter_readout_s: 0.02\n", 0.02),
    ("%YAML:1.0\n" + _flat_fr1("Camera.") + "Camera.rollingShutterReadout: 0.025\n", 0.025),
    (_flat_fr1("Camera1.") + "Camera1.rollingShutterReadout: 1.5e-2\n", 0.015),
    (_flat_fr1(""), 0.0),
    ("%YAML:1.0\n" + _flat_fr1("Camera."), 0.0),
], ids=["flat", "orbslam-legacy", "camera1-prefix", "flat-absent", "orbslam-absent"])
def test_flat_and_orbslam_readout_keys(tmp_path, text, readout_s):
    camera = read_camera_yaml(_write(tmp_path, text, "camera.yaml"))
    _assert_camera(camera, TUM_FR1, TUM_FR1_DIST, (640, 480))
    assert camera.rolling_shutter_readout_s == readout_s


def test_orbslam3_readout_per_camera(tmp_path):
    text = ORBSLAM3_STEREO_INERTIAL.replace(
        "Camera.width: 752", "Camera1.rollingShutterReadout: 0.02\nCamera.width: 752")
    calib = load_calibration(_write(tmp_path, text))
    assert [c.rolling_shutter_readout_s for c in calib.cameras] == [0.02, 0.0]


def test_kalibr_line_delay_is_a_readout_over_the_image_height(tmp_path):
    text = KALIBR_CAMCHAIN.replace("  rostopic: /cam0/image_raw",
                                   "  line_delay: 5.0e-05\n  rostopic: /cam0/image_raw", 1)
    calib = load_calibration(_write(tmp_path, text, "camchain.yaml"))
    assert calib.cameras[0].rolling_shutter_readout_s == pytest.approx(5e-5 * 480)
    assert calib.cameras[1].rolling_shutter_readout_s == 0.0


@pytest.mark.parametrize("key, text", [
    ("rolling_shutter_readout_s", _flat_fr1("") + "rolling_shutter_readout_s: -0.01\n"),
    ("rolling_shutter_readout_s", _flat_fr1("") + "rolling_shutter_readout_s: fast\n"),
    ("Camera.rollingShutterReadout",
     "%YAML:1.0\n" + _flat_fr1("Camera.") + "Camera.rollingShutterReadout: .nan\n"),
])
def test_bad_readouts_name_the_file_and_key(tmp_path, key, text):
    path = _write(tmp_path, text, "camera.yaml")
    with pytest.raises(ValueError, match=key) as info:
        read_camera_yaml(path)
    assert str(path) in str(info.value)


def test_kalibr_bad_line_delay_is_named(tmp_path):
    text = KALIBR_CAMCHAIN.replace("  rostopic: /cam0/image_raw",
                                   "  line_delay: -1.0e-05\n  rostopic: /cam0/image_raw", 1)
    with pytest.raises(ValueError, match="cam0.line_delay"):
        load_calibration(_write(tmp_path, text, "camchain.yaml"))


@pytest.mark.parametrize("text, name", [(ORBSLAM3_STEREO_INERTIAL, "calib.yaml"),
                                        (KALIBR_CAMCHAIN, "camchain-imucam.yaml")])
def test_two_camera_files_load_as_the_euroc_rig(tmp_path, euroc, text, name):
    """ORB-SLAM3 Camera1/Camera2 + Stereo.T_c1_c2 and a Kalibr camchain give the rig the
    EuRoC folder's sensor.yaml files give (body = IMU), a stereo pair."""
    rig = Rig.from_calibration(load_calibration(_write(tmp_path, text, name)))
    raw = EurocSequence(euroc.mav0, rectify=False)
    assert rig.stereo and rig.tracked_sensor() == "stereo" and len(rig.cameras) == 2
    for got, want in zip(rig.T_body_cam, raw.rig.T_body_cam):
        np.testing.assert_allclose(got, want, atol=1e-8)
    np.testing.assert_allclose(rig.T_left_right, raw.rig.T_left_right, atol=1e-8)
    for got, want in zip(rig.cameras, raw.rig.cameras):
        np.testing.assert_allclose(got.K, want.K, rtol=1e-6)


def _camchain_without_imu(n_cameras: int, chain_last: bool = True) -> str:
    """The EuRoC camchain without its IMU poses, cam1's section repeated as cam2.. (each
    camera chained to the previous one by cam1's ``T_cn_cnm1``, unless ``chain_last`` is
    false for the last)."""
    text = re.sub(r"  T_cam_imu:\n(    - .*\n){4}", "", KALIBR_CAMCHAIN)
    cam1 = text[text.index("cam1:"):]
    for n in range(2, n_cameras):
        section = cam1.replace("cam1:", f"cam{n}:", 1).replace("/cam1/", f"/cam{n}/")
        if n == n_cameras - 1 and not chain_last:
            section = re.sub(r"  T_cn_cnm1:\n(    - .*\n){4}", "", section)
        text += section
    return text


def test_a_camchain_of_three_cameras_loads_as_a_rig(tmp_path):
    """No IMU: the cameras' poses chain Kalibr's T_cn_cnm1 (cam n-1 -> cam n) from cam0; the
    first two are a pair, the third a further camera of the rig."""
    calib = load_calibration(_write(tmp_path, _camchain_without_imu(3), "camchain.yaml"))
    assert len(calib.cameras) == 3 and calib.camera_to_imu == [None] * 3
    T_c1_c0 = np.array(yaml.safe_load(KALIBR_CAMCHAIN)["cam1"]["T_cn_cnm1"])
    T_c0_c1 = np.linalg.inv(T_c1_c0)
    rig = Rig.from_calibration(calib)
    assert rig.stereo and rig.tracked_sensor() == "stereo" and len(rig.cameras) == 3
    np.testing.assert_allclose(rig.T_body_cam[1], T_c0_c1, atol=1e-12)
    np.testing.assert_allclose(rig.T_body_cam[2], T_c0_c1 @ T_c0_c1, atol=1e-12)
    [(camera, T_c0_c2, has_depth)] = rig.observers()
    assert camera is rig.cameras[2] and not has_depth
    np.testing.assert_allclose(T_c0_c2, T_c0_c1 @ T_c0_c1, atol=1e-12)
    broken = load_calibration(_write(tmp_path, _camchain_without_imu(3, chain_last=False),
                                     "broken.yaml"))
    assert broken.T_c0_cam[2] is None
    with pytest.raises(ValueError, match="has 3 cameras but does not give each one's pose"):
        Rig.from_calibration(broken)
