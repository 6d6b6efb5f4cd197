"""Dataset loaders. Each sequence type offers ``len()``, indexing/iteration over frames,
``load_gray(i)``, ``load_depth(i)``, ``camera``, ``timestamps`` and ``groundtruth()``."""

from __future__ import annotations

from pathlib import Path
from typing import Union

from ..camera import Camera, read_camera_yaml
from .tum import TUM_CAMERAS, TumFrame, TumSequence, associate_greedy

__all__ = [
    "TUM_CAMERAS",
    "Camera",
    "TumFrame",
    "TumSequence",
    "associate_greedy",
    "open_sequence",
    "read_camera_yaml",
]


def open_sequence(path: Union[str, Path], format: str = "auto", **kwargs) -> TumSequence:
    """Open a sequence folder, detecting its layout (only TUM RGB-D so far).

    Raises ``FileNotFoundError`` for a missing folder and ``ValueError`` for an unknown layout.
    """
    path = Path(path).expanduser()
    if not path.is_dir():
        raise FileNotFoundError(f"sequence folder not found: {path}")
    if format == "tum" or (format == "auto" and (path / "rgb.txt").is_file()):
        return TumSequence(path, **kwargs)
    if format != "auto":
        raise ValueError(f"dataset format {format!r} is not implemented yet (only 'tum')")
    raise ValueError(f"cannot detect the dataset layout of {path} (expected rgb.txt: TUM)")
