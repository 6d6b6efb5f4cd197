"""Trajectory file readers and writers (TUM, KITTI and EuRoC formats).

* TUM: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (``T_w_c``, metres, seconds);
  lines starting with ``#`` and blank lines are ignored.
* KITTI: one pose per line, the first three rows of ``T_w_c`` row-major (12 numbers).
* EuRoC: the ASL csv of EuRoC's ground truth (what evo's ``euroc`` command reads),
  ``timestamp_ns,tx,ty,tz,qw,qx,qy,qz`` (``T_w_c``, metres, integer nanoseconds; note the
  quaternion's ``w`` first) under a ``#timestamp [ns], p_RS_R_x [m], ...`` header.

Readers raise ``FileNotFoundError`` naming the file, and ``ValueError`` naming the file and
line for malformed lines or timestamps out of order. Writers go through
:func:`ferroslam._files.atomic_output` (the file appears complete or not at all).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Union

import numpy as np

from ._files import atomic_output, regular_file
from .trajectory import Trajectory
from .transforms import poses_from_tum, tum_from_poses

__all__ = [
    "read_euroc_trajectory",
    "read_kitti_poses",
    "read_table",
    "read_tum_trajectory",
    "write_euroc_trajectory",
    "write_kitti_poses",
    "write_tum_trajectory",
]

PathLike = Union[str, "os.PathLike[str]"]


def read_table(path: PathLike, n_columns: int, what: str = "file") -> list[tuple[int, list[str]]]:
    """Non-comment lines of a whitespace-separated text file as ``(line_number, fields)``.

    Raises ``FileNotFoundError`` if ``path`` is missing, ``IsADirectoryError`` for a folder,
    and ``ValueError`` for a FIFO or device, for text that is not UTF-8 and (with file and
    line) if a line has fewer than ``n_columns`` fields.
    """
    path = regular_file(path, what)  # a FIFO or a folder is refused before opening
    rows = []
    with open(path, encoding="utf-8") as f:
        try:
            for number, line in enumerate(f, start=1):
                text = line.strip()
                if not text or text.startswith("#"):
                    continue
                fields = text.replace(",", " ").split()
                if len(fields) < n_columns:
                    raise ValueError(f"{path}:{number}: expected {n_columns} fields, got "
                                     f"{len(fields)}: {text!r}")
                rows.append((number, fields))
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a UTF-8 text file") from None
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
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
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
    with atomic_output(path) as tmp:
        np.savetxt(tmp, T[:, :3, :].reshape(-1, 12), fmt="%.9e")


_EUROC_HEADER = ("#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], "
                 "q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []")


def _nanoseconds(timestamps_s: np.ndarray) -> np.ndarray:
    """Integer nanoseconds nearest to float seconds, whole seconds split off first so that
    ``t * 1e9`` (beyond float64's exact integers for Unix times) never rounds."""
    whole_s = np.floor(timestamps_s)
    fraction_ns = np.round((timestamps_s - whole_s) * 1e9).astype(np.int64)
    return whole_s.astype(np.int64) * 10**9 + fraction_ns


def read_asl_rows(path: Path, n_columns: int, what: str) -> tuple[np.ndarray, list[list[str]]]:
    """Rows of an ASL csv: nanosecond timestamps (strictly increasing) and the fields."""
    rows = read_table(path, n_columns, what)
    stamps = np.empty(len(rows), dtype=np.int64)
    for r, (number, fields) in enumerate(rows):
        try:
            stamps[r] = int(fields[0])
        except ValueError:
            raise ValueError(f"{path}:{number}: bad nanosecond timestamp {fields[0]!r}") from None
        if r and stamps[r] <= stamps[r - 1]:
            raise ValueError(
                f"{path}:{number}: timestamps out of order ({stamps[r]} ns after "
                f"{stamps[r - 1]} ns)"
            )
    return stamps, [fields for _, fields in rows]


def seconds_from_ns(ns: np.ndarray) -> np.ndarray:
    """Float seconds of integer nanoseconds (split first to keep every digit: 1.4e18 ns is
    beyond float64's exact integers)."""
    ns = np.asarray(ns, dtype=np.int64)
    return (ns // 10**9).astype(np.float64) + (ns % 10**9).astype(np.float64) * 1e-9


def read_asl_floats(path: Path, rows: list[list[str]], columns: slice) -> np.ndarray:
    """The ``columns`` of ASL csv ``rows`` as finite float64 values."""
    try:
        out = np.array([[float(v) for v in fields[columns]] for fields in rows], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{path}: a value is not a number") from None
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{path}: non-finite value")
    return out


def read_euroc_trajectory(path: PathLike) -> Trajectory:
    """Read an ASL csv (``t_ns, p xyz, q wxyz``, extra columns ignored) as ``T_w_c``.

    Nanosecond timestamps must strictly increase; they become float64 seconds (about 0.2 us
    resolution at today's Unix times). The pose is taken as is: for EuRoC's own ground truth
    (the IMU body, not a camera) use ``EurocSequence.groundtruth``, which applies ``T_b_c``.
    """
    path = Path(path)
    stamps_ns, rows = read_asl_rows(path, 8, "EuRoC trajectory")
    p_q_wxyz = read_asl_floats(path, rows, slice(1, 8)).reshape(-1, 7)
    xyz_quat = np.concatenate([p_q_wxyz[:, :3], p_q_wxyz[:, 4:7], p_q_wxyz[:, 3:4]], 1)
    return Trajectory(seconds_from_ns(stamps_ns), poses_from_tum(xyz_quat))


def write_euroc_trajectory(path: PathLike, timestamps: np.ndarray, T_w_c: np.ndarray) -> None:
    """Write ``timestamps (N,)`` seconds and ``T_w_c (N, 4, 4)`` as an ASL csv.

    Timestamps are written as the nearest integer nanoseconds, the pose with 9 decimals and
    the quaternion ``w`` first, as in EuRoC's ``state_groundtruth_estimate0/data.csv``.
    """
    traj = Trajectory(timestamps, T_w_c)
    xyz_quat = tum_from_poses(traj.poses)
    p_q_wxyz = np.concatenate([xyz_quat[:, :3], xyz_quat[:, 6:7], xyz_quat[:, 3:6]], 1)
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(_EUROC_HEADER + "\n")
        for t_ns, row in zip(_nanoseconds(traj.timestamps), p_q_wxyz):
            f.write(f"{t_ns}," + ",".join(f"{v:.9f}" for v in row) + "\n")
