"""Argument and file checks shared by the package (outputs, readers, options)."""

from __future__ import annotations

import os
from typing import Optional, Sequence

import numpy as np


def finite_array(value: object, name: str, shape: Sequence[Optional[int]]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (``None`` = any length), all finite.

    Raises ``ValueError`` naming ``name`` for a non-numeric value, a wrong shape, NaN or inf.
    """
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}") from None
    expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
    mismatch = any(s is not None and s != n for s, n in zip(shape, array.shape))
    if array.ndim != len(shape) or mismatch:
        raise ValueError(f"{name} must have shape {expected}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))[0]
        raise ValueError(
            f"{name} contains NaN or infinite values (first at index {tuple(bad.tolist())})"
        )
    return array


# Largest deviation of R R^T from I, and of the last row from (0 0 0 1), in a rigid transform:
# leaves room for matrices stored as float32 or printed with ~7 digits.
RIGID_TOL = 1e-6


def rigid_transform(value: object, name: str) -> np.ndarray:
    """``value`` as a finite rigid ``(4, 4)`` float64 transform; ``ValueError`` naming
    ``name`` otherwise."""
    T = finite_array(value, name, (4, 4))
    R = T[:3, :3]
    if (not np.allclose(R @ R.T, np.eye(3), atol=RIGID_TOL) or np.linalg.det(R) < 0
            or not np.allclose(T[3], [0, 0, 0, 1], atol=RIGID_TOL)):
        raise ValueError(f"{name} is not a rigid transform (rotation not orthonormal or last "
                         "row not 0 0 0 1)")
    return T


# Calibration and list files are kilobytes; a bound keeps a wrong path (a video, a disk
# image) from being read whole.
MAX_TEXT_FILE_BYTES = 16 << 20


def read_text(path: "os.PathLike[str] | str", what: str,
              max_bytes: int = MAX_TEXT_FILE_BYTES) -> str:
    """The UTF-8 text of the regular file ``path`` through the package's bounded reader
    (``_files.read_bounded_text``): ``FileNotFoundError`` naming ``what`` and the file when
    it is missing, ``ValueError`` naming the file for a FIFO/device (refused before it could
    block), a file over ``max_bytes`` or one that is not UTF-8."""
    from ._files import read_bounded_text

    return read_bounded_text(path, max_bytes, what)
