"""One SLAM session: the core system with its ORB extractor, vocabulary and IMU, and one
frame's way in (ORB extraction, depth and colour at the keypoints, the track call).

:func:`ferroslam.pipeline.run_sequence` and the vSLAM objects (:mod:`ferroslam.vslam`) both
drive a :class:`Session`; they differ only in where frames come from (a dataset read in
order, or the caller's ``add_frame``) and in what they report. Every default lives in the
core (``ferroslam._core.default_options``): a session passes on only the options given.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional

import numpy as np

from ._validate import rigid_transform
from .calibration import ImuParams
from .camera import Camera
from .features import OrbExtractor, frame_mask, sample_colors, sample_depth
from .options import OPTIONS, validate_options

__all__ = ["EXTRACTOR_KEYS", "IMU_KEYS", "Features", "Session", "load_vocabulary",
           "make_extractor"]

# Options of SlamSystem.set_imu (MATLAB NumPosesThreshold, AlignmentFraction).
IMU_KEYS = tuple(o.name for o in OPTIONS if o.scope == "imu")
# The extractor's options among the core's (SlamSystem.options holds them all, defaults
# included: the ORB budget follows the image width).
EXTRACTOR_KEYS = ("n_features", "scale_factor", "n_levels", "ini_fast", "min_fast")


def make_extractor(options: dict) -> OrbExtractor:
    """ORB extractor from the extractor keys of a configuration (``SlamSystem.options``;
    keys left out take ``OrbExtractor``'s defaults)."""
    return OrbExtractor(**{k: options[k] for k in EXTRACTOR_KEYS if k in options})


def load_vocabulary(spec):
    """A ``Vocabulary``: ``"default"`` (the one shipped in the package), a vocabulary file's
    path, or a ``Vocabulary`` itself (returned as is)."""
    from ._core import Vocabulary

    if isinstance(spec, Vocabulary):
        return spec
    if spec == "default" or spec is True:
        from .vocabulary import default_vocabulary

        return default_vocabulary()
    return Vocabulary.load(str(spec))


def _size(image: np.ndarray) -> str:
    shape = np.shape(image)
    return f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else f"of shape {shape}"


def _core_system(*args, **kwargs):
    try:
        from ._core import SlamSystem  # the native module is only needed to actually run
    except ImportError as err:
        raise ImportError(
            f"the native module ferroslam._core is not available ({err}); build it with "
            "`maturin develop --release` in the repository root"
        ) from err
    return SlamSystem(*args, **kwargs)


class Features(NamedTuple):
    """One frame's input to the core: ``args`` of the ``track_*`` call after the timestamp
    (keypoints, descriptors, depth or the right image's), the keypoints' RGB ``colors`` and
    the tracked image's ``keypoints`` ``(N, 5)``."""

    args: tuple
    colors: np.ndarray
    keypoints: np.ndarray


class Session:
    """The core system of one camera and sensor, with what feeds it.

    Args:
        camera: the (raw) camera of the tracked images.
        sensor: ``"mono"``, ``"stereo"`` or ``"rgbd"``.
        options: ``SlamSystem`` keyword options (``threaded`` among them); the rest take
            the core's defaults for the sensor and image width.
        vocabulary: ``"default"``, a vocabulary file or ``Vocabulary``, or ``None``.
        imu: IMU noise parameters (``ferroslam.ImuParams`` or a dict), with ``T_b_c`` the
            (4, 4) camera pose in the IMU (body) frame and ``imu_options`` the ``set_imu``
            options (:data:`IMU_KEYS`).
        mapping_thread: local mapping and loop closing in a thread of their own.
        system_factory: replaces ``ferroslam._core.SlamSystem`` (tests, instrumentation).

    Raises:
        ValueError, TypeError: bad options, naming them (from the core).
    """

    def __init__(self, camera: Camera, sensor: str, options: Optional[dict] = None, *,
                 vocabulary: Any = "default", imu: Any = None,
                 T_b_c: Optional[np.ndarray] = None, imu_options: Optional[dict] = None,
                 mapping_thread: bool = False,
                 system_factory: Optional[Callable[..., Any]] = None) -> None:
        c = camera
        self.sensor = sensor
        inertial = imu is not None
        options = validate_options(options, sensor, inertial, scopes=("core", "object"))
        imu_options = validate_options(imu_options, sensor, inertial, scopes=("imu",))
        if inertial:
            imu = ImuParams.of(imu)
            if T_b_c is None:
                raise ValueError("imu needs camera_to_imu_transform: the (4, 4) camera pose "
                                 "in the IMU (body) frame, e.g. EuRoC's T_BS")
            T_b_c = rigid_transform(T_b_c, "camera_to_imu_transform")
        elif T_b_c is not None:
            raise ValueError("camera_to_imu_transform given without imu=: it would be "
                             "ignored; pass the IMU noise parameters too, or leave it out")
        self.system = (system_factory or _core_system)(
            c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor=sensor,
            model=c.model, rolling_shutter_readout_s=c.rolling_shutter_readout_s, **options)
        self.extractor = make_extractor(self.system.options)
        self.mask = c.mask  # the camera's static keypoint mask, None for none
        if inertial:
            self.system.set_imu(imu, T_b_c, **imu_options)
        if vocabulary is not None and vocabulary is not False and vocabulary != "":
            self.system.set_vocabulary(load_vocabulary(vocabulary))
        if mapping_thread:
            self.system.set_mapping_thread(True)
        self._track = getattr(self.system, f"track_{sensor}")

    def mono(self, image: np.ndarray, color: Optional[np.ndarray] = None,
             mask: Optional[np.ndarray] = None) -> Features:
        """A grey or BGR image's features; colours from ``color`` (the same frame in
        colour) when given, else from ``image``; none where the camera's static mask or the
        frame's ``mask`` is 0 (:func:`~ferroslam.features.frame_mask`)."""
        keypoints, descriptors = self.extractor.detect(
            image, frame_mask(self.mask, mask, np.shape(image)[:2]))
        colors = sample_colors(image if color is None else color, keypoints)
        return Features((keypoints, descriptors), colors, keypoints)

    def rgbd(self, image: np.ndarray, depth_m: np.ndarray,
             color: Optional[np.ndarray] = None, mask: Optional[np.ndarray] = None) -> Features:
        """As :meth:`mono`, with the depth (metres) of ``depth_m`` at each keypoint.

        Raises ``ValueError`` when ``depth_m`` is not the size of ``image``: its pixels
        would be sampled at the wrong places."""
        if np.shape(depth_m)[:2] != np.shape(image)[:2]:
            raise ValueError(f"the depth image is {_size(depth_m)} but the colour image "
                             f"{_size(image)} (width x height): they must be registered, "
                             "of one size")
        keypoints, descriptors = self.extractor.detect(
            image, frame_mask(self.mask, mask, np.shape(image)[:2]))
        colors = sample_colors(image if color is None else color, keypoints)
        return Features((keypoints, descriptors, sample_depth(depth_m, keypoints)), colors,
                        keypoints)

    def stereo(self, left: np.ndarray, right: np.ndarray,
               masks: tuple[Optional[np.ndarray], Optional[np.ndarray]] = (None, None)
               ) -> Features:
        """A rectified pair's features, both images extracted at once; the left image's
        colours. The camera's static mask applies to both images, ``masks`` (left, right)
        to one each, as :meth:`mono`'s ``mask``."""
        left_features, right_features = self.extractor.detect_pair(
            left, right, frame_mask(self.mask, masks[0], np.shape(left)[:2], "left mask"),
            frame_mask(self.mask, masks[1], np.shape(right)[:2], "right mask"))
        return Features((*left_features, *right_features),
                        sample_colors(left, left_features[0]), left_features[0])

    def track(self, timestamp_s: float, features: Features):
        """Hands a frame to the core: its ``TrackResult`` (``None`` when a threaded system
        queued it)."""
        return self._track(timestamp_s, *features.args, colors=features.colors)
