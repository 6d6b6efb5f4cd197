"""Visual SLAM objects with MATLAB's ``monovslam`` / ``stereovslam`` / ``rgbdvslam`` workflow.

Create one per camera, feed it images with ``add_frame``, look at the map when
``has_new_keyframe()`` says so, and stop when ``check_status()`` reports tracking lost::

    with RGBDVSlam(camera, depth_scale_factor=5000) as vslam:
        for color, depth in frames:
            vslam.add_frame(color, depth)
            if vslam.has_new_keyframe():
                vslam.plot(path="map.png")
            if vslam.check_status() is TrackingStatus.LOST:
                break
        ids, poses = vslam.poses()

ORB features are extracted in Python (OpenCV) in the caller's thread; by default tracking
and local mapping run in a Rust background thread fed through a bounded queue, so
``add_frame`` returns as soon as the frame is queued and the next image's features are
extracted while the core works (the GIL is released). Frames are processed in order, so the
results equal the synchronous mode's (``threaded=False``: each ``add_frame`` finishes its
frame). ``check_status``, ``has_new_keyframe`` and the map reflect the frames processed so
far; ``is_done()`` says whether all added frames are.

Live sources (a camera, ``ferroslam.sources.CameraSource``) bring frames at their own pace:
``MonoVSlam.track_source`` then keeps only the newest frame while the core is busy and drops
the older ones (``dropped_frames``), so the lag stays bounded instead of growing with a
queue. ``on_frame`` is called with a :class:`FrameResult` (pose, state, latency) as each
frame's result comes in, and ``current_pose()`` gives the latest pose.
"""

from __future__ import annotations

import collections
import enum
import itertools
import math
import numbers
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Optional, Sequence, TextIO, Union

import numpy as np

from .camera import Camera
from .features import check_mask
from .calibration import ImuParams
from .keyframe_images import KeyframeImages
from .options import check_option, core_default, validate_options
from .rig import Rig, rig_images
from .session import IMU_KEYS, Session
from .stereo import StereoRectifier

__all__ = ["FrameResult", "MonoVSlam", "RGBDVSlam", "RigVSlam", "StereoVSlam", "TrackingStatus"]

# Live feeding: a new frame is taken from the source once at most this many added frames are
# still unprocessed, so the next frame's features are extracted while the core tracks the
# previous one, and a frame waits behind at most one other.
_LIVE_FRAMES_IN_FLIGHT = 1
# How often a live feed looks whether the core has caught up, seconds (a frame takes tens of
# milliseconds to track).
_LIVE_POLL_S = 0.001


class TrackingStatus(enum.Enum):
    """What ``check_status()`` reports about the last frame (MATLAB ``checkStatus``)."""

    NOT_INITIALIZED = "not_initialized"
    """No map yet (monocular: waiting for two views with enough parallax)."""
    LOST = "lost"
    """Fewer tracked points than the lower ``track_feature_range`` limit (``TrackingLost``);
    with an aligned IMU the pose is then the IMU's prediction for up to 5 s."""
    SUCCESSFUL = "successful"
    """Tracked points within ``track_feature_range`` (``TrackingSuccessful``)."""
    FREQUENT_KEYFRAMES = "frequent_keyframes"
    """More tracked points than the upper limit: keyframes come too often for so slow a
    camera; raise ``skip_max_frames`` (``FrequentKeyFrames``)."""


@dataclass(frozen=True)
class FrameResult:
    """One processed frame, as ``on_frame`` receives it.

    ``index``: the frame's number among those added (dropped frames are never added);
    ``timestamp_s``: its time; ``latency_ms``: from the ``add_frame`` call to its result
    taken in (feature extraction, waiting in the queue, tracking), what a live user sees;
    ``track``: the core's ``TrackResult`` (``state``, ``T_w_c`` (4, 4) float64 or ``None``,
    ``num_tracked``, ``is_keyframe``, ``tracking_ms``, ``mapping_ms``, ``init_reason``).
    """

    index: int
    timestamp_s: float
    latency_ms: float
    track: Any


def _pose_text(T: np.ndarray) -> str:
    """The 3x4 part of a pose, one line."""
    return np.array2string(T[:3].ravel(), precision=6, max_line_width=400)


