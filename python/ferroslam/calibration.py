"""Camera and IMU calibration read from the files users already have.

:func:`load_calibration` detects the format from the keys a file holds, not from its name, so
a renamed file still loads:

* ORB-SLAM3 settings, format ``File.version: "1.0"`` (``Camera1.fx``, ``Camera2.*``,
  ``Stereo.T_c1_c2``, ``IMU.T_b_c1``, ``IMU.Noise*``) and the legacy / ORB-SLAM2 one
  (``Camera.fx``, ``Tbc``, ``IMU.*``), which also covers flat TUM-style ``camera.yaml`` files
  (``fx fy cx cy k1 k2 p1 p2 k3 width height``, and ``model: kannala_brandt`` with
  ``k1 k2 k3 k4``); ``Camera.type`` ``"PinHole"`` or ``"KannalaBrandt8"`` (``k1..k4``);
* Kalibr camchains (``cam0: {camera_model, intrinsics, distortion_model,
  distortion_coeffs, resolution, T_cam_imu, T_cn_cnm1}``), ``distortion_model`` ``radtan``,
  ``none`` or ``equidistant`` (Kannala-Brandt);
* OpenCV FileStorage camera files (``camera_matrix``, ``distortion_coefficients``,
  ``image_width``, ``image_height``, as OpenCV's calibration sample writes them) and ROS
  ``camera_info`` YAML (the same keys, matrices as ``{rows, cols, data}``; ``plumb_bob`` or
  ``equidistant`` distortion).

Rolling shutter: a camera's readout (seconds from its first row to its last, rows top first;
``Camera.rolling_shutter_readout_s``, 0 = global shutter when absent) is read from Kalibr's
``line_delay`` (seconds per row, times the image height), a flat file's
``rolling_shutter_readout_s`` and ORB-SLAM-style settings' ``Camera.rollingShutterReadout`` /
``Camera1.rollingShutterReadout`` (seconds; our key, as ORB-SLAM models no rolling shutter).

Masks: a flat ``camera.yaml`` may name a static keypoint mask, ``mask: FILE`` (an image read
grey, relative to the calibration file; 0 = no features there, see ``Camera.mask``).

Kannala-Brandt (fisheye) cameras come out as ``Camera(model="kannala_brandt")`` with the four
coefficients of OpenCV's ``cv2.fisheye``, which all these formats share.

:func:`load_imu_params` reads IMU noise from Kalibr IMU files, EuRoC ``imu0/sensor.yaml`` and
ORB-SLAM settings; ``load_calibration(path, imu_path=...)`` joins it to a camchain.

Files written by OpenCV (a ``%YAML:1.0`` header or ``!!opencv-matrix`` values) are read with
``cv2.FileStorage``, the reader they were written for; all others with PyYAML.
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import cv2
import numpy as np
import numpy.typing
import yaml

from .camera import Camera
from ._validate import read_text, rigid_transform
from .transforms import inverse


@dataclass(frozen=True)
class ImuParams:
    """IMU noise model and mounting (continuous-time densities), as EuRoC's
    ``imu0/sensor.yaml`` and Kalibr's ``imu.yaml`` give them.

    ``T_b_imu``: ``(4, 4)`` pose of the IMU in the body frame (identity in EuRoC).
    """

    gyroscope_noise_density: float  # rad / s / sqrt(Hz)
    gyroscope_random_walk: float  # rad / s^2 / sqrt(Hz)
    accelerometer_noise_density: float  # m / s^2 / sqrt(Hz)
    accelerometer_random_walk: float  # m / s^3 / sqrt(Hz)
    rate_hz: float
    T_b_imu: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        # Checked before any arithmetic (1 / rate_hz, noise covariances) can use them.
        for name in ("gyroscope_noise_density", "gyroscope_random_walk",
                     "accelerometer_noise_density", "accelerometer_random_walk", "rate_hz"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
                raise TypeError(f"imu {name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"imu {name} must be a positive finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, "T_b_imu", rigid_transform(self.T_b_imu, "imu T_b_imu"))

    @classmethod
    def of(cls, imu: Any) -> "ImuParams":
        """``imu`` as ``ImuParams``: one already, or a dict of its fields (``T_b_imu``
        optional, identity).

        Raises ``TypeError`` naming ``imu`` for anything else (a string such as ``"euroc"``),
        ``ValueError`` naming a missing or unknown key, and as the constructor for values.
        """
        if isinstance(imu, cls):
            return imu
        if not isinstance(imu, dict):
            raise TypeError(f"imu must be ferroslam.calibration.ImuParams or a dict of its "
                            f"fields, got {type(imu).__name__} {imu!r}"[:200])
        names = [f.name for f in fields(cls)]
        unknown = sorted(str(k) for k in imu if k not in names)
        if unknown:
            raise ValueError(f"imu: unknown key(s) {', '.join(unknown)} (expected "
                             f"{', '.join(names)})")
        missing = [n for n in names[:5] if n not in imu]
        if missing:
            raise ValueError(f"imu: missing key(s) {', '.join(missing)}")
        return cls(**imu)


__all__ = ["Calibration", "ImuParams", "load_calibration", "load_imu_params", "load_mask",
           "read_camera_yaml"]

# Largest deviation of R R^T from I, and of the last row from (0 0 0 1), in a rigid transform:
# leaves room for matrices stored as float32 (dt: f) or printed with ~7 digits.
_RIGID_TOL = 1e-6
# Coefficient keys of each camera model in ORB-SLAM settings and flat files.
_DIST_KEYS = {"pinhole": ("k1", "k2", "p1", "p2", "k3"), "kannala_brandt": ("k1", "k2", "k3", "k4")}
# Camera models as each format names them -> ours.
_ORBSLAM_MODELS = {"PinHole": "pinhole", "KannalaBrandt8": "kannala_brandt"}
_FLAT_MODELS = {"pinhole": "pinhole", "kannala_brandt": "kannala_brandt"}
_KALIBR_DISTORTIONS = {"radtan": "pinhole", "none": "pinhole", "equidistant": "kannala_brandt"}
_ROS_DISTORTIONS = {"plumb_bob": "pinhole", "equidistant": "kannala_brandt"}
# ImuParams fields in order, then the rate, as each format names them.
_ORBSLAM_IMU_KEYS = ("IMU.NoiseGyro", "IMU.GyroWalk", "IMU.NoiseAcc", "IMU.AccWalk",
                     "IMU.Frequency")
_KALIBR_IMU_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk",
                    "accelerometer_noise_density", "accelerometer_random_walk")
# Key prefixes of a camera's fields in legacy ORB-SLAM settings and flat camera files.
_FLAT_PREFIXES = ("Camera.", "Camera1.", "")
# The rolling-shutter readout (seconds, first row to last; absent = 0, a global shutter), one
# key per format: a flat camera.yaml's, ORB-SLAM-style settings' (after the camera's prefix:
# ``Camera.``, ``Camera1.``; our key, ORB-SLAM has none), and Kalibr's per-row delay (seconds
# per row, times the image height).
_FLAT_READOUT_KEY = "rolling_shutter_readout_s"
# A flat camera.yaml's static mask image, relative to the file.
_FLAT_MASK_KEY = "mask"
_ORBSLAM_READOUT_KEY = "rollingShutterReadout"
_KALIBR_LINE_DELAY_KEY = "line_delay"

_MISSING = object()


@dataclass(frozen=True)
class Calibration:
    """Intrinsics of each camera, their poses in the IMU frame and the IMU noise model.

    Attributes:
        cameras: one :class:`~ferroslam.Camera` per camera (raw intrinsics with their lens
            model and distortion: ``"pinhole"`` radial-tangential or ``"kannala_brandt"``),
            in file order: ``cameras[0]`` is the left camera.
        camera_to_imu: per camera, ``T_imu_cam``, the ``(4, 4)`` float64 pose of the camera in
            the IMU frame (``p_imu = T_imu_cam @ p_cam``), exactly what the vSLAM objects'
            ``camera_to_imu_transform=`` takes; ``None`` where the file gives no IMU.
        imu: IMU noise densities, random walks and rate, or ``None``.
        T_left_right: ``(4, 4)`` pose of ``cameras[1]`` in ``cameras[0]``'s frame, ``None``
            unless the file has two cameras and relates them.
        depth_factor: depth pixel value per metre of the RGB-D camera's depth images
            (``metres = pixel / depth_factor``: 5000 for TUM, 1000 for millimetres), ``None``
            where the file gives none; see :data:`DEPTH_FACTOR_KEYS`.
        T_c0_cam: per camera, its ``(4, 4)`` pose in ``cameras[0]``'s frame (``p_0 = T @
            p``) from the file's own chain of relative poses (Kalibr ``T_cn_cnm1``, ORB-SLAM3
            ``Stereo.T_c1_c2``), ``None`` from the first camera the chain does not reach;
            derived from ``T_left_right`` for two cameras when not given.
    """

    cameras: list[Camera]
    camera_to_imu: list[Optional[np.ndarray]]
    imu: Optional[ImuParams] = None
    T_left_right: Optional[np.ndarray] = None
    depth_factor: Optional[float] = None
    T_c0_cam: list[Optional[np.ndarray]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.T_c0_cam and self.T_left_right is not None and len(self.cameras) == 2:
            object.__setattr__(self, "T_c0_cam", [np.eye(4), np.asarray(self.T_left_right)])

    @property
    def baseline_m(self) -> Optional[float]:
        """Distance between the two camera centres in metres (``None`` without
        ``T_left_right``)."""
        if self.T_left_right is None:
            return None
        return float(np.linalg.norm(self.T_left_right[:3, 3]))


def load_calibration(path: Union[str, Path],
                     imu_path: Union[str, Path, None] = None) -> Calibration:
    """Read the cameras (and IMU, if the file has one) of a calibration file.

    Args:
        path: an ORB-SLAM3 / ORB-SLAM2 settings file, a flat ``camera.yaml``, a Kalibr
            camchain, an OpenCV FileStorage camera file or a ROS ``camera_info`` YAML (see the
            module doc); the format is detected from the keys found.
        imu_path: a file for :func:`load_imu_params` (a Kalibr ``imu.yaml`` next to a
            camchain); its parameters replace any IMU noise in ``path``.

    Raises:
        FileNotFoundError: a file does not exist (named).
        ValueError: naming the file and field: an unknown format, a missing field, a value
            that is not a number, a matrix of the wrong shape, a transform that is not rigid,
            an unsupported camera or distortion model (the supported ones listed).
    """
    fields = _Fields(_read_document(Path(path)), Path(path))
    calibration = replace(_reader_for(fields)(fields), depth_factor=_depth_factor(fields))
    if imu_path is not None:
        calibration = replace(calibration, imu=load_imu_params(imu_path))
    return calibration


def load_imu_params(path: Union[str, Path]) -> ImuParams:
    """IMU noise model of a Kalibr IMU file (``imu0: {...}`` or flat), EuRoC
    ``imu0/sensor.yaml`` or the ``IMU.*`` keys of ORB-SLAM settings.

    Raises ``FileNotFoundError`` naming a missing file, ``ValueError`` naming the file and
    field for a file without IMU noise, a missing, non-numeric or non-positive value.
    """
    fields = _Fields(_read_document(Path(path)), Path(path))
    imu = _imu_params(fields)
    if imu is None:
        raise ValueError(f"{path}: no IMU noise parameters (expected Kalibr "
                         "gyroscope_noise_density ... or ORB-SLAM IMU.NoiseGyro ...)")
    return imu


# --- reading a document ---------------------------------------------------------------------


def _read_document(path: Path) -> dict[str, Any]:
    """The file's top-level mapping, as plain dicts, lists, numbers and strings."""
    text = read_text(path, "calibration file")
    document = (_read_filestorage(path) if text.startswith("%YAML:") or "!!opencv-matrix" in text
                else _read_yaml(path, text))
    if not isinstance(document, dict):
        raise ValueError(f"{path}: expected a mapping of calibration fields, got "
                         f"{type(document).__name__}")
    return document


