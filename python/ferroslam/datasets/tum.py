"""TUM RGB-D benchmark sequences (Sturm et al., IROS 2012).

Layout: ``<seq>/rgb.txt``, ``<seq>/depth.txt`` (``timestamp path`` lines) and optionally
``<seq>/groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``, ``T_w_c`` of the RGB optical
centre in the motion-capture frame). RGB frames are paired with depth frames like TUM's
``associate.py``: candidate pairs with ``|t_rgb - t_depth| < max_diff`` (0.02 s), taken
greedily by increasing time difference, each frame used at most once.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from ..calibration import load_calibration
from ..camera import Camera
from ..io import read_table, read_tum_trajectory
from .images import read_depth, read_gray, read_gray_and_color

__all__ = ["TUM_CAMERAS", "TumFrame", "TumSequence", "associate_greedy"]

# Intrinsics from the TUM benchmark page (ROS default for the IR camera aside); 640x480.
TUM_CAMERAS = {
    1: Camera(517.3, 516.5, 318.6, 255.3, np.array([0.2624, -0.9531, -0.0054, 0.0026, 1.1633])),
    2: Camera(520.9, 521.0, 325.1, 249.7, np.array([0.2312, -0.7849, -0.0033, -0.0001, 0.9172])),
    3: Camera(535.4, 539.2, 320.1, 247.6, np.zeros(5)),
}

# Depth pixel value per metre of every TUM sequence.
TUM_DEPTH_FACTOR = 5000.0

_FREIBURG = re.compile(r"(?:freiburg|(?<![a-z])fr)([123])(?![0-9])", re.IGNORECASE)


@dataclass(frozen=True)
class TumFrame:
    """One RGB frame paired with its depth frame (paths are absolute)."""

    index: int
    timestamp: float  # of the RGB image, seconds
    rgb_path: Path
    depth_path: Optional[Path]
    depth_timestamp: Optional[float]


def associate_greedy(
    t_first: np.ndarray, t_second: np.ndarray, max_diff: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairing of two sorted timestamp lists like TUM's ``associate.py``.

    All pairs with ``|a - b| < max_diff`` are sorted by difference and taken greedily while
    neither frame is used yet. Returns index arrays sorted by the first list.
    """
    t_first = np.asarray(t_first, dtype=np.float64)
    t_second = np.asarray(t_second, dtype=np.float64)
    lo = np.searchsorted(t_second, t_first - max_diff, side="left")
    hi = np.searchsorted(t_second, t_first + max_diff, side="right")
    counts = hi - lo
    i = np.repeat(np.arange(t_first.size), counts)
    j = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)) + np.repeat(
        lo, counts
    )
    diff = np.abs(t_first[i] - t_second[j])
    keep = diff < max_diff
    i, j, diff = i[keep], j[keep], diff[keep]
    order = np.lexsort((t_second[j], t_first[i], diff))
    used_i = np.zeros(t_first.size, dtype=bool)
    used_j = np.zeros(t_second.size, dtype=bool)
    pairs = []
    for a, b in zip(i[order].tolist(), j[order].tolist()):  # few candidates per frame
        if not used_i[a] and not used_j[b]:
            used_i[a] = used_j[b] = True
            pairs.append((a, b))
    pairs.sort()
    out = np.array(pairs, dtype=np.intp).reshape(-1, 2)
    return out[:, 0], out[:, 1]


# Unix time in seconds stays below 1e11 until the year 5138; TUM lists give seconds, so a
# larger stamp is nanoseconds (or microseconds) and would pair nothing.
_MAX_SECONDS = 1e11


def _read_list(path: Path, what: str) -> tuple[np.ndarray, list[str]]:
    rows = read_table(path, 2, what)
    if not rows:
        raise ValueError(f"{path}: {what} lists no frames")
    stamps = np.empty(len(rows))
    for r, (number, fields) in enumerate(rows):
        try:
            stamps[r] = float(fields[0])
        except ValueError:
            raise ValueError(f"{path}:{number}: bad timestamp {fields[0]!r}") from None
        if not np.isfinite(stamps[r]):
            raise ValueError(f"{path}:{number}: bad timestamp {fields[0]!r}")
        if abs(stamps[r]) >= _MAX_SECONDS:
            raise ValueError(f"{path}:{number}: timestamp {fields[0]} looks like nanoseconds; "
                             "TUM lists give seconds")
        if r and stamps[r] <= stamps[r - 1]:
            raise ValueError(
                f"{path}:{number}: timestamps out of order ({stamps[r]} after {stamps[r - 1]})"
            )
    return stamps, [fields[1] for _, fields in rows]


