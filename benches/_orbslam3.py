"""Helpers shared by the benchmark scripts: ORB-SLAM3 (``pyorbslam3``) settings, vocabulary,
per-frame driver, and process memory readings.

ORB-SLAM3 is fed the same images ferroslam reads through ``ferroslam.datasets`` (rectified
pairs for stereo, hence zero distortion; TUM keeps its radial-tangential distortion).
Settings files are written from the loader's calibration in the ORB-SLAM2-style format that
ORB-SLAM3 still parses (``Camera.fx``, ``Camera.bf``, ``ThDepth``, ``DepthMapFactor``), with
the ORB / depth parameters of ORB-SLAM3's example files (TUM1.yaml, KITTI00-02.yaml,
EuRoC.yaml). Not the v1.0 format: its ``Camera.type: "Rectified"`` stereo path segfaults in
the wheel's ORB-SLAM3 (the settings printer dereferences the absent second camera). The vocabulary is
ferroslam's shipped one exported as DBoW2 text (``Vocabulary.save_dbow2_text``), because
ORB-SLAM3's ``ORBvoc.txt`` is a separate 139 MB download.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from ferroslam.trajectory import Trajectory

# Per dataset family: ORB features, FAST thresholds, fps and (stereo/RGB-D) ThDepth, as in
# ORB-SLAM3's example settings; TUM RGB-D also uses bf = 40 and DepthMapFactor 5000.
PRESETS = {
    "tum": {"n_features": 1000, "ini_fast": 20, "min_fast": 7, "th_depth": 40.0,
            "bf": 40.0, "depth_factor": 5000.0},
    "kitti": {"n_features": 2000, "ini_fast": 20, "min_fast": 7, "th_depth": 35.0},
    "euroc": {"n_features": 1200, "ini_fast": 20, "min_fast": 7, "th_depth": 35.0},
}


def family(seq) -> str:
    """``"tum"``, ``"kitti"`` or ``"euroc"`` from the loader class."""
    name = type(seq).__name__.lower()
    for key in PRESETS:
        if key in name:
            return key
    raise ValueError(f"no ORB-SLAM3 preset for {type(seq).__name__}")


EXTRACTOR_KEYS = ("n_features", "ini_fast", "min_fast")
INERTIAL = "-inertial"


def camera_sensor(sensor: str) -> str:
    """The camera part of ``sensor``: ``"stereo-inertial"`` -> ``"stereo"``; the camera
    settings and the ORB options do not depend on the IMU."""
    return sensor.removesuffix(INERTIAL)


def _preset(seq, extractor: Optional[dict]) -> dict:
    """The preset of ``seq``'s family with the ORB extractor options in ``extractor``
    (keys of :data:`EXTRACTOR_KEYS`) replaced.

    Raises:
        ValueError: a key that is not an extractor option.
    """
    extractor = extractor or {}
    unknown = set(extractor) - set(EXTRACTOR_KEYS)
    if unknown:
        raise ValueError(f"unknown extractor options {sorted(unknown)}; known: {EXTRACTOR_KEYS}")
    return {**PRESETS[family(seq)], **{k: int(v) for k, v in extractor.items()}}


def ferroslam_config(seq, sensor: str, extractor: Optional[dict] = None) -> dict:
    """ferroslam run options matching the ORB-SLAM3 settings (features, ThDepth, bf), with the
    extractor options in ``extractor`` replaced (see :func:`_preset`)."""
    p = _preset(seq, extractor)
    config = {k: p[k] for k in EXTRACTOR_KEYS}
    sensor = camera_sensor(sensor)
    if sensor in ("rgbd", "stereo"):
        config["depth_threshold"] = p["th_depth"]
    if sensor == "rgbd":
        config["bf"] = p["bf"]
    return config


def _f(x: float) -> str:
    """A YAML real that OpenCV's FileStorage reads as real (always with a decimal point)."""
    return repr(float(x))


