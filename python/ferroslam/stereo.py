"""Stereo rectification of a calibrated, horizontal two-camera rig (OpenCV).

Frames: ``left`` and ``right`` are the raw (distorted, unrectified) camera optical frames;
``rect`` is the rectified left optical frame (x right, y down, z forward). ``R1`` is the
rotation with ``p_rect = R1 @ p_left`` (OpenCV's ``R1``), so a camera pose of the rectified
left camera is ``T_w_rect = T_w_left @ T_left_rect`` with ``T_left_rect = [R1^T | 0]``.
Rectified images are pinholes without distortion sharing ``fx = fy``, ``cx``, ``cy`` and
rows: a point at depth ``z`` appears at ``u_right = u_left - fx * baseline_m / z``.
"""

from __future__ import annotations

import cv2
import numpy as np

from .camera import Camera

__all__ = ["StereoRectifier"]


class StereoRectifier:
    """Rectification maps computed once, applied per frame with :meth:`rectify`.

    Args:
        left, right: raw intrinsics (with distortion) of both cameras; same image size.
        T_left_right: ``(4, 4)`` pose of the right camera in the left camera frame
            (``p_left = T_left_right @ p_right``), metres.

    Uses ``cv2.stereoRectify`` with ``alpha=0`` (only valid pixels, no black border) and
    ``CALIB_ZERO_DISPARITY`` (both rectified images share ``cx``); the rectified images keep
    the raw image size.

    Attributes:
        camera: rectified left (and right) pinhole, ``dist`` zeros.
        baseline_m: distance between the optical centres along rectified x, metres (> 0).
        R1: ``(3, 3)`` rotation from the raw left frame to the rectified left frame.
        R2: ``(3, 3)`` rotation from the raw right frame to the rectified right frame.

    Raises:
        ValueError: different image sizes, a bad ``T_left_right``, or a rig that is not
            horizontal with the right camera on the left camera's +x side.
    """

    def __init__(self, left: Camera, right: Camera, T_left_right: np.ndarray) -> None:
        if (left.width, left.height) != (right.width, right.height):
            raise ValueError(
                f"stereo cameras differ in image size: {left.width}x{left.height} "
                f"vs {right.width}x{right.height}"
            )
        T = np.asarray(T_left_right, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_left_right must be a finite (4, 4) pose, got shape {T.shape}")
        # stereoRectify wants the transform from the first to the second camera (T_right_left).
        R = T[:3, :3].T
        t = (-R @ T[:3, 3]).reshape(3, 1)  # OpenCV 5 rejects a (3,) vector here
        size = (left.width, left.height)
        R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
            left.K, left.dist, right.K, right.dist, size, R, t,
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
        )
        # Horizontal rectification puts the baseline into P2[0, 3] = -fx * baseline.
        if abs(P2[1, 3]) > abs(P2[0, 3]) or P2[0, 3] >= 0:
            raise ValueError(
                "expected a horizontal stereo rig with the right camera on the +x side of "
                f"the left one; got right camera centre {T[:3, 3]} in the left frame"
            )
        self.R1 = R1
        self.R2 = R2
        self.baseline_m = float(-P2[0, 3] / P2[0, 0])
        self.camera = Camera(P1[0, 0], P1[1, 1], P1[0, 2], P1[1, 2], np.zeros(5), *size)
        self._maps = (
            cv2.initUndistortRectifyMap(left.K, left.dist, R1, P1, size, cv2.CV_16SC2),
            cv2.initUndistortRectifyMap(right.K, right.dist, R2, P2, size, cv2.CV_16SC2),
        )

    @property
    def T_left_rect(self) -> np.ndarray:
        """``(4, 4)`` pose of the rectified left frame in the raw left frame: ``[R1^T | 0]``."""
        T = np.eye(4)
        T[:3, :3] = self.R1.T
        return T

    def _remap(self, image: np.ndarray, side: int) -> np.ndarray:
        size = (self.camera.height, self.camera.width)
        if image.shape[:2] != size:
            raise ValueError(
                f"image is {image.shape[1]}x{image.shape[0]}, the rectifier expects "
                f"{self.camera.width}x{self.camera.height}"
            )
        map1, map2 = self._maps[side]
        return cv2.remap(image, map1, map2, cv2.INTER_LINEAR)

    def rectify_left(self, image: np.ndarray) -> np.ndarray:
        """Rectified left image (same size and dtype as the raw one)."""
        return self._remap(image, 0)

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified ``(left, right)`` images; raises ``ValueError`` for a wrong image size."""
        return self._remap(left, 0), self._remap(right, 1)
