"""Per-frame ORB extraction time, as the pipeline calls it (not a test).

Times ``ferroslam.features.OrbExtractor`` on real frames, back to back: ``detect`` on TUM
fr1/rpy (640 x 480, 1000 features) and ``detect_pair`` on KITTI 01 stereo pairs
(1241 x 376, 2000 features each, ORB-SLAM's setting for KITTI); then, for comparison with
the core's own pyramid and smoothing, OpenCV building the same pyramid
(``cv2.resize(..., INTER_LINEAR_EXACT)``) and smoothing its levels (``cv2.sepFilter2D``,
7 x 7 Gaussian of sigma 2) on the TUM frames. Prints the median over ``--passes`` passes
over the frames and the process CPU time per call (all threads, so also the time helper
threads spend waiting for work), in milliseconds: on a machine shared with other work the
wall-clock median moves with the load, the CPU time much less.

    python benches/extractor_time.py [--frames N] [--passes P]

Data from ``$FERROSLAM_DATA`` (``<repo>/../shared/data`` without the variable). Build the
native module in release mode first. To time another build, put its package first on
``PYTHONPATH`` (and set ``FERROSLAM_DATA``).
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

import ferroslam
from ferroslam._data import data_dir
from ferroslam.features import OrbExtractor


def _time_ms(call, inputs, passes: int) -> tuple[float, float]:
    """(median wall-clock ms, mean process CPU ms) per call."""
    call(*inputs[0])  # warm-up: thread pools, caches
    times = []
    cpu_start = time.process_time()
    for _ in range(passes):
        for args in inputs:
            start = time.perf_counter()
            call(*args)
            times.append((time.perf_counter() - start) * 1e3)
    cpu_ms = (time.process_time() - cpu_start) * 1e3 / len(times)
    return float(np.median(times)), cpu_ms


def _opencv_pyramid_and_smoothing(gray: np.ndarray, scale_factor: float = 1.2, levels: int = 8):
    kernel = cv2.getGaussianKernel(7, 2)
    pyramid = [gray]
    h, w = gray.shape
    for level in range(1, levels):
        scale = scale_factor**level
        size = (int(round(w / scale)), int(round(h / scale)))
        pyramid.append(cv2.resize(pyramid[-1], size, interpolation=cv2.INTER_LINEAR_EXACT))
    return [cv2.sepFilter2D(p, -1, kernel, kernel, borderType=cv2.BORDER_REFLECT_101)
            for p in pyramid]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=50, help="frames of each sequence")
    parser.add_argument("--passes", type=int, default=3, help="passes over the frames")
    args = parser.parse_args()

    data = data_dir()
    tum = sorted((data / "tum/rgbd_dataset_freiburg1_rpy/rgb").glob("*.jpg"))[: args.frames]
    kitti = data / "kitti/stereo_51_frames"
    pairs = sorted((kitti / "image_0").glob("*.png"))[: args.frames]
    tum_frames = [(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE),) for p in tum]
    kitti_pairs = [(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE),
                    cv2.imread(str(kitti / "image_1" / p.name), cv2.IMREAD_GRAYSCALE))
                   for p in pairs]

    print(f"ferroslam from {ferroslam.__file__}; OpenCV {cv2.__version__}, "
          f"{cv2.getNumThreads()} threads")
    tum_orb, kitti_orb = OrbExtractor(1000), OrbExtractor(2000)
    rows = [
        ("TUM 640x480 detect", _time_ms(tum_orb.detect, tum_frames, args.passes)),
        ("KITTI 1241x376 detect_pair",
         _time_ms(kitti_orb.detect_pair, kitti_pairs, args.passes)),
        ("TUM 640x480 OpenCV pyramid + smoothing",
         _time_ms(_opencv_pyramid_and_smoothing, tum_frames, args.passes)),
    ]
    for label, (wall_ms, cpu_ms) in rows:
        print(f"{label:<42} median {wall_ms:6.2f} ms   CPU {cpu_ms:6.2f} ms")


if __name__ == "__main__":
    main()
