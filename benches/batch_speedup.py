#!/usr/bin/env python3
"""How much faster ``ferroslam batch`` gets through a SPEC than running it serially.

Times the runs of one SPEC called in this process one after another (``execute_run``, the
body of every batch task) and then ``run_batch`` on a local Ray instance of ``--num-cpus``
CPUs, one CPU and one Rayon thread per run in both cases, and prints both wall times and the
speedup. The cluster's time includes starting Ray and a fresh worker process per run, which
is what a user waits for. The default SPEC: TUM fr1/rpy (RGB-D, 150 frames) and EuRoC
V1_01_easy_micro (stereo, all 95 frames) from ``../shared/data``, twice each.

    python benches/batch_speedup.py [--spec SPEC] [--num-cpus N]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

# One Rayon thread in this process too (read when the core first uses its pool), as each
# batch task gets with --cpus-per-run 1: the two timings then run the same threads per run.
os.environ["RAYON_NUM_THREADS"] = "1"

from ferroslam._data import data_dir  # noqa: E402
from ferroslam.batch import execute_run, load_spec, run_batch  # noqa: E402


def default_spec(folder: Path) -> Path:
    """A SPEC of four runs on the shared data, written into ``folder``."""
    data = data_dir()
    spec = {"repeats": 2, "runs": [
        {"sequence": str(data / "tum" / "rgbd_dataset_freiburg1_rpy"), "sensor": "rgbd",
         "max_frames": 150},
        {"sequence": str(data / "euroc" / "V1_01_easy_micro"), "sensor": "stereo"},
    ]}
    path = folder / "spec.json"
    path.write_text(json.dumps(spec, indent=2), encoding="utf-8")
    return path


def time_serial(spec: Path, out: Path) -> tuple[float, list[dict]]:
    """Wall seconds of every run of ``spec`` in this process, and the runs' rows."""
    start = time.perf_counter()
    rows = [execute_run(run, out) for run in load_spec(spec)]
    return time.perf_counter() - start, rows


def time_cluster(spec: Path, out: Path, num_cpus: int) -> tuple[float, list[dict]]:
    """Wall seconds of ``run_batch`` on a local Ray instance, and the runs' rows."""
    start = time.perf_counter()
    outcome = run_batch(spec, out, num_cpus=num_cpus, progress=False)
    return time.perf_counter() - start, outcome.rows


def report(label: str, wall_s: float, rows: list[dict]) -> None:
    """One line: the wall time, and the runs' own time (their ``wall_s`` summed: it grows
    when parallel runs share cores) and failures, which tell Ray's overhead apart."""
    runs_s = sum(row.get("wall_s", 0.0) for row in rows)
    failed = sum(row["status"] != "ok" for row in rows)
    print(f"{label:<26}{wall_s:7.1f} s   (runs' own time {runs_s:5.1f} s, {failed} failed)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=Path, help="SPEC to time (default: four short runs)")
    parser.add_argument("--num-cpus", type=int, default=2,
                        help="CPUs of the local Ray instance (default: 2)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="batch_speedup_") as tmp:
        folder = Path(tmp)
        spec = args.spec or default_spec(folder)
        runs = len(load_spec(spec))
        serial_s, serial_rows = time_serial(spec, folder / "serial")
        cluster_s, cluster_rows = time_cluster(spec, folder / "cluster", args.num_cpus)
    print(f"{runs} runs of {spec.name}, load average {os.getloadavg()[0]:.1f} at the end")
    report("serial (in process)", serial_s, serial_rows)
    report(f"local Ray, {args.num_cpus} CPUs", cluster_s, cluster_rows)
    print(f"{'speedup':<26}{serial_s / cluster_s:7.2f}x (the cluster's time includes Ray's start)")


if __name__ == "__main__":
    main()
