"""KITTI odometry sequences (Geiger et al., CVPR 2012).

Layout of a sequence folder (``sequences/NN`` in the KITTI release):

* ``image_0/`` left and, for stereo, ``image_1/`` right grayscale images (``image_l/`` and
  ``image_r/`` are accepted too), already rectified, named ``NNNNNN.png`` (or ``.jpg``); the
  sorted file names of the left folder are the frames, the right folder has the same names.
* ``calib.txt``: lines ``P0: <12 numbers>`` .. ``P3:``, row-major 3x4 rectified projection
  matrices. ``P0`` gives the pinhole of ``image_0``; the baseline is
  ``(P0[0, 3] - P1[0, 3]) / P1[0, 0]`` metres (``-P1[0, 3] / fx`` since ``P0[0, 3] = 0``).
* ``times.txt``: one time per frame, seconds from the start of the sequence.
* Ground truth (optional), the first file found of ``poses.txt``, ``poses/<folder name>.txt``,
  the only ``.txt`` in ``poses/``, or ``../../poses/<folder name>.txt`` (KITTI release layout):
  one line per frame, the first three rows of ``T_w_c`` row-major, where ``c`` is camera 0 and
  the world frame is camera 0 at frame 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from .._validate import read_text
from ..camera import Camera
from ..io import read_kitti_poses, read_table
from .images import IMAGE_EXTENSIONS, read_gray

__all__ = ["KittiFrame", "KittiSequence", "read_kitti_calib"]

_LEFT_DIRS = ("image_0", "image_l")
_RIGHT_DIRS = ("image_1", "image_r")


@dataclass(frozen=True)
class KittiFrame:
    """One frame: left image and, for stereo, the right image of the same name."""

    index: int
    timestamp: float  # seconds from the start of the sequence
    left_path: Path
    right_path: Optional[Path]


def read_kitti_calib(path: Union[str, Path]) -> dict[str, np.ndarray]:
    """``{"P0": (3, 4), ...}`` from a KITTI ``calib.txt`` (every ``NAME: 12 numbers`` line).

    Raises ``FileNotFoundError`` naming a missing file and ``ValueError`` naming file and line
    for a line that is not 12 numbers.
    """
    path = Path(path)
    out = {}
    text = read_text(path, "KITTI calibration file")
    for number, line in enumerate(text.splitlines(), start=1):
        name, sep, values = line.partition(":")
        if not sep:
            continue
        try:
            P = np.array([float(v) for v in values.split()])
        except ValueError:
            raise ValueError(f"{path}:{number}: {name.strip()} is not 12 numbers") from None
        if P.size != 12 or not np.all(np.isfinite(P)):
            raise ValueError(f"{path}:{number}: {name.strip()} must be 12 finite numbers")
        out[name.strip()] = P.reshape(3, 4)
    return out


def _read_times(path: Path) -> np.ndarray:
    rows = read_table(path, 1, "KITTI times file")
    times = np.empty(len(rows))
    for r, (number, fields) in enumerate(rows):
        try:
            times[r] = float(fields[0])
        except ValueError:
            times[r] = np.nan
        if not np.isfinite(times[r]):
            raise ValueError(f"{path}:{number}: bad time {fields[0]!r}")
        if r and times[r] <= times[r - 1]:
            raise ValueError(
                f"{path}:{number}: times out of order ({times[r]} after {times[r - 1]})"
            )
    return times


def _first_dir(root: Path, names: tuple[str, ...]) -> Optional[Path]:
    return next((root / n for n in names if (root / n).is_dir()), None)


class KittiSequence:
    """A KITTI odometry sequence folder (see the module doc for the layout).

    Args:
        path: sequence folder.
        stereo: use the right images; ``None`` means stereo if ``image_1/`` (or ``image_r/``)
            exists. Needs a ``P1`` line in ``calib.txt``.

    Attributes:
        camera: pinhole of ``image_0`` from ``P0`` (``dist`` zeros: KITTI images are
            rectified), size of the first left image.
        is_stereo, baseline_m (metres, ``None`` if mono), timestamps (seconds, increasing).

    Raises:
        FileNotFoundError: missing folder, ``calib.txt``, ``times.txt``, image folder.
        ValueError: missing ``P0``/``P1`` line, image count differs from the times count, a
            missing right image, left and right image sizes differ, times out of order.
    """

    def __init__(self, path: Union[str, Path], *, stereo: Optional[bool] = None) -> None:
        self.path = Path(path).expanduser().resolve()
        if not self.path.is_dir():
            raise FileNotFoundError(f"KITTI sequence folder not found: {self.path}")
        left_dir = _first_dir(self.path, _LEFT_DIRS)
        if left_dir is None:
            raise FileNotFoundError(f"no image_0/ (or image_l/) folder in {self.path}")
        right_dir = _first_dir(self.path, _RIGHT_DIRS)
        self.is_stereo = right_dir is not None if stereo is None else bool(stereo)
        if self.is_stereo and right_dir is None:
            raise FileNotFoundError(f"stereo=True but no image_1/ (or image_r/) in {self.path}")

        calib_path = self.path / "calib.txt"
        calib = read_kitti_calib(calib_path)
        for key in ("P0", "P1") if self.is_stereo else ("P0",):
            if key not in calib:
                raise ValueError(f"{calib_path}: no {key} line")
        P0 = calib["P0"]
        self.baseline_m: Optional[float] = None
        if self.is_stereo:
            P1 = calib["P1"]
            self.baseline_m = float((P0[0, 3] - P1[0, 3]) / P1[0, 0])
            if not self.baseline_m > 0:
                raise ValueError(f"{calib_path}: P1 gives a non-positive baseline "
                                 f"{self.baseline_m} m")

        lefts = sorted(p for p in left_dir.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)
        times_path = self.path / "times.txt"
        times = _read_times(times_path)
        if len(lefts) != times.size:
            raise ValueError(
                f"{left_dir} has {len(lefts)} images but {times_path} has {times.size} times"
            )
        rights: list[Optional[Path]] = [None] * len(lefts)
        if self.is_stereo:
            assert right_dir is not None
            rights = [right_dir / p.name for p in lefts]
            missing = [p.name for p in rights if not p.is_file()]
            if missing:
                raise ValueError(f"{len(missing)} right images missing in {right_dir}, "
                                 f"first {missing[0]}")
        self.frames = [
            KittiFrame(k, float(t), left, right)
            for k, (t, left, right) in enumerate(zip(times.tolist(), lefts, rights))
        ]
        self.timestamps = times
        if not self.frames:
            raise ValueError(f"no .png/.jpg images in {left_dir}")
        height, width = read_gray(lefts[0]).shape
        self.camera = Camera(P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2], np.zeros(5), width, height)
        if self.is_stereo:
            self.load_stereo(0)  # fail now, not mid-run, if the right size differs

    @property
    def name(self) -> str:
        """Folder name, e.g. ``06`` or ``stereo_51_frames``."""
        return self.path.name

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> KittiFrame:
        return self.frames[i]

    def __iter__(self) -> Iterator[KittiFrame]:
        return iter(self.frames)

    def __repr__(self) -> str:
        return f"KittiSequence({str(self.path)!r}, frames={len(self)}, stereo={self.is_stereo})"

    def _read(self, path: Path) -> np.ndarray:
        image = read_gray(path)
        if image.shape != (self.camera.height, self.camera.width):
            raise ValueError(
                f"{path} is {image.shape[1]}x{image.shape[0]}, expected "
                f"{self.camera.width}x{self.camera.height} (size of the first left image)"
            )
        return image

    def load_gray(self, i: int) -> np.ndarray:
        """Left image of frame ``i``: ``(H, W)`` uint8."""
        return self._read(self.frames[i].left_path)

    def load_stereo(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Rectified ``(left, right)`` images of frame ``i``, both ``(H, W)`` uint8.

        Raises ``ValueError`` if the sequence is mono or the sizes differ.
        """
        right = self.frames[i].right_path
        if right is None:
            raise ValueError(f"{self.path} was opened as a mono sequence")
        return self.load_gray(i), self._read(right)

    @property
    def groundtruth_path(self) -> Optional[Path]:
        """The pose file (see the module doc), or ``None`` if there is none."""
        candidates = [self.path / "poses.txt", self.path / "poses" / f"{self.name}.txt"]
        in_folder = sorted((self.path / "poses").glob("*.txt"))
        if len(in_folder) == 1:
            candidates.append(in_folder[0])
        candidates.append(self.path.parent.parent / "poses" / f"{self.name}.txt")
        return next((p for p in candidates if p.is_file()), None)

    @property
    def has_groundtruth(self) -> bool:
        return self.groundtruth_path is not None

    def groundtruth(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth ``(timestamps (N,), T_w_c (N, 4, 4))`` of camera 0, one pose per frame.

        Raises ``FileNotFoundError`` without a pose file and ``ValueError`` if its line count
        differs from the frame count.
        """
        path = self.groundtruth_path
        if path is None:
            raise FileNotFoundError(
                f"no KITTI pose file (poses.txt or poses/*.txt) for {self.path}"
            )
        poses = read_kitti_poses(path).poses
        if len(poses) != len(self):
            raise ValueError(
                f"{path} has {len(poses)} poses but the sequence has {len(self)} frames"
            )
        return self.timestamps.copy(), poses
