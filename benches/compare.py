#!/usr/bin/env python3
"""Head-to-head: ferroslam against ORB-SLAM3 (the ``pyorbslam3`` wheel) on the same frames.

For each sequence one worker process runs ferroslam (``ferroslam.pipeline.run_sequence``)
and ORB-SLAM3 in turn, ``--runs`` times each (the run with the median ATE is reported, the
spread beside it), fed frame by frame with every call timed, and evaluates both
trajectories with ``ferroslam.metrics.ate`` against the same ground truth (SE(3) alignment
for stereo / RGB-D and for inertial runs whose IMU made the trajectory metric, Sim(3) for
monocular otherwise; ``ate_alignment``). One process per sequence because ORB-SLAM3 keeps
per-camera statics (``Frame::mbInitialComputations``) that a second camera in the same
process would inherit; both systems of a sequence share that process.

    python benches/compare.py [--sequences tum_rgbd tum_mono kitti_mono kitti_stereo euroc_stereo]
                              [--max-frames N] [--runs R] [--json OUT] [--workdir DIR]
                              [--inline-mapping] [--realtime] [--extractor JSON]
                              [--keep-cpus-busy]

Needs ``pip install -e .[bench]`` (pyorbslam3) and the native module built in release mode.
ORB-SLAM3 uses ferroslam's shipped vocabulary exported as DBoW2 text and settings files
written from the loaders' calibration (``benches/_orbslam3.py``), both in a temporary folder
(``--workdir`` to keep them); ORB-SLAM3's console output goes to ``<workdir>/<seq>.log``.

Times: ours = ``frame_ms`` (ORB extraction + depth sampling / stereo matching + tracking;
local mapping and loop closing run in their own thread, as ORB-SLAM3's do, unless
``--inline-mapping`` puts them inside the call); ORB-SLAM3 = the track call (extraction +
tracking; its local mapping and loop closing run in background threads that compete for
the same cores). Frames go to both systems as fast as they take them, or at the pace of
their timestamps with ``--realtime`` (a live camera: mapping threads then have the time
between frames, as in ORB-SLAM's own examples). ``--keep-cpus-busy`` runs one idle-priority
busy loop per CPU meanwhile, a sensitivity check for virtual machines whose host packs an
idling guest's vCPUs onto fewer cores (``benches/cpu_packing.py`` tells; see
``_orbslam3.cpus_kept_busy``); each sequence's record carries the speedup of two threads over
one measured at its start (``cpu_packing.two_thread_speedups``). Image loading is excluded
from both. Peak memory: ``VmHWM`` reset before each system (``/proc/self/clear_refs``), minus
the RSS at its start.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Optional

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _orbslam3 as orb  # noqa: E402
import cpu_packing  # noqa: E402

# name: (folder under the data dir, sensor, default frame limit)
SEQUENCES = {
    "tum_rgbd": ("tum/rgbd_dataset_freiburg1_rpy", "rgbd", 300),
    "tum_mono": ("tum/rgbd_dataset_freiburg1_rpy", "mono", 300),
    "kitti_mono": ("kitti/odometry_06_first51", "mono", 51),
    "kitti_stereo": ("kitti/stereo_51_frames", "stereo", 51),
    "euroc_stereo": ("euroc/V1_01_easy_micro", "stereo", None),
    "mh01_stereo": ("euroc/MH_01_easy_window", "stereo", None),
    "mh01_mono": ("euroc/MH_01_easy_window", "mono", None),
    "mh01_stereo_inertial": ("euroc/MH_01_easy_window", "stereo-inertial", None),
    "mh01_mono_inertial": ("euroc/MH_01_easy_window", "mono-inertial", None),
}
NAME_W = max(map(len, SEQUENCES))  # width of the sequence column
STAGES = ("extraction_ms", "tracking_ms", "matching_ms", "pose_optimisation_ms", "mapping_ms",
          "track_call_ms", "frame_ms")


def _stats(values) -> dict:
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "mean": float("nan")}
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
            "mean": float(np.mean(v))}


def _both_tracking(ours_ok: np.ndarray, ours_ms: np.ndarray, orb_states: list,
                   orb_ms: np.ndarray) -> dict:
    """Median ms of each system over the frames both track (a lost system skips most work,
    so the plain medians favour the one that loses more frames)."""
    both = ours_ok & np.array([s == "OK" for s in orb_states])
    return {"frames": int(both.sum()), "ours": _stats(ours_ms[both])["median"],
            "orbslam3": _stats(orb_ms[both])["median"]}


def ate_alignment(sensor: str, imu_metric: bool) -> str:
    """``"sim3"`` for a trajectory of arbitrary scale (monocular, unless the IMU made it
    metric: ours aligned to the IMU, ORB-SLAM3's IMU initialised), else ``"se3"``: fitting a
    scale to a metric trajectory would hide its scale error."""
    return "sim3" if sensor.startswith("mono") and not imu_metric else "se3"


def _common_ate(gt, ours, theirs, align_ours: str, align_theirs: str) -> dict:
    """ATE of each trajectory over only the poses both have (same timestamps): a system that
    loses the map keeps its few easy poses, which its plain ATE would otherwise compare with
    the other system's whole run."""
    t_o, t_t = np.round(ours.timestamps, 6), np.round(theirs.timestamps, 6)
    common = np.intersect1d(t_o, t_t)
    return {"poses": int(common.size),
            "ours": _ate(gt, ours.subset(np.flatnonzero(np.isin(t_o, common))),
                         align_ours)["rmse_m"],
            "orbslam3": _ate(gt, theirs.subset(np.flatnonzero(np.isin(t_t, common))),
                             align_theirs)["rmse_m"]}


def _ate(gt, traj, align: str) -> dict:
    from ferroslam.metrics import ate

    try:
        a = ate(gt, traj, align=align)
    except ValueError as err:
        return {"rmse_m": None, "pairs": 0, "error": str(err)}
    return {"rmse_m": float(a.rmse), "pairs": int(a.pairs), "scale": float(a.scale)}


def _median_ate_run(records: list) -> int:
    """Index of the run whose ATE is the median (failed runs count as the worst)."""
    ates = [r["ate"]["rmse_m"] if r["ate"]["rmse_m"] is not None else float("inf")
            for r in records]
    return int(np.argsort(ates)[(len(ates) - 1) // 2])


def _spread(records: list, chosen: int) -> dict:
    """The chosen run, with every run's tracked frames, ATE and median ms beside it."""
    out = dict(records[chosen])
    out["runs"] = len(records)
    out["tracked_all"] = [r["tracked"] for r in records]
    out["ate_all_m"] = [r["ate"]["rmse_m"] for r in records]
    out["frame_ms_median_all"] = [r["frame_ms"]["median"] for r in records]
    out["frame_ms_p95_all"] = [r["frame_ms"]["p95"] for r in records]
    return out


def worker(name: str, max_frames, out: Path, workdir: Path, runs: int,
           mapping_thread: bool, realtime: bool, extractor: Optional[dict] = None,
           keep_cpus_busy: bool = False) -> None:
    """Run both systems on one sequence and write the measurements as JSON to ``out``;
    ``extractor`` replaces ORB extractor options of both (``_orbslam3.EXTRACTOR_KEYS``);
    ``keep_cpus_busy`` runs both inside ``_orbslam3.cpus_kept_busy``."""
    from ferroslam._data import data_dir
    from ferroslam.datasets import open_sequence
    from ferroslam.pipeline import run_sequence
    from ferroslam.trajectory import Trajectory

    folder, sensor, default_n = SEQUENCES[name]
    seq = open_sequence(data_dir() / folder, sensor=sensor)
    n = min(len(seq), max_frames or default_n or len(seq))
    gt = Trajectory(*seq.groundtruth())
    vocab = orb.export_vocabulary(workdir)
    settings = orb.write_settings(seq, sensor, workdir, extractor)
    config = {**orb.ferroslam_config(seq, sensor, extractor), "mapping_thread": mapping_thread}
    rec = {"sequence": name, "path": folder, "sensor": sensor, "frames": n,
           "realtime": realtime, "cpus_kept_busy": keep_cpus_busy,
           "config": config, "settings": str(settings), "load_start": orb.load_average()}

    def ours() -> tuple[dict, np.ndarray, np.ndarray, Trajectory]:
        base = orb.memory_kb()["VmRSS"]
        orb.reset_peak_memory()
        t0 = time.perf_counter()
        res = run_sequence(seq, config, max_frames=n, progress=False, sensor=sensor,
                           realtime=realtime)
        wall = time.perf_counter() - t0
        peak = orb.memory_kb()["VmHWM"]
        traj = res.trajectory
        status = (res.inertial or {}).get("status")
        align = ate_alignment(sensor, status == "aligned")
        if align == "sim3":
            traj = res.largest_map_trajectory  # as the pipeline's Sim(3) ATE
        record = {
            "tracked": res.tracked_frames, "poses": len(res.trajectory),
            "keyframes": len(res.keyframes), "map_points": int(res.map_points.shape[0]),
            "wall_s": wall, "frame_ms": _stats(res.timings["frame_ms"]),
            "stages_ms": {k: _stats(res.timings[k]) for k in STAGES},
            "align": align, "ate": _ate(gt, traj, align), "inertial_status": status,
            "scale_error": None if res.path_length is None else res.path_length.scale_error,
            "peak_rss_mb": peak / 1024, "peak_delta_mb": (peak - base) / 1024,
        }
        ok = np.array([st == "ok" for st in res.states])
        return record, ok, np.asarray(res.timings["frame_ms"], np.float64), traj, align

    def orbslam3():
        t0 = time.perf_counter()
        run = orb.run_orbslam3(seq, sensor, n, vocab, settings, realtime=realtime)
        wall = time.perf_counter() - t0
        align = ate_alignment(sensor, run.imu_initialized)
        record = {
            "tracked": run.tracked_frames, "poses": len(run.trajectory), "wall_s": wall,
            "vocab_and_setup_s": run.load_s, "shutdown_s": run.shutdown_s,
            "imu_initialized": run.imu_initialized, "align": align,
            "frame_ms": _stats(run.call_ms), "ate": _ate(gt, run.trajectory, align),
            "ate_online": _ate(gt, run.online, align),
            "states": {s: run.states.count(s) for s in set(run.states)},
            "peak_rss_mb": run.peak_rss_kb / 1024, "peak_delta_mb": run.peak_delta_kb / 1024,
            "errors": run.errors,
        }
        return (record, run.states, np.asarray(run.call_ms, np.float64), run.trajectory,
                align)

    # Neither system is deterministic with its mapping thread, so each runs `runs` times,
    # alternating so that a change of machine load reaches both; the run with the median ATE
    # is reported, the spread beside it.
    ours_runs, orb_runs = [], []
    with orb.cpus_kept_busy(keep_cpus_busy):
        rec["two_thread_speedup"] = cpu_packing.two_thread_speedups()
        for _ in range(runs):
            ours_runs.append(ours())
            orb_runs.append(orbslam3())
    io = _median_ate_run([r[0] for r in ours_runs])
    it = _median_ate_run([r[0] for r in orb_runs])
    rec["ours"] = _spread([r[0] for r in ours_runs], io)
    rec["orbslam3"] = _spread([r[0] for r in orb_runs], it)
    # Over the frames both track: per pair of runs made one after the other, the median over
    # the pairs (a pair where either fails to align counts as NaN and is left out).
    both = [_both_tracking(o[1], o[2], t[1], t[2]) for o, t in zip(ours_runs, orb_runs)]
    rec["both_tracking_ms_all"] = [[float(b[k]) for k in ("frames", "ours", "orbslam3")]
                                   for b in both]
    rec["both_tracking_ms"] = {k: float(np.median([b[k] for b in both]))
                               for k in ("frames", "ours", "orbslam3")}
    common = [_common_ate(gt, o[3], t[3], o[4], t[4]) for o, t in zip(ours_runs, orb_runs)]
    rec["both_tracking_ate_all_m"] = [
        [None if c[k] is None else float(c[k]) for k in ("poses", "ours", "orbslam3")]
        for c in common]
    rec["both_tracking_ate_m"] = {
        k: float(np.nanmedian([np.nan if c[k] is None else c[k] for c in common]))
        for k in ("poses", "ours", "orbslam3")}
    rec["load_end"] = orb.load_average()
    out.write_text(json.dumps(rec, indent=2) + "\n", encoding="utf-8")


def _ratio(a, b) -> str:
    if a is None or b is None or not np.isfinite(a) or not np.isfinite(b) or b == 0:
        return "-"
    return f"{a / b:.2f}"


def _cm(a: dict) -> str:
    return "fail" if a.get("rmse_m") is None else f"{a['rmse_m'] * 100:.2f}"


def _per_pair(pairs: list) -> str:
    """Run pairs (``[count, ours, orbslam3]`` over what both have; the counts differ from pair
    to pair, so the two medians may come from different pairs): the median of ours / theirs
    and in how many pairs ours is lower. Pairs with a missing or non-finite value are left
    out."""
    valid = [(o, t) for _, o, t in pairs
             if o is not None and t is not None and np.isfinite(o) and np.isfinite(t) and t > 0]
    if not valid:
        return "no valid pair"
    ratio = float(np.median([o / t for o, t in valid]))
    return f"per pair: ratio median {ratio:.2f}, ours lower in {sum(o < t for o, t in valid)} " \
           f"of {len(valid)}"


def _alignment_note(r: dict) -> str:
    """How each system's ATE of sequence record ``r`` was aligned and why: our path-length
    scale error (metric runs), our IMU alignment status and whether ORB-SLAM3's IMU
    initialised (inertial runs)."""
    ours, theirs = r["ours"], r["orbslam3"]
    note = f"ATE alignment ours {ours['align']}, ORB-SLAM3 {theirs['align']}"
    if ours["scale_error"] is not None:
        note += f"; ours path-length scale error {100 * ours['scale_error']:+.1f}%"
    if r["sensor"].endswith(orb.INERTIAL):
        note += (f"; ours IMU {ours['inertial_status']}, ORB-SLAM3 IMU initialised: "
                 f"{theirs['imu_initialized']}")
    return note


def print_table(records: list) -> None:
    head = (f"{'sequence':<{NAME_W}} {'frames':>6} {'tracked o/t':>11} {'ATE cm ours':>11} "
            f"{'ATE cm orb3':>11} {'ATE o/t':>7} {'ms med ours':>11} {'ms med orb3':>11} "
            f"{'p95 ours':>8} {'p95 orb3':>8} {'t o/t':>6} {'peak MB o/t':>12}")
    print(head)
    print("-" * len(head))
    for r in records:
        o, t = r["ours"], r["orbslam3"]
        med_o, med_t = np.median(o["frame_ms_median_all"]), np.median(t["frame_ms_median_all"])
        print(f"{r['sequence']:<{NAME_W}} {r['frames']:>6} {o['tracked']:>5}/{t['tracked']:<5} "
              f"{_cm(o['ate']):>11} {_cm(t['ate']):>11} "
              f"{_ratio(o['ate'].get('rmse_m'), t['ate'].get('rmse_m')):>7} "
              f"{med_o:>11.1f} {med_t:>11.1f} "
              f"{np.median(o['frame_ms_p95_all']):>8.1f} {np.median(t['frame_ms_p95_all']):>8.1f} "
              f"{_ratio(med_o, med_t):>6} "
              f"{o['peak_delta_mb']:>5.0f}/{t['peak_delta_mb']:<5.0f}")
    print("\nours (the median-ATE run): per-stage median (p95) ms; ORB-SLAM3 extras")
    for r in records:
        o, t = r["ours"], r["orbslam3"]
        stages = "  ".join(f"{k[:-3]} {v['median']:.1f} ({v['p95']:.1f})"
                           for k, v in o["stages_ms"].items())
        print(f"{r['sequence']:<{NAME_W}} {stages}")
        extractor = {k: r["config"][k] for k in orb.EXTRACTOR_KEYS}
        print(f"{'':<{NAME_W}} extractor (both): {extractor}")
        print(f"{'':<{NAME_W}} {_alignment_note(r)}")
        print(f"{'':<{NAME_W}} ours: {o['keyframes']} KFs, {o['map_points']} points, wall {o['wall_s']:.1f} s, "
              f"peak RSS {o['peak_rss_mb']:.0f} MB | ORB-SLAM3: setup+vocab {t['vocab_and_setup_s']:.1f} s, "
              f"wall {t['wall_s']:.1f} s, online-pose ATE {_cm(t['ate_online'])} cm, states {t['states']}, "
              f"peak RSS {t['peak_rss_mb']:.0f} MB {' '.join(t['errors'])}")
        for who, x in (("ours", o), ("ORB-SLAM3", t)):
            spread = ", ".join("fail" if a is None else f"{100 * a:.2f}" for a in x["ate_all_m"])
            meds = ", ".join(f"{m:.1f}" for m in x["frame_ms_median_all"])
            tracked = ", ".join(str(n) for n in x["tracked_all"])
            print(f"{'':<{NAME_W}} {who} over {x['runs']} runs: tracked [{tracked}], ATE cm [{spread}], "
                  f"median ms [{meds}]")
        print(f"{'':<{NAME_W}} ATE pairs ours/ORB-SLAM3 {o['ate'].get('pairs')}/{t['ate'].get('pairs')}; "
              f"wall per frame incl. image loading and (ORB-SLAM3) its mapping threads and "
              f"shutdown: {1e3 * o['wall_s'] / r['frames']:.1f} / "
              f"{1e3 * (t['wall_s'] - t['vocab_and_setup_s']) / r['frames']:.1f} ms")
        both = r["both_tracking_ms"]
        print(f"{'':<{NAME_W}} median ms over the frames both track ({both['frames']:.0f}), median of the "
              f"run pairs: ours "
              f"{both['ours']:.1f} / ORB-SLAM3 {both['orbslam3']:.1f} "
              f"({_ratio(both['ours'], both['orbslam3'])}); {_per_pair(r['both_tracking_ms_all'])}")
        a = r["both_tracking_ate_m"]
        print(f"{'':<{NAME_W}} ATE over the poses both have ({a['poses']:.0f}), median of the run pairs: "
              f"ours {100 * a['ours']:.2f} / ORB-SLAM3 {100 * a['orbslam3']:.2f} cm "
              f"({_ratio(a['ours'], a['orbslam3'])}); {_per_pair(r['both_tracking_ate_all_m'])}")
        busy = "; CPUs kept busy" if r.get("cpus_kept_busy") else ""
        print(f"{'':<{NAME_W}} load average at start {r['load_start']}, at end {r['load_end']}{busy}")
        if "two_thread_speedup" in r:  # benches/cpu_packing.py
            sp = r["two_thread_speedup"]
            print(f"{'':<{NAME_W}} two threads against one at the start: {sp['back_to_back']:.2f}x "
                  f"back to back, {sp['after_10ms_idle']:.2f}x after 10 ms idle (about 1: no "
                  "second core, packed or busy)")
    print("\nATE: RMSE after SE(3) (Sim(3) for mono, unless the IMU made it metric) alignment, final trajectories (ours: longest "
          "segment for mono; ORB-SLAM3: SaveTrajectoryEuRoC, biggest map; for each system the run "
          "with the median ATE of --runs; ms med and p95: the median over the runs). o/t = ours / "
          "ORB-SLAM3 (< 1: ours better/faster). ms: ours frame_ms, ORB-SLAM3 track call; peak MB: "
          "VmHWM rise during each system's run.")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sequences", nargs="+", choices=sorted(SEQUENCES),
                        default=list(SEQUENCES))
    parser.add_argument("--max-frames", type=int, help="frames per sequence (default: all, TUM 300)")
    parser.add_argument("--json", type=Path, metavar="OUT", help="write all records as JSON")
    parser.add_argument("--workdir", type=Path, help="keep settings, vocabulary and logs here")
    parser.add_argument("--runs", type=int, default=3,
                        help="runs of each system per sequence, alternating (neither is "
                             "deterministic with mapping threads; the median-ATE run is shown)")
    parser.add_argument("--inline-mapping", action="store_true",
                        help="run our local mapping inside the track call (deterministic)")
    parser.add_argument("--realtime", action="store_true",
                        help="feed frames at the pace of their timestamps")
    parser.add_argument("--extractor", type=json.loads, metavar="JSON",
                        help="ORB extractor options for both systems, replacing the "
                             "sequence's preset, e.g. '{\"n_features\": 1100, \"ini_fast\": 19}'")
    parser.add_argument("--keep-cpus-busy", action="store_true",
                        help="one idle-priority busy loop per CPU during the runs, so that a "
                             "virtual machine's host does not pack the vCPUs")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--worker-out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.worker:
        worker(args.worker, args.max_frames, args.worker_out, args.workdir, args.runs,
               not args.inline_mapping, args.realtime, args.extractor, args.keep_cpus_busy)
        return 0

    tmp = None
    if args.workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="ferroslam_compare_")
        args.workdir = Path(tmp.name)
    args.workdir.mkdir(parents=True, exist_ok=True)
    records, failures = [], []
    for name in args.sequences:
        out = args.workdir / f"{name}.json"
        log = args.workdir / f"{name}.log"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", name,
               "--worker-out", str(out), "--workdir", str(args.workdir)]
        cmd += ["--runs", str(args.runs)]
        cmd += ["--inline-mapping"] * args.inline_mapping + ["--realtime"] * args.realtime
        cmd += ["--keep-cpus-busy"] * args.keep_cpus_busy
        if args.extractor:
            cmd += ["--extractor", json.dumps(args.extractor)]
        if args.max_frames:
            cmd += ["--max-frames", str(args.max_frames)]
        print(f"running {name} ... (log {log})", flush=True)
        with open(log, "w", encoding="utf-8") as f:
            rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=os.environ).returncode
        if rc != 0 or not out.is_file():
            tail = log.read_text(encoding="utf-8", errors="replace").splitlines()[-5:]
            failures.append((name, rc, tail))
            continue
        records.append(json.loads(out.read_text(encoding="utf-8")))
    print()
    if records:
        print_table(records)
    for name, rc, tail in failures:
        print(f"\n{name}: worker failed (exit {rc}); last log lines:\n  " + "\n  ".join(tail))
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=2) + "\n", encoding="utf-8")
    if tmp is not None:
        tmp.cleanup()
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
