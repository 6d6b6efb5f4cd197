"""``ferroslam batch``: many runs (sequence x option set x repeat) fanned out over a Ray
cluster, one table of them (``results.csv``) and their median and range over repeats
(``summary.md``), as the ORB-SLAM papers report.

A SPEC (JSON, or YAML with PyYAML) lists the runs; :data:`SPEC_EXAMPLE` shows every key.
Top-level ``repeats``, ``max_frames`` and ``options`` are defaults that a run's own keys
override (``options`` key by key); a run's ``grid`` sweeps every combination of the listed
option values. ``sequence`` is a folder (relative paths are relative to the SPEC file's
folder) in any layout ``ferroslam run`` reads, or ``DATASET:NAME`` as ``ferroslam download``
takes them (``tum:freiburg1_xyz``): the driver downloads each such sequence once into
``DIR/datasets`` before the runs start (with a cluster, ``DIR`` must be on a filesystem the
nodes share); a sequence that cannot be fetched fails its runs with the download error.
``options`` go to :func:`ferroslam.pipeline.run_sequence` as they are; the core's defaults
for the sensor and image width fill the rest.

Repeats run the same options. Mapping runs inline by default, which makes tracking
deterministic, so repeats then measure the spread of time and memory only; the option
``"mapping_thread": true`` gives ORB-SLAM's threaded runs, whose ATE varies from run to run
as in the papers' median of five.

Each run is one Ray task in a fresh worker process (``max_calls=1``: its peak memory is its
own) with ``cpus_per_run`` CPUs and as many Rayon threads. A run that fails is a row with its
error and the others go on. Each finished run leaves ``row.json`` in its folder below the
output folder, so the same SPEC into the same folder again runs only what is missing and
rewrites the table.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import itertools
import json
import math
import os
import re
import resource
import statistics
import sys
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, NamedTuple, Optional, Union

from tqdm import tqdm

from ._files import MAX_CONFIG_BYTES, atomic_output, check_nesting, read_bounded_text, write_text
from .download import DATASETS, DownloadError, fetch_dataset
from .options import validate_options
from .pipeline import SENSORS

__all__ = ["BatchOutcome", "RunSpec", "SPEC_EXAMPLE", "execute_run", "expand_spec",
           "fetch_named_sequences", "load_spec", "read_spec", "run_batch", "write_summary", "write_table"]

# ``DATASET:NAME`` as ``ferroslam download DATASET NAME`` takes them.
_DATASET_NAME = re.compile(rf"^({'|'.join(DATASETS)}):(\S+)$")

SPEC_EXAMPLE = """\
{"repeats": 3, "max_frames": null, "options": {"n_features": 1200},
 "runs": [{"sequence": "data/rgbd_dataset_freiburg1_xyz", "sensor": "rgbd"},
          {"sequence": "data/V1_01_easy", "sensor": "stereo-inertial",
           "options": {"depth_threshold": 35},
           "grid": {"n_features": [1000, 1500, 2000]}, "repeats": 5}]}"""

# Runs one SPEC may expand to, checked before expanding ("repeats": 100000000 is a typo).
MAX_RUNS = 10_000
_SPEC_KEYS = ("repeats", "max_frames", "options", "runs")
_RUN_KEYS = ("sequence", "sensor", "repeats", "max_frames", "options", "grid")
_ROW_FILE = "row.json"  # written by the driver once a run is over: the run is done
_OK = "ok"
# Columns before the option columns, and after them (the run's figures).
_RUN_COLUMNS = ("sequence", "sensor", "max_frames", "repeat")
_RESULT_COLUMNS = ("status", "error", "tracked_frames", "frames", "ate_rmse_m", "scale_error",
                   "rpe_trans_rmse_m", "rpe_rot_rmse_deg", "frame_ms_median", "frame_ms_p95",
                   "peak_rss_mb", "wall_s", "run_dir")
# summary.md: (column, heading, format) of the figures given as median [min, max] over repeats.
_SUMMARY_FIGURES = (
    ("tracked_frames", "tracked frames", "{:.0f}"),
    ("ate_rmse_m", "ATE RMSE (m)", "{:.4f}"),
    ("scale_error", "scale error", "{:+.3f}"),
    ("rpe_trans_rmse_m", "RPE (m)", "{:.4f}"),
    ("frame_ms_median", "frame (ms)", "{:.1f}"),
    ("peak_rss_mb", "peak RSS (MB)", "{:.0f}"),
)
# Node addresses of a local Ray instance: Ray replaces 127.0.0.1 with the machine's public
# address unless this variable says "no cluster" (it must be set before Ray is imported).
_RAY_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
_LOOPBACK = "127.0.0.1"


@dataclass(frozen=True)
class RunSpec:
    """One run of a batch: ``sequence`` as the SPEC names it, ``path`` the folder it names,
    ``options`` for ``run_sequence`` (the SPEC's only), ``max_frames`` (``None``: all) and
    ``repeat`` (0-based)."""

    sequence: str
    path: Path
    sensor: str
    options: dict = field(hash=False)
    max_frames: Optional[int]
    repeat: int
    # Why the sequence could not be had (a named dataset that failed to download).
    unavailable: str = ""

    @property
    def option_set(self) -> str:
        """The options as canonical JSON: the key of the runs that repeat each other."""
        return json.dumps(self.options, sort_keys=True)

    @property
    def folder(self) -> str:
        """The run's folder below the output folder, the same for the same SPEC entry in
        every call (which is how a second call finds the runs already done)."""
        key = json.dumps([self.sequence, self.sensor, self.option_set, self.max_frames])
        # The whole digest: distinct runs never share a folder (8 hex digits collided).
        digest = hashlib.sha256(key.encode("utf-8")).hexdigest()
        slug = re.sub(r"[^A-Za-z0-9._-]+", "-", Path(self.sequence).name)[:40] or "run"
        return f"{slug}_{self.sensor}_{digest}/repeat_{self.repeat}"


class BatchOutcome(NamedTuple):
    """The rows of the table in SPEC order, and how many runs this call ran and skipped."""

    rows: list
    ran: int
    skipped: int


def load_spec(path: Union[str, Path]) -> list[RunSpec]:
    """The runs a SPEC file asks for (JSON if it ends in ``.json``, YAML otherwise).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the file and
    the key for a malformed SPEC; a missing sequence folder is the run's failure, not the
    SPEC's."""
    path = Path(path)
    return expand_spec(read_spec(path), path.parent, str(path))


def read_spec(path: Union[str, Path]) -> Any:
    """The parsed SPEC file, not yet expanded (JSON if it ends in ``.json``, YAML
    otherwise); size- and depth-bounded, errors as :func:`load_spec`'s."""
    path = Path(path)
    text = read_bounded_text(path, MAX_CONFIG_BYTES, "SPEC file")
    check_nesting(text, str(path))
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"{path}: invalid JSON: {err}") from None
    return _load_yaml(text, path)


