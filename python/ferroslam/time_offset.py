"""The camera-IMU time offset, estimated from the data: the gyroscope's angular rate against
the rotation rate the camera poses of a visual-only run show.

Sign convention, ferroslam's ``imu_time_offset_s`` (Kalibr's ``timeshift_cam_imu``): a
sample stamped ``t_imu`` was measured at camera time ``t_imu - imu_time_offset_s``, so
``t_imu = t_cam + imu_time_offset_s``. IMU stamps that run 20 ms late give +0.020.

The camera gives the mean rate between consecutive frames, ``Log(R_w_ck^T R_w_ck+1) / dt``
in camera ``k``; rotated into the IMU frame it is compared with the gyroscope's mean over the
same interval shifted by a candidate offset (from the integrated gyro, so both are the same
box average, whatever the two rates). The normalised cross-correlation over the candidate
offsets, one IMU period apart, peaks at the offset; a parabola through the peak and its two
neighbours gives it below the sample period. Its uncertainty is the spread of the peak over
a block bootstrap (blocks of about a second of frames, resampled with replacement): the
motion of the window decides how sharp the peak is, not a model of the noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .transforms import matrix_to_quat

__all__ = ["TimeOffsetEstimate", "camera_rotation_rates", "estimate_imu_time_offset"]

# Bootstrap: resamples, block length and the seed (estimates repeat exactly).
_BOOTSTRAP_RESAMPLES = 200
_BOOTSTRAP_BLOCK_S = 1.0
_BOOTSTRAP_SEED = 0


@dataclass(frozen=True)
class TimeOffsetEstimate:
    """``imu_time_offset_s`` (seconds, the sign of the module doc), its bootstrap standard
    deviation ``uncertainty_s``, the correlation at the peak (1 for rates equal up to a
    scale), ``gyro_scale`` (gyro rate over camera rate at the peak, least squares: 1 when
    units and extrinsic rotation agree, about 57.3 for a gyro in deg/s), ``at_search_edge``
    (the peak lies at the end of the searched range: the offset may be beyond it),
    ``intervals`` (frame pairs used) and ``rotation_rate_rad_s`` (RMS camera rotation rate,
    what makes the peak sharp)."""

    imu_time_offset_s: float
    uncertainty_s: float
    correlation: float
    gyro_scale: float
    at_search_edge: bool
    intervals: int
    rotation_rate_rad_s: float


def camera_rotation_rates(timestamps: np.ndarray, T_w_c: np.ndarray,
                          max_gap_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean rotation rates between consecutive poses: ``(t_start (K,), t_end (K,),
    rate (K, 3) rad/s in the camera frame of the start)``, for the pairs at most ``max_gap_s``
    apart (a pair across a lost stretch is no rate)."""
    t = np.asarray(timestamps, dtype=np.float64)
    R = np.asarray(T_w_c, dtype=np.float64)[:, :3, :3]
    dt = np.diff(t)
    keep = (dt > 0) & (dt <= max_gap_s)
    R_k_k1 = np.einsum("nji,njk->nik", R[:-1][keep], R[1:][keep])
    q = matrix_to_quat(R_k_k1)
    q = q * np.where(q[:, 3:] < 0, -1.0, 1.0)  # the short way round
    s = np.linalg.norm(q[:, :3], axis=1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[:, 3:])
    rotvec = q[:, :3] * np.where(s > 0, angle / np.maximum(s, 1e-300), 2.0)
    return t[:-1][keep], t[1:][keep], rotvec / dt[keep][:, None]


def _normalised(x: np.ndarray) -> np.ndarray:
    """Zero-mean per axis (the gyro bias, a constant, drops out) over the last two axes."""
    return x - x.mean(axis=-2, keepdims=True)


def _peak(correlation: np.ndarray, lags: np.ndarray) -> float:
    """The lag of the largest correlation, refined by the parabola through it and its two
    neighbours (at either end of the range: the end itself)."""
    k = int(np.argmax(correlation))
    if k in (0, len(lags) - 1):
        return float(lags[k])
    y0, y1, y2 = correlation[k - 1:k + 2]
    curvature = y0 - 2.0 * y1 + y2
    step = lags[1] - lags[0]
    shift = 0.5 * (y0 - y2) / curvature if curvature < 0 else 0.0
    return float(lags[k] + shift * step)


