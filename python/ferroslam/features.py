"""ORB features spread evenly over the image, as ORB-SLAM's ``ORBextractor`` does.

Pipeline per frame (Mur-Artal et al., ORB-SLAM, T-RO 2015, section III-A):

1. Image pyramid: ``n_levels`` levels, each ``scale_factor`` smaller than the previous.
2. Feature budget per level from a geometric series, so that finer levels (more area)
   get more features; the budgets sum to ``n_features``.
3. FAST corners per level with threshold ``min_fast``; on a grid of ~30 px cells, a cell
   that has corners scoring ``>= ini_fast`` keeps only those (same result as running FAST
   at ``ini_fast`` first and falling back to ``min_fast`` where it finds nothing, because
   OpenCV's FAST score does not depend on the detection threshold).
4. Quadtree-like spread: each corner gets the coarsest quadtree depth at which it is the
   strongest corner of its cell; the level keeps its budget ordered by (depth, -score),
   i.e. the best corner of every cell at the deepest fitting depth plus the strongest
   corners of the next finer one.
5. Orientation by intensity centroid over a circular patch of radius 15 (unblurred level),
   then rotated BRIEF (256 bits) by OpenCV's ORB on the Gaussian-blurred pyramid.

Everything per keypoint is vectorised with numpy or done inside OpenCV.
Keypoints are in RAW (distorted) level-0 pixel coordinates; undistortion is up to the
consumer (the Rust core receives the distortion coefficients).
"""

from __future__ import annotations

import math
from functools import lru_cache
from operator import attrgetter

import cv2
import numpy as np

__all__ = ["OrbExtractor", "sample_depth", "level_budgets"]

_EDGE = 19  # keypoints keep this distance (level pixels) from the border, as in ORB-SLAM
_FAST_BORDER = _EDGE - 3  # FAST itself cannot fire within 3 px of the searched region
_HALF_PATCH = 15  # radius of the orientation patch
_CELL = 30  # cell size (level pixels) of the FAST threshold fallback grid
_response = attrgetter("response")


