#!/usr/bin/env python3
"""Pose-graph solver comparison: ferroslam's Rust solver beside gtsam's reference runs.

Builds and runs `crates/optim/examples/pose_graph_solve` (release) on the g2o benchmarks in
the data folder, from the file's initial estimate and from the chordal initialisation, and
prints a table beside the gtsam 4.3.0 figures of `posegraph/reference.json` (same cost:
0.5 sum r^T Omega r with the full SE(3) log). The gtsam times there were measured on another
occasion on a 2-core VM; if `import gtsam` works here, gtsam is also run in this process for
a same-machine ratio.

Usage: python benches/pose_graph_compare.py [--data DIR] [DATASET ...]
(default datasets: smallGrid3D parking-garage sphere2500 torus3D; data dir from
$FERROSLAM_DATA, else ../shared/data relative to the repository root).
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["smallGrid3D", "parking-garage", "sphere2500", "torus3D"]


def data_dir(arg):
    if arg:
        return Path(arg)
    env = os.environ.get("FERROSLAM_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


def run_ours(files):
    cmd = ["cargo", "run", "--release", "-q", "-p", "ferroslam-optim",
           "--example", "pose_graph_solve", "--", "--init", "both", *map(str, files)]
    out = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True)
    return [json.loads(line) for line in out.stdout.splitlines() if line.strip()]


def run_gtsam(path, init):
    """Same-machine gtsam LM run (settings of reference.json); None if gtsam is missing."""
    try:
        import gtsam
    except ImportError:
        return None
    graph, initial = gtsam.readG2o(str(path), True)
    prior = gtsam.noiseModel.Diagonal.Sigmas([1e-6] * 6)
    graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0), prior))
    start = time.perf_counter()
    if init == "chordal":
        initial = gtsam.InitializePose3.initialize(graph)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(1000)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimizer.optimize()
    seconds = time.perf_counter() - start
    # Cost over the between factors only (the prior is the gauge, excluded as in reference).
    cost = graph.error(result) - graph.at(graph.size() - 1).error(result)
    return {"final_cost": cost, "iterations": optimizer.iterations(), "time_s": seconds}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", help="data folder holding posegraph/")
    parser.add_argument("datasets", nargs="*", default=DEFAULT)
    args = parser.parse_args()
    folder = data_dir(args.data) / "posegraph"
    reference = json.loads((folder / "reference.json").read_text())["datasets"]
    files = [folder / f"{name}.g2o" for name in args.datasets]
    missing = [str(f) for f in files if not f.exists()]
    if missing:
        sys.exit(f"missing data files: {missing} (set FERROSLAM_DATA or --data)")
    ours = run_ours(files)

    header = (f"{'dataset':<15} {'init':<8} {'ours cost':>18} {'gtsam cost':>18} {'rel diff':>9} "
              f"{'it':>4} {'gt it':>5} {'ours s':>8} {'gtsam s':>8} {'ratio':>6}  gtsam status")
    print(header)
    print("-" * len(header))
    same_machine = []
    for r in ours:
        ref = reference[r["name"]]["runs"].get(f"{r['init']}_LM", {})
        ours_s = r["init_s"] + r["solve_s"]
        # gtsam's chordal timing in reference.json excludes the initialisation; add it back.
        ref_s = ref.get("time_s", float("nan"))
        if r["init"] == "chordal":
            ref_s += reference[r["name"]].get("chordal_init_time_s", 0.0)
        ref_cost = ref.get("final_cost", float("nan"))
        # '*': our iteration limit (100) ran out before convergence.
        iterations = f"{r['iterations']}{'' if r['converged'] else '*'}"
        best = reference[r["name"]]["best_final_cost"]
        print(f"{r['name']:<15} {r['init']:<8} {r['final_cost']:>18.10f} {ref_cost:>18.10f} "
              f"{r['final_cost'] / best - 1:>9.1e} {iterations:>4} "
              f"{ref.get('iterations', 0):>5} {ours_s:>8.3f} {ref_s:>8.3f} "
              f"{ref_s / ours_s:>6.2f}  {ref.get('status', '-')}")
        live = run_gtsam(folder / f"{r['name']}.g2o", r["init"])
        if live:
            same_machine.append((r, live, ours_s))
    print("\nrel diff: our final cost relative to the best gtsam optimum of the dataset; "
          "ratio: gtsam time / ours (> 1: ours faster); times include the chordal "
          "initialisation where used; it*: stopped at our iteration limit. gtsam figures from reference.json (gtsam 4.3.0, "
          "another run on a 2-core VM: indicative).")
    if same_machine:
        print("\nSame-machine gtsam runs:")
        for r, live, ours_s in same_machine:
            print(f"{r['name']:<15} {r['init']:<8} gtsam cost {live['final_cost']:.10f} "
                  f"it {live['iterations']} time {live['time_s']:.3f} s, "
                  f"ratio {live['time_s'] / ours_s:.2f}")
    else:
        print("(gtsam is not importable here: no same-machine run)")


if __name__ == "__main__":
    main()
