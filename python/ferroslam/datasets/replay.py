"""A sequence replayed forwards, backwards, forwards, ...: one long run that keeps revisiting
the same places (long-run scaling of time and memory per frame)."""

from __future__ import annotations

import numpy as np


def replay_order(n: int, passes: int) -> np.ndarray:
    """Frame indices of ``passes`` passes over ``n`` frames, alternately forwards and
    backwards; the frame at a turn is not repeated (``n + (passes - 1) * (n - 1)`` in all)."""
    order = [np.arange(n)]
    for p in range(1, passes):
        order.append(np.arange(n - 2, -1, -1) if p % 2 else np.arange(1, n))
    return np.concatenate(order)


class ReplayedSequence:
    """The first ``max_frames`` frames (default all) of ``seq`` replayed ``passes`` times (see
    :func:`replay_order`), stamped one median frame interval apart from the first timestamp so
    that time keeps increasing. Offers ``len()``, ``name``, ``camera``, ``timestamps``,
    ``order`` (the source frame of each replayed frame), ``load_gray`` and, when ``seq`` has
    it, ``load_depth``."""

    def __init__(self, seq, passes: int, max_frames: int | None = None):
        n = min(len(seq), max_frames or len(seq))
        self.seq, self.camera = seq, seq.camera
        self.name = f"{seq.name} x{passes}"
        self.order = replay_order(n, passes)
        dt = float(np.median(np.diff(seq.timestamps[:n])))
        self.timestamps = float(seq.timestamps[0]) + dt * np.arange(len(self.order))

    def __len__(self) -> int:
        return len(self.order)

    def load_gray(self, i: int) -> np.ndarray:
        return self.seq.load_gray(self.order[i])

    def load_depth(self, i: int) -> np.ndarray:
        return self.seq.load_depth(self.order[i])
