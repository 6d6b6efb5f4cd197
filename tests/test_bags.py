"""ROS bag input (ferroslam.bags): bags written here with rosbags from the shared data, as ROS 1,
ROS 2 sqlite3 and MCAP, give the trajectory of the same frames read from the folder; the real
T265 recording parses to fisheye pairs and one united IMU stream."""

from __future__ import annotations

import dataclasses
import json

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

if importlib.util.find_spec("rosbags") is None:  # CI installs it (.ci/run): there it must be
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        raise ImportError("rosbags is missing: pip install 'ferroslam[ros]'")
    pytest.skip("rosbags is missing: pip install 'ferroslam[ros]'", allow_module_level=True)

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag1 import Writer as Ros1Writer  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Ros2Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from conftest import require_data  # noqa: E402
from ferroslam import _core, cli  # noqa: E402
from ferroslam.calibration import load_calibration  # noqa: E402
from ferroslam.datasets import EurocSequence, TumSequence  # noqa: E402
from ferroslam.datasets.images import read_gray  # noqa: E402
from ferroslam.pipeline import imu_batch_end, run_sequence  # noqa: E402
from ferroslam.sources import open_bag  # noqa: E402
from ferroslam.transforms import inverse  # noqa: E402

FORMATS = ("ros1", "sqlite3", "mcap")
# Frames of the clips: EuRoC's 100 (5 s) are the fewest after which stereo-inertial has
# aligned the IMU (at 80 it still waits), so the comparison covers the alignment; few enough
# that this file stays near a minute and a half on two cores.
EUROC_FRAMES = 100
TUM_FRAMES = 60
INLINE = {"vocabulary": None, "mapping_thread": False}


# -- writing bags ----------------------------------------------------------------------------


class BagWriter:
    """A ROS 1 bag or ROS 2 bag (sqlite3, MCAP) written message by message, serialised with
    the typestore of its ROS version."""

    def __init__(self, path: Path, kind: str) -> None:
        self.kind = kind
        self.store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
        self.writer = (Ros1Writer(path) if kind == "ros1" else Ros2Writer(
            path, version=9, storage_plugin=StoragePlugin.SQLITE3 if kind == "sqlite3"
            else StoragePlugin.MCAP))
        self.connections: dict = {}

    def __enter__(self) -> "BagWriter":
        self.writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self.writer.close()

    def header(self, t_ns: int):
        types = self.store.types
        stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        extra = {"seq": 0} if self.kind == "ros1" else {}
        return types["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id="")

    def write(self, topic: str, msgtype: str, t_ns: int, **fields) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype,
                                                                 typestore=self.store)
        message = self.store.types[msgtype](header=self.header(t_ns), **fields)
        data = (self.store.serialize_ros1(message, msgtype) if self.kind == "ros1"
                else self.store.serialize_cdr(message, msgtype))
        self.writer.write(self.connections[topic], t_ns, data)

    def image(self, topic: str, t_ns: int, pixels: np.ndarray, encoding: str) -> None:
        pixels = np.ascontiguousarray(pixels)
        height, width = pixels.shape[:2]
        self.write(topic, "sensor_msgs/msg/Image", t_ns, height=height, width=width,
                   encoding=encoding, is_bigendian=0, step=pixels.strides[0],
                   data=pixels.view(np.uint8).reshape(-1))

    def compressed(self, topic: str, t_ns: int, path: Path) -> None:
        self.write(topic, "sensor_msgs/msg/CompressedImage", t_ns, format="jpeg",
                   data=np.fromfile(path, dtype=np.uint8))

    def imu(self, topic: str, t_ns: int, gyro, accel) -> None:
        types = self.store.types
        vector = types["geometry_msgs/msg/Vector3"]
        self.write(topic, "sensor_msgs/msg/Imu", t_ns,
                   orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                   orientation_covariance=np.zeros(9), angular_velocity=vector(*map(float, gyro)),
                   angular_velocity_covariance=np.zeros(9),
                   linear_acceleration=vector(*map(float, accel)),
                   linear_acceleration_covariance=np.zeros(9))

    def camera_info(self, topic: str, t_ns: int, camera) -> None:
        K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
        matrices = {"D": np.asarray(camera.dist, dtype=np.float64), "K": K.reshape(-1),
                    "R": np.eye(3).reshape(-1), "P": np.hstack([K, np.zeros((3, 1))]).reshape(-1)}
        if self.kind != "ros1":
            matrices = {k.lower(): v for k, v in matrices.items()}
        roi = self.store.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        self.write(topic, "sensor_msgs/msg/CameraInfo", t_ns, height=camera.height,
                   width=camera.width, distortion_model="plumb_bob", binning_x=0, binning_y=0,
                   roi=roi, **matrices)