def estimate_imu_time_offset(frame_timestamps: np.ndarray, T_w_c: np.ndarray,
                             imu_timestamps: np.ndarray, gyro: np.ndarray,
                             R_imu_c: np.ndarray, *, max_offset_s: float = 0.2,
                             max_gap_s: float = np.inf) -> TimeOffsetEstimate:
    """Estimate ``imu_time_offset_s`` (module doc) from camera poses and gyro samples.

    Args:
        frame_timestamps: ``(N,)`` seconds, camera clock, of the poses ``T_w_c`` ``(N, 4, 4)``
            (a visual-only run's tracked frames).
        imu_timestamps: ``(M,)`` seconds, IMU clock, strictly increasing; ``gyro`` ``(M, 3)``
            rad/s in the IMU frame.
        R_imu_c: ``(3, 3)`` rotation of the camera in the IMU frame.
        max_offset_s: offsets searched, ``[-max_offset_s, max_offset_s]``.
        max_gap_s: longest frame interval used (longer ones span lost frames).

    Raises ``ValueError`` when fewer than 20 frame intervals fall where the shifted IMU data
    covers them (too short a window, or clocks further apart than ``max_offset_s``).
    """
    t_imu = np.asarray(imu_timestamps, dtype=np.float64)
    gyro = np.asarray(gyro, dtype=np.float64)
    t0, t1, rate_c = camera_rotation_rates(frame_timestamps, T_w_c, max_gap_s)
    step = float(np.median(np.diff(t_imu)))
    n_lags = int(np.floor(max_offset_s / step))
    lags = step * np.arange(-n_lags, n_lags + 1)
    # Intervals that the IMU covers at every candidate offset.
    inside = (t0 + lags[0] >= t_imu[0]) & (t1 + lags[-1] <= t_imu[-1])
    t0, t1, rate_c = t0[inside], t1[inside], rate_c[inside]
    if len(t0) < 20:
        raise ValueError(f"only {len(t0)} frame intervals overlap the IMU data within "
                         f"+-{max_offset_s} s: the camera and IMU times do not overlap enough "
                         "to estimate their offset")
    # The integral of the gyro: its difference over an interval is the interval's mean rate.
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(
        0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t_imu)[:, None], axis=0)])

    def at(times: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(times, t_imu, integral[:, k]) for k in range(3)], axis=-1)

    dt = (t1 - t0)[None, :, None]
    rate_g = (at(t1[None, :] + lags[:, None]) - at(t0[None, :] + lags[:, None])) / dt
    rate_ci = rate_c @ np.asarray(R_imu_c, dtype=np.float64).T  # (K, 3), IMU frame

    def peak_of(index: np.ndarray) -> tuple[float, np.ndarray]:
        x = _normalised(rate_ci[index])
        g = _normalised(rate_g[:, index])
        corr = np.einsum("kj,lkj->l", x, g) / np.sqrt(
            np.sum(x * x) * np.einsum("lkj,lkj->l", g, g))
        return _peak(corr, lags), corr

    everything = np.arange(len(t0))
    offset_s, corr = peak_of(everything)
    k = int(np.argmax(corr))
    x, g = _normalised(rate_ci), _normalised(rate_g[k])
    # Blocks of consecutive intervals, resampled with replacement.
    block = max(2, int(round(_BOOTSTRAP_BLOCK_S / np.median(t1 - t0))))
    starts = np.arange(0, len(t0) - block + 1)
    rng = np.random.default_rng(_BOOTSTRAP_SEED)
    n_blocks = int(np.ceil(len(t0) / block))
    boot = [peak_of((rng.choice(starts, n_blocks)[:, None] + np.arange(block)).ravel())[0]
            for _ in range(_BOOTSTRAP_RESAMPLES)]
    return TimeOffsetEstimate(
        imu_time_offset_s=offset_s, uncertainty_s=float(np.std(boot)),
        correlation=float(corr[k]), gyro_scale=float(np.sum(x * g) / np.sum(x * x)),
        at_search_edge=k in (0, len(lags) - 1), intervals=len(t0),
        rotation_rate_rad_s=float(np.sqrt(np.mean(np.sum(x * x, axis=1)))))