def _load_yaml(text: str, path: Path) -> Any:
    try:
        import yaml
    except ImportError as err:
        raise ImportError(f"{path}: a YAML SPEC needs PyYAML: pip install 'ferroslam[batch]' "
                          "(or write the SPEC as .json)") from err
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ValueError(f"{path}: invalid YAML: {err}") from None
    except RecursionError:  # block-style nesting, which check_nesting does not see
        raise ValueError(f"{path}: nested too deeply") from None


def expand_spec(spec: Any, base_dir: Path, source: str) -> list[RunSpec]:
    """Every run of a parsed SPEC, in SPEC order: each entry of ``runs`` x each combination
    of its ``grid`` x each repeat. ``base_dir`` anchors relative sequence folders; ``source``
    names the SPEC in errors (``ValueError``)."""
    _check_keys(spec, _SPEC_KEYS, "the SPEC", source)
    entries = spec.get("runs")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{source}: 'runs' must be a non-empty list of runs")
    defaults = _check_options(spec.get("options", {}), "options", source)
    repeats = _check_count(spec.get("repeats", 1), "repeats", source)
    max_frames = _check_limit(spec.get("max_frames"), "max_frames", source)
    runs: list[RunSpec] = []
    for i, entry in enumerate(entries):
        runs += _expand_entry(entry, f"runs[{i}]", base_dir, source, defaults, repeats,
                              max_frames, MAX_RUNS - len(runs))
    _check_unique(runs, source)
    return runs