def _flag(name: str, value: Any) -> bool:
    """``value`` if it is a bool: ``"no"`` or ``0`` for ``False`` is a mistake to report, not
    to take as true."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _check_camera(intrinsics: Any) -> None:
    if not isinstance(intrinsics, Camera):
        raise TypeError(f"intrinsics must be a ferroslam.Camera, got {type(intrinsics).__name__}")


def _length(value: Any) -> str:
    """``"of N items"`` for a sized value, else ``""`` (for messages)."""
    return f"of {len(value)} items" if hasattr(value, "__len__") else ""


def _positive_int(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be a positive integer, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _positive_real(name: str, value: Any, unit: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a positive number of {unit}, got {value!r}")
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number of {unit}, got {value!r}")
    return float(value)


class _VSlam:
    """Shared workflow of the three sensor objects (use one of them).

    ``threaded`` (default True): tracking and mapping in a background thread; False processes
    each frame inside ``add_frame``.

    Keyword options (MATLAB property names in brackets; left out, the core's defaults for the
    sensor and image width, ``ferroslam._core.default_options``, apply; each default and
    range is in ``docs/options.md``): ``scale_factor`` (ScaleFactor), ``num_levels``
    (NumLevels), ``max_num_points`` (MaxNumPoints: the budget follows the image width),
    ``track_feature_range`` (TrackFeatureRange; wider for RGB-D than MATLAB's, where keyframes
    made at 100 tracked points left poses centimetres off), ``skip_max_frames``
    (SkipMaxFrames), ``loop_closure_threshold`` (LoopClosureThreshold: matched points a loop
    needs; ``loop_closure=False`` turns loop closing off), ``vocabulary`` (the bag of words
    used to relocalise and detect loops: ``"default"`` ships with the package; a file path or
    a ``ferroslam._core.Vocabulary``; ``None`` for none; CustomBagOfFeatures), ``verbose``
    (Verbose: 1 prints stages and loop closures, 2 also logs every frame, the initial map and
    each loop closure's data to a file in the temporary folder, 3 adds each new keyframe's
    pose before local BA and the keyframe poses after it), ``frame_rate_hz`` (timestamps when
    none are given), ``seed``, ``on_frame`` (called with each frame's :class:`FrameResult`
    as results are taken in, in the caller's thread; also settable as an attribute; an
    exception it raises comes out of the call that took the result in). With an IMU: ``imu``
    (noise parameters), ``camera_to_imu_transform``, ``num_poses_threshold``,
    ``alignment_fraction`` and ``imu_time_offset_s`` (the IMU clock's offset, ``t_imu = t_cam
    + imu_time_offset_s``, as Kalibr's ``timeshift_cam_imu``).
    """

    _sensor = ""
    # An unrectified pair's (right camera, T_left_right) and the further cameras
    # (camera, T_c0_c, depth), for the core (RigVSlam, see Rig.observers).
    _pair: Optional[tuple[Camera, np.ndarray]] = None
    _observers: tuple = ()

    def __init__(
        self,
        intrinsics: Camera,
        *,
        scale_factor: Optional[float] = None,
        num_levels: Optional[int] = None,
        max_num_points: Optional[int] = None,
        track_feature_range: Optional[Sequence[int]] = None,
        skip_max_frames: Optional[int] = None,
        loop_closure_threshold: Optional[int] = None,
        loop_closure: Optional[bool] = None,
        frame_rate_hz: float = 30.0,
        threaded: bool = True,
        vocabulary: Any = "default",
        verbose: int = 0,
        seed: Optional[int] = None,
        imu: Any = None,
        camera_to_imu_transform: Optional[np.ndarray] = None,
        num_poses_threshold: Optional[int] = None,
        alignment_fraction: Optional[float] = None,
        imu_time_offset_s: Optional[float] = None,
        core_options: Optional[dict] = None,
        on_frame: Optional[Callable[[FrameResult], Any]] = None,
    ) -> None:
        _check_camera(intrinsics)
        if verbose not in (0, 1, 2, 3):
            raise ValueError(f"verbose must be 0, 1, 2 or 3, got {verbose!r}")
        self.intrinsics = intrinsics
        self.frame_rate_hz = _positive_real("frame_rate_hz", frame_rate_hz, "Hz")
        self.verbose = verbose
        # MATLAB's names for the core's options; those not given are left to the core.
        given = {"scale_factor": scale_factor, "num_levels": num_levels,
                 "max_num_points": max_num_points, "skip_max_frames": skip_max_frames,
                 "loop_closure_threshold": loop_closure_threshold,
                 "track_feature_range": track_feature_range,
                 "num_poses_threshold": num_poses_threshold,
                 "alignment_fraction": alignment_fraction,
                 "imu_time_offset_s": imu_time_offset_s, "loop_closure": loop_closure,
                 "seed": seed}
        options = validate_options(
            {"threaded": threaded,
             **{k: v for k, v in given.items() if v is not None}, **(core_options or {})},
            self._sensor, imu is not None, scopes=("core", "imu", "object"))
        imu_options = {k: options.pop(k) for k in IMU_KEYS if k in options}
        self.imu = None if imu is None else ImuParams.of(imu)
        self._imu_period_s = 0.0 if imu is None else 1.0 / self.imu.rate_hz
        self._imu_time_offset_s = imu_options.get(
            "imu_time_offset_s", core_default("imu_time_offset_s", self._sensor))
        self._session = Session(
            intrinsics, self._sensor, options, vocabulary=vocabulary, imu=self.imu,
            T_b_c=camera_to_imu_transform, imu_options=imu_options, pair=self._pair,
            observers=self._observers)
        self._system = self._session.system
        options = self._system.options
        self.scale_factor: float = options["scale_factor"]
        self.num_levels: int = options["n_levels"]
        self.max_num_points: int = options["n_features"]
        self.skip_max_frames: int = options["skip_max_frames"]
        self.loop_closure_threshold: int = options["loop_closure_threshold"]
        self.track_feature_range: tuple[int, int] = self._system.track_feature_range
        self.on_frame = on_frame
        self._frames = 0
        self._processed = 0
        self._dropped = 0
        self._draining = False
        # (timestamp_s, add_frame call time, pixels to keep if it becomes a keyframe) of the
        # frames added but not yet processed, oldest first: results come in the order frames
        # were added.
        self._in_flight: collections.deque[tuple[float, float, Any]] = collections.deque()
        # The keyframes' images, for the outputs that need pixels (RGBDVSlam.dense_mesh).
        self._keyframe_images: Optional[KeyframeImages] = None
        self._last_timestamp: Optional[float] = None
        self._last = None
        self._new_keyframe = False
        self._loops_seen = 0
        self._closed = False
        self._log: Optional[TextIO] = None
        self.log_path: Optional[Path] = None
        if verbose >= 2:
            handle = tempfile.NamedTemporaryFile(
                "w", prefix=f"ferroslam-{self._sensor}-", suffix=".log", delete=False,
                encoding="utf-8")
            self._log, self.log_path = handle, Path(handle.name)
            print(f"ferroslam: log file {self.log_path}")

    # -- feeding frames -------------------------------------------------------------------
    def _timestamp(self, timestamp: Optional[float]) -> float:
        if timestamp is None:
            timestamp = self._frames / self.frame_rate_hz
            if self._last_timestamp is not None and timestamp <= self._last_timestamp:
                timestamp = self._last_timestamp + 1.0 / self.frame_rate_hz
        return float(timestamp)

    def _track(self, started_s: float, timestamp: Optional[float], frame: dict,
               imu: Optional[Sequence[np.ndarray]] = None, pixels: Any = None) -> None:
        """Hands a frame (``Session.track``'s arguments) to the core; ``started_s``:
        ``time.perf_counter()`` at the ``add_frame`` call (for the latency); ``pixels``:
        ``(image, depth_m)`` kept if the frame becomes a keyframe."""
        if self._closed:
            raise RuntimeError(f"this {type(self).__name__} is closed")
        t = self._timestamp(timestamp)
        if not math.isfinite(t):
            raise ValueError(f"timestamp must be a finite number of seconds, got {timestamp!r}")
        if self._last_timestamp is not None and t <= self._last_timestamp:
            # Checked here too, before the IMU batch is stored: a retry with the right
            # timestamp and the same batch must be accepted.
            raise ValueError(f"timestamp {t} s is not after the previous frame's "
                             f"{self._last_timestamp} s")
        if imu is not None:
            self._system.add_imu(*self._imu_batch(imu, t))
        result = self._session.track(t, **frame)  # None when queued (threaded)
        self._last_timestamp = t
        self._frames += 1
        self._in_flight.append((t, started_s, pixels))
        if result is not None:
            self._absorb(result)
        self._drain()

    def _imu_batch(self, imu: Any, frame_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``(t, gyro, accel)`` float64 arrays of a frame's IMU batch, checked against the
        frame time: samples more than an IMU period after it (half a period more for clock
        jitter) belong to later frames, and taken now they would be integrated as this one's
        (the core refuses the later frames' samples then)."""
        if self.imu is None:
            raise ValueError("IMU samples given but this object has no IMU: pass imu=... "
                             "and camera_to_imu_transform=... when creating it")
        if not isinstance(imu, (tuple, list)) or len(imu) != 3:
            raise ValueError("imu must be (timestamps (M,), gyro (M, 3) rad/s, accel (M, 3) "
                             f"m/s^2), got {type(imu).__name__} {_length(imu)}")
        stamps, gyro, accel = (np.asarray(a, dtype=np.float64) for a in imu)
        if stamps.size and stamps.max() - self._imu_time_offset_s > (
                frame_s + 1.5 * self._imu_period_s):
            raise ValueError(
                f"imu: a sample at {stamps.max()} s (IMU clock) is "
                f"{stamps.max() - self._imu_time_offset_s - frame_s:.3f} s after the frame at "
                f"{frame_s} s: pass the samples up to the frame (and at most the one after it, "
                f"within an IMU period, {self._imu_period_s:.4f} s); check imu_time_offset_s")
        return stamps, gyro, accel

    def _drain(self) -> None:
        """Takes in the results of the frames the background thread has processed. Not
        again from inside ``on_frame``: the callback sees the object as of its frame
        (``current_pose()`` is that frame's), and the later results follow in order."""
        if self._draining:
            return
        self._draining = True
        try:
            for result in self._system.take_results():
                self._absorb(result)
        finally:
            self._draining = False

    def _absorb(self, result: Any) -> None:
        previous = self._last.state if self._last is not None else "not_initialized"
        timestamp_s, started_s, pixels = self._in_flight.popleft()
        if result.is_keyframe and pixels is not None and self._keyframe_images is not None:
            self._keyframe_images.add(timestamp_s, *pixels)
        self._last = result
        self._processed += 1
        self._new_keyframe |= bool(result.is_keyframe)
        self._report(previous, result)
        if self.on_frame is not None:
            self.on_frame(FrameResult(self._processed - 1, timestamp_s,
                                      (time.perf_counter() - started_s) * 1e3, result))

    def _report(self, previous: str, result: Any) -> None:
        if self.verbose == 0:
            return
        frame = self._processed - 1
        initialised = previous == "not_initialized" and result.state == "ok"
        events = []
        if initialised:
            events.append("map initialised")
        elif previous == "ok" and result.state == "lost":
            events.append("tracking lost")
        elif previous == "ok" and result.state == "recently_lost":
            events.append("tracking lost, pose from the IMU")
        elif previous in ("lost", "recently_lost") and result.state == "ok":
            events.append("relocalised" if previous == "lost" else "tracking resumed")
        if result.is_keyframe:
            events.append(f"new keyframe ({self._system.num_keyframes} in the map)")
        loops = self._new_loops() if result.is_keyframe else []
        events.extend(f"loop closed between keyframes {lp['current']} and {lp['matched']}"
                      for lp in loops)
        for event in events:
            print(f"ferroslam: frame {frame}: {event}")
        if self._log is None:
            return
        reason = getattr(result, "init_reason", None)
        ms = result.tracking_ms + result.mapping_ms
        self._log.write(f"frame {frame} state={result.state} tracked={result.num_tracked} "
                        f"keyframe={result.is_keyframe} core_ms={ms:.2f}"
                        + (f" init: {reason}" if reason else "") + "\n")
        if initialised:
            self._log.write(f"  initial map: {self._system.num_keyframes} keyframes, "
                            f"{self._system.num_map_points} map points\n")
        for lp in loops:
            self._log.write(f"  loop closure {lp}\n")
        if self.verbose >= 3 and result.is_keyframe:
            if result.T_w_c is not None:
                self._log.write(f"  new keyframe T_w_c before local BA "
                                f"{_pose_text(result.T_w_c)}\n")
            ids, poses = self.poses()
            for i, T in zip(ids.tolist(), poses):
                self._log.write(f"  keyframe {i} T_w_c after local BA {_pose_text(T)}\n")
        self._log.flush()

    def _new_loops(self) -> list:
        """Loops closed since the last call (only looked up when verbose)."""
        loops = self._system.loops()
        new, self._loops_seen = loops[self._loops_seen:], len(loops)
        return new

    # -- what MATLAB users call -----------------------------------------------------------
    def has_new_keyframe(self) -> bool:
        """Whether a keyframe was added since the previous call (MATLAB ``hasNewKeyFrame``)."""
        self._drain()
        new, self._new_keyframe = self._new_keyframe, False
        return new

    def check_status(self) -> TrackingStatus:
        """Tracking outcome of the last processed frame (MATLAB ``checkStatus``)."""
        self._drain()
        if self._last is None or self._last.state == "not_initialized":
            return TrackingStatus.NOT_INITIALIZED
        if self._last.state in ("lost", "recently_lost"):
            return TrackingStatus.LOST
        if self._last.num_tracked > self.track_feature_range[1]:
            return TrackingStatus.FREQUENT_KEYFRAMES
        return TrackingStatus.SUCCESSFUL

    def current_pose(self) -> tuple[Optional[np.ndarray], TrackingStatus]:
        """``(T_w_c, status)`` of the latest processed frame: its ``(4, 4)`` float64 camera
        pose in the world (``None`` when it was not tracked, or before any frame) and
        :meth:`check_status`. Cheap: for showing the pose live."""
        status = self.check_status()  # takes in the processed results first
        pose = None if self._last is None else self._last.T_w_c
        return (None if pose is None else np.array(pose, dtype=np.float64)), status

    def is_done(self) -> bool:
        """Whether every added frame has been processed (MATLAB ``isDone``)."""
        return bool(self._system.is_done())

    def wait(self) -> None:
        """Blocks until every added frame has been processed."""
        self._system.wait()
        self._drain()

    def _wait_for_core(self, in_flight: int) -> None:
        """Blocks until at most ``in_flight`` added frames are unprocessed (polling: the
        core's ``wait`` also waits for mapping, which would hold a live feed back)."""
        while self._frames - self.num_processed > in_flight:
            time.sleep(_LIVE_POLL_S)

    @property
    def num_frames(self) -> int:
        """Frames added so far."""
        return self._frames

    @property
    def num_processed(self) -> int:
        """Frames the core has processed so far."""
        self._drain()
        return self._processed

    @property
    def dropped_frames(self) -> int:
        """Frames of a live source never added because tracking was behind (see
        ``MonoVSlam.track_source``); every frame read is either added or dropped."""
        return self._dropped

    def map_points(self, map_id: Optional[int] = None) -> np.ndarray:
        """World positions of the map points of map ``map_id`` (default the current map),
        ``(M, 3)`` float64 (metres, or map units monocular)."""
        return np.asarray(self._system.map_points(map_id), dtype=np.float64).reshape(-1, 3)

    def maps(self) -> list[dict]:
        """Every map of the run (the atlas's and the current one): dicts ``id``, ``frames``,
        ``keyframes``, ``points``, ``current`` (see ``ferroslam._core.SlamSystem.maps``)."""
        return self._system.maps()

    @property
    def current_map_id(self) -> int:
        """Id of the map tracking runs in."""
        return self._system.current_map_id

    def merges(self) -> list[dict]:
        """Maps merged so far (see ``ferroslam._core.TrackResult.merge``)."""
        return self._system.merges()

    def map_point_colors(self, map_id: Optional[int] = None) -> np.ndarray:
        """Colours of the map points of map ``map_id`` (default the current map), ``(M, 3)``
        uint8 RGB in the order of :meth:`map_points`: each the pixel of the image the point
        was first seen in (grey images give grey)."""
        return np.asarray(self._system.map_point_colors(map_id), dtype=np.uint8).reshape(-1, 3)

    def inertial_alignment(self) -> Optional[dict]:
        """The camera-IMU alignment (``None`` without an IMU): status ``"waiting"``,
        ``"failed"`` (with the reason) or ``"aligned"`` with scale, gravity and biases (see
        ``ferroslam._core.SlamSystem.inertial_alignment``)."""
        return self._system.inertial_alignment()

    def poses(self, map_id: Optional[int] = None) -> tuple[np.ndarray, np.ndarray]:
        """``(keyframe ids (K,), T_w_c (K, 4, 4))`` of the keyframes of map ``map_id``
        (default the current map; MATLAB ``poses``)."""
        ids, _, poses = self._system.keyframe_trajectory(map_id)
        return np.asarray(ids), np.asarray(poses).reshape(-1, 4, 4)

    def frame_trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(timestamps (N,), T_w_c (N, 4, 4), map id (N,))`` of every tracked frame, each
        in its map's world (see ``maps``)."""
        stamps, poses = self._system.frame_trajectory()
        return (np.asarray(stamps), np.asarray(poses).reshape(-1, 4, 4),
                np.asarray(self._system.frame_map_ids()))

    def plot(self, ax: Any = None, *, path: Optional[Union[str, Path]] = None) -> Any:
        """3-D plot of the map points and the keyframe trajectory (MATLAB ``plot``); returns
        the matplotlib 3-D axes, saving the figure to ``path`` if given."""
        from .plot import plot_map

        return plot_map(self.map_points(), self.poses()[1], ax, path=path)

    def reset(self) -> None:
        """Discards the map and the trajectory (after the queued frames); the next frame
        starts a new one."""
        self._system.reset()
        self._drain()  # the queued frames were processed before the reset: count them
        self._last = None
        self._new_keyframe = False

    # -- maps -----------------------------------------------------------------------------
    def save_map(self, path: Union[str, Path]) -> None:
        """Writes every map (the whole atlas; versioned binary records with checksums) through
        :func:`ferroslam._files.atomic_output`: complete or not at all; a symlink at ``path``
        is replaced, not followed; a FIFO or device is refused with ``ValueError``, a folder
        with ``IsADirectoryError``."""
        from ._files import atomic_output

        with atomic_output(path) as tmp:
            self._system.save_map(tmp)

    def load_map(self, path: Union[str, Path], *, localization_only: bool = True) -> None:
        """Loads saved maps (the whole atlas of a ``save_map``; the last one becomes current,
        the map tracked until now is kept); the next frames relocalise in it. With
        ``localization_only`` (default) the map is used as it is, never extended; without,
        the object maps onward from it (a later session).

        Raises ``FileNotFoundError`` for a missing file, ``IsADirectoryError`` for a folder
        and ``ValueError`` for a FIFO or device (refused before opening: reading it would
        block) or a corrupt, truncated or incompatible file (the object is unchanged then).
        """
        from ._files import regular_file

        self._system.load_map(regular_file(path, "map file"))
        # An empty map has nothing to localise in: the next frames start one.
        self._system.localization_only = (_flag("localization_only", localization_only)
                                          and self._system.num_keyframes > 0)
        self._last = None

    @property
    def localization_only(self) -> bool:
        """Track against the map without adding keyframes."""
        return bool(self._system.localization_only)

    @localization_only.setter
    def localization_only(self, on: bool) -> None:
        self._system.localization_only = check_option("localization_only", on)

    # -- lifetime -------------------------------------------------------------------------
    def close(self) -> None:
        """Finishes the queued frames, stops and joins every thread the object started
        (tracking and mapping), releases the log file; ``add_frame`` raises afterwards, the
        map and poses stay readable. Idempotent."""
        if not self._closed:
            self.wait()
            self._system.close()
        self._closed = True
        if self._log is not None:
            self._log.close()
            self._log = None

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = self._last.state if self._last is not None else "not_initialized"
        return (f"{type(self).__name__}(frames={self._frames}, state={state!r}, "
                f"keyframes={self._system.num_keyframes}, points={self._system.num_map_points})")


class MonoVSlam(_VSlam):
    """Monocular visual SLAM (MATLAB ``monovslam``): the map starts from two views and its
    scale is arbitrary. Keyword options as :class:`_VSlam`'s ``__init__``."""

    _sensor = "mono"

    def add_frame(self, image: np.ndarray, timestamp: Optional[float] = None,
                  imu: Optional[Sequence[np.ndarray]] = None, *,
                  mask: Optional[np.ndarray] = None) -> None:
        """Adds a grey ``(H, W)`` or BGR ``(H, W, 3)`` uint8 image (raw, distorted: the
        intrinsics' distortion is applied to the keypoints). ``timestamp`` in seconds defaults
        to the frame count divided by ``frame_rate_hz``. ``imu``: the IMU samples since the previous
        frame, ``(timestamps (M,), gyro (M, 3) rad/s, accel (M, 3) m/s^2)``: those up to this
        frame's time and, if there, the first one after it (at most one IMU period later: the
        frame is then interpolated, not extrapolated). ``mask``: this frame's ``(H, W)`` uint8 or
        bool mask, 0 = no keypoint there (on top of the camera's static mask)."""
        started_s = time.perf_counter()
        self.intrinsics.check_image(image)
        self._track(started_s, timestamp, {"images": image, "mask": mask}, imu=imu)

    def track_source(self, source: Iterable[tuple[float, np.ndarray]], *,
                     drop_frames: Optional[bool] = None,
                     max_frames: Optional[int] = None) -> None:
        """Adds the ``(timestamp_s, image)`` frames of ``source`` (e.g. a
        ``ferroslam.sources`` source) until it ends or ``max_frames`` were read; returns
        before the last frames are processed (``wait()``).

        ``drop_frames`` (default: ``source.live``, True for cameras, never for files): a
        thread reads the source and keeps only the newest frame; it is added once the core
        has caught up (at most one frame still being tracked), and the older ones are dropped
        and counted in ``dropped_frames``. So with a camera faster than tracking, each
        tracked frame is the newest there is and the lag stays bounded. Without it every
        frame is added in turn (``add_frame`` waits when the core's queue is full).
        """
        live = bool(getattr(source, "live", False))
        frames = itertools.islice(source, None if max_frames is None
                                  else _positive_int("max_frames", max_frames))
        if not _flag("drop_frames", live if drop_frames is None else drop_frames):
            for timestamp_s, image in frames:
                self.add_frame(image, timestamp_s)
            return
        from .sources import LatestFrameReader

        reader = LatestFrameReader(frames)
        try:
            while True:
                self._wait_for_core(_LIVE_FRAMES_IN_FLIGHT)
                frame, skipped = reader.take()
                self._dropped += skipped
                if frame is None:
                    return
                timestamp_s, image = frame
                self.add_frame(image, timestamp_s)
        finally:
            self._dropped += reader.close()


class RigVSlam(_VSlam):
    """Visual SLAM on a camera rig (:class:`ferroslam.rig.Rig`): one frame per instant, one
    image per camera, through the core's one door. Camera 0 is tracked as its sensor's (one
    camera: :class:`MonoVSlam`; with depth: RGB-D; a stereo rig, cameras 0 and 1 with
    ``stereo=True``, from its RAW images: the core matches camera 0's keypoints into camera 1
    along epipolar curves, each camera with its own model and distortion, no rectification,
    and the scale is metric from the rig's extrinsics). Every further camera, overlapping or
    not, with or without depth, adds its keypoints to the same frame: matched against the
    map, in every pose and bundle adjustment, triangulated against the other keyframes'
    cameras. Poses are camera 0's ``T_w_c``. With ``imu=``, camera 0's pose in the IMU frame
    defaults to ``rig.T_body_cam[0]`` (the body frame is the IMU's).

    Keyword options as :class:`_VSlam`'s ``__init__`` (a stereo rig takes its baseline from
    its extrinsics).

    Raises:
        TypeError: ``rig`` is not a :class:`~ferroslam.rig.Rig`.
        ValueError: a rig the core cannot track (further cameras beside a monocular first
            camera), naming it; options as the other objects.
    """

    def __init__(self, rig: Rig, **options: Any) -> None:
        if not isinstance(rig, Rig):
            raise TypeError(f"rig must be a ferroslam.rig.Rig, got {type(rig).__name__}")
        self._sensor = rig.tracked_sensor()
        self.rig = rig
        if self._sensor == "stereo":
            self._pair = (rig.cameras[1], rig.T_left_right)
        self._observers = tuple(rig.observers())
        if options.get("imu") is not None and options.get("camera_to_imu_transform") is None:
            options["camera_to_imu_transform"] = rig.camera_to_imu()
        super().__init__(rig.cameras[0], **options)

    def add_frame(self, images: Union[Sequence[np.ndarray], np.ndarray],
                  timestamp: Optional[float] = None,
                  imu: Optional[Sequence[np.ndarray]] = None, *,
                  mask: Union[None, np.ndarray, Sequence[Optional[np.ndarray]]] = None,
                  depth: Optional[Sequence[Optional[np.ndarray]]] = None) -> None:
        """Adds one instant of the rig: one raw grey or BGR uint8 image per camera, in the
        rig's order (a single array for a rig of one camera). ``timestamp`` and ``imu`` as
        :meth:`MonoVSlam.add_frame`; ``mask``: this frame's mask per camera (a sequence with
        ``None`` where a camera has none; a single array for a rig of one camera), 0 = no
        keypoint there, on top of each camera's static mask; ``depth``: per camera its
        registered depth image in metres (float), ``None`` for the cameras without depth
        (``rig.depth``)."""
        started_s = time.perf_counter()
        frame = rig_images(self.rig, images)
        if isinstance(mask, np.ndarray) and len(frame) > 1:
            raise ValueError(f"mask: a rig of {len(frame)} cameras takes one mask per camera "
                             "(a sequence, None where a camera has none), not one array")
        if mask is not None and not isinstance(mask, np.ndarray):
            mask = list(mask)
            if len(mask) != len(frame):
                raise ValueError(f"mask: got {len(mask)} mask(s) for a rig of {len(frame)} "
                                 "camera(s): pass one per camera (None where none)")
        depth_m = self._depth_images(depth, len(frame))
        images_arg = frame[0] if len(frame) == 1 else tuple(frame)
        self._track(started_s, timestamp, {"images": images_arg, "mask": mask,
                                           "depth_m": depth_m}, imu=imu)

    def _depth_images(self, depth: Any, n: int) -> Any:
        """``depth`` of :meth:`add_frame` checked against the rig's depth cameras: what
        ``Session.track`` takes (one array for a rig of one camera)."""
        wanted = self.rig.depth
        if not any(wanted):
            if depth is not None and any(d is not None for d in _as_list(depth, n)):
                raise ValueError("depth given, but no camera of this rig has depth images "
                                 "(Rig(depth=...))")
            return None
        if depth is None:
            raise ValueError(f"depth: cameras {[k for k in range(n) if wanted[k]]} of this rig "
                             "have depth images: pass one per camera (None where none)")
        given = _as_list(depth, n)
        if len(given) != n:
            raise ValueError(f"depth: got {len(given)} image(s) for a rig of {n} camera(s): "
                             "pass one per camera (None where none)")
        for k, (d, want) in enumerate(zip(given, wanted)):
            if (d is None) == want:
                raise ValueError(f"depth[{k}]: camera {k} " + (
                    "has depth images: pass its depth in metres" if want
                    else "has no depth: pass None for it"))
        return given[0] if n == 1 else [None if d is None else np.asarray(d) for d in given]


def _as_list(value: Any, n: int) -> list:
    """A per-camera argument as a list (a single array for a rig of one camera)."""
    if isinstance(value, np.ndarray) and n == 1:
        return [value]
    if isinstance(value, np.ndarray) or not isinstance(value, (list, tuple)):
        raise ValueError(f"depth must be a sequence of {n} image(s) or None, one per camera, "
                         f"got {type(value).__name__}")
    return list(value)


class StereoVSlam(_VSlam):
    """Stereo visual SLAM (MATLAB ``stereovslam``) on RECTIFIED pairs: ``intrinsics`` is the
    rectified left camera (no distortion) and ``baseline`` the distance between the cameras in
    metres. For a raw pair of calibrated cameras use :meth:`from_raw`, which rectifies.

    Attributes:
        rectifier: the :class:`~ferroslam.stereo.StereoRectifier` applied to every pair
            (:meth:`from_raw`), ``None`` when the pairs come rectified.
        T_left_rect: ``(4, 4)`` pose of the tracked (rectified left) camera in the raw left
            camera: ``rectifier.T_left_rect`` (a rotation), identity without a rectifier.
            Poses are those of the rectified left camera; the raw left camera's pose is
            ``T_w_left = T_w_rect @ inv(T_left_rect)`` (same position).
    """

    _sensor = "stereo"

    def __init__(self, intrinsics: Camera, baseline: float, **options: Any) -> None:
        _check_camera(intrinsics)
        baseline = _positive_real("baseline", baseline, "metres")
        if np.any(intrinsics.dist != 0) or intrinsics.model != "pinhole":
            raise ValueError("StereoVSlam needs rectified images: intrinsics must have no "
                             "distortion and be a pinhole (for raw cameras use "
                             "StereoVSlam.from_raw)")
        self.baseline = float(baseline)
        self.rectifier: Optional[StereoRectifier] = None
        self.T_left_rect = np.eye(4)
        core = {"baseline": self.baseline, **options.pop("core_options", {})}
        super().__init__(intrinsics, core_options=core, **options)

    @classmethod
    def from_raw(cls, left_camera: Camera, right_camera: Camera, T_left_right: np.ndarray,
                 **options: Any) -> "StereoVSlam":
        """Stereo SLAM on RAW pairs of two calibrated cameras, rectified internally.

        Args:
            left_camera, right_camera: raw intrinsics with their distortion, both pinhole
                (radial-tangential) or both Kannala-Brandt, of one image size.
            T_left_right: ``(4, 4)`` pose of the right camera in the left camera frame
                (``p_left = T_left_right @ p_right``), metres; the right camera on the left
                one's +x side.
            options: as :class:`StereoVSlam`. ``camera_to_imu_transform`` is the RAW left
                camera's pose in the IMU frame (``T_b_left``); it is moved to the rectified
                camera (``T_b_left @ T_left_rect``).

        Returns a :class:`StereoVSlam` whose ``add_frame(left, right)`` takes raw images
        and whose poses (``poses``, ``current_pose``, ``frame_trajectory``) are those of the
        RECTIFIED left camera (``T_left_rect``; as ``EurocSequence`` rectified: ground truth
        ``T_w_b @ T_b_left @ T_left_rect``).

        Raises:
            TypeError: a camera that is not a ``ferroslam.Camera``.
            ValueError: cameras of different sizes or models; ``T_left_right`` not a finite
                rigid ``(4, 4)`` transform, with a zero baseline or the right camera not on
                the +x side (named); options as :class:`StereoVSlam`.
        """
        for name, camera in (("left_camera", left_camera), ("right_camera", right_camera)):
            if not isinstance(camera, Camera):
                raise TypeError(f"{name} must be a ferroslam.Camera, got "
                                f"{type(camera).__name__}")
            if camera.mask is not None:
                raise ValueError(f"{name} has a static mask, which from_raw does not rectify "
                                 "yet: pass it to add_frame(..., mask=(left, right))")
        rectifier = StereoRectifier(left_camera, right_camera, T_left_right)
        T_b_left = options.get("camera_to_imu_transform")
        if T_b_left is not None:
            options["camera_to_imu_transform"] = (np.asarray(T_b_left, dtype=np.float64)
                                                  @ rectifier.T_left_rect)
        vslam = cls(rectifier.camera, rectifier.baseline_m, **options)
        vslam.rectifier = rectifier
        vslam.T_left_rect = rectifier.T_left_rect
        return vslam

    def add_frame(self, left: np.ndarray, right: np.ndarray,
                  timestamp: Optional[float] = None,
                  imu: Optional[Sequence[np.ndarray]] = None, *,
                  mask: Any = None) -> None:
        """Adds a pair of uint8 images of equal size, grey or BGR (the map points take the
        left image's colours; ``imu`` as :meth:`MonoVSlam.add_frame`): rectified, or raw for
        an object made by :meth:`from_raw`. ``mask``: as :meth:`MonoVSlam.add_frame`'s, one
        array for both images or a ``(left_mask, right_mask)`` pair (either may be None);
        raw masks of a :meth:`from_raw` pair are rectified with the images (a pixel stays
        open where its whole neighbourhood is)."""
        masks = tuple(mask) if isinstance(mask, (tuple, list)) else (mask, mask)
        if len(masks) != 2:
            raise ValueError(f"mask must be one (H, W) array or a (left, right) pair, got "
                             f"{len(masks)} masks")
        self.intrinsics.check_image(left, "left image")
        if np.shape(left)[:2] != np.shape(right)[:2]:
            raise ValueError(f"left and right images differ in size: {np.shape(left)} vs "
                             f"{np.shape(right)}")
        started_s = time.perf_counter()
        if self.rectifier is not None:
            masks = self._rectify_masks(masks, np.shape(left)[:2])
            left, right = self.rectifier.rectify(left, right)
        self._track(started_s, timestamp, {"images": (left, right), "mask": masks}, imu=imu)

    def _rectify_masks(self, masks: tuple, shape: tuple[int, int]) -> tuple:
        """Raw per-frame masks (of raw images of ``shape``) in the rectified images: open only
        where the bilinear remap saw open pixels alone; rectified pixels outside the raw
        image stay closed."""
        assert self.rectifier is not None
        checked = [None if m is None else check_mask(m, shape, name) > 0
                   for m, name in zip(masks, ("left mask", "right mask"))]
        if all(m is None for m in checked):
            return masks
        open_255 = [np.full(shape, 255, np.uint8) if m is None else m.astype(np.uint8) * 255
                    for m in checked]
        rectified = self.rectifier.rectify(*open_255)
        return tuple(None if m is None else (r == 255).astype(np.uint8)
                     for m, r in zip(checked, rectified))


class RGBDVSlam(_VSlam):
    """RGB-D visual SLAM (MATLAB ``rgbdvslam``). A depth pixel ``P`` means ``P /
    depth_scale_factor`` metres (5000 for TUM, 1000 for millimetre sensors); depths outside
    ``depth_range`` (metres) count as missing."""

    _sensor = "rgbd"

    def __init__(self, intrinsics: Camera, depth_scale_factor: float = 1.0, *,
                 depth_range: Optional[Sequence[float]] = None, **options: Any) -> None:
        if isinstance(depth_scale_factor, bool) or not isinstance(depth_scale_factor,
                                                                  numbers.Real):
            raise TypeError(f"depth_scale_factor must be a real number, got "
                            f"{depth_scale_factor!r}")
        if not (math.isfinite(depth_scale_factor) and depth_scale_factor > 0):
            raise ValueError(f"depth_scale_factor must be positive, got {depth_scale_factor!r}")
        self.depth_scale_factor = float(depth_scale_factor)
        self._depth_checked = False
        given = {} if depth_range is None else {"depth_range": tuple(depth_range)}
        core = {**given, **options.pop("core_options", {})}
        super().__init__(intrinsics, core_options=core, **options)
        # The range in use: the one given, else the core's default for RGB-D.
        self.depth_range: tuple[float, float] = tuple(self._system.options["depth_range"])
        self._keyframe_images = KeyframeImages(keep_depth=True)

    def add_frame(self, color: np.ndarray, depth: np.ndarray,
                  timestamp: Optional[float] = None,
                  imu: Optional[Sequence[np.ndarray]] = None, *,
                  mask: Optional[np.ndarray] = None) -> None:
        """Adds a colour (BGR or grey, uint8) image and its registered depth image (any real
        dtype; divided by ``depth_scale_factor``; ``imu`` and ``mask`` as
        :meth:`MonoVSlam.add_frame`)."""
        started_s = time.perf_counter()
        self.intrinsics.check_image(color, "color image")
        depth = np.asarray(depth)
        if depth.dtype.kind not in "uif":
            raise ValueError(f"depth must be an integer or float image, got dtype {depth.dtype}")
        if depth.shape[:2] != np.shape(color)[:2]:
            raise ValueError(f"color and depth images differ in size: {np.shape(color)} vs "
                             f"{depth.shape}")
        depth_m = depth.astype(np.float64) / self.depth_scale_factor
        self._check_depth_scale(depth_m)
        self._track(started_s, timestamp, {"images": color, "depth_m": depth_m, "mask": mask},
                    imu=imu, pixels=(color, depth_m))

    def dense_mesh(self, *, voxel_m: Optional[float] = None,
                   truncation_m: Optional[float] = None,
                   max_depth_m: Optional[float] = None):
        """The keyframes' depth fused at their current poses (after local BA and loop
        closing; call it when done) into a coloured TSDF mesh and dense cloud
        (:class:`ferroslam.dense.DenseModel`; write it with
        :func:`ferroslam.dense.write_dense_outputs`). Settings left out take the
        ``dense_*`` option defaults (:data:`ferroslam.options.OPTIONS`).

        Only keyframes' images are kept (PNG-encoded), so memory follows the map. Raises
        ``ImportError`` without Open3D (``pip install 'ferroslam[dense]'``)."""
        from .dense import fuse_tsdf
        from .options import pipeline_default

        given = {"dense_voxel_m": voxel_m, "dense_truncation_m": truncation_m,
                 "dense_max_depth_m": max_depth_m}
        settings = validate_options({k: v for k, v in given.items() if v is not None}, "rgbd")
        self.wait()
        _, stamps, poses = self._system.keyframe_trajectory()
        images = self._keyframe_images
        assert images is not None  # every RGBDVSlam keeps its keyframes' pixels
        images.keep_only(stamps)
        kept = [i for i, t in enumerate(stamps) if t in images]
        return fuse_tsdf(
            self.intrinsics, np.asarray(poses).reshape(-1, 4, 4)[kept],
            [images.image(stamps[i]) for i in kept], [images.depth_m(stamps[i]) for i in kept],
            voxel_m=pipeline_default(settings, "dense_voxel_m"),
            truncation_m=pipeline_default(settings, "dense_truncation_m"),
            max_depth_m=pipeline_default(settings, "dense_max_depth_m"))

    def _check_depth_scale(self, depth_m: np.ndarray) -> None:
        """Warns when the first frame with depth has none of it inside ``depth_range``: raw
        millimetres with ``depth_scale_factor=1`` (or metres with 5000) would otherwise never
        start a map, and nothing would say why. Every 4th pixel of every 4th row is enough."""
        if self._depth_checked:
            return
        sample = depth_m[::4, ::4]
        measured = sample[np.isfinite(sample) & (sample > 0)]
        if measured.size:
            self._depth_checked = True  # checked once: the scale of a stream does not change
        low, high = self.depth_range
        if measured.size and not np.any((measured >= low) & (measured <= high)):
            warnings.warn(
                f"no depth of this frame falls inside depth_range {self.depth_range} m (median "
                f"{float(np.median(measured)):.4g} m after dividing by depth_scale_factor="
                f"{self.depth_scale_factor:g}): is depth_scale_factor right? (5000 for TUM, "
                "1000 for millimetre sensors)", UserWarning, stacklevel=3)
