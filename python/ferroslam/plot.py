"""Trajectory and map plots (matplotlib, Agg backend: works headless).

Figures are built with ``matplotlib.figure.Figure`` and an Agg canvas, never through
``pyplot``, so nothing here needs a display or touches pyplot's global state. Positions are
camera centres of ``T_w_c`` (camera to world) in metres.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional, Union

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ._files import atomic_output
from ._validate import finite_array
from .trajectory import Trajectory

__all__ = [
    "plot_map",
    "plot_overview",
    "plot_trajectories",
    "plot_trajectory_top_view",
    "top_view_axes",
]

_AXIS_NAMES = "xyz"


def top_view_axes(*trajectories: Trajectory) -> tuple[int, int]:
    """The two world axes with the largest extent over all positions, in index order."""
    positions = np.concatenate([t.positions for t in trajectories if len(t)])
    if positions.size == 0:
        return 0, 2
    extent = positions.max(0) - positions.min(0)
    a, b = sorted(np.argsort(-extent, kind="stable")[:2].tolist())
    return a, b


def plot_trajectory_top_view(
    est: Trajectory,
    ref: Optional[Trajectory],
    path: Union[str, Path],
    title: str = "trajectory (top view)",
) -> Path:
    """Save a PNG of the estimate (and reference) projected on the two widest world axes.

    Positions are the camera centres of ``T_w_c`` in metres; pass an aligned estimate
    (e.g. ``ate(...).aligned``) to compare it with the reference. Returns the written path.
    """
    shown = [est] + ([ref] if ref is not None else [])
    a, b = top_view_axes(*shown)
    fig = _figure((6.4, 5.4))
    ax = fig.add_subplot(1, 1, 1)
    _draw_view(ax, est, ref, a, b, title)
    return _save(fig, path)


def plot_trajectories(
    estimate: Union[Trajectory, np.ndarray],
    reference: Optional[Union[Trajectory, np.ndarray]] = None,
    path: Optional[Union[str, Path]] = None,
) -> Figure:
    """Top and side views of ``estimate`` (and ``reference``, e.g. ground truth).

    The top view shows the two world axes of widest extent (:func:`top_view_axes`), the side
    view the wider of those two against the remaining axis, both with equal scaling. Pass an
    aligned estimate (e.g. ``ate(...).aligned``) to compare it with the reference.

    Args:
        estimate: :class:`Trajectory` or ``(N, 4, 4)`` poses ``T_w_c``, ``N >= 1``.
        reference: optional, same kinds.
        path: if given, the figure is also saved there (PNG by suffix; folders created).

    Returns:
        The matplotlib ``Figure`` (two axes).

    Raises:
        ValueError: naming ``estimate`` / ``reference`` for wrong shapes, NaN/inf or an
            empty estimate.
    """
    est, ref = _checked_pair(estimate, reference)
    fig = _figure((11.0, 5.0))
    _draw_top_and_side(fig, 1, 2, est, ref)
    if path is not None:
        _save(fig, path)
    return fig


def plot_overview(
    estimate: Union[Trajectory, np.ndarray],
    reference: Optional[Union[Trajectory, np.ndarray]],
    points: np.ndarray,
    keyframe_poses: np.ndarray,
    path: Optional[Union[str, Path]] = None,
    title: Optional[str] = None,
) -> Figure:
    """One figure of a run: top and side views (as :func:`plot_trajectories`) and the map
    (as :func:`plot_map`), side by side.

    All inputs must be in the same world frame: to compare with ground truth, pass the
    aligned estimate and map (apply ``ate(...).alignment`` to points and poses).

    Raises:
        ValueError: as :func:`plot_trajectories` and :func:`plot_map`.
    """
    est, ref = _checked_pair(estimate, reference)
    fig = _figure((16.5, 5.2))
    _draw_top_and_side(fig, 1, 3, est, ref)
    plot_map(points, keyframe_poses, fig.add_subplot(1, 3, 3, projection="3d"))
    if title:
        fig.suptitle(title)
    if path is not None:
        _save(fig, path)
    return fig


def _checked_pair(
    estimate: Union[Trajectory, np.ndarray], reference: Optional[Union[Trajectory, np.ndarray]]
) -> tuple[Trajectory, Optional[Trajectory]]:
    est = _trajectory(estimate, "estimate")
    if not len(est):
        raise ValueError("estimate is empty: nothing to plot")
    return est, None if reference is None else _trajectory(reference, "reference")


def _draw_top_and_side(fig: Figure, rows: int, cols: int, est: Trajectory,
                       ref: Optional[Trajectory]) -> None:
    """Top view in subplot 1, side view in subplot 2 of a ``rows x cols`` grid."""
    a, b = top_view_axes(*([est] + ([ref] if ref is not None else [])))
    side = 3 - a - b
    positions = np.concatenate([t.positions for t in (est, ref) if t is not None])
    extent = np.ptp(positions, axis=0)
    wide = a if extent[a] >= extent[b] else b
    _draw_view(fig.add_subplot(rows, cols, 1), est, ref, a, b, "top view")
    _draw_view(fig.add_subplot(rows, cols, 2), est, ref, wide, side, "side view")


# Percentiles of the map points, per axis, that the map view spans, and its margin around
# them and the keyframes.
_ROBUST_PERCENTILES = (1.0, 99.0)
_VIEW_MARGIN = 1.25


def plot_map(
    points: np.ndarray,
    keyframe_poses: np.ndarray,
    ax: Optional[Any] = None,
    *,
    path: Optional[Union[str, Path]] = None,
    max_points: int = 100_000,
) -> Any:
    """3-D scatter of map points with the keyframe camera centres joined as a trajectory.

    Axes are scaled equally (a cube around the data), so distances look right. The cube
    spans the keyframes and the 1st to 99th percentile of the points on each axis, with a
    quarter more room, so a few stray far points do not shrink the map to a dot; points
    outside it are not drawn (the legend counts them).

    Args:
        points: ``(N, 3)`` map point positions in the world (metres), ``N`` may be 0.
        keyframe_poses: ``(K, 4, 4)`` keyframe poses ``T_w_c`` in time order, ``K`` may be 0.
        ax: a matplotlib 3-D axes (``projection="3d"``) to draw into; ``None`` makes a new
            figure (Agg canvas).
        path: if given, the figure is saved there (folders created).
        max_points: at most this many points are drawn (an even stride over ``points``:
            deterministic), for speed on large maps.

    Returns:
        The 3-D axes drawn into (``ax.figure`` is its figure).

    Raises:
        ValueError: naming ``points`` / ``keyframe_poses`` for wrong shapes or NaN/inf, or
            ``ax`` if it is not a 3-D axes, or ``max_points < 1``.
    """
    xyz = finite_array(points, "points", (None, 3))
    poses = finite_array(keyframe_poses, "keyframe_poses", (None, 4, 4))
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    if ax is None:
        ax = _figure((7.0, 6.0)).add_subplot(1, 1, 1, projection="3d")
    elif getattr(ax, "name", None) != "3d":
        raise ValueError("ax must be a 3-D axes (add_subplot(..., projection='3d'))")
    shown = xyz[:: max(1, -(-len(xyz) // max_points))]  # ceil(N / max_points)
    centres = poses[:, :3, 3]
    bulk = np.percentile(shown, _ROBUST_PERCENTILES, axis=0) if len(shown) else shown
    everything = np.concatenate([bulk, centres])
    if len(everything):
        middle = (everything.max(0) + everything.min(0)) / 2.0
        half = max(_VIEW_MARGIN * np.ptp(everything, axis=0).max() / 2.0, 1e-3)
        inside = np.all(np.abs(shown - middle) <= half, axis=1)
        outside = len(shown) - int(inside.sum())
        shown = shown[inside]
    if len(shown):
        ax.scatter(*shown.T, s=1.0, c="0.25", alpha=0.6, depthshade=False,
                   label=f"map points ({len(xyz)}"
                   + (f", {outside} beyond the view)" if outside else ")"))
    if len(centres):
        ax.plot(*centres.T, "-", color="tab:blue", lw=1.2, label=f"keyframes ({len(centres)})")
        ax.scatter(*centres.T, s=8.0, color="tab:blue", depthshade=False)
        ax.scatter(*centres[0], s=30.0, color="tab:green", depthshade=False, label="first")
    if len(everything):
        ax.set_xlim(middle[0] - half, middle[0] + half)
        ax.set_ylim(middle[1] - half, middle[1] + half)
        ax.set_zlim(middle[2] - half, middle[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    if len(everything):
        ax.legend(loc="upper left")
    if path is not None:
        _save(ax.figure, path)
    return ax


def _trajectory(value: Union[Trajectory, np.ndarray], name: str) -> Trajectory:
    """``value`` as a Trajectory (poses without time get frame indices)."""
    if isinstance(value, Trajectory):
        return value
    return Trajectory.from_poses(finite_array(value, name, (None, 4, 4)))


def _figure(size: tuple[float, float]) -> Figure:
    fig = Figure(figsize=size, dpi=120)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Union[str, Path]) -> Path:
    """Saves ``fig`` to ``path``, creating its folders; an ``OSError`` names the path (a
    parent that is a file otherwise reads "File exists")."""
    path = Path(path)
    try:
        fig.tight_layout()
        with atomic_output(path) as tmp:  # the format from the target's name, not tmp's
            fig.savefig(tmp, format=path.suffix.lstrip(".").lower() or "png")
    except OSError as err:
        raise OSError(err.errno, f"cannot write the plot to {path}: {err.strerror}") from err
    return path


def _draw_view(ax: Any, est: Trajectory, ref: Optional[Trajectory], a: int, b: int,
               title: str) -> None:
    """Estimate (and reference) projected on world axes ``a`` (horizontal), ``b``."""
    if ref is not None and len(ref):
        ax.plot(ref.positions[:, a], ref.positions[:, b], "--", color="0.4", lw=1.2,
                label="reference")
    if len(est):
        ax.plot(est.positions[:, a], est.positions[:, b], "-", color="tab:blue", lw=1.4,
                label="estimate")
        ax.plot(*est.positions[0, [a, b]], "o", color="tab:green", label="start")
    ax.set_xlabel(f"{_AXIS_NAMES[a]} [m]")
    ax.set_ylabel(f"{_AXIS_NAMES[b]} [m]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best")
