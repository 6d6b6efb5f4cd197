"""Trajectory accuracy metrics, computed like evo (M. Grupp, github.com/MichaelGrupp/evo).

Notation follows Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems"
(IROS 2012): ``Q_i`` are reference (ground-truth) poses, ``P_i`` estimated poses, both
``T_w_c``. The absolute trajectory error (ATE) compares positions after aligning the
estimate to the reference with Umeyama's method; the relative pose error (RPE) compares
motions over ``delta`` frames: ``E_i = (Q_i^-1 Q_{i+delta})^-1 (P_i^-1 P_{i+delta})``.

``/work/shared/data/groundtruth/expected.json`` holds evo's numbers for real trajectories;
``tests/test_metrics.py`` reproduces all of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .trajectory import Trajectory
from .transforms import inverse, rotation_angle

__all__ = [
    "ALIGNMENTS",
    "AteResult",
    "PathLengthResult",
    "RpeResult",
    "Stats",
    "Trajectory",
    "associate",
    "ate",
    "path_length",
    "rpe",
    "stats",
    "umeyama_alignment",
]

ALIGNMENTS = ("none", "se3", "sim3")


@dataclass(frozen=True)
class Stats:
    """Summary statistics of per-pose errors (as evo's ``get_all_statistics``)."""

    rmse: float
    mean: float
    median: float
    std: float  # population standard deviation (ddof 0)
    min: float
    max: float
    sse: float  # sum of squared errors


def stats(errors: np.ndarray) -> Stats:
    """Statistics of a non-empty 1-D error array; ``ValueError`` if it is empty."""
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or e.size == 0:
        raise ValueError(f"need a non-empty 1-D error array, got shape {e.shape}")
    sq = e * e
    return Stats(
        rmse=float(np.sqrt(np.mean(sq))),
        mean=float(np.mean(e)),
        median=float(np.median(e)),
        std=float(np.std(e)),
        min=float(np.min(e)),
        max=float(np.max(e)),
        sse=float(np.sum(sq)),
    )


def associate(
    t_ref: np.ndarray, t_est: np.ndarray, max_diff: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Pair poses by timestamp with evo's rule (``evo.core.sync.associate_trajectories``).

    Walk over the timestamps of the trajectory with fewer poses (the reference when both
    have the same length); for each, take the nearest timestamp of the other one (the earlier
    on an exact tie) and keep the pair if ``|dt| <= max_diff`` seconds. A pose of the longer
    trajectory may be used twice. Both inputs must be sorted (non-decreasing).

    Returns:
        ``(idx_ref, idx_est)``: int arrays of equal length, in the order of the shorter list.
    """
    if not (isinstance(max_diff, (int, float, np.floating, np.integer))
            and np.isfinite(max_diff) and max_diff >= 0):
        raise ValueError(f"max_diff must be a number of seconds >= 0, got {max_diff!r}")
    t_ref = np.asarray(t_ref, dtype=np.float64)
    t_est = np.asarray(t_est, dtype=np.float64)
    for name, t in (("t_ref", t_ref), ("t_est", t_est)):
        if t.ndim != 1:
            raise ValueError(f"{name} must be 1-D, got shape {t.shape}")
        if np.any(np.diff(t) < 0):
            raise ValueError(f"{name} must be sorted in time")
    if t_ref.size == 0 or t_est.size == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    est_longer = t_est.size > t_ref.size
    short, long_ = (t_ref, t_est) if est_longer else (t_est, t_ref)
    right = np.searchsorted(long_, short, side="left").clip(1, long_.size - 1)
    left = right - 1
    if long_.size == 1:
        left = right = np.zeros_like(right)
    d_left = np.abs(long_[left] - short)
    d_right = np.abs(long_[right] - short)
    nearest = np.where(d_right < d_left, right, left)
    # np.argmin over equal timestamps returns the first of them.
    nearest = np.searchsorted(long_, long_[nearest], side="left")
    diff = np.minimum(d_left, d_right)
    idx_short = np.flatnonzero(diff <= max_diff)
    idx_long = nearest[idx_short]
    return (idx_short, idx_long) if est_longer else (idx_long, idx_short)


def umeyama_alignment(
    x: np.ndarray, y: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity ``y ~ c R x + t`` (Umeyama, PAMI 1991).

    Args:
        x: ``(N, 3)`` source points (estimate positions).
        y: ``(N, 3)`` target points (reference positions).
        with_scale: estimate ``c`` (Sim(3)); otherwise ``c = 1`` (SE(3)).

    Returns:
        ``(R (3, 3), t (3,), c)``.

    Raises:
        ValueError: on shape mismatch, fewer than 3 points or a degenerate (collinear) set.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x and y must both be (N, 3), got {x.shape} and {y.shape}")
    n = x.shape[0]
    if n < 3:
        raise ValueError(f"Umeyama alignment needs at least 3 point pairs, got {n}")
    mean_x, mean_y = x.mean(0), y.mean(0)
    xc, yc = x - mean_x, y - mean_y
    sigma_x = np.sum(xc * xc) / n
    cov = yc.T @ xc / n
    U, D, Vt = np.linalg.svd(cov)
    if np.count_nonzero(D > np.finfo(D.dtype).eps) < 2:
        raise ValueError("degenerate point set (rank < 2): alignment is not unique")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    c = float(np.trace(np.diag(D) @ S) / sigma_x) if with_scale else 1.0
    t = mean_y - c * R @ mean_x
    return R, t, c


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error: translation error after alignment.

    ``errors[i] = |trans(Q_i) - trans(P'_i)|`` in metres over the associated pairs, where
    ``P'_i = S P_i`` is the aligned estimate; ``alignment`` is ``S`` as a 4x4 matrix
    ``[scale * R | t]`` (``None`` for ``align='none'``). ``aligned`` is the associated,
    aligned estimate and ``reference`` the associated reference (for plots).
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    errors: np.ndarray
    scale: float
    alignment: Optional[np.ndarray]
    pairs: int
    aligned: Trajectory
    reference: Trajectory
    unit: str = "m"


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error over ``delta`` frames of associated poses.

    ``trans_*`` in metres, ``rot_deg_*`` in degrees; ``trans_errors`` / ``rot_deg_errors``
    hold the ``pairs`` per-pair values.
    """

    trans_rmse: float
    trans_mean: float
    trans_median: float
    trans_std: float
    trans_min: float
    trans_max: float
    trans_sse: float
    rot_deg_rmse: float
    rot_deg_mean: float
    rot_deg_median: float
    rot_deg_std: float
    rot_deg_min: float
    rot_deg_max: float
    rot_deg_sse: float
    trans_errors: np.ndarray
    rot_deg_errors: np.ndarray
    pairs: int
    delta: int
    trans_unit: str = "m"
    rot_unit: str = "deg"

    def trans_stats(self) -> Stats:
        """Translation statistics as a :class:`Stats`."""
        return stats(self.trans_errors)

    def rot_deg_stats(self) -> Stats:
        """Rotation statistics (degrees) as a :class:`Stats`."""
        return stats(self.rot_deg_errors)


def _associated_aligned(
    traj_ref: Trajectory, traj_est: Trajectory, align: str, max_diff: float
) -> tuple[Trajectory, Trajectory, float, Optional[np.ndarray]]:
    for name, value in (("traj_ref", traj_ref), ("traj_est", traj_est)):
        if not isinstance(value, Trajectory):
            raise TypeError(f"{name} must be a ferroslam.Trajectory (Trajectory(timestamps, "
                            "poses) or io.read_tum_trajectory(path)), got "
                            f"{type(value).__name__}")
    if align not in ALIGNMENTS:
        raise ValueError(f"align must be one of {ALIGNMENTS}, got {align!r}")
    if not (isinstance(max_diff, (int, float)) and 0 <= max_diff < float("inf")):
        raise ValueError(f"max_diff must be a finite number of seconds >= 0, got {max_diff!r}")
    idx_ref, idx_est = associate(traj_ref.timestamps, traj_est.timestamps, max_diff)
    if idx_ref.size == 0:
        raise ValueError(
            f"no timestamps of the estimate match the reference within {max_diff} s: "
            "check that both files use the same clock (or raise max_diff)"
        )
    ref = traj_ref.subset(idx_ref)
    est = traj_est.subset(idx_est)
    if align == "none":
        return ref, est, 1.0, None
    R, t, c = umeyama_alignment(est.positions, ref.positions, with_scale=(align == "sim3"))
    S = np.eye(4)
    S[:3, :3] = c * R
    S[:3, 3] = t
    return ref, est.transformed(R, t, c), c, S


def ate(
    traj_ref: Trajectory, traj_est: Trajectory, align: str = "se3", max_diff: float = 0.01
) -> AteResult:
    """Absolute trajectory error (evo ``APE``, translation part).

    Poses are associated with :func:`associate` (``max_diff`` seconds), the estimate is
    aligned on positions with :func:`umeyama_alignment` (``'se3'``, ``'sim3'`` for
    monocular/arbitrary scale, ``'none'``), and per-pair position errors are summarised.

    Raises:
        ValueError: unknown ``align``, no associated pairs, or a degenerate alignment.
    """
    ref, est, c, S = _associated_aligned(traj_ref, traj_est, align, max_diff)
    errors = np.linalg.norm(ref.positions - est.positions, axis=1)
    s = stats(errors)
    return AteResult(
        **vars(s), errors=errors, scale=c, alignment=S, pairs=len(ref), aligned=est, reference=ref
    )


@dataclass(frozen=True)
class PathLengthResult:
    """Path lengths (metres) of the associated poses; ``scale_error = estimate / reference - 1``
    measures metric scale independently of any alignment."""

    estimate_m: float
    reference_m: float
    pairs: int

    @property
    def scale_error(self) -> float:
        return self.estimate_m / self.reference_m - 1.0


def path_length(
    traj_ref: Trajectory, traj_est: Trajectory, max_diff: float = 0.01
) -> PathLengthResult:
    """Lengths of both trajectories over the poses they have in common (by timestamp).

    Raises:
        ValueError: fewer than two associated poses or a reference that does not move.
    """
    ref, est, _, _ = _associated_aligned(traj_ref, traj_est, "none", max_diff)
    if len(ref) < 2:
        raise ValueError(f"path length needs at least 2 associated poses, got {len(ref)}")
    result = PathLengthResult(est.path_length(), ref.path_length(), len(ref))
    if not result.reference_m > 0:
        raise ValueError("the reference trajectory does not move: no scale to compare")
    return result


def rpe(
    traj_ref: Trajectory,
    traj_est: Trajectory,
    delta: int = 1,
    align: str = "none",
    max_diff: float = 0.01,
) -> RpeResult:
    """Relative pose error (evo ``RPE``, ``delta`` in frames, consecutive pairs only).

    After association (and optional alignment: only ``'sim3'`` changes the result, by
    rescaling translations), for every associated index ``i``:
    ``E_i = (Q_i^-1 Q_{i+delta})^-1 (P_i^-1 P_{i+delta})``; ``trans = |trans(E_i)|`` (m),
    ``rot = |Log(Rot(E_i))|`` (degrees).

    Raises:
        ValueError: ``delta < 1``, fewer than ``delta + 1`` associated poses, unknown align.
    """
    if int(delta) != delta or delta < 1:
        raise ValueError(f"delta must be a positive integer number of frames, got {delta}")
    delta = int(delta)
    ref, est, _, _ = _associated_aligned(traj_ref, traj_est, align, max_diff)
    if len(ref) <= delta:
        raise ValueError(f"need more than delta={delta} associated poses, got {len(ref)}")
    Q, P = ref.poses, est.poses
    dQ = inverse(Q[:-delta]) @ Q[delta:]
    dP = inverse(P[:-delta]) @ P[delta:]
    E = inverse(dQ) @ dP
    trans = np.linalg.norm(E[:, :3, 3], axis=1)
    rot = np.degrees(rotation_angle(E[:, :3, :3]))
    st, sr = stats(trans), stats(rot)
    fields = {f"trans_{k}": v for k, v in vars(st).items()}
    fields.update({f"rot_deg_{k}": v for k, v in vars(sr).items()})
    return RpeResult(
        **fields, trans_errors=trans, rot_deg_errors=rot, pairs=int(trans.size), delta=delta
    )
