"""RGB-D-inertial on a real IMU stream: the MH_01 window (400 frames, 20 s) into
``RGBDVSlam`` with the real 200 Hz IMU, cam0's depth computed per frame from the RECTIFIED
pair with OpenCV's SGBM (issue case "MH_01 window as RGB-D-inertial": aligned, metric, SE(3)
ATE <= 1 cm). Until this file RGB-D-inertial was tested on synthetic vision only.

Depth: ``fx * baseline / disparity`` metres (rectified fx 436.2 px, baseline 11.0 cm), 0
(missing) where SGBM gives none; the default ``depth_range`` (0.1, 8) m. Mapping runs inline
(``threaded=False``), so the run is deterministic.

Measured 2026-12-02 (this build, OpenCV 5.1.0, SGBM blockSize 3, 64 disparities): 400/400 tracked
in one segment, aligned and refined twice (5 s and 15 s), gravity 1.4 deg from the ground
truth's, SE(3) ATE 7.1 mm with no scale fitted, Sim(3) ATE 5.1 mm at scale 0.977 (the SGBM
depth puts the map 2.3 % large), about 38 s (23 s of it SGBM). The same with
blockSize 5: 8.7 mm (scale 0.970); blockSize 7: 27.7 mm (0.908); blockSize 5 with
``depth_range`` (0.3, 5) m: 10.4 mm; the HH and 3-way SGBM modes (blockSize 5): 17.2 and
17.0 mm. blockSize 3 (the SGBM default of OpenCV's stereo_match sample) was kept after these
trials; the smaller the block the smaller the scale bias, plausibly because the features sit on
edges, where a larger block smears the near disparity over the far side. The
stereo-inertial run on the same frames reaches 4.3 mm (test_real_data_matrix.py). Without
the IMU the same depth gives 6.9 mm (scale 0.979): the IMU does not correct SGBM's scale,
which the depth fixes and the alignment keeps, so this proves the RGB-D-inertial path runs
and stays metric on a real IMU stream rather than that the IMU improves the trajectory.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from conftest import require_data

from ferroslam.datasets import open_sequence
from ferroslam.metrics import ate
from ferroslam.pipeline import imu_batch_end
from ferroslam.trajectory import Trajectory
from ferroslam.vslam import RGBDVSlam

BLOCK = 3
SGBM = dict(minDisparity=0, numDisparities=64, blockSize=BLOCK, P1=8 * BLOCK ** 2,
            P2=32 * BLOCK ** 2, disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100,
            speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM)


def _depth_m(sgbm, bf_m: float, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Float32 depth in metres of the rectified left image, 0 where there is no disparity."""
    disparity = sgbm.compute(left, right).astype(np.float32) / 16.0  # 4 fractional bits
    depth = np.zeros_like(disparity)
    valid = disparity > 0
    depth[valid] = bf_m / disparity[valid]
    return depth


@pytest.fixture(scope="module")
def run():
    seq = open_sequence(require_data("euroc", "MH_01_easy_window"))
    assert seq.is_rectified
    sgbm = cv2.StereoSGBM_create(**SGBM)
    bf_m = seq.camera.fx * seq.baseline_m
    t_imu, gyro, accel = seq.imu()
    period_s = 1.0 / seq.imu_params().rate_hz
    started = time.perf_counter()
    vslam = RGBDVSlam(seq.camera, depth_scale_factor=1.0, imu=seq.imu_params(),
                      camera_to_imu_transform=seq.T_b_c, threaded=False)
    with vslam:
        first = 0
        for i in range(len(seq)):
            left, right = seq.load_stereo(i)
            end = imu_batch_end(t_imu, float(seq.timestamps[i]), period_s)
            vslam.add_frame(left, _depth_m(sgbm, bf_m, left, right),
                            timestamp=float(seq.timestamps[i]),
                            imu=(t_imu[first:end], gyro[first:end], accel[first:end]))
            first = end
        stamps, T_w_c, segments = vslam.frame_trajectory()
        alignment = vslam.inertial_alignment()
    seconds = time.perf_counter() - started
    gt, est = Trajectory(*seq.groundtruth()), Trajectory(stamps, T_w_c)
    se3, sim3 = ate(gt, est, align="se3"), ate(gt, est, align="sim3")
    print(f"MH_01 RGB-D-inertial (SGBM depth): {len(stamps)}/{len(seq)} tracked, "
          f"{alignment['status']}, SE(3) ATE {se3.rmse * 1e3:.1f} mm, Sim(3) ATE "
          f"{sim3.rmse * 1e3:.1f} mm at scale {sim3.scale:.4f}, {seconds:.0f} s")
    return dict(seq=seq, stamps=stamps, segments=segments, alignment=alignment, se3=se3,
                sim3=sim3)


def test_every_frame_is_tracked_in_one_map(run):
    assert len(run["stamps"]) == len(run["seq"]) == 400
    assert set(run["segments"].tolist()) == {0}


def test_the_imu_is_aligned_with_gravity_of_the_ground_truth(run):
    """Gravity in the map's world, turned into the ground truth's (z up) by the SE(3)
    alignment of the trajectory, points down: measured 1.4 deg."""
    status = run["alignment"]
    assert status["status"] == "aligned" and status["refinement"] == 2, status
    assert not status["map_rescaled"]  # depth is metric: the alignment keeps the scale
    np.testing.assert_allclose(np.linalg.norm(status["gravity_w"]), 9.81, rtol=1e-9)
    g = run["se3"].alignment[:3, :3] @ status["gravity_w"]
    gravity_deg = float(np.degrees(np.arccos(-g[2] / np.linalg.norm(g))))
    print(f"gravity {gravity_deg:.2f} deg from the ground truth's -z")
    assert gravity_deg < 2.0


def test_metric_trajectory_within_1_cm_with_no_scale_fitted(run):
    """The issue's target, SE(3) ATE <= 1 cm; the Sim(3) fit's scale says the map is metric
    to within 3 % (SGBM's depth bias)."""
    assert run["se3"].pairs == 400
    assert run["se3"].rmse <= 0.01
    assert abs(1.0 / run["sim3"].scale - 1.0) <= 0.03, run["sim3"].scale
