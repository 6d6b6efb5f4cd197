"""Files users look at outside Python: map point clouds (PLY) and keyframe trajectories.

* :func:`write_ply` writes points (and optional colours) as a PLY vertex list, readable by
  MeshLab, CloudCompare, Open3D, Blender.
* :func:`write_trajectory` dispatches to the TUM / KITTI writers of :mod:`ferroslam.io`.

Both raise ``ValueError`` naming the offending argument (shape, NaN/inf, range) before
touching the file, and create missing parent folders.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ._validate import finite_array
from .io import PathLike, write_kitti_poses, write_tum_trajectory
from .trajectory import Trajectory

__all__ = ["write_ply", "write_trajectory"]

_XYZ = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
_RGB = [("red", "u1"), ("green", "u1"), ("blue", "u1")]


def _colors_u8(colors: object, n: int) -> np.ndarray:
    """``(n, 3)`` uint8 colours from uint8-range integers or floats in ``[0, 1]``."""
    raw = np.asarray(colors)
    c = finite_array(raw, "colors", (n, 3))
    if np.issubdtype(raw.dtype, np.floating):
        if c.size and (c.min() < 0.0 or c.max() > 1.0):
            raise ValueError("colors given as floats must lie in [0, 1]")
        return np.round(c * 255.0).astype(np.uint8)
    if c.size and (c.min() < 0 or c.max() > 255):
        raise ValueError("colors given as integers must lie in [0, 255]")
    return c.astype(np.uint8)


def write_ply(
    path: PathLike,
    points: np.ndarray,
    colors: Optional[np.ndarray] = None,
    *,
    binary: bool = False,
) -> Path:
    """Write ``points`` as a PLY point cloud and return the path.

    Args:
        path: output file (parent folders are created).
        points: ``(N, 3)`` world positions in metres (``N`` may be 0), all finite.
        colors: optional ``(N, 3)`` RGB, integers in ``[0, 255]`` or floats in ``[0, 1]``
            (rounded to 8 bits).
        binary: ``False`` writes ``format ascii 1.0`` (coordinates with 17 significant
            digits: exact float64 round trip); ``True`` writes ``format
            binary_little_endian 1.0``.

    The header is::

        ply
        format ascii 1.0            (or binary_little_endian 1.0)
        comment ferroslam map points (world frame, metres)
        element vertex N
        property double x
        property double y
        property double z
        property uchar red          (these three only with colors)
        property uchar green
        property uchar blue
        end_header

    followed by one vertex per line (ASCII) or packed records of 3 float64 (+ 3 uint8).

    Raises:
        ValueError: ``points`` or ``colors`` of the wrong shape, non-finite or out of range.
    """
    xyz = finite_array(points, "points", (None, 3))
    rgb = None if colors is None else _colors_u8(colors, xyz.shape[0])
    fields = _XYZ + (_RGB if rgb is not None else [])
    types = {"<f8": "double", "u1": "uchar"}
    header = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment ferroslam map points (world frame, metres)",
        f"element vertex {xyz.shape[0]}",
        *(f"property {types[t]} {name}" for name, t in fields),
        "end_header",
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            records = np.empty(xyz.shape[0], dtype=fields)
            for i, axis in enumerate("xyz"):
                records[axis] = xyz[:, i]
            if rgb is not None:
                for i, (name, _) in enumerate(_RGB):
                    records[name] = rgb[:, i]
            f.write(records.tobytes())
        else:
            table = xyz if rgb is None else np.column_stack([xyz, rgb])
            np.savetxt(f, table, fmt=["%.17g"] * 3 + ["%d"] * (table.shape[1] - 3))
    return path


def write_trajectory(
    path: PathLike,
    timestamps: np.ndarray,
    poses: np.ndarray,
    format: str = "tum",
) -> Path:
    """Write a (keyframe) trajectory with the :mod:`ferroslam.io` writers; return the path.

    Args:
        path: output file (parent folders are created).
        timestamps: ``(N,)`` seconds, non-decreasing (not written in KITTI files, whose
            lines are implicitly indexed 0, 1, ...).
        poses: ``(N, 4, 4)`` camera poses ``T_w_c`` (camera to world, metres).
        format: ``"tum"`` (``timestamp tx ty tz qx qy qz qw``) or ``"kitti"`` (first three
            rows of ``T_w_c``, row-major).

    Raises:
        ValueError: unknown ``format``; shapes, NaN/inf or decreasing timestamps (from
            :class:`~ferroslam.trajectory.Trajectory`); a pose that is not rigid.
    """
    writers = {
        "tum": lambda t: write_tum_trajectory(path, t.timestamps, t.poses),
        "kitti": lambda t: write_kitti_poses(path, t.poses),
    }
    if format not in writers:
        raise ValueError(f"format must be one of {sorted(writers)}, got {format!r}")
    trajectory = Trajectory(timestamps, poses)
    rotations = trajectory.poses[:, :3, :3]
    gram_error = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max(axis=(1, 2))
    bottom_ok = np.all(trajectory.poses[:, 3] == [0.0, 0.0, 0.0, 1.0], axis=1)
    bad = np.flatnonzero((gram_error > 1e-6) | (np.linalg.det(rotations) <= 0) | ~bottom_ok)
    if bad.size:
        raise ValueError(f"poses[{bad[0]}] is not a rigid transform (orthonormal rotation, "
                         "determinant +1, last row 0 0 0 1): a TUM or KITTI file holds "
                         "rigid camera poses")
    writers[format](trajectory)
    return Path(path)
