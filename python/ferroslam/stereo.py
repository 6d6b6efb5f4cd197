"""Stereo rectification of a calibrated, horizontal two-camera rig (OpenCV).

Frames: ``left`` and ``right`` are the raw (distorted, unrectified) camera optical frames;
``rect`` is the rectified left optical frame (x right, y down, z forward). ``R1`` is the
rotation with ``p_rect = R1 @ p_left`` (OpenCV's ``R1``), so a camera pose of the rectified
left camera is ``T_w_rect = T_w_left @ T_left_rect`` with ``T_left_rect = [R1^T | 0]``.
Rectified images are pinholes without distortion sharing ``fx``, ``fy``, ``cx``, ``cy`` and
rows: a point at depth ``z`` appears at ``u_right = u_left - fx * baseline_m / z``.

Both camera models rectify: pinhole (radial-tangential) pairs with ``cv2.stereoRectify`` and
``cv2.initUndistortRectifyMap``, Kannala-Brandt (fisheye) pairs with their ``cv2.fisheye``
counterparts. A fisheye's rectified image is a pinhole, so it keeps the central part of the
field of view: its focal length is the raw cameras' smallest, so a ``w``-pixel-wide image
spans ``2 atan(w / 2 fx)`` (for fx 285 at 848 px, 112 degrees).
"""

from __future__ import annotations

import cv2
import numpy as np

from .camera import Camera

__all__ = ["StereoRectifier"]

# Largest deviation of R R^T from I (and of the last row from 0 0 0 1) in T_left_right.
_RIGID_TOL = 1e-6
# Smallest baseline, metres: below it there is no stereo depth.
_MIN_BASELINE_M = 1e-6


def _rig_pose(T_left_right: np.ndarray) -> np.ndarray:
    """``T_left_right`` as a finite rigid ``(4, 4)`` float64 transform with a baseline, or a
    ``ValueError`` naming it."""
    try:
        T = np.asarray(T_left_right, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"T_left_right must be a (4, 4) rigid transform, got "
                         f"{T_left_right!r}") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_left_right must be a finite (4, 4) pose, got shape {T.shape}")
    R = T[:3, :3]
    if (not np.allclose(R @ R.T, np.eye(3), atol=_RIGID_TOL) or np.linalg.det(R) < 0
            or not np.allclose(T[3], [0, 0, 0, 1], atol=_RIGID_TOL)):
        raise ValueError("T_left_right is not a rigid transform (rotation not orthonormal or "
                         "last row not 0 0 0 1)")
    if R[2, 2] <= 0.0:  # the cosine between the two optical axes
        angle = np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0)))
        raise ValueError(f"T_left_right turns the right camera {angle:.0f} degrees away from "
                         "the left one: a stereo pair's cameras face the same hemisphere "
                         "(is the transform inverted, or given in another convention?)")
    if np.linalg.norm(T[:3, 3]) < _MIN_BASELINE_M:
        raise ValueError(f"T_left_right has a zero baseline (translation {T[:3, 3]} m): the "
                         "cameras must be apart for stereo depth")
    return T


