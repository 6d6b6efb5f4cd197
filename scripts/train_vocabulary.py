#!/usr/bin/env python3
"""Train a ferroslam ORB vocabulary (crates/vocabulary) from images.

Extracts ORB descriptors with ``ferroslam.features.OrbExtractor`` (1000 per image by default),
writes them as a descriptor pack (per image: u32 LE count, then count x 32 bytes) in a
temporary directory, and runs ``cargo run --release -p ferroslam-vocabulary --example train``.

IMAGES are image files or directories (every .png/.jpg inside, sorted); ``--step N`` keeps
every N-th image of each directory. ``--eval`` takes a directory of consecutive frames and
reports how often frame i scores higher against i + 2 than against i + 150; with
``--min-fraction`` the script fails below that fraction.

Example (the vocabulary used for the figures in the crate's report; it trains on KITTI 06
and EuRoC V1_01 frames, and is evaluated on TUM fr1/rpy, which it never saw):

    . /work/venv/bin/activate
    python scripts/train_vocabulary.py \\
        ../shared/data/kitti/odometry_06_first51/image_0 \\
        ../shared/data/euroc/V1_01_easy_micro/mav0/cam0/data \\
        --k 10 --levels 4 --out /tmp/voc.bin \\
        --eval ../shared/data/tum/rgbd_dataset_freiburg1_rpy/rgb --min-fraction 0.8
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ferroslam.features import OrbExtractor
from ferroslam.vocabulary import image_paths

def write_pack(images: list[Path], extractor: OrbExtractor, path: Path) -> int:
    """Write the descriptor pack of `images`; returns the number of descriptors."""
    total = 0
    with open(path, "wb") as f:
        for image in images:
            gray = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
            if gray is None:
                raise ValueError(f"cannot read image {image}")
            _, descriptors = extractor.detect(gray)
            descriptors = np.ascontiguousarray(descriptors, dtype=np.uint8).reshape(-1, 32)
            f.write(np.uint32(len(descriptors)).astype("<u4").tobytes())
            f.write(descriptors.tobytes())
            total += len(descriptors)
    return total


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("images", nargs="+", help="image files or directories")
    ap.add_argument("--k", type=int, default=10, help="branching factor (default 10)")
    ap.add_argument("--levels", type=int, default=5, help="tree depth L (default 5)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--step", type=int, default=1, help="keep every N-th image of a directory")
    ap.add_argument("--features", type=int, default=1000, help="ORB features per image")
    ap.add_argument("--out", required=True, help="binary vocabulary to write")
    ap.add_argument("--text", help="also write DBoW2 text (ORBvoc.txt format) here")
    ap.add_argument("--eval", help="directory of consecutive frames for the near/far check")
    ap.add_argument("--min-fraction", type=float, help="fail if the near/far fraction is below")
    args = ap.parse_args(argv)

    extractor = OrbExtractor(n_features=args.features)
    repo = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory() as tmp:
        train_images = image_paths(args.images, args.step)
        pack = Path(tmp) / "train.desc"
        n = write_pack(train_images, extractor, pack)
        print(f"extracted {n} descriptors from {len(train_images)} images")
        cmd = ["cargo", "run", "--quiet", "--release", "-p", "ferroslam-vocabulary", "--example", "train", "--",
               str(pack), args.out, "--k", str(args.k), "--levels", str(args.levels), "--seed", str(args.seed)]
        if args.text:
            cmd += ["--text", args.text]
        if args.eval:
            eval_pack = Path(tmp) / "eval.desc"
            write_pack(image_paths([args.eval]), extractor, eval_pack)
            cmd += ["--eval", str(eval_pack)]
        result = subprocess.run(cmd, cwd=repo, capture_output=True, text=True)
        sys.stdout.write(result.stdout)
        sys.stderr.write(result.stderr)
        if result.returncode != 0:
            return result.returncode
    if args.min_fraction is not None and args.eval:
        line = next(l for l in result.stdout.splitlines() if l.startswith("near_far_fraction "))
        fraction = float(line.split()[1])
        if fraction < args.min_fraction:
            print(f"near/far fraction {fraction} below {args.min_fraction}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
