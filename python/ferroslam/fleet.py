"""``ferroslam merge`` and ``ferroslam fleet``: maps of several sessions (robots, or one robot
at different times) merged into one frame where they overlap.

:func:`merge_maps` merges saved map files (``ferroslam._core.merge_map_files``) and
:func:`merge_chain` follows a map through the merges of such a call to the map it ended in,
with the similarity that takes its frame there; :func:`run_fleet` maps each sequence of a
SPEC (the format of ``ferroslam batch``) as one Ray task, then merges the maps pairwise as a
tree of Ray tasks, within groups of runs of the same sensor and camera (maps of different
cameras cannot merge).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import time
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np

from ._files import write_text
from .trajectory import Trajectory

__all__ = ["FLEET_SPEC_EXAMPLE", "apply_similarity", "merge_chain", "merge_lines", "merge_maps", "read_fleet_spec",
           "run_fleet", "FleetRun"]

PathLike = Union[str, "os.PathLike[str]"]

FLEET_SPEC_EXAMPLE = """\
{"max_frames": 80,
 "runs": [{"sequence": "data/rgbd_dataset_freiburg1_rpy", "sensor": "rgbd"},
          {"sequence": "data/rgbd_dataset_freiburg1_rpy", "sensor": "rgbd", "first_frame": 60},
          {"sequence": "data/kitti_01", "sensor": "stereo", "max_frames": 30,
           "options": {"n_features": 2000}}]}"""


# -- merging map files ----------------------------------------------------------------------

def merge_maps(inputs: Sequence[PathLike], output: PathLike, vocabulary: Any = "default") -> dict:
    """``ferroslam._core.merge_map_files`` with the vocabulary ``vocabulary`` names
    (:func:`ferroslam.session.load_vocabulary`); a missing input raises
    ``FileNotFoundError`` naming it before the core reads anything."""
    from ._core import merge_map_files
    from .session import load_vocabulary

    if not inputs:
        raise ValueError("no map files to merge")
    for path in inputs:
        if not Path(path).is_file():
            raise FileNotFoundError(f"{path}: no such map file")
    return merge_map_files([str(p) for p in inputs], str(output), load_vocabulary(vocabulary))


def merge_chain(merges: Sequence[dict], map_id: int) -> tuple[int, np.ndarray]:
    """The map ``map_id`` ended in after ``merges`` (in their order, as ``merge_map_files``
    returns them) and the similarity ``S`` (4x4 ``[sR | t]``) from ``map_id``'s frame to that
    map's: each merge of the current map (``merged_map``) into ``into_map`` composes its
    ``similarity`` from the left."""
    current, S = int(map_id), np.eye(4)
    for merge in merges:
        if int(merge["merged_map"]) == current:
            S = np.asarray(merge["similarity"], dtype=np.float64) @ S
            current = int(merge["into_map"])
    return current, S


def apply_similarity(S: np.ndarray, traj: Trajectory) -> Trajectory:
    """``traj`` (poses ``T_w_c``) in the frame ``S = [sR | t]`` maps its world to: positions
    ``s R p + t``, rotations ``R R_w_c``."""
    S = np.asarray(S, dtype=np.float64)
    scale = float(np.cbrt(np.linalg.det(S[:3, :3])))
    return traj.transformed(S[:3, :3] / scale, S[:3, 3], scale)


def merge_lines(result: dict, names: Sequence[str]) -> list[str]:
    """One line per merge (which map went into which) and per map kept apart, naming the
    input file (``names[i]``) of each map id."""
    origin = {int(map_id): names[i] for i, ids in enumerate(result["inputs"]) for map_id in ids}
    lines = []
    for m in result["merges"]:
        lines.append(f"merged map {m['merged_map']} ({origin.get(int(m['merged_map']), '?')}) "
                     f"into map {m['into_map']} ({origin.get(int(m['into_map']), '?')}): "
                     f"{m['num_matches']} matches, scale {float(m['scale']):.4f}")
    touched = {int(m["merged_map"]) for m in result["merges"]} | {
        int(m["into_map"]) for m in result["merges"]}
    for m in result["maps"]:
        if int(m["id"]) not in touched:
            lines.append(f"kept apart map {m['id']} ({origin.get(int(m['id']), '?')}): it "
                         f"overlaps no other map ({m['keyframes']} keyframes)")
    return lines


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# -- the fleet SPEC -------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class FleetRun:
    """One session of a fleet: the batch run (``spec``) and where it starts."""

    spec: Any  # ferroslam.batch.RunSpec
    first_frame: int
    folder: str


def read_fleet_spec(path: PathLike) -> list[FleetRun]:
    """The sessions of a fleet SPEC: ``ferroslam batch``'s format, each run one session,
    with ``first_frame`` (top level or per run, default 0) besides ``max_frames``; repeats
    above 1 and grids are refused (``ValueError`` naming the file and key)."""
    from .batch import expand_spec, read_spec

    path = Path(path)
    source = str(path)
    spec = read_spec(path)
    if not isinstance(spec, dict):
        raise ValueError(f"{source}: the SPEC must be a mapping of repeats, max_frames, "
                         "options, runs, first_frame")
    spec = dict(spec)
    default_first = _first_frame(spec.pop("first_frame", 0), "first_frame", source)
    _refuse_repeats(spec, "the SPEC", source)
    entries = spec.get("runs")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{source}: 'runs' must be a non-empty list of runs")
    runs = []
    for i, entry in enumerate(entries):
        where = f"runs[{i}]"
        if not isinstance(entry, dict):
            raise ValueError(f"{source}: {where} must be a mapping")
        entry = dict(entry)
        first = _first_frame(entry.pop("first_frame", default_first), f"{where}.first_frame",
                             source)
        _refuse_repeats(entry, where, source)
        if "grid" in entry:
            raise ValueError(f"{source}: {where}.grid: a fleet maps each session once; list "
                             "each option set as its own run")
        try:
            (run,) = expand_spec({**spec, "runs": [entry]}, path.parent, source)
        except ValueError as err:  # name the entry, not runs[0] of the one-entry SPEC
            raise ValueError(str(err).replace("runs[0]", where)) from None
        slug = re.sub(r"[^A-Za-z0-9._-]+", "-", Path(run.sequence).name)[:40] or "run"
        runs.append(FleetRun(run, first, f"{i:02d}_{slug}_{run.sensor}_from{first}"))
    return runs


def _refuse_repeats(obj: dict, where: str, source: str) -> None:
    repeats = obj.get("repeats", 1)
    if repeats != 1:
        raise ValueError(f"{source}: {where}.repeats is {repeats!r}: a fleet maps each session "
                         "once (repeats are for ferroslam batch)")


def _first_frame(value: Any, where: str, source: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{source}: {where} must be a non-negative integer, got {value!r}")
    return value


# -- the Ray tasks --------------------------------------------------------------------------

def camera_key(seq: Any, sensor: str) -> list:
    """What two runs must share for their maps to merge: the sensor, the tracked camera's
    model, size, intrinsics and distortion, and the stereo baseline."""
    cam = seq.camera
    baseline = getattr(seq, "baseline_m", None)
    return [sensor, cam.model, int(cam.width), int(cam.height),
            *[round(float(v), 6) for v in (cam.fx, cam.fy, cam.cx, cam.cy)],
            [round(float(v), 6) for v in np.ravel(cam.dist)],
            None if baseline is None else round(float(baseline), 6)]


def map_session(run: FleetRun, out_dir: Path) -> dict:
    """Track one session into ``out_dir/run.folder``: ``map.map`` (the atlas) and
    ``trajectory.txt`` (the largest map, TUM); the body of each mapping task."""
    from .datasets import open_sequence
    from .export import write_trajectory
    from .pipeline import run_sequence

    start = time.perf_counter()
    folder = out_dir / run.folder
    row: dict[str, Any] = {"run_dir": run.folder, "sequence": run.spec.sequence,
                           "sensor": run.spec.sensor, "first_frame": run.first_frame,
                           "max_frames": run.spec.max_frames}
    try:
        if run.spec.unavailable:
            raise FileNotFoundError(run.spec.unavailable)
        seq = open_sequence(run.spec.path, sensor=run.spec.sensor)
        key = camera_key(seq, run.spec.sensor)
        folder.mkdir(parents=True, exist_ok=True)
        result = run_sequence(seq, run.spec.options, max_frames=run.spec.max_frames,
                              progress=False, sensor=run.spec.sensor,
                              first_frame=run.first_frame, save_map=folder / "map.map")
        largest = result.largest_map
        traj = result.largest_map_trajectory
        write_trajectory(folder / "trajectory.txt", traj.timestamps, traj.poses, "tum")
        ids = [int(m["id"]) for m in result.atlas]
        row.update(status="ok", error="", camera=key, frames=result.frames,
                   poses=len(result.trajectory), largest_map_poses=len(traj),
                   maps=len(ids), largest_record=None if largest is None
                   else ids.index(int(largest.id)),
                   trajectory=traj, groundtruth=result.groundtruth)
    except Exception as err:  # noqa: BLE001 - a failed session is a row, the fleet goes on
        row.update(status="failed", error=f"{type(err).__name__}: {err}")
    row["wall_s"] = time.perf_counter() - start
    return row


def merge_task(inputs: list[str], output: str) -> dict:
    """The body of each merging task: :func:`merge_maps` of ``inputs`` into ``output``."""
    start = time.perf_counter()
    result = merge_maps(inputs, output)
    result["wall_s"] = time.perf_counter() - start
    return result


# -- the fleet ------------------------------------------------------------------------------

def run_fleet(spec_path: PathLike, out_dir: PathLike, *, address: Optional[str] = None,
              num_cpus: Optional[int] = None, progress: bool = True) -> dict:
    """Map every session of the SPEC on Ray, merge the maps of each camera group as a tree
    of pairwise merges, write each session's trajectory in its merged frame and
    ``summary.json``; return the summary.

    Outputs in ``out_dir``: ``<run>/map.map``, ``<run>/trajectory.txt`` (largest map, its own
    frame), ``<run>/trajectory_merged.txt`` (the same poses in the frame of the merged map
    they ended in), ``merged.map`` (the largest group's maps: most runs, ties the first),
    ``merged_<k>.map`` for every other group ``k`` (0-based, in SPEC order of their first
    run), ``merges/`` (the intermediate levels) and ``summary.json``."""
    from .batch import _ray_session, fetch_named_sequences

    start = time.perf_counter()
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = read_fleet_spec(spec_path)
    fetched = fetch_named_sequences([r.spec for r in runs], out_dir / "datasets", progress)
    runs = [dataclasses.replace(r, spec=s) for r, s in zip(runs, fetched)]
    with _ray_session(address, num_cpus) as ray:
        ray_ready = time.perf_counter()
        env = {"env_vars": {"RAYON_NUM_THREADS": "1"}}
        # Workers are reused (no max_calls=1 as in batch): a merge then starts in a process
        # that has ferroslam loaded already; the tasks are seconds long at test scale.
        mapper = ray.remote(max_retries=0)(map_session).options(
            num_cpus=1, runtime_env=env)
        rows = ray.get([mapper.remote(run, out_dir) for run in runs])
        mapped = time.perf_counter()
        merger = ray.remote(max_retries=0)(merge_task).options(
            num_cpus=1, runtime_env=env)
        groups, merge_log, states = _merge_tree(ray, merger, rows, out_dir)
        done = time.perf_counter()
    summary = _finish(rows, groups, merge_log, states, out_dir)
    serial = sum(r["wall_s"] for r in rows) + sum(m["wall_s"] for m in merge_log)
    tasks_wall = done - ray_ready
    summary["times"] = {"wall_s": time.perf_counter() - start, "ray_start_s": ray_ready - start,
                        "tasks_wall_s": tasks_wall, "mapping_wall_s": mapped - ray_ready,
                        "merging_wall_s": done - mapped, "serial_s": serial,
                        "speedup": serial / tasks_wall if tasks_wall > 0 else None}
    write_text(out_dir / "summary.json", json.dumps(_jsonable(summary), indent=2) + "\n")
    return summary


def _merge_tree(ray: Any, merger: Any, rows: list[dict], out_dir: Path):
    """Group the mapped runs by camera, merge each group pairwise level by level (every
    level's merges of every group as parallel tasks) and follow each run's largest map
    through them: ``states[i] = (group, record index in the group's file, S)``."""
    groups: list[dict] = []
    for i, row in enumerate(rows):
        if row["status"] != "ok" or row["largest_record"] is None:
            continue
        group = next((g for g in groups if g["camera"] == row["camera"]), None)
        if group is None:
            group = {"index": len(groups), "camera": row["camera"], "runs": []}
            groups.append(group)
        group["runs"].append(i)
    # A node: a map file and the runs whose largest map it holds, as {run: (record, S)}.
    nodes = {g["index"]: [{"file": out_dir / rows[i]["run_dir"] / "map.map",
                           "runs": {i: (rows[i]["largest_record"], np.eye(4))}}
                          for i in g["runs"]] for g in groups}
    (out_dir / "merges").mkdir(exist_ok=True)
    merge_log: list[dict] = []
    level = 0
    while any(len(n) > 1 for n in nodes.values()) or level == 0:
        jobs = []  # (group, pair of nodes, output file, task)
        kept_by_group: dict[int, list] = {}
        for g, group_nodes in nodes.items():
            if len(group_nodes) == 1 and level > 0:
                continue
            pairs = [group_nodes[j:j + 2] for j in range(0, len(group_nodes), 2)]
            kept = []
            for j, pair in enumerate(pairs):
                if len(pair) == 1 and len(group_nodes) > 1:  # the odd one waits a level
                    kept.append(pair[0])
                    continue
                output = out_dir / "merges" / f"level{level}_group{g}_{j}.map"
                ref = merger.remote([str(n["file"]) for n in pair], str(output))
                jobs.append((g, pair, output, ref))
            kept_by_group[g] = kept
            nodes[g] = []
        for (g, pair, output, _), result in zip(jobs, ray.get([job[3] for job in jobs])):
            ids = {m["id"]: k for k, m in enumerate(result["maps"])}
            runs = {}
            for n, node in enumerate(pair):
                for i, (record, S) in node["runs"].items():
                    final, S_level = merge_chain(result["merges"], result["inputs"][n][record])
                    runs[i] = (ids[final], S_level @ S)
            merge_log.append({"level": level, "group": g,
                              "inputs": [str(n["file"].relative_to(out_dir)) for n in pair],
                              "output": str(output.relative_to(out_dir)),
                              "merges": result["merges"], "maps": result["maps"],
                              "wall_s": result["wall_s"]})
            nodes[g].append({"file": output, "runs": runs, "maps": result["maps"]})
        for g, kept in kept_by_group.items():
            nodes[g] += kept
        level += 1
    largest = max(groups, key=lambda g: len(g["runs"]), default=None)
    try:  # empty when every group was one merge
        (out_dir / "merges").rmdir()
    except OSError:
        pass
    states: dict[int, tuple] = {}
    for g in groups:
        (node,) = nodes[g["index"]]
        name = "merged.map" if g is largest else f"merged_{g['index']}.map"
        os.replace(node["file"], out_dir / name)
        g.update(file=name, maps=node["maps"])
        for i, (record, S) in node["runs"].items():
            states[i] = (g, record, S)
    return groups, merge_log, states


def _finish(rows: list[dict], groups: list[dict], merge_log: list[dict], states: dict,
            out_dir: Path) -> dict:
    """Write each run's merged trajectory, compute its ATE, and make the summary."""
    from .export import write_trajectory
    from .metrics import ate

    merged: dict[int, Trajectory] = {}
    table = []
    for i, row in enumerate(rows):
        out = {k: v for k, v in row.items() if k not in ("trajectory", "groundtruth")}
        if i in states:
            g, record, S = states[i]
            traj = apply_similarity(S, row["trajectory"])
            merged[i] = traj
            write_trajectory(out_dir / row["run_dir"] / "trajectory_merged.txt",
                             traj.timestamps, traj.poses, "tum")
            out.update(group=g["index"], merged_file=g["file"],
                       merged_map=int(g["maps"][record]["id"]), similarity=S)
            out["ate"] = _ate(row, traj, ate)
        table.append(out)
    # Runs of one sequence that ended in one map: the first one's alignment to the ground
    # truth applied to the others says whether the merge put them in the same frame.
    for i, out in enumerate(table):
        first = next((j for j, o in enumerate(table) if j in merged and i in merged
                      and o["sequence"] == out["sequence"]
                      and o.get("merged_file") == out.get("merged_file")
                      and o.get("merged_map") == out.get("merged_map")), None)
        if first is None or first == i or table[first].get("ate") is None:
            continue
        S = np.asarray(table[first]["ate"]["alignment"])
        try:
            result = ate(rows[i]["groundtruth"], apply_similarity(S, merged[i]), align="none")
        except (TypeError, ValueError):
            continue
        out["ate_first_session_alignment"] = {"rmse": result.rmse, "pairs": result.pairs,
                                              "aligned_with": table[first]["run_dir"]}
    apart = [{"group": g["index"], "file": g["file"], "sensor": g["camera"][0],
              "camera": g["camera"], "runs": [rows[i]["run_dir"] for i in g["runs"]],
              "maps": g["maps"]} for g in groups]
    return {"runs": table, "groups": apart, "merge_tasks": merge_log}


def _ate(row: dict, traj: Trajectory, ate) -> Optional[dict]:
    gt = row.get("groundtruth")
    if gt is None or len(traj) < 3:
        return None
    align = "sim3" if row["sensor"] == "mono" else "se3"
    try:
        result = ate(gt, traj, align=align)
    except ValueError:
        return None
    return {"rmse": result.rmse, "align": align, "pairs": result.pairs,
            "alignment": result.alignment}


def summary_lines(summary: dict) -> list[str]:
    """The printed summary of :func:`run_fleet`."""
    lines = []
    for run in summary["runs"]:
        if run["status"] != "ok":
            lines.append(f"{run['run_dir']}: {run['status']}: {run['error']}")
            continue
        text = (f"{run['run_dir']}: {run['frames']} frames, {run['poses']} poses "
                f"({run['largest_map_poses']} in the largest map)")
        if "merged_file" in run:
            text += f", in map {run['merged_map']} of {run['merged_file']}"
        if run.get("ate"):
            text += f", ATE {run['ate']['rmse']:.4f} m ({run['ate']['align']})"
        shared = run.get("ate_first_session_alignment")
        if shared:
            text += (f", {shared['rmse']:.4f} m with {shared['aligned_with']}'s alignment")
        lines.append(text)
    for task in summary["merge_tasks"]:
        for m in task["merges"]:
            lines.append(f"level {task['level']} group {task['group']}: merged map "
                         f"{m['merged_map']} into map {m['into_map']} "
                         f"({m['num_matches']} matches) -> {task['output']}")
    for g in summary["groups"]:
        lines.append(f"group {g['group']} ({g['sensor']}, {g['camera'][2]}x{g['camera'][3]} "
                     f"fx {g['camera'][4]:g}): {len(g['runs'])} run(s) -> {g['file']}, "
                     f"{len(g['maps'])} map(s)")
    if len(summary["groups"]) > 1:
        lines.append(f"{len(summary['groups'])} groups kept apart (different sensor or camera: "
                     "their maps cannot merge)")
    t = summary["times"]
    speedup = "-" if t["speedup"] is None else f"{t['speedup']:.2f}x"
    lines.append(f"time: fleet {t['tasks_wall_s']:.1f} s (mapping {t['mapping_wall_s']:.1f} s, "
                 f"merging {t['merging_wall_s']:.1f} s; {t['wall_s']:.1f} s with Ray's start), "
                 f"serial {t['serial_s']:.1f} s, speedup {speedup}")
    return lines
