"""Frames from a video file, a folder of images or a live camera.

Each source is an iterable of ``(timestamp_s, image)`` pairs (``image``: BGR ``(H, W, 3)`` or
grey ``(H, W)`` uint8), to feed the vSLAM objects (``MonoVSlam.track_source``), and has
``.live`` (True for cameras: frames come at the camera's pace whether or not they are
tracked). The finite ones, :class:`VideoSource` and :class:`ImageFolderSource`, are also
sequences for :func:`ferroslam.pipeline.run_sequence` (``len``, ``load_gray(i)``,
``load_gray_and_color(i)``, ``timestamps``, ``camera``, ``name``, ``has_groundtruth = False``). None carries a
calibration: give it as ``camera=`` (e.g. ``ferroslam.load_calibration(path).cameras[0]``).

ROS bags (``.bag``, ROS 2 folders, ``.mcap``) are recordings of whole rigs: :func:`open_bag`
(from :mod:`ferroslam.bags`) opens one as a sequence, with its stereo pairs, depth and IMU.

:class:`CameraSource` and :class:`VideoSource` read through the same code (``cv2.VideoCapture``
of a device index or of a path), so a camera's timestamps and decoding are what a video's are.
"""

from __future__ import annotations

import itertools
import math
import re
import threading
from pathlib import Path
from typing import Any, Iterable, Iterator, Optional, Union

import cv2
import numpy as np

from ._files import regular_file
from .bags import BagSequence, open_bag
from .camera import Camera
from .datasets.images import IMAGE_EXTENSIONS, read_gray, read_gray_and_color

__all__ = ["BagSequence", "CameraSource", "ImageFolderSource", "LatestFrameReader",
           "VideoSource", "open_bag", "open_source"]

Frame = tuple[float, np.ndarray]
"""``(timestamp_s, image)``: seconds, BGR or grey uint8."""

# A numeric file name above this is nanoseconds (EuRoC's 1403636579763555584.png): 1e12 s
# is 31,700 years, while 1e12 ns is 17 minutes after 1970, before any recording.
_NANOSECOND_NAMES = 1e12
_CAMERA_SPEC = re.compile(r"camera:(\d+)")


class _Source:
    """What every source has: a name (the output folder's), ``live``, no ground truth, and the
    calibration given to it (``camera``)."""

    live = False
    has_groundtruth = False

    def __init__(self, name: str, camera: Optional[Camera]) -> None:
        self.name = name
        self.camera = camera

    @property
    def camera(self) -> Camera:
        """The intrinsics of the images; ``ValueError`` when none was given, since videos,
        folders and cameras carry none."""
        if self._camera is None:
            raise ValueError(f"{self.name}: no calibration: pass camera=... (command line: "
                             "--camera FILE)")
        return self._camera

    @camera.setter
    def camera(self, camera: Optional[Camera]) -> None:
        if camera is not None and not isinstance(camera, Camera):
            raise TypeError(f"camera must be a ferroslam.Camera, got {type(camera).__name__}")
        self._camera = camera


def _next_time_s(stream_s: float, previous_s: Optional[float], fps: float, what: str) -> float:
    """A frame's time: the stream's (``CAP_PROP_POS_MSEC``) while it increases, else the
    previous frame's plus one frame period (streams without times report 0 for every frame;
    this then gives ``index / fps``)."""
    if previous_s is None:
        return stream_s if math.isfinite(stream_s) and stream_s >= 0 else 0.0
    if math.isfinite(stream_s) and stream_s > previous_s:
        return stream_s
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"{what}: the stream gives neither frame times nor a frame rate")
    return previous_s + 1.0 / fps


def _frame_times_s(capture: Any, what: str) -> Iterator[float]:
    """Grabs frame after frame (releasing the capture at the end), yielding each frame's time
    in seconds; ``capture.retrieve()`` decodes the frame just grabbed. Grabbing alone skips
    the decoding, so counting a video's frames is cheap."""
    fps = float(capture.get(cv2.CAP_PROP_FPS))
    previous_s = None
    try:
        while capture.grab():
            previous_s = _next_time_s(capture.get(cv2.CAP_PROP_POS_MSEC) / 1e3, previous_s,
                                      fps, what)
            yield previous_s
    finally:
        capture.release()


def _retrieve(capture: Any, what: str) -> np.ndarray:
    ok, image = capture.retrieve()
    if not ok or image is None:
        raise ValueError(f"{what}: a frame could not be decoded")
    return image


class _CaptureSource(_Source):
    """Frames of ``cv2.VideoCapture(target)``: a path for a video file, an index for a
    camera."""

    def __init__(self, target: Union[str, int], name: str, camera: Optional[Camera]) -> None:
        super().__init__(name, camera)
        self._target = target

    def _open(self) -> Any:
        capture = cv2.VideoCapture(self._target)
        if not capture.isOpened():
            raise ValueError(f"{self.name}: OpenCV cannot open {self._target!r} (not a video "
                             "its FFmpeg reads, or no such camera)")
        return capture

    def __iter__(self) -> Iterator[Frame]:
        capture = self._open()
        for t_s in _frame_times_s(capture, self.name):
            yield t_s, _retrieve(capture, self.name)


