"""ROS bags as sequences: ROS 1 ``.bag`` files, ROS 2 bags (sqlite3 folders, ``.mcap``).

:func:`open_bag` reads a recording through the pure-Python ``rosbags`` package (no ROS
install; ``pip install 'ferroslam[ros]'``) and gives a :class:`BagSequence`, which offers what
the dataset folders offer (``len``, ``timestamps``, ``camera``, ``load_gray``,
``load_gray_and_color``, ``load_stereo`` and ``baseline_m`` for stereo, ``load_depth`` for
RGB-D, ``imu()``, ``imu_params()`` and ``T_b_c`` with an IMU), so that
:func:`ferroslam.pipeline.run_sequence` and ``ferroslam run FILE.bag`` track it as they track
a folder.

Messages read: ``sensor_msgs/Image`` (``mono8``, ``rgb8``, ``bgr8``; depth ``16UC1`` and
``32FC1``), ``sensor_msgs/CompressedImage`` (JPEG, PNG), ``sensor_msgs/CameraInfo`` (the
calibration when none is given) and ``sensor_msgs/Imu``. Times are the messages' header
stamps, not the recording times.

Topics are found by type and name unless named (``topics=``): image topics whose name says
``depth`` are depth, the others colour or grey; for stereo the two image topics are left and
right in name order (``cam0 < cam1``, ``fisheye1 < fisheye2``, ``infra1 < infra2``,
``left < right``), or in the order named. One ``Imu`` topic carries both sensors; two (named
``gyro`` and ``accel``, as RealSense drivers publish them) are united onto the gyroscope's
stamps with the accelerometer linearly interpolated there, as RealSense's
``unite_imu_method: linear_interpolation`` does; gyroscope samples outside the
accelerometer's span are dropped (said in ``notes``).

Frames are associated by stamp, one to one as TUM's ``associate.py`` does: stereo pairs within
:data:`STEREO_TOLERANCE_S`, colour and depth within :data:`RGBD_TOLERANCE_S`. Stereo pairs are
rectified from the calibration's extrinsics (a Kalibr camchain's ``T_cn_cnm1``) as EuRoC
folders are (:class:`~ferroslam.stereo.StereoRectifier`); sensor ``rig`` leaves them raw, for
the core to match along epipolar curves (``seq.rig``, ``load_rig``).

Opening a bag reads it once for the stamps and the IMU; images are then read as they are
asked for, in order, so memory holds a few frames, not the recording.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generator, Optional, Union

import cv2
import numpy as np

from .calibration import Calibration, ImuParams, load_calibration, load_imu_params
from .camera import Camera
from .datasets.tum import associate_greedy
from .io import seconds_from_ns
from .options import RUN_SENSORS, check_option
from .rig import Rig
from .stereo import StereoRectifier

__all__ = ["BagSequence", "BagTopics", "RGBD_TOLERANCE_S", "STEREO_TOLERANCE_S", "is_bag",
           "open_bag"]

# Hardware-synchronised stereo cameras (EuRoC, RealSense) stamp both images alike; a few ms
# leave room for software-triggered pairs and stay far below a frame period at 60 Hz (16.7
# ms), so a pair is never two instants.
STEREO_TOLERANCE_S = 0.005
# Colour and depth cameras run unsynchronised (Kinect, RealSense without sync): TUM's
# associate.py default.
RGBD_TOLERANCE_S = 0.02
# REP 118: 16-bit depth images are millimetres, 32-bit float ones metres.
_ROS_DEPTH_FACTOR_16UC1 = 1000.0

_IMAGE = "sensor_msgs/msg/Image"
_COMPRESSED = "sensor_msgs/msg/CompressedImage"
_CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
_IMU = "sensor_msgs/msg/Imu"
_IMAGE_TYPES = (_IMAGE, _COMPRESSED)
_GREY = ("mono8", "8UC1")
_COLOUR = {"rgb8": cv2.COLOR_RGB2BGR, "bgr8": None}
_DEPTH = ("16UC1", "mono16", "32FC1")
_ENCODINGS = (*_GREY, *_COLOUR, *_DEPTH)
_ROS_DISTORTIONS = {"plumb_bob": "pinhole", "equidistant": "kannala_brandt"}
_ROS2_METADATA = "metadata.yaml"
_BAG_SUFFIXES = (".bag", ".mcap", ".db3")

Key = tuple[str, int]
"""A message of an image topic: ``(topic, ordinal)``, its place among the topic's messages
in the order the bag stores them."""


def is_bag(path: Union[str, Path]) -> bool:
    """Whether ``path`` is a ROS bag: a ``.bag``, ``.mcap`` or ``.db3`` file, or a ROS 2 bag
    folder (with ``metadata.yaml``)."""
    path = Path(path).expanduser()
    if path.is_dir():
        return (path / _ROS2_METADATA).is_file()
    return path.suffix.lower() in _BAG_SUFFIXES


def _any_reader() -> Any:
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise ImportError("reading ROS bags needs the rosbags package: pip install "
                          "'ferroslam[ros]'") from None
    return AnyReader


def _reader_path(path: Path) -> Path:
    """What AnyReader opens: the ``.bag`` or lone ``.mcap`` file, or the ROS 2 bag folder (an
    ``.mcap`` or ``.db3`` file stands for its folder when ``metadata.yaml`` is beside it)."""
    if path.suffix.lower() in (".mcap", ".db3") and (path.parent / _ROS2_METADATA).is_file():
        return path.parent
    return path


@dataclass(frozen=True)
class BagTopics:
    """The topics a sequence reads: ``images`` (the left / only image topic first, then the
    right one for stereo), ``depth``, ``camera_info`` (one per image topic, ``None`` where
    there is none), ``gyro`` and ``accel`` (the same topic when one ``Imu`` topic holds
    both)."""

    images: tuple[str, ...]
    depth: Optional[str] = None
    camera_info: tuple[Optional[str], ...] = ()
    gyro: Optional[str] = None
    accel: Optional[str] = None


@dataclass
class _Scan:
    """What one pass over the bag gives: per image topic, the stamps (ns) of its messages in
    stored order and the first message's encoding; the first CameraInfo message per topic;
    the IMU samples per topic."""

    stamps: dict[str, list[int]]
    encodings: dict[str, str]
    infos: dict[str, Any]
    imu: dict[str, list[tuple[int, tuple[float, float, float], tuple[float, float, float]]]]


class _ImageStream:
    """The image messages of ``topics`` in stored order, from one pass of the reader; a
    message asked for later than one stored after it waits in a buffer, and only messages a
    frame still to come needs are kept, so the buffer holds a few frames. Asking for a
    message already passed (going back) starts the pass again."""

    def __init__(self, path: Path, topics: tuple[str, ...], frame_of: dict[Key, int]) -> None:
        self._path, self._topics, self._frame_of = path, topics, frame_of
        self._buffer: dict[Key, Any] = {}
        self._messages: Optional[Generator[tuple[Key, Any], None, None]] = None
        self._read: dict[str, int] = {}
        self._last: tuple[int, list[Any]] = (-1, [])  # colour and depth are asked apart
        self.peak_buffered = 0
        """The most messages the buffer held at once (the memory bound, for tests)."""

    def _pass(self) -> Generator[tuple[Key, Any], None, None]:
        with _any_reader()([self._path]) as reader:
            connections = [c for c in reader.connections if c.topic in self._topics]
            for connection, _, raw in reader.messages(connections=connections):
                ordinal = self._read.get(connection.topic, 0)
                self._read[connection.topic] = ordinal + 1
                yield (connection.topic, ordinal), reader.deserialize(raw, connection.msgtype)

    def take(self, frame: int, keys: tuple[Key, ...]) -> list[Any]:
        """The messages ``keys`` of frame ``frame``."""
        if self._last[0] == frame:
            return self._last[1]
        for key in list(self._buffer):
            if self._frame_of[key] < frame:
                del self._buffer[key]
        if any(k not in self._buffer and k[1] < self._read.get(k[0], 0) for k in keys):
            if self._messages is not None:
                self._messages.close()
            self._messages, self._buffer, self._read = None, {}, {}
        if self._messages is None:
            self._messages = self._pass()
            # Closes the reader of a pass left unfinished (a run of the first frames only)
            # while the interpreter can still run its cleanup.
            weakref.finalize(self, self._messages.close)
        for key, message in self._messages:
            if self._frame_of.get(key, -1) >= frame:
                self._buffer[key] = message
                self.peak_buffered = max(self.peak_buffered, len(self._buffer))
            if all(k in self._buffer for k in keys):
                break
        missing = [k for k in keys if k not in self._buffer]
        if missing:
            raise ValueError(f"{self._path}: message {missing[0][1]} of {missing[0][0]} is no "
                             "longer in the bag (changed while reading?)")
        self._last = (frame, [self._buffer.pop(k) for k in keys])
        return self._last[1]


def _stamp_ns(message: Any) -> int:
    stamp = message.header.stamp
    return int(stamp.sec) * 10**9 + int(stamp.nanosec)


def _scan(reader: Any, image_topics: set[str], info_topics: set[str],
          imu_topics: set[str]) -> _Scan:
    """One pass of the open ``reader`` over the topics (see :class:`_Scan`)."""
    scan = _Scan({t: [] for t in image_topics}, {}, {}, {t: [] for t in imu_topics})
    wanted = image_topics | info_topics | imu_topics
    connections = [c for c in reader.connections if c.topic in wanted]
    for connection, _, raw in reader.messages(connections=connections):
        topic = connection.topic
        if topic in info_topics and topic in scan.infos:
            continue
        message = reader.deserialize(raw, connection.msgtype)
        if topic in image_topics:
            scan.stamps[topic].append(_stamp_ns(message))
            if connection.msgtype == _IMAGE:
                scan.encodings.setdefault(topic, str(message.encoding))
            else:
                scan.encodings.setdefault(topic, str(message.format))
        elif topic in info_topics:
            scan.infos[topic] = message
        else:
            w, a = message.angular_velocity, message.linear_acceleration
            scan.imu[topic].append((_stamp_ns(message), (w.x, w.y, w.z), (a.x, a.y, a.z)))
    return scan


def _pick(candidates: list[str], count: int, what: str, path: Path) -> list[str]:
    if len(candidates) < count:
        raise ValueError(f"{path}: {count} {what} topic(s) needed, found "
                         f"{len(candidates)}: {', '.join(candidates) or 'none'}")
    if len(candidates) > count:
        raise ValueError(f"{path}: {len(candidates)} {what} topics ({', '.join(candidates)}) "
                         f"for {count}: name the ones to read (topics=[...]; command line: "
                         "--topics A,B)")
    return candidates


def _camera_info_topic(image_topic: str, infos: list[str]) -> Optional[str]:
    """The CameraInfo topic beside ``image_topic`` (``/ns/image_raw`` -> ``/ns/camera_info``)."""
    namespace = image_topic.rsplit("/", 1)[0]
    return next((t for t in infos if t.rsplit("/", 1)[0] == namespace), None)


def _find_topics(types: dict[str, str], sensor: str, path: Path,
                 topics: Optional[list[str]] = None) -> BagTopics:
    """The topics ``sensor`` reads among ``types`` (topic -> message type), found by type and
    name (see the module doc), or among ``topics`` only, in their order; IMU topics only for
    the inertial sensors. Raises ``ValueError`` naming the topics for a missing, unknown or
    ambiguous one."""
    if topics is not None:
        unknown = [t for t in topics if t not in types]
        if unknown:
            raise ValueError(f"{path}: no topic {unknown[0]} in the bag (topics: "
                             f"{', '.join(sorted(types))})")
        order = list(topics)
    else:
        order = sorted(types)

    def of_type(kinds: tuple[str, ...]) -> list[str]:
        return [t for t in order if types[t] in kinds]

    camera = sensor.removesuffix("-inertial")
    images = [t for t in of_type(_IMAGE_TYPES) if "depth" not in t.lower()]
    depth = None
    if camera == "rgbd":
        depth = _pick([t for t in of_type(_IMAGE_TYPES) if "depth" in t.lower()], 1,
                      "depth image", path)[0]
    images = _pick(images, 2 if camera in ("stereo", "rig") else 1, "image", path)
    infos = [t for t in sorted(types) if types[t] == _CAMERA_INFO]
    gyro = accel = None
    if sensor.endswith("-inertial"):
        imus = of_type((_IMU,))
        if not imus:
            raise ValueError(f"{path}: sensor {sensor!r} needs an IMU, and the bag has no "
                             f"{_IMU} topic")
        if len(imus) == 1:
            gyro = accel = imus[0]
        else:
            gyros = [t for t in imus if "gyro" in t.lower()]
            accels = [t for t in imus if "accel" in t.lower()]
            if len(imus) != 2 or len(gyros) != 1 or len(accels) != 1:
                raise ValueError(f"{path}: IMU topics {', '.join(imus)}: expected one, or a "
                                 "gyro and an accel topic; name them (topics=[...]; command "
                                 "line: --topics)")
            gyro, accel = gyros[0], accels[0]
    return BagTopics(tuple(images), depth, tuple(_camera_info_topic(t, infos) for t in images),
                     gyro, accel)


def _camera_from_info(info: Any, topic: str) -> Camera:
    """A raw camera from a CameraInfo message (``K``, ``D``, ``distortion_model``, size)."""
    model = _ROS_DISTORTIONS.get(str(info.distortion_model))
    if model is None:
        raise ValueError(f"{topic}: distortion_model {info.distortion_model!r} is not "
                         f"supported (supported: {', '.join(_ROS_DISTORTIONS)}); give the "
                         "calibration (camera=...; command line: --camera FILE)")
    # ROS 2 names the matrices k and d, ROS 1 K and D.
    K = np.asarray(info.k if hasattr(info, "k") else info.K,
                   dtype=np.float64).reshape(3, 3)
    dist = np.asarray(info.d if hasattr(info, "d") else info.D, dtype=np.float64).reshape(-1)
    sizes = (0, 4, 5) if model == "pinhole" else (4,)
    if dist.size not in sizes:
        raise ValueError(f"{topic}: {dist.size} distortion coefficients for "
                         f"{info.distortion_model} (expected {' or '.join(map(str, sizes))})")
    if model == "pinhole":
        dist = np.append(dist, np.zeros(5 - dist.size))
    try:
        return Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist, int(info.width),
                      int(info.height), model)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{topic}: {err}") from None


def _unite_imu(gyro: list, accel: list, topics: BagTopics, notes: list[str]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_ns, gyro, accel)``: one stream on the gyroscope's stamps, the accelerometer
    interpolated linearly at them; gyroscope samples outside its span are dropped."""
    t_g, w = _sorted_samples(gyro, 1, topics.gyro)
    if topics.gyro == topics.accel:
        return t_g, w, _sorted_samples(gyro, 2, topics.gyro)[1]
    t_a, a = _sorted_samples(accel, 2, topics.accel)
    inside = (t_g >= t_a[0]) & (t_g <= t_a[-1])
    if not inside.any():
        raise ValueError(f"{topics.gyro} and {topics.accel} do not overlap in time: no IMU "
                         "sample can be made")
    if not inside.all():
        notes.append(f"{np.count_nonzero(~inside)} of {t_g.size} {topics.gyro} samples lie "
                     f"outside {topics.accel}'s span and were dropped")
    t_g, w = t_g[inside], w[inside]
    # Interpolated relative to the first accelerometer stamp: ns since 1970 as float64 would
    # keep only ~0.2 us.
    x, xp = (t_g - t_a[0]).astype(np.float64), (t_a - t_a[0]).astype(np.float64)
    united = np.stack([np.interp(x, xp, a[:, k]) for k in range(3)], axis=1)
    return t_g, w, united


