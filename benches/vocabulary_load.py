#!/usr/bin/env python3
"""Vocabulary size and load time: the shipped binary vocabulary (or FILE) and its DBoW2 text.

Prints file size, words, and the load time (median / min / max over --repeat fresh loads) of
the compact binary format, and, with --text, of its DBoW2 text export (ORBvoc.txt format,
written to a temporary file), plus one cold-process load of ``default_vocabulary()`` that
includes importing ferroslam. The claim checked: the shipped vocabulary loads "well under a
second" (exit status 1 if the binary median exceeds --budget seconds).

Usage: python benches/vocabulary_load.py [FILE] [--repeat 20] [--text] [--budget 1.0]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ferroslam.vocabulary import DEFAULT_VOCABULARY_PATH, Vocabulary


def timed_loads(load, path: Path, repeat: int) -> list[float]:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        load(path)
        times.append(time.perf_counter() - t)
    return times


def report(label: str, path: Path, times: list[float]) -> None:
    size = path.stat().st_size
    print(f"{label:<12} {size / 2**20:8.2f} MiB  median {1e3 * statistics.median(times):8.1f} ms"
          f"  min {1e3 * min(times):8.1f} ms  max {1e3 * max(times):8.1f} ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", nargs="?", type=Path, default=DEFAULT_VOCABULARY_PATH)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--text", action="store_true", help="also time the DBoW2 text format")
    ap.add_argument("--budget", type=float, default=1.0, help="seconds (default: 1.0)")
    args = ap.parse_args(argv)

    voc = Vocabulary.load(args.file)
    print(f"{args.file}: {voc!r}")
    binary = timed_loads(Vocabulary.load, args.file, args.repeat)
    report("binary", args.file, binary)
    if args.text:
        with tempfile.TemporaryDirectory() as tmp:
            text_path = Path(tmp) / "voc.txt"
            voc.save_dbow2_text(text_path)
            report("dbow2 text", text_path,
                   timed_loads(Vocabulary.load_dbow2_text, text_path, max(1, args.repeat // 4)))
    if args.file == DEFAULT_VOCABULARY_PATH:
        code = ("import time; t = time.perf_counter(); "
                "from ferroslam.vocabulary import default_vocabulary; t1 = time.perf_counter(); "
                "default_vocabulary(); t2 = time.perf_counter(); "
                "print(f'{1e3 * (t1 - t):.1f} {1e3 * (t2 - t1):.1f}')")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True).stdout.split()
        print(f"cold process: import ferroslam.vocabulary {out[0]} ms, "
              f"default_vocabulary() {out[1]} ms")
    median = statistics.median(binary)
    if median > args.budget:
        print(f"binary load median {median:.3f} s exceeds the budget {args.budget} s")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
