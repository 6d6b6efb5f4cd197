"""A complete COLMAP model of a map: ``images/`` with every keyframe's image and
``sparse/0/`` with the cameras, the images' poses and 2-D points, and the points' tracks.

This is the layout ``colmap`` (``--image_path images``, ``--input_path sparse/0``),
nerfstudio (``ns-process-data``'s output) and Gaussian-splatting trainers (gsplat, the
original 3DGS ``-s FOLDER``) read. The model comes from the core in one call
(:class:`SparseModel`: ``SlamSystem.sparse_model()`` or, for a saved map,
``_core.load_sparse_model(path)``), written against the map's keyframes, keypoints and
points only. A rig's model carries every camera (below).

Images are the raw (distorted) frames as tracked, and the camera is written in the COLMAP
model of the same lens (``OPENCV`` / ``FULL_OPENCV`` / ``PINHOLE``, ``OPENCV_FISHEYE``;
see :func:`ferroslam.export.write_colmap_model`); the 2-D points are in those raw pixels.
COLMAP has no rolling-shutter camera: a rolling-shutter run's keypoints are written where
the camera would have seen them from the keyframe's pose (its reference time), each moved by
its row's motion (``ferroslam_map::sparse_model``), so points reproject through the written
poses as closely as through the rows' poses the core adjusted them with.
Trainers that take only ``PINHOLE`` cameras (the original 3DGS) want ``colmap
image_undistorter`` run on the folder first.

A multi-camera rig (``ferroslam.Rig``, ``RigVSlam``) is one COLMAP camera per core camera
(the tracked one, then the rig's further cameras, each with its own model and size) and one
image per keyframe and camera, ``images/cam<k>/keyframe_<id>.png``, posed at ``T_ck_w =
T_ck_c0 T_c0_w`` with that camera's keypoints, so a point's track spans the cameras that saw
it. ``rigs.txt`` and ``frames.txt`` (COLMAP 3.12 on) say the cameras are rigidly mounted:
one frame per keyframe. The partner of a stereo pair gives the first camera depths only (its
keypoints are no map observations), so it is no camera of the model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ._files import regular_file, write_bytes, write_text
from .camera import Camera
from .export import default_image_name, write_colmap_model
from .keyframe_images import KeyframeImages

__all__ = ["MIN_TRACK_LENGTH", "SparseModel", "export_map_file", "image_name", "write_colmap"]

# COLMAP's points are seen in two images at least, and its bundle adjustment refuses a track
# of one; the map has such points (made from one keyframe's depth, RGB-D or stereo). They
# are left out of the model, their keypoints listed without a point.
MIN_TRACK_LENGTH = 2


@dataclass(frozen=True)
class SparseModel:
    """The map's keyframes, keypoints and points, as ``SlamSystem.sparse_model()`` gives
    them.

    ``keyframe_ids (K,)``, ``timestamps (K,)`` seconds, ``T_w_c (K, 4, 4)``;
    ``keypoint_offsets (K + 1,)``: keyframe ``k``'s keypoints are rows
    ``offsets[k]:offsets[k + 1]`` of ``keypoints_px (N, 2)`` (raw image pixels, OpenCV's
    centre of the top-left pixel at (0, 0), as seen from ``T_w_c``) and ``point_index (N,)`` (row of
    ``points_xyz (M, 3)`` the keypoint observes, -1 for none); ``point_colors (M, 3)`` uint8.
    A rig's model has one image per keyframe and camera: ``camera_index (K,)`` (0 for the
    tracked camera), the further cameras' records in ``rig_cameras`` (the camera dict of
    ``_core.load_sparse_model`` with ``T_c0_c (4, 4)``, metres).
    """

    keyframe_ids: np.ndarray
    timestamps: np.ndarray
    T_w_c: np.ndarray
    keypoint_offsets: np.ndarray
    keypoints_px: np.ndarray
    point_index: np.ndarray
    points_xyz: np.ndarray
    point_colors: np.ndarray
    camera_index: Optional[np.ndarray] = None
    rig_cameras: tuple[dict, ...] = ()

    def __post_init__(self) -> None:
        if self.camera_index is None:  # one camera
            object.__setattr__(self, "camera_index", np.zeros(len(self.keyframe_ids), np.uint32))

    @classmethod
    def from_core(cls, arrays: dict) -> "SparseModel":
        """From the dict of ``SlamSystem.sparse_model()`` / ``_core.load_sparse_model``."""
        fields = {name: np.asarray(arrays[name]) for name in cls.__dataclass_fields__
                  if name in arrays and name != "rig_cameras"}
        return cls(**fields, rig_cameras=tuple(arrays.get("rig_cameras", ())))

    @property
    def is_rig(self) -> bool:
        """Whether the model has several cameras."""
        return bool(self.rig_cameras)

    def image_names(self) -> list[str]:
        """Each image's file name in ``images/`` (:func:`image_name`)."""
        return [image_name(i, int(k) if self.is_rig else None)
                for i, k in zip(self.keyframe_ids, np.asarray(self.camera_index))]

    def with_tracks_of_at_least(self, length: int) -> "SparseModel":
        """The model without the points seen by fewer than ``length`` keypoints (their
        keypoints then observe none, -1)."""
        seen = self.point_index[self.point_index >= 0]
        keep = np.bincount(seen, minlength=len(self.points_xyz)) >= length
        new_row = np.where(keep, np.cumsum(keep) - 1, -1)
        point_index = np.where(self.point_index >= 0, new_row[self.point_index], -1)
        return replace(self, point_index=point_index, points_xyz=self.points_xyz[keep],
                       point_colors=self.point_colors[keep])

    def keyframe_of_keypoint(self) -> np.ndarray:
        """``(N,)`` row of the keyframe each keypoint belongs to."""
        return np.repeat(np.arange(len(self.keyframe_ids)), np.diff(self.keypoint_offsets))


