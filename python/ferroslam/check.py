"""``ferroslam check``: what in the data or its calibration would make a run fail, said before
the run, one :class:`Check` (ok / warning / error, and what to do) per concern.

The checks read what every source gives (``ferroslam.datasets`` and ``ferroslam.sources``;
any other with the same attributes plugs in): ``timestamps``, ``camera``, ``load_gray(i)``,
and where the source has them ``is_stereo`` + ``load_stereo(i)``, ``load_depth(i)`` (metres)
with ``depth_factor``, and ``imu()`` + ``imu_params()`` + ``T_b_c``.

- cheap (:func:`cheap_checks`, which ``ferroslam run`` runs first): image sizes against the
  calibration, the calibration's plausibility (the core's checks, run when a ``Camera`` is
  made: principal point inside the image, distortion one-to-one and lens-like out to the
  farthest corner), frame times;
- the rest (:func:`check_sequence`): depth scale, the IMU stream (rate, gaps, coverage,
  units, gravity, noise) and the camera-IMU time offset from a short visual-only run
  (:mod:`ferroslam.time_offset`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from .depth_scale import assess_depth_scale, describe
from .time_offset import TimeOffsetEstimate, estimate_imu_time_offset

__all__ = ["Check", "CheckReport", "check_depth_scale", "check_frame_times", "check_imu",
           "check_sequence", "cheap_checks", "opening_error", "require_cheap_checks",
           "sensor_of"]

OK, WARNING, ERROR = "ok", "warning", "error"

_DEPTH_FRAMES = 5  # frames sampled over the sequence for the depth check

# A frame interval this many times the median is a gap (frames dropped).
_FRAME_GAP = 1.5
# An IMU interval this many times the median is a gap; the core falls back to vision over
# gaps of more than 10 periods, shorter ones are interpolated over.
_IMU_GAP = 3.0
_IMU_RATE_TOLERANCE = 0.05  # measured vs declared rate, relative
_GRAVITY_TOLERANCE_M_S2 = 0.3  # |g| varies by 0.05 over the Earth; the rest, bias and scale
_REST_WINDOW_S = 1.0  # the quietest window of this length is taken as "at rest"
# Measured white noise beyond this multiple of the declared density: the estimator would
# trust the IMU far more than it deserves.
_NOISE_RATIO = 10.0

# The time offset: the visual run's window (the first seconds; hand-held or flying data
# rotates from the start), the offsets searched (the option allows +-1 s; every offset
# searched costs the window's ends, which the shifted IMU must still cover), a correlation
# below which the estimate is not trusted, and the rotation rate below which the peak is too
# flat to mean anything.
_OFFSET_WINDOW_S = 10.0
_MAX_OFFSET_S = 0.2
_MIN_CORRELATION = 0.7
_MIN_ROTATION_RAD_S = 0.05
# An offset is worth setting when above this and 3 standard deviations: a fifth of a 200 Hz
# IMU's period, what the core's interpolation of the samples resolves anyway.
_NEGLIGIBLE_OFFSET_S = 0.001


@dataclass(frozen=True)
class Check:
    """One check's outcome: ``name`` (what was checked), ``verdict`` (``"ok"``,
    ``"warning"``, ``"error"``: the run would fail or go wrong), ``message`` (what was found
    and, unless ok, what to do) and the figures behind it (``values``, JSON-ready)."""

    name: str
    verdict: str
    message: str
    values: dict = field(default_factory=dict)

    def line(self) -> str:
        """The one line ``ferroslam check`` prints."""
        return f"{self.verdict:<7} {self.name}: {self.message}"


@dataclass
class CheckReport:
    """Every :class:`Check` of one input, and the time offset estimate (``None`` without an
    IMU, or when it could not be estimated)."""

    checks: list[Check]
    time_offset: Optional[TimeOffsetEstimate] = None

    @property
    def failed(self) -> bool:
        """Whether any check is an error (``ferroslam check`` exits with 1)."""
        return any(c.verdict == ERROR for c in self.checks)

    def to_json(self) -> dict:
        """``{"ok", "checks": [{"name", "verdict", "message", "values"}],
        "imu_time_offset_s", "imu_time_offset_uncertainty_s"}`` (seconds or null)."""
        offset = self.time_offset
        return {
            "ok": not self.failed,
            "checks": [{"name": c.name, "verdict": c.verdict, "message": c.message,
                        "values": c.values} for c in self.checks],
            "imu_time_offset_s": None if offset is None else offset.imu_time_offset_s,
            "imu_time_offset_uncertainty_s": None if offset is None else offset.uncertainty_s,
        }


def sensor_of(seq: Any) -> str:
    """The richest sensor ``seq`` can feed: ``rgbd`` with depth, ``stereo`` with pairs, else
    ``mono``; ``-inertial`` with an IMU."""
    camera = ("rgbd" if _has_depth(seq) else "stereo" if getattr(seq, "is_stereo", False)
              else "mono")
    return camera + "-inertial" if _has_imu(seq) else camera


def _has_depth(seq: Any) -> bool:
    try:
        seq.load_depth(0)
    except (AttributeError, ValueError):  # no depth at all, or opened without it
        return False
    return True


def _has_imu(seq: Any) -> bool:
    return all(hasattr(seq, a) for a in ("imu", "imu_params", "T_b_c"))


# What a loader's refusal is about, by the words the loaders and the core use: the check that
# would have found it names the line.
_OPENING_CAUSES = (
    ("principal point", "principal point"),
    ("distortion", "distortion"),
    ("out of order", "frame times"),
    ("the same time", "frame times"),
    ("image size", "image size"),
    ("calibration", "calibration"),
    ("camera", "calibration"),
)


def opening_error(err: Exception) -> Check:
    """The error line for an input that could not be opened (loaders refuse what no run
    could use: an implausible camera, times out of order, a missing file)."""
    text = " ".join(str(err).split())
    name = next((n for words, n in _OPENING_CAUSES if words in text), "input")
    todo = {"principal point": "cx, cy must lie inside the image: check the calibration's "
                               "units and image size",
            "distortion": "the coefficients do not describe a lens over this image: check "
                          "the model and coefficient order, or recalibrate",
            "frame times": "sort the frames by time and drop repeated ones"}.get(name)
    return Check(name, ERROR, f"{text}" + (f"; {todo}" if todo else ""))


def _image_size(seq: Any, sensor: str) -> Check:
    """Frame 0's images (both of a pair, the depth) against the calibration."""
    camera = seq.camera
    try:
        camera.check_image(seq.load_gray(0), "frame 0")
        if sensor.startswith("stereo") and getattr(seq, "is_stereo", False):
            for side, image in zip(("left", "right"), seq.load_stereo(0)):
                camera.check_image(image, f"frame 0 ({side})")
        if sensor.startswith("rgbd"):
            camera.check_image(seq.load_depth(0), "depth of frame 0")
    except ValueError as err:
        return Check("image size", ERROR, f"{err}: give the calibration of these images "
                                          "(or images of the calibrated size)")
    return Check("image size", OK, f"{camera.width}x{camera.height} as calibrated",
                 {"width": camera.width, "height": camera.height})