def write_settings(seq, sensor: str, out_dir: Path, extractor: Optional[dict] = None) -> Path:
    """Write an ORB-SLAM3 v1.0 settings file for ``seq`` and ``sensor`` into ``out_dir``.

    ``sensor``: ``"mono"``, ``"rgbd"`` or ``"stereo"`` (the loader's rectified pair), each
    optionally ``"-inertial"`` (adds :func:`_imu_settings`); ``extractor`` replaces ORB
    extractor options (see :func:`_preset`).
    """
    fam = family(seq)
    p = _preset(seq, extractor)
    inertial, sensor = sensor.endswith(INERTIAL), camera_sensor(sensor)
    cam = seq.camera
    dist = np.asarray(cam.dist, dtype=np.float64).reshape(-1)
    fps = int(round(1.0 / float(np.median(np.diff(seq.timestamps)))))
    lines = ["%YAML:1.0", 'Camera.type: "PinHole"']
    lines += [f"Camera.{k}: {_f(v)}" for k, v in
              (("fx", cam.fx), ("fy", cam.fy), ("cx", cam.cx), ("cy", cam.cy))]
    # Stereo pairs come rectified (zero distortion); k1..p2 are required keys anyway.
    coeffs = np.zeros(5) if sensor == "stereo" else np.pad(dist, (0, max(0, 5 - dist.size)))
    lines += [f"Camera.{k}: {_f(v)}" for k, v in zip(("k1", "k2", "p1", "p2", "k3"), coeffs)]
    lines += [f"Camera.width: {int(cam.width)}", f"Camera.height: {int(cam.height)}",
              f"Camera.fps: {_f(fps)}", "Camera.RGB: 1"]
    if sensor == "stereo":
        lines += [f"Camera.bf: {_f(seq.baseline_m * cam.fx)}", f"ThDepth: {_f(p['th_depth'])}"]
    if sensor == "rgbd":
        lines += [f"Camera.bf: {_f(p['bf'])}", f"ThDepth: {_f(p['th_depth'])}",
                  f"DepthMapFactor: {_f(p['depth_factor'])}"]
    lines += [f"ORBextractor.nFeatures: {p['n_features']}", "ORBextractor.scaleFactor: 1.2",
              "ORBextractor.nLevels: 8", f"ORBextractor.iniThFAST: {p['ini_fast']}",
              f"ORBextractor.minThFAST: {p['min_fast']}"]
    if inertial:
        lines += _imu_settings(seq)
    # The viewer is off, but ORB-SLAM3 still parses these.
    lines += ["Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0",
              "Viewer.GraphLineWidth: 0.9", "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08",
              "Viewer.CameraLineWidth: 3.0", "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7",
              "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500.0"]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"orbslam3_{fam}_{sensor}{INERTIAL * inertial}.yaml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def T_imu_c(seq) -> np.ndarray:
    """ORB-SLAM3's ``Tbc``: the pose of the camera whose images it gets (``seq.T_b_c``) in
    the IMU frame, its "body" (EuRoC's body frame is the IMU's, but say so)."""
    return np.linalg.inv(seq.imu_params().T_b_imu) @ seq.T_b_c


def _imu_settings(seq) -> list:
    """The IMU keys of ORB-SLAM3's EuRoC settings from ``seq.imu_params()`` (continuous-time
    noise densities and random walks, as ORB-SLAM3 expects) and ``Tbc`` (:func:`T_imu_c`)."""
    imu = seq.imu_params()
    data = ", ".join(_f(v) for v in T_imu_c(seq).reshape(-1))
    return ["Tbc: !!opencv-matrix", "   rows: 4", "   cols: 4", "   dt: f",
            f"   data: [{data}]",
            f"IMU.NoiseGyro: {_f(imu.gyroscope_noise_density)}",
            f"IMU.NoiseAcc: {_f(imu.accelerometer_noise_density)}",
            f"IMU.GyroWalk: {_f(imu.gyroscope_random_walk)}",
            f"IMU.AccWalk: {_f(imu.accelerometer_random_walk)}",
            f"IMU.Frequency: {int(round(imu.rate_hz))}",  # an integer, or ORB-SLAM3 refuses
            # ORB-SLAM3's default, written out: keyframes are inserted while lost.
            "IMU.InsertKFsWhenLost: 1"]


