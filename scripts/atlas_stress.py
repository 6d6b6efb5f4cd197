#!/usr/bin/env python3
"""Runs one case of the atlas many times with the mapping thread and checks that every run
ends (no crash, no deadlock) with the same maps: issue 55's "merges under the mapping
thread" check.

Cases (real frames of TUM fr1/rpy, monocular, default options plus the mapping thread):
``rpy`` the 300 frames of the sequence folder; ``video`` its first 150 frames as an MJPG
video at 30 fps with an ORB-SLAM settings file of the fr1 camera (no rolling-shutter
readout, as a user's video comes). Each run is its own ``ferroslam run`` process with a time
limit (a hung run counts as a deadlock); the summary prints, per run, the map count, the
frames with a pose in the largest map, the merges and the wall time, then whether every
run agreed.

    python scripts/atlas_stress.py --case rpy --runs 20 [--deterministic] [--timeout 300]
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

import cv2

# The fr1 camera in the ORB-SLAM settings format (the TUM README's calibration).
FR1_SETTINGS = """%YAML:1.0
Camera.type: "PinHole"
Camera.fx: 517.3
Camera.fy: 516.5
Camera.cx: 318.6
Camera.cy: 255.3
Camera.k1: 0.2624
Camera.k2: -0.9531
Camera.p1: -0.0054
Camera.p2: 0.0026
Camera.k3: 1.1633
Camera.width: 640
Camera.height: 480
Camera.fps: 30.0
"""
VIDEO_FRAMES = 150


def data_dir() -> Path:
    here = Path(__file__).resolve().parent
    return Path(os.environ.get("FERROSLAM_DATA", here.parent.parent / "shared" / "data"))


def write_video(sequence: Path, root: Path) -> tuple[Path, Path]:
    """The first frames of ``sequence`` as an MJPG video and the settings file beside it."""
    rgb = [line.split()[1] for line in (sequence / "rgb.txt").read_text().splitlines()
           if line and not line.startswith("#")][:VIDEO_FRAMES]
    video = root / "rpy.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 480))
    if not writer.isOpened():
        raise SystemExit("atlas_stress: error: OpenCV cannot write an MJPG video here")
    for name in rgb:
        writer.write(cv2.imread(str(sequence / name)))
    writer.release()
    settings = root / "fr1.yaml"
    settings.write_text(FR1_SETTINGS, encoding="utf-8")
    return video, settings


def run_once(source: Path, extra: list[str], config: Path, out: Path, timeout: float) -> dict:
    command = [sys.executable, "-m", "ferroslam", "run", str(source), "--sensor", "mono",
               "--config", str(config), "--out", str(out), "--silent", *extra]
    start = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"outcome": "timeout", "seconds": timeout}
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        return {"outcome": f"exit {done.returncode}: {done.stderr.strip()[-200:]}",
                "seconds": seconds}
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    maps = results["maps"]
    return {"outcome": "ok", "seconds": seconds, "num_maps": len(maps),
            "frames": sum(m["frames"] for m in maps),
            "largest": max((m["frames"] for m in maps), default=0),
            "merges": results["merges"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=("rpy", "video"), default="rpy")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per run")
    parser.add_argument("--deterministic", action="store_true",
                        help="the mapping thread's deterministic mode (results equal inline)")
    args = parser.parse_args()
    sequence = data_dir() / "tum" / "rgbd_dataset_freiburg1_rpy"
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if args.case == "video":
            source, settings = write_video(sequence, root)
            extra = ["--camera", str(settings)]
        else:
            source, extra = sequence, []
        config = root / "config.json"
        config.write_text(json.dumps({"mapping_thread": True,
                                      "deterministic": args.deterministic}))
        runs = []
        for i in range(args.runs):
            run = run_once(source, extra, config, root / f"run{i}", args.timeout)
            runs.append(run)
            print(f"run {i:2d}: " + ", ".join(f"{k} {v:.1f}" if isinstance(v, float)
                                              else f"{k} {v}" for k, v in run.items()),
                  flush=True)
    failed = [r for r in runs if r["outcome"] != "ok"]
    counts = sorted({r["num_maps"] for r in runs if r["outcome"] == "ok"})
    largest = [r["largest"] for r in runs if r["outcome"] == "ok"]
    print(f"{args.case}, {args.runs} runs, mapping thread"
          f"{' (deterministic)' if args.deterministic else ''}: {len(failed)} failed or hung;"
          f" map counts {counts}; largest map {min(largest, default=0)}-"
          f"{max(largest, default=0)} frames;"
          f" merges {sorted({r['merges'] for r in runs if r['outcome'] == 'ok'})}")
    return 0 if not failed and len(counts) == 1 else 1


if __name__ == "__main__":
    sys.exit(main())