def _calibration(seq: Any) -> Check:
    """The calibration passed the core's plausibility checks, or the input would not have
    opened (:func:`opening_error` reports that). Raw stereo cameras (``raw_cameras``, as
    EuRoC's before rectification) are the ones calibrated, so the ones named."""
    cameras = [c for c in getattr(seq, "raw_cameras", (seq.camera,)) if c is not None]
    models = ", ".join(sorted({c.model for c in cameras}))
    return Check("distortion", OK,
                 f"{len(cameras)} {models} camera(s): principal point inside the image, "
                 "distortion one-to-one and lens-like out to the farthest corner",
                 {"models": [c.model for c in cameras], "dist": [c.dist.tolist()
                                                                 for c in cameras]})


def check_frame_times(timestamps: np.ndarray) -> list[Check]:
    """``frame times`` (finite, increasing: the tracker refuses a frame not after the
    previous one) and ``frame rate`` (the median rate; gaps of dropped frames)."""
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    if t.size < 2:
        return [Check("frame times", ERROR if t.size == 0 else WARNING,
                      f"{t.size} frame(s): nothing to track")]
    if not np.all(np.isfinite(t)):
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        return [Check("frame times", ERROR, f"frame {i} has time {t[i]}: give every frame a "
                                            "finite time in seconds")]
    dt = np.diff(t)
    backwards, repeated = np.flatnonzero(dt < 0), np.flatnonzero(dt == 0)
    checks = []
    if backwards.size:
        i = int(backwards[0])
        checks.append(Check("frame times", ERROR,
                            f"{backwards.size} frame(s) earlier than the one before (first: "
                            f"frame {i + 1} at {t[i + 1]:.6f} s after {t[i]:.6f} s): sort the "
                            "frames by time", {"backwards": int(backwards.size)}))
    if repeated.size:
        i = int(repeated[0])
        checks.append(Check("frame times", ERROR,
                            f"{repeated.size} repeated time(s) (first: frames {i} and {i + 1} "
                            f"at {t[i]:.6f} s): drop the repeated frames",
                            {"repeated": int(repeated.size)}))
    if checks:
        return checks
    period = float(np.median(dt))
    gaps = np.flatnonzero(dt > _FRAME_GAP * period)
    values = {"rate_hz": 1.0 / period, "frames": int(t.size), "gaps": int(gaps.size)}
    rate = f"{t.size} frames at {1.0 / period:.2f} Hz over {t[-1] - t[0]:.2f} s"
    if gaps.size:
        i = int(gaps[np.argmax(dt[gaps])])
        return [Check("frame times", OK, "increasing"),
                Check("frame rate", WARNING,
                      f"{rate}, {gaps.size} gap(s) of dropped frames (longest {dt[i]:.3f} s "
                      f"after frame {i}): tracking may be lost across them; record without "
                      "drops if it is", values)]
    return [Check("frame times", OK, "increasing"), Check("frame rate", OK, rate, values)]