def imu_bounds(imu_t: np.ndarray, frame_t: np.ndarray) -> np.ndarray:
    """Sample ranges for the frames: frame ``i`` gets the samples ``bounds[i]:bounds[i + 1]``,
    those in (frame ``i - 1``, frame ``i``] (the first frame every sample up to it: ORB-SLAM3
    drops those before the previous frame itself), as ORB-SLAM3's track calls want."""
    return np.concatenate(([0], np.searchsorted(imu_t, frame_t, side="right")))


def export_vocabulary(out_dir: Path) -> Path:
    """ferroslam's shipped vocabulary as DBoW2 text in ``out_dir`` (written once)."""
    from ferroslam.vocabulary import default_vocabulary

    path = Path(out_dir) / "ferroslam_dbow2.txt"
    if not path.is_file():
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        default_vocabulary().save_dbow2_text(str(path))
    return path


def read_euroc_trajectory(path: Path) -> Trajectory:
    """ORB-SLAM3's ``SaveTrajectoryEuRoC`` file (``ns tx ty tz qx qy qz qw``) as T_w_c, one
    pose per timestamp.

    ORB-SLAM3 records a frame it failed to track as a copy of the last recorded frame: same
    timestamp, same pose (``Tracking::Track`` pushes ``mlFrameTimes.back()`` and
    ``mlRelativeFramePoses.back()``). The copies say nothing about the lost frames, and kept
    they would weigh the last tracked pose once per lost frame in an ATE: the first row of
    each timestamp is kept.
    """
    rows = np.loadtxt(path, ndmin=2)
    if rows.size == 0:
        return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    _, first = np.unique(rows[:, 0], return_index=True)
    rows = rows[first]
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    x, y, z, w = rows[:, 4], rows[:, 5], rows[:, 6], rows[:, 7]
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    poses[:, 0, 0] = 1 - 2 * (y * y + z * z)
    poses[:, 0, 1] = 2 * (x * y - z * w)
    poses[:, 0, 2] = 2 * (x * z + y * w)
    poses[:, 1, 0] = 2 * (x * y + z * w)
    poses[:, 1, 1] = 1 - 2 * (x * x + z * z)
    poses[:, 1, 2] = 2 * (y * z - x * w)
    poses[:, 2, 0] = 2 * (x * z - y * w)
    poses[:, 2, 1] = 2 * (y * z + x * w)
    poses[:, 2, 2] = 1 - 2 * (x * x + y * y)
    poses[:, :3, 3] = rows[:, 1:4]
    return Trajectory(rows[:, 0] * 1e-9, poses)


@dataclass
class OrbSlam3Run:
    """Outcome of :func:`run_orbslam3`: per-call milliseconds, states, trajectories."""

    call_ms: np.ndarray
    states: list
    load_s: float
    trajectory: Trajectory            # final (after shutdown), biggest map, one pose per frame
    online: Trajectory                # poses returned by each call (pose_valid frames)
    imu_initialized: bool             # inertial sensors: the IMU initialised by the last frame
    peak_rss_kb: int                  # VmHWM of the run's process after the last frame
    peak_delta_kb: int                # ... minus its RSS before ORB-SLAM3 was created
    shutdown_s: float = float("nan")  # shutdown + trajectory save; NaN when it never answered
    errors: list = field(default_factory=list)

    @property
    def tracked_frames(self) -> int:
        return sum(s == "OK" for s in self.states)


