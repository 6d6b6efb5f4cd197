"""Rigid-body helpers on batches of 4x4 homogeneous poses (numpy, float64).

Conventions (see notes/COMMON.md): ``T_a_b`` maps points from frame b into frame a,
``p_a = T_a_b @ p_b``; a camera pose in the world is ``T_w_c``. Quaternions are stored
in the TUM order ``(qx, qy, qz, qw)``. Every function accepts one pose ``(4, 4)`` or a batch
``(N, 4, 4)`` and returns the same rank.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "inverse",
    "matrix_to_quat",
    "poses_from_tum",
    "quat_to_matrix",
    "rotation_angle",
    "tum_from_poses",
]


def inverse(T: np.ndarray) -> np.ndarray:
    """SE(3) inverse ``[R^T | -R^T t]`` of one ``(4, 4)`` or many ``(N, 4, 4)`` poses."""
    T = np.asarray(T, dtype=np.float64)
    R_t = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R_t, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from quaternions ``(..., 4)`` in ``(qx, qy, qz, qw)``.

    Quaternions are normalised first; a zero quaternion raises ``ValueError``.
    """
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(~np.isfinite(norm)) or np.any(norm < 1e-12):
        raise ValueError("quaternion with zero norm or non-finite entries")
    x, y, z, w = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` ``(qx, qy, qz, qw)`` with ``qw >= 0`` from ``(..., 3, 3)``.

    Uses Markley's method (pick the largest of trace and diagonal), which also projects a
    slightly non-orthonormal matrix onto a nearby rotation, as scipy's ``from_matrix`` does.
    """
    R = np.asarray(R, dtype=np.float64)
    batch = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], -1)
    trace = diag.sum(-1)
    choice = np.argmax(np.concatenate([diag, trace[:, None]], -1), -1)
    # Case: a diagonal element i is largest (rows where the trace wins are overwritten below).
    i = np.minimum(choice, 2)
    j = (i + 1) % 3
    k = (j + 1) % 3
    n = np.arange(R.shape[0])
    q_diag = np.empty((R.shape[0], 4))
    q_diag[n, i] = 1 - trace + 2 * R[n, i, i]
    q_diag[n, j] = R[n, j, i] + R[n, i, j]
    q_diag[n, k] = R[n, k, i] + R[n, i, k]
    q_diag[n, 3] = R[n, k, j] - R[n, j, k]
    # Case: the trace is largest.
    q_trace = np.stack(
        [R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1], 1 + trace], -1
    )
    q = np.where((choice == 3)[:, None], q_trace, q_diag)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    return q.reshape(*batch, 4)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, ``|Log(R)|``, of ``(..., 3, 3)`` matrices.

    Computed as ``2 atan2(|q_xyz|, |q_w|)`` from the Markley quaternion, which is accurate
    near 0 and pi and robust to matrices orthonormal only to ~1e-7 (KITTI files).
    """
    q = matrix_to_quat(R)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3]))


def poses_from_tum(xyz_quat: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` poses from TUM rows ``(N, 7)`` = ``tx ty tz qx qy qz qw``."""
    xyz_quat = np.asarray(xyz_quat, dtype=np.float64)
    T = np.zeros((xyz_quat.shape[0], 4, 4))
    T[:, :3, :3] = quat_to_matrix(xyz_quat[:, 3:7])
    T[:, :3, 3] = xyz_quat[:, :3]
    T[:, 3, 3] = 1.0
    return T


def tum_from_poses(T: np.ndarray) -> np.ndarray:
    """TUM rows ``(N, 7)`` = ``tx ty tz qx qy qz qw`` from ``(N, 4, 4)`` poses."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[:, :3, 3], matrix_to_quat(T[:, :3, :3])], -1)
