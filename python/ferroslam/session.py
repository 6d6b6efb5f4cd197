"""One SLAM session: the core system with its vocabulary and IMU, and one frame's way in
(``SlamSystem.track``: the images in, the core's front end does the rest).

:func:`ferroslam.pipeline.run_sequence` and the vSLAM objects (:mod:`ferroslam.vslam`) both
drive a :class:`Session`; they differ only in where frames come from (a dataset read in
order, or the caller's ``add_frame``) and in what they report. Every default lives in the
core (``ferroslam._core.default_options``): a session passes on only the options given.
"""

from __future__ import annotations

from typing import Any, Callable, Optional, Sequence

import numpy as np

from ._validate import rigid_transform
from .calibration import ImuParams
from .camera import Camera
from .features import OrbExtractor
from .options import EXTRACTOR_KEYS, IMU_KEYS, validate_options

__all__ = ["EXTRACTOR_KEYS", "IMU_KEYS", "Session", "load_vocabulary", "make_extractor"]

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


def _core_system(*args, **kwargs):
    try:
        from ._core import SlamSystem  # the native module is only needed to actually run
    except ImportError as err:
        raise ImportError(
            f"the native module ferroslam._core is not available ({err}); build it with "
            "`maturin develop --release` in the repository root"
        ) from err
    return SlamSystem(*args, **kwargs)


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
        pair: ``(right_camera, T_left_right)`` of an UNRECTIFIED stereo pair (``sensor``
            ``"stereo"``, ``camera`` the raw left one): the core matches the raw images along
            epipolar curves; its baseline is that of ``T_left_right``.
        observers: ``(camera, T_c0_c, depth)`` of each further camera of a rig
            (:meth:`ferroslam.rig.Rig.observers`; ``depth`` a bool, or ``(partner_camera,
            T_left_right)`` of its stereo partner, whose image follows its own): its image
            follows the first camera's (and the pair partner's) in every frame.

    Raises:
        ValueError, TypeError: bad options, naming them (from the core).
    """

    def __init__(self, camera: Camera, sensor: str, options: Optional[dict] = None, *,
                 vocabulary: Any = "default", imu: Any = None,
                 T_b_c: Optional[np.ndarray] = None, imu_options: Optional[dict] = None,
                 mapping_thread: bool = False,
                 system_factory: Optional[Callable[..., Any]] = None,
                 pair: Optional[tuple[Camera, np.ndarray]] = None,
                 observers: Sequence[tuple[Camera, np.ndarray, Any]] = ()) -> None:
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
        # An unrectified pair's second camera and its pose in the first, for the core.
        paired = {} if pair is None else {"right_camera": pair[0], "T_left_right": pair[1]}
        if observers:
            paired["cameras"] = [tuple(o) for o in observers]
        self.system = (system_factory or _core_system)(
            c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor=sensor,
            model=c.model, rolling_shutter_readout_s=c.rolling_shutter_readout_s,
            **paired, **options)
        # Each further camera's image, then its stereo partner's, after the first camera's.
        first_observer = 2 if sensor == "stereo" else 1
        image_index = first_observer
        for observer, _, depth in observers:
            partner = depth[0] if isinstance(depth, tuple) else None
            for masked in (observer, partner) if partner is not None else (observer,):
                if masked.mask is not None:
                    self.system.set_mask(image_index, masked.mask)
                image_index += 1
        if pair is not None:  # each camera's own static mask
            for camera_index, masked in enumerate((c, pair[0])):
                if masked.mask is not None:
                    self.system.set_mask(camera_index, masked.mask)
        elif c.mask is not None:  # the camera's static mask, on both images of a pair
            for camera_index in range(first_observer):
                self.system.set_mask(camera_index, c.mask)
        if inertial:
            self.system.set_imu(imu, T_b_c, **imu_options)
        if vocabulary is not None and vocabulary is not False and vocabulary != "":
            self.system.set_vocabulary(load_vocabulary(vocabulary))
        if mapping_thread:
            self.system.set_mapping_thread(True)

    def track(self, timestamp_s: float, images: Any, *, depth_m: Optional[np.ndarray] = None,
              color: Optional[np.ndarray] = None, mask: Any = None):
        """Hands one frame's images to the core, the door every frame goes through: ORB
        extraction, the masks, depth and colour at the keypoints and stereo matching happen
        there, in one call without the GIL. Its ``TrackResult`` (``None`` when a threaded
        system queued it).

        Args:
            images: the tracked image (grey or BGR uint8), or ``(left, right)`` for stereo.
            depth_m: the registered depth image in metres (RGB-D), or one per image (None
                where a camera has no depth) for a rig with depth cameras.
            color: the first image in colour, when ``images`` is grey (map point colours).
            mask: this frame's mask, 0 = no keypoint, on top of the camera's static mask
                (stereo: ``(left, right)``, either None).
        """
        colors = color
        if color is not None and isinstance(images, (tuple, list)):
            colors = [color] + [None] * (len(images) - 1)  # colours are the first camera's
        return self.system.track(timestamp_s, images, depth=depth_m, colors=colors,
                                 masks=mask)