def cheap_checks(seq: Any, sensor: str) -> list[Check]:
    """Image sizes, the calibration and the frame times: a frame read, no tracking."""
    return [_image_size(seq, sensor), _calibration(seq), *check_frame_times(seq.timestamps)]


def require_cheap_checks(seq: Any, sensor: str) -> None:
    """Raises ``ValueError`` with the first error of :func:`cheap_checks` (``ferroslam run``
    calls it before tracking). A live camera has no times to check in advance: skipped."""
    if getattr(seq, "live", False):
        return
    for check in cheap_checks(seq, sensor):
        if check.verdict == ERROR:
            raise ValueError(f"{check.name}: {check.message}")


def check_depth_scale(depth_m: np.ndarray, depth_factor: Optional[float]) -> Check:
    """The median valid depth (metres, as read with ``depth_factor`` pixel values per metre)
    against :data:`~ferroslam.depth_scale.PLAUSIBLE_MEDIAN_DEPTH_M`
    (:func:`~ferroslam.depth_scale.assess_depth_scale`); outside it, an error naming the common
    factor that makes it plausible (a map at the wrong scale tracks but is wrong)."""
    finding = assess_depth_scale(depth_m, 1.0 if depth_factor is None else depth_factor)
    if finding.median_m is None:
        return Check("depth scale", ERROR, "no valid depth in the frames sampled: check the "
                                           "depth images (all zero?)")
    values: dict[str, Any] = {"median_depth_m": finding.median_m, "depth_factor": depth_factor}
    factor = "" if depth_factor is None else f" with depth factor {depth_factor:g}"
    if finding.advice is None:
        return Check("depth scale", OK, f"median depth {finding.median_m:.2f} m{factor}", values)
    if depth_factor is None:
        return Check("depth scale", ERROR, f"median depth {finding.median_m:.3g} m: the depth "
                                           "images are not in the unit the calibration says",
                     values)
    if finding.suggested_factor is not None:
        values["suggested_depth_factor"] = finding.suggested_factor
    return Check("depth scale", ERROR, f"{describe(finding, depth_factor)}; {finding.advice}",
                 values)


def _depth_samples(seq: Any) -> np.ndarray:
    picks = np.unique(np.linspace(0, len(seq) - 1, _DEPTH_FRAMES).round().astype(int))
    return np.concatenate([np.asarray(seq.load_depth(int(i)), np.float64).ravel()
                           for i in picks])


def _imu_units(seq: Any, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> Check:
    """The core's own unit checks (gyro beyond 35 rad/s: deg/s; mean |accel| near 1: g), run
    by adding the samples to a system, so they live in one place."""
    from ._core import SlamSystem

    c = seq.camera
    system = SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, model=c.model,
                        sensor="mono")
    try:
        system.set_imu(seq.imu_params(), np.asarray(seq.T_b_c, np.float64))
        system.add_imu(t, gyro, accel)
    except ValueError as err:
        return Check("imu units", ERROR, str(err))  # the core says which unit it looks like
    finally:
        system.close()
    return Check("imu units", OK, "rad/s and m/s^2 (gyro under 35 rad/s, mean |accel| "
                                  "not near 1)")


