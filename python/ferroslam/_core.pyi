"""Type stub of ``ferroslam._core``, the native module built from ``crates/python/src``.

Conventions: ``T_w_c`` maps camera points into the world (p_w = T_w_c @ p_c), as (4, 4)
float64 homogeneous matrices; metres, pixels, seconds. Bad input raises ``TypeError``
(wrong array dtype/rank, wrong option type) or ``ValueError`` (wrong shape, lengths,
values, configuration), always naming the problem; ``SlamError`` is an internal failure.
"""

import os
import sys
from typing import (Any, Iterable, Literal, Optional, Protocol, Sequence, TypedDict, Union,
                    final)

import numpy as np
from numpy.typing import NDArray

if sys.version_info >= (3, 11):
    from typing import Unpack
else:
    from typing_extensions import Unpack

__all__ = [
    "KeyframeDatabase", "OrbExtractor", "SlamError", "SlamSystem", "TrackResult", "Vocabulary",
    "__version__", "default_options", "load_sparse_model", "match_stereo", "merge_map_files",
    "option_table",
    "project_points", "unproject_pixels",
]

__version__: str
"""Version of the Rust crate the module was built from."""

_State = Literal["not_initialized", "ok", "lost", "recently_lost"]
_Sensor = Literal["mono", "stereo", "rgbd"]
_CameraModel = Literal["pinhole", "kannala_brandt"]
_Floats = Union[Sequence[float], NDArray[np.floating[Any]]]

class _SlamOptions(TypedDict, total=False):
    """Keyword options of ``SlamSystem``; any other name raises ``ValueError`` listing the
    valid ones. A value of the wrong type raises ``TypeError`` naming the option and the type
    expected; a value out of range, ``ValueError`` naming the field of the core's
    configuration it sets (``tracking.skip_max_frames``, ``depth.bf``, ...).

    Omitted options take the defaults of the sensor and image width
    (:func:`default_options`, the presets ``SlamConfig::for_camera`` in
    ``crates/slam/src/config/``); :func:`option_table` gives each option's type, range, unit
    and defaults (``docs/options.md`` is generated from it), so they are not repeated here.
    """

    n_features: int
    """ORB keypoints per image (ORB-SLAM ``nFeatures``); the default follows the image width.
    The extractor's option: the core holds it so that every front end reads one default."""
    ini_fast: int
    """FAST threshold tried first in every extractor cell (the extractor's default,
    ``OrbExtractor().ini_fast``)."""
    min_fast: int
    """FAST threshold of cells where ``ini_fast`` finds nothing, at most ``ini_fast`` (the
    extractor's default)."""
    scale_factor: float
    """Scale between ORB pyramid levels (the extractor's default)."""
    n_levels: int
    """ORB pyramid levels; keypoint octaves must be below it (the extractor's default)."""
    track_feature_range: Sequence[int]
    """(lower, upper), lower below upper (MATLAB ``TrackFeatureRange``): tracking fails
    with fewer than ``lower`` inliers; fewer than ``upper`` makes the frame a keyframe
    (monocular: only below 0.9 of the reference keyframe's points too, as in MATLAB's
    monocular example; ORB-SLAM's keyframe rules apply too)."""
    skip_max_frames: int
    """Frames after which a keyframe is inserted regardless of tracking quality."""
    relocalisation_window_s: float
    """Seconds a lost map tries to relocalise before the atlas keeps it and a new map
    starts (monocular, or with a vocabulary to find it again)."""
    gap_frames: int
    """Frames without a pose (lost, before a map starts) kept and tracked backwards once a
    later frame is tracked, so the trajectory fills in behind the live results; 0 keeps
    none (visual maps only)."""
    bf: float
    """RGB-D only: fx * baseline of the virtual right camera, pixels * metres."""
    baseline: float
    """Stereo only (required): baseline of the rectified pair in metres; bf = fx * it."""
    depth_threshold: float
    """Close-point threshold in baselines."""
    depth_range: Sequence[float]
    """(min, max) valid depth in metres (max may be inf); the default depends on the
    sensor."""
    match_pair_every_frame: bool
    """Unrectified stereo pair only: match it at every frame (default); False: only at the
    frames that become keyframes, where its two cameras are triangulated."""
    seed: int
    """Seed of every random choice (RANSAC)."""
    deterministic: bool
    """With the mapping thread, wait for each keyframe's mapping before the next frame so
    that poses and map equal the inline run's (off: tracking runs ahead)."""
    loop_closure: bool
    """Detect and close loops once a vocabulary is set."""
    loop_closure_threshold: int
    """Matched map points a verified loop needs (MATLAB ``LoopClosureThreshold``)."""

class SlamError(RuntimeError):
    """Base class of ferroslam errors that are not plain bad input (internal failures)."""

