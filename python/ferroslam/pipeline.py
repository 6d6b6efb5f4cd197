"""Run the SLAM core over a dataset sequence: load, extract ORB, sample depth, track.

The heavy lifting happens in ``ferroslam._core.SlamSystem`` (Rust); this module feeds it
frame by frame, times every stage and evaluates the result against ground truth.
:func:`run_source` does the same for a live source (a camera) through ``MonoVSlam``, which
drops the frames that come while tracking is behind.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Union

import numpy as np
from tqdm import tqdm

from .camera import Camera
from .colmap import SparseModel
from .datasets import frame_images
from .dense import DenseModel, fuse_tsdf
from .depth_scale import check_depth_scale
from .keyframe_images import KeyframeImages
from .metrics import AteResult, PathLengthResult, RpeResult, ate, path_length, rpe
from .options import OPTIONS, RUN_SENSORS, pipeline_default, validate_options
from .session import EXTRACTOR_KEYS, IMU_KEYS, Session, load_vocabulary, make_extractor
from .rig import rig_images
from .trajectory import Trajectory
from .vslam import FrameResult, MonoVSlam

__all__ = ["EXTRACTOR_KEYS", "MapInfo", "RunError", "RunResult", "load_vocabulary",
           "make_extractor", "run_sequence", "run_source"]

SENSORS = RUN_SENSORS
_INERTIAL = "-inertial"
# Pipeline options that are not SlamSystem keywords.
_PIPELINE_ONLY = tuple(o.name for o in OPTIONS if o.scope == "pipeline") + IMU_KEYS
_TIMINGS = ("load_ms", "extraction_ms", "tracking_ms", "matching_ms", "pose_optimisation_ms",
            "mapping_ms", "local_ba_ms", "loop_closing_ms", "track_call_ms", "frame_ms")


@dataclass(frozen=True)
class MapInfo:
    """One map of a run.

    ``id``: the core's map id (``SlamSystem.maps``): unique within the run, in creation
    order; a run lost for ``relocalisation_window_s`` keeps its map and starts a new one, and
    a merged map keeps the older map's id. ``trajectory``: the poses of the frames tracked in
    this map, in its own world frame (and, monocular, its own scale): poses of different maps
    are not comparable. ``keyframes`` and ``points``: the map's live keyframes and points at
    the end of the run (``None`` for a result made without the core's map list).
    """

    id: int
    trajectory: Trajectory
    keyframes: Optional[int]
    points: Optional[int] = None

    @property
    def frames(self) -> int:
        """Frame poses in this map."""
        return len(self.trajectory)

    def summary(self) -> dict:
        """``{"id", "frames", "keyframes", "points"}``, as results.json's ``"maps"`` lists
        them."""
        return {"id": self.id, "frames": self.frames, "keyframes": self.keyframes,
                "points": self.points}


@dataclass
class RunResult:
    """Everything a run produced.

    ``trajectory``: final poses ``T_w_c`` of all tracked frames (after bundle adjustment);
    ``keyframes`` and ``keyframe_ids``: the keyframe poses; ``map_points (M, 3)`` world
    points in metres and ``map_point_colors (M, 3)`` uint8 RGB, each the colour of the image
    pixel the point was first seen at (``SlamSystem.map_point_colors``); ``timings``:
    per-frame milliseconds (``load_ms``; ``extraction_ms`` (the core's front end:
    extraction, masks, depth and colour sampling, stereo matching's extraction),
    ``tracking_ms`` and ``mapping_ms`` as reported by the core, with their parts
    ``pose_optimisation_ms``, ``matching_ms`` = tracking minus pose optimisation (matching,
    local-map search, keyframe decision), ``local_ba_ms`` and ``loop_closing_ms`` (mapping
    inside the call only), ``track_call_ms`` measured around the one call into the core, ``frame_ms`` = the
    track call and the Python around it);
    ``states``: tracking state per frame; ``map_ids``: the map of each trajectory pose (a run
    lost for ``relocalisation_window_s`` keeps its map and starts a new one; merges join
    them); ``atlas``: the core's map list (``SlamSystem.maps``); ``maps``: the maps
    (:class:`MapInfo`) and ``largest_map`` the one ``trajectory.txt`` holds (the
    ``trajectory`` field itself holds every map's poses, each in its own frame); ``merges``:
    the maps merged (``SlamSystem.merges``);
    ``init_reasons``: per frame, why
    monocular initialisation waited (``None`` otherwise); ``loops``: the loops closed (see
    ``SlamSystem.loops``) and ``loop_stats`` what loop detection did; ``inertial``: the
    camera-IMU alignment at the end (``SlamSystem.inertial_alignment``) for the ``-inertial``
    sensors. With ground truth: ATE (SE(3), or Sim(3) over the largest map for monocular
    runs without an IMU alignment), RPE, path length and ``scale_error`` (metric scale; not
    for those runs): the estimate's scale relative to the ground truth minus 1, from a Sim(3)
    alignment (``1 / s - 1`` for the alignment's scale ``s``). Path lengths are not a scale
    measure: per-frame jitter adds length.
    ``camera``: the intrinsics of the images tracked (for exports such as COLMAP models).
    ``sparse_model``: the keyframes' keypoints and the points' tracks
    (:class:`~ferroslam.colmap.SparseModel`); ``keyframe_images``: the images (and, with
    ``dense``, depth) of the keyframes in the map; ``dense``: the TSDF mesh of the RGB-D
    keyframes at their final poses (:class:`~ferroslam.dense.DenseModel`), with the
    ``dense`` option.
    ``dropped_frames``: for a live run (:func:`run_source`), the frames read but not tracked
    because tracking was behind (``None`` otherwise: every frame is tracked); its timings are
    ``tracking_ms``, ``mapping_ms`` and ``latency_ms`` (``FrameResult.latency_ms``).
    """

    sequence: str
    sensor: str
    config: dict
    timestamps: np.ndarray
    states: list
    num_tracked: np.ndarray
    timings: dict
    trajectory: Trajectory
    keyframes: Trajectory
    keyframe_ids: np.ndarray
    map_points: np.ndarray
    map_point_colors: np.ndarray
    map_ids: Optional[np.ndarray] = None
    atlas: list = field(default_factory=list)
    merges: list = field(default_factory=list)
    init_reasons: list = field(default_factory=list)
    loops: list = field(default_factory=list)
    loop_stats: dict = field(default_factory=dict)
    inertial: Optional[dict] = None
    camera: Optional[Camera] = None
    sparse_model: Optional[SparseModel] = None
    keyframe_images: Optional[KeyframeImages] = None
    dense: Optional[DenseModel] = None
    groundtruth: Optional[Trajectory] = None
    ate_frames: Optional[AteResult] = None
    ate_keyframes: Optional[AteResult] = None
    rpe_frames: Optional[RpeResult] = None
    path_length: Optional[PathLengthResult] = None
    scale_error: Optional[float] = None
    metric_errors: list = field(default_factory=list)
    dropped_frames: Optional[int] = None

    @property
    def scale_free(self) -> bool:
        """Whether the trajectory's scale is arbitrary: monocular, and no IMU alignment made
        it metric."""
        aligned = (self.inertial or {}).get("status") == "aligned"
        return self.sensor.startswith("mono") and not aligned

    @property
    def frames(self) -> int:
        return len(self.states)

    @property
    def tracked_frames(self) -> int:
        """Frames whose tracking state is ``"ok"``."""
        return sum(s == "ok" for s in self.states)

    @property
    def first_initialised_frame(self) -> Optional[int]:
        """Index of the first frame tracked (the map's start), ``None`` if it never started."""
        return next((i for i, s in enumerate(self.states) if s == "ok"), None)

    @property
    def tracked_after_init(self) -> float:
        """Fraction of the frames from the first initialisation on that were tracked."""
        first = self.first_initialised_frame
        if first is None:
            return 0.0
        return sum(s == "ok" for s in self.states[first:]) / (len(self.states) - first)

    @property
    def num_maps(self) -> int:
        """Maps with frame poses (0 when nothing was tracked)."""
        return len(self.maps)

    def _pose_map_ids(self) -> np.ndarray:
        """``(N,)`` int64: ``map_ids``, all 0 for a result made without them."""
        if self.map_ids is None:
            return np.zeros(len(self.trajectory), dtype=np.int64)
        return np.asarray(self.map_ids, dtype=np.int64)

    @property
    def maps(self) -> list[MapInfo]:
        """The maps with at least one frame pose, by id (empty when nothing was tracked)."""
        ids = self._pose_map_ids()
        known = {m["id"]: m for m in self.atlas}
        return [MapInfo(int(i), self.trajectory.subset(np.flatnonzero(ids == i)),
                        known.get(int(i), {}).get("keyframes"),
                        known.get(int(i), {}).get("points"))
                for i in np.unique(ids)]

    @property
    def largest_map(self) -> Optional[MapInfo]:
        """The map with the most frame poses (ties: the older), ``None`` when nothing was
        tracked: what ``trajectory.txt`` holds and monocular ATE is computed over."""
        largest = largest_map_id(self._pose_map_ids())
        return next((m for m in self.maps if m.id == largest), None)

    @property
    def largest_map_trajectory(self) -> Trajectory:
        """The largest map's poses, what ``trajectory.txt`` holds (the whole trajectory, empty,
        when nothing was tracked; the whole one, too, with a single map)."""
        largest = self.largest_map
        return self.trajectory if largest is None else largest.trajectory

    def summary(self) -> dict:
        """JSON-serialisable summary (what ``ferroslam run`` writes to results.json)."""
        timing = {}
        for name, values in self.timings.items():
            v = np.asarray(values, dtype=np.float64)
            v = v[np.isfinite(v)]
            timing[name] = (
                {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
                 "mean": float(np.mean(v)), "max": float(np.max(v))}
                if v.size else None
            )
        largest = self.largest_map
        out: dict[str, Any] = {
            "sequence": self.sequence,
            "sensor": self.sensor,
            "config": self.config,
            "frames": self.frames,
            "tracked_frames": self.tracked_frames,
            "states": {s: self.states.count(s) for s in sorted(set(self.states))},
            "trajectory_poses": len(self.trajectory),
            "first_initialised_frame": self.first_initialised_frame,
            "tracked_after_init": self.tracked_after_init,
            "num_maps": self.num_maps,
            "maps": [m.summary() for m in self.maps],
            "merges": len(self.merges),
            "trajectory_map": None if largest is None else largest.id,
            "loops": len(self.loops),
            "keyframes": len(self.keyframes),
            "map_points": int(self.map_points.shape[0]),
            **({"dense": {"mesh_vertices": len(self.dense.vertices),
                          "mesh_triangles": len(self.dense.triangles),
                          "points": len(self.dense.points), "frames": self.dense.frames,
                          "fusion_s": self.dense.fusion_s}} if self.dense is not None else {}),
            "timing_ms": timing,
            "inertial": _jsonable(self.inertial),
            "metrics": {},
            "metric_errors": list(self.metric_errors),
        }
        if self.dropped_frames is not None:
            out["dropped_frames"] = self.dropped_frames
        for name, result in (("ate_frames", self.ate_frames), ("ate_keyframes", self.ate_keyframes)):
            if result is not None:
                out["metrics"][name] = {
                    "align": "sim3" if self.scale_free else "se3", "pairs": result.pairs, "scale": result.scale, "unit": "m",
                    **{k: getattr(result, k) for k in ("rmse", "mean", "median", "std", "min", "max")},
                }
        if self.rpe_frames is not None:
            r = self.rpe_frames
            out["metrics"]["rpe_frames"] = {
                "delta_frames": r.delta, "pairs": r.pairs,
                **{f"trans_{k}_m": getattr(r, f"trans_{k}") for k in ("rmse", "mean", "median")},
                **{f"rot_{k}_deg": getattr(r, f"rot_deg_{k}") for k in ("rmse", "mean", "median")},
            }
        if self.path_length is not None:
            p = self.path_length
            out["metrics"]["path_length"] = {
                "estimate_m": p.estimate_m, "reference_m": p.reference_m, "pairs": p.pairs,
                "ratio": p.estimate_m / p.reference_m if p.reference_m > 0 else None,
            }
        if self.scale_error is not None:
            out["metrics"]["scale_error"] = self.scale_error
        return out


class RunError(ValueError):
    """A run that stopped at an error: ``partial`` holds the result of the frames before it
    (trajectory, map, timings; evaluated when the ground truth could be read), so that
    nothing tracked is lost; ``frame`` is the index of the frame that failed (``None`` when
    the error came after the last frame, e.g. from the ground truth)."""

    def __init__(self, message: str, partial: RunResult, frame: Optional[int]) -> None:
        super().__init__(message)
        self.partial = partial
        self.frame = frame


class _RgbdFeed:
    """Loads the grey and colour image and the depth of a frame. A sequence that says its
    depth scale (``depth_factor``) has it checked on the first frame, before any tracking:
    a wrong one would scale the whole map silently."""

    core_sensor = "rgbd"
    pair = None
    observers: tuple = ()

    def __init__(self, seq) -> None:
        if not hasattr(seq, "load_depth"):
            raise ValueError(
                f"{getattr(seq, 'name', seq)} has no depth images: use sensor 'stereo' or 'mono'"
            )
        self.seq = seq
        if getattr(seq, "depth_factor", None) is not None and len(seq):
            check_depth_scale(seq.load_depth(0), seq.depth_factor,
                              f"{getattr(seq, 'name', seq)} frame 0")

    def system_options(self) -> dict:
        return {}

    def load(self, i: int):
        gray, color = frame_images(self.seq, i)
        self.seq.camera.check_image(gray, f"image {i}")
        return gray, color, self.seq.load_depth(i)

    @staticmethod
    def image(data) -> np.ndarray:
        """The image of loaded ``data`` (for ``on_frame``), in colour where there is."""
        return data[1]

    @staticmethod
    def depth(data) -> np.ndarray:
        """The depth image (metres) of loaded ``data``."""
        return data[2]

    @staticmethod
    def frame(data) -> dict:
        """``Session.track``'s arguments for loaded ``data``."""
        gray, color, depth = data
        return {"images": gray, "depth_m": depth, "color": color}


class _StereoFeed:
    """Loads a rectified pair (both images are extracted at once)."""

    core_sensor = "stereo"
    pair = None
    observers: tuple = ()

    def __init__(self, seq) -> None:
        if not getattr(seq, "is_stereo", False):
            raise ValueError(
                f"{getattr(seq, 'name', seq)} is not a stereo sequence (no right images)"
            )
        if getattr(seq, "is_rectified", True) is False:
            raise ValueError(
                f"{getattr(seq, 'name', seq)} was opened with rectify=False: its pairs are "
                "raw; open it rectified or track it with StereoVSlam.from_raw"
            )
        self.seq = seq

    def system_options(self) -> dict:
        return {"baseline": float(self.seq.baseline_m)}

    def load(self, i: int):
        left, right = self.seq.load_stereo(i)
        self.seq.camera.check_image(left, f"left image {i}")
        return left, right

    @staticmethod
    def image(data) -> np.ndarray:
        """The tracked (left) image of a loaded pair (for ``on_frame``)."""
        return data[0]

    @staticmethod
    def depth(data) -> None:
        return None

    @staticmethod
    def frame(data) -> dict:
        """``Session.track``'s arguments for a loaded pair."""
        return {"images": tuple(data)}


class _MonoFeed:
    """Loads one grey image per frame (and its colour version where the sequence has one)."""

    core_sensor = "mono"
    pair = None
    observers: tuple = ()

    def __init__(self, seq) -> None:
        self.seq = seq

    def system_options(self) -> dict:
        return {}

    def load(self, i: int):
        gray, color = frame_images(self.seq, i)
        self.seq.camera.check_image(gray, f"image {i}")
        return gray, color

    @staticmethod
    def image(data) -> np.ndarray:
        """The image of loaded ``data`` (for ``on_frame``), in colour where there is."""
        return data[1]

    @staticmethod
    def depth(data) -> None:
        return None

    @staticmethod
    def frame(data) -> dict:
        """``Session.track``'s arguments for loaded ``data``."""
        gray, color = data
        return {"images": gray, "color": color}


class _RigFeed(_StereoFeed):
    """Loads every camera's RAW image of an instant of the sequence's rig (``seq.rig``,
    ``seq.load_rig(i)``); the core tracks the rig as :meth:`Rig.tracked_sensor` says (a
    stereo rig: matched along epipolar curves, no rectification)."""

    def __init__(self, seq) -> None:
        rig = getattr(seq, "rig", None)
        if rig is None or not hasattr(seq, "load_rig"):
            raise ValueError(
                f"{getattr(seq, 'name', seq)} has no camera rig: sensor 'rig' tracks the "
                "cameras of a EuRoC folder (cam0, cam1 with their sensor.yaml) as they are"
            )
        if getattr(seq, "is_rectified", False):
            # Its camera, body pose and ground truth are the rectified camera's, not cam0's.
            raise ValueError(
                f"{getattr(seq, 'name', seq)} was opened rectified: sensor 'rig' tracks the "
                "raw images (open_sequence(path, rectify=False), or sensor='rig' there)"
            )
        self.seq, self.rig = seq, rig
        self.core_sensor = rig.tracked_sensor()
        self.pair = (rig.cameras[1], rig.T_left_right) if self.core_sensor == "stereo" else None
        self.observers = rig.observers()

    def system_options(self) -> dict:
        return {}

    def load(self, i: int):
        return rig_images(self.rig, self.seq.load_rig(i))

    @staticmethod
    def frame(data) -> dict:
        """``Session.track``'s arguments for a loaded instant."""
        return {"images": data[0] if len(data) == 1 else tuple(data)}

    def camera_images(self, data) -> tuple[np.ndarray, ...]:
        """The images of the core's cameras (the tracked one, then the further cameras:
        a pair partner gives depths only, it has no keyframe image of its own)."""
        return tuple(data[k] for k in self.rig.observing_cameras())


_FEEDS = {"mono": _MonoFeed, "rgbd": _RgbdFeed, "stereo": _StereoFeed}


def _evaluate(result: RunResult, gt: Trajectory) -> None:
    if result.scale_free:  # per map: each has its own frame and scale
        cases = (
            ("ate_frames", lambda: ate(gt, result.largest_map_trajectory, align="sim3")),
            ("ate_keyframes", lambda: ate(gt, result.keyframes, align="sim3")),
        )
    else:
        cases = (
            ("ate_frames", lambda: ate(gt, result.trajectory, align="se3")),
            ("ate_keyframes", lambda: ate(gt, result.keyframes, align="se3")),
            ("rpe_frames", lambda: rpe(gt, result.trajectory, delta=1, align="none")),
            ("path_length", lambda: path_length(gt, result.trajectory)),
            ("scale_error", lambda: 1.0 / ate(gt, result.trajectory, align="sim3").scale - 1.0),
        )
    for name, compute in cases:
        try:
            setattr(result, name, compute())
        except ValueError as err:  # too few poses, no timestamps in common, degenerate
            result.metric_errors.append(f"{name}: {err}")


def run_sequence(
    seq,
    config: Optional[dict] = None,
    max_frames: Optional[int] = None,
    progress: bool = True,
    *,
    sensor: str = "rgbd",
    system_factory: Optional[Callable[..., Any]] = None,
    realtime: bool = False,
    on_frame: Optional[Callable[..., None]] = None,
    first_frame: int = 0,
    prior_map: Optional[Union[str, Path]] = None,
    save_map: Optional[Union[str, Path]] = None,
) -> RunResult:
    """Track a whole sequence and evaluate it.

    Args:
        seq: a dataset sequence (``len``, ``load_gray(i)``, ``load_depth(i)``, ``timestamps``,
            ``camera``, ``has_groundtruth``, ``groundtruth()``), e.g. ``TumSequence``; a
            sequence with ``load_gray_and_color(i)`` is read in colour too
            (``ferroslam.datasets.frame_images``), so that map points take their image colour.
        config: keyword options for ``SlamSystem``, the extractor's among them (checked by
            :func:`ferroslam.options.validate_options` for the sensor: unknown or
            inapplicable keys, wrong types and values out of range raise naming the key; the
            rest take the defaults of the sensor and image width,
            ``ferroslam._core.default_options``) and
            ``vocabulary`` (``"default"``: the shipped one; a vocabulary file; ``None`` for
            none): lost frames relocalise against the keyframes they resemble; and
            ``mapping_thread`` (``True``: local mapping and loop closing run in their own
            thread, as in ORB-SLAM, and ``tracking_ms`` is the tracking thread's time; the
            default, ``False``, maps inline and is deterministic).
        max_frames: process only the first ``max_frames`` frames (from ``first_frame``).
        first_frame: start at this frame of the sequence (a later session of a sequence).
        prior_map: a map file to map onward from (a session after an earlier one saved its
            map): its maps are loaded first (``SlamSystem.load_map``); tracking relocalises
            in them, or starts a map of its own that merges into them once it recognises
            them, so the outputs are in the prior's frame once joined.
        save_map: write the run's maps (the whole atlas) to this file at the end, through
            :func:`ferroslam._files.atomic_output`.
        progress: show a tqdm progress bar.
        realtime: feed frames at the pace of their timestamps, as a live camera would
            (frames are otherwise fed as fast as they are processed).
        sensor: ``"mono"``, ``"rgbd"`` (needs ``load_depth``) or ``"stereo"`` (needs
            ``is_stereo``, ``load_stereo(i)`` giving a rectified pair and ``baseline_m``),
            each optionally ``"-inertial"`` (needs ``imu()``, ``imu_params()`` and ``T_b_c``,
            as EuRoC has): the samples up to each frame, and the first one after it when it
            is less than an IMU period later, are added before it is tracked; ``config`` may
            hold the ``set_imu`` options ``num_poses_threshold``, ``alignment_fraction``,
            ``gravity_magnitude`` and ``imu_time_offset_s`` (``t_imu = t_cam + offset``).
        system_factory: replaces ``ferroslam._core.SlamSystem`` (tests, instrumentation).
        on_frame: called after each frame as ``on_frame(result, image=, keypoints=,
            timestamp_s=, system=)`` (the core's ``TrackResult``, the frame's image (BGR where
            the sequence has colour, else grey; the left one for stereo), its
            keypoints, the frame time, the ``SlamSystem``), e.g. a live view
            (``ferroslam.viewer.make_frame_callback``).

    Raises:
        ValueError, TypeError: bad configuration (naming the key) or ``max_frames``; a
            sequence with no frames; for RGB-D, a sequence's ``depth_factor`` that puts the
            first frame's median depth outside 0.1-20 m (naming the scale that would not,
            :func:`ferroslam.depth_scale.check_depth_scale`).
    """
    if sensor not in SENSORS:
        raise ValueError(f"unknown sensor {sensor!r}; expected one of {SENSORS}")
    camera = sensor[: -len(_INERTIAL)] if sensor.endswith(_INERTIAL) else sensor
    imu = _imu_stream(seq, sensor) if camera != sensor else None
    if isinstance(config, dict) and "sensor" in config:
        raise ValueError("pass the sensor as run_sequence(sensor=...), not in config")
    # The options are checked before any frame is read (the RGB-D feed reads one); a rig's
    # feed reads none and tells the sensor the rig is tracked as.
    rig_feed = _RigFeed(seq) if camera == "rig" else None
    core_sensor = camera if rig_feed is None else rig_feed.core_sensor
    config = validate_options(config, core_sensor + sensor[len(camera):])
    if isinstance(first_frame, bool) or int(first_frame) != first_frame or first_frame < 0:
        raise ValueError(f"first_frame must be a non-negative integer, got {first_frame!r}")
    if first_frame:
        if first_frame >= len(seq):
            raise ValueError(f"first_frame {first_frame} is past the sequence's last frame "
                             f"({len(seq) - 1})")
        seq = _FrameWindow(seq, int(first_frame))
    n = len(seq)
    if n == 0:  # a dataset says why when it is opened; any other sequence, here
        raise ValueError(f"{getattr(seq, 'name', seq)}: the sequence has no frames to track")
    if max_frames is not None:
        if int(max_frames) != max_frames or max_frames < 1:
            raise ValueError(f"max_frames must be a positive integer, got {max_frames}")
        n = min(n, int(max_frames))
    core_config = {k: v for k, v in config.items() if k not in _PIPELINE_ONLY}
    feed = rig_feed or _FEEDS[camera](seq)
    session = Session(
        seq.camera, feed.core_sensor, {**feed.system_options(), **core_config},
        vocabulary=config.get("vocabulary", "default"),
        imu=seq.imu_params() if imu is not None else None,
        T_b_c=seq.T_b_c if imu is not None else None,
        imu_options={k: config[k] for k in IMU_KEYS if k in config},
        mapping_thread=config.get("mapping_thread", False), system_factory=system_factory,
        pair=feed.pair, observers=feed.observers)
    if prior_map is not None:
        from ._files import regular_file

        session.system.load_map(regular_file(prior_map, "map file"))
    try:
        return _run(seq, session, feed, n, sensor, config, progress, realtime, imu, on_frame)
    finally:
        # Also after a failed frame: the maps built until then are the run's result too.
        if save_map is not None:
            from ._files import atomic_output

            with atomic_output(save_map) as tmp:
                session.system.save_map(tmp)


class _FrameWindow:
    """The frames ``first``.. of a sequence, indexed from 0: every ``load_*(i, ...)`` reads
    frame ``first + i``; anything else is the sequence's (its IMU, ground truth, camera)."""

    def __init__(self, seq, first: int) -> None:
        self._seq = seq
        self._first = first

    def __len__(self) -> int:
        return len(self._seq) - self._first

    @property
    def timestamps(self) -> np.ndarray:
        return np.asarray(self._seq.timestamps)[self._first:]

    def __getattr__(self, name: str):
        value = getattr(self._seq, name)
        if name.startswith("load_") and callable(value):
            return lambda i, *args, **kwargs: value(i + self._first, *args, **kwargs)
        return value


def _imu_stream(seq, sensor: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sequence's IMU ``(t, gyro, accel)`` for an ``-inertial`` sensor."""
    if not all(hasattr(seq, a) for a in ("imu", "imu_params", "T_b_c")):
        raise ValueError(
            f"sensor {sensor!r} needs an IMU: {getattr(seq, 'name', seq)} has no imu(), "
            "imu_params() and T_b_c (EuRoC sequences have them)")
    t, gyro, accel = seq.imu()
    return (np.ascontiguousarray(t, dtype=np.float64), np.ascontiguousarray(gyro, dtype=np.float64),
            np.ascontiguousarray(accel, dtype=np.float64))


def imu_batch_end(stamps: np.ndarray, frame_s: float, period_s: float,
                  offset_s: float = 0.0) -> int:
    """End (exclusive) of the IMU samples to add before the frame at ``frame_s``: every
    sample up to the frame and the first one after it when it is at most ``period_s`` later
    (the core then interpolates the frame's pose instead of extrapolating it, as ORB-SLAM3).
    ``stamps`` on the IMU clock, ``t_imu = t_cam + offset_s``."""
    end = int(np.searchsorted(stamps, frame_s + offset_s, side="right"))
    if end < len(stamps) and stamps[end] - offset_s - frame_s <= period_s:
        end += 1
    return end


def largest_map_id(map_ids: np.ndarray) -> Optional[int]:
    """The map with the most frame poses, given the map of each pose (ties: the older, its
    id the lower: ids count up in creation order); ``None`` for no poses."""
    ids, counts = np.unique(np.asarray(map_ids, dtype=np.int64), return_counts=True)
    # argmax keeps the first of equal maxima.
    return None if len(ids) == 0 else int(ids[np.argmax(counts)])


def _map_outputs(system) -> dict:
    """The ``RunResult`` fields a ``SlamSystem`` holds at the end of a run: trajectories,
    keyframes, maps, merges, loops, map points. Keyframes, points and the sparse model are
    those of the largest map, the one ``trajectory.txt`` holds (a run may end in a young
    map started after its main one was lost): the current one when nothing was tracked."""
    stamps, poses = system.frame_trajectory()
    map_ids = np.asarray(system.frame_map_ids(), dtype=np.int64).reshape(-1)
    shown = largest_map_id(map_ids)
    kf_ids, kf_stamps, kf_poses = system.keyframe_trajectory(shown)
    # In time order: a session's keyframes in a prior map come after the prior's by id.
    order = np.argsort(np.asarray(kf_stamps).reshape(-1), kind="stable")
    kf_ids = np.asarray(kf_ids).reshape(-1)[order]
    kf_stamps = np.asarray(kf_stamps).reshape(-1)[order]
    kf_poses = np.asarray(kf_poses).reshape(-1, 4, 4)[order]
    return dict(
        trajectory=Trajectory(np.asarray(stamps).reshape(-1), np.asarray(poses).reshape(-1, 4, 4)),
        keyframes=Trajectory(np.asarray(kf_stamps).reshape(-1), np.asarray(kf_poses).reshape(-1, 4, 4)),
        keyframe_ids=np.asarray(kf_ids, dtype=np.uint32).reshape(-1),
        map_ids=map_ids,
        atlas=system.maps(),
        merges=system.merges(),
        loops=system.loops(),
        loop_stats=system.loop_stats(),
        map_points=np.asarray(system.map_points(shown), dtype=np.float64).reshape(-1, 3),
        map_point_colors=np.asarray(system.map_point_colors(shown),
                                    dtype=np.uint8).reshape(-1, 3),
        sparse_model=SparseModel.from_core(system.sparse_model(shown)),
    )


def run_source(source, config: Optional[dict] = None, max_frames: Optional[int] = None,
               progress: bool = True) -> RunResult:
    """Track a live monocular source (``ferroslam.sources.CameraSource``, or any iterable of
    ``(timestamp_s, image)`` with ``camera``, ``name`` and ``live``) as its frames come,
    with ``MonoVSlam.track_source``: frames that arrive while tracking is behind are dropped
    (``RunResult.dropped_frames``). Ends when the source does, after ``max_frames`` frames
    read, or at Ctrl+C (``KeyboardInterrupt``), the usual end of a camera run: the frames
    tracked until then make the result. No ground truth, so no metrics.

    ``config``: as :func:`run_sequence`'s (``SlamSystem`` options, ``vocabulary``,
    ``seed``); tracking and mapping run in background threads, so runs are not repeatable.
    """
    config = validate_options(config, "mono")
    core_options = {k: v for k, v in config.items() if k not in _PIPELINE_ONLY + ("seed",)}
    records: list[FrameResult] = []
    bar = tqdm(disable=not progress, desc=source.name, unit="frame")

    def record(frame: FrameResult) -> None:
        records.append(frame)
        bar.update()
        bar.set_postfix(state=frame.track.state, refresh=False)

    with MonoVSlam(source.camera, vocabulary=config.get("vocabulary", "default"),
                   seed=config.get("seed", 0), core_options=core_options,
                   on_frame=record) as vslam:
        try:
            vslam.track_source(source, max_frames=max_frames)
        except KeyboardInterrupt:
            pass  # stopping the camera: keep what was tracked
        vslam.wait()
        bar.close()
        tracks = [r.track for r in records]
        return RunResult(
            sequence=source.name, sensor="mono", config=config,
            timestamps=np.array([r.timestamp_s for r in records], dtype=np.float64),
            states=[str(t.state) for t in tracks],
            num_tracked=np.array([t.num_tracked for t in tracks], dtype=np.int64),
            timings={"tracking_ms": np.array([t.tracking_ms for t in tracks], dtype=np.float64),
                     "mapping_ms": np.array([t.mapping_ms for t in tracks], dtype=np.float64),
                     "latency_ms": np.array([r.latency_ms for r in records], dtype=np.float64)},
            init_reasons=[t.init_reason for t in tracks],
            camera=source.camera, dropped_frames=vslam.dropped_frames,
            **_map_outputs(vslam._system),
        )


def _camera_images(feed, data) -> tuple[np.ndarray, ...]:
    """The keyframe images of loaded ``data``, one per core camera (``_RigFeed``'s
    ``camera_images``; the other feeds' one image)."""
    camera_images = getattr(feed, "camera_images", None)
    return (feed.image(data),) if camera_images is None else camera_images(data)


def _add_keyframe(images: KeyframeImages, timestamp_s: float, feed, data) -> None:
    """Keeps every core camera's image of a keyframe (and the first camera's depth)."""
    first, *others = _camera_images(feed, data)
    images.add(timestamp_s, first, feed.depth(data))
    for k, image in enumerate(others, start=1):
        images.add(timestamp_s, image, camera=k)


def _keep_keyframe(images: KeyframeImages, system, timestamp_s: float, feed, data) -> None:
    """Keeps a new keyframe's images; forgets those of culled keyframes once they are as many
    as the live ones, so memory follows the map."""
    _add_keyframe(images, timestamp_s, feed, data)
    if len(images) > 2 * system.num_keyframes:
        images.keep_only(system.keyframe_trajectory()[1])


def _complete_keyframe_images(images: KeyframeImages, keyframe_stamps: np.ndarray, seq,
                              feed) -> None:
    """Keeps exactly the images of the map's keyframes: those of culled keyframes go, and a
    keyframe no track result announced (a monocular map's first, chosen when the second
    view came) is loaded again from the sequence."""
    images.keep_only(keyframe_stamps)
    frame_of = {float(t): i for i, t in enumerate(seq.timestamps)}
    for t in keyframe_stamps:
        if t not in images and float(t) in frame_of:
            try:
                data = feed.load(frame_of[float(t)])
            except (OSError, ValueError):
                continue  # the model names the image all the same; the run's error says why
            _add_keyframe(images, float(t), feed, data)


def _fuse_keyframes(camera: Camera, keyframes: Trajectory, images: KeyframeImages,
                    config: dict) -> DenseModel:
    """The TSDF mesh of the run's keyframes at their final poses."""
    return fuse_tsdf(camera, keyframes.poses, [images.image(t) for t in keyframes.timestamps],
                     [images.depth_m(t) for t in keyframes.timestamps],
                     voxel_m=pipeline_default(config, "dense_voxel_m"),
                     truncation_m=pipeline_default(config, "dense_truncation_m"),
                     max_depth_m=pipeline_default(config, "dense_max_depth_m"))


def _jsonable(value):
    """``value`` with numpy arrays and scalars turned into lists and floats."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _run(seq, session: Session, feed, n: int, sensor: str, config: dict, progress: bool,
         realtime: bool, imu, on_frame: Optional[Callable[..., None]] = None) -> RunResult:
    system = session.system
    timings = {name: np.full(n, np.nan) for name in _TIMINGS}
    states: list[str] = []
    init_reasons: list[Optional[str]] = []
    num_tracked = np.zeros(n, dtype=np.int64)
    bar = tqdm(range(n), disable=not progress, desc=getattr(seq, "name", "sequence"), unit="frame")
    start = time.perf_counter()
    imu_from = 0
    imu_period_s = 1.0 / float(seq.imu_params().rate_hz) if imu is not None else 0.0
    failure: Optional[tuple[int, Exception]] = None
    dense = bool(pipeline_default(config, "dense"))
    keyframe_images = KeyframeImages(keep_depth=dense)
    for i in bar:
        if realtime:
            time.sleep(max(0.0, start + float(seq.timestamps[i] - seq.timestamps[0])
                           - time.perf_counter()))
        try:
            t0 = time.perf_counter()
            data = feed.load(i)
            t1 = time.perf_counter()
            frame = feed.frame(data)
            if imu is not None:
                imu_to = imu_batch_end(imu[0], float(seq.timestamps[i]), imu_period_s,
                                       float(config.get("imu_time_offset_s", 0.0)))
                if imu_to > imu_from:
                    system.add_imu(*(a[imu_from:imu_to] for a in imu))
                imu_from = imu_to
            t2 = time.perf_counter()
            res = session.track(float(seq.timestamps[i]), **frame)
            if res.is_keyframe:
                _keep_keyframe(keyframe_images, system, float(seq.timestamps[i]), feed, data)
            if on_frame is not None:
                on_frame(res, image=feed.image(data), keypoints=res.keypoints,
                         timestamp_s=float(seq.timestamps[i]), system=system)
        except Exception as err:  # noqa: BLE001 - raised again with the frames done
            failure = (i, err)
            break
        t3 = time.perf_counter()
        timings["load_ms"][i] = (t1 - t0) * 1e3
        timings["extraction_ms"][i] = float(res.extraction_ms)
        timings["track_call_ms"][i] = (t3 - t2) * 1e3
        timings["frame_ms"][i] = (t3 - t1) * 1e3
        timings["tracking_ms"][i] = float(res.tracking_ms)
        timings["mapping_ms"][i] = float(res.mapping_ms)
        timings["pose_optimisation_ms"][i] = float(res.pose_optimisation_ms)
        timings["matching_ms"][i] = float(res.tracking_ms) - float(res.pose_optimisation_ms)
        timings["local_ba_ms"][i] = float(res.local_ba_ms)
        timings["loop_closing_ms"][i] = float(res.loop_closing_ms)
        states.append(str(res.state))
        init_reasons.append(getattr(res, "init_reason", None))
        num_tracked[i] = int(res.num_tracked)
        if progress:
            bar.set_postfix(state=res.state, tracked=res.num_tracked, refresh=False)
    bar.close()
    try:
        system.wait()  # the mapping thread's last keyframes (no-op when mapping inline)
    except Exception:  # noqa: BLE001 - the first error is the one to report
        if failure is None:
            raise
    done = len(states)
    result = RunResult(
        sequence=str(getattr(seq, "name", "")),
        sensor=sensor,
        config=config,
        timestamps=np.asarray(seq.timestamps[:done], dtype=np.float64),
        states=states,
        num_tracked=num_tracked[:done],
        timings={name: values[:done] for name, values in timings.items()},
        init_reasons=init_reasons,
        inertial=system.inertial_alignment() if imu is not None else None,
        camera=getattr(seq, "camera", None),
        keyframe_images=keyframe_images,
        **_map_outputs(system),
    )
    _complete_keyframe_images(keyframe_images, result.keyframes.timestamps, seq, feed)
    if dense and failure is None:
        result.dense = _fuse_keyframes(seq.camera, result.keyframes, keyframe_images, config)
    evaluation_error = None
    if getattr(seq, "has_groundtruth", False):
        try:
            result.groundtruth = Trajectory(*seq.groundtruth())
        except (OSError, ValueError) as err:
            evaluation_error = err
        else:
            _evaluate(result, result.groundtruth)
    if failure is not None:
        i, err = failure
        raise RunError(f"frame {i} ({type(err).__name__}): {err}", result, i) from err
    if evaluation_error is not None:
        raise RunError(f"ground truth: {evaluation_error}", result, None) from evaluation_error
    return result
