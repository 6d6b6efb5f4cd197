"""Trajectory file readers and writers (TUM and KITTI formats).

* TUM: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (``T_w_c``, metres, seconds);
  lines starting with ``#`` and blank lines are ignored.
* KITTI: one pose per line, the first three rows of ``T_w_c`` row-major (12 numbers).

Readers raise ``FileNotFoundError`` naming the file, and ``ValueError`` naming the file and
line for malformed lines or timestamps out of order.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Union

import numpy as np

from .trajectory import Trajectory
from .transforms import poses_from_tum, tum_from_poses

__all__ = [
    "read_kitti_poses",
    "read_table",
    "read_tum_trajectory",
    "write_kitti_poses",
    "write_tum_trajectory",
]

PathLike = Union[str, "os.PathLike[str]"]


def read_table(path: PathLike, n_columns: int, what: str = "file") -> list[tuple[int, list[str]]]:
    """Non-comment lines of a whitespace-separated text file as ``(line_number, fields)``.

    Raises ``FileNotFoundError`` if ``path`` is missing and ``ValueError`` (with file and line)
    if a line has fewer than ``n_columns`` fields.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    rows = []
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.replace(",", " ").split()
            if len(fields) < n_columns:
                raise ValueError(
                    f"{path}:{number}: expected {n_columns} fields, got {len(fields)}: {text!r}"
                )
            rows.append((number, fields))
    return rows


def _floats(path: Path, rows: list[tuple[int, list[str]]], n_columns: int) -> np.ndarray:
    out = np.empty((len(rows), n_columns))
    for r, (number, fields) in enumerate(rows):
        try:
            out[r] = [float(v) for v in fields[:n_columns]]
        except ValueError:
            raise ValueError(f"{path}:{number}: not a number in {' '.join(fields)!r}") from None
        if not np.all(np.isfinite(out[r])):
            raise ValueError(f"{path}:{number}: non-finite value in {' '.join(fields)!r}")
    return out


def read_tum_trajectory(path: PathLike) -> Trajectory:
    """Read a TUM trajectory file into a :class:`Trajectory` (timestamps must not decrease)."""
    path = Path(path)
    rows = read_table(path, 8, "TUM trajectory")
    data = _floats(path, rows, 8)
    backwards = np.flatnonzero(np.diff(data[:, 0]) < 0)
    if backwards.size:
        number = rows[backwards[0] + 1][0]
        raise ValueError(f"{path}:{number}: timestamp out of order (earlier than previous line)")
    return Trajectory(data[:, 0], poses_from_tum(data[:, 1:8]))


def write_tum_trajectory(path: PathLike, timestamps: np.ndarray, T_w_c: np.ndarray) -> None:
    """Write ``timestamps (N,)`` and ``T_w_c (N, 4, 4)`` as a TUM file.

    Timestamps are written with 6 decimals (microseconds, as in TUM files), the pose with 9.
    """
    traj = Trajectory(timestamps, T_w_c)
    rows = tum_from_poses(traj.poses)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        for t, row in zip(traj.timestamps, rows):
            f.write(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in row) + "\n")


def read_kitti_poses(path: PathLike) -> Trajectory:
    """Read a KITTI pose file; timestamps are the frame indices (0, 1, 2, ...)."""
    path = Path(path)
    rows = read_table(path, 12, "KITTI pose file")
    data = _floats(path, rows, 12)
    T = np.zeros((len(rows), 4, 4))
    T[:, :3, :] = data.reshape(-1, 3, 4)
    T[:, 3, 3] = 1.0
    return Trajectory.from_poses(T)


def write_kitti_poses(path: PathLike, T_w_c: np.ndarray) -> None:
    """Write ``T_w_c (N, 4, 4)`` as KITTI lines (first three rows, row-major, ``%.9e``)."""
    T = np.asarray(T_w_c, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"T_w_c must have shape (N, 4, 4), got {T.shape}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, T[:, :3, :].reshape(-1, 12), fmt="%.9e")
