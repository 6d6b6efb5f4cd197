"""Synthetic vision on the real EuRoC V1_01_easy flight: ready-made ORB-like features.

The whole 144 s, 58 m flight of ``shared/data/euroc/V1_01_easy_imu_gt`` (vicon2gt body poses
at the 20 Hz camera timestamps, the real 200 Hz IMU, the real cam0/cam1 calibration) looks at a
seeded field of landmarks on the walls, floor, ceiling and a few boxes of a synthetic 8 x 8 x 3 m
room around the flight volume. Every landmark has its own random 256-bit descriptor; each frame
reports the landmarks cam0 sees as keypoints ``(N, 5) float32 [x, y, octave, angle_deg,
response]`` and descriptors ``(N, 32) uint8``, the format of :mod:`ferroslam.features`, so they
can be fed to ``ferroslam._core.SlamSystem`` without images.

Camera model (what is and is not simulated):

* cam0 is the ideal pinhole of its real intrinsics (fx, fy, cx, cy, 752 x 480); lens
  distortion is NOT simulated, so create the system with ``dist`` zeros
  (``seq.camera.dist``). Camera poses are ``T_w_c = T_w_b(t) @ T_b_cam0`` (``T_BS`` of
  ``cam0_sensor.yaml``).
* Stereo is an ideal rectified pair: a virtual right camera with cam0's intrinsics and
  orientation, displaced by ``baseline_m`` (the real cam0-cam1 distance, 0.110 m) along cam0's
  x axis. Its keypoint of a landmark is ``(u_right, y)`` with ``u_right = u - bf / z``,
  ``bf = fx * baseline_m`` (ORB-SLAM's virtual right coordinate). The core's ``track_stereo``
  needs image pyramids, which do not exist here: feed stereo through ``track_rgbd`` with
  ``bf=seq.bf`` and ``depth_m`` (identical observations, because ``u - bf / depth_m`` is
  ``u_right`` again). The real cam1 pose ``T_b_cam1`` is exposed but not used.
* Visibility: in front (z > ``min_depth_m``), inside the image minus ``border_px``, distance
  at most ``max_range_m``, the landmark's surface facing the camera within
  ``max_incidence_deg``, and (``occlusion=True``) no box between camera and landmark. Room
  surfaces cannot occlude (the room is convex).
* Noise: gaussian pixel noise ``pixel_sigma`` on x, y and (independently) ``u_right``, the
  same at every octave (real ORB noise grows with the level); ``depth_m = bf / (x - u_right)``
  from the noisy disparity, so depth noise is stereo-like (~5 % at 4 m for 0.5 px). Each
  observation's descriptor is the landmark's with exactly ``bit_flips`` distinct bits flipped.
* Octave from distance ``d``, as ORB's scale pyramid would detect a patch:
  ``clamp(round(log(d_ref / d) / log(scale_factor)), 0, n_levels - 1)`` with a per-landmark
  reference distance ``d_ref`` (uniform in ``ref_distance_m``). Angle: a per-landmark constant
  (``angle_deg="random"``) or 0; response 1.

Randomness: the field comes from ``seed``; frame ``k`` of the flight draws its noise from
``numpy.random.default_rng([seed, 1, k])``, so ``features(i)`` is random-access and identical
whatever ``start_s``/``duration_s`` cut the sequence.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional, Union

import numpy as np

from ._data import data_dir
from .camera import Camera
from .datasets.euroc import (
    ImuParams,
    _number,
    _numbers,
    _T_BS,
    read_sensor_yaml,
)
from .io import read_asl_floats, read_asl_rows, seconds_from_ns
from .transforms import inverse, poses_from_tum

__all__ = [
    "DEFAULT_BOXES",
    "LandmarkField",
    "ROOM_MAX",
    "ROOM_MIN",
    "SyntheticStereoSequence",
    "VisionModel",
    "default_flight_path",
    "make_landmark_field",
]

# Room around the V1_01 flight volume (positions x -2.2..2.2, y -2.5..3.3, z 0.9..1.9 m).
ROOM_MIN = (-4.0, -3.6, 0.0)
ROOM_MAX = (4.0, 4.4, 3.0)
# Boxes (min corner, max corner) standing on the floor, clear of the flight path; the last one
# is the take-off platform under the resting MAV (its top is 0.2 m below the body).
DEFAULT_BOXES = (
    ((2.7, -3.2, 0.0), (3.7, -1.9, 1.2)),
    ((-3.7, 2.5, 0.0), (-2.6, 3.8, 1.6)),
    ((-3.6, -3.3, 0.0), (-2.6, -2.2, 0.8)),
    ((2.8, 2.9, 0.0), (3.8, 4.2, 2.0)),
    ((-0.6, -0.5, 0.0), (0.6, 0.5, 0.5)),
    ((0.5, 1.8, 0.0), (1.3, 2.6, 0.7)),
)


def default_flight_path() -> Path:
    """``<shared data>/euroc/V1_01_easy_imu_gt`` (may not exist; see ``ferroslam._data``)."""
    return data_dir() / "euroc" / "V1_01_easy_imu_gt"


@dataclass(frozen=True)
class LandmarkField:
    """Landmarks in the world frame with what a camera needs to observe them.

    Attributes:
        points: ``(M, 3)`` float64 world positions, metres.
        normals: ``(M, 3)`` float64 unit normals of the surface each lies on (pointing into
            free space).
        descriptors: ``(M, 32)`` uint8, 256 random bits per landmark.
        ref_distance: ``(M,)`` float64 metres, distance at which it is detected at octave 0.
        angle_deg: ``(M,)`` float32 keypoint angle reported with every observation.
        strength: ``(M,)`` float64 in [0, 1): rank for the per-frame feature budget (the
            strongest visible landmarks are detected, consistently from frame to frame).
        boxes: ``(B, 2, 3)`` float64 (min corner, max corner) of the occluding boxes.
    """

    points: np.ndarray
    normals: np.ndarray
    descriptors: np.ndarray
    ref_distance: np.ndarray
    angle_deg: np.ndarray
    strength: np.ndarray
    boxes: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _faces(lo: np.ndarray, hi: np.ndarray, inward: bool, floor: bool) -> list:
    """Axis-aligned faces ``(axis, value, lo, hi, normal)`` of a box; ``floor=False`` drops
    the bottom face (boxes stand on the floor)."""
    faces = []
    for axis in range(3):
        for value, sign in ((lo[axis], -1.0), (hi[axis], 1.0)):
            if axis == 2 and sign < 0 and not floor:
                continue
            normal = np.zeros(3)
            normal[axis] = -sign if inward else sign
            faces.append((axis, value, lo, hi, normal))
    return faces


def make_landmark_field(
    n_landmarks: int = 24000,
    seed: int = 0,
    *,
    room: tuple = (ROOM_MIN, ROOM_MAX),
    boxes: tuple = DEFAULT_BOXES,
    ref_distance_m: tuple[float, float] = (3.0, 6.0),
    angle_deg: Literal["random", "zero"] = "random",
) -> LandmarkField:
    """Landmarks spread uniformly (by area) over the room's six inner faces and the boxes'
    five visible faces; those falling inside another box (floor under a box) are dropped, so
    slightly fewer than ``n_landmarks`` remain. Deterministic for a given ``seed``.

    Raises ``ValueError`` for ``n_landmarks < 1``, an empty room or box, or a bad
    ``ref_distance_m``/``angle_deg``.
    """
    if n_landmarks < 1:
        raise ValueError(f"n_landmarks must be >= 1, got {n_landmarks}")
    if not 0 < ref_distance_m[0] <= ref_distance_m[1]:
        raise ValueError(f"ref_distance_m must be 0 < lo <= hi, got {ref_distance_m}")
    if angle_deg not in ("random", "zero"):
        raise ValueError(f"angle_deg must be 'random' or 'zero', got {angle_deg!r}")
    box_arr = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    room_arr = np.asarray(room, dtype=np.float64).reshape(2, 3)
    for lo, hi in (room_arr, *box_arr):
        if not np.all(hi > lo):
            raise ValueError(f"box with max corner {hi} not above min corner {lo}")
    faces = _faces(room_arr[0], room_arr[1], inward=True, floor=True)
    owners = [-1] * len(faces)
    for b, (lo, hi) in enumerate(box_arr):
        box_faces = _faces(lo, hi, inward=False, floor=False)
        faces += box_faces
        owners += [b] * len(box_faces)
    areas = np.array([np.prod(np.delete(hi - lo, axis)) for axis, _, lo, hi, _ in faces])

    rng = np.random.default_rng([seed, 0])
    face_of = rng.choice(len(faces), size=n_landmarks, p=areas / areas.sum())
    points = np.empty((n_landmarks, 3))
    normals = np.empty((n_landmarks, 3))
    owner = np.empty(n_landmarks, dtype=np.intp)
    for f, (axis, value, lo, hi, normal) in enumerate(faces):
        sel = face_of == f
        points[sel] = rng.uniform(lo, hi, size=(int(sel.sum()), 3))
        points[sel, axis] = value
        normals[sel] = normal
        owner[sel] = owners[f]
    keep = np.ones(n_landmarks, dtype=bool)
    for b, (lo, hi) in enumerate(box_arr):
        inside = np.all((points >= lo - 1e-9) & (points <= hi + 1e-9), axis=1)
        keep &= ~(inside & (owner != b))
    descriptors = rng.integers(0, 256, size=(n_landmarks, 32), dtype=np.uint8)
    ref = rng.uniform(*ref_distance_m, size=n_landmarks)
    angles = rng.uniform(0.0, 360.0, size=n_landmarks) if angle_deg == "random" else np.zeros(
        n_landmarks)
    strength = rng.random(n_landmarks)
    return LandmarkField(
        points=points[keep], normals=normals[keep], descriptors=descriptors[keep],
        ref_distance=ref[keep], angle_deg=angles[keep].astype(np.float32),
        strength=strength[keep], boxes=box_arr,
    )


@dataclass(frozen=True)
class VisionModel:
    """How cam0 observes the landmarks (see the module doc). Units: pixels, metres, degrees.

    ``scale_factor`` and ``n_levels`` must match the ``SlamSystem``'s ORB pyramid options.
    ``max_features`` is the detector's budget per frame (ORB-SLAM's ``nFeatures``): of the
    visible landmarks only the strongest that many are reported (0: no limit).
    """

    pixel_sigma: float = 0.5
    bit_flips: int = 10
    max_range_m: float = 8.0
    min_depth_m: float = 0.1
    border_px: float = 16.0
    max_incidence_deg: float = 75.0
    occlusion: bool = True
    scale_factor: float = 1.2
    n_levels: int = 8
    max_features: int = 1000

    def __post_init__(self) -> None:
        if not (np.isfinite(self.pixel_sigma) and self.pixel_sigma >= 0):
            raise ValueError(f"pixel_sigma must be >= 0, got {self.pixel_sigma}")
        if not 0 <= self.bit_flips <= 256:
            raise ValueError(f"bit_flips must be in 0..=256, got {self.bit_flips}")
        if not 0 < self.min_depth_m < self.max_range_m:
            raise ValueError("need 0 < min_depth_m < max_range_m")
        if not 0 < self.max_incidence_deg <= 90:
            raise ValueError(f"max_incidence_deg must be in (0, 90], got {self.max_incidence_deg}")
        if self.scale_factor <= 1 or self.n_levels < 1 or self.border_px < 0:
            raise ValueError("need scale_factor > 1, n_levels >= 1, border_px >= 0")
        if self.max_features < 0:
            raise ValueError(f"max_features must be >= 0, got {self.max_features}")


def _occluded(centre: np.ndarray, points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: the open segment centre -> point crosses a box (slab test). A point on
    a box face ends its segment on the face (t = 1) and is not occluded by that box."""
    d = points - centre
    hit = np.zeros(len(points), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo, hi in boxes:
            t1 = (lo - centre) / d
            t2 = (hi - centre) / d
            inside_slab = (centre >= lo) & (centre <= hi)
            near = np.where(d == 0, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
            far = np.where(d == 0, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
            t_in = near.max(axis=1)
            t_out = far.min(axis=1)
            hit |= (t_in <= t_out) & (t_out > 0) & (t_in < 1 - 1e-6)
    return hit


def _flip_bits(descriptors: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Copies of ``(N, 32)`` descriptors with exactly ``k`` distinct random bits flipped."""
    if k == 0 or len(descriptors) == 0:
        return descriptors.copy()
    bits = np.argpartition(rng.random((len(descriptors), 256)), k - 1, axis=1)[:, :k]
    mask = np.zeros((len(descriptors), 256), dtype=bool)
    np.put_along_axis(mask, bits, True, axis=1)
    return descriptors ^ np.packbits(mask, axis=1)


class SyntheticStereoSequence:
    """The V1_01_easy flight at 20 Hz with synthetic cam0 (+ virtual right) features.

    Args:
        path: folder with ``groundtruth_vicon2gt.csv``, ``cam0_sensor.yaml``,
            ``cam1_sensor.yaml`` and ``imu0/`` (default :func:`default_flight_path`).
        seed: seeds the landmark field (unless ``landmarks`` is given) and the noise.
        landmarks: a ready field (default ``make_landmark_field(seed=seed)``).
        vision: the observation model (default ``VisionModel()``).
        start_s, duration_s: keep the frames with ``start_s <= t - t_first < start_s +
            duration_s`` (``t_first``: first camera time of the flight; the MAV rests until
            ~5.3 s, then flies).

    Attributes:
        timestamps: ``(N,)`` float64 seconds; ``timestamps_ns``: ``(N,)`` int64.
        camera: ideal cam0 pinhole (``dist`` zeros). ``baseline_m``, ``bf`` (= fx * baseline).
        T_b_c (= ``T_b_cam0``), ``T_b_cam1``: ``(4, 4)`` camera poses in the body (IMU) frame.
        T_w_b: ``(N, 4, 4)`` body poses; ``v_w_b``: ``(N, 3)`` m/s; ``gyro_bias`` (rad/s),
            ``acc_bias`` (m/s^2): ``(N, 3)``, all from vicon2gt at the frame times.
        landmarks: the :class:`LandmarkField`; vision: the :class:`VisionModel`.

    Raises:
        FileNotFoundError: a missing folder or file (named).
        ValueError: malformed files, or a cut that keeps no frame.
    """

    is_stereo = True
    has_groundtruth = True

    def __init__(
        self,
        path: Optional[Union[str, Path]] = None,
        *,
        seed: int = 0,
        landmarks: Optional[LandmarkField] = None,
        vision: Optional[VisionModel] = None,
        start_s: float = 0.0,
        duration_s: Optional[float] = None,
    ) -> None:
        self.path = Path(path) if path is not None else default_flight_path()
        if not self.path.is_dir():
            raise FileNotFoundError(f"EuRoC flight folder not found: {self.path}")
        self.seed = int(seed)
        self.vision = vision if vision is not None else VisionModel()
        self.landmarks = landmarks if landmarks is not None else make_landmark_field(seed=seed)

        cam0_yaml = self.path / "cam0_sensor.yaml"
        yaml = read_sensor_yaml(cam0_yaml)
        fx, fy, cx, cy = _numbers(yaml, "intrinsics", 4, cam0_yaml)
        width, height = _numbers(yaml, "resolution", 2, cam0_yaml)
        self.camera = Camera(fx, fy, cx, cy, np.zeros(5), int(width), int(height))
        self.T_b_c = _T_BS(yaml, cam0_yaml)
        cam1_yaml = self.path / "cam1_sensor.yaml"
        self.T_b_cam1 = _T_BS(read_sensor_yaml(cam1_yaml), cam1_yaml)
        self.baseline_m = float(np.linalg.norm((inverse(self.T_b_c) @ self.T_b_cam1)[:3, 3]))
        self.bf = self.camera.fx * self.baseline_m

        gt_path = self.path / "groundtruth_vicon2gt.csv"
        stamps, rows = read_asl_rows(gt_path, 17, "vicon2gt ground truth")
        values = read_asl_floats(gt_path, rows, slice(1, 17))
        t_all = seconds_from_ns(stamps)
        rel = t_all - t_all[0]
        keep = rel >= start_s - 1e-6
        if duration_s is not None:
            keep &= rel < start_s + duration_s - 1e-6
        self._flight_index = np.flatnonzero(keep)
        if self._flight_index.size == 0:
            raise ValueError(f"no frame in [{start_s}, {start_s} + {duration_s}) s of the flight")
        self._flight_ns = stamps
        values = values[keep]
        self.timestamps_ns = stamps[keep]
        self.timestamps = t_all[keep]
        # vicon2gt columns: p xyz, q wxyz, v xyz, gyro bias xyz, acc bias xyz.
        self.T_w_b = poses_from_tum(
            np.concatenate([values[:, 0:3], values[:, 4:7], values[:, 3:4]], 1))
        self.v_w_b = values[:, 7:10]
        self.gyro_bias = values[:, 10:13]
        self.acc_bias = values[:, 13:16]
        self._T_c_w = inverse(self.T_w_b @ self.T_b_c)
        self._imu: Optional[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = None

    @property
    def name(self) -> str:
        return f"synthetic_{self.path.name}_seed{self.seed}"

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def __repr__(self) -> str:
        return (f"SyntheticStereoSequence({str(self.path)!r}, frames={len(self)}, "
                f"landmarks={len(self.landmarks)}, seed={self.seed})")

    def groundtruth(self) -> tuple[np.ndarray, np.ndarray]:
        """``(timestamps (N,) s, T_w_c (N, 4, 4))`` of cam0 at every frame (exact: the
        features were generated from these poses)."""
        return self.timestamps.copy(), inverse(self._T_c_w)

    def visible(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free observations of frame ``i``: ``(landmark ids (N,) int64 ascending,
        ideal pixels (N, 2) float64)`` of the landmarks cam0 sees (module doc: visibility),
        at most ``vision.max_features`` of them (the strongest)."""
        vm, cam, lm = self.vision, self.camera, self.landmarks
        T_c_w = self._T_c_w[i]
        centre = inverse(T_c_w)[:3, 3]
        p_c = lm.points @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        z = p_c[:, 2]
        ok = z > vm.min_depth_m
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([cam.fx * p_c[:, 0] / z + cam.cx, cam.fy * p_c[:, 1] / z + cam.cy], 1)
        b = vm.border_px
        ok &= (uv[:, 0] >= b) & (uv[:, 0] < cam.width - b)
        ok &= (uv[:, 1] >= b) & (uv[:, 1] < cam.height - b)
        dist = np.linalg.norm(p_c, axis=1)
        ok &= dist <= vm.max_range_m
        to_cam = centre - lm.points
        facing = np.einsum("ij,ij->i", lm.normals, to_cam)
        ok &= facing >= np.cos(np.radians(vm.max_incidence_deg)) * dist
        ids = np.flatnonzero(ok)
        if vm.occlusion and len(lm.boxes):
            ids = ids[~_occluded(centre, lm.points[ids], lm.boxes)]
        if 0 < vm.max_features < len(ids):
            ids = np.sort(ids[np.argsort(-lm.strength[ids], kind="stable")[: vm.max_features]])
        return ids.astype(np.int64), uv[ids]

    def features(self, i: int) -> dict[str, np.ndarray]:
        """Features of frame ``i``, in random order.

        Returns a dict with ``keypoints`` ``(N, 5) float32 [x, y, octave, angle_deg,
        response]`` (noisy undistorted pixels), ``descriptors`` ``(N, 32) uint8`` (bit noise),
        ``depth_m`` ``(N,) float32`` and ``u_right`` ``(N,) float32`` (both -1 where the
        virtual right camera does not see the landmark: outside its image or a non-positive
        disparity), and ``landmark_ids`` ``(N,) int64`` (rows of ``landmarks``).
        Raises ``IndexError`` for ``i`` out of range.
        """
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range (0..{len(self)})")
        i %= len(self)
        vm, lm = self.vision, self.landmarks
        rng = np.random.default_rng([self.seed, 1, int(self._flight_index[i])])
        ids, uv = self.visible(i)
        order = rng.permutation(len(ids))
        ids, uv = ids[order], uv[order]
        n = len(ids)
        T_c_w = self._T_c_w[i]
        p_c = lm.points[ids] @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        dist = np.linalg.norm(p_c, axis=1)
        octave = np.clip(np.round(np.log(lm.ref_distance[ids] / dist) / np.log(vm.scale_factor)),
                         0, vm.n_levels - 1)
        xy = uv + rng.normal(0.0, vm.pixel_sigma, size=(n, 2))
        u_right_true = uv[:, 0] - self.bf / p_c[:, 2]
        u_right = u_right_true + rng.normal(0.0, vm.pixel_sigma, size=n)
        disparity = xy[:, 0] - u_right
        seen = (u_right_true >= vm.border_px) & (disparity > 0)
        with np.errstate(divide="ignore"):
            depth = np.where(seen, self.bf / disparity, -1.0)
        keypoints = np.column_stack([xy, octave, lm.angle_deg[ids], np.ones(n)])
        return {
            "keypoints": keypoints.astype(np.float32),
            "descriptors": _flip_bits(lm.descriptors[ids], vm.bit_flips, rng),
            "depth_m": depth.astype(np.float32),
            "u_right": np.where(seen, u_right, -1.0).astype(np.float32),
            "landmark_ids": ids,
        }

    def _imu_ns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self._imu is None:
            path = self.path / "imu0" / "data.csv"
            stamps, rows = read_asl_rows(path, 7, "EuRoC IMU file")
            values = read_asl_floats(path, rows, slice(1, 7))
            self._imu = (stamps, seconds_from_ns(stamps), values[:, :3], values[:, 3:6])
        return self._imu

    def imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The real IMU stream of the whole flight: ``(t (M,) s, gyro (M, 3) rad/s,
        acc (M, 3) m/s^2)`` in the body (IMU) frame, 200 Hz (read once, then cached)."""
        return self._imu_ns()[1:]

    def imu_between(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU samples ``(t, gyro, acc)`` with ``t_prev < t <= t_i``, ``t_prev`` the previous
        camera time of the flight (also for the first frame of a cut sequence; -inf for the
        flight's first frame), as ORB-SLAM3's EuRoC driver groups them. Compared in
        nanoseconds with 1 us of slack: vicon2gt frame times lie up to 256 ns before the IMU
        sample taken with the image."""
        ns, t, gyro, acc = self._imu_ns()
        k = int(self._flight_index[i])
        slack = 1000
        lo = 0 if k == 0 else np.searchsorted(ns, self._flight_ns[k - 1] + slack, side="right")
        hi = np.searchsorted(ns, self._flight_ns[k] + slack, side="right")
        return t[lo:hi], gyro[lo:hi], acc[lo:hi]

    def imu_params(self) -> ImuParams:
        """Noise model and ``T_b_imu`` from ``imu0/sensor.yaml``."""
        path = self.path / "imu0" / "sensor.yaml"
        yaml = read_sensor_yaml(path)
        names = ("gyroscope_noise_density", "gyroscope_random_walk",
                 "accelerometer_noise_density", "accelerometer_random_walk", "rate_hz")
        return ImuParams(*(_number(yaml, k, path) for k in names), T_b_imu=_T_BS(yaml, path))