def _read_yaml(path: Path, text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ValueError(f"{path}: not valid YAML: {error}") from None


def _read_filestorage(path: Path) -> Any:
    # cv2 reports parse errors as cv2.error, or as a SystemError wrapping it.
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:
        cause = error.__cause__ or error
        raise ValueError(f"{path}: not a valid OpenCV FileStorage file: {cause}") from None
    try:
        return _node_value(storage.root())
    finally:
        storage.release()


def _node_value(node: cv2.FileNode) -> Any:
    """A FileStorage node as plain Python. ``!!opencv-matrix`` nodes stay mappings
    ``{rows, cols, dt, data}`` whose ``data`` is read as float64 even when ``dt: f``, so the
    digits in the file are kept."""
    if node.isMap():
        return {key: _node_value(node.getNode(key)) for key in node.keys()}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


class _Fields:
    """The fields of one file (or one section of it), typed on access; every error names the
    file and the field."""

    def __init__(self, values: dict[str, Any], path: Path, prefix: str = "") -> None:
        self.values, self.path, self.prefix = values, path, prefix

    def __contains__(self, key: str) -> bool:
        return key in self.values

    def error(self, key: str, message: str) -> ValueError:
        return ValueError(f"{self.path}: {self.prefix}{key} {message}")

    def get(self, key: str, default: Any = _MISSING) -> Any:
        if key in self.values and self.values[key] is not None:
            return self.values[key]
        if default is _MISSING:
            raise ValueError(f"{self.path}: missing field {self.prefix}{key}")
        return default

    def section(self, key: str) -> _Fields:
        value = self.get(key)
        if not isinstance(value, dict):
            raise self.error(key, f"must be a mapping of fields, got {value!r}")
        return _Fields(value, self.path, f"{self.prefix}{key}.")

    def text(self, key: str, default: Any = _MISSING) -> str:
        return str(self.get(key, default))

    def number(self, key: str, default: Any = _MISSING) -> float:
        value = self.get(key, default)
        # PyYAML follows YAML 1.1, which reads "1e-3" (no dot) as a string.
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise self.error(key, f"is not a number: {value!r}")
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value!r}")
        return float(value)

    def integer(self, key: str, default: Any = _MISSING) -> int:
        value = self.number(key, default)
        if not value.is_integer():
            raise self.error(key, f"must be a whole number, got {value!r}")
        return int(value)

    def array(self, key: str, shape: Optional[Sequence[int]] = None) -> np.ndarray:
        """A list (flat or nested), or a ``{rows, cols, data}`` matrix (``!!opencv-matrix``,
        ROS, EuRoC); a flat list is reshaped to ``shape``, otherwise its shape must match."""
        value = self.get(key)
        data = value.get("data") if isinstance(value, dict) else value
        try:
            array = np.array(data, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(key, f"must hold numbers, got {value!r}") from None
        if isinstance(value, dict) and "rows" in value and "cols" in value:
            rows, cols = value["rows"], value["cols"]
            if not all(isinstance(n, int) and not isinstance(n, bool) for n in (rows, cols)):
                raise self.error(key, f"rows and cols must be integers, got {rows!r}, {cols!r}")
            if array.size != rows * cols:
                raise self.error(key, f"declares {rows}x{cols} but holds {array.size} values")
            array = array.reshape(rows, cols)
        if shape is not None and array.ndim == 1 and array.size == math.prod(shape):
            array = array.reshape(shape)
        if shape is not None and array.shape != tuple(shape):
            raise self.error(key, f"must have shape {tuple(shape)}, got {array.shape}")
        if not np.all(np.isfinite(array)):
            raise self.error(key, "holds a non-finite value")
        return array

    def pose(self, key: str) -> np.ndarray:
        """A ``(4, 4)`` rigid transform: a non-rigid one means a misread or mistyped file."""
        T = self.array(key, (4, 4))
        R = T[:3, :3]
        if (not np.allclose(R @ R.T, np.eye(3), atol=_RIGID_TOL) or np.linalg.det(R) < 0
                or not np.allclose(T[3], [0, 0, 0, 1], atol=_RIGID_TOL)):
            raise self.error(key, "is not a rigid transform (rotation not orthonormal or last "
                                  "row not 0 0 0 1)")
        return T

    def model(self, key: str, default: Any, supported: Sequence[str]) -> str:
        """The camera / distortion model named by ``key``, refused unless ``supported``
        (the error lists them)."""
        value = self.text(key, default)
        if value in supported:
            return value
        raise self.error(key, f"{value!r} is not supported (supported: "
                              f"{', '.join(supported)})")

    def camera(self, where: str, fx: float, fy: float, cx: float, cy: float,
               dist: np.typing.ArrayLike, width: int, height: int,
               model: str = "pinhole", readout_s: float = 0.0) -> Camera:
        """A :class:`Camera` of ``model`` (``readout_s``: its rolling-shutter readout),
        its validation errors naming the file and ``where``."""
        try:
            return Camera(fx, fy, cx, cy, np.array(dist, dtype=np.float64), width, height,
                          model, rolling_shutter_readout_s=readout_s)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{self.path}: {self.prefix}{where}: {error}") from None


# --- formats ----------------------------------------------------------------------------------


def _reader_for(fields: _Fields) -> Callable[[_Fields], Calibration]:
    """The reader of the format whose keys ``fields`` holds."""
    if "File.version" in fields:
        return _read_orbslam3
    if any(prefix + "fx" in fields for prefix in _FLAT_PREFIXES):
        return _read_orbslam_legacy
    if "cam0" in fields:
        return _read_kalibr_camchain
    if "camera_matrix" in fields:
        return _read_opencv_camera
    if "imu0" in fields or "gyroscope_noise_density" in fields:
        raise ValueError(f"{fields.path}: holds IMU noise only; read it with "
                         "load_imu_params, or pass it as load_calibration(..., imu_path=)")
    keys = ", ".join(list(fields.values)[:8])
    raise ValueError(
        f"{fields.path}: not a calibration format ferroslam knows (ORB-SLAM settings, flat "
        f"fx/fy/cx/cy, Kalibr camchain, OpenCV or ROS camera file); top-level keys: {keys}")


def _prefixed_camera(fields: _Fields, prefix: str, width: int, height: int,
                     model: str) -> Camera:
    """An ORB-SLAM-style camera of ``model``: ``<prefix>fx`` ... and the model's
    coefficients (``<prefix>k1 k2 p1 p2 k3`` or ``<prefix>k1 k2 k3 k4``), absent ones 0, and
    the readout ``<prefix>rollingShutterReadout`` (``rolling_shutter_readout_s`` in a flat
    file), seconds, absent 0."""
    fx, fy, cx, cy = (fields.number(prefix + key) for key in ("fx", "fy", "cx", "cy"))
    dist = [fields.number(prefix + key, 0.0) for key in _DIST_KEYS[model]]
    readout_key = prefix + _ORBSLAM_READOUT_KEY if prefix else _FLAT_READOUT_KEY
    readout_s = fields.number(readout_key, 0.0)
    where = readout_key if readout_key in fields else prefix + "fx"
    return fields.camera(where, fx, fy, cx, cy, dist, width, height, model, readout_s)


def _orbslam_model(fields: _Fields) -> str:
    """Our model name for ``Camera.type`` (ORB-SLAM's default ``PinHole``)."""
    return _ORBSLAM_MODELS[fields.model("Camera.type", "PinHole", tuple(_ORBSLAM_MODELS))]


def _read_orbslam3(fields: _Fields) -> Calibration:
    """ORB-SLAM3 settings format 1.0: ``Camera1.*`` (and ``Camera2.*`` with
    ``Stereo.T_c1_c2``), shared ``Camera.width/height``, ``IMU.T_b_c1`` = ``T_imu_c1`` (the
    body frame is the IMU)."""
    fields.model("File.version", _MISSING, ("1.0",))
    model = _orbslam_model(fields)
    size = fields.integer("Camera.width"), fields.integer("Camera.height")
    cameras = [_prefixed_camera(fields, "Camera1.", *size, model)]
    T_c1_c2 = None
    if "Camera2.fx" in fields:
        cameras.append(_prefixed_camera(fields, "Camera2.", *size, model))
        T_c1_c2 = fields.pose("Stereo.T_c1_c2")
    T_b_c1 = fields.pose("IMU.T_b_c1") if "IMU.T_b_c1" in fields else None
    camera_to_imu = [T_b_c1]
    if T_c1_c2 is not None:
        camera_to_imu.append(None if T_b_c1 is None else T_b_c1 @ T_c1_c2)
    return Calibration(cameras, camera_to_imu, _imu_params(fields), T_c1_c2)


def _read_orbslam_legacy(fields: _Fields) -> Calibration:
    """Legacy ORB-SLAM settings (``Camera.fx``, ``Tbc`` = ``T_imu_cam``, ``IMU.*``) and flat
    ``camera.yaml`` files (``fx`` or ``Camera1.fx`` ... without ``File.version``). A missing
    size is 640x480, as ``read_camera_yaml`` always assumed for TUM ``camera.yaml`` files.
    The model is ``model:`` in a flat file (``pinhole`` or ``kannala_brandt``), else
    ``Camera.type``."""
    prefix = next(prefix for prefix in _FLAT_PREFIXES if prefix + "fx" in fields)
    model = (_FLAT_MODELS[fields.model("model", _MISSING, tuple(_FLAT_MODELS))]
             if "model" in fields else _orbslam_model(fields))
    size = fields.integer(prefix + "width", 640), fields.integer(prefix + "height", 480)
    camera = _prefixed_camera(fields, prefix, *size, model)
    if prefix == "" and _FLAT_MASK_KEY in fields:
        camera = _with_mask_file(fields, camera)
    T_b_c = fields.pose("Tbc") if "Tbc" in fields else None
    return Calibration([camera], [T_b_c], _imu_params(fields))


def load_mask(path: Union[str, Path]) -> np.ndarray:
    """A keypoint mask image (any format OpenCV reads, converted to grey): ``(H, W)`` uint8,
    0 = no features there.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: a file OpenCV cannot read as an image.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mask image {path} does not exist")
    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise ValueError(f"mask image {path} is not an image OpenCV can read")
    return mask


def _with_mask_file(fields: _Fields, camera: Camera) -> Camera:
    """``camera`` with the mask image a flat file names (``mask: FILE``, relative to it)."""
    path = fields.path.parent / fields.text(_FLAT_MASK_KEY)
    try:
        return camera.with_mask(load_mask(path))
    except ValueError as error:
        raise ValueError(f"{fields.path}: {_FLAT_MASK_KEY} {path}: {error}") from None


def _read_kalibr_camchain(fields: _Fields) -> Calibration:
    """Kalibr camchain: ``cam0``, ``cam1``, ... in order. ``T_cam_imu`` maps IMU points into
    the camera, so the camera pose in the IMU is its inverse; ``cam1.T_cn_cnm1`` = ``T_c1_c0``
    relates the first two cameras."""
    names = sorted((key for key in fields.values if re.fullmatch(r"cam\d+", key)),
                   key=lambda key: int(key[3:]))
    sections = [fields.section(name) for name in names]
    cameras = [_kalibr_camera(section) for section in sections]
    camera_to_imu = [inverse(s.pose("T_cam_imu")) if "T_cam_imu" in s else None
                     for s in sections]
    T_left_right = None
    if len(sections) > 1 and "T_cn_cnm1" in sections[1]:
        T_left_right = inverse(sections[1].pose("T_cn_cnm1"))
    elif len(sections) > 1 and camera_to_imu[0] is not None and camera_to_imu[1] is not None:
        T_left_right = inverse(camera_to_imu[0]) @ camera_to_imu[1]
    # cam n in cam 0: the chain of T_cn_cnm1 (each maps cam n-1 points into cam n).
    T_c0_cam: list[Optional[np.ndarray]] = [np.eye(4)]
    for section in sections[1:]:
        previous = T_c0_cam[-1]
        chained = previous is not None and "T_cn_cnm1" in section
        T_c0_cam.append(previous @ inverse(section.pose("T_cn_cnm1")) if chained else None)
    if len(sections) < 2 or T_c0_cam[1] is None:
        T_c0_cam = []
    return Calibration(cameras, camera_to_imu, None, T_left_right, T_c0_cam=T_c0_cam)


def _kalibr_camera(cam: _Fields) -> Camera:
    """``pinhole`` with ``radtan`` (k1 k2 r1 r2), ``none`` or ``equidistant`` (Kalibr's
    ``pinhole-equi``: the Kannala-Brandt k1..k4) distortion; ``line_delay`` (seconds per
    row, absent 0) makes the readout ``line_delay * height``."""
    cam.model("camera_model", _MISSING, ("pinhole",))
    distortion = cam.model("distortion_model", _MISSING, tuple(_KALIBR_DISTORTIONS))
    fu, fv, pu, pv = cam.array("intrinsics", (4,))
    coeffs = list(cam.array("distortion_coeffs", (4,))) if distortion != "none" else [0.0] * 4
    width, height = cam.array("resolution", (2,))
    if not (width.is_integer() and height.is_integer()):
        raise cam.error("resolution", f"must be whole pixels, got {[width, height]}")
    model = _KALIBR_DISTORTIONS[distortion]
    dist = coeffs + [0.0] if model == "pinhole" else coeffs
    # Kalibr's rolling-shutter calibration gives the delay between rows, seconds.
    line_delay_s = cam.number(_KALIBR_LINE_DELAY_KEY, 0.0)
    where = _KALIBR_LINE_DELAY_KEY if _KALIBR_LINE_DELAY_KEY in cam else "intrinsics"
    return cam.camera(where, fu, fv, pu, pv, dist, int(width), int(height), model,
                      line_delay_s * height)


def _read_opencv_camera(fields: _Fields) -> Calibration:
    """OpenCV FileStorage camera files and ROS ``camera_info`` YAML: a zero-skew ``K``, 4 or
    5 plumb-bob coefficients (OpenCV's rational and thin-prism terms are not modelled), or
    ROS's ``equidistant`` model with the 4 ``cv2.fisheye`` coefficients."""
    model = _ROS_DISTORTIONS[fields.model("distortion_model", "plumb_bob",
                                          tuple(_ROS_DISTORTIONS))]
    K = fields.array("camera_matrix", (3, 3))
    if K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0, 0, 1]):
        raise fields.error("camera_matrix", f"must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "
                                            f"got {K.tolist()}")
    dist = fields.array("distortion_coefficients").reshape(-1)
    sizes, names = ((4, 5), "k1 k2 p1 p2 [k3]") if model == "pinhole" else ((4,), "k1 k2 k3 k4")
    if dist.size not in sizes:
        raise fields.error("distortion_coefficients", f"must hold {' or '.join(map(str, sizes))} "
                                                      f"values ({names}), got {dist.size}")
    if model == "pinhole":
        dist = np.append(dist, [0.0] * (5 - dist.size))
    camera = fields.camera("camera_matrix", K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist,
                           fields.integer("image_width"), fields.integer("image_height"), model)
    return Calibration([camera], [None])


