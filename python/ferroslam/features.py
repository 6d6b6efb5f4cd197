"""ORB features spread evenly over the image, as ORB-SLAM's ``ORBextractor`` does.

The whole extraction runs in the Rust core (``ferroslam._core.OrbExtractor``,
``crates/features/src/extractor/``), one call per image, without the GIL (Mur-Artal et al.,
ORB-SLAM, T-RO 2015, section III-A):

1. Image pyramid: ``n_levels`` levels, each ``scale_factor`` smaller than the previous and
   resized from it as OpenCV's ORB resizes (``INTER_LINEAR_EXACT``, bit for bit).
2. Feature budget per level from a geometric series, so that finer levels (more area)
   get more features; the budgets sum to ``n_features``.
3. All levels in parallel: FAST corners at ``min_fast``; on a grid of ~30 px cells, a cell
   that has corners scoring ``>= ini_fast`` keeps only those; a quadtree-like spread keeps
   the level's budget (the best corner of every cell at the deepest depth that fits, then
   the next strongest); orientation by intensity centroid over a circular patch of radius 15.
4. Rotated BRIEF (256 bits) with OpenCV's tests (a table in the crate, generated from
   ``cv2.ORB`` by ``scripts/opencv_brief_tests.py``) on each level smoothed as OpenCV's ORB
   smooths it (7 x 7 Gaussian, sigma 2, bit for bit).

So the descriptors equal ``cv2.ORB.compute`` on the whole image bit for bit (ORB-SLAM resizes
with ``INTER_LINEAR``; its levels differ by 1-3 grey levels, enough to change 3 descriptor bits
in 256 on average). Colour images are converted to grey with OpenCV first.

Keypoints are in RAW (distorted) level-0 pixel coordinates; undistortion is up to the
consumer (the Rust core receives the distortion coefficients).

Masks: every call takes an optional keypoint mask, a ``(H, W)`` uint8 or bool array of the
image's size, 0 (False) where no keypoint may be. The core drops each level's corners on
zero pixels (at their level-0 position) before the even spread, so the level's budget goes
to the open part of the image. :func:`frame_mask` combines a camera's static mask with a
frame's own (``Camera.mask``, ``add_frame(..., mask=)``).
"""

from __future__ import annotations

import numbers
from typing import Optional

import cv2
import numpy as np

from ferroslam import _core

__all__ = ["OrbExtractor", "check_mask", "frame_mask", "level_budgets", "sample_colors",
           "sample_depth"]

_Features = tuple[np.ndarray, np.ndarray, list[np.ndarray]]