def _expand_entry(entry: Any, where: str, base_dir: Path, source: str, defaults: dict,
                  repeats: int, max_frames: Optional[int], room: int) -> list[RunSpec]:
    """The entry's runs; ``ValueError`` before expanding when there are more than ``room``
    (what :data:`MAX_RUNS` leaves after the earlier entries)."""
    _check_keys(entry, _RUN_KEYS, where, source)
    sequence = entry.get("sequence")
    if not isinstance(sequence, str) or not sequence:
        raise ValueError(f"{source}: {where}.sequence must be a folder path or DATASET:NAME")
    sensor = entry.get("sensor")
    if sensor not in SENSORS:
        raise ValueError(f"{source}: {where}.sensor must be one of {', '.join(SENSORS)}, "
                         f"got {sensor!r}")
    options = {**defaults, **_check_options(entry.get("options", {}), f"{where}.options",
                                            source)}
    repeats = _check_count(entry.get("repeats", repeats), f"{where}.repeats", source)
    max_frames = _check_limit(entry.get("max_frames", max_frames), f"{where}.max_frames",
                              source)
    grid = entry.get("grid", {})
    _check_grid(grid, f"{where}.grid", source)
    count = math.prod(len(values) for values in grid.values()) * repeats
    if count > room:
        raise ValueError(f"{source}: {where} expands to {count} runs (grid points x repeats); "
                         f"a SPEC may have at most {MAX_RUNS} runs in all")
    # A dataset name stands in until fetch_named_sequences puts the download there.
    path = (Path(sequence) if _DATASET_NAME.match(sequence)
            else (base_dir / Path(sequence).expanduser()).resolve())
    points = _grid_points(grid)
    for point in points:
        _validate_run_options({**options, **point}, sensor, where, source)
    return [RunSpec(sequence, path, sensor, {**options, **point}, max_frames, repeat)
            for point in points
            for repeat in range(repeats)]


def _validate_run_options(options: dict, sensor: str, where: str, source: str) -> None:
    """The run's options through the one option schema (as ``run_sequence`` would check
    them), so that a bad value fails the SPEC before any run starts, naming the entry."""
    # The rigs a SPEC can name (EuRoC folders) are tracked as stereo pairs; run_sequence
    # checks again with the rig's own sensor.
    try:
        validate_options(options, sensor.replace("rig", "stereo", 1))
    except (TypeError, ValueError) as err:
        raise type(err)(f"{source}: {where}: {err}") from None


def _check_grid(grid: Any, where: str, source: str) -> None:
    if not isinstance(grid, dict):
        raise ValueError(f"{source}: {where} must map option names to lists of values")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ValueError(f"{source}: {where}.{key} must be a non-empty list of values")


def _grid_points(grid: dict) -> list[dict]:
    """Every combination of the grid's values (one empty point for no grid), first key
    slowest."""
    return [dict(zip(grid, values)) for values in itertools.product(*grid.values())]


def _check_keys(obj: Any, allowed: tuple[str, ...], where: str, source: str) -> None:
    if not isinstance(obj, dict):
        raise ValueError(f"{source}: {where} must be a mapping of {', '.join(allowed)}")
    unknown = sorted(set(obj) - set(allowed))
    if unknown:
        raise ValueError(f"{source}: unknown key {unknown[0]!r} in {where} "
                         f"(expected {', '.join(allowed)})")