# The keys that give the depth factor: ORB-SLAM3 settings 1.0, ORB-SLAM2 / legacy settings,
# a flat camera.yaml.
DEPTH_FACTOR_KEYS = ("RGBD.DepthMapFactor", "DepthMapFactor", "depth_scale")


def _depth_factor(fields: _Fields) -> Optional[float]:
    """The depth factor of the first of :data:`DEPTH_FACTOR_KEYS` the file holds."""
    key = next((k for k in DEPTH_FACTOR_KEYS if k in fields), None)
    if key is None:
        return None
    value = fields.number(key)
    if value <= 0:
        raise fields.error(key, f"must be a positive pixel value per metre, got {value!r}")
    return value


def _imu_params(fields: _Fields) -> Optional[ImuParams]:
    """IMU noise in ORB-SLAM (``IMU.*``, the IMU is the body), Kalibr (``imu0`` section or
    flat, ``T_i_b`` = inverse of ``T_b_imu``) or EuRoC (``rate_hz``, ``T_BS`` = ``T_b_imu``)
    keys; ``None`` if ``fields`` holds none."""
    if "IMU.NoiseGyro" in fields:
        return _imu(fields, _ORBSLAM_IMU_KEYS, np.eye(4))
    if "imu0" in fields:
        fields = fields.section("imu0")
    if "gyroscope_noise_density" not in fields:
        return None
    rate_key = "rate_hz" if "rate_hz" in fields else "update_rate"
    T_b_imu = (fields.pose("T_BS") if "T_BS" in fields
               else inverse(fields.pose("T_i_b")) if "T_i_b" in fields else np.eye(4))
    return _imu(fields, (*_KALIBR_IMU_KEYS, rate_key), T_b_imu)


