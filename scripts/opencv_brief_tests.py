#!/usr/bin/env python3
"""Generator of ``crates/features/src/extractor/opencv_brief_tests.rs``: OpenCV's rotated-BRIEF
tests, read off the installed ``cv2.ORB``.

ORB's 256 binary tests (Rublee et al., ICCV 2011) were learned, not derived: each compares
the smoothed intensities at two offsets around the corner. Our vocabulary was trained on
OpenCV's ORB descriptors, so the Rust extractor must use OpenCV's tests in OpenCV's order
(its ``bit_pattern_31_``, in ``modules/features2d/src/orb.cpp``). The crate carries them as
data; this script is how that table was made, and ``tests/test_features.py`` runs
:func:`opencv_brief_tests` to check the committed table against the installed OpenCV.

:func:`opencv_brief_tests` describes unrotated corners on images that are flat but for one
bright (then one dark) pixel at a known offset. After ORB's smoothing that pixel is a blob
peaking at the offset, so a test's bit is set by a bright blob only near its second pixel,
and by a dark blob only near its first; the test is the pair of offsets that predicts every
bit seen.

Run from the repository root (rewrites the table; the diff should touch only its header)::

    python scripts/opencv_brief_tests.py
"""

from __future__ import annotations

import datetime
import re
import sys
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

_RADIUS = 18  # offsets probed, px: ORB's tests lie within 15 px of the centre, blobs 3 more
_SIDE = 2 * _RADIUS + 1
_CELL = 40  # one corner per cell: no blob comes within 3 px of another cell's tests


@lru_cache(maxsize=1)
def opencv_brief_tests() -> np.ndarray:
    """``(256, 4)`` int32 rows ``[x1, y1, x2, y2]`` (pixels, x right, y down): bit ``k`` of
    descriptor byte ``i`` is ``I(x1, y1) < I(x2, y2)`` of row ``8 i + k`` for a corner at
    angle 0, as ``cv2.ORB`` computes it (once per process).

    Raises:
        RuntimeError: the installed OpenCV's ORB does not behave as described above.
    """
    offsets = np.stack(np.meshgrid(np.arange(-_RADIUS, _RADIUS + 1),
                                   np.arange(-_RADIUS, _RADIUS + 1)), -1).reshape(-1, 2)
    cells = np.arange(len(offsets))
    centres = _CELL * np.stack([cells % _SIDE, cells // _SIDE], 1) + _CELL
    corners = [cv2.KeyPoint(float(x), float(y), 31.0, 0.0) for x, y in centres]
    orb = cv2.ORB_create(nfeatures=len(corners), nlevels=1, edgeThreshold=19, patchSize=31)

    def bits_with_blobs(background: int) -> np.ndarray:
        image = np.full(((_SIDE + 2) * _CELL,) * 2, background, np.uint8)
        image[centres[:, 1] + offsets[:, 1], centres[:, 0] + offsets[:, 0]] = 255 - background
        kept, descriptors = orb.compute(image, corners)
        if descriptors is None or len(kept) != len(corners):
            raise RuntimeError("cv2.ORB dropped probe corners: cannot read its BRIEF tests")
        return np.unpackbits(descriptors, axis=1, bitorder="little").astype(bool).T

    bright, dark = bits_with_blobs(0), bits_with_blobs(255)
    # The smoothed blob (one 255 pixel): response[e] at offset e from it, 0 beyond 3 px.
    spike = np.zeros((15, 15), np.uint8)
    spike[7, 7] = 255
    blob = cv2.sepFilter2D(spike, -1, cv2.getGaussianKernel(7, 2), cv2.getGaussianKernel(7, 2))

    def response(point: np.ndarray) -> np.ndarray:
        e = point - offsets + 7
        inside = np.all((e >= 0) & (e < 15), axis=1)
        out = np.zeros(len(offsets), int)
        out[inside] = blob[e[inside, 1], e[inside, 0]]
        return out

    def near_all(members: np.ndarray) -> np.ndarray:
        """The members within 3 px (both axes) of all others: where the test pixel may be."""
        spread = np.abs(members[:, None, :] - members[None, :, :]).max(-1)
        return members[np.all(spread <= 3, axis=1)]

    tests = []
    for i in range(256):
        seconds = [(q, response(q)) for q in near_all(offsets[bright[i]])]
        fits = [(p, q) for p in near_all(offsets[dark[i]]) for rp in [response(p)]
                for q, rq in seconds
                if np.array_equal(rp < rq, bright[i]) and np.array_equal(rp > rq, dark[i])]
        if len(fits) != 1:
            raise RuntimeError(f"cannot read cv2.ORB's BRIEF test {i}: {len(fits)} candidates")
        tests.append(np.concatenate(fits[0]))
    return np.array(tests, np.int32)


TABLE = Path(__file__).resolve().parents[1] / "crates/features/src/extractor/opencv_brief_tests.rs"

# One test a line: `    [x1, y1, x2, y2], // index`.
_ROW = re.compile(r"^\s*\[(-?\d+), (-?\d+), (-?\d+), (-?\d+)\], // (\d+)$", re.MULTILINE)


def read_table(path: Path = TABLE) -> np.ndarray:
    """The tests of the committed Rust table, ``(256, 4)`` int32 as :func:`opencv_brief_tests`.

    Raises:
        ValueError: the file does not hold 256 rows numbered 0..255.
    """
    rows = _ROW.findall(path.read_text(encoding="utf-8"))
    if [int(r[4]) for r in rows] != list(range(256)):
        raise ValueError(f"{path} does not hold 256 tests numbered 0..255")
    return np.array([r[:4] for r in rows], np.int32)


def render(tests: np.ndarray) -> str:
    """The Rust source of the table of ``tests`` (``(256, 4)``), with its provenance."""
    today = datetime.date.today().isoformat()
    rows = "\n".join(f"    [{x1}, {y1}, {x2}, {y2}], // {i}"
                     for i, (x1, y1, x2, y2) in enumerate(tests.tolist()))
    return f"""\
//! OpenCV's 256 rotated-BRIEF tests (`bit_pattern_31_` of OpenCV's
//! `modules/features2d/src/orb.cpp`, learned by Rublee et al., ICCV 2011), in OpenCV's order.
//!
//! Provenance: GENERATED by `scripts/opencv_brief_tests.py`, which reads the tests off
//! `cv2.ORB` (it does not copy OpenCV's source); read off OpenCV {cv2.__version__} on {today}.
//! `tests/test_features.py` checks this table against the installed OpenCV. Do not edit by
//! hand: rerun the script.
//!
//! Licence: the pattern is OpenCV's data, under OpenCV's licence; see `LICENSE-OpenCV` in this
//! folder (the BSD notice of `orb.cpp`; OpenCV 4.5 and later is distributed under Apache-2.0).

/// Rows `[x1, y1, x2, y2]` (pixels, x right, y down, within 13 px of the centre): bit `k` of
/// descriptor byte `i` is `I(x1, y1) < I(x2, y2)` of row `8 i + k`, for a corner at angle 0.
#[rustfmt::skip]
pub const OPENCV_BRIEF_TESTS: [[i8; 4]; 256] = [
{rows}
];
"""


def main() -> int:
    tests = opencv_brief_tests()
    TABLE.write_text(render(tests), encoding="utf-8")
    print(f"wrote {TABLE} ({len(tests)} tests, OpenCV {cv2.__version__})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