@final
class TrackResult:
    """Result of tracking one frame (returned by ``SlamSystem.track`` and ``track_*``,
    immutable)."""

    @property
    def state(self) -> _State:
        """Tracking state after this frame: ``"recently_lost"`` when vision failed and the pose
        is the IMU's prediction (aligned visual-inertial maps, at most 5 s)."""
    @property
    def T_w_c(self) -> NDArray[np.float64] | None:
        """Camera pose in the world, (4, 4) float64 (the IMU's prediction when ``recently_lost``),
        or None when the frame was not tracked."""
    @property
    def map_id(self) -> int:
        """The map ``T_w_c`` is in (see ``SlamSystem.maps``)."""
    @property
    def merge(self) -> dict[str, Any] | None:
        """The merge this frame made: ``merged_map`` (joined into) ``into_map``, whose id and
        world the merged map keeps; keyframes ``current`` and ``matched``, their
        ``timestamps`` (s), ``num_matches``, the similarity's ``scale`` (1 with depth),
        the essential graph's ``graph_cost`` (before, after) and ``welded_keyframes`` (the
        seam's local BA)."""
    @property
    def is_keyframe(self) -> bool:
        """Whether this frame became a keyframe."""
    @property
    def num_tracked(self) -> int:
        """Map points tracked as inliers."""
    @property
    def tracking_ms(self) -> float:
        """Tracking wall time, milliseconds (after the front end)."""
    @property
    def extraction_ms(self) -> float:
        """The front end's wall time inside ``track`` (extraction, masks, sampling),
        milliseconds; 0 for the features-level ``track_*``."""
    @property
    def keypoints(self) -> NDArray[np.float32]:
        """The first camera's raw keypoints as ``track`` extracted them, (N, 5) float32
        ``[x, y, octave, angle_deg, response]``; (0, 5) for the features-level ``track_*``."""
    @property
    def camera_keypoints(self) -> list[NDArray[np.float32]]:
        """Every camera's raw keypoints as ``track`` extracted them (stereo: left, right),
        each (N, 5) float32 as ``keypoints``; empty for the features-level ``track_*``."""
    @property
    def mapping_ms(self) -> float:
        """Local mapping wall time, milliseconds (0 unless a keyframe was inserted)."""
    @property
    def pose_optimisation_ms(self) -> float:
        """Of ``tracking_ms``, the time spent in motion-only BA, milliseconds."""
    @property
    def local_ba_ms(self) -> float:
        """Of ``mapping_ms``, local BA, milliseconds (mapping inside the call; else 0)."""
    @property
    def loop_closing_ms(self) -> float:
        """Of ``mapping_ms``, loop detection, verification and correction, milliseconds
        (mapping inside the call; else 0)."""
    @property
    def init_reason(self) -> str | None:
        """Monocular, before the map exists: why this frame did not start it (too few
        matches, degenerate pair refused by the two-view reconstruction, ...); else None."""
    @property
    def loop_closed(self) -> bool:
        """Whether this frame's keyframe closed a loop (details: ``SlamSystem.loops()``)."""

