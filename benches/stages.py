"""Per-stage timing of the whole pipeline on a sequence, against its frame-rate budget.

Runs ``ferroslam.pipeline.run_sequence`` (progress bar off) and prints median / p95 / mean
milliseconds of each stage, the tracking outcome, ATE, scale error and frame time / budget
(the median interval between the sequence's timestamps: 33.3 ms for TUM, ~100 ms for KITTI).

    python benches/stages.py [--sequence DIR] [--sensor rgbd|stereo|mono] [--max-frames N]
                             [--config JSON] [--json OUT]

``--config`` is an inline JSON object (``'{"seed": 3}'``) or a JSON file, as ``ferroslam run
--config``. The sequence (any layout ``ferroslam run`` reads) defaults to
``$FERROSLAM_DATA/tum/rgbd_dataset_freiburg1_rpy`` (``<repo>/../shared/data`` without the
variable). Build the native module in release mode
first (``maturin develop --release``). ``local mapping`` is timed on every tracked frame (it
includes the keyframe decision); ``new KFs`` keeps the frames local mapping inserted.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from ferroslam._data import data_dir
from ferroslam.cli import _load_config  # the same JSON rules as `ferroslam run --config`
from ferroslam.datasets import open_sequence
from ferroslam._core import SlamSystem
from ferroslam.pipeline import run_sequence

# (label, RunResult.timings key, frames included: all or keyframes only)
STAGES = (
    ("image load", "load_ms", "all"),
    ("ORB extraction (+ depth)", "extraction_ms", "all"),
    ("tracking (core)", "tracking_ms", "all"),
    ("  matching and search", "matching_ms", "all"),
    ("  pose optimisation", "pose_optimisation_ms", "all"),
    ("local mapping (core)", "mapping_ms", "all"),
    ("local mapping, new KFs", "mapping_ms", "keyframes"),
    ("  local BA, new KFs", "local_ba_ms", "keyframes"),
    ("  loop closing, new KFs", "loop_closing_ms", "keyframes"),
    ("track_* call", "track_call_ms", "all"),
    ("whole frame (no load)", "frame_ms", "all"),
)


def _config(text: str | None) -> dict:
    if text is None:
        return {}
    if text.lstrip().startswith("{"):
        config = json.loads(text)
        if not isinstance(config, dict):
            raise ValueError("--config must be a JSON object")
        return config
    return _load_config(Path(text))


def _stats(values: np.ndarray) -> dict | None:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return None
    return {"n": int(v.size), "median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
            "mean": float(np.mean(v)), "max": float(np.max(v))}


class KeyframeRecorder:
    """``SlamSystem`` that remembers which frames local mapping inserted as keyframes
    (``RunResult`` does not); an initialisation keyframe is built by tracking and not counted."""

    def __init__(self, *args, **kwargs):
        self.system = SlamSystem(*args, **kwargs)
        self.is_keyframe: list[bool] = []

    def _track(self, method: str, *args, **options):
        initialising = self.system.state == "not_initialized"
        result = getattr(self.system, method)(*args, **options)
        self.is_keyframe.append(result.is_keyframe and not initialising)
        return result

    def track_rgbd(self, *args, **options):
        return self._track("track_rgbd", *args, **options)

    def track_stereo(self, *args, **options):
        return self._track("track_stereo", *args, **options)

    def track_mono(self, *args, **options):
        return self._track("track_mono", *args, **options)

    def __getattr__(self, name):
        return getattr(self.system, name)


def stage_table(result, is_keyframe: np.ndarray) -> list[dict]:
    """One row per stage: label, timings key, frames counted and statistics (ms)."""
    rows = []
    for label, key, subset in STAGES:
        values = np.asarray(result.timings[key], np.float64)
        if subset == "keyframes":
            values = values[is_keyframe]
        rows.append({"stage": label, "key": key, "subset": subset, **(_stats(values) or {})})
    return rows


def _ate(result, name: str) -> dict | None:
    ate = getattr(result, name)
    if ate is None:
        return None
    return {"rmse_m": ate.rmse, "mean_m": ate.mean, "max_m": ate.max, "pairs": ate.pairs}


def report(result, is_keyframe: np.ndarray, wall_s: float, budget_ms: float) -> dict:
    rows = stage_table(result, is_keyframe)
    frame = next(r for r in rows if r["key"] == "frame_ms")
    return {
        "sequence": result.sequence,
        "config": result.config,
        "frames": result.frames,
        "tracked_frames": result.tracked_frames,
        "states": {s: result.states.count(s) for s in sorted(set(result.states))},
        "keyframes_mapped": int(is_keyframe.sum()),
        "keyframes": len(result.keyframes),
        "map_points": int(result.map_points.shape[0]),
        "ate_frames": _ate(result, "ate_frames"),
        "ate_keyframes": _ate(result, "ate_keyframes"),
        # The metric scale from the Sim(3) alignment (None for monocular runs); the path length
        # ratio measures per-frame jitter too, so it is reported apart.
        "scale_error": result.scale_error,
        "path_length_ratio": (None if result.path_length is None
                              else 1.0 + result.path_length.scale_error),
        "metric_errors": list(result.metric_errors),
        "stages_ms": rows,
        "sensor": result.sensor,
        "budget_ms": budget_ms,
        "realtime_ratio": {k: frame[k] / budget_ms for k in ("median", "p95", "mean")},
        "wall_s": wall_s,
        "machine": {"python": platform.python_version(), "processor": platform.machine()},
    }


def print_report(rep: dict) -> None:
    print(f"sequence {rep['sequence']} ({rep['sensor']}): {rep['frames']} frames, {rep['tracked_frames']} tracked "
          f"(states {rep['states']}), {rep['keyframes_mapped']} keyframes mapped, "
          f"{rep['keyframes']} in the final map, {rep['map_points']} map points, "
          f"wall {rep['wall_s']:.1f} s")
    print(f"\n{'stage':<26} {'frames':>6} {'median':>8} {'p95':>8} {'mean':>8} {'max':>8}  (ms)")
    for r in rep["stages_ms"]:
        if "median" not in r:
            print(f"{r['stage']:<26} {0:>6} {'-':>8} {'-':>8} {'-':>8} {'-':>8}")
            continue
        print(f"{r['stage']:<26} {r['n']:>6} {r['median']:8.2f} {r['p95']:8.2f} {r['mean']:8.2f} "
              f"{r['max']:8.2f}")
    ratio = rep["realtime_ratio"]
    print(f"\nwhole frame / {rep['budget_ms']:.1f} ms budget: median {ratio['median']:.2f}, "
          f"p95 {ratio['p95']:.2f}, mean {ratio['mean']:.2f}  (< 1 = real time)")
    align = "Sim(3)" if rep["sensor"] == "mono" else "SE(3)"
    for name in ("ate_frames", "ate_keyframes"):
        a = rep[name]
        if a is not None:
            print(f"{name:<14} rmse {a['rmse_m'] * 100:6.2f} cm  mean {a['mean_m'] * 100:6.2f} cm  "
                  f"max {a['max_m'] * 100:6.2f} cm  ({a['pairs']} poses, {align} alignment)")
    if rep["scale_error"] is not None:
        print(f"scale error    {100 * rep['scale_error']:+.2f} % (Sim(3) alignment's scale)")
    if rep["path_length_ratio"] is not None:
        print(f"path length    {rep['path_length_ratio']:.2f} x the truth's (jitter adds length)")
    for err in rep["metric_errors"]:
        print(f"metric not computed: {err}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sequence", type=Path,
                        default=data_dir() / "tum" / "rgbd_dataset_freiburg1_rpy",
                        help="sequence folder (default: TUM fr1/rpy in the shared data)")
    parser.add_argument("--sensor", choices=("rgbd", "stereo", "mono"), default="rgbd")
    parser.add_argument("--max-frames", type=int, help="process only the first N frames")
    parser.add_argument("--config", help="JSON object or JSON file of SlamSystem/extractor options")
    parser.add_argument("--json", type=Path, metavar="OUT", help="also write the report as JSON")
    parser.add_argument("--realtime", action="store_true",
                        help="feed frames at the pace of their timestamps (a live camera)")
    args = parser.parse_args(argv)
    if not args.sequence.is_dir():
        parser.error(f"sequence not found: {args.sequence} (set FERROSLAM_DATA)")

    seq = open_sequence(args.sequence)
    budget_ms = float(np.median(np.diff(seq.timestamps))) * 1e3
    start = time.perf_counter()
    recorders: list[KeyframeRecorder] = []

    def factory(*a, **kw):
        recorders.append(KeyframeRecorder(*a, **kw))
        return recorders[-1]

    result = run_sequence(seq, _config(args.config), max_frames=args.max_frames, progress=False,
                          sensor=args.sensor, system_factory=factory, realtime=args.realtime)
    rep = report(result, np.array(recorders[0].is_keyframe, bool), time.perf_counter() - start,
                 budget_ms)
    print_report(rep)
    if args.json is not None:
        args.json.write_text(json.dumps(rep, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
