"""What a run leaves in its output folder, written the same way by ``ferroslam run``,
``demo`` and ``batch``: trajectories (``trajectory.txt``: the largest map's frames;
``keyframes.txt``; ``maps/map_<id>.txt``: each map's frames), ``map.ply``, a COLMAP model
(``colmap/images/`` and ``colmap/sparse/0/``), with ``dense`` the TSDF mesh (``mesh.ply``) and dense cloud
(``dense.ply``), plots and ``results.json``. The files are written into a fresh folder
beside the output folder and moved into it when the run is over (:class:`ferroslam._files.StagedFolder`): a failed run
never replaces the results of an earlier one.

``maps/`` is written for every run, with one file for a single map (the same poses as
``trajectory.txt``) and none when nothing was tracked: the staged folder replaces a folder
entry whole, so a run into an ``--out`` that holds an earlier multi-map run's ``maps/``
never leaves those files beside a trajectory they do not belong to; and readers find every
map at the same place whatever the run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ._files import StagedFolder, write_text
from .colmap import write_colmap
from .dense import write_dense_outputs
from .export import write_ply, write_trajectory

__all__ = ["publish_run_outputs", "write_run_outputs"]

_MAPS = "maps"  # the folder of the per-map trajectories


def publish_run_outputs(result, out: Path, trajectory_format: str = "tum") -> dict:
    """:func:`write_run_outputs` into a staging folder whose files then replace those of
    ``out``; if writing fails they are left in ``out/partial-<UTC time>/``."""
    with StagedFolder(out) as stage:
        return write_run_outputs(result, stage.path, trajectory_format)


def write_run_outputs(result, out: Path, trajectory_format: str = "tum") -> dict:
    """Write what ``ferroslam run`` leaves in ``out`` (created) and return the summary put in
    results.json; one function so that ``run``, ``demo`` and ``batch`` write the same files."""
    _write_outputs(result, out, result.sequence, trajectory_format)
    summary = result.summary()
    write_text(out / "results.json", json.dumps(summary, indent=2) + "\n")
    return summary


def _write_trajectories(result, out: Path, trajectory_format: str) -> None:
    """``trajectory`` (the largest map's frames: poses of different maps live in different
    frames and scales, so one file never mixes them), ``keyframes`` (the core's current map)
    and ``maps/map_<id>`` per map, all through the one writer in ``trajectory_format``."""
    suffix = ".csv" if trajectory_format == "euroc" else ".txt"
    (out / _MAPS).mkdir(parents=True, exist_ok=True)  # also when empty: see the module doc
    files = [("trajectory", result.largest_map_trajectory), ("keyframes", result.keyframes),
             *((f"{_MAPS}/map_{m.id}", m.trajectory) for m in result.maps)]
    for stem, trajectory in files:
        write_trajectory(out / f"{stem}{suffix}", trajectory.timestamps, trajectory.poses,
                         format=trajectory_format)


def _write_outputs(result, out: Path, name: str, trajectory_format: str) -> None:
    """Trajectories (in ``trajectory_format``), map points with their colours (PLY), the
    keyframes and points as a COLMAP model (``colmap/``), the dense mesh if fused, and plots; the plots show the
    estimate and map aligned to the ground truth when ATE could be computed."""
    # matplotlib (a third of a second) only once a run writes its plots, not for `--help`.
    from .plot import plot_overview, plot_trajectory_top_view

    _write_trajectories(result, out, trajectory_format)
    write_ply(out / "map.ply", result.map_points, result.map_point_colors)
    if result.camera is not None and result.sparse_model is not None:
        write_colmap(out / "colmap", result.camera, result.sparse_model,
                     result.keyframe_images)
    if result.dense is not None:
        write_dense_outputs(out, result.dense)
    if not len(result.trajectory):
        return  # nothing tracked: nothing to draw
    ate = result.ate_frames
    if ate is not None and ate.alignment is not None:
        s = ate.alignment
        align = "Sim(3)" if result.scale_free else "SE(3)"
        est, ref, title = ate.aligned, ate.reference, f"{name} ({align}-aligned to ground truth)"
        points = result.map_points @ s[:3, :3].T + s[:3, 3]
        keyframes = s @ result.keyframes.poses
    else:
        est, ref, title = result.largest_map_trajectory, None, name
        points, keyframes = result.map_points, result.keyframes.poses
    plot_trajectory_top_view(est, ref, out / "trajectory_top.png", title=title)
    plot_overview(est, ref, points, np.asarray(keyframes).reshape(-1, 4, 4), out / "plot.png",
                  title=f"{title}, ATE {ate.rmse * 100:.2f} cm" if ate is not None else title)
