"""A live 3-D view of a run in Rerun (https://rerun.io): the camera, its image, the map.

Needs the optional extra ``pip install "ferroslam[viewer]"`` (``rerun-sdk``).

Frames, stated once for the whole module:

* The world is ferroslam's map frame, the first keyframe's camera frame (also with an IMU:
  the map is not rotated to gravity), so ``world`` is logged as RDF: x right, y down,
  z forward, as OpenCV.
* ``world/camera`` carries ``T_w_c`` (metres; map units for monocular maps), which maps
  camera points into the world. Rerun's ``Transform3D`` maps an entity's points into its
  parent's, so ``T_w_c`` is logged as it is, never inverted.
* ``world/camera/image`` is the pinhole of the ``ferroslam.Camera`` (RDF) with the image
  and, below it, the keypoints in raw pixels.

Entities: ``world/map/points`` (map points in the colour of the image pixel each was
first seen at), ``world/map/keyframes`` (keyframe centres as
one line strip), ``world/map/loops`` (one segment per loop closure, between the two
keyframes' centres), ``tracking/state`` (text log: state changes, loop closures, a new
current map and merges), ``tracking/num_tracked`` and ``tracking/map_id`` (scalars: the map
each pose is in; a merged map's poses move into the older map's world). Timelines: ``frame`` (frame index) and ``time``
(the frame's timestamp as a duration in seconds: dataset clocks start at the epoch (TUM,
EuRoC) or at 0 (KITTI), so it is not shown as a date).

Three ways in: :meth:`RerunLogger.log_frame` per frame, :func:`make_frame_callback` for the
``on_frame`` hook of the vSLAM objects, and :meth:`RerunLogger.log_run` for a finished
:class:`ferroslam.pipeline.RunResult`.
"""

from __future__ import annotations

import itertools
from contextlib import ExitStack
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np

from ._files import atomic_output
from ._validate import finite_array
from .camera import Camera
from .datasets import frame_images
from .export import _colors_u8

__all__ = ["RerunLogger", "make_frame_callback"]

CAMERA = "world/camera"
IMAGE = "world/camera/image"
KEYPOINTS = "world/camera/image/keypoints"
MAP_POINTS = "world/map/points"
KEYFRAMES = "world/map/keyframes"
LOOPS = "world/map/loops"
MESH = "world/map/mesh"
STATE = "tracking/state"
NUM_TRACKED = "tracking/num_tracked"
MAP_ID = "tracking/map_id"
# Map points without colours.
_GREY = (128, 128, 128)
_STATE_LEVEL = {"ok": "INFO", "not_initialized": "INFO"}  # the other states: WARN


def _rerun() -> Any:
    """The ``rerun`` module, imported only when a logger is made: the viewer is optional."""
    try:
        import rerun
    except ImportError as err:
        raise ImportError(
            f"the Rerun viewer needs rerun-sdk ({err}); install it with "
            '`pip install "ferroslam[viewer]"`'
        ) from err
    return rerun


