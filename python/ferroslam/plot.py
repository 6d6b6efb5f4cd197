"""Trajectory plots (matplotlib, Agg backend: works headless)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Union

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .trajectory import Trajectory

__all__ = ["plot_trajectory_top_view", "top_view_axes"]

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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    shown = [est] + ([ref] if ref is not None else [])
    a, b = top_view_axes(*shown)
    fig = Figure(figsize=(6.4, 5.4), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
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
    fig.tight_layout()
    fig.savefig(path)
    return path
