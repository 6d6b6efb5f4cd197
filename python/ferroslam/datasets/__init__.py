"""Dataset loaders (TUM RGB-D, KITTI odometry, EuRoC MAV).

Every sequence type offers ``len()``, indexing/iteration over frames, ``name``,
``timestamps`` (float64 seconds, strictly increasing), ``camera`` (intrinsics of the images
``load_gray`` returns), ``load_gray(i)`` (``(H, W)`` uint8), ``has_groundtruth`` and
``groundtruth()`` (``(timestamps (M,), T_w_c (M, 4, 4))`` of that camera). TUM adds
``load_depth(i)`` and ``load_gray_and_color(i)`` (the grey image and the ``(H, W, 3)`` uint8
BGR one, from one read of the file; see :func:`frame_images`); stereo sequences
(``is_stereo``) add ``load_stereo(i)`` (rectified ``(left, right)``) and ``baseline_m``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from ..calibration import Calibration, read_camera_yaml
from ..camera import Camera
from .euroc import EurocFrame, EurocSequence, ImuParams, read_sensor_yaml
from .kitti import KittiFrame, KittiSequence, read_kitti_calib
from .replay import ReplayedSequence, replay_order
from .tum import TUM_CAMERAS, TumFrame, TumSequence, associate_greedy

__all__ = [
    "TUM_CAMERAS",
    "Camera",
    "EurocFrame",
    "EurocSequence",
    "ImuParams",
    "KittiFrame",
    "KittiSequence",
    "ReplayedSequence",
    "Sequence",
    "TumFrame",
    "TumSequence",
    "associate_greedy",
    "detect_format",
    "frame_images",
    "is_sequence_folder",
    "open_sequence",
    "read_camera_yaml",
    "read_kitti_calib",
    "read_sensor_yaml",
    "replay_order",
]

Sequence = Union[TumSequence, KittiSequence, EurocSequence]

_LOADERS = {"tum": TumSequence, "kitti": KittiSequence, "euroc": EurocSequence}
_EXPECTED = (
    "rgb.txt (TUM), calib.txt + image_0/ or image_l/ (KITTI), mav0/ or cam0/data.csv (EuRoC)"
)


def _layout(path: Path) -> Optional[str]:
    if (path / "rgb.txt").is_file():
        return "tum"
    if any((path / d).is_dir() for d in ("image_0", "image_l")):
        return "kitti"  # without calib.txt KittiSequence says it is missing
    if (path / "mav0").is_dir() or (path / "cam0" / "data.csv").is_file():
        return "euroc"
    return None


def detect_format(path: Union[str, Path]) -> str:
    """``"tum"``, ``"kitti"`` or ``"euroc"`` from the files in folder ``path``.

    Raises ``ValueError`` (saying what was expected) if no layout matches.
    """
    path = Path(path)
    layout = _layout(path)
    if layout is None:
        raise ValueError(f"cannot detect the dataset layout of {path} (expected {_EXPECTED})")
    return layout


def is_sequence_folder(path: Union[str, Path]) -> bool:
    """Whether ``path`` is a folder in one of the dataset layouts (else ``ferroslam run``
    reads it as a folder of images, ``ferroslam.sources.ImageFolderSource``)."""
    return _layout(Path(path).expanduser()) is not None


def frame_images(seq: Any, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``i`` of ``seq`` as it is tracked, grey ``(H, W)``, and as its map points are
    coloured: ``(H, W, 3)`` BGR where the sequence has colour (``load_gray_and_color``), else
    the grey image again (grey colours)."""
    both = getattr(seq, "load_gray_and_color", None)
    if both is not None:
        return both(i)
    gray = seq.load_gray(i)
    return gray, gray


def open_sequence(path: Union[str, Path], format: str = "auto", *, sensor: str = "",
                  rectify: bool = True, calibration: Optional[Calibration] = None,
                  depth_factor: Optional[float] = None, **kwargs) -> Sequence:
    """Open a sequence folder as ``TumSequence``, ``KittiSequence`` or ``EurocSequence``.

    ``format`` is ``"auto"`` (see :func:`detect_format`), ``"tum"``, ``"kitti"`` or
    ``"euroc"``; ``kwargs`` go to the loader (e.g. ``stereo=False``). With a monocular
    ``sensor`` (``"mono"``, ``"mono-inertial"``) only what it reads is needed: no depth list
    (TUM), no right images (KITTI, EuRoC). ``rectify=False`` opens a EuRoC stereo sequence
    raw (``load_stereo`` gives raw pairs, the rig is ``left_camera``, ``right_camera``,
    ``T_left_right``: feed it to ``StereoVSlam.from_raw``). A rig ``sensor`` (``"rig"``,
    ``"rig-inertial"``) opens a EuRoC folder raw, its cameras as ``seq.rig``.

    ``calibration`` (``ferroslam.load_calibration(FILE)``; command line ``--camera FILE``)
    replaces the layout's own: TUM takes its first camera and its depth factor, EuRoC its
    cameras and extrinsics (``EurocSequence(calibration=)``). ``depth_factor`` (``--depth-scale``)
    is the depth pixel value per metre of a TUM-layout folder, over the calibration's.

    Raises ``FileNotFoundError`` for a missing folder and ``ValueError`` for an unknown
    format or layout, ``rectify=False`` for a format whose images are not raw stereo
    pairs (TUM, KITTI: rectified already), a calibration for KITTI (its ``calib.txt`` holds
    the rectified cameras the images are in) or a depth factor for a layout without depth.
    """
    path = Path(path).expanduser()
    if not path.is_dir():
        raise FileNotFoundError(f"sequence folder not found: {path} (expected a folder with "
                                f"{_EXPECTED})")
    if format == "auto":
        format = detect_format(path)
    if format not in _LOADERS:
        raise ValueError(f"unknown dataset format {format!r} (use auto, {', '.join(_LOADERS)})")
    if calibration is not None and format == "kitti":
        raise ValueError(f"{path}: a KITTI folder's calib.txt holds the rectified cameras its "
                         "images are in; a calibration cannot replace it")
    if depth_factor is not None and format != "tum":
        raise ValueError(f"{path}: a depth scale is for RGB-D folders (TUM layout), not "
                         f"{format}")
    if calibration is not None and format == "tum":
        kwargs["camera"] = calibration.cameras[0]
        if depth_factor is None:
            depth_factor = calibration.depth_factor
    elif calibration is not None:
        kwargs["calibration"] = calibration
    if depth_factor is not None:
        kwargs["depth_factor"] = depth_factor
    if sensor.startswith("mono"):
        kwargs.setdefault("with_depth" if format == "tum" else "stereo", False)
    if sensor.startswith("rig"):
        if format != "euroc":
            raise ValueError(f"{path}: sensor 'rig' tracks the cameras of a EuRoC folder "
                             f"(cam0, cam1 with their sensor.yaml) as they are; {format} has "
                             "no camera rig")
        rectify = False  # a rig is tracked from its raw images
    if format == "euroc":
        kwargs["rectify"] = rectify
    elif not rectify:
        raise ValueError(f"rectify=False is for raw EuRoC stereo pairs; {format} images are "
                         "not raw stereo pairs (KITTI ships them rectified)")
    return _LOADERS[format](path, **kwargs)
