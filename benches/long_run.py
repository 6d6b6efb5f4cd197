#!/usr/bin/env python3
"""Long-run scaling: are time and memory per frame flat when a sequence is replayed?

Replays the TUM fr1/rpy frames forwards, backwards, forwards, ... (``--passes`` times)
through one RGB-D system (ferroslam's ``SlamSystem``, or ORB-SLAM3); timestamps keep increasing (each replayed frame
is stamped one median frame interval after the previous one), so the core sees one long
sequence that revisits the same place. Frames are extracted once and cached, so the loop
times only what the system does per frame (``track_rgbd``: tracking + local mapping) plus,
from the first pass, ORB extraction for reference. Every ``--every`` frames it logs the
median / p95 call time over the window, the process RSS (``/proc/self/status``) and the
map size, and what handing the map to the mapping thread costs (``snapshot us``: the
copy-on-write copy made per keyframe; ``deep us``: the deep copy made before, for
reference; medians of 5, bench builds only); at the end it prints the curve, a least-squares slope of time and RSS against the
frame index, and with ``--plot PNG`` saves the curve with matplotlib.

With ``--mapping-thread`` local mapping runs in its own thread, as live, and with
``--realtime`` frames are fed at the pace of their timestamps (a live camera): tracking then
only asks for keyframes local mapping can take, as in ORB-SLAM. ``--system orbslam3`` replays
the same frames through ORB-SLAM3 (``pyorbslam3``; its call includes ORB extraction, ours
does not), one system per process so that the memory figures are each system's own.

    python benches/long_run.py [--sequence DIR] [--max-frames N] [--passes P]
                               [--every K] [--system {ferroslam,orbslam3}]
                               [--mapping-thread] [--realtime] [--plot OUT.png] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _orbslam3 as orb  # noqa: E402  (memory helpers)


class FerroslamReplay:
    """ferroslam's RGB-D ``SlamSystem`` on features extracted once (the call is tracking +
    local mapping, ORB extraction excluded)."""

    def __init__(self, seq, n: int, mapping_thread: bool):
        from ferroslam._core import SlamSystem
        from ferroslam.features import sample_depth
        from ferroslam.pipeline import make_extractor

        extractor = make_extractor({})
        self.features, extraction_ms = [], []
        for i in range(n):
            gray, depth = seq.load_gray(i), seq.load_depth(i)
            t0 = time.perf_counter()
            kps, desc = extractor.detect(gray)
            self.features.append((kps, desc, sample_depth(depth, kps)))
            extraction_ms.append((time.perf_counter() - t0) * 1e3)
        cam = seq.camera
        self.system = SlamSystem(cam.fx, cam.fy, cam.cx, cam.cy, cam.dist, cam.width,
                                 cam.height, sensor="rgbd")
        self.system.set_mapping_thread(mapping_thread)
        self.mode = (f"ferroslam, mapping {'thread' if mapping_thread else 'inline'}, ORB "
                     f"extraction cached (median {np.median(extraction_ms):.1f} ms, not timed)")

    def track(self, t: float, i: int) -> bool:
        return str(self.system.track_rgbd(t, *self.features[i]).state) == "ok"

    def map_size(self) -> tuple[int, int | None]:
        kf_ids, _, _ = self.system.keyframe_trajectory()
        return int(np.asarray(kf_ids).size), int(self.system.num_map_points)

    def map_copy_us(self) -> tuple[float, float] | None:
        if not hasattr(self.system, "map_copy_cost"):  # a build without the bench feature
            return None
        costs = np.array([self.system.map_copy_cost() for _ in range(5)])
        return float(np.median(costs[:, 0])), float(np.median(costs[:, 1]))


class OrbSlam3Replay:
    """ORB-SLAM3 RGB-D (``pyorbslam3``) on images loaded once (the call is extraction +
    tracking; local mapping runs in its own thread). Its map size is read through the
    keyframe trajectory it saves; it does not expose its point count."""

    def __init__(self, seq, n: int):
        import pyorbslam3 as pos

        # The exported text vocabulary is tens of MB: removed with this object.
        self._workdir = tempfile.TemporaryDirectory(prefix="ferroslam_long_run_")
        workdir = Path(self._workdir.name)
        vocab = orb.export_vocabulary(workdir)
        settings = orb.write_settings(seq, "rgbd", workdir)
        factor = orb.PRESETS["tum"]["depth_factor"]
        self.images = [(seq.load_gray(i), (seq.load_depth(i) * factor).astype(np.float32))
                       for i in range(n)]
        self.slam = pos.Slam(vocab_file=str(vocab), settings_file=str(settings),
                             sensor=pos.Sensor.RGBD, use_viewer=False)
        self.keyframes_file = workdir / "keyframes.txt"
        self.mode = "ORB-SLAM3, its own mapping thread, ORB extraction inside the call"

    def track(self, t: float, i: int) -> bool:
        return self.slam.track_rgbd(*self.images[i], t).state.name == "OK"

    def map_size(self) -> tuple[int, int | None]:
        self.slam.save_keyframe_trajectory_tum(str(self.keyframes_file))
        with open(self.keyframes_file, encoding="utf-8") as f:
            return sum(1 for line in f if line.strip()), None

    @staticmethod
    def map_copy_us() -> None:
        return None


def main(argv=None) -> int:
    from ferroslam._data import data_dir
    from ferroslam.datasets import ReplayedSequence, open_sequence

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sequence", type=Path,
                        default=data_dir() / "tum" / "rgbd_dataset_freiburg1_rpy")
    parser.add_argument("--max-frames", type=int, help="frames of the sequence to replay")
    parser.add_argument("--passes", type=int, default=6, help="forward/backward passes")
    parser.add_argument("--every", type=int, default=50, help="log window, frames")
    parser.add_argument("--system", choices=("ferroslam", "orbslam3"), default="ferroslam")
    parser.add_argument("--mapping-thread", action="store_true",
                        help="ferroslam: local mapping in its own thread")
    parser.add_argument("--realtime", action="store_true",
                        help="feed frames at the pace of their timestamps")
    parser.add_argument("--plot", type=Path, metavar="PNG", help="save the curve (matplotlib)")
    parser.add_argument("--json", type=Path, metavar="OUT")
    args = parser.parse_args(argv)

    seq = open_sequence(args.sequence)
    n = min(len(seq), args.max_frames or len(seq))
    replay = (OrbSlam3Replay(seq, n) if args.system == "orbslam3"
              else FerroslamReplay(seq, n, args.mapping_thread))
    replayed = ReplayedSequence(seq, args.passes, n)
    order, stamps = replayed.order, replayed.timestamps
    rss0 = orb.memory_kb()["VmRSS"]
    call_ms = np.zeros(len(order))
    tracked, rows = [], []
    mode = replay.mode + (", fed in real time" if args.realtime else ", fed as fast as it goes")
    print(f"{seq.name}: {n} frames x {args.passes} passes = {len(order)} frames; {mode}; "
          f"load average {orb.load_average()}")
    head = (f"{'frames':>7} {'pass':>4} {'median ms':>9} {'p95 ms':>7} {'max ms':>7} "
            f"{'RSS MB':>7} {'ok %':>5} {'KFs':>5} {'points':>7} {'snapshot us':>11} "
            f"{'deep us':>8}")
    print(head)
    print("-" * len(head))
    clock0 = time.perf_counter()
    for k, i in enumerate(order):
        if args.realtime:
            time.sleep(max(0.0, clock0 + (stamps[k] - stamps[0]) - time.perf_counter()))
        t0 = time.perf_counter()
        tracked.append(replay.track(float(stamps[k]), i))
        call_ms[k] = (time.perf_counter() - t0) * 1e3
        if (k + 1) % args.every == 0 or k + 1 == len(order):
            w = call_ms[k + 1 - ((k % args.every) + 1): k + 1]
            ok = sum(tracked[-len(w):]) / len(w)
            keyframes, points = replay.map_size()
            copy_us = replay.map_copy_us()
            row = {"frame": k + 1, "pass": int(np.searchsorted(
                       np.cumsum([n] + [n - 1] * (args.passes - 1)), k, side="right")) + 1,
                   "median_ms": float(np.median(w)), "p95_ms": float(np.percentile(w, 95)),
                   "max_ms": float(w.max()), "rss_mb": orb.memory_kb()["VmRSS"] / 1024,
                   "ok": ok, "keyframes": keyframes, "map_points": points,
                   "snapshot_us": copy_us and copy_us[0], "deep_copy_us": copy_us and copy_us[1]}
            rows.append(row)
            print(f"{row['frame']:>7} {row['pass']:>4} {row['median_ms']:>9.1f} "
                  f"{row['p95_ms']:>7.1f} {row['max_ms']:>7.1f} {row['rss_mb']:>7.1f} "
                  f"{100 * ok:>5.0f} {row['keyframes']:>5} "
                  f"{'-' if points is None else points:>7} "
                  + (f"{copy_us[0]:>11.1f} {copy_us[1]:>8.0f}" if copy_us else f"{'-':>11} {'-':>8}"),
                  flush=True)

    frames = np.array([r["frame"] for r in rows], float)
    med = np.array([r["median_ms"] for r in rows])
    rss = np.array([r["rss_mb"] for r in rows])
    half = len(rows) // 2
    slope_t = np.polyfit(frames, med, 1)[0] * 1000 if len(rows) > 1 else float("nan")
    slope_m = np.polyfit(frames, rss, 1)[0] * 1000 if len(rows) > 1 else float("nan")
    summary = {
        "frames": len(order), "passes": args.passes, "mode": mode, "sequence_frames": n,
        "rss_start_mb": rss0 / 1024, "rss_end_mb": float(rss[-1]), "rss_max_mb": float(rss.max()),
        "median_ms_first_half": float(np.median(call_ms[: len(order) // 2])),
        "median_ms_second_half": float(np.median(call_ms[len(order) // 2:])),
        "window_median_ms_first": float(med[0]), "window_median_ms_last": float(med[-1]),
        "slope_ms_per_1000_frames": float(slope_t), "slope_rss_mb_per_1000_frames": float(slope_m),
        "rss_second_half_growth_mb": float(rss[-1] - rss[half]) if half else float("nan"),
        "ok_fraction": sum(tracked) / len(tracked), "load_end": orb.load_average(),
    }
    print(f"\ncall time median: first half {summary['median_ms_first_half']:.1f} ms, second half "
          f"{summary['median_ms_second_half']:.1f} ms; trend {slope_t:+.2f} ms per 1000 frames")
    print(f"RSS: {summary['rss_start_mb']:.0f} MB before the first frame, max "
          f"{summary['rss_max_mb']:.0f} MB, end {summary['rss_end_mb']:.0f} MB; trend "
          f"{slope_m:+.2f} MB per 1000 frames, growth over the second half "
          f"{summary['rss_second_half_growth_mb']:+.1f} MB")
    if rows[-1]["snapshot_us"] is not None:
        print(f"map handed to the mapping thread at the end: {rows[-1]['snapshot_us']:.1f} us "
              f"(deep copy {rows[-1]['deep_copy_us']:.0f} us, "
              f"{rows[-1]['deep_copy_us'] / rows[-1]['snapshot_us']:.0f}x)")
    print(f"tracked {100 * summary['ok_fraction']:.1f} % of frames; final map "
          f"{rows[-1]['keyframes']} keyframes, {rows[-1]['map_points']} points; load average at "
          f"end {summary['load_end']}")

    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (a1, a2, a3) = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        a1.plot(np.arange(1, len(order) + 1), call_ms, lw=0.3, color="0.7", label="per frame")
        a1.plot(frames, med, "o-", label=f"median / {args.every}")
        a1.plot(frames, [r["p95_ms"] for r in rows], "s--", label="p95")
        a1.set_ylabel("track_rgbd ms")
        a1.legend(loc="upper right")
        a2.plot(frames, rss, "o-")
        a2.set_ylabel("RSS MB")
        a3.plot(frames, [r["keyframes"] for r in rows], "o-", label="keyframes")
        if rows[-1]["map_points"] is not None:
            a3.plot(frames, [r["map_points"] / 100 for r in rows], "s-", label="map points / 100")
        a3.set_xlabel("frame (replayed)")
        a3.legend(loc="upper left")
        for x in np.cumsum([n] + [n - 1] * (args.passes - 1))[:-1]:
            for a in (a1, a2, a3):
                a.axvline(x, color="0.85", lw=0.8)
        fig.suptitle(f"{seq.name} replayed {args.passes}x\n{mode}", fontsize=9)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"plot saved to {args.plot}")
    if args.json is not None:
        args.json.write_text(json.dumps({"summary": summary, "curve": rows}, indent=2) + "\n",
                             encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