def run_orbslam3(seq, sensor: str, n: int, vocab: Path, settings: Path,
                 realtime: bool = False, track_timeout_s: float = 1800.0,
                 shutdown_timeout_s: float = 120.0) -> OrbSlam3Run:
    """Feed frames ``0..n`` of ``seq`` to ORB-SLAM3 one by one, timing only the track call
    (at the pace of their timestamps with ``realtime``), in a forked child process.

    Image loading (and TUM depth scaling to raw units) happens outside the timed region, as
    ferroslam's ``frame_ms`` excludes loading. ORB-SLAM3's local mapping and loop closing
    run in their own threads, so a call's time is extraction + tracking only.

    The child sends the per-frame results after the last frame, then shuts ORB-SLAM3 down
    and sends its final trajectory (``SaveTrajectoryEuRoC``). The second step can hang,
    holding the GIL so that no thread can time it out: ORB-SLAM3 locks a stale map's mutex
    and never returns when every map of its atlas is empty (a monocular run whose map was
    reset and never re-initialised), and mono-inertial runs that reset their map hang in
    ``shutdown``. A child that does not answer within ``shutdown_timeout_s`` is killed and
    the per-call poses stand in for the final trajectory, with the failure in ``errors``.

    Raises:
        RuntimeError: the child failed or did not finish tracking within ``track_timeout_s``.
    """
    ctx = multiprocessing.get_context("fork")  # the child inherits seq; nothing is pickled in
    receiver, sender = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_orbslam3_child,
                        args=(sender, seq, sensor, n, vocab, settings, realtime), daemon=True)
    child.start()
    sender.close()
    try:
        run = _receive(receiver, track_timeout_s, "tracking")
        if isinstance(run, str):
            raise RuntimeError(f"ORB-SLAM3 tracking failed: {run}")
        try:
            shutdown_s, final = _receive(receiver, shutdown_timeout_s, "shutdown and save")
        except RuntimeError as err:
            run.errors.append(f"{err}; using the per-call poses")
        else:
            run.shutdown_s = shutdown_s
            if isinstance(final, str):
                run.errors.append(f"save_trajectory_euroc: {final}; using the per-call poses")
            else:
                run.trajectory = Trajectory(*final)
        return run
    finally:
        child.kill()
        child.join()


def _receive(conn, timeout_s: float, what: str):
    """The next message on ``conn``.

    Raises:
        RuntimeError: none within ``timeout_s``, or the child died first.
    """
    if not conn.poll(timeout_s):
        raise RuntimeError(f"ORB-SLAM3 {what}: no answer in {timeout_s:.0f} s")
    try:
        return conn.recv()
    except EOFError:
        raise RuntimeError(f"ORB-SLAM3 {what}: the process died") from None


def _orbslam3_child(conn, seq, sensor, n, vocab, settings, realtime) -> None:
    """:func:`run_orbslam3`'s child: sends the :class:`OrbSlam3Run` (or an error message),
    then ``(shutdown_s, (timestamps, T_w_c) or an error message)``."""
    import pyorbslam3 as pos

    try:
        slam, run = _track(pos, seq, sensor, n, vocab, settings, realtime)
    except Exception as err:  # noqa: BLE001 - reported to the parent, which raises
        conn.send(f"{type(err).__name__}: {err}")
        return
    conn.send(run)
    t0 = time.perf_counter()
    slam.shutdown()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "orbslam3_traj.txt"
        try:
            slam.save_trajectory_euroc(str(out))
            final = read_euroc_trajectory(out)
            if sensor.endswith(INERTIAL):  # ORB-SLAM3 saves the IMU's pose T_w_imu then
                final = Trajectory(final.timestamps, final.poses @ T_imu_c(seq))
            message = (final.timestamps, final.poses)
        except (RuntimeError, OSError, ValueError) as err:
            message = str(err)
    conn.send((time.perf_counter() - t0, message))


