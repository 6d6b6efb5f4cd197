"""Camera intrinsics (pixels) of the supported models: pinhole with OpenCV radial-tangential
distortion, and Kannala-Brandt fisheye (OpenCV ``cv2.fisheye``)."""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import numpy.typing

__all__ = ["Camera", "CAMERA_MODELS"]

# Model name -> (coefficient names of ``dist``): the one list of supported camera models.
CAMERA_MODELS = {
    "pinhole": ("k1", "k2", "p1", "p2", "k3"),
    "kannala_brandt": ("k1", "k2", "k3", "k4"),
}
# Largest image side accepted, pixels: beyond any camera (64k), and the core's u32 sizes.
_MAX_SIDE_PX = 1 << 16


@dataclass(frozen=True)
class Camera:
    """Intrinsics of a camera.

    ``fx, fy, cx, cy`` in pixels; ``width, height`` in pixels; ``model`` one of
    :data:`CAMERA_MODELS`:

    - ``"pinhole"`` (default): ``dist`` = OpenCV ``(k1, k2, p1, p2, k3)`` mapping ideal
      normalised coordinates to raw image coordinates;
    - ``"kannala_brandt"``: ``dist`` = ``(k1, k2, k3, k4)`` of OpenCV's ``cv2.fisheye``
      (``theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)``); build it with
      :meth:`kannala_brandt`.

    ``rolling_shutter_readout_s``: seconds the sensor takes to read its rows, top to bottom,
    from the first row to the last (the frame's timestamp is the middle row's time); ``0``
    (default) is a global shutter. With a readout, tracking estimates each frame's velocity
    with its pose and sees every keypoint from the pose its row was read at. Calibration
    files carry it as Kalibr ``line_delay`` (times the height), ``rolling_shutter_readout_s``
    (flat ``camera.yaml``) or ``Camera.rollingShutterReadout`` (ORB-SLAM-style settings); see
    :mod:`ferroslam.calibration`.

    ``mask``: an optional static keypoint mask, ``(height, width)`` uint8 or bool, 0 where
    no feature may be extracted in any image of this camera (a robot's body, a logo, the
    dark ring outside a fisheye's image circle: :meth:`with_image_circle_mask`); stored as
    a read-only uint8 array. A flat ``camera.yaml`` names one as ``mask: FILE`` (an image,
    relative to the calibration file), ``ferroslam run --mask FILE`` sets it.

    Raises ``TypeError`` naming the field for a value that is not a real number (a string, a
    bool) or a size that is not an integer, ``ValueError`` for non-positive focal lengths or
    image size, non-finite values, a negative readout, an unknown model, bad ``dist`` or a
    mask that is not 2-D uint8 / bool of the camera's size.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480
    model: str = "pinhole"
    rolling_shutter_readout_s: float = 0.0
    mask: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    @classmethod
    def kannala_brandt(cls, fx: float, fy: float, cx: float, cy: float, k, width: int,
                       height: int, rolling_shutter_readout_s: float = 0.0) -> "Camera":
        """A Kannala-Brandt fisheye camera; ``k`` = ``(k1, k2, k3, k4)``."""
        return cls(fx, fy, cx, cy, k, width, height, model="kannala_brandt",
                   rolling_shutter_readout_s=rolling_shutter_readout_s)

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy", "rolling_shutter_readout_s"):
            value = getattr(self, name)
            unit = "seconds" if name == "rolling_shutter_readout_s" else "pixels"
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
                raise TypeError(f"{name} must be a real number of {unit}, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.rolling_shutter_readout_s < 0:
            raise ValueError("rolling_shutter_readout_s must be >= 0 seconds (0 = global "
                             f"shutter), got {self.rolling_shutter_readout_s!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"fx and fy must be positive, got fx = {self.fx}, fy = {self.fy}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
                raise TypeError(f"{name} must be an integer number of pixels, got {value!r}")
            if not 0 < value <= _MAX_SIDE_PX:
                raise ValueError(f"{name} must be in 1..={_MAX_SIDE_PX} pixels, got {value}")
            object.__setattr__(self, name, int(value))
        if self.model not in CAMERA_MODELS:
            raise ValueError(f"unknown camera model {self.model!r} (use "
                             f"{', '.join(CAMERA_MODELS)})")
        names = CAMERA_MODELS[self.model]
        what = f"{len(names)} real numbers ({' '.join(names)}) for the {self.model} model"
        try:
            dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise TypeError(f"dist must be {what}, got {self.dist!r}") from None
        if dist.shape != (len(names),) or not np.all(np.isfinite(dist)):
            raise ValueError(f"dist must be {what}, finite, got {self.dist!r}")
        object.__setattr__(self, "dist", dist)
        if self.mask is not None:
            from .features import check_mask

            mask = check_mask(self.mask, (self.height, self.width), "the camera's mask").copy()
            mask.flags.writeable = False
            object.__setattr__(self, "mask", mask)
        self._check_plausible()

    def with_mask(self, mask: Optional[np.ndarray]) -> "Camera":
        """This camera with the static keypoint ``mask`` (``None``: none), replacing its own."""
        return dataclasses.replace(self, mask=mask)

    def with_image_circle_mask(self, radius_px: Optional[float] = None, margin_px: float = 8.0,
                               *, field_of_view_deg: Optional[float] = None) -> "Camera":
        """This camera with its static mask closed outside a fisheye's image circle, centred
        on the principal point ``(cx, cy)`` (combined with a mask it already has).

        Without it, the hard edge of the dark ring around the circle is a ring of corners
        that stay put in the image while the camera moves: tracking takes them for points at
        infinity and a monocular map breaks up.

        Args:
            radius_px: the circle's radius in pixels. ``None``: from ``field_of_view_deg``
                when given, else the largest circle around the principal point inside the
                image.
            margin_px: pixels inside the circle's edge that stay closed too, >= 0: FAST fires
                on the edge, and a corner within 3 px (times its pyramid level's scale) of it
                still sees it. The default 8 keeps the finest 5 levels' corners off it.
            field_of_view_deg: the lens's full field of view in degrees: the radius is the
                smaller distance from ``(cx, cy)`` of a ray ``field_of_view_deg / 2`` off the
                axis, horizontally and vertically (through :meth:`project`).

        Raises:
            ValueError: both ``radius_px`` and ``field_of_view_deg`` given, a field of view
                the lens does not project, or a radius / margin out of range (the core names
                it).
        """
        from ._core import OrbExtractor

        if radius_px is not None and field_of_view_deg is not None:
            raise ValueError("give radius_px or field_of_view_deg, not both")
        if field_of_view_deg is not None:
            half = math.radians(float(field_of_view_deg)) / 2
            rays = [[math.sin(half), 0.0, math.cos(half)], [0.0, math.sin(half), math.cos(half)]]
            pixels = self.project(np.array(rays))
            if not np.all(np.isfinite(pixels)):
                raise ValueError(f"field_of_view_deg = {field_of_view_deg}: the "
                                 f"{self.model} lens does not project rays "
                                 f"{math.degrees(half):g} degrees off its axis")
            radius_px = float(min(pixels[0, 0] - self.cx, pixels[1, 1] - self.cy))
        elif radius_px is None:
            # Pixel centres are at integer coordinates: the image's edges at -0.5, size - 0.5.
            radius_px = min(self.cx + 0.5, self.cy + 0.5, self.width - 0.5 - self.cx,
                            self.height - 0.5 - self.cy)
        circle = OrbExtractor.image_circle_mask(self.width, self.height, self.cx, self.cy,
                                                float(radius_px), float(margin_px))
        from .features import frame_mask

        return self.with_mask(frame_mask(self.mask, circle, (self.height, self.width)))

    def _check_plausible(self) -> None:
        """The core's plausibility checks (principal point inside the ``width x height``
        image, distortion monotonic and of lens-like size out to the image corners), run at
        construction through the core's one camera conversion, so they live in one place."""
        from ._core import project_points  # the conversion checks the camera, then no points

        try:
            project_points(self, np.zeros((0, 3)))
        except ValueError as err:
            raise ValueError(f"{err} (camera {self.width}x{self.height} pixels)") from None

    def check_image(self, image: np.ndarray, name: str = "image") -> None:
        """Raises ``ValueError`` naming both sizes unless ``image`` (``(H, W)`` or
        ``(H, W, C)``) is ``width x height``: features of an image of another size would be
        tracked with the wrong calibration."""
        if not isinstance(image, np.ndarray):
            raise TypeError(f"{name} must be a numpy array (H, W) or (H, W, 3), got "
                            f"{type(image).__name__}")
        shape = image.shape
        if len(shape) < 2 or tuple(shape[:2]) != (self.height, self.width):
            size = f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else f"of shape {shape}"
            raise ValueError(f"{name} is {size} (width x height) but the camera is "
                             f"{self.width}x{self.height}")

    def project(self, points: np.typing.ArrayLike) -> np.ndarray:
        """Raw image pixels of camera-frame points, computed by the core's camera model.

        Args:
            points: ``(N, 3)`` camera-frame points in metres (x right, y down, z forward),
                any real dtype (converted to float64).

        Returns:
            ``(N, 2)`` float64 pixels of the RAW image, with the lens distortion applied
            (what ``cv2.projectPoints`` / ``cv2.fisheye.projectPoints`` give). A row is NaN
            where the model does not project the point: at or behind the image plane of a
            pinhole (``z <= 1e-6``), beyond a fisheye's largest one-to-one incidence angle
            (up to 180 degrees, so points behind a wide fisheye do project), or a
            non-finite point.

        Raises ``TypeError`` (a non-numeric array) or ``ValueError`` (a shape other than
        ``(N, 3)``) naming ``points``.
        """
        from ._core import project_points

        return project_points(self, _float64(points, "points"))

    def unproject(self, pixels: np.typing.ArrayLike) -> np.ndarray:
        """Unit rays through raw image pixels, inverting :meth:`project`.

        Args:
            pixels: ``(N, 2)`` pixels of the RAW (distorted) image, any real dtype.

        Returns:
            ``(N, 3)`` float64 unit vectors in the camera frame. A row is NaN for a
            non-finite pixel or, for a fisheye, one outside the image circle of its largest
            incidence angle.

        Raises ``TypeError`` or ``ValueError`` naming ``pixels`` as :meth:`project`.
        """
        from ._core import unproject_pixels

        return unproject_pixels(self, _float64(pixels, "pixels"))

    @property
    def K(self) -> np.ndarray:
        """3x3 calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def _float64(values: np.typing.ArrayLike, name: str) -> np.ndarray:
    """``values`` as a float64 array when it holds real numbers (ints, floats, a list of
    them); anything else is passed on unchanged for the core to refuse, naming ``name``."""
    array = values if isinstance(values, np.ndarray) else np.asarray(values)
    if array.dtype.kind in "iuf":
        return np.ascontiguousarray(array, dtype=np.float64)
    return values