def check_imu(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, params: Any,
              frame_timestamps: np.ndarray) -> list[Check]:
    """``imu rate`` (against ``params.rate_hz``; gaps), ``imu coverage`` (of the frames),
    ``gravity`` (|mean accel| in the quietest second, against the core's
    ``gravity_magnitude``) and ``imu noise`` (white noise from sample-to-sample differences against the declared densities).
    ``t`` increasing seconds, ``gyro`` rad/s, ``accel`` m/s^2, ``params`` an ``ImuParams``."""
    dt = np.diff(t)
    period = float(np.median(dt))
    rate = 1.0 / period
    checks = []
    gaps = np.flatnonzero(dt > _IMU_GAP * period)
    values = {"rate_hz": rate, "declared_rate_hz": params.rate_hz, "gaps": int(gaps.size)}
    problems = []
    if abs(rate / params.rate_hz - 1.0) > _IMU_RATE_TOLERANCE:
        problems.append(f"the parameters say {params.rate_hz:g} Hz: correct rate_hz (the "
                        "noise model is discretised with it)")
    if gaps.size:
        i = int(gaps[np.argmax(dt[gaps])])
        problems.append(f"{gaps.size} gap(s) (longest {dt[i]:.3f} s, {t[i] - t[0]:.2f} s in): the "
                        "IMU is not used across gaps of more than 10 periods")
    checks.append(Check("imu rate", WARNING if problems else OK,
                        "; ".join([f"{len(t)} samples at {rate:.1f} Hz"] + problems), values))
    frames = np.asarray(frame_timestamps, np.float64)
    before, after = int(np.sum(frames < t[0])), int(np.sum(frames > t[-1]))
    checks.append(Check(
        "imu coverage", WARNING if before or after else OK,
        f"{before} frame(s) before the first sample, {after} after the last"
        + (": those frames get no IMU; record the IMU over the whole sequence"
           if before or after else ""), {"frames_before": before, "frames_after": after}))
    window = max(2, int(round(_REST_WINDOW_S * rate)))
    n_windows = len(t) // window
    if n_windows:
        blocks = accel[:n_windows * window].reshape(n_windows, window, 3)
        quiet = int(np.argmin(blocks.std(axis=1).sum(axis=1)))
        g = float(np.linalg.norm(blocks[quiet].mean(axis=0)))
        from .options import core_default  # the core's |g|, the one the alignment uses

        gravity_m_s2 = core_default("gravity_magnitude", "mono")
        gravity_ok = abs(g - gravity_m_s2) <= _GRAVITY_TOLERANCE_M_S2
        checks.append(Check(
            "gravity", OK if gravity_ok else WARNING,
            f"|accel| {g:.2f} m/s^2 in the quietest {_REST_WINDOW_S:g} s ("
            f"{t[quiet * window] - t[0]:.1f} s in)" + ("" if gravity_ok else
                                            f", not {gravity_m_s2} m/s^2: check the "
                                            "accelerometer's scale, or that it was at rest"),
            {"gravity_m_s2": g, "at_s": float(t[quiet * window])}))
    # Differences of consecutive samples: smooth motion cancels, white noise of std s gives
    # std s * sqrt(2); the declared density d (per sqrt(Hz)) gives s = d * sqrt(rate).
    measured = {name: float(np.median(np.std(np.diff(x, axis=0), axis=0)) / np.sqrt(2.0))
                for name, x in (("gyro", gyro), ("accel", accel))}
    declared = {"gyro": params.gyroscope_noise_density * np.sqrt(rate),
                "accel": params.accelerometer_noise_density * np.sqrt(rate)}
    ratios = {k: measured[k] / declared[k] for k in measured}
    noisy = [k for k, r in ratios.items() if r > _NOISE_RATIO]
    checks.append(Check(
        "imu noise", WARNING if noisy else OK,
        f"measured / declared white noise: gyro {ratios['gyro']:.1f}x, accel "
        f"{ratios['accel']:.1f}x" + (f"; raise the {' and '.join(noisy)} noise density "
                                     "(vibration, or a density per sample instead of per "
                                     "sqrt(Hz)?)" if noisy else ""),
        {"gyro_ratio": ratios["gyro"], "accel_ratio": ratios["accel"]}))
    return checks


