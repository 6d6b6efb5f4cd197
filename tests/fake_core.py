"""A stand-in for ``ferroslam._core.SlamSystem`` with the same Python API.

It "tracks" by looking up the ground-truth pose (perturbed by a fixed world transform), so
the pipeline, writers, metrics and CLI can be tested without the native module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ferroslam.options import core_default
from ferroslam.transforms import quat_to_matrix


@dataclass
class FakeTrackResult:
    state: str
    T_w_c: Optional[np.ndarray]
    is_keyframe: bool
    num_tracked: int
    tracking_ms: float
    mapping_ms: float
    pose_optimisation_ms: float = 0.0
    local_ba_ms: float = 0.0
    loop_closing_ms: float = 0.0
    extraction_ms: float = 0.5  # the core reports its front end
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 5), np.float32))


class FakeSlamSystem:
    # the native SlamSystem's option names (tests/test_core_api.py keeps them in step)
    KNOWN = {"n_features", "ini_fast", "min_fast", "scale_factor", "n_levels",
             "track_feature_range", "skip_max_frames", "relocalisation_window_s", "gap_frames",
             "bf",
             "baseline", "depth_threshold",
             "depth_range", "match_pair_every_frame", "seed", "deterministic", "loop_closure",
             "loop_closure_threshold"}
    # The extractor's defaults, read from the core's option table (never restated).
    EXTRACTOR_DEFAULTS = {name: core_default(name, "rgbd") for name in
                          ("n_features", "ini_fast", "min_fast", "scale_factor", "n_levels")}

    def __init__(self, fx, fy, cx, cy, dist, width, height, sensor="rgbd", *, groundtruth,
                 model="pinhole", rolling_shutter_readout_s=0.0, **config):
        unknown = set(config) - self.KNOWN
        if unknown:
            raise ValueError(f"unknown option(s) {sorted(unknown)}")
        assert model == "pinhole" and np.asarray(dist).shape == (5,) and sensor == "rgbd"
        self.config = config
        self.gt_t, self.gt_T = groundtruth
        # The map frame differs from the motion-capture frame by a rigid transform.
        self.T_map_gt = np.eye(4)
        self.T_map_gt[:3, :3] = quat_to_matrix(np.array([0.1, -0.2, 0.3, 0.9]))
        self.T_map_gt[:3, 3] = [0.5, -1.0, 2.0]
        self.stamps, self.poses, self.kf = [], [], []
        self.calls = []

    @property
    def options(self) -> dict:
        return {**self.EXTRACTOR_DEFAULTS, **self.config}

    def track(self, timestamp, images, *, depth=None, colors=None, masks=None):
        assert images.dtype == np.uint8 and images.ndim in (2, 3)
        assert depth is not None and depth.shape == images.shape[:2]
        assert colors is None or (colors.dtype == np.uint8 and colors.shape[:2] == images.shape[:2])
        depth_m = depth[::16, ::16]  # "tracked": the depth pixels of a coarse grid
        self.calls.append(timestamp)
        if len(self.calls) == 1:
            return FakeTrackResult("not_initialized", None, False, 0, 1.0, 0.0)
        i = int(np.argmin(np.abs(self.gt_t - timestamp)))
        T = self.T_map_gt @ self.gt_T[i]
        self.stamps.append(timestamp)
        self.poses.append(T)
        key = len(self.stamps) % 3 == 1
        if key:
            self.kf.append(len(self.stamps) - 1)
        return FakeTrackResult("ok", T, key, int((depth_m > 0).sum()), 2.0, 0.5)

    def frame_trajectory(self):
        return np.array(self.stamps), np.array(self.poses).reshape(-1, 4, 4)

    def set_vocabulary(self, vocabulary):
        self.vocabulary = vocabulary

    def frame_map_ids(self):
        return np.zeros(len(self.stamps), dtype=np.uint32)

    def maps(self):
        return [{"id": 0, "frames": len(self.stamps), "keyframes": len(self.kf), "points": 10,
                 "current": True}] if self.stamps else []

    def merges(self):
        return []

    def close(self):
        pass

    def wait(self):
        pass

    def loops(self):
        return []

    def loop_stats(self):
        return {"keyframes_checked": 0, "with_candidates": 0, "verified": 0, "rejected": 0}

    @property
    def num_keyframes(self) -> int:
        return len(self.kf)

    def keyframe_trajectory(self, map_id=None):
        ids = np.arange(len(self.kf), dtype=np.uint32)
        return ids, np.array(self.stamps)[self.kf], np.array(self.poses)[self.kf]

    def map_points(self, map_id=None):
        return np.zeros((10, 3))

    def map_point_colors(self, map_id=None):
        return np.full((10, 3), 128, np.uint8)

    def sparse_model(self, map_id=None):
        ids, stamps, poses = self.keyframe_trajectory()
        return {"keyframe_ids": ids, "timestamps": stamps, "T_w_c": poses,
                "keypoint_offsets": np.zeros(len(ids) + 1, np.int64),
                "keypoints_px": np.zeros((0, 2)), "point_index": np.zeros(0, np.int64),
                "points_xyz": self.map_points(), "point_colors": self.map_point_colors()}