class StereoRectifier:
    """Rectification maps computed once, applied per frame with :meth:`rectify`.

    Args:
        left, right: raw intrinsics (with distortion) of both cameras; same image size.
        T_left_right: ``(4, 4)`` pose of the right camera in the left camera frame
            (``p_left = T_left_right @ p_right``), metres.

    Uses ``cv2.stereoRectify`` with ``alpha=0`` (only valid pixels, no black border) and
    ``CALIB_ZERO_DISPARITY`` (both rectified images share ``cx``) for pinhole cameras,
    ``cv2.fisheye.stereoRectify`` for Kannala-Brandt ones (their rectified focal length is
    the raw cameras' smallest, see the module doc); the rectified images keep the raw image
    size.

    Attributes:
        camera: rectified left (and right) pinhole, ``dist`` zeros.
        baseline_m: distance between the optical centres along rectified x, metres (> 0).
        R1: ``(3, 3)`` rotation from the raw left frame to the rectified left frame.
        R2: ``(3, 3)`` rotation from the raw right frame to the rectified right frame.
        P1, P2: ``(3, 4)`` projection matrices of the rectified left and right cameras
            (``P2[0, 3] = -fx * baseline_m``).

    Raises:
        ValueError: different image sizes or camera models, a ``T_left_right`` that is not a
            finite rigid ``(4, 4)`` transform or has a zero baseline (named), or a rig that
            is not horizontal with the right camera on the left camera's +x side.
    """

    def __init__(self, left: Camera, right: Camera, T_left_right: np.ndarray) -> None:
        if (left.width, left.height) != (right.width, right.height):
            raise ValueError(
                f"stereo cameras differ in image size: {left.width}x{left.height} "
                f"vs {right.width}x{right.height}"
            )
        if left.model != right.model:
            raise ValueError(f"stereo cameras differ in model: {left.model} vs {right.model} "
                             "(rectify a pair of one model)")
        T = _rig_pose(T_left_right)
        # stereoRectify wants the transform from the first to the second camera (T_right_left).
        R = T[:3, :3].T
        t = (-R @ T[:3, 3]).reshape(3, 1)  # OpenCV 5 rejects a (3,) vector here
        size = (left.width, left.height)
        self._fisheye = left.model == "kannala_brandt"
        if self._fisheye:
            R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(
                left.K, left.dist, right.K, right.dist, size, R, t,
                flags=cv2.CALIB_ZERO_DISPARITY, balance=0.0,
            )
            # OpenCV sizes the focal length to the image corners, which lie beyond a
            # fisheye's image circle (a 195-degree lens gets fx 60 at 512 px); the raw focal
            # length keeps the resolution at the centre.
            focal = min(left.fx, left.fy, right.fx, right.fy)
            for P in (P1, P2):
                P[0, 3] *= focal / P[0, 0]
                P[0, 0] = P[1, 1] = focal
            init_map = cv2.fisheye.initUndistortRectifyMap
        else:
            R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
                left.K, left.dist, right.K, right.dist, size, R, t,
                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
            )
            init_map = cv2.initUndistortRectifyMap
        # Horizontal rectification puts the baseline into P2[0, 3] = -fx * baseline.
        if abs(P2[1, 3]) > abs(P2[0, 3]) or P2[0, 3] >= 0:
            raise ValueError(
                "expected a horizontal stereo rig with the right camera on the +x side of "
                f"the left one; got right camera centre {T[:3, 3]} in the left frame "
                "(T_left_right)"
            )
        self.R1 = R1
        self.R2 = R2
        self.P1, self.P2 = P1, P2
        self.baseline_m = float(-P2[0, 3] / P2[0, 0])
        # Rectified rows stand in for the raw rows' times (a small rotation of the image).
        self.camera = Camera(P1[0, 0], P1[1, 1], P1[0, 2], P1[1, 2], np.zeros(5), *size,
                             rolling_shutter_readout_s=left.rolling_shutter_readout_s)
        self._raw = (left, right)
        self._maps = (
            init_map(left.K, left.dist, R1, P1, size, cv2.CV_16SC2),
            init_map(right.K, right.dist, R2, P2, size, cv2.CV_16SC2),
        )

    def rectify_points(self, pixels: np.ndarray, side: str = "left") -> np.ndarray:
        """Rectified pixels ``(N, 2)`` float64 of raw pixels ``(N, 2)`` of the ``"left"`` or
        ``"right"`` image (``cv2.undistortPoints`` / ``cv2.fisheye.undistortPoints`` with the
        rectification; the point-wise counterpart of :meth:`rectify`)."""
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        uv = np.asarray(pixels, dtype=np.float64)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"pixels must have shape (N, 2), got {uv.shape}")
        i = 0 if side == "left" else 1
        camera, R, P = self._raw[i], (self.R1, self.R2)[i], (self.P1, self.P2)[i]
        undistort = cv2.fisheye.undistortPoints if self._fisheye else cv2.undistortPoints
        out = undistort(uv.reshape(-1, 1, 2), camera.K, camera.dist, R=R, P=P)
        return out.reshape(-1, 2)

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
