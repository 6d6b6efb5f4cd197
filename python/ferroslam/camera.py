"""Pinhole camera with OpenCV radial-tangential distortion (intrinsics in pixels)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Camera", "read_camera_yaml"]


@dataclass(frozen=True)
class Camera:
    """Intrinsics of a distorted pinhole camera.

    ``fx, fy, cx, cy`` in pixels; ``dist`` = OpenCV ``(k1, k2, p1, p2, k3)`` mapping ideal
    normalised coordinates to raw image coordinates; ``width, height`` in pixels.
    Raises ``ValueError`` for non-positive focal lengths or image size, or bad ``dist``.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480

    def __post_init__(self) -> None:
        dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if dist.shape != (5,) or not np.all(np.isfinite(dist)):
            raise ValueError(f"dist must be 5 finite values (k1 k2 p1 p2 k3), got {self.dist!r}")
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(values)) or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"invalid intrinsics fx, fy, cx, cy = {values}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"invalid image size {self.width}x{self.height}")
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def K(self) -> np.ndarray:
        """3x3 calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


_KEYS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "width", "height")


def read_camera_yaml(path: str | Path) -> Camera:
    """Read a flat ``key: value`` YAML camera file.

    Accepts the keys ``fx fy cx cy k1 k2 p1 p2 k3 width height``, optionally prefixed as in
    ORB-SLAM settings (``Camera.fx``, ``Camera1.fx``); other keys are ignored. Missing
    distortion terms are 0, missing size is 640x480.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: a needed value is missing or not a number.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    values: dict[str, float] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if ":" not in text or text.startswith("%"):
            continue
        key, value = (s.strip() for s in text.split(":", 1))
        key = key.rsplit(".", 1)[-1]
        if key not in _KEYS or not value:
            continue
        try:
            values[key] = float(value)
        except ValueError:
            raise ValueError(f"{path}:{number}: {key} is not a number: {value!r}") from None
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in values]
    if missing:
        raise ValueError(f"{path}: missing {', '.join(missing)}")
    return Camera(
        values["fx"],
        values["fy"],
        values["cx"],
        values["cy"],
        np.array([values.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]),
        int(values.get("width", 640)),
        int(values.get("height", 480)),
    )
