"""ORB features spread evenly over the image, as ORB-SLAM's ``ORBextractor`` does.

Pipeline per frame (Mur-Artal et al., ORB-SLAM, T-RO 2015, section III-A):

1. Image pyramid: ``n_levels`` levels, each ``scale_factor`` smaller than the previous.
2. Feature budget per level from a geometric series, so that finer levels (more area)
   get more features; the budgets sum to ``n_features``.
3. In the Rust core (``ferroslam._core.detect_orb_corners``, all levels in parallel): FAST
   corners per level at ``min_fast``; on a grid of ~30 px cells, a cell that has corners
   scoring ``>= ini_fast`` keeps only those; a quadtree-like spread keeps the level's budget
   (the best corner of every cell at the deepest depth that fits, then the next strongest);
   orientation by intensity centroid over a circular patch of radius 15.
4. Rotated BRIEF (256 bits) in the Rust core (``_core.BriefPattern``, all keypoints in
   parallel) on each level smoothed as OpenCV's ORB smooths it, with OpenCV's tests
   (:mod:`ferroslam._brief` reads them off ``cv2.ORB``).

The pyramid is resized with ``INTER_LINEAR_EXACT``, as OpenCV's ORB builds its own, so the
descriptors equal ``cv2.ORB.compute`` on the whole image bit for bit (ORB-SLAM resizes with
``INTER_LINEAR``; its levels differ by 1-3 grey levels, enough to change 3 descriptor bits
in 256 on average).

Keypoints are in RAW (distorted) level-0 pixel coordinates; undistortion is up to the
consumer (the Rust core receives the distortion coefficients).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor, wait

import cv2
import numpy as np

from ferroslam import _core
from ferroslam._brief import opencv_brief_tests

__all__ = ["OrbExtractor", "level_budgets", "sample_colors", "sample_depth"]

# ORB's smoothing before BRIEF: 7 x 7 Gaussian, sigma 2, separable (``cv2.GaussianBlur``
# rounds differently and changes 0.2 bits per descriptor against ``cv2.ORB``).
_SMOOTHING = cv2.getGaussianKernel(7, 2)


def level_budgets(n_features: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """Features per pyramid level: ``n * (1 - f) / (1 - f^L) * f^l`` with ``f = 1/scale``.

    Rounded per level; the coarsest level takes the remainder (never negative).
    """
    f = 1.0 / scale_factor
    per = n_features * (1 - f) / (1 - f**n_levels) if n_levels > 1 else float(n_features)
    budgets = np.array([int(round(per * f**level)) for level in range(n_levels - 1)], int)
    return np.append(budgets, max(n_features - int(budgets.sum()), 0))


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
    return np.ascontiguousarray(image)


class OrbExtractor:
    """ORB keypoints and descriptors with ORB-SLAM's even spread.

    Args:
        n_features: total keypoints wanted per image (fewer on textureless images).
        scale_factor: scale between consecutive pyramid levels (> 1).
        n_levels: number of pyramid levels (>= 1).
        ini_fast: FAST threshold tried first in every cell.
        min_fast: FAST threshold used in cells where ``ini_fast`` finds no corner.

    Raises:
        ValueError: invalid parameters.
    """

    def __init__(
        self,
        n_features: int = 1000,
        scale_factor: float = 1.2,
        n_levels: int = 8,
        ini_fast: int = 20,
        min_fast: int = 7,
    ) -> None:
        if int(n_features) != n_features or n_features < 1:
            raise ValueError(f"n_features must be a positive integer, got {n_features}")
        if not (np.isfinite(scale_factor) and scale_factor > 1.0):
            raise ValueError(f"scale_factor must be > 1, got {scale_factor}")
        if int(n_levels) != n_levels or not 1 <= n_levels <= 32:
            raise ValueError(f"n_levels must be an integer in [1, 32], got {n_levels}")
        if not 0 < min_fast <= ini_fast < 255:
            raise ValueError(f"need 0 < min_fast <= ini_fast < 255, got {min_fast}, {ini_fast}")
        self.n_features = int(n_features)
        self.scale_factor = float(scale_factor)
        self.n_levels = int(n_levels)
        self.ini_fast = int(ini_fast)
        self.min_fast = int(min_fast)
        self.scales = self.scale_factor ** np.arange(self.n_levels)
        self.budgets = level_budgets(self.n_features, self.scale_factor, self.n_levels)
        self._brief = _core.BriefPattern(opencv_brief_tests())
        self._second_thread: ThreadPoolExecutor | None = None

    def __repr__(self) -> str:
        return (
            f"OrbExtractor(n_features={self.n_features}, scale_factor={self.scale_factor}, "
            f"n_levels={self.n_levels}, ini_fast={self.ini_fast}, min_fast={self.min_fast})"
        )

    def pyramid(self, gray: np.ndarray) -> list[np.ndarray]:
        """Image pyramid: each level resized from the previous, bilinear (OpenCV ORB's
        ``INTER_LINEAR_EXACT``, see the module doc)."""
        levels = [gray]
        h, w = gray.shape
        for level, scale in enumerate(self.scales[1:], start=1):
            size = (int(round(w / scale)), int(round(h / scale)))
            if min(size) < 1:
                raise ValueError(
                    f"image {w}x{h} is too small for {self.n_levels} pyramid levels of scale "
                    f"{self.scale_factor}: level {level} would be {size[0]}x{size[1]} px")
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR_EXACT))
        return levels

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Detect and describe ORB features.

        Args:
            gray: ``(H, W)`` uint8 image (``(H, W, 3)`` BGR is converted).

        Returns:
            ``keypoints (N, 5)`` float32 ``[x, y, octave, angle_deg, response]`` with
            ``x, y`` raw level-0 pixels, ``octave`` the pyramid level, ``angle_deg`` in
            [0, 360) and ``response`` the FAST score; ``descriptors (N, 32)`` uint8.
            Rows are grouped by octave.

        Raises:
            ValueError: wrong dtype or shape, empty image, NaN values.
        """
        keypoints, descriptors, _ = self.detect_with_pyramid(gray)
        return keypoints, descriptors

    def detect_with_pyramid(
        self, gray: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """As :meth:`detect`, also returning the pyramid the corners were found on.

        Stereo matching refines disparities on these levels (ORB-SLAM correlates patches on
        the keypoint's level).
        """
        return self._detect(gray)

    def detect_pair(
        self, left: np.ndarray, right: np.ndarray
    ) -> tuple[tuple[np.ndarray, np.ndarray, list[np.ndarray]],
               tuple[np.ndarray, np.ndarray, list[np.ndarray]]]:
        """:meth:`detect_with_pyramid` on both images of a stereo pair at once, the right one
        on a second thread (OpenCV and the Rust core release the GIL).

        OpenCV's own thread pool is held to one thread meanwhile: the two extractions fill two
        cores, and its workers would only contend with them (KITTI stereo, 2 cores: frame
        median 36 -> 33 ms).

        Raises:
            ValueError: as :meth:`detect`, for either image.
        """
        cv_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            right_job = self._worker().submit(self._detect, right)
            try:
                left_features = self._detect(left)
            finally:
                wait([right_job])  # never leave the right image's extraction running
            return left_features, right_job.result()
        finally:
            cv2.setNumThreads(cv_threads)

    def _worker(self) -> ThreadPoolExecutor:
        """The second thread of :meth:`detect_pair`."""
        if self._second_thread is None:
            self._second_thread = ThreadPoolExecutor(1, thread_name_prefix="ferroslam-orb")
        return self._second_thread

    def _detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        gray = _validate_gray(gray)
        levels = self.pyramid(gray)
        kp = _core.detect_orb_corners(
            levels, self.budgets.tolist(), ini_fast=self.ini_fast, min_fast=self.min_fast
        )
        if kp.shape[0] == 0:
            return np.zeros((0, 5), np.float32), np.zeros((0, 32), np.uint8), levels
        descriptors = self._describe(levels, kp)
        kp[:, :2] *= self.scales.astype(np.float32)[kp[:, 2].astype(np.intp), None]
        return kp, descriptors, levels

    def _describe(self, levels: list[np.ndarray], kp: np.ndarray) -> np.ndarray:
        """Descriptors of ``kp`` (level pixels): each level smoothed by OpenCV as its ORB
        smooths it, then all keypoints described in parallel in the Rust core."""
        smoothed = [cv2.sepFilter2D(level, -1, _SMOOTHING, _SMOOTHING,
                                    borderType=cv2.BORDER_REFLECT_101) for level in levels]
        return self._brief.describe(smoothed, kp)


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