class RerunLogger:
    """Logs frames, maps and whole runs to one Rerun recording (frames: see the module doc).

    Give exactly one destination: ``spawn=True`` starts (or connects to) a Rerun viewer on
    this machine, ``save_path`` writes an ``.rrd`` file to open later (``rerun run.rrd``),
    ``recording`` logs to a ``rerun.RecordingStream`` of the caller's (which keeps its own
    sinks and application id). ``jpeg_quality`` (1-100) sends images JPEG-compressed, for
    long runs (a 640x480 grey frame is 300 kB raw); ``None`` sends them raw.

    Raises:
        ImportError: rerun-sdk is not installed (the message says how to install it).
        ValueError: no destination, or more than one; ``jpeg_quality`` out of range.
    """

    def __init__(self, application_id: str = "ferroslam", *, spawn: bool = False,
                 save_path: Optional[Union[str, Path]] = None, recording: Any = None,
                 jpeg_quality: Optional[int] = None) -> None:
        self._rr = _rerun()
        if jpeg_quality is not None and (isinstance(jpeg_quality, bool) or not (
                isinstance(jpeg_quality, int) and 1 <= jpeg_quality <= 100)):
            raise ValueError(f"jpeg_quality must be an integer in 1..=100, got {jpeg_quality!r}")
        self.jpeg_quality = jpeg_quality
        choices = (("spawn", bool(spawn)), ("save_path", save_path is not None),
                   ("recording", recording is not None))
        given = [name for name, used in choices if used]
        if len(given) != 1:
            raise ValueError("RerunLogger needs one destination: spawn=True, save_path=... or "
                             f"recording=...; got {given or 'none'}")
        self._owned = recording is None
        self.recording = recording if recording is not None else self._rr.RecordingStream(
            application_id)
        # The .rrd file is recorded to a temporary file beside save_path (its folder created
        # first) and moved there by close(): a recording is complete or absent.
        self._output = ExitStack()
        if spawn:
            self.recording.spawn()
        elif save_path is not None:
            with ExitStack() as opening:
                self.recording.save(opening.enter_context(atomic_output(save_path)))
                self._output = opening.pop_all()
        self.recording.log("world", self._rr.ViewCoordinates.RDF, static=True)
        self._camera: Optional[Camera] = None
        self._state: Optional[str] = None
        self._map_id: Optional[int] = None

    # -- per frame --------------------------------------------------------------------------
    def log_frame(self, index: int, timestamp_s: Optional[float], image: Optional[np.ndarray],
                  camera: Camera, result: Any, keypoints: Optional[np.ndarray] = None) -> None:
        """Logs one tracked frame at ``frame = index`` (and ``time = timestamp_s`` unless
        ``None``): the camera pose ``result.T_w_c`` (left at the last pose while the frame is
        not tracked), the pinhole of ``camera``, ``image`` (``(H, W)`` grey or ``(H, W, 3)``
        BGR, as OpenCV reads it; ``None``: none), ``keypoints`` (``(N, 2+)`` raw pixels,
        e.g. ``OrbExtractor.detect``'s ``(N, 5)``: the frame's detected features, as the
        core does not say which of them it tracked) and the tracking state.

        ``result``: a ``ferroslam._core.TrackResult`` (``state``, ``T_w_c``,
        ``num_tracked``, ``loop_closed``, ``map_id``, ``merge``).
        """
        self._set_time(index, timestamp_s)
        self._log_view(camera, image, keypoints)
        self._log_track(result.T_w_c, str(result.state), int(result.num_tracked),
                        bool(result.loop_closed))
        self._log_maps(int(result.map_id), result.merge)

    def _set_time(self, index: int, timestamp_s: Optional[float]) -> None:
        self.recording.set_time("frame", sequence=int(index))
        if timestamp_s is None:  # the time of an earlier frame must not stick to this one
            self.recording.disable_timeline("time")
        else:
            self.recording.set_time("time", duration=float(timestamp_s))

    def _log_view(self, camera: Camera, image: Optional[np.ndarray],
                  keypoints: Optional[np.ndarray]) -> None:
        """The pinhole (static, logged again only for another camera), image and keypoints."""
        rr = self._rr
        if camera is not self._camera:
            self.recording.log(IMAGE, rr.Pinhole(
                focal_length=[camera.fx, camera.fy], principal_point=[camera.cx, camera.cy],
                width=camera.width, height=camera.height, camera_xyz=rr.ViewCoordinates.RDF),
                static=True)
            self._camera = camera
        if image is not None:
            camera.check_image(image)
            picture = rr.Image(image, color_model="BGR" if np.ndim(image) == 3 else None)
            self.recording.log(IMAGE, picture if self.jpeg_quality is None
                               else picture.compress(self.jpeg_quality))
        if keypoints is not None:
            uv = finite_array(keypoints, "keypoints", (None, None))[:, :2]
            if uv.shape[1] != 2:
                raise ValueError(f"keypoints must have shape (N, 2+), got {np.shape(keypoints)}")
            self.recording.log(KEYPOINTS, rr.Points2D(uv, radii=2.0, colors=(0, 255, 0)))

    def _log_track(self, T_w_c: Optional[np.ndarray], state: str, num_tracked: int,
                   loop_closed: bool) -> None:
        """The pose when there is one, ``num_tracked`` every frame, text on events only (a
        line per frame would bury the state changes)."""
        rr = self._rr
        if T_w_c is not None:
            T = finite_array(T_w_c, "T_w_c", (4, 4))
            self.recording.log(CAMERA, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.recording.log(NUM_TRACKED, rr.Scalars(num_tracked))
        if state != self._state:
            self.recording.log(STATE, rr.TextLog(f"{state} ({num_tracked} tracked)",
                                                 level=_STATE_LEVEL.get(state, "WARN")))
            self._state = state
        if loop_closed:
            self.recording.log(STATE, rr.TextLog("loop closed", level="INFO"))

    def _log_maps(self, map_id: int, merge: Optional[dict]) -> None:
        """The map id every frame, text when the current map changes or a merge joins two."""
        rr = self._rr
        self.recording.log(MAP_ID, rr.Scalars(map_id))
        if merge is not None:
            self.recording.log(STATE, rr.TextLog(
                f"map {merge['merged_map']} merged into map {merge['into_map']} "
                f"({merge['num_matches']} points matched)", level="INFO"))
        elif self._map_id is not None and map_id != self._map_id:
            self.recording.log(STATE, rr.TextLog(f"tracking in map {map_id}", level="WARN"))
        self._map_id = merge["into_map"] if merge is not None else map_id

    # -- the map ----------------------------------------------------------------------------
    def log_map(self, points_xyz: np.ndarray, colors: Optional[np.ndarray] = None,
                keyframe_poses_T_w_c: Optional[np.ndarray] = None,
                loops: Optional[Sequence[dict]] = None,
                keyframe_ids: Optional[Union[Sequence[int], np.ndarray]] = None) -> None:
        """Logs the map at the current time (it replaces the previous one in the view).

        Args:
            points_xyz: ``(M, 3)`` world points.
            colors: ``(M, 3)`` RGB, integers in ``[0, 255]`` or floats in ``[0, 1]``;
                ``None``: all grey.
            keyframe_poses_T_w_c: ``(K, 4, 4)``, in keyframe order; their centres are
                joined in one line strip.
            loops: loop closures as ``SlamSystem.loops()`` gives them (dicts with the
                ``current`` and ``matched`` keyframe ids); a loop whose keyframe is not
                among ``keyframe_ids`` (culled since) is left out.
            keyframe_ids: ``(K,)`` the ids of ``keyframe_poses_T_w_c``; needed for loops.

        Raises:
            ValueError: wrong shapes, non-finite values, colours out of range, loops without
                keyframe poses and ids.
        """
        rr = self._rr
        xyz = finite_array(points_xyz, "points_xyz", (None, 3))
        rgb = _GREY if colors is None else _colors_u8(colors, len(xyz))
        self.recording.log(MAP_POINTS, rr.Points3D(xyz, colors=rgb, radii=rr.Radius.ui_points(2.0)))
        if keyframe_poses_T_w_c is not None:
            centres = finite_array(keyframe_poses_T_w_c, "keyframe_poses_T_w_c",
                                   (None, 4, 4))[:, :3, 3]
            self.recording.log(KEYFRAMES, rr.LineStrips3D([centres], colors=(0, 120, 255)))
        if loops is not None:
            self.recording.log(LOOPS, rr.LineStrips3D(
                _loop_segments(loops, keyframe_ids, keyframe_poses_T_w_c), colors=(255, 0, 0)))

    def log_mesh(self, dense: Any) -> None:
        """Logs a fused surface (``ferroslam.dense.DenseModel``: vertices, triangles, vertex
        colours) at the current time."""
        self.recording.log(MESH, self._rr.Mesh3D(
            vertex_positions=dense.vertices.astype(np.float32),
            triangle_indices=dense.triangles.astype(np.uint32),
            vertex_colors=dense.vertex_colors))

    def log_system(self, system: Any) -> None:
        """Logs the current map of a ``ferroslam._core.SlamSystem``: points in their colours,
        keyframes and loops (see :meth:`log_map`)."""
        ids, _, poses = system.keyframe_trajectory()
        self.log_map(np.asarray(system.map_points()).reshape(-1, 3),
                     np.asarray(system.map_point_colors()).reshape(-1, 3),
                     keyframe_poses_T_w_c=np.asarray(poses).reshape(-1, 4, 4),
                     loops=system.loops(), keyframe_ids=np.asarray(ids).reshape(-1))

    # -- a finished run ---------------------------------------------------------------------
    def log_run(self, result: Any, sequence: Any = None) -> None:
        """Logs a finished ``ferroslam.pipeline.RunResult`` after the fact: every frame's state
        and final (bundle-adjusted) pose, then the map at the last frame.

        ``sequence``: the run's dataset sequence, to log each frame's image too (its
        ``camera`` and its image, in colour where it has one: ``ferroslam.datasets.
        frame_images``); without it, ``result.camera`` gives the pinhole.
        """
        camera = sequence.camera if sequence is not None else result.camera
        poses = dict(zip(result.trajectory.timestamps.tolist(), result.trajectory.poses))
        closing = {float(lp["timestamps"][0]) for lp in result.loops}
        for i, t in enumerate(result.timestamps.tolist()):
            self._set_time(i, t)
            if camera is not None:
                image = None if sequence is None else frame_images(sequence, i)[1]
                self._log_view(camera, image, None)
            self._log_track(poses.get(t), result.states[i], int(result.num_tracked[i]),
                            t in closing)
        self.log_map(result.map_points, result.map_point_colors,
                     keyframe_poses_T_w_c=result.keyframes.poses, loops=result.loops,
                     keyframe_ids=result.keyframe_ids)
        if getattr(result, "dense", None) is not None:
            self.log_mesh(result.dense)

    # -- lifetime ---------------------------------------------------------------------------
    def close(self) -> None:
        """Sends what is buffered; a recording this logger made is then disconnected and an
        ``.rrd`` file moved to ``save_path`` (it appears there only now). Idempotent."""
        self.recording.flush()
        if self._owned:
            self.recording.disconnect()
        self._output.close()

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _loop_segments(loops: Sequence[dict],
                   keyframe_ids: Optional[Union[Sequence[int], np.ndarray]],
                   keyframe_poses_T_w_c: Optional[np.ndarray]) -> list[np.ndarray]:
    """``(2, 3)`` segments between the centres of each loop's two keyframes."""
    if keyframe_ids is None or keyframe_poses_T_w_c is None:
        raise ValueError("loops need keyframe_poses_T_w_c and keyframe_ids to place them")
    ids = np.asarray(keyframe_ids).reshape(-1).tolist()
    centres = np.asarray(keyframe_poses_T_w_c, dtype=np.float64)[:, :3, 3]
    if len(ids) != len(centres):
        raise ValueError(f"{len(ids)} keyframe_ids but {len(centres)} keyframe poses")
    where = {kf: centres[k] for k, kf in enumerate(ids)}
    return [np.stack([where[lp["current"]], where[lp["matched"]]]) for lp in loops
            if lp["current"] in where and lp["matched"] in where]


def make_frame_callback(logger: RerunLogger, camera: Camera, *,
                        system: Any = None) -> Callable[..., None]:
    """A per-frame hook, ``on_frame(result, image=None, keypoints=None, timestamp_s=None,
    system=None)``, for the vSLAM objects' ``on_frame`` or ``run_sequence``'s: logs each
    result with :meth:`RerunLogger.log_frame`, and with ``system`` (the ``SlamSystem``
    tracking; given here or per call, as ``run_sequence`` does) the map at every keyframe,
    so the view grows as the map does.

    ``result``: a ``TrackResult``, logged as the next frame (indices from 0, in the order
    called), or a vSLAM ``FrameResult`` (``index``, ``timestamp_s``, ``track``), logged at
    its own index and time.
    """
    frames = itertools.count()

    def on_frame(result: Any, image: Optional[np.ndarray] = None,
                 keypoints: Optional[np.ndarray] = None,
                 timestamp_s: Optional[float] = None, system: Any = system) -> None:
        if hasattr(result, "track"):  # a FrameResult: the vSLAM object counts the frames
            index, timestamp_s, result = result.index, result.timestamp_s, result.track
        else:
            index = next(frames)
        logger.log_frame(index, timestamp_s, image, camera, result, keypoints)
        if system is not None and result.is_keyframe:
            logger.log_system(system)

    return on_frame