def bag_path(folder: Path, kind: str) -> Path:
    """Where a bag of ``kind`` is written: a ROS 1 file, or a ROS 2 bag folder."""
    return folder / ("clip.bag" if kind == "ros1" else f"clip_{kind}")


def run_path(path: Path, kind: str) -> Path:
    """What is opened: the ``.mcap`` file itself for MCAP (its folder's metadata beside it)."""
    return next(path.glob("*.mcap")) if kind == "mcap" else path


# -- EuRoC MH_01 window: stereo and stereo-inertial --------------------------------------------


def write_camchain(seq: EurocSequence, path: Path) -> Path:
    """EuRoC's two cameras as a Kalibr camchain: ``T_cam_imu`` = inverse of ``T_BS``, and
    ``cam1.T_cn_cnm1`` = ``T_c1_c0``."""
    def camera(cam, T_b_cam):
        return {"camera_model": "pinhole", "distortion_model": "radtan",
                "intrinsics": [cam.fx, cam.fy, cam.cx, cam.cy],
                "distortion_coeffs": [float(d) for d in cam.dist[:4]],
                "resolution": [cam.width, cam.height],
                "T_cam_imu": inverse(T_b_cam).tolist()}
    chain = {"cam0": camera(seq.raw_cameras[0], seq.T_b_cam0),
             "cam1": camera(seq.raw_cameras[1], seq.T_b_cam1)}
    chain["cam1"]["T_cn_cnm1"] = (inverse(seq.T_b_cam1) @ seq.T_b_cam0).tolist()
    path.write_text(yaml.safe_dump(chain))
    return path


@pytest.fixture(scope="module")
def euroc(tmp_path_factory):
    """The MH_01 window's first frames as bags of every format, with EuRoC's topic names,
    and its calibration as a Kalibr camchain."""
    folder = require_data("euroc", "MH_01_easy_window")
    out = tmp_path_factory.mktemp("euroc_bags")
    seq = EurocSequence(folder)
    camchain = write_camchain(seq, out / "camchain.yaml")
    t_imu, gyro, accel = seq.imu()
    imu_ns = np.array([int(line.split(",")[0]) for line in
                       (seq.mav0 / "imu0" / "data.csv").read_text().splitlines()
                       if line and not line.startswith("#")], dtype=np.int64)
    last_ns = int(seq.timestamps_ns[EUROC_FRAMES - 1])
    bags = {}
    for kind in FORMATS:
        path = bag_path(out, kind)
        with BagWriter(path, kind) as bag:
            # In time order, as a recorder stores them; the IMU a little past the last frame.
            events = [(int(t), 0, k) for k, t in enumerate(imu_ns) if t <= last_ns + 10**8]
            events += [(int(seq.timestamps_ns[i]), 1, i) for i in range(EUROC_FRAMES)]
            for t_ns, what, k in sorted(events):
                if what == 0:
                    bag.imu("/imu0", t_ns, gyro[k], accel[k])
                    continue
                frame = seq.frames[k]
                bag.image("/cam0/image_raw", t_ns, read_gray(frame.left_path), "mono8")
                bag.image("/cam1/image_raw", t_ns, read_gray(frame.right_path), "mono8")
        bags[kind] = run_path(path, kind)
    return {"folder": folder, "camchain": camchain, "bags": bags,
            "imu_yaml": seq.mav0 / "imu0" / "sensor.yaml", "imu_ns": imu_ns}


def _trajectory(result) -> tuple[np.ndarray, np.ndarray]:
    return result.trajectory.timestamps, result.trajectory.poses