def _sorted_samples(samples: list, column: int, topic: Optional[str]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Stamps ``(N,)`` int64 ns (by stamp: bags store messages by arrival) and the ``column``
    of the samples; ``ValueError`` naming the topic for none or a repeated stamp."""
    if not samples:
        raise ValueError(f"{topic}: no IMU messages")
    samples = sorted(samples, key=lambda s: s[0])
    t = np.array([s[0] for s in samples], dtype=np.int64)
    repeated = np.flatnonzero(np.diff(t) == 0)
    if repeated.size:
        raise ValueError(f"{topic}: two samples stamped {t[repeated[0]]} ns")
    return t, np.array([s[column] for s in samples], dtype=np.float64)


def _calibration(camera: Union[Calibration, Camera, str, Path, None]) -> Optional[Calibration]:
    if camera is None or isinstance(camera, Calibration):
        return camera
    if isinstance(camera, Camera):
        return Calibration([camera], [None])
    return load_calibration(camera)


class BagSequence:
    """A ROS bag as a sequence (see the module doc); made by :func:`open_bag`.

    Attributes:
        path, name (the file or folder name without suffix), sensor, topics
        (:class:`BagTopics`), timestamps (``(N,)`` float64 s) and timestamps_ns (int64) of
        the frames (the left / colour image's header stamps), camera (the intrinsics of the
        images returned: rectified for stereo, raw for a rig), is_stereo (stereo and rig),
        is_rectified, baseline_m (stereo, rig), rig and ``load_rig(i)`` (the raw pair),
        rectifier, depth_factor (RGB-D: pixel value per metre of the depth images),
        T_b_c (``(4, 4)``, with an IMU: pose of the returned camera in the body = IMU frame),
        notes (what a user should know: frames without IMU samples, dropped samples).
    """

    has_groundtruth = False

    def __init__(self, path: Path, *, sensor: str, topics: Optional[list[str]],
                 camera: Union[Calibration, Camera, str, Path, None],
                 imu: Union[ImuParams, str, Path, None], depth_scale: Optional[float],
                 pair_tolerance_s: Optional[float]) -> None:
        self.path, self.sensor = path, sensor
        self.name = path.stem if path.is_file() else path.name
        self.notes: list[str] = []
        camera_kind = sensor.removesuffix("-inertial")
        # A rig is the stereo pair left raw (the core matches it along epipolar curves).
        self.is_stereo = camera_kind in ("stereo", "rig")
        self.is_rectified = camera_kind == "stereo"
        with _any_reader()([_reader_path(path)]) as reader:
            self.topics = _find_topics({c.topic: c.msgtype for c in reader.connections},
                                       sensor, path, topics)
            images = self.topics.images + ((self.topics.depth,) if self.topics.depth else ())
            scan = _scan(reader, set(images), {t for t in self.topics.camera_info if t},
                         {t for t in (self.topics.gyro, self.topics.accel) if t})
        for topic in images:
            if not scan.stamps[topic]:
                raise ValueError(f"{path}: topic {topic} holds no messages")
        self._encodings = scan.encodings
        tolerance = (pair_tolerance_s if pair_tolerance_s is not None
                     else STEREO_TOLERANCE_S if self.is_stereo else RGBD_TOLERANCE_S)
        self._frames = self._associate(scan, images, tolerance)
        self.timestamps_ns = np.array([scan.stamps[images[0]][k[0][1]] for k in self._frames],
                                      dtype=np.int64)
        self.timestamps = seconds_from_ns(self.timestamps_ns)
        self._stream = _ImageStream(_reader_path(path), images,
                                    {key: i for i, keys in enumerate(self._frames)
                                     for key in keys})
        gyro, accel = self.topics.gyro, self.topics.accel
        self._imu = (_unite_imu(scan.imu[gyro], scan.imu[accel], self.topics, self.notes)
                     if gyro is not None and accel is not None else None)
        if self._imu is not None:
            before = int(np.searchsorted(self.timestamps_ns, self._imu[0][0]))
            if before:
                self.notes.append(f"{before} frame(s) before the first IMU sample "
                                  f"({seconds_from_ns(self._imu[0][:1])[0]:.6f} s) get no IMU "
                                  "samples")
        self._imu_params = load_imu_params(imu) if isinstance(imu, (str, Path)) else imu
        calibration = _calibration(camera)
        self._set_cameras(calibration, scan)
        self.depth_factor = self._depth_factor(depth_scale, calibration)

    def _associate(self, scan: _Scan, images: tuple[str, ...], tolerance: float
                   ) -> list[tuple[Key, ...]]:
        """The frames: per frame the message of each topic, paired by stamp to the first
        topic's (messages sorted by stamp: bags store them by arrival)."""
        order = {t: np.argsort(np.array(scan.stamps[t], dtype=np.int64), kind="stable")
                 for t in images}
        stamps = {t: seconds_from_ns(np.array(scan.stamps[t], dtype=np.int64)[order[t]])
                  for t in images}
        first = images[0]
        repeated = np.flatnonzero(np.diff(stamps[first]) <= 0)
        if repeated.size:
            raise ValueError(f"{first}: two images stamped {stamps[first][repeated[0]]:.9f} s")
        chosen = np.arange(len(stamps[first]))
        partners: list[np.ndarray] = []
        for topic in images[1:]:
            i, j = associate_greedy(stamps[first][chosen], stamps[topic], tolerance)
            if i.size == 0:
                raise ValueError(f"{self.path}: no {topic} message within {tolerance} s of a "
                                 f"{first} message")
            partners = [p[i] for p in partners] + [j]
            chosen = chosen[i]
        left_out = len(stamps[first]) - chosen.size
        if left_out:
            self.notes.append(f"{left_out} {first} message(s) have no partner within "
                              f"{tolerance} s on {', '.join(images[1:])} and are skipped")
        return [tuple((t, int(order[t][k])) for t, k in zip(images, ks))
                for ks in zip(chosen.tolist(), *(p.tolist() for p in partners))]

    def _set_cameras(self, calibration: Optional[Calibration], scan: _Scan) -> None:
        wanted = 2 if self.is_stereo else 1
        if calibration is None:
            if self.is_stereo:
                raise ValueError(f"{self.path}: stereo needs the rig's extrinsics, which "
                                 "CameraInfo does not give: pass the calibration (camera=...; "
                                 "command line: --camera FILE, e.g. a Kalibr camchain)")
            info_topic = self.topics.camera_info[0]
            if info_topic is None or info_topic not in scan.infos:
                raise ValueError(f"{self.path}: no CameraInfo beside {self.topics.images[0]}: "
                                 "pass the calibration (camera=...; command line: --camera "
                                 "FILE)")
            calibration = Calibration([_camera_from_info(scan.infos[info_topic], info_topic)],
                                      [None])
        if len(calibration.cameras) < wanted:
            raise ValueError(f"{self.path}: stereo needs two cameras in the calibration, it "
                             f"has {len(calibration.cameras)}")
        T_imu_cam0 = calibration.camera_to_imu[0]
        T_b_imu = self._imu_params.T_b_imu if self._imu_params is not None else np.eye(4)
        self._T_b_cam0 = T_b_imu @ T_imu_cam0 if T_imu_cam0 is not None else None
        self.raw_cameras = tuple(calibration.cameras[:wanted])
        self.rectifier: Optional[StereoRectifier] = None
        self.baseline_m: Optional[float] = None
        self.camera = calibration.cameras[0]
        T_cam0_c = np.eye(4)
        if self.is_stereo:
            if calibration.T_left_right is None:
                raise ValueError(f"{self.path}: the calibration does not relate its two "
                                 "cameras (Kalibr: cam1.T_cn_cnm1; ORB-SLAM3: Stereo.T_c1_c2)")
            self._T_left_right = np.asarray(calibration.T_left_right, dtype=np.float64)
            self.baseline_m = float(np.linalg.norm(self._T_left_right[:3, 3]))
            if self.is_rectified:
                self.rectifier = StereoRectifier(calibration.cameras[0], calibration.cameras[1],
                                                 calibration.T_left_right)
                self.camera, T_cam0_c = self.rectifier.camera, self.rectifier.T_left_rect
                self.baseline_m = self.rectifier.baseline_m
        self._T_cam0_c = T_cam0_c

    def _depth_factor(self, depth_scale: Optional[float],
                      calibration: Optional[Calibration]) -> Optional[float]:
        if self.topics.depth is None:
            return None
        encoding = self._encodings[self.topics.depth]
        if encoding == "32FC1":
            if depth_scale not in (None, 1.0):
                raise ValueError(f"{self.topics.depth}: 32FC1 depth is in metres; a depth "
                                 f"scale of {depth_scale} does not apply")
            return 1.0
        if depth_scale is not None:
            return float(check_option("depth_scale", depth_scale))
        given = getattr(calibration, "depth_factor", None) if calibration else None
        return float(given) if given is not None else _ROS_DEPTH_FACTOR_16UC1

    @property
    def T_b_c(self) -> np.ndarray:
        """Pose of the returned camera in the body (IMU) frame: ``T_b_imu @ T_imu_cam0``
        (the calibration's camera-to-IMU pose), then the rectification for stereo."""
        if self._T_b_cam0 is None:
            raise ValueError(f"{self.path}: the calibration gives no camera-IMU pose (Kalibr: "
                             "T_cam_imu; ORB-SLAM3: IMU.T_b_c1)")
        return self._T_b_cam0 @ self._T_cam0_c

    def __len__(self) -> int:
        return len(self._frames)

    def __repr__(self) -> str:
        return f"BagSequence({str(self.path)!r}, frames={len(self)}, sensor={self.sensor!r})"

    @property
    def buffered_peak(self) -> int:
        """The most image messages held at once while reading (a few frames' worth)."""
        return self._stream.peak_buffered

    def _images(self, i: int) -> list[Any]:
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} of a {len(self)}-frame bag")
        return self._stream.take(i, self._frames[i])

    def _decode(self, message: Any, topic: str, colour: bool) -> tuple[np.ndarray, ...]:
        """``(grey,)`` or ``(grey, BGR)`` of an image message (``colour``)."""
        if hasattr(message, "format"):  # CompressedImage: decoded as image files are
            data = np.asarray(message.data, dtype=np.uint8)
            flags = (cv2.IMREAD_GRAYSCALE, cv2.IMREAD_COLOR)[: 1 + colour]
            decoded = [cv2.imdecode(data, f) for f in flags]
            images = tuple(im for im in decoded if im is not None and im.size)
            if len(images) != len(flags):
                raise ValueError(f"{topic}: a {message.format!r} image could not be decoded")
            return images
        image = _raw_pixels(message, topic)
        if image.ndim == 2:
            return (image, image) if colour else (image,)
        conversion = _COLOUR[str(message.encoding)]
        bgr = cv2.cvtColor(image, conversion) if conversion is not None else image
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        return (gray, bgr) if colour else (gray,)

    def load_gray(self, i: int) -> np.ndarray:
        """Frame ``i``'s (left) image in grey, ``(H, W)`` uint8 (rectified for stereo)."""
        gray = self._decode(self._images(i)[0], self.topics.images[0], False)[0]
        return gray if self.rectifier is None else self.rectifier.rectify_left(gray)

    def load_gray_and_color(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i``'s image in grey ``(H, W)`` and colour ``(H, W, 3)`` BGR uint8 (grey
        twice for a grey topic); a compressed image is decoded twice, as image files are
        (``ferroslam.datasets.images.read_gray_and_color``)."""
        if self.rectifier is not None:
            gray = self.load_gray(i)
            return gray, gray
        gray, color = self._decode(self._images(i)[0], self.topics.images[0], True)
        return gray, color

    @property
    def rig(self) -> Optional[Rig]:
        """A stereo bag's RAW cameras as a :class:`~ferroslam.rig.Rig` (body = the left
        camera; the calibration's relative pose), a stereo pair; ``None`` otherwise."""
        if not self.is_stereo:
            return None
        return Rig(self.raw_cameras, (np.eye(4), self._T_left_right), stereo=True)

    def load_rig(self, i: int) -> list[np.ndarray]:
        """Frame ``i``'s RAW images, one per rig camera (left, right), ``(H, W)`` uint8."""
        if not self.is_stereo:
            raise ValueError(f"{self.path} was opened for sensor {self.sensor!r}, not stereo")
        return [self._decode(m, t, False)[0] for m, t in zip(self._images(i), self.topics.images)]

    def load_stereo(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i``'s rectified ``(left, right)`` pair, ``(H, W)`` uint8 each (raw for
        sensor ``rig``)."""
        left, right = self.load_rig(i)
        return (left, right) if self.rectifier is None else self.rectifier.rectify(left, right)

    def load_depth(self, i: int) -> np.ndarray:
        """Frame ``i``'s depth, ``(H, W)`` float32 metres, 0 where there is none."""
        if self.topics.depth is None or self.depth_factor is None:
            raise ValueError(f"{self.path} was opened for sensor {self.sensor!r}, without "
                             "depth")
        raw = _raw_pixels(self._images(i)[-1], self.topics.depth)
        if raw.dtype == np.float32:
            return np.where(np.isfinite(raw), raw, np.float32(0.0)).astype(np.float32)
        # As read_depth does for depth files, so a bag's depth is a folder's bit for bit.
        return raw.astype(np.float32) / np.float32(self.depth_factor)

    def imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t (N,) s, gyro (N, 3) rad/s, accel (N, 3) m/s^2)`` on one time base."""
        if self._imu is None:
            raise ValueError(f"{self.path}: no IMU topic was read")
        t_ns, gyro, accel = self._imu
        return seconds_from_ns(t_ns), gyro, accel

    def imu_params(self) -> ImuParams:
        """The IMU noise model given (``imu=``; command line ``--imu FILE``): a bag holds
        none."""
        if self._imu_params is None:
            raise ValueError(f"{self.path}: the IMU's noise model is not in a bag: pass it "
                             "(imu=FILE; command line: --imu FILE, a Kalibr imu.yaml, EuRoC "
                             "sensor.yaml or ORB-SLAM3 settings)")
        return self._imu_params


def _raw_pixels(message: Any, topic: str) -> np.ndarray:
    """The pixels of a ``sensor_msgs/Image``: ``(H, W)`` uint8 / uint16 / float32, or
    ``(H, W, 3)`` uint8 in the message's channel order; rows may be padded (``step``)."""
    encoding = str(message.encoding)
    if encoding not in _ENCODINGS:
        raise ValueError(f"{topic}: image encoding {encoding!r} is not supported (supported: "
                         f"{', '.join(_ENCODINGS)})")
    dtype = np.dtype(np.uint8 if encoding in _GREY or encoding in _COLOUR
                     else np.float32 if encoding == "32FC1" else np.uint16)
    dtype = dtype.newbyteorder(">" if message.is_bigendian else "<")
    channels = 3 if encoding in _COLOUR else 1
    height, width, step = int(message.height), int(message.width), int(message.step)
    data = np.asarray(message.data, dtype=np.uint8)
    row = width * channels * dtype.itemsize
    if step < row or data.size < step * height:
        raise ValueError(f"{topic}: a {width}x{height} {encoding} image with step {step} "
                         f"holds {data.size} bytes")
    rows = data[: step * height].reshape(height, step)[:, :row]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels)
    pixels = pixels.astype(dtype.newbyteorder("="), copy=False)
    return pixels[:, :, 0] if channels == 1 else pixels