@final
class SlamSystem:
    """The SLAM system. By default tracking, local mapping and loop closing run inside each
    ``track_*`` call (deterministic); ``threaded=True`` tracks in a background thread fed
    through a bounded queue, and ``set_mapping_thread(True)`` (implied by ``threaded``) maps in
    another."""

    def __new__(
        cls,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        dist: _Floats,
        width: int,
        height: int,
        *,
        sensor: _Sensor = "rgbd",
        model: _CameraModel = "pinhole",
        rolling_shutter_readout_s: float = 0.0,
        threaded: bool = False,
        right_camera: Optional[Any] = None,
        T_left_right: Optional[NDArray[np.float64]] = None,
        cameras: Optional[Sequence[tuple[Any, NDArray[np.float64]] | tuple[Any, NDArray[np.float64], bool | tuple[Any, NDArray[np.float64]]]]] = None,
        **options: Unpack[_SlamOptions],
    ) -> SlamSystem:
        """Creates a system for a pinhole + radial-tangential or a Kannala-Brandt camera.

        Args:
            fx, fy, cx, cy: intrinsics in pixels (fx, fy > 0).
            dist: pinhole: 0, 4 or 5 coefficients ``k1 k2 p1 p2 [k3]``; kannala_brandt: 4
                coefficients ``k1 k2 k3 k4``.
            width, height: image size in pixels (> 0).
            sensor: ``"mono"``, ``"rgbd"`` or ``"stereo"`` (rectified pair: ``dist`` must be
                zeros and ``baseline`` is required; or an unrectified pair with
                ``right_camera`` and ``T_left_right``); others raise ``NotImplementedError``.
            model: ``"pinhole"`` or ``"kannala_brandt"`` (a fisheye, tracked on unit rays so
                that fields of view beyond 180 degrees work; with ``sensor="stereo"`` only as
                an unrectified pair).
            rolling_shutter_readout_s: seconds the sensor reads its rows over, top first
                (>= 0, finite; 0 = global shutter, today's arithmetic): each keypoint is seen
                from the pose at its row's time, the frame's velocity estimated with its pose
                (``ferroslam.Camera.rolling_shutter_readout_s``).
            threaded: process frames in a background thread fed through a bounded queue
                (8 frames; ``track_*`` block when it is full): ``track_*`` check the input,
                queue the frame and return None; ``take_results`` gives the results in order.
                Frames are processed in call order, so results equal the synchronous mode's.
            right_camera: with ``T_left_right``, the second camera of an UNRECTIFIED stereo
                pair (a ``ferroslam.Camera``, raw, any model, the first camera's image size):
                the left keypoints are matched into the raw right image along epipolar curves
                on unit rays and triangulated; the baseline is ``T_left_right``'s (pass no
                ``baseline`` or ``bf``).
            T_left_right: ``(4, 4)`` float64 pose of the right camera in the left one
                (``p_left = T_left_right @ p_right``, metres).
            cameras: the rig's further cameras, ``(camera, T_c0_c)`` or ``(camera, T_c0_c,
                depth)`` each: a ``ferroslam.Camera`` (raw, any model and size), its
                ``(4, 4)`` pose in the first camera (``p_0 = T_c0_c @ p``, metres) and
                ``depth``: ``True`` when its frames come with a depth image, or
                ``(partner_camera, T_left_right)`` for a stereo partner (its pose in this
                camera), whose image follows this camera's and gives its keypoints depth by
                matching along epipolar curves (a rig of several stereo pairs). Their images
                follow the first camera's (and the pair partner's) in every ``track``; their
                keypoints are tracked, optimised and triangulated with the first camera's,
                each at its own rows' times with a rolling shutter. Not with
                ``sensor="mono"``.
            options: see ``_SlamOptions``.

        Raises:
            ValueError: invalid camera, camera model or option value, unknown option name, a
                stereo sensor with a rectified fisheye camera; only one of ``right_camera`` and
                ``T_left_right``; a pair of different image sizes or no baseline; ``baseline``
                or ``bf`` with a pair.
            TypeError: option of the wrong type.
            NotImplementedError: an unknown sensor.
        """
    def track(
        self,
        timestamp: float,
        images: NDArray[np.uint8] | Sequence[NDArray[np.uint8]],
        *,
        depth: NDArray[np.floating] | Sequence[NDArray[np.floating] | None] | None = None,
        colors: NDArray[np.uint8] | Sequence[NDArray[np.uint8] | None] | None = None,
        masks: NDArray[Any] | Sequence[NDArray[Any] | None] | None = None,
    ) -> TrackResult | None:
        """Tracks one instant of the camera(s) from images, the door every frame goes
        through (queues it in threaded mode and returns None): ORB extraction of every image
        in parallel, the masks, depth and colour at the keypoints and stereo matching run in
        the core without the GIL.

        Args:
            timestamp: seconds, finite, strictly after the previous accepted frame's.
            images: one uint8 image, grey (H, W) or BGR (H, W, 3), or one per camera
                (stereo: ``(left, right)``, rectified), each the camera's size.
            depth: (H, W) float32/float64 metres registered to the first image (RGB-D only;
                0, negative or NaN = none), or one per image (None where a camera has no
                depth) for a rig with depth cameras.
            colors: the first image in colour when ``images`` is grey (map point colours);
                per image, or one array for one camera.
            masks: per image a (H, W) uint8/bool mask, 0 = no keypoint there (on top of
                ``set_mask``'s static mask), or None.

        Raises:
            ValueError: the wrong number of images for the sensor, an image, colour image,
                mask or depth of another size than the camera or of another dtype or rank,
                depth for a sensor other than RGB-D (or none for RGB-D), a timestamp not
                after the previous one; the system is unchanged.
            TypeError: an argument that is not a numpy array.
        """
    def set_mask(self, camera: int, mask: NDArray[Any] | None) -> None:
        """Sets camera ``camera``'s static mask ((H, W) uint8/bool, 0 = no keypoint there),
        applied to every frame ``track`` measures; None removes it.

        Raises:
            ValueError: a camera the system does not have, a mask of another size or dtype.
        """
    def track_rgbd(
        self,
        timestamp: float,
        keypoints: NDArray[np.float32],
        descriptors: NDArray[np.uint8],
        depth_m: NDArray[np.float32],
        *,
        colors: NDArray[np.uint8] | None = None,
    ) -> TrackResult | None:
        """Tracks one RGB-D frame (the GIL is released while it runs); the system must have
        been created with ``sensor="rgbd"``.

        Args:
            timestamp: seconds, finite, strictly after the previous accepted frame's.
            keypoints: (N, 5) float32 ``[x, y, octave, angle_deg, response]``, raw
                (distorted) pixels; finite; octave an integer in ``[0, n_levels)``.
            descriptors: (N, 32) uint8, 256-bit ORB.
            depth_m: (N,) float32 depth at each keypoint in metres (0, NaN or out of
                ``depth_range`` = no depth).
            colors: (N, 3) uint8 RGB of each keypoint (``ferroslam.features.sample_colors``);
                a map point made from a keypoint keeps its colour (``map_point_colors``).
                ``None``: the frame's points have no colour.

        Raises:
            TypeError: an array of the wrong dtype or rank (or not an array).
            ValueError: wrong shape, lengths differ, NaN/inf keypoints, bad octave,
                timestamp not increasing; the system is unchanged then.
            SlamError: internal failure.
        """
    def track_stereo(
        self,
        timestamp: float,
        left_keypoints: NDArray[np.float32],
        left_descriptors: NDArray[np.uint8],
        left_pyramid: Sequence[NDArray[np.uint8]],
        right_keypoints: NDArray[np.float32],
        right_descriptors: NDArray[np.uint8],
        right_pyramid: Sequence[NDArray[np.uint8]],
        *,
        colors: NDArray[np.uint8] | None = None,
    ) -> TrackResult | None:
        """Tracks one rectified stereo pair (the GIL is released while it runs).

        Left keypoints are matched into the right image (row band, octave, Hamming distance,
        SAD refinement on the keypoint's pyramid level); depth is ``bf / disparity``.

        Args:
            timestamp: seconds, finite, strictly after the previous accepted frame's.
            left_keypoints, right_keypoints: (N, 5) float32 ``[x, y, octave, angle_deg,
                response]`` in rectified pixels.
            left_descriptors, right_descriptors: (N, 32) uint8.
            left_pyramid, right_pyramid: the images' pyramids (level ``l`` scaled by
                ``scale_factor ** -l``), 2-D uint8, same sizes left and right, at least
                one level beyond the highest octave.
            colors: (N, 3) uint8 RGB of each LEFT keypoint, as ``track_rgbd``'s.

        Raises:
            TypeError: an array of the wrong dtype or rank (or not an array).
            ValueError: as ``track_rgbd``; a system not created with ``sensor="stereo"``,
                a camera with distortion, missing pyramid levels, left/right sizes differ.
            SlamError: internal failure.
        """
    def track_mono(
        self,
        timestamp: float,
        keypoints: NDArray[np.float32],
        descriptors: NDArray[np.uint8],
        *,
        colors: NDArray[np.uint8] | None = None,
    ) -> TrackResult | None:
        """Tracks one monocular frame (the GIL is released while it runs). Until the map
        exists every frame is offered to two-view initialisation (see
        ``TrackResult.init_reason``); a map that stays lost for a second goes to the
        atlas and a new one starts (see ``maps``).

        Args:
            timestamp: seconds, finite, strictly after the previous accepted frame's.
            keypoints: (N, 5) float32 ``[x, y, octave, angle_deg, response]``, raw pixels.
            descriptors: (N, 32) uint8.
            colors: (N, 3) uint8 RGB of each keypoint, as ``track_rgbd``'s.

        Raises:
            TypeError / ValueError: as ``track_rgbd``; a system not created with
                ``sensor="mono"``.
            SlamError: internal failure.
        """
    def take_results(self) -> list[TrackResult]:
        """Threaded mode: the results of the frames processed since the last call, in order
        (a frame the core rejected raises here). Synchronous mode: always empty."""
    def is_done(self) -> bool:
        """Whether every submitted frame has been tracked and mapped (always true
        synchronously)."""
    def close(self) -> None:
        """Finishes the submitted frames, stops and joins every thread the system started;
        it stays usable with mapping inline. Idempotent."""
    def wait(self) -> None:
        """Blocks (without the GIL) until every submitted frame has been tracked and every
        keyframe mapped (see ``set_mapping_thread``)."""
    @property
    def threaded(self) -> bool:
        """Whether frames are processed in a background thread."""
    def set_mapping_thread(self, on: bool) -> None:
        """Runs local mapping and loop closing in a thread of their own, fed with map
        snapshots (always so when ``threaded``); off again, the queued keyframes are mapped
        first. ``wait()`` waits for the mapping thread too."""
    def record_local_ba_problems(self, on: bool) -> None:
        """Records (``True``) each local BA problem as local mapping builds it, before solving,
        to run other solvers on the same problems (``benches/solvers_compare.py``); ``False``
        stops and drops the record. Raises ``ValueError`` while the mapping thread runs (and
        ``set_mapping_thread(True)`` does while recording)."""
    def take_local_ba_problems(self) -> list[str]:
        """The local BA problems recorded since the last call, oldest first, as text:
        ``ferroslam-ba 1``, ``intrinsics fx fy cx cy bf``, ``poses n`` then per pose
        ``fixed qw qx qy qz tx ty tz`` (``T_c_w``), ``points m`` then ``x y z``,
        ``observations k`` then ``pose point u v u_right|- inv_sigma2`` (pixels)."""
    def map_copy_cost(self) -> tuple[float, float]:
        """``(snapshot_us, deep_copy_us)``: wall time of handing the current map to the
        mapping thread (a copy-on-write copy) and of the deep copy it used to take. (Builds
        with the ``bench`` feature only.)"""
    @property
    def mapping_thread(self) -> bool:
        """Whether local mapping and loop closing run in a thread of their own."""
    def loops(self) -> list[dict[str, Any]]:
        """Loops closed so far, oldest first: ``current`` and ``matched`` keyframe ids, their
        ``timestamps`` (s), ``num_matches``, the Sim(3) ``scale`` (1 with depth),
        ``correction_m`` (how far the current keyframe moved) and the essential graph's
        ``graph_cost`` (before, after)."""
    def loop_stats(self) -> dict[str, int]:
        """Loop-detection counters: ``keyframes_checked``, ``with_candidates`` (bag-of-words
        candidates found), ``verified`` (consistent candidates checked geometrically) and
        ``rejected`` (refused by the Sim(3) or the match count)."""
    def frame_map_ids(self) -> NDArray[np.uint32]:
        """Map id of each pose of ``frame_trajectory`` (N,). A system lost for
        ``relocalisation_window_s`` keeps its map in the atlas and starts a new one; maps
        have their own world frame (and, monocular, scale) until merged."""
    def maps(self) -> list[dict[str, Any]]:
        """Every map of the run with keyframes, the atlas's oldest first, then the current
        one (the order ``save_map`` writes them): ``id``, ``frames`` (poses tracked in it),
        ``keyframes``, ``points``, ``current`` (tracking runs in it)."""
    @property
    def current_map_id(self) -> int:
        """Id of the map tracking runs in."""
    def merges(self) -> list[dict[str, Any]]:
        """Maps merged so far, oldest first (keys as ``TrackResult.merge``)."""
    def frame_trajectory(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(timestamps (N,) float64, T_w_c (N, 4, 4) float64)`` of every tracked frame in
        time order, relative to its reference keyframe, so later map corrections are
        included; each in its map's world (see ``frame_map_ids``)."""
    def keyframe_trajectory(
        self, map_id: int | None = None
    ) -> tuple[NDArray[np.uint32], NDArray[np.float64], NDArray[np.float64]]:
        """``(ids (K,) uint32, timestamps (K,) float64, T_w_c (K, 4, 4) float64)`` of the
        live keyframes of map ``map_id`` (default the current map). ``ValueError`` naming
        the run's maps for an id that is none of them (or negative), ``TypeError`` for a
        ``map_id`` that is not an int."""
    def map_points(self, map_id: int | None = None) -> NDArray[np.float64]:
        """World positions of the live map points of map ``map_id`` (default the current
        map), (M, 3) float64 metres; errors as ``keyframe_trajectory``."""
    def map_point_colors(self, map_id: int | None = None) -> NDArray[np.uint8]:
        """Colours of the live map points of map ``map_id`` (default the current map; errors
        as ``keyframe_trajectory``), (M, 3) uint8 RGB in the order of ``map_points(map_id)``:
        each the colour of the keypoint that created the point (the ``colors`` given with
        its frame); grey ``(128, 128, 128)`` for points made from frames given without
        colours, as the exporters draw uncoloured points."""
    def sparse_model(self, map_id: int | None = None) -> dict[str, Any]:
        """Map ``map_id`` (default the current map; errors as ``keyframe_trajectory``) as
        images and tracks, in one call (GIL released), one image per keyframe
        and rig camera: ``keyframe_ids (K,)`` uint32, ``camera_index (K,)`` uint32 (the
        image's camera, 0 the tracked one), ``rig_cameras`` (list of dicts of cameras 1..:
        ``model``, ``fx``, ``fy``, ``cx``, ``cy``, ``dist``, ``width``, ``height``, ``T_c0_c
        (4, 4)`` metres), ``timestamps (K,)`` float64 s, ``T_w_c (K, 4, 4)`` float64 (the
        image's camera),
        ``keypoint_offsets (K + 1,)`` int64 (keyframe ``k``'s keypoints are rows
        ``offsets[k]:offsets[k + 1]``), ``keypoints_px (N, 2)`` float64 raw image pixels
        (the lens distortion applied), ``point_index (N,)`` int64 (row of ``points_xyz``
        the keypoint observes, -1 for none), ``points_xyz (M, 3)`` float64 metres (the
        order of ``map_points``), ``point_colors (M, 3)`` uint8 RGB."""
    def save_map(self, path: str | os.PathLike[str]) -> None:
        """Writes every map of ``maps()`` (the whole atlas, the current map last) to ``path``:
        one versioned binary record with a checksum per map, back to back.

        Raises:
            FileNotFoundError: the folder does not exist; ValueError: not writable.
        """
    def add_maps(self, path: str | os.PathLike[str]) -> list[int]:
        """Adds every map saved at ``path`` to the atlas (the current map stays); their new
        ids, in file order. Raises as ``load_map``."""
    def merge_maps(self) -> list[dict[str, Any]]:
        """Merges the atlas's maps where they overlap, offline (each map's keyframes, in id
        order, look for a place of every older map; a verified one merges the newer map into
        the older); the merges made (keys as ``TrackResult.merge``). Needs a vocabulary."""
    def load_map(self, path: str | os.PathLike[str]) -> None:
        """Makes the last map saved at ``path`` the current one, the file's others and the
        map tracked until now go to the atlas; the next frames relocalise in it (state
        ``"lost"`` until they do) and map onward from it (unless localisation-only); lost
        for ``relocalisation_window_s``, a map of the run's own starts and merges into a
        loaded one once it recognises it.

        Raises:
            FileNotFoundError: no such file.
            ValueError: truncated, corrupt (checksum), another format version, or built with
                another ORB pyramid; the system is unchanged.
        """
    def set_vocabulary(self, vocabulary: Vocabulary) -> None:
        """Sets the ORB vocabulary (shared, not copied): keyframes are indexed by bag of words
        and a lost frame is relocalised against the keyframes it resembles (ORB-SLAM's
        relocalisation), instead of the last reference keyframe's neighbourhood."""
    @property
    def localization_only(self) -> bool:
        """Track against the map without adding keyframes (e.g. in a loaded map)."""
    @localization_only.setter
    def localization_only(self, on: bool) -> None: ...
    def reset(self) -> None:
        """Clears the map and the trajectory and counts a reset; tracking initialises again
        with the next frame, whose timestamp must still follow the last accepted one."""
    @property
    def sensor(self) -> _Sensor:
        """The sensor the system was created for."""
    @property
    def track_feature_range(self) -> tuple[int, int]:
        """(lower, upper) tracked-point limits in use: the option given, else the sensor's
        default ((30, 100); (30, 250) for RGB-D)."""
    @property
    def options(self) -> dict[str, Any]:
        """Every option in use, as keyword options (a stereo ``baseline`` as ``bf``): those
        given, the defaults of the sensor and image width for the rest."""
    @property
    def state(self) -> _State:
        """Current tracking state."""
    @property
    def num_keyframes(self) -> int:
        """Live keyframes in the map."""
    @property
    def num_map_points(self) -> int:
        """Live map points."""
    @property
    def num_resets(self) -> int:
        """Map resets so far: automatic ones (tracking lost with at most 5 keyframes in the
        map) and ``reset()`` calls."""
    def set_imu(
        self,
        params: Any,
        T_b_c: NDArray[np.float64],
        *,
        num_poses_threshold: Optional[int] = None,
        alignment_fraction: Optional[float] = None,
        gravity_magnitude: Optional[float] = None,
        imu_time_offset_s: Optional[float] = None,
    ) -> None:
        """Sets the IMU (options left out take the core's defaults, ``default_options``);
        from now on the camera-IMU alignment runs once the map has had
        ``num_poses_threshold`` keyframes (MATLAB NumPosesThreshold; culled ones count), on
        the newest ``alignment_fraction`` of them (AlignmentFraction). A monocular map is then
        rescaled to metres in place; the world is not rotated (gravity is reported).

        Args:
            params: ``ferroslam.datasets.euroc.ImuParams`` or a dict with
                ``gyroscope_noise_density``, ``gyroscope_random_walk``,
                ``accelerometer_noise_density``, ``accelerometer_random_walk``, ``rate_hz``.
            T_b_c: (4, 4) float64 camera pose in the body (IMU) frame (EuRoC ``T_BS``).
            imu_time_offset_s: the IMU clock's offset to the camera's, seconds: a sample
                stamped ``t_imu`` was measured at camera time ``t_imu - imu_time_offset_s``
                (Kalibr's ``timeshift_cam_imu``, ``t_imu = t_cam + shift``).

        Raises:
            TypeError: missing parameter, wrong dtype.
            ValueError: non-rigid ``T_b_c``, a threshold below 3, a fraction outside (0, 1],
                invalid noise values.
        """
    def add_imu(
        self,
        timestamps: NDArray[np.float64],
        gyro: NDArray[np.float64],
        accel: NDArray[np.float64],
    ) -> None:
        """Adds IMU samples (body frame): timestamps (M,) s on the IMU clock (moved to the
        camera's by ``imu_time_offset_s``), gyro (M, 3) rad/s, accel (M, 3) m/s^2 specific
        force. Feed the samples up to each frame's time before tracking it, and the first one
        after it if it is there: the last stretch before the frame is then interpolated,
        else the last sample is held to the frame time (as ORB-SLAM3). Where samples are
        missing (more than 10 sample periods apart, or ending more than that before a frame) the system falls back to vision there: the alignment waits for
        enough keyframes with IMU throughout (``inertial_alignment()["reason"]`` names the
        gap), and IMU prediction and inertial BA do not span it.

        Raises:
            TypeError: not float64 arrays.
            ValueError: no ``set_imu`` yet, wrong shapes, non-finite values, timestamps not
                strictly increasing (also against the samples added before), gyro beyond
                35 rad/s (deg/s?) or mean |accel| near 1 (g?); the system is unchanged then.
        """
    def keyframe_imu_state(self) -> dict[str, Any] | None:
        """The newest keyframe's IMU state once the camera and the IMU are aligned, else None:
        ``{"keyframe_id", "timestamp", "velocity" (3,) m/s (body velocity in the world),
        "gyro_bias" (3,) rad/s, "accel_bias" (3,) m/s^2}``. Refined by local inertial BA once
        the last refinement of the alignment is done; predicted from the previous keyframe
        before."""
    def inertial_alignment(self) -> dict[str, Any] | None:
        """The camera-IMU alignment of the current map, None without ``set_imu``. It runs
        after ``num_poses_threshold`` keyframes and again (ORB-SLAM3 style) when the keyframes
        since then span 5 s and 15 s; this is the latest.

        ``{"status": "waiting", "keyframes", "needed"}``, ``{"status": "failed",
        "keyframes", "reason"}`` (retried at the next keyframe) or ``{"status": "aligned",
        "refinement" (0 first, then 1 and 2), "keyframes", "scale" (metres per former map
        unit: relative to the previous alignment for a refinement), "map_rescaled" (mono),
        "gravity_w" (3,) m/s^2 in the map's world, "R_w_g" (3, 3) gravity-aligned (z up) to
        world, "gyro_bias" (3,) rad/s, "accel_bias" (3,) (zero when not estimated: the window
        must rotate enough),
        "keyframe_ids" (K,) uint32, "keyframe_timestamps" (K,), "velocities" (K, 3) m/s in the
        world, "timestamp", "acceleration_excitation" m/s^2}``.
        """

def load_sparse_model(
    path: str | os.PathLike[str],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(camera, model)`` of a map file: ``camera`` the dict (``sensor``, ``model``, ``fx``,
    ``fy``, ``cx``, ``cy``, ``dist``, ``width``, ``height``) of the first camera it was built
    with,
    ``model`` as ``SlamSystem.sparse_model``. Read without the GIL.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: a corrupt or truncated file, another format version, or a file without
            its camera record.
    """

def merge_map_files(
    inputs: Sequence[str | os.PathLike[str]],
    output: str | os.PathLike[str],
    vocabulary: Vocabulary,
) -> dict[str, Any]:
    """Merges the maps saved in ``inputs`` where they overlap (``SlamSystem.merge_maps``,
    without the GIL) and writes every map left, merged or not, to ``output``, in the order of
    the returned ``maps``. The first file's sensor and camera build the merging system; the
    others must match them. Returns ``inputs`` (per input file, the map ids its maps got, in
    file order), ``merges`` (as ``SlamSystem.merges``, each with its ``similarity`` (4, 4)
    ``[s R | t]``: ``p_into = s R p_merged + t``) and ``maps`` (as ``SlamSystem.maps``).

    Raises:
        FileNotFoundError / ValueError: a missing, corrupt or incompatible input (nothing is
            written then); ValueError: no input, or maps of a multi-camera rig.
    """

def default_options(sensor: _Sensor, width: int) -> dict[str, Any]:
    """The options a ``SlamSystem`` of ``sensor`` for images ``width`` pixels wide uses when
    given none, as keyword options (``n_features`` follows the width: 1000 at 640 px, 1200 at
    752, 1900 at 1241). The CLI, ``run_sequence`` and the vSLAM objects all read these.

    Raises:
        ValueError: width not positive.
        NotImplementedError: unknown sensor.
    """

def option_table(width: int = 640) -> list[dict[str, Any]]:
    """The core's declaration of every user-facing option, in order, one dict each:
    ``name``, ``scope`` (``"core"``: ``SlamSystem`` keywords; ``"imu"``: ``set_imu``
    keywords), ``field`` (the configuration field it sets, ``section.field``; None for
    ``baseline``), ``kind`` (``"int"``, ``"float"``, ``"flag"``, ``"int_pair"``,
    ``"float_pair"``), ``unit``, the range (``low``, ``high``: None for no bound;
    ``open_low``, ``open_high``, ``infinite_high``), ``sensors`` (tuple of sensor names),
    ``doc`` (one line) and ``defaults`` (sensor name -> default for images ``width`` px
    wide; None: none, the option must be given). ``ferroslam.options`` and
    ``docs/options.md`` are built from it.

    Raises:
        ValueError: width not positive.
    """

def match_stereo(
    left_keypoints: NDArray[np.float32],
    left_descriptors: NDArray[np.uint8],
    left_pyramid: Sequence[NDArray[np.uint8]],
    right_keypoints: NDArray[np.float32],
    right_descriptors: NDArray[np.uint8],
    right_pyramid: Sequence[NDArray[np.uint8]],
    *,
    fx: float,
    baseline: float,
    scale_factor: float = 1.2,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The core's stereo matcher on its own: ``(u_right (N,), depth_m (N,))`` float32 for the
    left keypoints of a rectified pair, -1 where no reliable match exists.

    Raises:
        TypeError / ValueError: as ``SlamSystem.track_stereo``; non-positive fx or baseline.
    """

class _CameraLike(Protocol):
    """What the camera functions read of a ``ferroslam.Camera``."""

    model: str
    fx: float
    fy: float
    cx: float
    cy: float
    dist: NDArray[np.float64]
    width: int
    height: int
    rolling_shutter_readout_s: float

def project_points(camera: _CameraLike, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(N, 2)`` float64 RAW image pixels (lens distortion applied) of ``(N, 3)`` float64
    camera-frame points in metres, by the core's model of ``camera`` (``Camera.project``).

    Rows are NaN where the model does not project: behind a pinhole (``z <= 1e-6``), beyond a
    fisheye's largest one-to-one incidence angle, non-finite points.

    Raises:
        TypeError: ``points`` not a float64 array, or a camera field of the wrong type.
        ValueError: ``points`` not ``(N, 3)``; an unknown model, a wrong number of ``dist``
            coefficients or intrinsics the core refuses (named).
    """

def unproject_pixels(camera: _CameraLike, pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(N, 3)`` float64 unit rays (camera frame) through ``(N, 2)`` float64 RAW image
    pixels, inverting :func:`project_points` (``Camera.unproject``).

    Rows are NaN for non-finite pixels and, for a fisheye, pixels outside the image circle
    of its largest incidence angle.

    Raises:
        TypeError / ValueError: as :func:`project_points`, naming ``pixels``.
    """

_Features = tuple[NDArray[np.float32], NDArray[np.uint8], list[NDArray[np.uint8]]]
_Mask = Union[NDArray[np.uint8], NDArray[np.bool_]]

@final
class OrbExtractor:
    """ORB-SLAM's ORB extractor, whole, in the core (``crates/features/src/extractor/``): the
    image pyramid (OpenCV's ``INTER_LINEAR_EXACT``, bit for bit), FAST with the per-cell
    threshold fallback, the even spread, the intensity-centroid orientation and rotated BRIEF
    with OpenCV's tests on levels smoothed as OpenCV's ORB smooths them, so the descriptors
    equal ``cv2.ORB``'s bit for bit. Each call releases the GIL.

    Each setting left out (``None``) takes the core's default (``OrbConfig::default``,
    ORB-SLAM's settings for 640 x 480 images); the read-only attributes of the same names
    hold the values in use.

    Args:
        n_features: keypoints wanted per image (>= 1).
        scale_factor: scale between neighbouring pyramid levels (finite, > 1).
        n_levels: pyramid levels, in [1, 32].
        ini_fast: FAST threshold tried first in every grid cell.
        min_fast: FAST threshold of the cells where ``ini_fast`` finds no corner
            (``0 < min_fast <= ini_fast < 255``).

    Raises:
        ValueError: a setting out of range, named.
    """

    def __new__(
        cls,
        *,
        n_features: Optional[int] = None,
        scale_factor: Optional[float] = None,
        n_levels: Optional[int] = None,
        ini_fast: Optional[int] = None,
        min_fast: Optional[int] = None,
    ) -> OrbExtractor: ...
    @property
    def n_features(self) -> int:
        """Keypoints wanted per image."""
    @property
    def scale_factor(self) -> float:
        """Scale between neighbouring pyramid levels."""
    @property
    def n_levels(self) -> int:
        """Pyramid levels."""
    @property
    def ini_fast(self) -> int:
        """FAST threshold tried first in every grid cell."""
    @property
    def min_fast(self) -> int:
        """FAST threshold of the cells where ``ini_fast`` finds no corner."""
    @property
    def level_budgets(self) -> list[int]:
        """Keypoints wanted per pyramid level, finest first (a geometric series summing to
        ``n_features``)."""
    def extract(
        self, image: NDArray[np.uint8], mask: Optional[_Mask] = None
    ) -> _Features:
        """``(keypoints, descriptors, pyramid)`` of an ``(H, W)`` uint8 grey image:
        keypoints ``(N, 5)`` float32 ``[x, y, octave, angle_deg, response]`` in raw level-0
        pixels, grouped by octave (``angle_deg`` in [0, 360), ``response`` the FAST score);
        descriptors ``(N, 32)`` uint8; the pyramid's levels, finest (a copy of the image)
        first, ``(round(H / s^l), round(W / s^l))`` uint8.

        ``mask``: ``(H, W)`` uint8 or bool, 0 (False) where no keypoint may be; each level's
        corners on closed pixels are dropped before the even spread, so the level's budget
        goes to the open part. A mask with no zero gives exactly the unmasked result.

        Raises:
            TypeError: ``image`` is not a 2-D uint8 array.
            ValueError: empty image; a pyramid level would have no pixels; ``mask`` not a
                2-D uint8 or bool array, or not the image's size (both sizes named).
        """
    def extract_stereo(
        self,
        left: NDArray[np.uint8],
        right: NDArray[np.uint8],
        left_mask: Optional[_Mask] = None,
        right_mask: Optional[_Mask] = None,
    ) -> tuple[_Features, _Features]:
        """``extract`` of both images of a stereo pair in one call, in parallel, each with
        its own optional mask.

        Raises:
            TypeError / ValueError: as ``extract``, for either image or mask (the message
                names it).
        """
    @staticmethod
    def image_circle_mask(
        width: int, height: int, centre_x_px: float, centre_y_px: float, radius_px: float,
        margin_px: float,
    ) -> NDArray[np.uint8]:
        """A ``(height, width)`` uint8 mask: 255 where pixel ``(x, y)`` lies within
        ``radius_px - margin_px`` of the image circle's centre, 0 elsewhere.

        Raises:
            ValueError: an empty size, a non-finite centre, a radius <= 0 or a margin < 0.
        """
    def pyramid(self, image: NDArray[np.uint8]) -> list[NDArray[np.uint8]]:
        """The image pyramid ``extract`` builds, alone.

        Raises:
            TypeError / ValueError: as ``extract``.
        """

# --- Place recognition: Vocabulary and KeyframeDatabase (crates/python/src/vocabulary.rs) ---

_PathLike = Union[str, "os.PathLike[str]"]

@final
class Vocabulary:
    """ORB vocabulary tree (hierarchical k-majority clustering, TF-IDF word weights), as
    DBoW2's. BoW vectors are ``dict[int, float]``: word id -> weight, L1-normalised.

    File errors name the file: ``FileNotFoundError`` / ``OSError`` when it cannot be read or
    written, ``ValueError`` when its content is corrupt or malformed.
    """

    @staticmethod
    def train(
        descriptor_list: Sequence[NDArray[np.uint8]], k: int = 10, levels: int = 5, seed: int = 0
    ) -> Vocabulary:
        """Trains on one ``(N, 32)`` uint8 descriptor array per image (IDF counts images);
        deterministic for a given seed.

        Raises:
            TypeError: not a list of uint8 arrays (the message names ``descriptor_list[i]``).
            ValueError: a shape other than (N, 32); k < 2; levels outside 1..16; no descriptor.
        """
    @staticmethod
    def load(path: _PathLike) -> Vocabulary:
        """Reads the compact checksummed binary format written by ``save``."""
    @staticmethod
    def load_dbow2_text(path: _PathLike) -> Vocabulary:
        """Reads DBoW2's text format (ORB-SLAM's ``ORBvoc.txt``)."""
    def save(self, path: _PathLike) -> None:
        """Writes the compact binary format."""
    def save_dbow2_text(self, path: _PathLike) -> None:
        """Writes DBoW2's text format, readable by ORB-SLAM2/3."""
    def transform(self, descriptors: NDArray[np.uint8]) -> dict[int, float]:
        """BoW vector of one image's ``(N, 32)`` uint8 descriptors (empty for N = 0)."""
    @staticmethod
    def score(a: dict[int, float], b: dict[int, float]) -> float:
        """DBoW2's L1 similarity ``1 - 0.5 |a/|a| - b/|b||_1`` in [0, 1] (0 if either is
        empty). Raises ``TypeError`` for non-dict input, ``ValueError`` for negative or
        non-finite weights."""
    @property
    def k(self) -> int:
        """Branching factor."""
    @property
    def levels(self) -> int:
        """Tree depth."""
    @property
    def num_words(self) -> int:
        """Number of words (leaves)."""

@final
class KeyframeDatabase:
    """Inverted-index keyframe database over a ``Vocabulary``, scored with the L1 score."""

    def __new__(cls, vocabulary: Vocabulary) -> KeyframeDatabase:
        """An empty database; raises ``TypeError`` if ``vocabulary`` is not a ``Vocabulary``."""
    def add(self, id: int, descriptors: NDArray[np.uint8]) -> bool:
        """Adds keyframe ``id`` (0..2**32-1) from its ``(N, 32)`` uint8 descriptors; True when
        it replaced an entry with the same id."""
    def remove(self, id: int) -> bool:
        """Removes keyframe ``id``; whether it was present."""
    def query(
        self,
        descriptors: NDArray[np.uint8],
        max_results: int = 10,
        exclude: Optional[Iterable[int]] = None,
    ) -> list[tuple[int, float]]:
        """The ``max_results`` best ``(id, score)`` pairs, best first (ties by id); keyframes
        sharing no word with the query and those in ``exclude`` are left out."""
    def __len__(self) -> int: ...
    def __contains__(self, id: int, /) -> bool: ...