class VideoSource(_CaptureSource):
    """The frames of a video file (any format OpenCV's FFmpeg reads), BGR, with the stream's
    timestamps (``CAP_PROP_POS_MSEC``, the first frame's usually 0), or ``index / fps`` where
    the stream has none. Counting the frames (``len``, ``timestamps``) reads the file once
    without decoding.

    Raises ``FileNotFoundError`` for a missing file; ``ValueError`` when OpenCV cannot open it
    (on first use) or it holds no frames.
    """

    def __init__(self, path: Union[str, Path], *, camera: Optional[Camera] = None) -> None:
        path = regular_file(Path(path).expanduser(), "video file")
        super().__init__(str(path), path.stem, camera)
        self._timestamps: Optional[np.ndarray] = None
        self._reader: Optional[tuple[Any, Iterator[float]]] = None
        self._next = 0

    @property
    def timestamps(self) -> np.ndarray:
        """Every frame's time, float64 seconds, increasing."""
        if self._timestamps is None:
            times = list(_frame_times_s(self._open(), self.name))
            if not times:
                raise ValueError(f"{self._target}: no frames (empty, or a codec OpenCV cannot "
                                 "read)")
            self._timestamps = np.asarray(times, dtype=np.float64)
        return self._timestamps

    def __len__(self) -> int:
        return len(self.timestamps)

    def load_gray(self, i: int) -> np.ndarray:
        """Frame ``i`` in grey, ``(H, W)`` uint8 (see :meth:`load_gray_and_color`)."""
        return self.load_gray_and_color(i)[0]

    def load_gray_and_color(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i`` in grey ``(H, W)`` and as decoded, ``(H, W, 3)`` BGR, uint8. Read in
        order (as ``run_sequence`` does) each frame is decoded once; any other order reopens
        the file and skips to the frame, since seeking is not frame-exact in every codec."""
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} of a {len(self)}-frame video")
        if self._reader is None or i < self._next:
            capture = self._open()
            self._reader, self._next = (capture, _frame_times_s(capture, self.name)), 0
        capture, times = self._reader
        for _ in itertools.islice(times, i - self._next + 1):
            pass
        self._next = i + 1
        color = _retrieve(capture, self.name)
        return cv2.cvtColor(color, cv2.COLOR_BGR2GRAY), color


class CameraSource(_CaptureSource):
    """A live camera, ``cv2.VideoCapture(index)`` (``index`` as OpenCV numbers the devices:
    ``/dev/video<index>`` on Linux), BGR frames with the driver's timestamps. Endless and
    ``live``: feed it to ``MonoVSlam.track_source``, which drops the frames that arrive while
    tracking is busy."""

    live = True

    def __init__(self, index: int, *, camera: Optional[Camera] = None) -> None:
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise ValueError(f"camera index must be an integer >= 0, got {index!r}")
        super().__init__(index, f"camera{index}", camera)


def _name_time_s(stem: str) -> Optional[float]:
    """The time a numeric file name gives, seconds (``1305031102.175304``) or nanoseconds
    (``1403636579763555584``); ``None`` for other names."""
    try:
        value = float(stem)
    except ValueError:
        return None
    if not math.isfinite(value) or value < 0:
        return None
    return value * 1e-9 if value > _NANOSECOND_NAMES else value


class ImageFolderSource(_Source):
    """The images (.png, .jpg, .jpeg) of a folder, in grey. Numeric names are taken in
    numeric order and give the frame times (seconds, or nanoseconds above 1e12) unless ``fps``
    is given; other names are taken in name order and need ``fps`` (frame ``i`` at ``i /
    fps`` seconds).

    Raises ``FileNotFoundError`` for a missing folder; ``ValueError`` for a folder without
    images, names that are not times without ``fps``, or times that repeat.
    """

    def __init__(self, path: Union[str, Path], fps: Optional[float] = None, *,
                 camera: Optional[Camera] = None) -> None:
        path = Path(path).expanduser()
        if not path.is_dir():
            raise FileNotFoundError(f"image folder not found: {path}")
        super().__init__(path.name, camera)
        files = [p for p in path.iterdir()
                 if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
        if not files:
            raise ValueError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in {path}")
        named = {p: t for p in files if (t := _name_time_s(p.stem)) is not None}
        numeric = len(named) == len(files)
        self.paths = sorted(files, key=named.__getitem__) if numeric else sorted(files)
        if fps is not None:
            if not (math.isfinite(fps) and fps > 0):
                raise ValueError(f"fps must be a positive number of frames per second, got "
                                 f"{fps!r}")
            self.timestamps = np.arange(len(files), dtype=np.float64) / float(fps)
        elif numeric:
            self.timestamps = np.array([named[p] for p in self.paths], dtype=np.float64)
            _check_increasing(self.timestamps, self.paths)
        else:
            example = next(p.name for p in self.paths if p not in named)
            raise ValueError(f"{path}: the image names ({example}, ...) are not times in "
                             "seconds or nanoseconds: give the frame rate, fps=... "
                             "(command line: --fps)")

    def __len__(self) -> int:
        return len(self.paths)

    def load_gray(self, i: int) -> np.ndarray:
        """Image ``i`` in grey, ``(H, W)`` uint8."""
        return read_gray(self.paths[i])

    def load_gray_and_color(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Image ``i`` in grey (as :meth:`load_gray`) and in colour, ``(H, W, 3)`` uint8 BGR,
        from one read of the file."""
        return read_gray_and_color(self.paths[i])

    def __iter__(self) -> Iterator[Frame]:
        for i, t_s in enumerate(self.timestamps):
            yield float(t_s), self.load_gray(i)


def _check_increasing(timestamps: np.ndarray, paths: list[Path]) -> None:
    """Two names for one time (``1.png``, ``1.0.png``) would give the tracker a frame that is
    not after the previous one."""
    same = np.flatnonzero(np.diff(timestamps) <= 0)
    if same.size:
        i = int(same[0])
        raise ValueError(f"{paths[i].name} and {paths[i + 1].name} name the same time; "
                         "remove one or give fps=... (command line: --fps)")


def open_source(spec: Union[str, Path, int], *, fps: Optional[float] = None,
                camera: Optional[Camera] = None) -> Union[VideoSource, ImageFolderSource,
                                                           CameraSource]:
    """The source ``spec`` names: ``"camera:N"`` (or the int ``N``) a live camera, a folder
    an :class:`ImageFolderSource` (with ``fps``), a file a :class:`VideoSource`.

    Raises ``FileNotFoundError`` when ``spec`` names nothing, ``ValueError`` for ``fps`` with
    a video or camera (their frames carry times).
    """
    match = _CAMERA_SPEC.fullmatch(str(spec))
    path = None if isinstance(spec, int) or match else Path(spec).expanduser()
    if path is not None and path.is_dir():
        return ImageFolderSource(path, fps, camera=camera)
    if path is not None and not path.is_file():
        raise FileNotFoundError(f"no video file or image folder at {spec} (or camera:N for "
                                "camera N)")
    if fps is not None:
        raise ValueError(f"{spec}: fps is for image folders; a video's or camera's frames "
                         "carry their times")
    if path is None:
        return CameraSource(int(match.group(1)) if match else int(str(spec)), camera=camera)
    return VideoSource(path, camera=camera)


class LatestFrameReader:
    """Reads ``frames`` in a background thread and keeps only the newest frame not yet taken:
    a consumer slower than the frames arrive always gets the newest, and the older ones are
    skipped (counted), as a live camera's frames must be, since waiting for each would make
    the lag grow without bound (OpenCV's capture buffer fills with stale frames otherwise).
    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, frames: Iterable[Frame]) -> None:
        self._changed = threading.Condition()
        self._frame: Optional[Frame] = None
        self._skipped = 0
        self._ended = False
        self._stop = False
        self._error: Optional[BaseException] = None
        self._thread = threading.Thread(target=self._read, args=(frames,), daemon=True,
                                        name="ferroslam-source")
        self._thread.start()

    def _read(self, frames: Iterable[Frame]) -> None:
        iterator = iter(frames)
        try:
            for frame in iterator:
                with self._changed:
                    if self._stop:
                        break
                    self._skipped += self._frame is not None
                    self._frame = frame
                    self._changed.notify()
        except BaseException as err:  # noqa: BLE001 - raised again in the consumer's take()
            self._error = err
        finally:
            getattr(iterator, "close", lambda: None)()  # releases a capture
            with self._changed:
                self._ended = True
                self._changed.notify()

    def take(self) -> tuple[Optional[Frame], int]:
        """Blocks until a frame not taken yet is there; returns it (``None`` at the end of
        the frames) and how many frames were skipped since the previous call. An error
        reading the frames is raised here."""
        with self._changed:
            self._changed.wait_for(lambda: self._frame is not None or self._ended)
            frame, self._frame = self._frame, None
            skipped, self._skipped = self._skipped, 0
        if frame is None and self._error is not None:
            raise self._error
        return frame, skipped

    def close(self) -> int:
        """Stops reading (after the frame being read) and returns the frames read but never
        taken."""
        with self._changed:
            self._stop = True
        self._thread.join()
        left = self._skipped + (self._frame is not None)
        self._frame, self._skipped = None, 0
        return left

    def __enter__(self) -> "LatestFrameReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