def open_bag(path: Union[str, Path], *, sensor: str, topics: Optional[list[str]] = None,
             camera: Union[Calibration, Camera, str, Path, None] = None,
             imu: Union[ImuParams, str, Path, None] = None,
             depth_scale: Optional[float] = None,
             pair_tolerance_s: Optional[float] = None) -> BagSequence:
    """A ROS 1 ``.bag``, a ROS 2 bag folder (sqlite3 or MCAP) or a ``.mcap`` file as a
    :class:`BagSequence` for ``sensor`` (``"mono"``, ``"stereo"``, ``"rgbd"``, each optionally
    ``"-inertial"``).

    Args:
        topics: the topics to read, in order (left before right); otherwise found by type
            and name (module doc).
        camera: the calibration, a :class:`~ferroslam.calibration.Calibration`, a ``Camera``
            or a file for :func:`~ferroslam.load_calibration`; otherwise the CameraInfo
            beside the image topic (not for stereo: it holds no extrinsics).
        imu: the IMU noise model (``ImuParams`` or a file for ``load_imu_params``), for the
            ``-inertial`` sensors.
        depth_scale: depth pixel value per metre of 16-bit depth (default: the calibration's
            depth factor, else 1000, REP 118's millimetres); 32FC1 depth is metres.
        pair_tolerance_s: the stamp difference allowed in a stereo or colour/depth pair
            (default :data:`STEREO_TOLERANCE_S`, :data:`RGBD_TOLERANCE_S`).

    Raises:
        ImportError: without ``rosbags`` (naming ``pip install 'ferroslam[ros]'``).
        FileNotFoundError: no such file or folder.
        ValueError: naming the bag or topic: a topic missing, unknown or ambiguous, an empty
            one, images without partners, an unsupported encoding, no calibration, no IMU
            for an inertial sensor.
    """
    path = Path(path).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"ROS bag not found: {path}")
    if sensor not in RUN_SENSORS:
        raise ValueError(f"unknown sensor {sensor!r}; expected one of {RUN_SENSORS}")
    if pair_tolerance_s is not None:
        check_option("pair_tolerance_s", pair_tolerance_s)
    if depth_scale is not None:
        check_option("depth_scale", depth_scale)
    try:
        return BagSequence(path, sensor=sensor, topics=topics, camera=camera, imu=imu,
                           depth_scale=depth_scale, pair_tolerance_s=pair_tolerance_s)
    except (ImportError, FileNotFoundError, ValueError, TypeError):
        raise
    except Exception as err:  # rosbags' own errors (a truncated or foreign file)
        raise ValueError(f"{path}: not a ROS bag rosbags can read ({type(err).__name__}: "
                         f"{err})") from None
