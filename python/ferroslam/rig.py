"""A camera rig: the cameras of one instant, where each sits on the body, and which two of
them form a stereo pair.

The core tracks a rig as one frame per instant through one call (``SlamSystem.track``):

* one camera: monocular;
* one camera with registered depth: RGB-D (:class:`~ferroslam.RGBDVSlam`);
* a declared pair, cameras 0 and 1, raw: each frame's camera-0 keypoints are matched into
  camera 1 along epipolar curves on unit rays (any model, any relative pose, no
  rectification) and triangulated;
* every further camera (overlapping the others or not, with or without depth) adds its
  keypoints to the same frame: matched against the map, in the pose optimisation and in
  local BA, and triangulated against every camera of the neighbouring keyframes.

The first camera must give the map its metric scale (depth or a pair): a monocular first
camera with further cameras is refused, naming the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np

from ._validate import rigid_transform
from .calibration import Calibration
from .camera import Camera


@dataclass(frozen=True)
class Rig:
    """Cameras rigidly mounted on one body.

    Attributes:
        cameras: the raw cameras (model, intrinsics, distortion, size, optional static
            mask), in the order their images are passed; ``cameras[0]`` is the tracked one
            (trajectories are its ``T_w_c``).
        T_body_cam: per camera, its ``(4, 4)`` pose in the body frame (``p_body = T_body_cam
            @ p_cam``, metres). With an IMU the body frame is the IMU's (EuRoC's ``T_BS``,
            Kalibr's ``inv(T_cam_imu)``).
        stereo: cameras 0 and 1 are a stereo pair, matched at every frame (metric depth).
        depth: per camera, whether its frames come with a registered depth image (metres);
            empty for none.
        pairs: further stereo pairs ``(k, k + 1)`` among the cameras after the first (and
            its partner): camera ``k``'s keypoints get depth by matching into camera
            ``k + 1``'s image along epipolar curves (any model, no rectification); the
            partner observes nothing itself. A rig of a front and a rear pair is
            ``Rig(cameras, poses, stereo=True, pairs=((2, 3),))``.
    """

    cameras: tuple[Camera, ...]
    T_body_cam: tuple[np.ndarray, ...] = field(default=())
    stereo: bool = False
    depth: tuple[bool, ...] = field(default=())
    pairs: tuple[tuple[int, int], ...] = field(default=())

    def __post_init__(self) -> None:
        cameras = tuple(self.cameras)
        if not cameras:
            raise ValueError("a rig needs at least one camera")
        for k, camera in enumerate(cameras):
            if not isinstance(camera, Camera):
                raise TypeError(f"rig camera {k} must be a ferroslam.Camera, got "
                                f"{type(camera).__name__}")
        poses = tuple(self.T_body_cam) or tuple(np.eye(4) for _ in cameras)
        if len(poses) != len(cameras):
            raise ValueError(f"a rig of {len(cameras)} camera(s) needs one T_body_cam each, "
                             f"got {len(poses)}")
        poses = tuple(rigid_transform(T, f"T_body_cam[{k}]") for k, T in enumerate(poses))
        if self.stereo and len(cameras) < 2:
            raise ValueError("a stereo rig needs two cameras")
        depth = tuple(bool(d) for d in self.depth) or tuple(False for _ in cameras)
        if len(depth) != len(cameras):
            raise ValueError(f"a rig of {len(cameras)} camera(s) needs one depth flag each, "
                             f"got {len(depth)}")
        if self.stereo and (depth[0] or depth[1]):
            raise ValueError("the cameras of a stereo pair take their depth from each other, "
                             "not from depth images")
        object.__setattr__(self, "depth", depth)
        object.__setattr__(self, "pairs", self._checked_pairs(len(cameras), depth))
        object.__setattr__(self, "cameras", cameras)
        object.__setattr__(self, "T_body_cam", poses)
        object.__setattr__(self, "stereo", bool(self.stereo))

    def _checked_pairs(self, n: int, depth: tuple[bool, ...]) -> tuple[tuple[int, int], ...]:
        first = 2 if self.stereo else 1
        try:
            pairs = tuple(tuple(p) for p in self.pairs)
        except TypeError:
            raise TypeError(f"pairs must be a sequence of (k, k + 1) camera index pairs, got "
                            f"{self.pairs!r}") from None
        if not all(isinstance(k, (int, np.integer)) and not isinstance(k, bool)
                   for p in pairs for k in p):
            raise TypeError(f"pairs must hold camera indices (int), got {self.pairs!r}")
        pairs = tuple(tuple(int(k) for k in p) for p in pairs)
        used: set[int] = set()
        for p in pairs:
            if len(p) != 2 or p[1] != p[0] + 1 or not first <= p[0] < n - 1:
                raise ValueError(
                    f"pairs: {p} is not a further stereo pair (k, k + 1) of cameras "
                    f"{first}..{n - 1} (cameras 0 and 1 are a pair by stereo=True)")
            if used & set(p):
                raise ValueError(f"pairs: camera {sorted(used & set(p))[0]} is in two pairs")
            if depth[p[0]] or depth[p[1]]:
                raise ValueError(f"pairs: the cameras of pair {p} take their depth from each "
                                 "other, not from depth images")
            used |= set(p)
        return pairs

    @classmethod
    def from_calibration(cls, calibration: Calibration, *, stereo: Optional[bool] = None,
                         pairs: Sequence[tuple[int, int]] = ()) -> "Rig":
        """The rig of a calibration file (:func:`ferroslam.load_calibration`: Kalibr
        camchain ``cam0..camN``, ORB-SLAM3 ``Camera1``/``Camera2`` with ``Stereo.T_c1_c2``):
        body = the IMU where the file relates every camera to one, else camera 0 (the
        cameras chained by the file's relative poses).
        ``stereo`` defaults to whether the file relates cameras 0 and 1; ``pairs`` declares
        further stereo pairs (no calibration format names them)."""
        cameras = tuple(calibration.cameras)
        T_imu_cam = list(calibration.camera_to_imu)
        if all(T is not None for T in T_imu_cam[: len(cameras)]) and len(T_imu_cam) >= len(
                cameras):
            poses = tuple(np.asarray(T, dtype=np.float64) for T in T_imu_cam[: len(cameras)])
        elif len(cameras) == 1:
            poses = (np.eye(4),)
        elif len(calibration.T_c0_cam) == len(cameras) and all(
                T is not None for T in calibration.T_c0_cam):
            poses = tuple(np.asarray(T, dtype=np.float64) for T in calibration.T_c0_cam)
        else:
            raise ValueError(f"the calibration has {len(cameras)} cameras but does not give "
                             "each one's pose (camera-IMU transforms, or relative poses "
                             "chaining every camera to the first)")
        if stereo is None:
            stereo = len(cameras) >= 2 and calibration.T_left_right is not None
        rig = cls(cameras, poses, stereo, pairs=tuple(pairs))
        if rig.stereo and calibration.T_left_right is not None:
            # The file's own relative pose, not the product of two rounded ones.
            T_body_right = rig.T_body_cam[0] @ np.asarray(calibration.T_left_right)
            poses = (rig.T_body_cam[0], T_body_right, *rig.T_body_cam[2:])
            rig = cls(cameras, poses, stereo, pairs=tuple(pairs))
        return rig

    @property
    def T_left_right(self) -> np.ndarray:
        """``(4, 4)`` pose of camera 1 in camera 0 (``p_0 = T_left_right @ p_1``)."""
        if len(self.cameras) < 2:
            raise ValueError("a rig of one camera has no T_left_right")
        return np.linalg.inv(self.T_body_cam[0]) @ self.T_body_cam[1]

    def tracked_sensor(self) -> str:
        """The core sensor of the rig's first camera (``"mono"``, ``"rgbd"``, ``"stereo"``
        with its pair partner); the further cameras join it (:meth:`observers`).

        Raises:
            ValueError: a monocular first camera with further cameras (its map has no
                metric scale for the rig's metric extrinsics).
        """
        sensor = "stereo" if self.stereo else "rgbd" if self.depth[0] else "mono"
        if sensor == "mono" and len(self.cameras) > 1:
            raise ValueError(
                f"this rig has {len(self.cameras)} cameras and its first has neither depth "
                "nor a stereo partner: a monocular map has no metric scale for the rig's "
                "metric extrinsics; declare cameras 0 and 1 a pair (stereo=True) or give "
                "camera 0 depth")
        return sensor

    @property
    def first_observer(self) -> int:
        """The index of the first camera after the tracked one and its pair partner."""
        return 2 if self.stereo else 1

    def observing_cameras(self) -> list[int]:
        """The cameras whose keypoints the map holds, in order: the first and every further
        camera but the stereo partners (which give depths only)."""
        partners = {p[1] for p in self.pairs}
        return [0, *(k for k in range(self.first_observer, len(self.cameras))
                     if k not in partners)]

    def observers(self) -> list[tuple[Camera, np.ndarray, Any]]:
        """``(camera, T_c0_c, depth)`` of every camera after the first (and its pair
        partner), partners left out: its pose in camera 0 (``p_0 = T_c0_c @ p``, metres) and
        whether it has depth images, or ``(partner_camera, T_left_right)`` for a camera of
        :attr:`pairs` (the partner's pose in it)."""
        T_c0_body = np.linalg.inv(self.T_body_cam[0])
        partner = dict(self.pairs)
        out = []
        for k in self.observing_cameras()[1:]:
            depth: Any = self.depth[k]
            if k in partner:
                j = partner[k]
                depth = (self.cameras[j],
                         np.linalg.inv(self.T_body_cam[k]) @ self.T_body_cam[j])
            out.append((self.cameras[k], T_c0_body @ self.T_body_cam[k], depth))
        return out

    def camera_to_imu(self, T_body_imu: Optional[np.ndarray] = None) -> np.ndarray:
        """Camera 0's pose in the IMU frame, ``inv(T_body_imu) @ T_body_cam[0]`` (the body
        frame is the IMU's when ``T_body_imu`` is left out)."""
        T = self.T_body_cam[0]
        if T_body_imu is None:
            return T.copy()
        return np.linalg.inv(rigid_transform(T_body_imu, "T_body_imu")) @ T

    def __repr__(self) -> str:
        models = ", ".join(f"{c.model} {c.width}x{c.height}" for c in self.cameras)
        depth = f", depth={self.depth}" if any(self.depth) else ""
        pairs = f", pairs={self.pairs}" if self.pairs else ""
        return f"Rig({len(self.cameras)} camera(s): {models}; stereo={self.stereo}{depth}{pairs})"


def rig_images(rig: Rig, images: Sequence[np.ndarray] | np.ndarray) -> list[np.ndarray]:
    """One image per camera of ``rig``, as given (one array for a one-camera rig)."""
    if isinstance(images, np.ndarray) and len(rig.cameras) == 1:
        images = [images]
    if isinstance(images, np.ndarray) or not isinstance(images, (list, tuple)):
        raise ValueError(f"images must be a sequence of {len(rig.cameras)} image(s), one per "
                         f"rig camera, got {type(images).__name__}")
    if len(images) != len(rig.cameras):
        raise ValueError(f"got {len(images)} image(s) for a rig of {len(rig.cameras)} "
                         "camera(s): pass one per camera, in the rig's order")
    for k, (camera, image) in enumerate(zip(rig.cameras, images)):
        camera.check_image(image, f"camera {k} image")
    return list(images)
