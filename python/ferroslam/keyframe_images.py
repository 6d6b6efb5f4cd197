"""The images (and depth) of the frames that became keyframes, kept for the outputs that need
pixels: the COLMAP model's ``images/`` and the dense mesh.

Only keyframes are kept, so memory grows with the map, not with the sequence, and every
image is stored PNG-encoded (a third to a tenth of its pixels' size): colour losslessly,
depth as 16-bit steps of :data:`DEPTH_STEP_M`. Frames are found again by their timestamp, which the core keeps with each
keyframe (``SlamSystem.keyframe_trajectory``, ``sparse_model``), and, for a rig, by the core's
camera index (0 the tracked camera, then the rig's further cameras: ``sparse_model``'s
``camera_index``).
"""

from __future__ import annotations

from typing import Iterable, Optional

import cv2
import numpy as np

__all__ = ["DEPTH_STEP_M", "KeyframeImages"]

# Depth is kept in steps of 0.2 mm (TUM's 1/5000 m), far below any depth sensor's noise; 16
# bits then reach 13.1 m, beyond what structured light or time of flight measures indoors.
DEPTH_STEP_M = 1.0 / 5000.0
_MAX_DEPTH_STEPS = 2**16 - 1


class KeyframeImages:
    """Images of keyframes by timestamp (seconds).

    Args:
        keep_depth: also keep each keyframe's depth image (RGB-D, for dense fusion).
    """

    def __init__(self, *, keep_depth: bool = False) -> None:
        self.keep_depth = keep_depth
        self._png: dict[tuple[float, int], bytes] = {}
        self._depth_m: dict[float, bytes] = {}

    def add(self, timestamp_s: float, image: np.ndarray,
            depth_m: Optional[np.ndarray] = None, *, camera: int = 0) -> None:
        """Keeps a keyframe's image of ``camera`` (grey or BGR uint8, as tracked) and, with
        ``keep_depth``, its depth image in metres (``None`` for none; the first camera's)."""
        ok, png = cv2.imencode(".png", np.ascontiguousarray(image))
        if not ok:
            raise ValueError(f"cannot encode the image of the frame at {timestamp_s} s as PNG")
        self._png[(float(timestamp_s), int(camera))] = png.tobytes()
        if self.keep_depth and depth_m is not None:
            steps = np.nan_to_num(np.asarray(depth_m, np.float64) / DEPTH_STEP_M, nan=0.0)
            steps[(steps < 0) | (steps > _MAX_DEPTH_STEPS)] = 0  # out of range: no depth
            ok, png = cv2.imencode(".png", np.round(steps).astype(np.uint16))
            if not ok:
                raise ValueError(f"cannot encode the depth of the frame at {timestamp_s} s")
            self._depth_m[float(timestamp_s)] = png.tobytes()

    def keep_only(self, timestamps_s: Iterable[float]) -> None:
        """Forgets the frames not among ``timestamps_s`` (keyframes the map culled)."""
        live = {float(t) for t in timestamps_s}
        for t, camera in [key for key in self._png if key[0] not in live]:
            del self._png[(t, camera)]
        for t in [t for t in self._depth_m if t not in live]:
            del self._depth_m[t]

    def __len__(self) -> int:
        """Number of keyframes kept (of the first camera)."""
        return sum(1 for _, camera in self._png if camera == 0)

    def __contains__(self, timestamp_s: float) -> bool:
        return self.has(timestamp_s)

    def has(self, timestamp_s: float, camera: int = 0) -> bool:
        """Whether the image of ``camera`` of the keyframe at ``timestamp_s`` is kept."""
        return (float(timestamp_s), int(camera)) in self._png

    def png(self, timestamp_s: float, camera: int = 0) -> bytes:
        """The PNG file of ``camera``'s image of the keyframe at ``timestamp_s`` (``KeyError``
        if not kept)."""
        return self._png[(float(timestamp_s), int(camera))]

    def image(self, timestamp_s: float, camera: int = 0) -> np.ndarray:
        """``camera``'s image of the keyframe at ``timestamp_s``, as it was added."""
        return _decode(self.png(timestamp_s, camera))

    def depth_m(self, timestamp_s: float) -> np.ndarray:
        """The depth image (float32 metres, 0 for none) of the keyframe at ``timestamp_s``
        (``KeyError`` if none was kept)."""
        steps = _decode(self._depth_m[float(timestamp_s)])
        return steps.astype(np.float32) * np.float32(DEPTH_STEP_M)


def _decode(png: bytes) -> np.ndarray:
    """The pixels of a PNG this class encoded (so it decodes)."""
    pixels = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert pixels is not None, "a PNG encoded by KeyframeImages.add"
    return pixels
