"""A dense surface from RGB-D keyframes: TSDF fusion of their depth at their final poses
(after local BA and loop closing), with colour, into a triangle mesh and a point cloud.

Fusion runs in Open3D (its tensor ``VoxelBlockGrid`` on the CPU: a hash map of voxel blocks
allocated where depth falls, so memory follows the surface, not the scene's bounding box),
an optional extra: ``pip install
'ferroslam[dense]'`` (``open3d-cpu``). Open3D's 0.20 wheel links the system library
libusb-1.0 (Debian/Ubuntu ``libusb-1.0-0``); :func:`require_open3d` names it when it is
missing.

The images are undistorted first (colour bilinear, depth nearest-neighbour: interpolating
depth across an edge would invent surfaces), because the volume integrates with an ideal
pinhole.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ._files import atomic_output
from .camera import Camera
from .export import write_ply

__all__ = ["DEFAULT_MAX_DEPTH_M", "DEFAULT_TRUNCATION_M", "DEFAULT_VOXEL_M", "DenseModel",
           "fuse_tsdf", "require_open3d", "write_dense_outputs", "write_mesh_ply"]

# 1 cm voxels resolve a desk-scale scene (TUM fr1) with a mesh of ~10^5 vertices in seconds.
DEFAULT_VOXEL_M = 0.01
# Four voxels: wider than the Kinect's depth noise at 2-3 m (~1-2 cm) so a surface seen
# from several keyframes averages instead of breaking up, narrow enough to keep thin objects.
DEFAULT_TRUNCATION_M = 0.04
# Voxel blocks of 16^3 (Open3D's default), and the blocks the hash map starts with: it grows
# as the surface does (a desk scene at 1 cm takes a few thousand).
_BLOCK_RESOLUTION = 16
_INITIAL_BLOCKS = 1000
# A voxel enters the mesh once seen in this many depth images (summed weights): surfaces seen
# once are kept, so the mesh covers everything the keyframes saw.
_MIN_WEIGHT = 1.0
# Structured-light depth noise grows with the square of the distance (~4 cm at 4 m); farther
# depth would blur the surface more than it adds.
DEFAULT_MAX_DEPTH_M = 4.0


def require_open3d():
    """The ``open3d`` module; ``ImportError`` saying what to install when it is missing or
    its system library libusb-1.0 is."""
    try:
        import open3d
    except ImportError as err:
        if "libusb" in str(err):
            raise ImportError(
                f"open3d needs the system library libusb-1.0 ({err}): install it, e.g. "
                "`apt-get install libusb-1.0-0` (Debian/Ubuntu) or `dnf install libusb1`"
            ) from err
        raise ImportError(
            f"dense fusion needs Open3D ({err}): pip install 'ferroslam[dense]' (open3d-cpu)"
        ) from err
    return open3d


@dataclass(frozen=True)
class DenseModel:
    """The fused surface: ``vertices (V, 3)`` world metres, ``triangles (T, 3)`` vertex
    indices, ``vertex_colors (V, 3)`` uint8 RGB; ``points (P, 3)`` / ``point_colors (P, 3)``
    the dense cloud (the volume's zero crossings); ``fusion_s``: seconds the integration
    and extraction took; ``frames``: depth images fused."""

    vertices: np.ndarray
    triangles: np.ndarray
    vertex_colors: np.ndarray
    points: np.ndarray
    point_colors: np.ndarray
    fusion_s: float
    frames: int


def _undistortion_maps(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    if camera.model != "pinhole":
        raise ValueError(f"dense fusion takes pinhole cameras, got a {camera.model!r} one")
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    return cv2.initUndistortRectifyMap(K, np.asarray(camera.dist, np.float64), None, K,
                                       (camera.width, camera.height), cv2.CV_32FC1)


def fuse_tsdf(camera: Camera, T_w_c: np.ndarray, images: Sequence[np.ndarray],
              depths_m: Sequence[np.ndarray], *, voxel_m: float = DEFAULT_VOXEL_M,
              truncation_m: float = DEFAULT_TRUNCATION_M,
              max_depth_m: float = DEFAULT_MAX_DEPTH_M) -> DenseModel:
    """Fuses registered depth images at their poses into a TSDF volume; its mesh and cloud.

    Args:
        camera: the raw pinhole camera of the images (its distortion is removed first).
        T_w_c: ``(K, 4, 4)`` camera poses in the world, metres.
        images: ``K`` BGR (or grey) uint8 images.
        depths_m: ``K`` depth images in metres (0 or NaN: no measurement), the images' size.
        voxel_m, truncation_m: voxel edge and signed-distance truncation, metres.
        max_depth_m: depth beyond this is not fused.

    Raises:
        ValueError: a non-pinhole camera, mismatched counts or sizes, bad settings.
        ImportError: Open3D missing (see :func:`require_open3d`).
    """
    o3d = require_open3d()
    poses = np.asarray(T_w_c, dtype=np.float64).reshape(-1, 4, 4)
    if not (len(poses) == len(images) == len(depths_m)):
        raise ValueError(f"{len(poses)} poses, {len(images)} images and {len(depths_m)} "
                         "depth images: one of each per keyframe")
    if not (0 < voxel_m < truncation_m and max_depth_m > 0):
        raise ValueError(f"need 0 < voxel_m ({voxel_m}) < truncation_m ({truncation_m}) and "
                         f"max_depth_m ({max_depth_m}) > 0")
    map_x, map_y = _undistortion_maps(camera)
    K = o3d.core.Tensor([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]],
                        o3d.core.float64)
    start = time.perf_counter()
    float32 = o3d.core.float32
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(float32, float32, float32),
        attr_channels=(1, 1, 3), voxel_size=voxel_m, block_resolution=_BLOCK_RESOLUTION,
        block_count=_INITIAL_BLOCKS, device=o3d.core.Device("CPU:0"))
    trunc_voxels = truncation_m / voxel_m
    for T, image, depth in zip(poses, images, depths_m):
        if np.shape(depth)[:2] != (camera.height, camera.width):
            raise ValueError(f"a depth image is {np.shape(depth)[:2]}, the camera "
                             f"{camera.height}x{camera.width} (rows x columns)")
        rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB if image.ndim == 2 else cv2.COLOR_BGR2RGB)
        rgb = cv2.remap(rgb, map_x, map_y, cv2.INTER_LINEAR).astype(np.float32) / 255.0
        depth = np.nan_to_num(np.asarray(depth, np.float32), nan=0.0)
        depth = o3d.t.geometry.Image(o3d.core.Tensor(
            np.ascontiguousarray(cv2.remap(depth, map_x, map_y, cv2.INTER_NEAREST))))
        color = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(rgb)))
        T_c_w = o3d.core.Tensor(np.linalg.inv(T), o3d.core.float64)
        blocks = grid.compute_unique_block_coordinates(depth, K, T_c_w, 1.0, max_depth_m,
                                                       trunc_voxel_multiplier=trunc_voxels)
        grid.integrate(blocks, depth, color, K, K, T_c_w, 1.0, max_depth_m,
                       trunc_voxel_multiplier=trunc_voxels)
    mesh = grid.extract_triangle_mesh(weight_threshold=_MIN_WEIGHT)
    cloud = grid.extract_point_cloud(weight_threshold=_MIN_WEIGHT)
    fusion_s = time.perf_counter() - start
    return DenseModel(
        vertices=mesh.vertex.positions.numpy().astype(np.float64).reshape(-1, 3),
        triangles=mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3),
        vertex_colors=_u8(mesh.vertex.colors.numpy()),
        points=cloud.point.positions.numpy().astype(np.float64).reshape(-1, 3),
        point_colors=_u8(cloud.point.colors.numpy()), fusion_s=fusion_s, frames=len(poses))


def _u8(colors: np.ndarray) -> np.ndarray:
    """``(N, 3)`` uint8 from Open3D's float colours in [0, 1]."""
    return np.round(np.clip(colors, 0.0, 1.0) * 255.0).astype(np.uint8).reshape(-1, 3)


def write_mesh_ply(path: Path, dense: DenseModel) -> Path:
    """Writes the mesh as a binary PLY (vertices with colours, triangles) and returns the
    path; readable by MeshLab, Blender, Open3D."""
    header = "\n".join([
        "ply", "format binary_little_endian 1.0",
        "comment ferroslam TSDF mesh (world frame, metres)",
        f"element vertex {len(dense.vertices)}",
        "property float x", "property float y", "property float z",
        "property uchar red", "property uchar green", "property uchar blue",
        f"element face {len(dense.triangles)}",
        "property list uchar int vertex_indices", "end_header", ""]).encode("ascii")
    vertices = np.empty(len(dense.vertices), dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    vertices["xyz"], vertices["rgb"] = dense.vertices, dense.vertex_colors
    faces = np.empty(len(dense.triangles), dtype=[("n", "u1"), ("v", "<i4", 3)])
    faces["n"], faces["v"] = 3, dense.triangles
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(header + vertices.tobytes() + faces.tobytes())
    return Path(path)


def write_dense_outputs(out: Path, dense: DenseModel) -> None:
    """``mesh.ply`` and the dense cloud ``dense.ply`` in ``out``."""
    write_mesh_ply(out / "mesh.ply", dense)
    write_ply(out / "dense.ply", dense.points, dense.point_colors)
