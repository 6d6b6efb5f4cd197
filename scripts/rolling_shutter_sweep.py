"""Sweep a camera's rolling-shutter readout on a TUM sequence: ATE / RPE per readout.

The freiburg1 readout default of ``ferroslam.datasets.tum`` was measured with it (table and
command in docs/benchmarks.md). Each run is ``ferroslam run`` with its defaults (mapping
inline, the shipped vocabulary), only the camera's ``rolling_shutter_readout_s`` changed.

    python scripts/rolling_shutter_sweep.py PATH --sensor rgbd --readouts-ms 0 10 20 30
"""

from __future__ import annotations

import argparse
import dataclasses

from ferroslam.datasets import TumSequence
from ferroslam.pipeline import run_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="TUM sequence folder")
    parser.add_argument("--sensor", choices=("rgbd", "mono"), default="rgbd")
    parser.add_argument("--readouts-ms", type=float, nargs="+",
                        default=[0, 10, 15, 20, 25, 30, 35])
    parser.add_argument("--max-frames", type=int, default=None)
    args = parser.parse_args()
    print("| readout (ms) | frames tracked | ATE (cm) | RPE 1 frame (cm) | RPE rot (deg) |")
    print("|---|---|---|---|---|")
    for readout_ms in args.readouts_ms:
        seq = TumSequence(args.path, with_depth=args.sensor == "rgbd")
        seq.camera = dataclasses.replace(seq.camera, rolling_shutter_readout_s=readout_ms / 1e3)
        result = run_sequence(seq, {}, max_frames=args.max_frames, progress=False,
                              sensor=args.sensor)
        m = result.summary()["metrics"]
        rpe = m.get("rpe_frames")
        rpe_text = (f"{100 * rpe['trans_rmse_m']:.2f} | {rpe['rot_rmse_deg']:.3f}"
                    if rpe else "- | -")
        print(f"| {readout_ms:g} | {result.tracked_frames}/{result.frames} | "
              f"{100 * m['ate_frames']['rmse']:.2f} | {rpe_text} |", flush=True)


if __name__ == "__main__":
    main()
