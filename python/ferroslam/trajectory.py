"""``Trajectory``: timestamped camera poses ``T_w_c``, the unit every metric works on."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    """Camera poses in the world with their timestamps.

    Attributes:
        timestamps: ``(N,)`` float64 seconds, non-decreasing (KITTI files: frame indices).
        poses: ``(N, 4, 4)`` float64 ``T_w_c`` (maps camera points into the world frame).

    Raises:
        ValueError: on shape mismatch, non-finite values or timestamps that decrease.
    """

    timestamps: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.timestamps, dtype=np.float64)
        T = np.ascontiguousarray(self.poses, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"timestamps must be 1-D, got shape {t.shape}")
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise ValueError(f"poses must have shape (N, 4, 4), got {T.shape}")
        if T.shape[0] != t.shape[0]:
            raise ValueError(f"{t.shape[0]} timestamps but {T.shape[0]} poses")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(T))):
            raise ValueError("trajectory contains NaN or infinite values")
        if np.any(np.diff(t) < 0):
            i = int(np.argmax(np.diff(t) < 0))
            raise ValueError(f"timestamps out of order at index {i + 1}: {t[i + 1]} < {t[i]}")
        object.__setattr__(self, "timestamps", t)
        object.__setattr__(self, "poses", T)

    @classmethod
    def from_poses(cls, poses: np.ndarray) -> "Trajectory":
        """Trajectory without time (KITTI): timestamps are the frame indices 0, 1, ..."""
        poses = np.asarray(poses, dtype=np.float64)
        return cls(np.arange(poses.shape[0], dtype=np.float64), poses)

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    @property
    def positions(self) -> np.ndarray:
        """``(N, 3)`` camera centres in the world frame (metres)."""
        return self.poses[:, :3, 3]

    @property
    def rotations(self) -> np.ndarray:
        """``(N, 3, 3)`` rotations ``R_w_c``."""
        return self.poses[:, :3, :3]

    def subset(self, indices: np.ndarray) -> "Trajectory":
        """Trajectory with only the poses at ``indices`` (in the given order)."""
        indices = np.asarray(indices, dtype=np.intp)
        return Trajectory(self.timestamps[indices], self.poses[indices])

    def path_length(self) -> float:
        """Sum of distances between consecutive positions (metres)."""
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def transformed(self, R: np.ndarray, t: np.ndarray, scale: float = 1.0) -> "Trajectory":
        """Apply a similarity from the left: ``T' = [R R_w_c | scale R t_w_c + t]``."""
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)
        out = self.poses.copy()
        out[:, :3, :3] = R @ self.poses[:, :3, :3]
        out[:, :3, 3] = scale * self.positions @ R.T + t
        return Trajectory(self.timestamps, out)