def _track(pos, seq, sensor, n, vocab, settings, realtime):
    """Create ORB-SLAM3 and track frames ``0..n``: ``(slam, OrbSlam3Run)`` whose final
    trajectory is still the per-call poses."""
    kind = {"mono": pos.Sensor.MONOCULAR, "rgbd": pos.Sensor.RGBD,
            "stereo": pos.Sensor.STEREO, "mono-inertial": pos.Sensor.IMU_MONOCULAR,
            "stereo-inertial": pos.Sensor.IMU_STEREO}[sensor]
    base = memory_kb()["VmRSS"]
    reset_peak_memory()
    t0 = time.perf_counter()
    slam = pos.Slam(vocab_file=str(vocab), settings_file=str(settings), sensor=kind,
                    use_viewer=False)
    load_s = time.perf_counter() - t0
    imu = None
    if sensor.endswith(INERTIAL):
        imu_t, gyro, accel = seq.imu()
        samples = np.column_stack((imu_t, gyro, accel))
        bounds = imu_bounds(imu_t, np.asarray(seq.timestamps[:n], dtype=np.float64))
    factor = PRESETS["tum"]["depth_factor"]
    call_ms = np.full(n, np.nan)
    states, stamps, poses = [], [], []
    run_start = time.perf_counter()
    camera = camera_sensor(sensor)
    for i in range(n):
        t = float(seq.timestamps[i])
        if realtime:
            time.sleep(max(0.0, run_start + t - float(seq.timestamps[0]) - time.perf_counter()))
        if camera == "rgbd":
            args = (seq.load_gray(i), (seq.load_depth(i) * factor).astype(np.float32))
            fn = slam.track_rgbd
        elif camera == "stereo":
            args = seq.load_stereo(i)
            fn = slam.track_stereo
        else:
            args = (seq.load_gray(i),)
            fn = slam.track_monocular
        if sensor.endswith(INERTIAL):
            imu = samples[bounds[i]:bounds[i + 1]]
        start = time.perf_counter()
        res = fn(*args, t, imu=imu)
        call_ms[i] = (time.perf_counter() - start) * 1e3
        states.append(res.state.name)
        if res.pose_valid and res.pose_wc is not None:
            stamps.append(t)
            poses.append(np.asarray(res.pose_wc, dtype=np.float64))
    peak = memory_kb()["VmHWM"]
    online = Trajectory(np.asarray(stamps), np.asarray(poses).reshape(-1, 4, 4))
    run = OrbSlam3Run(call_ms, states, load_s, online, online,
                      bool(slam.inertial and slam.imu_initialized()), peak, peak - base)
    return slam, run


def memory_kb() -> dict:
    """Current ``VmRSS`` and peak ``VmHWM`` of this process, kB (Linux ``/proc``)."""
    out = {}
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith(("VmRSS:", "VmHWM:")):
                out[line.split(":")[0]] = int(line.split()[1])
    return out


def reset_peak_memory() -> bool:
    """Reset ``VmHWM`` to the current RSS (``/proc/self/clear_refs`` = 5); False if refused."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as f:
            f.write("5")
        return True
    except OSError:
        return False


def load_average() -> Optional[tuple]:
    try:
        return os.getloadavg()
    except OSError:
        return None


@contextmanager
def cpus_kept_busy(enabled: bool = True):
    """While the block runs, one ``SCHED_IDLE`` busy-loop process per CPU, so that no CPU
    ever idles (Linux only; a no-op when not ``enabled``).

    For virtual machines whose host packs the vCPUs of a guest that idles onto fewer
    physical cores (measured with ``benches/cpu_packing.py``): a process that sleeps between
    frames then gets one core's worth of two threads. Inside the guest the measured threads
    always preempt the spinners, but the host still sees two busy vCPUs: on the machine of
    ``docs/benchmarks.md`` bursty monocular runs got faster with them and sustained stereo
    ones slower, for both systems, so it is a sensitivity check, not a cleaner measurement.

    Yields:
        The busy-loop processes (none when not ``enabled``).

    Raises:
        OSError: ``SCHED_IDLE`` not available (not Linux).
    """
    if not enabled:
        yield []
        return
    if not hasattr(os, "SCHED_IDLE"):
        raise OSError("keeping the CPUs busy needs Linux's SCHED_IDLE scheduling class")
    spinners = []
    try:
        for _ in range(os.cpu_count() or 1):
            spinners.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
            # The lowest class: it runs only when no other thread wants the CPU.
            os.sched_setscheduler(spinners[-1].pid, os.SCHED_IDLE, os.sched_param(0))
        time.sleep(0.5)  # the host has unpacked the vCPUs by then (cpu_packing.py)
        yield spinners
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()
