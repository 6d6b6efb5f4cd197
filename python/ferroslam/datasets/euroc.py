"""EuRoC MAV sequences in the ASL layout (Burri et al., IJRR 2016).

Layout: ``<seq>/mav0/`` with

* ``cam0/``, ``cam1/``: ``data.csv`` (``#timestamp [ns],filename``), ``data/<filename>``
  (raw, distorted 8-bit images) and ``sensor.yaml`` (``T_BS`` = ``T_b_cam`` 4x4,
  ``intrinsics: [fu, fv, cu, cv]``, radial-tangential ``distortion_coefficients:
  [k1, k2, p1, p2]`` or, with ``distortion_model: equidistant``, the Kannala-Brandt
  ``[k1, k2, k3, k4]``; ``resolution: [w, h]``);
* ``imu0/``: ``data.csv`` (``t_ns, w_xyz [rad/s], a_xyz [m/s^2]``) and ``sensor.yaml``
  (noise densities, random walks, ``rate_hz``, ``T_BS``);
* ``state_groundtruth_estimate0/data.csv`` (optional): ``t_ns, p_RS_R xyz, q_RS wxyz, ...``,
  the pose ``T_w_b`` of the body frame ``b`` (the IMU frame in EuRoC) in the world ``R``.

Left and right frames are paired by EXACT nanosecond timestamp: the EuRoC cameras are
hardware-synchronised, so an unpaired frame means a broken folder and raises ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from .._validate import read_text
from ..calibration import Calibration, ImuParams
from ..camera import Camera
from ..rig import Rig
from ..io import read_asl_floats, read_asl_rows, seconds_from_ns
from ..stereo import StereoRectifier
from ..transforms import poses_from_tum
from .images import read_gray

__all__ = ["EurocFrame", "EurocSequence", "ImuParams", "read_sensor_yaml"]


@dataclass(frozen=True)
class EurocFrame:
    """One cam0 frame and, for stereo, the cam1 frame with the same timestamp."""

    index: int
    timestamp: float  # seconds
    timestamp_ns: int
    left_path: Path
    right_path: Optional[Path]


def _yaml_value(text: str, where: str) -> object:
    if text.startswith("["):
        if not text.endswith("]"):
            raise ValueError(f"{where}: unterminated list {text!r}")
        try:
            return [float(v) for v in text[1:-1].split(",") if v.strip()]
        except ValueError:
            raise ValueError(f"{where}: list of numbers expected, got {text!r}") from None
    try:
        return float(text)
    except ValueError:
        return text.strip("'\"")


def read_sensor_yaml(path: Union[str, Path]) -> dict[str, object]:
    """Parse the small YAML subset of EuRoC ``sensor.yaml`` files.

    Supports ``key: scalar``, ``key: [numbers]`` (which may span lines) and one level of
    indented ``key:`` blocks (``T_BS: {cols, rows, data}``); ``#`` starts a comment. Numbers
    become float, lists of numbers ``list[float]``, blocks ``dict``, other scalars ``str``.

    Raises ``FileNotFoundError`` naming a missing file, ``ValueError`` with file and line for
    a line outside that subset.
    """
    path = Path(path)
    source = read_text(path, "EuRoC sensor file")
    out: dict[str, object] = {}
    block: Optional[dict[str, object]] = None
    pending: Optional[tuple[dict[str, object], str, str, int]] = None  # multi-line list
    for number, line in enumerate(source.splitlines(), start=1):
        text = line.split("#", 1)[0].rstrip()
        if pending is not None:
            target, key, value, start = pending
            value += " " + text.strip()
            if "]" in value:
                target[key] = _yaml_value(value, f"{path}:{start}")
                pending = None
            else:
                pending = (target, key, value, start)
            continue
        if not text.strip() or text.startswith(("%", "---")):
            continue
        key, sep, value = text.strip().partition(":")
        if not sep:
            raise ValueError(f"{path}:{number}: expected 'key: value', got {line.strip()!r}")
        value = value.strip()
        indented = text[0].isspace()
        if indented and block is None:
            raise ValueError(f"{path}:{number}: indented line outside a block: {line.strip()!r}")
        target = block if indented and block is not None else out
        if not indented:
            block = None
        if not value:
            if indented:
                raise ValueError(f"{path}:{number}: nested blocks are not supported")
            block = {}
            out[key] = block
        elif value.startswith("[") and "]" not in value:
            pending = (target, key, value, number)
        else:
            target[key] = _yaml_value(value, f"{path}:{number}")
    if pending is not None:
        raise ValueError(f"{path}:{pending[3]}: unterminated list for {pending[1]!r}")
    return out


def _numbers(yaml: dict, key: str, n: int, path: Path) -> np.ndarray:
    value = yaml.get(key)
    if not isinstance(value, list) or len(value) != n:
        raise ValueError(f"{path}: {key} must be a list of {n} numbers, got {value!r}")
    return np.array(value, dtype=np.float64)


def _number(yaml: dict, key: str, path: Path) -> float:
    value = yaml.get(key)
    if not isinstance(value, float):
        raise ValueError(f"{path}: {key} must be a number, got {value!r}")
    return value


def _T_BS(yaml: dict, path: Path) -> np.ndarray:
    block = yaml.get("T_BS")
    if not isinstance(block, dict) or block.get("rows") != 4.0 or block.get("cols") != 4.0:
        raise ValueError(f"{path}: T_BS must be a block with rows: 4, cols: 4 and data")
    T = _numbers(block, "data", 16, path).reshape(4, 4)
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValueError(f"{path}: T_BS is not a rigid transform")
    return T


# sensor.yaml distortion models -> our camera models; "equidistant" is Kannala-Brandt (the
# ASL layout of TUM-VI and other fisheye rigs).
_DISTORTION_MODELS = {"radial-tangential": "pinhole", "radtan": "pinhole",
                      "equidistant": "kannala_brandt"}


def _read_camera(folder: Path) -> tuple[Camera, np.ndarray]:
    """Raw camera and ``T_b_cam`` from ``sensor.yaml``: radial-tangential ``[k1, k2, p1,
    p2]`` (k3 = 0) or equidistant ``[k1, k2, k3, k4]`` (Kannala-Brandt)."""
    path = folder / "sensor.yaml"
    yaml = read_sensor_yaml(path)
    if yaml.get("camera_model", "pinhole") != "pinhole":
        raise ValueError(f"{path}: camera_model {yaml['camera_model']!r} is not supported "
                         "(only pinhole)")
    distortion = yaml.get("distortion_model", "radial-tangential")
    if distortion not in _DISTORTION_MODELS:
        raise ValueError(f"{path}: distortion_model {distortion!r} is not supported "
                         f"(supported: {', '.join(_DISTORTION_MODELS)})")
    model = _DISTORTION_MODELS[str(distortion)]
    fu, fv, cu, cv = _numbers(yaml, "intrinsics", 4, path)
    dist = _numbers(yaml, "distortion_coefficients", 4, path)
    if model == "pinhole":
        dist = np.append(dist, 0.0)
    width, height = _numbers(yaml, "resolution", 2, path)
    camera = Camera(fu, fv, cu, cv, dist, int(width), int(height), model)
    return camera, _T_BS(yaml, path)


class EurocSequence:
    """A EuRoC MAV sequence (see the module doc for the layout).

    Args:
        path: the sequence folder (containing ``mav0/``) or ``mav0/`` itself.
        stereo: pair cam0 with cam1 and rectify both. Then ``camera`` is the rectified
            pinhole (``dist`` zeros) and ``load_gray``/``load_stereo`` return rectified
            images. With ``stereo=False`` ``camera`` is raw cam0 with its distortion and
            ``load_gray`` returns raw cam0 images.
        rectify: with ``stereo``, ``False`` leaves the pair raw: ``load_stereo`` and
            ``load_gray`` return the raw images, ``camera`` is raw cam0, and the rig is
            ``left_camera``, ``right_camera``, ``T_left_right`` (for
            ``StereoVSlam.from_raw``, which rectifies internally).
        calibration: replaces the cameras of the ``sensor.yaml`` files (``ferroslam run
            --camera FILE``): its raw cameras, their relative pose ``T_left_right`` and, where
            it gives them, their poses in the IMU (``T_b_cam = T_b_imu @ T_imu_cam``, with
            ``T_b_imu`` from ``imu0/sensor.yaml``); without camera-IMU poses the
            ``sensor.yaml`` ones stay.

    Attributes:
        timestamps: ``(N,)`` float64 seconds; ``timestamps_ns``: ``(N,)`` int64 nanoseconds.
        camera, is_stereo, is_rectified, baseline_m (metres, ``None`` if mono).
        raw_cameras: ``(cam0, cam1)`` raw intrinsics; ``T_b_cam0``, ``T_b_cam1``: ``(4, 4)``
            raw camera poses in the body frame (``T_BS`` of the sensor.yaml files).
        left_camera, right_camera: raw cam0 and cam1 (``None`` if mono), with their
            distortion; ``T_left_right``: ``(4, 4)`` pose of raw cam1 in raw cam0
            (``p_left = T_left_right @ p_right``, ``inv(T_b_cam0) @ T_b_cam1``).
        rectifier: the :class:`~ferroslam.stereo.StereoRectifier` (``None`` if mono or
            raw).
        T_b_c: ``(4, 4)`` pose in the body frame of the camera whose images are returned:
            ``T_b_cam0`` (mono or raw) or ``T_b_cam0 @ rectifier.T_left_rect`` (rectified
            stereo).

    Raises:
        FileNotFoundError: a missing folder, ``sensor.yaml`` or ``data.csv`` (named).
        ValueError: malformed files, timestamps out of order, cam0/cam1 timestamps that do not
            pair exactly, unsupported camera or distortion model.
    """

    def __init__(self, path: Union[str, Path], *, stereo: bool = True,
                 rectify: bool = True, calibration: Optional[Calibration] = None) -> None:
        path = Path(path).expanduser().resolve()
        if not path.is_dir():
            raise FileNotFoundError(f"EuRoC sequence folder not found: {path}")
        self.mav0 = path if path.name == "mav0" or not (path / "mav0").is_dir() else path / "mav0"
        self.path = self.mav0.parent if self.mav0.name == "mav0" else self.mav0
        self.is_stereo = bool(stereo)
        self.is_rectified = self.is_stereo and bool(rectify)

        cam0, self.T_b_cam0 = _read_camera(self.mav0 / "cam0")
        if calibration is not None:
            cam0, self.T_b_cam0 = self._given_camera(calibration, 0, self.T_b_cam0)
        left_ns, left_files = self._read_frames("cam0")
        right_files: list[Optional[Path]] = [None] * len(left_files)
        self.rectifier: Optional[StereoRectifier] = None
        self.baseline_m: Optional[float] = None
        self.raw_cameras: tuple[Camera, Optional[Camera]] = (cam0, None)
        self.T_b_cam1: Optional[np.ndarray] = None
        self.left_camera: Optional[Camera] = None
        self.right_camera: Optional[Camera] = None
        self.T_left_right: Optional[np.ndarray] = None
        if self.is_stereo:
            cam1, self.T_b_cam1 = _read_camera(self.mav0 / "cam1")
            if calibration is not None:
                cam1, self.T_b_cam1 = self._given_camera(calibration, 1, self.T_b_cam1)
            self.raw_cameras = (cam0, cam1)
            self.left_camera, self.right_camera = cam0, cam1
            right_ns, files = self._read_frames("cam1")
            self._check_paired(left_ns, right_ns)
            right_files = list(files)
            self.T_left_right = (calibration.T_left_right
                                 if calibration is not None and calibration.T_left_right
                                 is not None else np.linalg.inv(self.T_b_cam0) @ self.T_b_cam1)
        if self.is_rectified:
            self.rectifier = StereoRectifier(cam0, cam1, self.T_left_right)
            self.baseline_m = self.rectifier.baseline_m
            self.camera = self.rectifier.camera
            self.T_b_c = self.T_b_cam0 @ self.rectifier.T_left_rect
        elif self.is_stereo:
            self.baseline_m = float(np.linalg.norm(self.T_left_right[:3, 3]))
            self.camera = cam0
            self.T_b_c = self.T_b_cam0.copy()
        else:
            self.camera = cam0
            self.T_b_c = self.T_b_cam0.copy()
        self.timestamps_ns = left_ns
        self.timestamps = seconds_from_ns(left_ns)
        self.frames = [
            EurocFrame(k, float(t), int(ns), left, right)
            for k, (t, ns, left, right) in enumerate(
                zip(self.timestamps.tolist(), left_ns.tolist(), left_files, right_files)
            )
        ]

    def _given_camera(self, calibration: Calibration, k: int, T_b_cam: np.ndarray
                      ) -> tuple[Camera, np.ndarray]:
        """Camera ``k`` of ``calibration`` and its pose in the body frame (the
        ``sensor.yaml`` one, ``T_b_cam``, where the calibration gives none)."""
        if len(calibration.cameras) <= k:
            raise ValueError(f"the calibration given for {self.mav0} has "
                             f"{len(calibration.cameras)} camera(s); stereo needs 2")
        T_imu_cam = calibration.camera_to_imu[k]
        if T_imu_cam is not None:
            has_imu = (self.mav0 / "imu0" / "sensor.yaml").is_file()
            T_b_cam = (self.imu_params().T_b_imu if has_imu else np.eye(4)) @ T_imu_cam
        return calibration.cameras[k], T_b_cam

    def _read_frames(self, cam: str) -> tuple[np.ndarray, list[Path]]:
        path = self.mav0 / cam / "data.csv"
        stamps, rows = read_asl_rows(path, 2, f"EuRoC {cam} list")
        if not rows:
            raise ValueError(f"{path}: EuRoC {cam} list lists no frames")
        return stamps, [self.mav0 / cam / "data" / fields[1] for fields in rows]

    def _check_paired(self, left_ns: np.ndarray, right_ns: np.ndarray) -> None:
        if np.array_equal(left_ns, right_ns):
            return
        only_left = np.setdiff1d(left_ns, right_ns)[:3].tolist()
        only_right = np.setdiff1d(right_ns, left_ns)[:3].tolist()
        raise ValueError(
            f"cam0 and cam1 timestamps of {self.mav0} do not pair exactly (the EuRoC cameras "
            f"are synchronised): {len(left_ns)} vs {len(right_ns)} frames, only in cam0 "
            f"(first 3): {only_left}, only in cam1: {only_right}"
        )

    @property
    def name(self) -> str:
        """Sequence folder name, e.g. ``V1_01_easy``."""
        return self.path.name

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> EurocFrame:
        return self.frames[i]

    def __iter__(self) -> Iterator[EurocFrame]:
        return iter(self.frames)

    def __repr__(self) -> str:
        raw = "" if self.is_rectified or not self.is_stereo else ", rectify=False"
        return (f"EurocSequence({str(self.path)!r}, frames={len(self)}, "
                f"stereo={self.is_stereo}{raw})")

    def _read(self, path: Path, camera: Camera) -> np.ndarray:
        image = read_gray(path)
        if image.shape != (camera.height, camera.width):
            raise ValueError(
                f"{path} is {image.shape[1]}x{image.shape[0]}, sensor.yaml says "
                f"{camera.width}x{camera.height}"
            )
        return image

    def load_gray(self, i: int) -> np.ndarray:
        """cam0 image of frame ``i`` (rectified if stereo): ``(H, W)`` uint8."""
        image = self._read(self.frames[i].left_path, self.raw_cameras[0])
        return image if self.rectifier is None else self.rectifier.rectify_left(image)

    def load_stereo(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Rectified ``(left, right)`` images of frame ``i``, both ``(H, W)`` uint8 (raw
        with ``rectify=False``).

        Raises ``ValueError`` if the sequence was opened with ``stereo=False``.
        """
        frame = self.frames[i]
        cam1 = self.raw_cameras[1]
        if not self.is_stereo or frame.right_path is None or cam1 is None:
            raise ValueError(f"{self.path} was opened with stereo=False")
        left = self._read(frame.left_path, self.raw_cameras[0])
        right = self._read(frame.right_path, cam1)
        return (left, right) if self.rectifier is None else self.rectifier.rectify(left, right)

    @property
    def rig(self) -> Optional[Rig]:
        """The RAW cameras as a :class:`~ferroslam.rig.Rig`: cam0 and cam1 with their
        distortion, at ``T_b_cam0`` / ``T_b_cam1`` in the body frame, a stereo pair;
        ``None`` with ``stereo=False``."""
        if not self.is_stereo or self.raw_cameras[1] is None:
            return None
        T_b_cam1 = self.T_b_cam0 @ self.T_left_right  # the pair's own relative pose
        return Rig(self.raw_cameras, (self.T_b_cam0, T_b_cam1), stereo=True)

    def load_rig(self, i: int) -> list[np.ndarray]:
        """The RAW images of frame ``i``, one per rig camera (cam0, cam1), ``(H, W)`` uint8,
        whether or not the sequence rectifies its pairs."""
        frame = self.frames[i]
        if not self.is_stereo or frame.right_path is None or self.raw_cameras[1] is None:
            raise ValueError(f"{self.path} was opened with stereo=False")
        return [self._read(frame.left_path, self.raw_cameras[0]),
                self._read(frame.right_path, self.raw_cameras[1])]

    @property
    def groundtruth_path(self) -> Path:
        return self.mav0 / "state_groundtruth_estimate0" / "data.csv"

    @property
    def has_groundtruth(self) -> bool:
        return self.groundtruth_path.is_file()

    def groundtruth(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth ``(timestamps (M,) s, T_w_c (M, 4, 4))`` of the returned camera frame.

        Every row of the state estimate, converted from the body pose:
        ``T_w_c = T_w_b @ T_b_c``, i.e. ``T_w_b @ T_b_cam0`` (mono, raw stereo) or
        ``T_w_b @ T_b_cam0 @ [R1^T | 0]`` (rectified stereo: the rectified left frame). The world is
        EuRoC's ``R`` (Vicon) frame. Rows are not matched to frames (times may differ by
        a few hundred ns).

        Raises ``FileNotFoundError`` naming a missing file, ``ValueError`` for bad rows.
        """
        path = self.groundtruth_path
        stamps, rows = read_asl_rows(path, 8, "EuRoC ground truth")
        values = read_asl_floats(path, rows, slice(1, 8))  # p xyz, q wxyz
        T_w_b = poses_from_tum(np.concatenate([values[:, :3], values[:, 4:7], values[:, 3:4]], 1))
        return seconds_from_ns(stamps), T_w_b @ self.T_b_c

    def imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU readings ``(t (N,) s, gyro (N, 3) rad/s, acc (N, 3) m/s^2)`` in the IMU frame.

        Raises ``FileNotFoundError`` naming ``imu0/data.csv`` and ``ValueError`` (file and
        line) for malformed rows or timestamps out of order, or (file) for no samples.
        """
        path = self.mav0 / "imu0" / "data.csv"
        stamps, rows = read_asl_rows(path, 7, "EuRoC IMU file")
        if not rows:  # an inertial run without samples would never align
            raise ValueError(f"{path}: EuRoC IMU file holds no samples")
        values = read_asl_floats(path, rows, slice(1, 7))
        return seconds_from_ns(stamps), values[:, :3], values[:, 3:6]

    def imu_params(self) -> ImuParams:
        """Noise model and ``T_b_imu`` from ``imu0/sensor.yaml`` (``FileNotFoundError`` if
        missing, ``ValueError`` naming a missing key)."""
        path = self.mav0 / "imu0" / "sensor.yaml"
        yaml = read_sensor_yaml(path)
        names = ("gyroscope_noise_density", "gyroscope_random_walk",
                 "accelerometer_noise_density", "accelerometer_random_walk", "rate_hz")
        return ImuParams(*(_number(yaml, k, path) for k in names), T_b_imu=_T_BS(yaml, path))