def image_name(keyframe_id: int, camera: Optional[int] = None) -> str:
    """The file name of a keyframe's image in ``images/`` (and in ``images.txt``): in
    sub-folder ``cam<k>/`` for camera ``k`` of a rig."""
    return default_image_name(keyframe_id, camera)


def _camera_of(record: dict) -> Camera:
    """The camera of a core camera record (``load_sparse_model``, ``rig_cameras``)."""
    return Camera(record["fx"], record["fy"], record["cx"], record["cy"], record["dist"],
                  record["width"], record["height"], model=record["model"])


def write_colmap(folder: Path, camera: Camera, model: SparseModel,
                 images: Optional[KeyframeImages] = None) -> Path:
    """Writes ``folder/sparse/0/`` (text model) and, from ``images``, ``folder/images/``;
    returns ``folder``.

    Every keyframe of ``model`` is an image with all its keypoints (POINT3D_ID -1 for those
    without a point); points seen in fewer than :data:`MIN_TRACK_LENGTH` keyframes are left
    out; a keyframe whose image ``images`` does not hold (or all of them, with
    ``images=None``: a map file keeps no pixels) is still in the model, named as if it were
    there, so that images put in ``images/`` later fit.

    Returns ``folder``; raises as :func:`ferroslam.export.write_colmap_model`.
    """
    folder = Path(folder)
    model = model.with_tracks_of_at_least(MIN_TRACK_LENGTH)
    names = model.image_names()
    cameras: list[Camera] = [camera, *(_camera_of(c) for c in model.rig_cameras)]
    # One camera: no rig files, the model as before rigs.
    T_c0_c = ([np.eye(4), *(np.asarray(c["T_c0_c"]) for c in model.rig_cameras)]
              if model.is_rig else None)
    write_colmap_model(
        folder / "sparse" / "0", cameras, model.keyframe_ids, model.T_w_c, model.points_xyz,
        point_colors=model.point_colors,
        observations=(model.keyframe_of_keypoint(), model.point_index, model.keypoints_px),
        image_names=names, camera_index=model.camera_index, T_c0_c=T_c0_c)
    if images is not None:
        for name, t, k in zip(names, model.timestamps, np.asarray(model.camera_index)):
            if images.has(t, int(k)):
                write_bytes(folder / "images" / name, images.png(t, int(k)))
    return folder


# Beside a model exported from a map file: which source frame each image is.
TIMESTAMPS_FILE = "image_timestamps.txt"


def export_map_file(map_path: Path, folder: Path) -> Path:
    """Writes the COLMAP model of a saved map (``SlamSystem.save_map``,
    ``*VSlam.save_map``) in ``folder/sparse/0/``; returns ``folder``.

    A map file keeps the keyframes' keypoints, poses, points and tracks and the camera, but
    no pixels (they would make it tens of times larger), so ``images/`` is not written:
    ``folder/image_timestamps.txt`` lists each image name with the timestamp (seconds) of
    its source frame, to copy those frames there (as PNG under the listed names). A run
    (``ferroslam run``) writes the images itself.

    Raises:
        FileNotFoundError: no map file. ValueError: not a map file, a corrupt one, or one
            without its camera record.
    """
    from ._core import load_sparse_model

    camera_record, arrays = load_sparse_model(regular_file(map_path, "map file"))
    model = SparseModel.from_core(arrays)
    folder = write_colmap(Path(folder), _camera_of(camera_record), model)
    write_text(folder / TIMESTAMPS_FILE, "# NAME TIMESTAMP_S\n" + "".join(
        f"{name} {float(t)!r}\n" for name, t in zip(model.image_names(), model.timestamps)))
    return folder