class TumSequence:
    """A TUM RGB-D sequence folder.

    Args:
        path: sequence folder (with ``rgb.txt`` and, if ``with_depth``, ``depth.txt``).
        camera: explicit intrinsics; otherwise ``<path>/camera.yaml`` if present, otherwise
            the freiburg camera named in the folder name (``freiburg1``/``fr1`` ... ``fr3``),
            so a folder of any name reads with ``camera`` given.
        with_depth: require ``depth.txt`` and pair every RGB frame with a depth frame
            (frames without a depth partner are dropped, as in ``associate.py``).
        max_diff: pairing tolerance in seconds.
        depth_factor: depth pixel value per metre; otherwise the depth factor of
            ``<path>/camera.yaml`` (``depth_scale``, ``DepthMapFactor``) when ``camera`` is not
            given and the file has one, else TUM's 5000.

    Raises:
        FileNotFoundError: the folder or a list file is missing (message names it).
        ValueError: malformed or out-of-order list lines, unknown camera.
    """

    def __init__(
        self,
        path: Union[str, Path],
        camera: Optional[Camera] = None,
        *,
        with_depth: bool = True,
        max_diff: float = 0.02,
        depth_factor: Optional[float] = None,
    ) -> None:
        self.path = Path(path).expanduser().resolve()
        if not self.path.is_dir():
            raise FileNotFoundError(f"TUM sequence folder not found: {self.path}")
        file_factor = None
        if camera is None:
            camera, file_factor = self._find_camera()
        if depth_factor is None:
            depth_factor = file_factor if file_factor is not None else TUM_DEPTH_FACTOR
        if not (np.isfinite(depth_factor) and depth_factor > 0):
            raise ValueError(f"depth_factor must be a positive number, got {depth_factor}")
        self.depth_factor = float(depth_factor)
        self.camera = camera
        t_rgb, rgb_files = _read_list(self.path / "rgb.txt", "TUM rgb list")
        if with_depth:
            t_depth, depth_files = _read_list(self.path / "depth.txt", "TUM depth list")
            i_rgb, i_depth = associate_greedy(t_rgb, t_depth, max_diff)
            self.frames = [
                TumFrame(k, float(t_rgb[a]), self.path / rgb_files[a],
                         self.path / depth_files[b], float(t_depth[b]))
                for k, (a, b) in enumerate(zip(i_rgb.tolist(), i_depth.tolist()))
            ]
            if not self.frames:
                raise ValueError(
                    f"{self.path}: no RGB frame has a depth frame within {max_diff} s (rgb.txt "
                    f"{t_rgb[0]:.3f}..{t_rgb[-1]:.3f} s, depth.txt {t_depth[0]:.3f}.."
                    f"{t_depth[-1]:.3f} s)")
        else:
            self.frames = [
                TumFrame(k, float(t), self.path / f, None, None)
                for k, (t, f) in enumerate(zip(t_rgb.tolist(), rgb_files))
            ]
        self.timestamps = np.array([f.timestamp for f in self.frames], dtype=np.float64)

    def _find_camera(self) -> tuple[Camera, Optional[float]]:
        """The camera and, from a ``camera.yaml``, its depth factor (``None`` if none)."""
        yaml = self.path / "camera.yaml"
        if yaml.is_file():
            calibration = load_calibration(yaml)
            return calibration.cameras[0], calibration.depth_factor
        match = _FREIBURG.search(self.path.name)
        if match is None:
            raise ValueError(
                f"cannot tell the camera of {self.path}: the folder name names no freiburg "
                "camera (fr1/fr2/fr3); add a camera.yaml or pass camera=Camera(...) (command "
                "line: --camera FILE)"
            )
        return TUM_CAMERAS[int(match.group(1))], None

    @property
    def name(self) -> str:
        """Folder name, e.g. ``rgbd_dataset_freiburg1_rpy``."""
        return self.path.name

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> TumFrame:
        return self.frames[i]

    def __iter__(self) -> Iterator[TumFrame]:
        return iter(self.frames)

    def __repr__(self) -> str:
        return f"TumSequence({str(self.path)!r}, frames={len(self)})"

    def load_gray(self, i: int) -> np.ndarray:
        """Grayscale image of frame ``i``: ``(H, W)`` uint8."""
        return read_gray(self.frames[i].rgb_path)

    def load_gray_and_color(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i`` in grey (as :meth:`load_gray`) and in colour, ``(H, W, 3)`` uint8 BGR
        (OpenCV's order), from one read of the file."""
        return read_gray_and_color(self.frames[i].rgb_path)

    def load_depth(self, i: int) -> np.ndarray:
        """Depth of frame ``i``: ``(H, W)`` float32 metres, 0 where there is no measurement."""
        frame = self.frames[i]
        if frame.depth_path is None:
            raise ValueError(f"{self.path} was opened with with_depth=False")
        return read_depth(frame.depth_path, self.depth_factor)

    @property
    def groundtruth_path(self) -> Path:
        return self.path / "groundtruth.txt"

    @property
    def has_groundtruth(self) -> bool:
        return self.groundtruth_path.is_file()

    def groundtruth(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth ``(timestamps (M,), T_w_c (M, 4, 4))``.

        Raises ``FileNotFoundError`` if ``groundtruth.txt`` is missing.
        """
        traj = read_tum_trajectory(self.groundtruth_path)
        return traj.timestamps, traj.poses
