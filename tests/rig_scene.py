"""A rendered room for rig tests: real TUM photographs pasted on the walls, floor and ceiling
of a 6 x 6 x 3 m box, seen by the cameras of a rig moving inside it, with exact depth.

Each pixel's ray is cut with the box (the first face it reaches), its texture sampled
bilinearly (OpenCV ``remap``) and its z-depth returned, so images, depths and poses agree
to the pixel: the only errors left are the core's.

World frame: z up, the room ``[-3, 3] x [-3, 3] x [0, 3]`` metres. Cameras: x right, y
down, z forward.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ferroslam import Camera

ROOM_MIN = np.array([-3.0, -3.0, 0.0])
ROOM_MAX = np.array([3.0, 3.0, 3.0])
EYE_HEIGHT_M = 1.5
TEXTURE_SIZE = (480, 640)  # rows, columns of one photograph


def room_textures(photos: list[Path]) -> np.ndarray:
    """An atlas of 6 faces, 2 grey photographs side by side each (``(6 * 480, 1280)`` uint8),
    from 12 image files (resized to 640 x 480)."""
    if len(photos) != 12:
        raise ValueError(f"the room takes 12 photographs, got {len(photos)}")
    rows, cols = TEXTURE_SIZE
    images = [cv2.resize(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (cols, rows),
                         interpolation=cv2.INTER_AREA) for p in photos]
    faces = [np.hstack(images[2 * f: 2 * f + 2]) for f in range(6)]
    return np.vstack(faces)


def room_atlas(data: Path) -> np.ndarray:
    """The room's texture atlas from 12 real photographs of the shared data (TUM, KITTI,
    EuRoC), the same room for every rig test."""
    tum = sorted((data / "tum/rgbd_dataset_freiburg1_desk/rgb").glob("*.png"))
    rpy = sorted((data / "tum/rgbd_dataset_freiburg1_rpy/rgb").glob("*.jpg"))
    kitti = sorted((data / "kitti/odometry_06_first51/image_0").glob("*.png"))
    euroc = sorted((data / "euroc/MH_01_easy_window/mav0/cam0/data").glob("*.jpg"))
    return room_textures([tum[0], kitti[0], tum[4], kitti[25], tum[8], euroc[0], rpy[150],
                          euroc[200], kitti[50], rpy[0], euroc[399], rpy[299]])


@dataclass
class RoomRenderer:
    """Renders the room through ``camera`` (a pinhole without distortion)."""

    atlas: np.ndarray
    camera: Camera

    def __post_init__(self) -> None:
        c = self.camera
        u, v = np.meshgrid(np.arange(c.width, dtype=np.float64),
                           np.arange(c.height, dtype=np.float64))
        # Rays with z = 1 in the camera: their hit parameter is the z-depth.
        self._rays_c = np.stack([(u - c.cx) / c.fx, (v - c.cy) / c.fy, np.ones_like(u)], -1)

    def render(self, T_w_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The grey image (uint8) and z-depth (float32 metres) from camera pose ``T_w_c``."""
        d = self._rays_c @ T_w_c[:3, :3].T
        o = T_w_c[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = np.where(d > 0, ROOM_MAX, ROOM_MIN)
            t_axis = np.where(d != 0, (bound - o) / d, np.inf)
        axis = np.argmin(t_axis, axis=-1)
        t = np.take_along_axis(t_axis, axis[..., None], -1)[..., 0]
        hit = o + d * t[..., None]
        positive = np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0
        face = 2 * axis + positive  # 0/1: x min/max, 2/3: y, 4/5: floor/ceiling
        # Face coordinates (a, b) in [0, 1]: the two other axes, b from the top.
        other = np.array([[1, 2], [1, 2], [0, 2], [0, 2], [0, 1], [0, 1]])[face]
        lo, hi = ROOM_MIN[other], ROOM_MAX[other]
        ab = (np.take_along_axis(hit, other, -1) - lo) / (hi - lo)
        rows, cols = TEXTURE_SIZE
        width = 2 * cols
        map_x = (np.clip(ab[..., 0], 0, 1) * (width - 1)).astype(np.float32)
        map_y = ((1 - np.clip(ab[..., 1], 0, 1)) * (rows - 1) + face * rows).astype(np.float32)
        image = cv2.remap(self.atlas, map_x, map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        return image, t.astype(np.float32)


def yaw(angle_rad: float) -> np.ndarray:
    """A rotation about the world's vertical axis."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def camera_facing(forward_w: np.ndarray) -> np.ndarray:
    """``R_w_c`` of a level camera looking along horizontal ``forward_w`` (y down)."""
    z = forward_w / np.linalg.norm(forward_w)
    y = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    return np.column_stack([x, y, z])


def body_path(n_frames: int, rate_hz: float = 30.0) -> list[np.ndarray]:
    """``T_w_body`` along a smooth loop: 0.6 m across, yawing +-25 degrees, at eye height."""
    poses = []
    for i in range(n_frames):
        s = 2 * np.pi * i / (rate_hz * 8.0)  # one loop every 8 s
        T = np.eye(4)
        T[:3, :3] = yaw(np.deg2rad(25.0) * np.sin(1.3 * s))
        T[:3, 3] = [0.3 * np.sin(s), 0.3 * np.sin(2 * s) / 2, EYE_HEIGHT_M + 0.1 * np.sin(s)]
        poses.append(T)
    return poses


def three_camera_rig(offset_m: float = 0.1) -> list[np.ndarray]:
    """``T_body_cam`` of three level cameras 90 degrees apart (front, left, right), each
    ``offset_m`` out from the body centre along its optical axis."""
    poses = []
    for forward in ([1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]):
        T = np.eye(4)
        T[:3, :3] = camera_facing(np.array(forward))
        T[:3, 3] = offset_m * np.array(forward)
        poses.append(T)
    return poses