def _imu(fields: _Fields, keys: Sequence[str], T_b_imu: np.ndarray) -> ImuParams:
    values = [fields.number(key) for key in keys]
    for key, value in zip(keys, values):
        if value <= 0:
            raise fields.error(key, f"must be positive, got {value!r}")
    gyro, gyro_walk, acc, acc_walk, rate_hz = values
    return ImuParams(gyroscope_noise_density=gyro, gyroscope_random_walk=gyro_walk,
                     accelerometer_noise_density=acc, accelerometer_random_walk=acc_walk,
                     rate_hz=rate_hz, T_b_imu=T_b_imu)


def read_camera_yaml(path: str | Path) -> Camera:
    """The first camera of a calibration file, e.g. a flat ``key: value`` YAML.

    Flat files hold the keys ``fx fy cx cy k1 k2 p1 p2 k3 width height``, optionally
    prefixed as in ORB-SLAM settings (``Camera.fx``, ``Camera1.fx``); other keys are ignored.
    A fisheye says ``model: kannala_brandt`` and gives ``k1 k2 k3 k4`` (``cv2.fisheye``).
    Missing distortion terms are 0, a missing size is 640x480. Any other format of
    :func:`ferroslam.load_calibration` is read too.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: a needed value is missing or not a number (naming the file and key).
    """
    return load_calibration(path).cameras[0]
