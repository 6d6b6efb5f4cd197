"""Pinhole camera with OpenCV radial-tangential distortion (intrinsics in pixels)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Camera"]

# Largest image side accepted, pixels: beyond any camera (64k), and the core's u32 sizes.
_MAX_SIDE_PX = 1 << 16


@dataclass(frozen=True)
class Camera:
    """Intrinsics of a distorted pinhole camera.

    ``fx, fy, cx, cy`` in pixels; ``dist`` = OpenCV ``(k1, k2, p1, p2, k3)`` mapping ideal
    normalised coordinates to raw image coordinates; ``width, height`` in pixels.
    Raises ``TypeError`` naming the field for a value that is not a real number (a string, a
    bool) or a size that is not an integer, ``ValueError`` for non-positive focal lengths or
    image size, non-finite values or bad ``dist``.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
                raise TypeError(f"{name} must be a real number of pixels, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"fx and fy must be positive, got fx = {self.fx}, fy = {self.fy}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
                raise TypeError(f"{name} must be an integer number of pixels, got {value!r}")
            if not 0 < value <= _MAX_SIDE_PX:
                raise ValueError(f"{name} must be in 1..={_MAX_SIDE_PX} pixels, got {value}")
            object.__setattr__(self, name, int(value))
        try:
            dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise TypeError(f"dist must be 5 real numbers (k1 k2 p1 p2 k3), got {self.dist!r}"
                            ) from None
        if dist.shape != (5,) or not np.all(np.isfinite(dist)):
            raise ValueError(f"dist must be 5 finite values (k1 k2 p1 p2 k3), got {self.dist!r}")
        object.__setattr__(self, "dist", dist)

    def check_image(self, image: np.ndarray, name: str = "image") -> None:
        """Raises ``ValueError`` naming both sizes unless ``image`` (``(H, W)`` or
        ``(H, W, C)``) is ``width x height``: features of an image of another size would be
        tracked with the wrong calibration."""
        shape = np.shape(image)
        if len(shape) < 2 or tuple(shape[:2]) != (self.height, self.width):
            size = f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else f"of shape {shape}"
            raise ValueError(f"{name} is {size} (width x height) but the camera is "
                             f"{self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:
        """3x3 calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