@pytest.mark.parametrize("sensor", ["stereo", "stereo-inertial"])
def test_euroc_bags_give_the_folder_trajectory_bit_for_bit(euroc, sensor):
    """Each format gives the folder run's poses, bit for bit: the same pixels, stamps, IMU
    samples and calibration reach the same deterministic (inline) run."""
    calibration = load_calibration(euroc["camchain"])
    folder = EurocSequence(euroc["folder"], calibration=calibration)
    expected = run_sequence(folder, INLINE, max_frames=EUROC_FRAMES, progress=False,
                            sensor=sensor)
    assert expected.tracked_frames == EUROC_FRAMES  # a real run, not an empty one
    if sensor == "stereo-inertial":
        assert expected.inertial["status"] == "aligned"
        # The folder's own sensor.yaml calibration gives the same run to rounding (measured
        # 2.5e-13 m): the camchain's extrinsics went through one inversion more.
        own = run_sequence(EurocSequence(euroc["folder"]), INLINE, max_frames=EUROC_FRAMES,
                           progress=False, sensor=sensor)
        np.testing.assert_allclose(own.trajectory.poses, expected.trajectory.poses, rtol=0,
                                   atol=1e-9)
    for kind, path in euroc["bags"].items():
        bag = open_bag(path, sensor=sensor, camera=euroc["camchain"], imu=euroc["imu_yaml"])
        assert bag.topics.images == ("/cam0/image_raw", "/cam1/image_raw")
        assert len(bag) == EUROC_FRAMES
        result = run_sequence(bag, INLINE, progress=False, sensor=sensor)
        times, poses = _trajectory(result)
        np.testing.assert_array_equal(times, expected.trajectory.timestamps, err_msg=kind)
        np.testing.assert_array_equal(poses, expected.trajectory.poses, err_msg=kind)
        # Streamed: the reader held one stereo pair at a time, never the bag.
        assert bag.buffered_peak <= 2, kind


def test_euroc_bag_imu_is_the_folder_imu(euroc):
    bag = open_bag(euroc["bags"]["ros1"], sensor="stereo-inertial", camera=euroc["camchain"],
                   imu=euroc["imu_yaml"])
    folder = EurocSequence(euroc["folder"])
    t, gyro, accel = bag.imu()
    t_ref, gyro_ref, accel_ref = folder.imu()
    n = t.size
    assert n == np.count_nonzero(euroc["imu_ns"] <= bag.timestamps_ns[-1] + 10**8)
    np.testing.assert_array_equal(t, t_ref[:n])
    np.testing.assert_array_equal(gyro, gyro_ref[:n])
    np.testing.assert_array_equal(accel, accel_ref[:n])
    given, own = bag.imu_params(), folder.imu_params()
    assert given.rate_hz == own.rate_hz == 200.0
    assert given.gyroscope_noise_density == own.gyroscope_noise_density
    np.testing.assert_array_equal(given.T_b_imu, own.T_b_imu)


def test_cli_runs_a_bag_as_it_runs_the_folder(euroc, tmp_path, capsys):
    """``ferroslam run FILE.bag`` goes the folder's way: the same trajectory file."""
    common = ["--sensor", "stereo", "--camera", str(euroc["camchain"]), "--silent"]
    assert cli.main(["run", str(euroc["folder"]), *common, "--max-frames", str(EUROC_FRAMES),
                     "--out", str(tmp_path / "folder")]) == 0
    assert cli.main(["run", str(euroc["bags"]["ros1"]), *common,
                     "--out", str(tmp_path / "bag")]) == 0
    assert ((tmp_path / "bag" / "trajectory.txt").read_text()
            == (tmp_path / "folder" / "trajectory.txt").read_text())


def test_folder_calibration_and_camchain_rectify_alike(euroc):
    """The camchain holds the sensor.yaml calibration: the rectified camera and baseline agree
    to rounding (the extrinsics go through one inversion more)."""
    own = EurocSequence(euroc["folder"])
    given = EurocSequence(euroc["folder"], calibration=load_calibration(euroc["camchain"]))
    assert given.baseline_m == pytest.approx(own.baseline_m, abs=1e-12)
    np.testing.assert_allclose(given.T_b_c, own.T_b_c, atol=1e-12)
    assert given.camera.fx == pytest.approx(own.camera.fx, abs=1e-9)


# -- TUM fr1/rpy: RGB-D with CameraInfo --------------------------------------------------------


