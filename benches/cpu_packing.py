#!/usr/bin/env python3
"""Does this machine give a process that sleeps between frames all its cores?

Some virtual machines' hosts move the vCPUs of a guest that idles onto fewer physical cores
and spread them again only under sustained load. A SLAM front end that works for a few
milliseconds per frame and then waits for the next one meets the packed state, so its
threads share one core. This script times a fixed OpenCV workload (Gaussian blurs of a VGA
image) on one thread and split over two, back to back and after a sleep before each
repetition, without and with ``_orbslam3.cpus_kept_busy`` (one ``SCHED_IDLE`` busy loop per
CPU), and prints the speedup of two threads over one: about 1.8 on two real cores, about 1.0
when the cores are packed.

    python benches/cpu_packing.py [--repeats N]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _orbslam3 as orb  # noqa: E402

SLEEPS_S = (0.0, 0.002, 0.010, 0.033)


def speedup(sleep_s: float, repeats: int, second: ThreadPoolExecutor) -> tuple[float, float]:
    """Median ms of the workload twice on one thread, and of the two halves on two threads,
    each repetition after ``sleep_s`` of idling."""
    image = np.random.default_rng(0).integers(0, 256, (480, 640), dtype=np.uint8)

    def half() -> None:
        for _ in range(4):
            cv2.GaussianBlur(image, (7, 7), 2.0)

    serial, parallel = [], []
    for _ in range(repeats):
        time.sleep(sleep_s)
        t0 = time.perf_counter()
        half()
        half()
        serial.append(time.perf_counter() - t0)
        time.sleep(sleep_s)
        t0 = time.perf_counter()
        job = second.submit(half)
        half()
        job.result()
        parallel.append(time.perf_counter() - t0)
    return float(np.median(serial)) * 1e3, float(np.median(parallel)) * 1e3


def two_thread_speedups(repeats: int = 20) -> dict:
    """Speedup of two threads over one, back to back and after 10 ms of idling: the machine
    state a measurement ran in (``compare.py`` records it). Holds OpenCV's pool to one
    thread meanwhile."""
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with ThreadPoolExecutor(1) as second:
            out = {}
            for key, sleep_s in (("back_to_back", 0.0), ("after_10ms_idle", 0.010)):
                one, two = speedup(sleep_s, repeats, second)
                out[key] = one / two
            return out
    finally:
        cv2.setNumThreads(cv_threads)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=60)
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)  # the two threads are ours
    print(f"{'CPUs kept busy':<15} {'sleep ms':>8} {'1 thread ms':>11} {'2 threads ms':>12} "
          f"{'speedup':>7}")
    with ThreadPoolExecutor(1) as second:
        for busy in (False, True):
            with orb.cpus_kept_busy(busy):
                for sleep_s in SLEEPS_S:
                    one, two = speedup(sleep_s, args.repeats, second)
                    print(f"{'yes' if busy else 'no':<15} {sleep_s * 1e3:>8.0f} {one:>11.2f} "
                          f"{two:>12.2f} {one / two:>7.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
