"""Files users open outside Python: map point clouds, trajectories and COLMAP models.

* :func:`write_ply` writes points (and optional colours) as a PLY vertex list, readable by
  MeshLab, CloudCompare, Open3D, Blender.
* :func:`write_trajectory` dispatches to the TUM / KITTI / EuRoC writers of
  :mod:`ferroslam.io` (:data:`TRAJECTORY_FORMATS`).
* :func:`write_colmap_model` writes keyframes and map points as a COLMAP text model
  (``cameras.txt``, ``images.txt``, ``points3D.txt``) for photogrammetry, NeRF and
  Gaussian-splatting tools.

All raise ``ValueError`` naming the offending argument (shape, NaN/inf, range) before
touching the file, and write through :func:`ferroslam._files.atomic_output` (missing parent
folders created, a symlink at the target replaced rather than followed, a FIFO or device
refused, the target changed only once the file is complete).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from ._files import atomic_output, write_text
from ._validate import finite_array
from .camera import Camera
from .io import PathLike, write_euroc_trajectory, write_kitti_poses, write_tum_trajectory
from .trajectory import Trajectory
from .transforms import inverse, matrix_to_quat

__all__ = [
    "PLY_BINARY_ABOVE_POINTS",
    "TRAJECTORY_FORMATS",
    "write_colmap_model",
    "write_ply",
    "write_trajectory",
]

# ``write_ply(binary=None)`` writes larger maps in binary: ASCII costs ~60 bytes per point
# and parses slowly, which starts to matter around a hundred thousand points.
PLY_BINARY_ABOVE_POINTS = 100_000

_XYZ = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
_RGB = [("red", "u1"), ("green", "u1"), ("blue", "u1")]


def _colors_u8(colors: object, n: int, name: str = "colors") -> np.ndarray:
    """``(n, 3)`` uint8 colours from uint8-range integers or floats in ``[0, 1]``."""
    raw = np.asarray(colors)
    c = finite_array(raw, name, (n, 3))
    if np.issubdtype(raw.dtype, np.floating):
        if c.size and (c.min() < 0.0 or c.max() > 1.0):
            raise ValueError(f"{name} given as floats must lie in [0, 1]")
        return np.round(c * 255.0).astype(np.uint8)
    if c.size and (c.min() < 0 or c.max() > 255):
        raise ValueError(f"{name} given as integers must lie in [0, 255]")
    return c.astype(np.uint8)


def _ply_header(fields: list[tuple[str, str]], n_points: int, binary: bool) -> bytes:
    """PLY header for ``n_points`` vertices of ``fields`` (see ``write_ply``)."""
    types = {"<f8": "double", "u1": "uchar"}
    lines = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment ferroslam map points (world frame, metres)",
        f"element vertex {n_points}",
        *(f"property {types[t]} {name}" for name, t in fields),
        "end_header",
    ]
    return ("\n".join(lines) + "\n").encode("ascii")


def _ply_records(fields: list[tuple[str, str]], columns: list[np.ndarray]) -> np.ndarray:
    """Packed little-endian vertex records, one field per column."""
    records = np.empty(len(columns[0]), dtype=fields)
    for (name, _), column in zip(fields, columns):
        records[name] = column
    return records


def write_ply(
    path: PathLike,
    points: np.ndarray,
    colors: Optional[np.ndarray] = None,
    *,
    binary: Optional[bool] = None,
) -> Path:
    """Write ``points`` as a PLY point cloud and return the path.

    Args:
        path: output file (parent folders are created).
        points: ``(N, 3)`` world positions in metres (``N`` may be 0), all finite.
        colors: optional ``(N, 3)`` RGB, integers in ``[0, 255]`` or floats in ``[0, 1]``
            (rounded to 8 bits).
        binary: ``False`` writes ``format ascii 1.0`` (coordinates with 17 significant
            digits: exact float64 round trip); ``True`` writes ``format
            binary_little_endian 1.0``; ``None`` (default) picks binary for more than
            :data:`PLY_BINARY_ABOVE_POINTS` points. Both hold the same float64 values.

    The header is::

        ply
        format ascii 1.0            (or binary_little_endian 1.0)
        comment ferroslam map points (world frame, metres)
        element vertex N
        property double x
        property double y
        property double z
        property uchar red          (these three only with colors)
        property uchar green
        property uchar blue
        end_header

    followed by one vertex per line (ASCII) or packed records of 3 float64 (+ 3 uint8).

    Raises:
        ValueError: ``points`` or ``colors`` of the wrong shape, non-finite or out of range.
    """
    xyz = finite_array(points, "points", (None, 3))
    fields, columns = _XYZ, list(xyz.T)
    if colors is not None:
        fields, columns = fields + _RGB, columns + list(_colors_u8(colors, len(xyz)).T)
    records = _ply_records(fields, columns)
    if binary is None:
        binary = len(xyz) > PLY_BINARY_ABOVE_POINTS
    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(_ply_header(fields, len(xyz), binary))
        if binary:
            f.write(records.tobytes())
        else:
            np.savetxt(f, records, fmt=["%.17g"] * 3 + ["%d"] * (len(fields) - 3))
    return path


def _rigid_poses(poses: np.ndarray, name: str, why: str) -> None:
    """Raises ``ValueError`` naming the first of ``poses (N, 4, 4)`` that is not rigid
    (orthonormal rotation to 1e-6, determinant +1, last row ``0 0 0 1``)."""
    rotations = poses[:, :3, :3]
    gram_error = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max(axis=(1, 2))
    bottom_ok = np.all(poses[:, 3] == [0.0, 0.0, 0.0, 1.0], axis=1)
    bad = np.flatnonzero((gram_error > 1e-6) | (np.linalg.det(rotations) <= 0) | ~bottom_ok)
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is not a rigid transform (orthonormal rotation, "
                         f"determinant +1, last row 0 0 0 1): {why}")


# Writers of ``write_trajectory``, by format name: ``(path, trajectory)``.
_TRAJECTORY_WRITERS: dict[str, Callable[[PathLike, Trajectory], None]] = {
    "tum": lambda path, t: write_tum_trajectory(path, t.timestamps, t.poses),
    "kitti": lambda path, t: write_kitti_poses(path, t.poses),
    "euroc": lambda path, t: write_euroc_trajectory(path, t.timestamps, t.poses),
}

#: Format names :func:`write_trajectory` accepts (the CLI's ``--trajectory-format`` choices).
TRAJECTORY_FORMATS = tuple(_TRAJECTORY_WRITERS)


def write_trajectory(
    path: PathLike,
    timestamps: np.ndarray,
    poses: np.ndarray,
    format: str = "tum",
) -> Path:
    """Write a (keyframe) trajectory with the :mod:`ferroslam.io` writers; return the path.

    Args:
        path: output file (parent folders are created).
        timestamps: ``(N,)`` seconds, non-decreasing (not written in KITTI files, whose
            lines are implicitly indexed 0, 1, ...).
        poses: ``(N, 4, 4)`` camera poses ``T_w_c`` (camera to world, metres).
        format: one of :data:`TRAJECTORY_FORMATS`: ``"tum"`` (``timestamp tx ty tz qx qy qz
            qw``), ``"kitti"`` (first three rows of ``T_w_c``, row-major) or ``"euroc"``
            (ASL csv ``timestamp_ns,tx,ty,tz,qw,qx,qy,qz``, integer nanoseconds).

    Raises:
        ValueError: unknown ``format``; shapes, NaN/inf or decreasing timestamps (from
            :class:`~ferroslam.trajectory.Trajectory`); a pose that is not rigid.
    """
    if format not in _TRAJECTORY_WRITERS:
        raise ValueError(f"format must be one of {list(TRAJECTORY_FORMATS)}, got {format!r}")
    trajectory = Trajectory(timestamps, poses)
    _rigid_poses(trajectory.poses, "poses", "a trajectory file holds rigid camera poses")
    _TRAJECTORY_WRITERS[format](path, trajectory)
    return Path(path)


_COLMAP_HEADERS = {
    "cameras.txt": ("# Camera list with one line of data per camera:\n"
                    "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                    "# Number of cameras: {n}\n"),
    "images.txt": ("# Image list with two lines of data per image:\n"
                   "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
                   "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
                   "# Number of images: {n}, mean observations per image: {mean}\n"),
    "points3D.txt": ("# 3D point list with one line of data per point:\n"
                     "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as "
                     "(IMAGE_ID, POINT2D_IDX)\n"
                     "# Number of points: {n}, mean track length: {mean}\n"),
    # COLMAP 3.12 on: the cameras rigidly mounted together, and each instant of the rig.
    "rigs.txt": ("# Rig calib list with one line of data per calib:\n"
                 "#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as "
                 "(SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])\n"
                 "# Number of rigs: 1\n"),
    "frames.txt": ("# Frame list with one line of data per frame:\n"
                   "#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], "
                   "NUM_DATA_IDS, DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)\n"
                   "# Number of frames: {n}\n"),
}

# COLMAP puts the centre of the top-left pixel at (0.5, 0.5); OpenCV and ferroslam at (0, 0).
_COLMAP_PIXEL_OFFSET = 0.5

# COLMAP numbers from 1: camera k of the list is CAMERA_ID k + 1, and a rig's model has one
# rig, with this id.
_COLMAP_RIG_ID = 1


def _numbers(values: np.ndarray | Sequence[float]) -> str:
    """Shortest text that reads back as the same float64 (``repr``), space-separated; -0.0
    is written 0.0."""
    return " ".join(repr(float(v) + 0.0) for v in values)


def _colmap_camera_line(camera: Camera, camera_id: int = 1) -> str:
    """``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` for ``camera``'s raw (distorted) images.

    ``PINHOLE`` (fx fy cx cy) without distortion, ``OPENCV`` (+ k1 k2 p1 p2) when ``k3 = 0``,
    else ``FULL_OPENCV`` (+ k1 k2 p1 p2 k3 k4 k5 k6 with k4 = k5 = k6 = 0: its rational radial
    term then equals OpenCV's five-coefficient model). The principal point moves by
    ``_COLMAP_PIXEL_OFFSET``. A Kannala-Brandt camera is ``OPENCV_FISHEYE`` (+ k1 k2 k3 k4,
    the same model).
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a ferroslam.Camera, got {type(camera).__name__}")
    if camera.model == "kannala_brandt":
        params = [camera.fx, camera.fy, camera.cx + _COLMAP_PIXEL_OFFSET,
                  camera.cy + _COLMAP_PIXEL_OFFSET, *camera.dist]
        return (f"{camera_id} OPENCV_FISHEYE {camera.width} {camera.height} "
                f"{_numbers(params)}")
    k1, k2, p1, p2, k3 = camera.dist
    params = [camera.fx, camera.fy, camera.cx + _COLMAP_PIXEL_OFFSET,
              camera.cy + _COLMAP_PIXEL_OFFSET]
    if k3 != 0.0:
        model, params = "FULL_OPENCV", params + [k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    elif np.any(camera.dist):
        model, params = "OPENCV", params + [k1, k2, p1, p2]
    else:
        model = "PINHOLE"
    return f"{camera_id} {model} {camera.width} {camera.height} {_numbers(params)}"


def _cameras(camera: Camera | Sequence[Camera]) -> list[Camera]:
    """One camera or a non-empty list of them."""
    cameras = [camera] if isinstance(camera, Camera) else list(camera)
    if not cameras:
        raise ValueError("camera must be a ferroslam.Camera or a non-empty list of them")
    return cameras


def _image_ids(keyframe_ids: object, camera_index: Optional[object], n_cameras: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """``(image_ids, camera_index)``: COLMAP's uint32 ``IMAGE_ID = id * n_cameras + camera +
    1`` (``id + 1`` for one camera), each keyframe seen once per camera."""
    ids = _index_array(keyframe_ids, "keyframe_ids", None, (2**32 - 1) // n_cameras)
    camera = (np.zeros(ids.size, np.int64) if camera_index is None
              else _index_array(camera_index, "camera_index", ids.size, n_cameras))
    image_ids = ids * n_cameras + camera + 1
    if np.unique(image_ids).size != image_ids.size:
        raise ValueError("keyframe_ids must be unique (per camera)")
    return image_ids, camera


def default_image_name(keyframe_id: int, camera: Optional[int] = None) -> str:
    """A keyframe's image file name: ``keyframe_<id:06d>.png``, in sub-folder ``cam<k>/``
    for camera ``k`` of a rig (``camera=None``: the one camera)."""
    name = f"keyframe_{int(keyframe_id):06d}.png"
    return name if camera is None else f"cam{int(camera)}/{name}"


def _image_names(image_names: Optional[Sequence[str]], keyframe_ids: np.ndarray,
                 camera: Optional[np.ndarray] = None) -> list[str]:
    """One unique name per image, without whitespace (COLMAP splits lines on spaces);
    ``camera`` the rig camera of each (``None``: one camera)."""
    if image_names is None:
        cameras = [None] * len(keyframe_ids) if camera is None else list(camera)
        return [default_image_name(i, k) for i, k in zip(keyframe_ids, cameras)]
    names = list(image_names)
    if len(names) != keyframe_ids.size:
        raise ValueError(f"image_names has {len(names)} names for {keyframe_ids.size} keyframes")
    for name in names:
        if not isinstance(name, str) or not name or name != "".join(name.split()):
            raise ValueError(f"image_names must be non-empty strings without whitespace, "
                             f"got {name!r}")
    if len(set(names)) != len(names):
        raise ValueError("image_names must be unique")
    return names


def _index_array(value: object, name: str, n_rows: Optional[int], bound: int,
                 low: int = 0) -> np.ndarray:
    """``(n_rows,)`` (``None``: any length) int64 indices in ``[low, bound)``."""
    index = np.asarray(value)
    shape_ok = index.ndim == 1 and n_rows in (None, index.shape[0])
    if not shape_ok or (index.size and not np.issubdtype(index.dtype, np.integer)):
        raise ValueError(f"{name} must be ({'N' if n_rows is None else n_rows},) integers, "
                         f"got {index.dtype} of shape {index.shape}")
    index = index.astype(np.int64)
    if index.size and (index.min() < low or index.max() >= bound):
        raise ValueError(f"{name} must lie in [{low}, {bound})")
    return index


def _observations(
    observations: Optional[Sequence[object]], n_images: int, n_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked ``(keyframe_index (K,), point_index (K,), uv_px (K, 2))``, each point seen at
    most once per keyframe; point index -1 is a keypoint without a point."""
    if observations is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2))
    try:
        keyframe_index, point_index, uv_px = observations
    except (TypeError, ValueError):
        raise ValueError("observations must be (keyframe_index, point_index, uv_px)") from None
    uv = finite_array(uv_px, "observations uv_px", (None, 2))
    image = _index_array(keyframe_index, "observations keyframe_index", len(uv), n_images)
    point = _index_array(point_index, "observations point_index", len(uv), n_points, low=-1)
    seen = point >= 0
    if np.unique(image[seen] * n_points + point[seen]).size != np.count_nonzero(seen):
        raise ValueError("observations see a point twice in one keyframe")
    return image, point, uv


def _groups(keys: np.ndarray, n_groups: int) -> list[np.ndarray]:
    """Row indices of each key ``0 .. n_groups - 1``, in the rows' order."""
    order = np.argsort(keys, kind="stable")
    bounds = np.searchsorted(keys[order], np.arange(n_groups + 1))
    return [order[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def _tracks(point: np.ndarray, n_points: int) -> list[np.ndarray]:
    """Observation rows of each point (rows without a point, -1, in none)."""
    seen = np.flatnonzero(point >= 0)
    return [seen[rows] for rows in _groups(point[seen], n_points)]


def _point2d_indices(by_image: list[np.ndarray], n_observations: int) -> np.ndarray:
    """COLMAP's ``POINT2D_IDX`` of each observation: its place in its image's POINTS2D line."""
    point2d_idx = np.empty(n_observations, np.int64)
    for rows in by_image:
        point2d_idx[rows] = np.arange(len(rows))
    return point2d_idx


def _mean(total: int, count: int) -> str:
    return repr(total / count if count else 0.0)


def _images_txt(
    image_ids: np.ndarray, camera: np.ndarray, T_w_c: np.ndarray, names: list[str],
    by_image: list[np.ndarray], point: np.ndarray, uv_px: np.ndarray,
) -> str:
    """Two lines per image: the world-to-camera pose ``T_c_w = T_w_c^-1`` as
    ``QW QX QY QZ TX TY TZ`` (COLMAP's ``cam_from_world``), then its ``X Y POINT3D_ID``s."""
    poses = _pose_texts(inverse(T_w_c))
    header = _COLMAP_HEADERS["images.txt"]
    n_observations = int(np.count_nonzero(point >= 0))
    lines = [header.format(n=len(names), mean=_mean(n_observations, len(names)))]
    for i, rows in enumerate(by_image):
        lines.append(f"{image_ids[i]} {poses[i]} {camera[i] + 1} {names[i]}\n")
        # POINT3D_ID -1: a keypoint without a point (COLMAP's "invalid" id).
        lines.append(" ".join(f"{_numbers(uv_px[r] + _COLMAP_PIXEL_OFFSET)} "
                              f"{point[r] + 1 if point[r] >= 0 else -1}"
                              for r in rows) + "\n")
    return "".join(lines)


def _points3d_txt(
    xyz: np.ndarray, rgb: np.ndarray, by_point: list[np.ndarray],
    image_id_of: np.ndarray, point2d_idx_of: np.ndarray,
) -> str:
    """One line per point; ``ERROR`` is -1 (COLMAP's "not computed")."""
    n_obs = sum(len(rows) for rows in by_point)
    lines = [_COLMAP_HEADERS["points3D.txt"].format(n=len(xyz), mean=_mean(n_obs, len(xyz)))]
    for j, rows in enumerate(by_point):
        track = "".join(f" {image_id_of[r]} {point2d_idx_of[r]}" for r in rows)
        lines.append(f"{j + 1} {_numbers(xyz[j])} {' '.join(map(str, rgb[j]))} -1{track}\n")
    return "".join(lines)


def _pose_texts(T_b_a: np.ndarray) -> list[str]:
    """``QW QX QY QZ TX TY TZ`` of each of ``(N, 4, 4)`` poses (COLMAP's ``b_from_a``)."""
    q_xyzw = matrix_to_quat(T_b_a[:, :3, :3])
    return [_numbers(np.concatenate([q[3:], q[:3], T[:3, 3]])) for q, T in zip(q_xyzw, T_b_a)]


def _rig_texts(T_c0_c: Sequence[np.ndarray], keyframe_ids: np.ndarray, camera: np.ndarray,
               image_ids: np.ndarray, T_w_c: np.ndarray) -> dict[str, str]:
    """``rigs.txt`` (camera 1 the reference, camera ``k`` at ``sensor_from_rig = T_ck_c0``)
    and ``frames.txt`` (per keyframe, ``rig_from_world = T_c0_w`` and its images)."""
    T_c0_ck = np.stack([finite_array(T, f"T_c0_c[{k}]", (4, 4)) for k, T in enumerate(T_c0_c)])
    _rigid_poses(T_c0_ck, "T_c0_c", "a rig's cameras are rigidly mounted")
    sensors = "".join(f" CAMERA {k + 1} 1 {pose}"
                      for k, pose in enumerate(_pose_texts(inverse(T_c0_ck))) if k > 0)
    rig_line = f"{_COLMAP_RIG_ID} {len(T_c0_ck)} CAMERA 1{sensors}\n"
    frame_ids = np.unique(keyframe_ids)
    frames = [_COLMAP_HEADERS["frames.txt"].format(n=len(frame_ids))]
    for frame_id, rows in zip(frame_ids, _groups(np.searchsorted(frame_ids, keyframe_ids),
                                                len(frame_ids))):
        # T_c0_w = T_c0_ck T_ck_w, from the keyframe's first image.
        i = rows[0]
        T_c0_w = T_c0_ck[camera[i]] @ inverse(T_w_c[i][None])
        data = "".join(f" CAMERA {camera[r] + 1} {image_ids[r]}" for r in rows)
        frames.append(f"{frame_id + 1} {_COLMAP_RIG_ID} {_pose_texts(T_c0_w)[0]} "
                      f"{len(rows)}{data}\n")
    return {"rigs.txt": _COLMAP_HEADERS["rigs.txt"] + rig_line, "frames.txt": "".join(frames)}


def write_colmap_model(
    folder: PathLike,
    camera: Camera | Sequence[Camera],
    keyframe_ids: np.ndarray,
    keyframe_poses_T_w_c: np.ndarray,
    points_xyz: np.ndarray,
    *,
    point_colors: Optional[np.ndarray] = None,
    observations: Optional[tuple[np.ndarray, np.ndarray, np.ndarray]] = None,
    image_names: Optional[Sequence[str]] = None,
    camera_index: Optional[np.ndarray] = None,
    T_c0_c: Optional[Sequence[np.ndarray]] = None,
) -> Path:
    """Write keyframes and map points as a COLMAP text model in ``folder``; return it.

    Writes ``cameras.txt``, ``images.txt`` and ``points3D.txt`` (COLMAP's text format, read by
    ``colmap``, ``pycolmap.Reconstruction(folder)``, nerfstudio, Gaussian-splatting trainers).

    Conventions: ferroslam poses are ``T_w_c`` (camera to world); COLMAP stores each image's
    world-to-camera pose ``T_c_w = T_w_c^-1`` (``cam_from_world``: ``p_c = R p_w + t``) as
    ``QW QX QY QZ TX TY TZ``. Pixel coordinates follow OpenCV (centre of the top-left pixel at
    ``(0, 0)``); COLMAP puts it at ``(0.5, 0.5)``, so the principal point and every
    observation are written 0.5 px larger. ``IMAGE_ID`` is keyframe id + 1 (``id *
    n_cameras + camera + 1`` for several cameras), ``POINT3D_ID`` is row + 1 and camera
    ``k`` is ``CAMERA_ID`` ``k + 1`` (COLMAP numbers from 1).

    Args:
        folder: output folder (created with its parents).
        camera: intrinsics of the images the keyframes come from (raw, distorted images:
            ``PINHOLE``, ``OPENCV`` or ``FULL_OPENCV``, see below), or a list of them: the
            cameras of a rig.
        keyframe_ids: ``(N,)`` integer keyframe ids, one per image: unique per camera.
        keyframe_poses_T_w_c: ``(N, 4, 4)`` rigid camera poses in the world, metres.
        points_xyz: ``(M, 3)`` world positions in metres.
        point_colors: optional ``(M, 3)`` RGB (integers in ``[0, 255]`` or floats in
            ``[0, 1]``); grey 128 if not given.
        observations: optional ``(keyframe_index (K,), point_index (K,), uv_px (K, 2))``:
            point ``points_xyz[point_index]`` seen in keyframe ``keyframe_index`` (a row of
            the keyframe arrays) at raw pixel ``uv_px``; at most once per keyframe. Point
            index -1 is a keypoint without a point (listed in POINTS2D with POINT3D_ID
            -1, in no track). Without them the images list no 2-D points and the points
            have empty tracks.
        image_names: optional ``N`` unique names without whitespace, the image files
            relative to the tools' image folder (default ``keyframe_<id:06d>.png``).
        camera_index: optional ``(N,)`` row of ``camera`` that took each image (default 0).
        T_c0_c: optional ``(4, 4)`` pose of each camera in the first (``p_c0 = T_c0_c p_c``,
            metres): the cameras are a rig, written to ``rigs.txt`` and ``frames.txt``
            (COLMAP 3.12 on; one frame per keyframe id, its images those of the id).

    The camera model is ``PINHOLE`` without distortion, ``OPENCV`` when ``k3 = 0`` and
    ``FULL_OPENCV`` (``k4 = k5 = k6 = 0``) otherwise; ``ERROR`` is -1 (not computed).

    Raises:
        TypeError: ``camera`` is not a :class:`~ferroslam.camera.Camera`.
        ValueError: shapes, NaN/inf, non-rigid poses, ids or indices out of range or
            repeated, bad names or colours.
    """
    cameras = _cameras(camera)
    camera_lines = "".join(_colmap_camera_line(c, k + 1) + "\n" for k, c in enumerate(cameras))
    image_ids, image_camera = _image_ids(keyframe_ids, camera_index, len(cameras))
    ids = np.asarray(keyframe_ids, np.int64)
    T_w_c = finite_array(keyframe_poses_T_w_c, "keyframe_poses_T_w_c", (len(ids), 4, 4))
    _rigid_poses(T_w_c, "keyframe_poses_T_w_c", "COLMAP images need rigid camera poses")
    names = _image_names(image_names, ids, image_camera if len(cameras) > 1 else None)
    xyz = finite_array(points_xyz, "points_xyz", (None, 3))
    rgb = (np.full(xyz.shape, 128, np.uint8) if point_colors is None
           else _colors_u8(point_colors, len(xyz), "point_colors"))
    image, point, uv_px = _observations(observations, len(image_ids), len(xyz))
    by_image = _groups(image, len(image_ids))
    texts = {
        "cameras.txt": _COLMAP_HEADERS["cameras.txt"].format(n=len(cameras)) + camera_lines,
        "images.txt": _images_txt(image_ids, image_camera, T_w_c, names, by_image, point,
                                  uv_px),
        "points3D.txt": _points3d_txt(xyz, rgb, _tracks(point, len(xyz)), image_ids[image],
                                      _point2d_indices(by_image, len(image))),
    }
    if T_c0_c is not None:
        if len(T_c0_c) != len(cameras):
            raise ValueError(f"T_c0_c has {len(T_c0_c)} poses for {len(cameras)} cameras")
        texts.update(_rig_texts(T_c0_c, ids, image_camera, image_ids, T_w_c))
    folder = Path(folder)
    for name, text in texts.items():
        write_text(folder / name, text)
    return folder