def level_budgets(n_features: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """Features per pyramid level: ``n * (1 - f) / (1 - f^L) * f^l`` with ``f = 1/scale``.

    Rounded per level; the coarsest level takes the remainder (never negative).

    Raises:
        ValueError: invalid parameters (as :class:`OrbExtractor`).
    """
    return OrbExtractor(n_features, scale_factor, n_levels).budgets


def _validate_gray(image: np.ndarray) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(image).__name__}")
    if image.size == 0:
        raise ValueError(f"image is empty (shape {image.shape})")
    if image.dtype.kind in "fc" and not np.all(np.isfinite(image)):
        raise ValueError("image contains NaN or infinite values")
    if image.dtype != np.uint8:
        raise ValueError(f"image dtype must be uint8, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    elif image.ndim != 2:
        raise ValueError(f"image must be (H, W) or (H, W, 3) BGR, got shape {image.shape}")
    return image


def check_mask(mask: object, shape: tuple[int, int], name: str = "mask") -> np.ndarray:
    """``mask`` as a C-contiguous ``(H, W)`` uint8 array (bool: True -> 1), checked against
    the image ``shape`` ``(H, W)``; 0 = no keypoint there.

    Raises:
        ValueError: not a numpy array, not 2-D, not uint8 or bool, or not ``shape``; the
            message names ``name``.
    """
    if not isinstance(mask, np.ndarray):
        raise ValueError(f"{name} must be a numpy array (H, W) uint8 or bool, got "
                         f"{type(mask).__name__}")
    if mask.ndim != 2:
        raise ValueError(f"{name} must be 2-D (H, W), got shape {mask.shape}")
    if mask.dtype not in (np.uint8, np.bool_):
        raise ValueError(f"{name} must be uint8 or bool (0 = no keypoint there), got "
                         f"{mask.dtype}")
    if mask.shape != tuple(shape[:2]):
        raise ValueError(f"{name} is {mask.shape[1]}x{mask.shape[0]} (width x height) but "
                         f"the image is {shape[1]}x{shape[0]}")
    return np.ascontiguousarray(mask, dtype=np.uint8)


def frame_mask(static: Optional[np.ndarray], per_frame: object,
               shape: tuple[int, int], name: str = "mask") -> Optional[np.ndarray]:
    """The keypoint mask of one image: open (non-zero) where both the camera's ``static``
    mask and the frame's ``per_frame`` mask are open (either may be ``None``; ``None`` when
    both are). ``shape`` is the image's ``(H, W)``; ``per_frame`` is checked as
    :func:`check_mask` checks it, naming ``name``."""
    if per_frame is None:
        return static
    mask = check_mask(per_frame, shape, name)
    return mask if static is None else np.minimum(static, mask)


def _integer(name: str, value: object) -> int:
    """``value`` as an ``int`` if it is a whole number (``1000.0`` too); else ``ValueError``."""
    if isinstance(value, numbers.Real) and float(value).is_integer():
        return int(value)
    raise ValueError(f"{name} must be an integer, got {value!r}")


class OrbExtractor:
    """ORB keypoints and descriptors with ORB-SLAM's even spread.

    Each setting left out (``None``) takes the core's default (``OrbConfig::default`` in
    ``crates/features``, ORB-SLAM's settings for 640 x 480 images); the attributes of the
    same names hold the values in use.

    Args:
        n_features: total keypoints wanted per image (fewer on textureless images).
        scale_factor: scale between consecutive pyramid levels (> 1).
        n_levels: number of pyramid levels, in [1, 32].
        ini_fast: FAST threshold tried first in every cell.
        min_fast: FAST threshold used in cells where ``ini_fast`` finds no corner
            (``0 < min_fast <= ini_fast < 255``).

    Raises:
        ValueError: invalid parameters, naming the first.
    """

    def __init__(
        self,
        n_features: Optional[int] = None,
        scale_factor: Optional[float] = None,
        n_levels: Optional[int] = None,
        ini_fast: Optional[int] = None,
        min_fast: Optional[int] = None,
    ) -> None:
        given = {"n_features": n_features, "n_levels": n_levels, "ini_fast": ini_fast,
                 "min_fast": min_fast}
        settings = {k: _integer(k, v) for k, v in given.items() if v is not None}
        if scale_factor is not None:
            settings["scale_factor"] = float(scale_factor)
        self._core = _core.OrbExtractor(**settings)
        self.n_features: int = self._core.n_features
        self.scale_factor: float = self._core.scale_factor
        self.n_levels: int = self._core.n_levels
        self.ini_fast: int = self._core.ini_fast
        self.min_fast: int = self._core.min_fast
        self.scales = self.scale_factor ** np.arange(self.n_levels)
        self.budgets = np.array(self._core.level_budgets, int)

    def __repr__(self) -> str:
        return (
            f"OrbExtractor(n_features={self.n_features}, scale_factor={self.scale_factor}, "
            f"n_levels={self.n_levels}, ini_fast={self.ini_fast}, min_fast={self.min_fast})"
        )

    def pyramid(self, gray: np.ndarray) -> list[np.ndarray]:
        """Image pyramid, finest first: each level resized from the previous, bilinear
        (OpenCV ORB's ``INTER_LINEAR_EXACT``, see the module doc).

        Raises:
            ValueError: as :meth:`detect`; the image too small for the pyramid.
        """
        return self._core.pyramid(_validate_gray(gray))

    def detect(self, gray: np.ndarray, mask: Optional[np.ndarray] = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Detect and describe ORB features.

        Args:
            gray: ``(H, W)`` uint8 image (``(H, W, 3)`` BGR is converted).
            mask: ``(H, W)`` uint8 or bool, 0 where no keypoint may be (module doc).

        Returns:
            ``keypoints (N, 5)`` float32 ``[x, y, octave, angle_deg, response]`` with
            ``x, y`` raw level-0 pixels, ``octave`` the pyramid level, ``angle_deg`` in
            [0, 360) and ``response`` the FAST score; ``descriptors (N, 32)`` uint8.
            Rows are grouped by octave.

        Raises:
            ValueError: wrong dtype or shape, empty image, NaN values, an image too small
                for the pyramid; a mask not 2-D uint8 / bool of the image's size.
        """
        keypoints, descriptors, _ = self.detect_with_pyramid(gray, mask)
        return keypoints, descriptors

    def detect_with_pyramid(self, gray: np.ndarray,
                            mask: Optional[np.ndarray] = None) -> _Features:
        """As :meth:`detect`, also returning the pyramid the corners were found on.

        Stereo matching refines disparities on these levels (ORB-SLAM correlates patches on
        the keypoint's level).
        """
        gray = _validate_gray(gray)
        return self._core.extract(gray, None if mask is None else check_mask(mask, gray.shape))

    def detect_pair(self, left: np.ndarray, right: np.ndarray,
                    left_mask: Optional[np.ndarray] = None,
                    right_mask: Optional[np.ndarray] = None) -> tuple[_Features, _Features]:
        """:meth:`detect_with_pyramid` on both images of a stereo pair, in parallel in one call
        to the core, each with its own optional mask.

        Raises:
            ValueError: as :meth:`detect`, for either image or mask.
        """
        left, right = _validate_gray(left), _validate_gray(right)
        masks = [None if m is None else check_mask(m, image.shape, name)
                 for m, image, name in ((left_mask, left, "left_mask"),
                                        (right_mask, right, "right_mask"))]
        return self._core.extract_stereo(left, right, *masks)


def _pixels_at(keypoints: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray,
                                                                         np.ndarray]:
    """``(inside (N,) bool, rows, columns)`` of each keypoint's rounded raw pixel position in
    an image of ``shape``; rows and columns only for the keypoints inside it.

    Raises:
        ValueError: keypoints not a real ``(N, >=2)`` array.
    """
    keypoints = np.asarray(keypoints)
    if keypoints.ndim != 2 or keypoints.shape[1] < 2 or keypoints.dtype.kind not in "fiu":
        raise ValueError(f"keypoints must be a real (N, >=2) array, got {keypoints.shape}")
    with np.errstate(invalid="ignore"):
        u = np.rint(keypoints[:, 0].astype(np.float64))
        v = np.rint(keypoints[:, 1].astype(np.float64))
    h, w = shape[:2]
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
    return inside, v[inside].astype(np.intp), u[inside].astype(np.intp)


def sample_depth(depth_m: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Depth (metres) at each keypoint's rounded raw pixel position.

    Args:
        depth_m: ``(H, W)`` float depth in metres (0 or NaN = no measurement).
        keypoints: ``(N, >=2)`` array whose first two columns are ``x, y`` pixels.

    Returns:
        ``(N,)`` float32; 0 where the depth is missing, non-finite, non-positive or the
        keypoint falls outside the image.

    Raises:
        ValueError: ``depth_m`` not a 2-D real array, or keypoints not ``(N, >=2)``.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2 or depth_m.dtype.kind not in "fiu":
        raise ValueError(f"depth must be a 2-D real array, got {depth_m.dtype} {depth_m.shape}")
    inside, rows, columns = _pixels_at(keypoints, depth_m.shape)
    out = np.zeros(inside.shape[0], np.float32)
    d = depth_m[rows, columns].astype(np.float32)
    out[inside] = np.where(np.isfinite(d) & (d > 0), d, np.float32(0))
    return out


def sample_colors(image: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """RGB colour of each keypoint: the pixel at its rounded raw position, as the map points
    made from the keypoints keep it (``colors=`` of the ``SlamSystem.track_*`` calls).

    Args:
        image: the uint8 image the keypoints were detected in: ``(H, W, 3)`` BGR or
            ``(H, W, 4)`` BGRA as OpenCV reads them, or ``(H, W)`` / ``(H, W, 1)`` grey
            (giving grey colours).
        keypoints: ``(N, >=2)`` array whose first two columns are ``x, y`` pixels.

    Returns:
        ``(N, 3)`` uint8 RGB; black for a keypoint outside the image (the core refuses those).

    Raises:
        ValueError: ``image`` not a uint8 image of those shapes, or keypoints not ``(N, >=2)``.
    """
    image = np.asarray(image)
    channels = 1 if image.ndim == 2 else image.shape[2] if image.ndim == 3 else 0
    if image.dtype != np.uint8 or channels not in (1, 3, 4):
        raise ValueError(f"image must be a uint8 (H, W) grey or (H, W, 3) BGR image, got "
                         f"{image.dtype} {image.shape}")
    inside, rows, columns = _pixels_at(keypoints, image.shape)
    out = np.zeros((inside.shape[0], 3), np.uint8)
    pixels = image[rows, columns].reshape(len(rows), channels)
    out[inside] = pixels if channels == 1 else pixels[:, 2::-1]  # BGR(A) -> RGB
    return out