def _check_options(options: Any, where: str, source: str) -> dict:
    if not isinstance(options, dict):
        raise ValueError(f"{source}: {where} must map option names to values")
    if "sensor" in options:
        raise ValueError(f"{source}: {where}.sensor: give the sensor as the run's 'sensor'")
    return dict(options)


def _check_count(value: Any, where: str, source: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{source}: {where} must be a positive integer, got {value!r}")
    return value


def _check_limit(value: Any, where: str, source: str) -> Optional[int]:
    """A frame limit: a positive integer, or ``None`` for every frame."""
    return None if value is None else _check_count(value, where, source)


def _check_unique(runs: list[RunSpec], source: str) -> None:
    """Two entries asking for the same run would write one folder at once."""
    seen: set[str] = set()
    for run in runs:
        if run.folder in seen:
            raise ValueError(f"{source}: runs: {run.sequence} ({run.sensor}, options "
                             f"{run.option_set}) is listed twice")
        seen.add(run.folder)


def execute_run(run: RunSpec, out_dir: Path) -> dict:
    """Track one run, write its outputs (as ``ferroslam run`` does) into its folder below
    ``out_dir`` and return its table row; any error becomes the row's ``status`` and
    ``error`` (the body of each Ray task, and of the serial loop of the benchmark)."""
    from .datasets import open_sequence
    from .outputs import publish_run_outputs
    from .pipeline import run_sequence

    start = time.perf_counter()
    try:
        if run.unavailable:
            raise FileNotFoundError(run.unavailable)
        seq = open_sequence(run.path, sensor=run.sensor)
        result = run_sequence(seq, run.options, max_frames=run.max_frames, progress=False,
                              sensor=run.sensor)
        figures = _figures(publish_run_outputs(result, out_dir / run.folder))
        status, error = _OK, ""
    except Exception as err:  # noqa: BLE001 - a failed run is a row, the batch goes on
        figures, status, error = {}, "failed", f"{type(err).__name__}: {err}"
    return {**_run_row(run), **figures, "status": status, "error": error,
            "peak_rss_mb": _peak_rss_mb(), "wall_s": time.perf_counter() - start}


def _run_row(run: RunSpec) -> dict:
    return {"sequence": run.sequence, "sensor": run.sensor, "max_frames": run.max_frames,
            "repeat": run.repeat, "options": run.options, "run_dir": run.folder}


def _figures(summary: dict) -> dict:
    """The table's figures from a run's results.json summary (absent metrics: ``None``)."""
    metrics = summary["metrics"]
    frame_ms = summary["timing_ms"].get("frame_ms") or {}
    return {
        "tracked_frames": summary["tracked_frames"],
        "frames": summary["frames"],
        "ate_rmse_m": metrics.get("ate_frames", {}).get("rmse"),
        "scale_error": metrics.get("scale_error"),
        "rpe_trans_rmse_m": metrics.get("rpe_frames", {}).get("trans_rmse_m"),
        "rpe_rot_rmse_deg": metrics.get("rpe_frames", {}).get("rot_rmse_deg"),
        "frame_ms_median": frame_ms.get("median"),
        "frame_ms_p95": frame_ms.get("p95"),
    }


def _peak_rss_mb() -> float:
    """Peak resident memory of this process (``ru_maxrss``: KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024 * 1024) if sys.platform == "darwin" else peak / 1024


def run_batch(spec_path: Union[str, Path], out_dir: Union[str, Path], *,
              address: Optional[str] = None, cpus_per_run: int = 1,
              num_cpus: Optional[int] = None, retry_failed: bool = False,
              progress: bool = True) -> BatchOutcome:
    """Run every run of the SPEC not yet done in ``out_dir`` on Ray and write
    ``results.csv`` and ``summary.md`` there.

    ``address``: an existing cluster (``"auto"``, ``"HOST:PORT"``, ``"ray://HOST:PORT"``
    with Ray's client), whose nodes must have ferroslam, see the sequence folders at the
    same paths and write ``out_dir`` at the same path; ``None`` starts a local Ray instance on
    127.0.0.1 with ``num_cpus`` CPUs (default: all) and stops it at the end.
    ``retry_failed`` runs failed runs again instead of keeping their rows.
    """
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = fetch_named_sequences(load_spec(spec_path), out_dir / "datasets", progress)
    rows = {run.folder: row for run in runs
            if (row := _done_row(out_dir / run.folder, retry_failed)) is not None}
    todo = [run for run in runs if run.folder not in rows]
    if todo:
        with _ray_session(address, num_cpus) as ray:
            rows.update(_fan_out(ray, todo, out_dir, cpus_per_run, progress))
    table = [rows[run.folder] for run in runs]
    write_table(table, out_dir / "results.csv")
    write_summary(table, out_dir / "summary.md")
    return BatchOutcome(table, len(todo), len(runs) - len(todo))


def fetch_named_sequences(runs: list[RunSpec], dest: Path, progress: bool = True,
                          fetch=fetch_dataset) -> list[RunSpec]:
    """``runs`` with each ``DATASET:NAME`` sequence downloaded once into ``dest`` (``fetch``
    as ``ferroslam.download.fetch_dataset``; an archive already there is not fetched again)
    and their ``path`` set to it; a sequence that cannot be fetched marks its runs
    ``unavailable`` with the error, so they fail as rows and the others go on."""
    fetched: dict[str, tuple[Path, str]] = {}
    for name in {run.sequence for run in runs if _DATASET_NAME.match(run.sequence)}:
        dataset, sequence = _DATASET_NAME.match(name).groups()
        try:
            fetched[name] = (Path(fetch(dataset, sequence, dest, progress=progress)), "")
        except (OSError, ValueError, DownloadError) as err:
            fetched[name] = (Path(name), f"{name}: {err}")
    return [dataclasses.replace(run, path=fetched[run.sequence][0],
                                unavailable=fetched[run.sequence][1])
            if run.sequence in fetched else run for run in runs]


def _done_row(folder: Path, retry_failed: bool) -> Optional[dict]:
    """The row a previous call left in ``folder``, ``None`` if the run is still to do."""
    path = folder / _ROW_FILE
    if not os.path.lexists(path):
        return None
    text = read_bounded_text(path, MAX_CONFIG_BYTES, "run row")
    check_nesting(text, str(path))
    try:
        row = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: invalid JSON: {err} (delete the file to run it again)"
                         ) from None
    missing = [key for key in (*_RUN_COLUMNS, "options", "status", "run_dir")
               if not isinstance(row, dict) or key not in row]
    if missing or not isinstance(row["options"], dict):
        raise ValueError(f"{path}: not a run row of ferroslam batch (no {missing[0]!r})"
                         if missing else f"{path}: 'options' must be a JSON object"
                         " (delete the file to run it again)")
    return None if retry_failed and row["status"] != _OK else row


@contextmanager
def _ray_session(address: Optional[str], num_cpus: Optional[int]) -> Iterator[Any]:
    """Ray, connected to the cluster at ``address`` or to a new local instance bound to
    127.0.0.1 (stopped on exit); disconnects on exit either way."""
    if address is None or _on_loopback(address):
        os.environ.setdefault(_RAY_LOOPBACK_ENV, "0")
    try:
        import ray
    except ImportError as err:
        raise ImportError("ferroslam batch needs Ray: pip install 'ferroslam[batch]'") from err
    if address is None:
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=False,
                 _node_ip_address=_LOOPBACK, log_to_driver=False)
        if ray.util.get_node_ip_address() != _LOOPBACK:
            warnings.warn(f"the local Ray instance listens on {ray.util.get_node_ip_address()}, "
                          f"not {_LOOPBACK}: Ray was imported before ferroslam.batch could set "
                          f"{_RAY_LOOPBACK_ENV}=0 (set it in the environment)", stacklevel=3)
    else:
        ray.init(address=address, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def _on_loopback(address: str) -> bool:
    """Whether a cluster address (``host:port``, ``ray://host:port``) is on this machine's
    loopback, which Ray would otherwise rewrite to the machine's public address."""
    host = address.split("://")[-1].rsplit(":", 1)[0]
    return host in (_LOOPBACK, "localhost")


def _fan_out(ray: Any, todo: list[RunSpec], out_dir: Path, cpus_per_run: int,
             progress: bool) -> dict:
    """One task per run; each row is saved in its run's folder as soon as the run ends, so
    an interrupted batch keeps what it finished."""
    task = ray.remote(max_calls=1, max_retries=0)(execute_run).options(
        num_cpus=cpus_per_run,
        runtime_env={"env_vars": {"RAYON_NUM_THREADS": str(cpus_per_run)}},
    )
    pending = {task.remote(run, out_dir): run for run in todo}
    rows = {}
    with tqdm(total=len(todo), disable=not progress, desc="ferroslam batch", unit="run") as bar:
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            run = pending.pop(ref)
            rows[run.folder] = _task_row(ray, ref, run)
            _save_row(rows[run.folder], out_dir / run.folder)
            bar.update()
    return rows


def _task_row(ray: Any, ref: Any, run: RunSpec) -> dict:
    """The task's row, or a ``crashed`` row when its worker died (segfault, out of memory)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayError as err:
        return {**_run_row(run), "status": "crashed", "error": f"{type(err).__name__}: {err}"}


def _save_row(row: dict, folder: Path) -> None:
    write_text(folder / _ROW_FILE, json.dumps(row, indent=2) + "\n")


def write_table(rows: list[dict], path: Path) -> None:
    """``results.csv``: one row per run, one column per option key any run sets (empty: the
    core's default), missing figures empty."""
    option_keys = sorted({key for row in rows for key in row["options"]})
    with atomic_output(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow((*_RUN_COLUMNS, *option_keys, *_RESULT_COLUMNS))
        for row in rows:
            values = ([row.get(c) for c in _RUN_COLUMNS]
                      + [row["options"].get(k) for k in option_keys]
                      + [row.get(c) for c in _RESULT_COLUMNS])
            writer.writerow([_cell(v) for v in values])


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return str(value)


def write_summary(rows: list[dict], path: Path) -> None:
    """``summary.md``: per sequence, sensor, option set and frame limit, the median and the
    range over the repeats that finished, then the failed runs."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        key = (row["sequence"], row["sensor"], json.dumps(row["options"], sort_keys=True),
               row["max_frames"])
        groups.setdefault(key, []).append(row)
    lines = ["# ferroslam batch", "",
             "Median [min, max] over the repeats that finished (`status` ok).", "",
             "| sequence | sensor | options | max frames | ok | "
             + " | ".join(heading for _, heading, _ in _SUMMARY_FIGURES) + " |",
             "|---" * (5 + len(_SUMMARY_FIGURES)) + "|"]
    for (sequence, sensor, _, max_frames), group in groups.items():
        ok = [row for row in group if row["status"] == _OK]
        cells = [sequence, sensor, _options_text(group[0]["options"]),
                 "all" if max_frames is None else str(max_frames), f"{len(ok)}/{len(group)}"]
        cells += [_median_range([row.get(col) for row in ok], fmt)
                  for col, _, fmt in _SUMMARY_FIGURES]
        lines.append("| " + " | ".join(cells) + " |")
    failed = [row for row in rows if row["status"] != _OK]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- `{row['run_dir']}` ({row['status']}): {row['error']}" for row in failed]
    write_text(path, "\n".join(lines) + "\n")


def _options_text(options: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(options.items())) or "defaults"


def _median_range(values: list, fmt: str) -> str:
    """``median [min, max]`` of the values present; the median alone for one value."""
    present = [v for v in values if v is not None]
    if not present:
        return "-"
    median = fmt.format(statistics.median(present))
    if len(present) == 1:
        return median
    return f"{median} [{fmt.format(min(present))}, {fmt.format(max(present))}]"