@pytest.fixture(scope="module")
def tum(tmp_path_factory):
    """fr1/rpy's first frames: colour as the JPEG files (CompressedImage), depth as 16UC1
    (TUM's raw values, 5000 per metre) and a CameraInfo with the fr1 intrinsics."""
    folder = require_data("tum", "rgbd_dataset_freiburg1_rpy")
    out = tmp_path_factory.mktemp("tum_bags")
    seq = TumSequence(folder)
    import cv2

    bags = {}
    for kind in FORMATS:
        path = bag_path(out, kind)
        with BagWriter(path, kind) as bag:
            for frame in seq.frames[:TUM_FRAMES]:
                t_ns = round(frame.timestamp * 1e9)
                bag.camera_info("/camera/rgb/camera_info", t_ns, seq.camera)
                bag.compressed("/camera/rgb/image_color", t_ns, frame.rgb_path)
                depth = cv2.imread(str(frame.depth_path), cv2.IMREAD_UNCHANGED)
                bag.image("/camera/depth/image", round(frame.depth_timestamp * 1e9), depth,
                          "16UC1")
        bags[kind] = run_path(path, kind)
    return {"folder": folder, "bags": bags}


def test_tum_bags_give_the_folder_trajectory(tum):
    """Calibration from CameraInfo, depth at TUM's scale: the folder run's poses. The stamps
    went through integer nanoseconds, so they agree to the float64 step at 1.3e9 s (2.4e-7 s):
    TUM's decimal seconds and seconds_from_ns round to neighbouring doubles at times.

    Colour goes in as the JPEG files (CompressedImage), decoded as the folder decodes them.
    Written as raw rgb8 of the decoded colour instead, the grey image is a conversion, not the
    JPEG's luma (0.3 % of the pixels differ, by up to 5 levels), and the run is another one
    (measured over these 60 frames: up to 3.2 cm apart, ATE 3.58 against 2.89 cm)."""
    # CameraInfo carries no readout: the folder is run with the same global-shutter camera.
    own = TumSequence(tum["folder"]).camera
    camera = dataclasses.replace(own, rolling_shutter_readout_s=0.0)
    expected = run_sequence(TumSequence(tum["folder"], camera=camera), INLINE,
                            max_frames=TUM_FRAMES, progress=False, sensor="rgbd")
    assert expected.tracked_frames == TUM_FRAMES
    for kind, path in tum["bags"].items():
        bag = open_bag(path, sensor="rgbd", depth_scale=5000)
        assert bag.topics.camera_info == ("/camera/rgb/camera_info",)
        assert bag.camera.rolling_shutter_readout_s == 0.0
        assert (bag.camera.fx, bag.camera.fy, bag.camera.cx, bag.camera.cy, bag.camera.width,
                bag.camera.height) == (own.fx, own.fy, own.cx, own.cy, own.width, own.height)
        np.testing.assert_array_equal(bag.camera.dist, own.dist)
        result = run_sequence(bag, INLINE, progress=False, sensor="rgbd")
        times, poses = _trajectory(result)
        np.testing.assert_allclose(times, expected.trajectory.timestamps, rtol=0,
                                   atol=np.spacing(expected.trajectory.timestamps).max())
        np.testing.assert_array_equal(poses, expected.trajectory.poses, err_msg=kind)
        assert bag.buffered_peak <= 2, kind


def test_16uc1_depth_is_millimetres_unless_told(tum, tmp_path):
    """REP 118: 16UC1 depth is millimetres; a calibration's depth factor or depth_scale says
    otherwise."""
    assert open_bag(tum["bags"]["mcap"], sensor="rgbd").depth_factor == 1000.0
    settings = tmp_path / "tum.yaml"
    settings.write_text("fx: 517.3\nfy: 516.5\ncx: 318.6\ncy: 255.3\nDepthMapFactor: 5000.0\n")
    assert open_bag(tum["bags"]["ros1"], sensor="rgbd", camera=settings).depth_factor == 5000.0
    assert open_bag(tum["bags"]["ros1"], sensor="rgbd", camera=settings,
                    depth_scale=4000).depth_factor == 4000.0


# -- the real T265 recording ---------------------------------------------------------------------