def _time_offset(seq: Any, sensor: str, t_imu: np.ndarray,
                 gyro: np.ndarray) -> tuple[Check, Optional[TimeOffsetEstimate]]:
    """The offset from a visual-only run over the first seconds (:mod:`ferroslam.time_offset`)."""
    from .pipeline import run_sequence

    visual = sensor.removesuffix("-inertial")
    frames = int(np.searchsorted(seq.timestamps, seq.timestamps[0] + _OFFSET_WINDOW_S))
    result = run_sequence(seq, sensor=visual, max_frames=max(frames, 2), progress=False)
    traj = result.trajectory
    R_imu_c = (np.asarray(seq.imu_params().T_b_imu)[:3, :3].T
               @ np.asarray(seq.T_b_c, np.float64)[:3, :3])
    period = float(np.median(np.diff(seq.timestamps)))
    try:
        est = estimate_imu_time_offset(traj.timestamps, traj.poses, t_imu, gyro, R_imu_c,
                                       max_offset_s=_MAX_OFFSET_S,
                                       max_gap_s=_FRAME_GAP * period)
    except ValueError as err:
        return Check("time offset", WARNING, f"not estimated: {err} ({len(traj.timestamps)} "
                                             f"of {frames} frames tracked by {visual})"), None
    values = {"imu_time_offset_s": est.imu_time_offset_s, "uncertainty_s": est.uncertainty_s,
              "correlation": est.correlation, "gyro_scale": est.gyro_scale,
              "intervals": est.intervals, "rotation_rate_rad_s": est.rotation_rate_rad_s}
    found = (f"{1e3 * est.imu_time_offset_s:+.1f} +- {1e3 * est.uncertainty_s:.1f} ms "
             f"(correlation {est.correlation:.3f} over {est.intervals} frame intervals of "
             f"{visual})")
    if est.rotation_rate_rad_s < _MIN_ROTATION_RAD_S:
        return Check("time offset", WARNING,
                     f"{found}: the first {traj.timestamps[-1] - traj.timestamps[0]:.1f} s "
                     "hardly rotate "
                     f"({est.rotation_rate_rad_s:.3f} rad/s RMS); rotate the camera there to "
                     "measure the offset", values), None
    if est.correlation < _MIN_CORRELATION or est.at_search_edge:
        why = (f"the peak is at the end of +-{_MAX_OFFSET_S:g} s searched"
               if est.at_search_edge else "the rates hardly agree")
        return Check("time offset", WARNING,
                     f"{found}: {why}; check the camera-IMU rotation (T_b_c) and that the "
                     "gyro is the camera's", values), None
    if not 0.8 < est.gyro_scale < 1.25:
        return Check("time offset", WARNING,
                     f"{found}, but the gyro rates are {est.gyro_scale:.2f} times the camera's:"
                     " check the gyro's unit (57.3: deg/s) and T_b_c", values), est
    if abs(est.imu_time_offset_s) > max(3.0 * est.uncertainty_s, _NEGLIGIBLE_OFFSET_S):
        late = "late" if est.imu_time_offset_s > 0 else "early"
        return Check("time offset", WARNING,
                     f"{found}: the IMU stamps are {late} against the camera's; set "
                     f"imu_time_offset_s = {est.imu_time_offset_s:.4f} (--config)", values), est
    return Check("time offset", OK, f"{found}: the clocks agree", values), est


def check_sequence(seq: Any, sensor: Optional[str] = None, *,
                   time_offset: bool = True) -> CheckReport:
    """Every check of ``seq`` for ``sensor`` (default :func:`sensor_of`): the cheap ones,
    the depth scale (``rgbd``), the IMU and, with ``time_offset``, the camera-IMU time offset
    (``-inertial``; a visual-only run over the first 10 s)."""
    sensor = sensor or sensor_of(seq)
    checks = cheap_checks(seq, sensor)
    report = CheckReport(checks)
    if any(c.verdict == ERROR for c in checks):
        return report  # nothing further can be read right
    if sensor.startswith("rgbd"):
        checks.append(check_depth_scale(_depth_samples(seq), getattr(seq, "depth_factor",
                                                                     None)))
    if not sensor.endswith("-inertial"):
        return report
    if not _has_imu(seq):
        checks.append(Check("imu samples", ERROR, f"sensor {sensor} needs an IMU and "
                                                  f"{getattr(seq, 'name', 'the input')} has "
                                                  "none: choose a sensor without -inertial"))
        return report
    try:
        t, gyro, accel = seq.imu()
    except ValueError as err:  # the loader refuses samples out of order, non-finite values
        checks.append(Check("imu samples", ERROR, f"{err}: fix the IMU file"))
        return report
    units = _imu_units(seq, t, gyro, accel)
    checks.append(units)
    checks.extend(check_imu(t, gyro, accel, seq.imu_params(), seq.timestamps))
    if time_offset and units.verdict != ERROR:
        check, report.time_offset = _time_offset(seq, sensor, t, gyro)
        checks.append(check)
    return report
