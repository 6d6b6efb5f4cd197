"""Whether a depth scale (depth pixel value per metre) makes an RGB-D scene plausible.

A wrong scale does not stop tracking: every map point and the trajectory come out scaled by
the ratio of the right scale to the given one, and nothing else looks wrong. RGB-D cameras
measure about 0.1 to 20 m (RealSense D4xx from 0.1 m, Kinect to about 10 m), so a median
depth outside that span means the scale is wrong, and the raw median says which of the
common scales is right.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

__all__ = ["COMMON_DEPTH_FACTORS", "PLAUSIBLE_MEDIAN_DEPTH_M", "DepthScaleFinding",
           "assess_depth_scale", "check_depth_scale", "describe"]

PLAUSIBLE_MEDIAN_DEPTH_M = (0.1, 20.0)
"""The median depth, metres, an RGB-D frame of a real scene has."""

COMMON_DEPTH_FACTORS = {
    1.0: "metres",
    1000.0: "millimetres: RealSense, Azure Kinect, ROS 16UC1",
    5000.0: "TUM RGB-D",
}
"""The depth scales cameras and datasets use, and whose they are."""

# The middle of the plausible span on a log scale (1.4 m, a room): of the common scales that
# make a frame plausible, the one nearest it is suggested.
_TYPICAL_DEPTH_M = math.sqrt(PLAUSIBLE_MEDIAN_DEPTH_M[0] * PLAUSIBLE_MEDIAN_DEPTH_M[1])


@dataclass(frozen=True)
class DepthScaleFinding:
    """What the depths of a frame say about its depth scale."""

    median_m: Optional[float]
    """Median of the valid depths, metres; ``None`` when there is none."""
    advice: Optional[str]
    """``None`` when the median is plausible, else which scale would make it so."""
    suggested_factor: Optional[float] = None
    """The common scale that makes the frame plausible, if one does."""


def assess_depth_scale(depth_m: np.ndarray, depth_factor: float) -> DepthScaleFinding:
    """The median of the valid (finite, positive) depths of ``depth_m`` (metres at
    ``depth_factor`` pixel values per metre) and, when it lies outside
    :data:`PLAUSIBLE_MEDIAN_DEPTH_M`, the common scale that would make it plausible."""
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        return DepthScaleFinding(None, None)
    median = float(np.median(valid))
    low, high = PLAUSIBLE_MEDIAN_DEPTH_M
    if low <= median <= high:
        return DepthScaleFinding(median, None)
    raw = median * depth_factor
    fitting = [f for f in COMMON_DEPTH_FACTORS if low <= raw / f <= high]
    if not fitting:
        return DepthScaleFinding(median, f"a scale near {raw / _TYPICAL_DEPTH_M:.3g} would put "
                                         f"it at {_TYPICAL_DEPTH_M:.1f} m")
    best = min(fitting, key=lambda f: abs(math.log(raw / f / _TYPICAL_DEPTH_M)))
    return DepthScaleFinding(median, f"a scale of {best:g} ({COMMON_DEPTH_FACTORS[best]}) gives "
                                     f"{raw / best:.2f} m (command line: --depth-scale {best:g})",
                             best)


def check_depth_scale(depth_m: np.ndarray, depth_factor: float, where: str) -> Optional[float]:
    """The median of the valid depths of ``depth_m`` (:func:`assess_depth_scale`), ``None``
    when there is none to judge.

    Raises ``ValueError`` naming ``where``, the scale, the median and the common scale that
    would make it plausible, when the median lies outside :data:`PLAUSIBLE_MEDIAN_DEPTH_M`.
    """
    finding = assess_depth_scale(depth_m, depth_factor)
    if finding.advice is None:
        return finding.median_m
    raise ValueError(f"{where}: {describe(finding, depth_factor)}; {finding.advice}")


def describe(finding: DepthScaleFinding, depth_factor: float) -> str:
    """The implausible median of ``finding`` in words."""
    low, high = PLAUSIBLE_MEDIAN_DEPTH_M
    return (f"a depth scale of {depth_factor:g} pixel values per metre puts the median depth "
            f"at {finding.median_m:.3g} m, outside the {low:g}-{high:g} m of an RGB-D scene")