def t265_camchain(path: Path, with_imu: bool = False) -> Path:
    """The README's fisheye intrinsics and nominal 64 mm rig as a Kalibr camchain; with
    ``with_imu`` an identity camera-IMU pose, nominal too (none is published)."""
    source = yaml.safe_load((require_data("rosbag", "t265_locoffice") / "calibration.yaml")
                            .read_text())
    chain = {}
    for name in ("cam0", "cam1"):
        cam = source[name]
        chain[name] = {"camera_model": "pinhole", "distortion_model": "equidistant",
                       "intrinsics": cam["intrinsics"], "distortion_coeffs": cam["distortion"],
                       "resolution": cam["resolution"]}
    T_c1_c0 = np.eye(4)
    T_c1_c0[0, 3] = -source["cam1"]["T_cam0_cam1_translation_m"][0]
    chain["cam1"]["T_cn_cnm1"] = T_c1_c0.tolist()
    if with_imu:
        chain["cam0"]["T_cam_imu"] = np.eye(4).tolist()
        chain["cam1"]["T_cam_imu"] = T_c1_c0.tolist()
    path.write_text(yaml.safe_dump(chain))
    return path


def _raw_imu(bag_file: Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """A topic's stamps (ns) and (gyro, accel) columns, read with rosbags directly."""
    rows = []
    with AnyReader([bag_file]) as reader:
        for connection, _, raw in reader.messages(
                connections=[c for c in reader.connections if c.topic == topic]):
            m = reader.deserialize(raw, connection.msgtype)
            w, a = m.angular_velocity, m.linear_acceleration
            rows.append((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                         w.x, w.y, w.z, a.x, a.y, a.z))
    rows.sort()
    return np.array([r[0] for r in rows]), np.array([r[1:] for r in rows])


def test_t265_bag_parses_to_fisheye_pairs_and_one_united_imu(tmp_path):
    bag_file = require_data("rosbag", "t265_locoffice", "trimmed_locoffice.bag")
    bag = open_bag(bag_file, sensor="stereo-inertial", camera=t265_camchain(tmp_path / "c.yaml"))
    assert bag.topics.images == ("/camera/fisheye1/image_raw", "/camera/fisheye2/image_raw")
    assert (bag.topics.gyro, bag.topics.accel) == ("/camera/gyro/sample",
                                                    "/camera/accel/sample")
    assert len(bag) == 3 and bag.baseline_m == pytest.approx(0.064)
    pairs = [bag.load_stereo(i) for i in range(len(bag))]
    assert all(l.shape == r.shape == (800, 848) and l.mean() > 10 for l, r in pairs)

    t, gyro, accel = bag.imu()
    t_gyro, g = _raw_imu(bag_file, "/camera/gyro/sample")
    t_accel, a = _raw_imu(bag_file, "/camera/accel/sample")
    assert np.all(np.diff(t) > 0)
    inside = (t_gyro >= t_accel[0]) & (t_gyro <= t_accel[-1])
    assert t.size == np.count_nonzero(inside) == 15  # 4 of the 19 gyro samples lie outside
    np.testing.assert_array_equal(gyro, g[inside, :3])
    # The accelerometer at the gyro stamps, linearly; in ns from its first stamp, since ns
    # since 1970 in float64 have 256 ns steps (1e-6 m/s^2 off here).
    x, xp = t_gyro[inside] - t_accel[0], t_accel - t_accel[0]
    for k in range(3):
        np.testing.assert_allclose(accel[:, k], np.interp(x, xp, a[:, 3 + k]), rtol=0,
                                   atol=1e-12)
    assert "4 of 19 /camera/gyro/sample samples lie outside" in bag.notes[0]
    # Frame 0 (0.3609 s) precedes the first united sample (0.3712 s): it gets none, and says so.
    assert "1 frame(s) before the first IMU sample" in bag.notes[1]
    period = np.median(np.diff(t))
    assert imu_batch_end(t, float(bag.timestamps[0]), period) == 0
    assert imu_batch_end(t, float(bag.timestamps[1]), period) > 0


def test_t265_raw_fisheye_pair_tracks_as_a_rig(tmp_path):
    """The T265's two raw fisheye images (Kannala-Brandt, about 170 degrees) matched in the
    core along epipolar curves, no rectification: a metric map from the first pair and every
    frame tracked. Measured 2026-12-02: 562 initial points, against 661 from the rectified
    pair (which crops the image circle to a pinhole view with its own keypoints); 3/3."""
    bag_file = require_data("rosbag", "t265_locoffice", "trimmed_locoffice.bag")
    bag = open_bag(bag_file, sensor="stereo", camera=t265_camchain(tmp_path / "c.yaml"))
    rig = bag.rig
    assert rig.stereo and [c.model for c in rig.cameras] == ["kannala_brandt"] * 2
    assert np.linalg.norm(rig.T_left_right[:3, 3]) == pytest.approx(0.064)
    left, right = rig.cameras
    raw = _core.SlamSystem(left.fx, left.fy, left.cx, left.cy, left.dist, left.width,
                           left.height, sensor="stereo", model=left.model, right_camera=right,
                           T_left_right=rig.T_left_right)
    c = bag.camera
    rectified = _core.SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height,
                                 sensor="stereo", baseline=bag.baseline_m)
    for i in range(len(bag)):
        assert raw.track(float(bag.timestamps[i]), bag.load_rig(i)).state == "ok"
        if i == 0:
            rectified.track(float(bag.timestamps[i]), bag.load_stereo(i))
            points = (raw.num_map_points, rectified.num_map_points)
    print(f"T265 raw pair: {points[0]} initial points, rectified {points[1]}")
    assert points[0] >= 0.7 * points[1] and points[0] >= 450
    # The same pair from the command line: --sensor rig leaves the bag's images raw.
    out = tmp_path / "out"
    assert cli.main(["run", str(bag_file), "--sensor", "rig", "--camera",
                     str(tmp_path / "c.yaml"), "--out", str(out), "--silent"]) == 0
    summary = json.loads((out / "results.json").read_text())
    assert summary["sensor"] == "rig" and summary["tracked_frames"] == 3