def level_budgets(n_features: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """Features per pyramid level: ``n * (1 - f) / (1 - f^L) * f^l`` with ``f = 1/scale``.

    Rounded per level; the coarsest level takes the remainder (never negative).
    """
    f = 1.0 / scale_factor
    per = n_features * (1 - f) / (1 - f**n_levels) if n_levels > 1 else float(n_features)
    budgets = np.array([int(round(per * f**level)) for level in range(n_levels - 1)], int)
    return np.append(budgets, max(n_features - int(budgets.sum()), 0))


def _circle_rows() -> np.ndarray:
    """Half-widths ``umax[|v|]`` of the radius-15 circular patch for rows v = -15..15."""
    umax = [0] * (_HALF_PATCH + 1)
    vmax = int(math.floor(_HALF_PATCH * math.sqrt(2) / 2 + 1))
    vmin = int(math.ceil(_HALF_PATCH * math.sqrt(2) / 2))
    for v in range(vmax + 1):
        umax[v] = int(round(math.sqrt(_HALF_PATCH**2 - v * v)))
    v0 = 0
    for v in range(_HALF_PATCH, vmin - 1, -1):  # make the circle symmetric in u and v
        while umax[v0] == umax[v0 + 1]:
            v0 += 1
        umax[v] = v0
        v0 += 1
    return np.array([umax[abs(v)] for v in range(-_HALF_PATCH, _HALF_PATCH + 1)])


_ROWS_V = np.arange(-_HALF_PATCH, _HALF_PATCH + 1)
_ROWS_U = _circle_rows()


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


def _threshold_fallback(xy: np.ndarray, score: np.ndarray, shape, ini: float) -> np.ndarray:
    """Mask of corners kept by the per-cell ``ini_fast`` -> ``min_fast`` fallback."""
    h, w = shape
    width, height = w - 2 * _FAST_BORDER, h - 2 * _FAST_BORDER
    cols, rows = max(width // _CELL, 1), max(height // _CELL, 1)
    cw, ch = math.ceil(width / cols), math.ceil(height / rows)
    cx = np.minimum((xy[:, 0] - _FAST_BORDER) // cw, cols - 1).astype(np.intp)
    cy = np.minimum((xy[:, 1] - _FAST_BORDER) // ch, rows - 1).astype(np.intp)
    cell = cy * cols + cx
    strong = score >= ini
    cell_has_strong = np.bincount(cell, weights=strong, minlength=rows * cols) > 0
    return strong | ~cell_has_strong[cell]


def _morton(q: np.ndarray) -> np.ndarray:
    """Interleave the bits of 16-bit cell coordinates ``q (N, 2)`` = (x, y) into Z-order codes."""
    out = np.zeros(q.shape[0], np.uint64)
    for axis in (0, 1):
        v = q[:, axis].astype(np.uint64)
        v = (v | (v << np.uint64(8))) & np.uint64(0x00FF00FF)
        v = (v | (v << np.uint64(4))) & np.uint64(0x0F0F0F0F)
        v = (v | (v << np.uint64(2))) & np.uint64(0x33333333)
        v = (v | (v << np.uint64(1))) & np.uint64(0x55555555)
        out |= v << np.uint64(axis)
    return out


_QUAD_DEPTH = 11  # finest quadtree depth: cells below one pixel for images < 2048 px


def _spread(xy: np.ndarray, score: np.ndarray, shape, budget: int) -> np.ndarray:
    """Indices of ``budget`` corners spread over the level (quadtree-like, see module doc).

    In Z-order every quadtree cell is a contiguous run, so the strongest corner of every
    cell at a depth is one ``minimum.reduceat`` over score ranks: O(N) per depth, no sort.
    """
    n = score.shape[0]
    if n <= budget:
        return np.arange(n)
    by_score = np.argsort(-score, kind="stable")
    rank = np.empty(n, np.int64)
    rank[by_score] = np.arange(n)  # 0 = strongest
    extent = max(shape) - 2 * _FAST_BORDER
    cells = 1 << _QUAD_DEPTH
    q = np.clip((xy - _FAST_BORDER) * (cells / extent), 0, cells - 1).astype(np.int64)
    code = _morton(q)
    z_order = np.argsort(code, kind="stable")
    code, rank_z = code[z_order], rank[z_order]
    depth_of = np.full(n, _QUAD_DEPTH + 1, np.int64)  # indexed by rank
    for depth in range(_QUAD_DEPTH + 1):
        cell = code >> np.uint64(2 * (_QUAD_DEPTH - depth))
        starts = np.flatnonzero(np.concatenate(([True], cell[1:] != cell[:-1])))
        best = np.minimum.reduceat(rank_z, starts)  # strongest corner of each cell
        depth_of[best] = np.minimum(depth_of[best], depth)
        if starts.size >= budget:
            break
    chosen_ranks = np.argsort(depth_of, kind="stable")[:budget]  # by (depth, rank)
    return by_score[chosen_ranks]


@lru_cache(maxsize=64)
def _orientation_stencil(width: int) -> tuple[np.ndarray, np.ndarray]:
    """Integral-image look-ups giving the patch moments ``(m10, m01)`` at a keypoint.

    For an integral image ``ii`` of shape ``(h + 1, w + 1)`` flattened, and a keypoint
    ``(x, y)``: ``(m10, m01) = ii.flat[y * (w + 1) + x + offsets] @ coefficients``.
    ``m01`` sums patch rows (weight v), ``m10`` patch columns (weight u); the circular patch
    is symmetric, so column u spans the same half-height as row u's half-width.
    """
    stride = width + 1
    terms: dict[int, np.ndarray] = {}

    def add(row: int, col: int, coef: np.ndarray) -> None:
        key = row * stride + col
        terms[key] = terms.get(key, np.zeros(2)) + coef

    for v, a in zip(_ROWS_V.tolist(), _ROWS_U.tolist()):
        # row v: rows [v, v+1), cols [-a, a+1)   -> weight v on m01
        # col v: rows [-a, a+1), cols [v, v+1)   -> weight v on m10
        for (r0, r1, c0, c1, k) in ((v, v + 1, -a, a + 1, 1), (-a, a + 1, v, v + 1, 0)):
            coef = np.zeros(2)
            coef[k] = v
            add(r1, c1, coef)
            add(r0, c1, -coef)
            add(r1, c0, -coef)
            add(r0, c0, coef)
    keys = [k for k, c in terms.items() if np.any(c != 0)]
    offsets, coefficients = np.array(keys, np.int64), np.array([terms[k] for k in keys])
    offsets.flags.writeable = coefficients.flags.writeable = False
    return offsets, coefficients


def _orientation(level: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Intensity-centroid angle (degrees, [0, 360)) of integer keypoints ``xy`` on a level.

    Keypoints must lie at least 16 px inside the level (guaranteed by the FAST border).
    """
    h, w = level.shape
    integral = cv2.integral(level, sdepth=cv2.CV_32S).ravel()
    offsets, coefficients = _orientation_stencil(w)
    base = xy[:, 1].astype(np.int64) * (w + 1) + xy[:, 0].astype(np.int64)
    m10, m01 = (integral[base[:, None] + offsets].astype(np.float64) @ coefficients).T
    return np.degrees(np.arctan2(m01, m10)) % 360.0


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
        self._fast = cv2.FastFeatureDetector_create(self.min_fast, True)
        self._orb = cv2.ORB_create(
            nfeatures=self.n_features,
            scaleFactor=self.scale_factor,
            nlevels=self.n_levels,
            edgeThreshold=_EDGE,
            firstLevel=0,
            WTA_K=2,
            scoreType=cv2.ORB_FAST_SCORE,
            patchSize=2 * _HALF_PATCH + 1,
            fastThreshold=self.min_fast,
        )

    def __repr__(self) -> str:
        return (
            f"OrbExtractor(n_features={self.n_features}, scale_factor={self.scale_factor}, "
            f"n_levels={self.n_levels}, ini_fast={self.ini_fast}, min_fast={self.min_fast})"
        )

    def pyramid(self, gray: np.ndarray) -> list[np.ndarray]:
        """Image pyramid (each level resized from the previous, bilinear, as ORB-SLAM)."""
        levels = [gray]
        h, w = gray.shape
        for scale in self.scales[1:]:
            size = (int(round(w / scale)), int(round(h / scale)))
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR))
        return levels

    def _level_keypoints(self, level: np.ndarray, budget: int) -> tuple[np.ndarray, np.ndarray]:
        """Selected corners ``(xy (n, 2) level px, score (n,))`` on one pyramid level."""
        h, w = level.shape
        empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        if budget <= 0 or h <= 2 * _EDGE + 1 or w <= 2 * _EDGE + 1:
            return empty
        corners = self._fast.detect(level[_FAST_BORDER : h - _FAST_BORDER, _FAST_BORDER : w - _FAST_BORDER])
        if not corners:
            return empty
        xy = cv2.KeyPoint_convert(corners).reshape(-1, 2) + np.float32(_FAST_BORDER)
        score = np.fromiter(map(_response, corners), np.float32, len(corners))
        keep = _threshold_fallback(xy, score, (h, w), self.ini_fast)
        xy, score = xy[keep], score[keep]
        chosen = _spread(xy, score, (h, w), budget)
        return xy[chosen], score[chosen]

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
        gray = _validate_gray(gray)
        levels = self.pyramid(gray)
        per_level = []
        for octave, (level, budget) in enumerate(zip(levels, self.budgets)):
            xy, score = self._level_keypoints(level, int(budget))
            if score.size == 0:
                continue
            angle = _orientation(level, xy)
            rows = np.empty((score.size, 5), np.float32)
            rows[:, :2] = xy * np.float32(self.scales[octave])
            rows[:, 2] = octave
            rows[:, 3] = angle
            rows[:, 4] = score
            per_level.append(rows)
        if not per_level:
            return np.zeros((0, 5), np.float32), np.zeros((0, 32), np.uint8), levels
        keypoints, descriptors = self._describe(gray, np.concatenate(per_level))
        return keypoints, descriptors, levels

    def _describe(self, gray: np.ndarray, kp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        size = (2 * _HALF_PATCH + 1) * self.scales[kp[:, 2].astype(np.intp)]
        cv_kps = list(
            map(cv2.KeyPoint, kp[:, 0].tolist(), kp[:, 1].tolist(), size.tolist(),
                kp[:, 3].tolist(), kp[:, 4].tolist(), kp[:, 2].astype(int).tolist())
        )
        cv_kps, descriptors = self._orb.compute(gray, cv_kps)
        # Selected corners keep >= 19 level pixels from the border, so OpenCV keeps them all
        # and, as they are sorted by octave, in order.
        if descriptors is None or len(cv_kps) != kp.shape[0]:
            raise RuntimeError("OpenCV ORB dropped keypoints: border handling disagrees")
        return kp, descriptors


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
    keypoints = np.asarray(keypoints)
    if keypoints.ndim != 2 or keypoints.shape[1] < 2 or keypoints.dtype.kind not in "fiu":
        raise ValueError(f"keypoints must be a real (N, >=2) array, got {keypoints.shape}")
    out = np.zeros(keypoints.shape[0], np.float32)
    with np.errstate(invalid="ignore"):
        u = np.rint(keypoints[:, 0].astype(np.float64))
        v = np.rint(keypoints[:, 1].astype(np.float64))
    h, w = depth_m.shape
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
    d = depth_m[v[inside].astype(np.intp), u[inside].astype(np.intp)].astype(np.float32)
    out[inside] = np.where(np.isfinite(d) & (d > 0), d, np.float32(0))
    return out
