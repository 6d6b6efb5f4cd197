"""ferroslam: visual SLAM (ORB-SLAM pipeline) for Python with a Rust core.

Pure-Python parts (``datasets``, ``sources``, ``features``, ``metrics``, ``io``, ``plot``)
import without the native extension; ``SlamSystem`` needs ``ferroslam._core`` (built with
maturin).
"""

from __future__ import annotations

from importlib import metadata as _metadata

from . import datasets, io, metrics, sources
from .calibration import Calibration, load_calibration
from .camera import Camera
from .rig import Rig
from .trajectory import Trajectory

try:
    __version__ = _metadata.version("ferroslam")
except _metadata.PackageNotFoundError:  # running from a source checkout
    __version__ = "0.0.0.dev0"

try:
    from ._core import SlamError
except ImportError:  # native module not built (or older than SlamError)

    class SlamError(RuntimeError):  # type: ignore[no-redef]
        """Failure inside the SLAM core (placeholder: the native module is not available)."""


__all__ = [
    "Calibration",
    "Camera",
    "FrameResult",
    "MonoVSlam",
    "RGBDVSlam",
    "Rig",
    "RigVSlam",
    "StereoVSlam",
    "TrackingStatus",
    "SlamError",
    "SlamSystem",
    "Trajectory",
    "__version__",
    "datasets",
    "io",
    "load_calibration",
    "metrics",
    "sources",
]


_VSLAM = ("FrameResult", "MonoVSlam", "RGBDVSlam", "RigVSlam", "StereoVSlam", "TrackingStatus")


def __getattr__(name: str):
    if name == "SlamSystem":  # native; imported on first use so the rest works without it
        from ._core import SlamSystem

        return SlamSystem
    if name in _VSLAM:
        from . import vslam

        return getattr(vslam, name)
    raise AttributeError(f"module 'ferroslam' has no attribute {name!r}")