def test_cli_says_what_the_t265_bag_lacks(tmp_path, capsys):
    """``ferroslam run`` on the real recording, stereo-inertial: its 3 frames run, and the
    summary says which IMU samples were dropped and which frame got none (the poses mean
    nothing: the camera-IMU pose is nominal)."""
    imu = tmp_path / "imu.yaml"
    imu.write_text("gyroscope_noise_density: 1.0e-3\ngyroscope_random_walk: 1.0e-5\n"
                   "accelerometer_noise_density: 1.0e-2\naccelerometer_random_walk: 1.0e-4\n"
                   "update_rate: 200.0\n")
    bag_file = require_data("rosbag", "t265_locoffice", "trimmed_locoffice.bag")
    assert cli.main(["run", str(bag_file), "--sensor", "stereo-inertial", "--camera",
                     str(t265_camchain(tmp_path / "c.yaml", with_imu=True)), "--imu", str(imu), "--out",
                     str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert "sequence        trimmed_locoffice  (stereo-inertial)" in printed
    assert "/3  keyframes" in printed
    assert "note: 4 of 19 /camera/gyro/sample samples lie outside" in printed
    assert "note: 1 frame(s) before the first IMU sample (1553180224.371165 s)" in printed


# -- errors --------------------------------------------------------------------------------------


def test_a_missing_rosbags_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    bag = tmp_path / "x.bag"
    bag.write_bytes(b"")
    with pytest.raises(ImportError, match=r"pip install 'ferroslam\[ros\]'"):
        open_bag(bag, sensor="mono")


def test_topic_errors_name_the_topics(euroc, tum):
    with pytest.raises(ValueError, match=r"2 image topics \(/cam0/image_raw, /cam1/image_raw\) "
                                         r"for 1: .*--topics"):
        open_bag(euroc["bags"]["ros1"], sensor="mono", camera=euroc["camchain"])
    with pytest.raises(ValueError, match="no topic /cam2/image_raw in the bag"):
        open_bag(euroc["bags"]["ros1"], sensor="mono", topics=["/cam2/image_raw"])
    with pytest.raises(ValueError, match="stereo needs the rig's extrinsics"):
        open_bag(euroc["bags"]["sqlite3"], sensor="stereo")
    with pytest.raises(ValueError, match="no CameraInfo beside /cam1/image_raw"):
        open_bag(euroc["bags"]["sqlite3"], sensor="mono", topics=["/cam1/image_raw"])
    with pytest.raises(ValueError, match="needs an IMU, and the bag has no"):
        open_bag(tum["bags"]["ros1"], sensor="rgbd-inertial")
    with pytest.raises(ValueError, match="noise model is not in a bag: .*--imu FILE"):
        open_bag(euroc["bags"]["mcap"], sensor="stereo-inertial",
                 camera=euroc["camchain"]).imu_params()


def test_named_topics_choose_the_camera(euroc):
    """``--topics`` picks the right camera for a monocular run (in the order given)."""
    bag = open_bag(euroc["bags"]["ros1"], sensor="mono", topics=["/cam1/image_raw"],
                   camera=load_calibration(euroc["camchain"]).cameras[1])
    assert bag.topics.images == ("/cam1/image_raw",)
    folder = EurocSequence(euroc["folder"])
    np.testing.assert_array_equal(bag.load_gray(3), read_gray(folder.frames[3].right_path))
    # Going back re-reads the bag from the start.
    np.testing.assert_array_equal(bag.load_gray(0), read_gray(folder.frames[0].right_path))


def test_image_encodings(tmp_path):
    """rgb8, bgr8, mono8 and 32FC1 depth (NaN: no measurement) decode to what was written."""
    rng = np.random.default_rng(7)
    bgr = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 3.0, (6, 8)).astype(np.float32)
    depth[0, 0] = np.nan
    path = bag_path(tmp_path, "mcap")
    with BagWriter(path, "mcap") as bag:
        for i, (encoding, pixels) in enumerate([("rgb8", bgr[..., ::-1]), ("bgr8", bgr)]):
            bag.image("/camera/color/image_raw", 10**9 * (i + 1), pixels, encoding)
            bag.image("/camera/aligned_depth_to_color/image_raw", 10**9 * (i + 1), depth,
                      "32FC1")
            bag.image("/camera/infra1/image_rect_raw", 10**9 * (i + 1), bgr[..., 0], "mono8")
    from ferroslam import Camera

    camera = Camera(5.0, 5.0, 4.0, 3.0, np.zeros(5), 8, 6)
    seq = open_bag(path, sensor="rgbd", camera=camera,
                   topics=["/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw"])
    for i in range(2):
        gray, color = seq.load_gray_and_color(i)
        np.testing.assert_array_equal(color, bgr)
        expected_depth = np.where(np.isnan(depth), 0, depth)
        np.testing.assert_array_equal(seq.load_depth(i), expected_depth)
    assert seq.depth_factor == 1.0
    with pytest.raises(ValueError, match="32FC1 depth is in metres"):
        open_bag(path, sensor="rgbd", camera=camera, depth_scale=1000.0,
                 topics=["/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw"])
    mono = open_bag(path, sensor="mono", camera=camera, topics=["/camera/infra1/image_rect_raw"])
    np.testing.assert_array_equal(mono.load_gray(1), bgr[..., 0])


def test_a_lone_mcap_file_opens(tmp_path):
    """An ``.mcap`` file without its ROS 2 folder (no metadata.yaml) is a bag too."""
    with BagWriter(tmp_path / "recording", "mcap") as bag:
        for i in range(3):
            bag.image("/cam/image_raw", 10**9 * (i + 1), np.full((6, 8), i, np.uint8), "mono8")
    lone = tmp_path / "lone.mcap"
    next((tmp_path / "recording").glob("*.mcap")).rename(lone)
    from ferroslam import Camera

    seq = open_bag(lone, sensor="mono", camera=Camera(5.0, 5.0, 4.0, 3.0, np.zeros(5), 8, 6))
    assert [int(seq.load_gray(i)[0, 0]) for i in range(len(seq))] == [0, 1, 2]
    np.testing.assert_array_equal(seq.timestamps, [1.0, 2.0, 3.0])


def test_cli_bag_options(euroc, tmp_path, capsys):
    """``--topics`` reaches the bag (an unknown one is named); bag options on a folder are
    refused."""
    assert cli.main(["run", str(euroc["bags"]["sqlite3"]), "--sensor", "mono", "--topics",
                     "/nope", "--camera", str(euroc["camchain"]), "--silent"]) == 1
    assert "no topic /nope in the bag (topics: /cam0/image_raw, /cam1/image_raw, /imu0)" in \
        capsys.readouterr().err
    assert cli.main(["run", str(euroc["folder"]), "--sensor", "stereo", "--topics", "/cam0",
                     "--silent"]) == 1
    assert "--topics and --imu are for ROS bags" in capsys.readouterr().err
